"""`mavastsm plot LOG` (the ux issue, item 11): the figures of one flight from the bridge's --log CSV, or its .tlog
when the CSV is absent, with labelled axes and units; the CSV gets a sidecar saying what flew and every
column's unit."""

from __future__ import annotations

import json
import re

import pytest

from mavastsm.bridge import Bridge
from mavastsm.cli import main
from mavastsm.lockstep_pair import LockstepPair

pytestmark = pytest.mark.sitl
UNIT = re.compile(r"\[[^\]]+\]")


@pytest.fixture(scope="module")
def flight_logs(tmp_path_factory):
    out = tmp_path_factory.mktemp("flightlog")
    with LockstepPair(sim=dict(lockstep_timeout_s=0.1)) as pair:
        s = Bridge(pair.bridge_options(controller="astsm", reference="paper_steps", duration_s=2.0,
                                       mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=1.0, on_exit="LAND", log_dir=str(out),
                                       overrides={"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5})).run()
    assert s.failsafe is None, s.end_reason
    return out, s


def test_the_csv_has_a_sidecar_with_what_flew_and_every_columns_unit(flight_logs):
    out, summary = flight_logs
    csv = next(out.glob("*.csv"))
    meta = json.loads(csv.with_suffix(".json").read_text())
    assert meta["controller"] == "astsm" and meta["autopilot"] == "ArduPilot" and meta["vehicle"] == "solo"
    assert meta["url"].startswith("udpout:127.0.0.1:") and meta["mavastsm_version"] and "surface_slope" in meta["gains"]
    header = csv.read_text().splitlines()[0].split(",")
    assert set(header) == set(meta["columns"]) and all(meta["columns"][c] for c in header)
    assert str(csv.with_suffix(".json")) in summary.log_paths


def _labels(fig):
    return [(ax.get_title(), ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]


def test_plot_from_the_csv_labels_every_panel_with_units(flight_logs, tmp_path, capsys):
    from mavastsm.flight_plot import flight_figure, load_flight

    out, _ = flight_logs
    png = tmp_path / "flight.png"
    assert main(["plot", str(out), "--png", str(png)]) == 0
    assert png.stat().st_size > 50_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in capsys.readouterr().out
    flight = load_flight(out)
    fig = flight_figure(flight)
    labels = _labels(fig)
    assert len(fig.axes) == 3 * 6  # attitude, error, sigma, alpha, body rates, thrust/latency/refused
    assert all(UNIT.search(y) for _, _, y in labels), [y for _, _, y in labels if not UNIT.search(y)]
    assert [t for t, _, _ in labels[:3]] == ["roll", "pitch", "yaw"]
    assert all(x == "time since the first row [s]" for _, x, _ in labels[-3:])
    ylabels = {y for _, _, y in labels}
    assert {"angle [deg]", "error e [deg]", "sliding variable σ [rad/s]", "body rate [deg/s]", "loop latency [ms]"} <= ylabels
    # the measured body rates are computed from the logged Euler rates (eq. 1), not the Euler rates themselves
    assert flight.measured_rates_rads.shape == flight.euler_rad.shape


def test_plot_falls_back_to_the_tlog_when_the_csv_is_absent(flight_logs, tmp_path):
    from mavastsm.flight_plot import flight_figure, load_flight

    out, _ = flight_logs
    tlog = next(out.glob("*.tlog"))
    lonely = tmp_path / tlog.name
    lonely.write_bytes(tlog.read_bytes())
    flight = load_flight(lonely)
    assert flight.kind == "tlog" and len(flight.t_s) > 100 and len(flight.commanded_rates_rads) > 100
    fig = flight_figure(flight)
    assert all(UNIT.search(ax.get_ylabel()) for ax in fig.axes)
    assert main(["plot", str(lonely), "--png", str(tmp_path / "t.png")]) == 0


def test_plot_without_matplotlib_or_a_log_is_one_line(tmp_path, capsys, monkeypatch):
    assert main(["plot", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no mavastsm-*.csv or mavastsm-*.tlog" in err[0]
    import mavastsm.offline.figures as figures

    monkeypatch.setattr(figures, "matplotlib_available", lambda: False)
    assert main(["plot", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "mavastsm[plot]"' in err[0]


def test_the_csv_has_a_row_for_every_phase_with_mode_armed_and_altitude(flight_logs):
    """The ux issue, item 11: the CSV held only the engaged cycles, without phase/mode/armed/altitude. Now takeoff,
    level hold and hand-back have rows too, and the engaged cycles are the rows of phase `engaged`, exactly the
    ones with a finite torque (what benchmarks/genuine_autopilots.py and the tracking metrics select)."""
    import math

    from mavastsm.bridge.record.flight_log import COLUMN_UNITS, read_flight_log, read_flight_rows

    out, summary = flight_logs
    csv = next(out.glob("*.csv"))
    rows = read_flight_rows(csv)
    phases = [r.phase for r in rows]
    order = [p for i, p in enumerate(phases) if i == 0 or phases[i - 1] != p]
    assert order == ["takeoff", "engaged", "level_hold", "handback"], order
    engaged = [r for r in rows if r.phase == "engaged"]
    controlled = [s for s in read_flight_log(csv) if s.failsafe is None and math.isfinite(s.u_nm[0])]
    assert [r.sample for r in engaged if r.sample.failsafe is None] == controlled
    assert len(controlled) == summary.cycles  # every control cycle, and only those
    takeoff = [r for r in rows if r.phase == "takeoff"]
    assert all(r.mode == "GUIDED_NOGPS" for r in takeoff + engaged) and all(r.armed for r in engaged)
    armed = [r.armed for r in takeoff]  # from the HEARTBEAT (1 Hz): the arming shows within a second, then stays
    assert armed[-1] and armed == sorted(armed)
    altitude = [r.altitude_m for r in takeoff if math.isfinite(r.altitude_m)]
    assert altitude and altitude[-1] >= 0.9 and min(altitude) < 0.5  # climbed to the 1 m takeoff altitude
    assert all(math.isfinite(r.sample.thrust_norm) and math.isfinite(r.sample.euler_rad[0]) for r in takeoff)
    # lockstep: the sim steps on the bridge's answers, so the hand-back (no setpoint) gets a single ATTITUDE
    assert [r.phase for r in rows[-1:]] == ["handback"] and rows[-1].sample.failsafe is None
    assert "above home" in COLUMN_UNITS["altitude_m"] and "up positive" in COLUMN_UNITS["altitude_m"]


def test_the_plot_shades_the_phases(flight_logs):
    from mavastsm.flight_plot import flight_figure, load_flight, phase_spans

    out, _ = flight_logs
    flight = load_flight(out)
    spans = phase_spans(flight.t_s, flight.phase)
    assert [name for _, _, name in spans] == ["takeoff", "engaged", "level_hold", "handback"]
    assert all(a < b for a, b, _ in spans[:-1]) and spans[-1][0] <= spans[-1][1] and spans[0][0] == 0.0
    fig = flight_figure(flight)
    assert "phases from: takeoff 0.0 s, engaged" in fig._suptitle.get_text()
    shaded = [p for p in fig.axes[0].patches]  # one shade per non-engaged phase on every panel
    assert len(shaded) == 3
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["takeoff", "level hold", "hand-back"]
    assert "altitude above home [m]" in {ax.get_ylabel() for ax in fig.axes}
