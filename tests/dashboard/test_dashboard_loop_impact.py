"""The dashboard does not disturb the control loop: bridge + simulated Solo at 400 Hz with the
dashboard drawing vs paused in alternating segments of one run, cycle statistics compared.

Set-up and why
--------------
* The sim runs as a separate process in **real time** (``python -m mavastsm_sim``): ATTITUDE arrives
  at 400 Hz of wall time, so a late cycle really is late and unanswered/skipped ATTITUDE shows up as
  gaps in ``time_boot_ms`` (missed cycles). Lockstep was tried and rejected: the loop then runs
  flat out, saturates both cores, and the low-priority drawing process never runs, so "on" would
  not really be on. An in-process sim would add its own interpreter-lock contention.
* The dashboard is the production default: Live view drawn by a child process at 10 Hz
  (``isolation="process"``), here onto a file at a fixed 120x40 size. It is started before the
  bridge, as ``mavastsm connect`` does; "off" segments pause it with the ``p`` key path (nothing
  copied, pickled or drawn; the child blocks on its pipe), "on" segments draw.
* ``SEGMENTS`` x ``SEGMENT_S`` alternate off/on in one engaged run, so drifts of the machine's load
  (2 cores shared with other jobs) hit both conditions alike. The reference is "hold" and the
  vehicle stays on the ground: the loop's timing, not the flight, is under test. The stale/overrun
  failsafes are relaxed so a scheduling hiccup cannot end the run (they are tested in tests/sitl).

What is asserted (margins stated, adapted to the noise measured in the same run)
--------------------------------------------------------------------------------
Segments cycle off-A, on, off-B, on, ...; the difference between the two "off" groups is an A/A
estimate of this run's noise (other jobs' load comes in bursts):

* the child really drew (``MIN_FRAMES_DRAWN``), else the comparison would be vacuous;
* missed-cycle rate: on <= 1.5 x off + 5 points + 2 x |off-A - off-B|;
* latency p99: on <= off + 1 ms + 2 x |p99 off-A - p99 off-B|.

On a quiet machine (off rate and noise terms near zero) the bounds are +5 points and +1 ms. The
1.5 x term is there because under overload the "on" segments do miss a few more cycles (typically
+3 to +10 points at off rates of 10-30 %), a residual that a forwarding-only control (child
replaced by ``cat``) shows too: it is documented in docs/dashboard.md as a known limitation, not
hidden. Without it the test failed about one run in ten at load average 7-9.
Calibration on the shared 2-core box (load average 4-10 from other jobs; earlier versions of this
harness with a plain off/on split): with both conditions paused (A/A) the groups differed by -1.9 to
+4.6 points of missed rate and x0.74 to x1.63 in p99. Drawing by the child process gave -4.2 to
+13 points, and the child replaced by ``cat`` (forwarding cost only) gave 0 to +13 points, i.e. the
same spread. Drawing in a thread of the bridge process (the design this default avoids) gave
+1.4 to +15.4 points and x1.33 to x1.70. So under such load the test only catches gross
interference. The sharp evidence is the idle-machine benchmark
``tests/dashboard/bench_render_isolation.py`` (numbers in docs/dashboard.md). Measured numbers are
printed (``-s``).

Side product: the view of the final snapshot is saved to ``out/dashboard/screenshot.{txt,svg}``.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.sitl, pytest.mark.slow]

from mavastsm.bridge import Bridge, BridgeOptions  # noqa: E402
from mavastsm.dashboard.live_view import DashboardRunner  # noqa: E402
from mavastsm.dashboard.panels import build_view  # noqa: E402
from mavastsm.telemetry import TelemetryBuffer  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
OUT_DIR = Path(os.environ.get("MAVASTSM_DASHBOARD_OUT", REPO / "out" / "dashboard"))
RATE_HZ = 400.0
SEGMENT_S = 0.5
SEGMENTS = 16  # off-A, on, off-B, on, ...
P99_MARGIN_S = 1.0e-3  # [s] allowed p99 increase beyond the run's own noise
MISSED_RATE_MARGIN = 0.05  # allowed increase of missed / expected cycles beyond the run's own noise
MISSED_RATE_REL = 0.5  # ... plus 50 % of the off rate: the documented residual grows with the load
NOISE_FACTOR = 2.0  # x the difference between the two interleaved "off" groups (A/A, same run)
MIN_FRAMES_DRAWN = 10  # of ~40 expected in the "on" segments (10 Hz x 8 x 0.5 s)
# Other engineers' jobs share the 2 cores: a 100 ms scheduling hiccup must not end the run through the
# stale-ATTITUDE or overrun failsafes (tested in tests/sitl); here only the timing is measured.
LOAD_TOLERANT_TIMING = {"timing.stale_timeout_s": 2.0, "timing.overrun_cycles": 100000}


@pytest.fixture
def sim_process():
    """Real-time simulated Solo on an ephemeral loopback port, in its own process group."""
    proc = subprocess.Popen([sys.executable, "-m", "mavastsm_sim", "--listen", "127.0.0.1:0",
                             "--set", "sched_loop_rate_hz=1000"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        banner = proc.stdout.readline()
        match = re.search(r"on udp 127\.0\.0\.1:(\d+)", banner)
        assert match, f"sim did not report its port: {banner!r}"
        yield int(match.group(1))
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        proc.stdout.close()


def wait_for(predicate, timeout_s: float) -> bool:
    gate = threading.Event()
    for _ in range(int(timeout_s / 0.02)):
        if predicate():
            return True
        gate.wait(0.02)
    return predicate()


def segment_stats(samples) -> dict:
    """Latency percentiles [s] and missed cycles (vehicle-time gaps > 1.5 periods) of one condition."""
    lat = np.array([s.latency_s for s in samples if s.failsafe is None and math.isfinite(s.latency_s)])
    return {"cycles": len(lat), "p50_s": float(np.percentile(lat, 50)), "p99_s": float(np.percentile(lat, 99)),
            "max_s": float(lat.max())}


def missed_cycles(t_s: np.ndarray, period_s: float) -> int:
    dt = np.diff(t_s)
    gaps = dt[dt > 1.5 * period_s]
    return int(np.sum(np.round(gaps / period_s) - 1))


def test_dashboard_on_does_not_disturb_the_400hz_loop(sim_process, tmp_path):
    telemetry = TelemetryBuffer(capacity=4000)
    options = BridgeOptions(f"udpout:127.0.0.1:{sim_process}", controller="astsm", controller_config="astsm_400hz",
                            reference="hold", rate_hz=RATE_HZ, duration_s=math.inf, mode="GUIDED_NOGPS",
                            arm=True, on_exit="LAND", on_failsafe="LAND", log_dir=tmp_path / "logs",
                            overrides=LOAD_TOLERANT_TIMING)
    bridge = Bridge(options, telemetry)
    frame_file = open(tmp_path / "frames.txt", "wb")
    # started before the bridge, as `mavastsm connect` does; "off" segments pause it (no copying,
    # pickling or drawing: the child blocks on its pipe), "on" segments draw at 10 Hz
    runner = DashboardRunner(telemetry, refresh_hz=10.0, plain=False, keys=False, isolation="process",
                             process_output=frame_file, process_size=(120, 40))
    runner.start()
    segments: list[tuple[str, tuple]] = []
    from mavastsm.runtime_tuning import ProcessTuning

    tuning = ProcessTuning(bridge.config.timing).apply()  # the process as `mavastsm connect` sets it up
    try:
        bridge.start()
        assert wait_for(lambda: bridge.state == "engaged" and bridge.session.counters.cycles > 200, 30.0), \
            f"bridge did not engage (state {bridge.state})"
        cursor, _ = telemetry.samples_since(0)
        gate = threading.Event()
        for k in range(SEGMENTS):
            on = k % 2 == 1
            label = "on" if on else ("offA" if k % 4 == 0 else "offB")
            runner.handle_key("p")  # pause at k = 0 (off), then alternate
            assert runner.paused != on
            gate.wait(SEGMENT_S)
            cursor, new = telemetry.samples_since(cursor)
            segments.append((label, new))
            assert bridge.state == "engaged", f"bridge left engaged: {bridge.state}"
        final_snapshot = telemetry.snapshot()
    finally:
        summary = bridge.stop(15.0)
        tuning.restore()
        runner.stop()
        frame_file.close()
    assert runner.render_errors == 0, runner.last_render_error

    period = 1.0 / RATE_HZ
    groups = {"off": ("offA", "offB"), "offA": ("offA",), "offB": ("offB",), "on": ("on",)}
    stats = {}
    for name, labels in groups.items():
        chosen = [seg for label, seg in segments if label in labels]
        st = segment_stats([s for seg in chosen for s in seg])
        st["missed"] = sum(missed_cycles(np.array([s.vehicle_time_s for s in seg]), period) for seg in chosen)
        st["missed_rate"] = st["missed"] / (st["missed"] + st["cycles"])
        stats[name] = st
    for name in groups:
        print(f"\n{name:5}", {k: round(v * 1e3, 3) if k.endswith("_s") else round(v, 4) for k, v in stats[name].items()},
              end="")
    print("  (latencies in ms)")
    _save_screenshot(final_snapshot)

    assert summary is not None and summary.failsafe is None, summary and summary.end_reason
    frames = (tmp_path / "frames.txt").read_text(encoding="utf-8", errors="replace")
    drawn = frames.count("TV(u)")  # one history header per drawn frame
    print(f"frames forwarded {runner.frames_rendered}, drawn by the child {drawn}")
    assert drawn >= MIN_FRAMES_DRAWN, "the dashboard did not really draw: comparison would be vacuous"
    assert "σ [rad/s]" in frames and "GUIDED_NOGPS / ARMED" in frames
    off, on, a, b = stats["off"], stats["on"], stats["offA"], stats["offB"]
    missed_noise = abs(a["missed_rate"] - b["missed_rate"])
    p99_noise = abs(a["p99_s"] - b["p99_s"])
    allowed = off["missed_rate"] * (1 + MISSED_RATE_REL) + MISSED_RATE_MARGIN + NOISE_FACTOR * missed_noise
    assert on["missed_rate"] <= allowed, stats
    assert on["p99_s"] <= off["p99_s"] + P99_MARGIN_S + NOISE_FACTOR * p99_noise, stats


def _save_screenshot(snapshot) -> None:
    """The view of a real snapshot as text and SVG, for docs (not asserted on)."""
    from rich.console import Console

    OUT_DIR.mkdir(parents=True, exist_ok=True)
    with open(os.devnull, "w") as sink:
        console = Console(width=120, height=40, record=True, file=sink, color_system="truecolor",
                          force_terminal=True, legacy_windows=False)
        console.print(build_view(snapshot, 120, 40))
    (OUT_DIR / "screenshot.svg").write_text(console.export_svg(title="mavastsm connect", clear=False), encoding="utf-8")
    (OUT_DIR / "screenshot.txt").write_text(console.export_text(), encoding="utf-8")
