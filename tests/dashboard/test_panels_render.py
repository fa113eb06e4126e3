"""The view rendered from hand-made snapshots on a fixed-size recording console (no colour)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rich.cells import cell_len

from mavastsm.dashboard.panels import build_view, chattering_nm_per_s, history_arrays, sparkline
from mavastsm.dashboard.status_lines import format_status_line
from mavastsm.state_types import FailsafeReason
from mavastsm.telemetry import ControlSample, LinkStatus, SessionInfo, TelemetryBuffer


def render(snapshot, console_maker, width, height, paused=False) -> list[str]:
    console = console_maker(width, height)
    console.print(build_view(snapshot, width, height, paused=paused))
    return console.export_text().splitlines()


def test_large_terminal_shows_every_panel_with_units(snapshot_maker, console_maker):
    text = "\n".join(render(snapshot_maker(), console_maker, 140, 50))
    # per-axis table: quantities with units, values converted to degrees
    for label in ("reference Θd [deg]", "angle Θ [deg]", "error e [deg]", "Euler rate [deg/s]", "σ [rad/s]",
                  "μ band [rad/s]", "α_m to α_max", "u_eq [N·m]", "u_D [N·m]", "u total [N·m]",
                  "cmd body rate [deg/s]"):
        assert label in text
    assert "+10.00" in text and "+89.00" in text and "-0.50" in text  # deg
    assert "+12.5" in text and "+20.0" in text and "-7.5" in text  # deg/s
    assert "±0.0100" in text and "+0.0123" in text and "-0.0456" in text and "0.01 to 1e+03" in text
    # link / vehicle
    for fragment in ("udpin:127.0.0.1:14550", "ArduPilot 4.5.7", "GUIDED / ARMED", "climb_rate",
                     "398.7 of 400 Hz requested; last 2.10 ms ago", "p50 0.41 ms  p99 1.23 ms",
                     "4936 cycles, 0 missed", "dropped 3  duplicate 1  superseded 2  invalid 4", "signing      off"):
        assert fragment in text, fragment
    # state
    for fragment in ("Λ=3.89", "paper-steps t=5.0/12.0 s", "thrust sent 0.500", "failsafe    none",
                     "level hold 2 s, then hand back to LOITER", "logs/run-001.csv"):
        assert fragment in text, fragment
    # history and footer
    assert "TV(u) [N·m/s]" in text and "q stop" in text and "p pause" in text
    assert "FAILSAFE" not in text and ">μ" not in text and "MAX" not in text


def test_failsafe_banner_names_reason_and_action(snapshot_maker, console_maker):
    snap = snapshot_maker(failsafe=FailsafeReason.STALE_ATTITUDE)
    lines = render(snap, console_maker, 100, 40)
    text = "\n".join(lines)
    assert "FAILSAFE STALE_ATTITUDE: stale or missing ATTITUDE" in text
    banner = " ".join(line.strip("┃ ") for line in lines if line.startswith("┃"))
    assert "→  level hold 2 s, then hand back to LOITER" in banner
    banner_row = next(i for i, line in enumerate(lines) if "FAILSAFE STALE_ATTITUDE:" in line)
    assert banner_row <= 2  # directly under the headline, above the tables


def test_sigma_outside_band_and_pinned_alpha_are_marked_per_axis(snapshot_maker, console_maker):
    snap = snapshot_maker(sigma=(0.5, 0.001, -0.02), alpha=(1000.0, 0.5, 0.01))
    lines = render(snap, console_maker, 100, 40)
    sigma_row = next(line for line in lines if line.startswith("σ [rad/s]"))
    assert sigma_row.split()[2:] == ["+0.5000", ">μ", "+0.0010", "-0.0200", ">μ"]
    alpha_row = next(line for line in lines if line.startswith("α "))
    assert alpha_row.split()[1:] == ["1e+03", "MAX", "0.5", "0.01"]


@pytest.mark.parametrize("failsafe", [None, FailsafeReason.LINK_LOST])
def test_80x24_degrades_by_dropping_panels(snapshot_maker, console_maker, failsafe):
    lines = render(snapshot_maker(failsafe=failsafe), console_maker, 80, 24)
    text = "\n".join(lines)
    assert len(lines) <= 24 and all(cell_len(line) <= 80 for line in lines)
    assert "error e [deg]" in text and "u total [N·m]" in text  # the per-axis table is kept
    assert "q stop" in lines[-1]  # footer kept
    assert "link / vehicle" not in text and "─ state" not in text  # big panels dropped
    if failsafe is None:
        assert "TV(u)" in text and "ATT 398.7/400 Hz" in text  # history + compact link still fit
    else:
        assert "FAILSAFE LINK_LOST" in text


@pytest.mark.parametrize("width,height", [(20, 1), (30, 5), (40, 10), (60, 18), (80, 24), (100, 30), (200, 60)])
@pytest.mark.parametrize("case", ["normal", "failsafe", "empty"])
def test_any_size_renders_within_bounds(snapshot_maker, console_maker, width, height, case):
    if case == "empty":
        buf = TelemetryBuffer()
        snap = buf.snapshot()
    else:
        snap = snapshot_maker(n=50, failsafe=FailsafeReason.ENVELOPE_BREACH if case == "failsafe" else None)
    lines = render(snap, console_maker, width, height)
    assert 1 <= len(lines) <= height
    assert all(cell_len(line) <= width for line in lines)


def test_missing_quantities_render_as_dash(console_maker):
    buf = TelemetryBuffer()
    buf.publish(ControlSample(vehicle_time_s=1.0, failsafe=None))  # a controller without ASTSM internals
    text = "\n".join(render(buf.snapshot(), console_maker, 100, 40))
    beta_row = next(line for line in text.splitlines() if line.startswith("β"))
    assert beta_row.split()[1:] == ["—", "—", "—"]
    assert "nan" not in text.lower()


def test_paused_is_shown_in_headline_and_footer(snapshot_maker, console_maker):
    lines = render(snapshot_maker(n=10), console_maker, 100, 40, paused=True)
    assert "PAUSED" in lines[0] and "PAUSED" in lines[-1]


def test_markup_like_strings_are_shown_verbatim(console_maker):
    buf = TelemetryBuffer()
    buf.set_link(LinkStatus(url="udp:[::1]:14550"))
    buf.set_session(SessionInfo(log_paths=("logs/[bold]run.csv",)))
    buf.publish(ControlSample(vehicle_time_s=0.0))
    text = "\n".join(render(buf.snapshot(), console_maker, 140, 50))
    assert "udp:[::1]:14550" in text and "logs/[bold]run.csv" in text


# --------------------------------------------------------------------------- history math


def test_sparkline_maps_min_to_max_onto_eight_levels():
    t = np.arange(8, dtype=float)
    assert sparkline(t, t.copy(), 8, window_s=8.0) == "▁▂▃▄▅▆▇█"


def test_sparkline_blanks_nan_and_time_before_first_sample():
    t = np.array([6.0, 7.0])
    v = np.array([np.nan, 1.0])
    # slots end at 1..8 s relative to t_end - window = -1 ... 7; only the last two slots have data
    assert sparkline(t, v, 8, window_s=8.0) == "      " + " " + "▁"


def test_chattering_is_total_variation_per_second():
    rate_hz, a = 400.0, 0.02
    n = 401  # 1 s of samples
    t = np.arange(n) / rate_hz
    u = np.zeros((n, 3))
    u[:, 0] = a * (-1.0) ** np.arange(n)  # flips sign every cycle: |du| = 2a per step
    u[:, 1] = np.linspace(0.0, 0.3, n)  # monotone ramp: TV = 0.3 over 1 s
    u[5, 2] = np.nan  # NaN steps are skipped, the rest is constant
    tv = chattering_nm_per_s(t, u)
    np.testing.assert_allclose(tv, [2 * a * (n - 1) / 1.0, 0.3, 0.0], rtol=1e-12, atol=1e-12)


def test_history_window_keeps_only_the_last_window_seconds(buffer_maker):
    snap = buffer_maker(n=4000, rate_hz=400.0, t0_s=0.0).snapshot()  # 10 s
    h = history_arrays(snap.history, window_s=2.0)
    assert h.t_s[-1] - h.t_s[0] == pytest.approx(2.0)
    assert len(h.t_s) == 801 and h.error_rad.shape == (801, 3)


def test_history_panel_shows_a_ramp_and_its_peak(console_maker):
    buf = TelemetryBuffer()
    for k in range(401):
        e = math.radians(k / 100.0)  # 0 .. 4 deg over 1 s
        buf.publish(ControlSample(vehicle_time_s=k / 400.0, error_rad=(e, 0.0, 0.0)))
    text = "\n".join(render(buf.snapshot(), console_maker, 100, 40))
    roll_row = next(line for line in text.splitlines() if line.startswith("roll "))
    assert "█" in roll_row and "4" in roll_row.split()[2]


# --------------------------------------------------------------------------- plain status line


def test_status_line_is_one_plain_line_with_units(snapshot_maker):
    line = format_status_line(snapshot_maker(failsafe=FailsafeReason.LINK_LOST))
    assert "\n" not in line and "\x1b" not in line
    for fragment in ("t=15.00s", "GUIDED ARMED", "ATT 399/400Hz", "p50 0.41 ms p99 1.23 ms", "missed 0",
                     "e[deg] roll -0.50 pitch +0.25 yaw -1.00", "u[N.m] +0.0123 -0.0456 +0.00789",
                     "cmd[deg/s] +20.0 -7.5 +2.5", "failsafe LINK_LOST"):
        assert fragment in line, fragment


def test_status_line_without_samples():
    line = format_status_line(TelemetryBuffer().snapshot())
    assert line.startswith("t=— ") and line.endswith("failsafe none")


def test_clipped_torque_is_marked_sat(console_maker):
    buf = TelemetryBuffer()
    # roll: u_eq + u_D = 0.098 but 0.0556 sent (clipped); pitch: exact sum; yaw: missing internals
    buf.publish(ControlSample(vehicle_time_s=1.0, u_eq=(0.003, -0.001, math.nan), u_d=(0.095, 0.002, math.nan),
                              u_nm=(0.0556, 0.001, 0.02)))
    lines = render(buf.snapshot(), console_maker, 100, 40)
    u_row = next(line for line in lines if line.startswith("u total [N·m]"))
    assert u_row.split()[3:] == ["+0.0556", "sat", "+0.001", "+0.02"]


def test_operator_stop_is_an_orderly_stopping_banner_with_the_exit_action(snapshot_maker, console_maker):
    lines = render(snapshot_maker(failsafe=FailsafeReason.OPERATOR_STOP), console_maker, 140, 50)
    text = "\n".join(lines)
    assert "FAILSAFE" not in text and "STOPPING OPERATOR_STOP" in lines[0]
    banner = " ".join(line.strip("┃ ") for line in lines if line.startswith("┃"))
    assert banner.endswith("→  level hold, then LOITER")  # on_exit, not on_failsafe


@pytest.mark.parametrize("reason", list(FailsafeReason))
def test_banner_height_matches_what_rich_draws(snapshot_maker, console_maker, reason):
    from mavastsm.dashboard.panels import render_failsafe_banner

    snap = snapshot_maker(n=3, failsafe=reason)
    for width in (24, 57, 80, 123):
        block = render_failsafe_banner(snap, width)
        console = console_maker(width, 100)
        console.print(block.renderable)
        assert len(console.export_text().splitlines()) == block.height


from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.just(0.0), st.floats(-1e3, 1e3))
_vec = st.tuples(_values, _values, _values)


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(width=st.integers(20, 220), height=st.integers(1, 80), vec=_vec, n=st.integers(0, 30),
       failsafe=st.one_of(st.none(), st.sampled_from(list(FailsafeReason))), url=st.text(max_size=60))
def test_any_values_and_size_never_crash_or_overflow(console_maker, width, height, vec, n, failsafe, url):
    buf = TelemetryBuffer()
    buf.set_link(LinkStatus(url=url, latency_p99_s=vec[0], attitude_rate_achieved_hz=vec[1]))
    buf.set_session(SessionInfo(mu=vec, alpha_min=vec, alpha_max=vec, gain_summary={"k": url}))
    for k in range(n):
        buf.publish(ControlSample(vehicle_time_s=k * 0.0025, reference_rad=vec, euler_rad=vec, error_rad=vec,
                                  sigma=vec, alpha=vec, beta=vec, nu=vec, u_eq=vec, u_d=vec, u_nm=vec,
                                  commanded_rates_rads=vec, failsafe=failsafe))
    lines = render(buf.snapshot(), console_maker, width, height)
    assert len(lines) <= height
    assert all(cell_len(line) <= width for line in lines)


# --------------------------------------------------------------------------- 80x24 and 120x40: nothing cut

REAL_GAINS = {"surface_slope": "3.89/3.89/4.36", "varpi": "100", "gamma1": "6.6", "epsilon": "0.6", "eta": "0.01",
              "alpha_min": "4.321/4.321/1.729", "alpha_max": "8.643/8.643/3.457", "mu": "0.06/0.06/0.06",
              "beta_offset": "0", "gain_units": "accel", "torque_limit_enabled": "True", "torque_limit_nm": "2.9/2.9/0.02821"}
REAL_LOGS = tuple(f"/tmp/demo_logs/mavastsm-20261202-023021.{ext}" for ext in ("csv", "tlog", "json"))
FLYING = "flying paper_steps"
WAITING = "waiting for the pilot or ground station to select GUIDED/GUIDED_NOGPS and arm"


def _real_snapshot(buffer_maker, phase: str, failsafe=None):
    """The fixture's cycles with what a real `mavastsm demo` shows around them: its phase, gains and log paths."""
    import dataclasses

    buf = buffer_maker(n=2000, failsafe=failsafe)
    snap = buf.snapshot()
    buf.set_link(dataclasses.replace(snap.link, phase=phase, mode="GUIDED_NOGPS", url="udpout:127.0.0.1:36353"))
    buf.set_session(dataclasses.replace(snap.session, gain_summary=REAL_GAINS, log_paths=REAL_LOGS,
                                        reference_name="paper_steps", on_failsafe="LAND", on_exit="LAND"))
    return buf.snapshot()


HISTORY_LABELS = ("error [deg]", "α (adaptive)", "cmd rate [deg/s]", "TV(u) [N·m/s]")
COMPACT_LINK_LABELS = ("ATT 398.7/400 Hz", "4936 cycles, 0 missed", "latency p50 0.41 ms p99 1.23 ms",
                       "dropped 3 duplicate 1 superseded 2 invalid 4 refused 0")
LINK_PANEL_ROWS = ("url          udpout:127.0.0.1:36353", "autopilot    ArduPilot 4.5.7", "mode / armed GUIDED_NOGPS / ARMED",
                   "thrust       climb_rate", "ATTITUDE     398.7 of 400 Hz requested; last 2.10 ms ago",
                   "latency      p50 0.41 ms  p99 1.23 ms", "cycles       4936 cycles, 0 missed",
                   "messages     dropped 3  duplicate 1  superseded 2  invalid 4  refused 0", "signing      off")
STATE_ITEMS = (f"phase {FLYING}", "failsafe none", "on failsafe LAND", "on exit LAND")


@pytest.mark.parametrize("width,height,failsafe,expected", [
    (80, 24, None, HISTORY_LABELS + COMPACT_LINK_LABELS),
    (80, 24, FailsafeReason.LINK_LOST, ("FAILSAFE LINK_LOST: link lost",)),
    (120, 40, None, HISTORY_LABELS + LINK_PANEL_ROWS + STATE_ITEMS + tuple(f"{k}={v}" for k, v in REAL_GAINS.items()) + REAL_LOGS),
    (120, 40, FailsafeReason.LINK_LOST, HISTORY_LABELS + LINK_PANEL_ROWS + ("failsafe LINK_LOST", "on failsafe LAND")),
], ids=["80x24", "80x24-failsafe", "120x40", "120x40-failsafe"])
def test_80x24_and_120x40_cut_no_label_or_value(buffer_maker, console_maker, width, height, failsafe, expected):
    """The ux issue, item 12: at 80x24 the compact lines' ends were cut ("p99 1.23…", "4936 cyc…", "ArduPil…") and
    at 120 columns the state lines ("on f… none", "alpha_min=(4.321259535585795, …"). Now a line never ends in "…":
    items that do not fit are left out whole, least important first, and long values wrap."""
    from mavastsm.dashboard.panels import _AXIS_ROW_LABELS

    lines = render(_real_snapshot(buffer_maker, FLYING, failsafe), console_maker, width, height)
    text = "\n".join(lines)
    assert len(lines) <= height and all(cell_len(line) <= width for line in lines)
    assert "…" not in text, [line for line in lines if "…" in line]
    flat = " ".join(line.strip(" │") for line in lines)  # a value wrapped inside a panel reads on as one line
    progress = () if failsafe else ("ref paper_steps t=5.0/12.0 s",)  # at 80x24 the FAILSAFE item takes its room
    for label in ("astsm", FLYING, "ARMED GUIDED_NOGPS", *progress, *_AXIS_ROW_LABELS, *expected):
        assert label in text or label in flat, label
    assert lines[-1].startswith("q stop (") and "p pause" in lines[-1]


@pytest.mark.parametrize("width,height", [(80, 24), (120, 40), (140, 50)])
@pytest.mark.parametrize("phase", [WAITING, "takeoff to 1 m (level, bounded climb)", "level hold (OPERATOR_STOP)"])
def test_every_phase_reads_whole_in_the_headline(buffer_maker, console_maker, width, height, phase):
    """The phase in words is in the headline (the state panel is dropped at 80x24), on a second line when needed."""
    lines = render(_real_snapshot(buffer_maker, phase), console_maker, width, height)
    assert len(lines) <= height and all(cell_len(line) <= width for line in lines)
    assert "…" not in "\n".join(lines)
    headline = " ".join(lines[:2])
    assert phase in headline and "astsm" in lines[0] and "ARMED GUIDED_NOGPS" in headline


def test_the_demo_summary_table_fits_80_columns_with_every_header_whole(console_maker):
    """The ux issue, item 12: at 80 columns the summary's headers read "settli…", "oversh…", "chatter…"."""
    import types

    from mavastsm.bridge.record.tracking_metrics import AxisMetrics
    from mavastsm.demo import SUMMARY_HEADERS, DemoResult, summary_table

    axes = (AxisMetrics("roll", 1.0, -10.0, 0.66, 0.0, 0.0, 10.0, 2.1, 1.0),
            AxisMetrics("pitch", 3.0, 10.0, math.inf, 0.0, 0.0, 10.0, 2.1, 1.0),
            AxisMetrics("yaw", 5.0, 45.0, math.nan, math.nan, 0.288, 44.99, 2.1, 1.0))
    result = DemoResult("nominal", "astsm", types.SimpleNamespace(axes=axes, samples=(), engage_time_s=math.nan),
                        True, True, 16.8, 16.6, False, "logs")
    console = console_maker(80, 40)
    console.print(summary_table(result))
    lines = console.export_text().splitlines()
    text = "\n".join(lines)
    assert all(cell_len(line) <= 80 for line in lines) and "…" not in text
    for header in SUMMARY_HEADERS:
        for word in header.split("\n"):
            assert word in text, word
    assert "never" in text  # pitch never settled, said in a word that fits
