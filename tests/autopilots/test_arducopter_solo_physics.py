"""Genuine ArduCopter, tuned as a Solo (configs/arducopter/solo.parm), flying our Solo physics over the JSON SITL
protocol (sim/json_physics.py), with the bridge flying the paper steps on top (``pytest -m ardupilot``;
MAVASTSM_ARDUCOPTER, see conftest).

This closes the loop the other genuine tests leave open: there ArduCopter flies its own generic quad, here the
firmware flies the same rigid body, motors and drag as ``mavastsm sim``, so the bridge's numbers on the two can be
compared plant for plant. Everything runs in one private network namespace; the pre-arm wait is shortened with
SIM_SPEEDUP 5 as in ``boot_arducopter(fast_prearm=True)``.
"""

from __future__ import annotations

import math
import signal
import tempfile
import time
from pathlib import Path

import pytest
from bridge_process import README_ARDUCOPTER, BridgeProcess, assert_no_traceback, sim_pair_in_private_namespace
from mavastsm_sim.genuine_observer import boot_arducopter_solo_physics

from mavastsm.bridge.bridge_config import load_bridge_config
from mavastsm.bridge.record.flight_log import read_flight_log
from mavastsm.bridge.record.tracking_metrics import flight_metrics
from mavastsm.references import load_reference

pytestmark = [pytest.mark.ardupilot, pytest.mark.timeout(300)]

MAX_TILT_DEG = 30.0  # the paper steps are 10 deg; anything near this is a fight between the loops


def _metrics(csv: Path) -> dict:
    """Per axis: 5 % settling [s], overshoot [%], steady error [deg], error p-p over the last second [deg], as
    benchmarks/genuine_autopilots.py computes them from the bridge's flight CSV."""
    metrics = flight_metrics(read_flight_log(csv), load_reference("paper_steps"), load_bridge_config(None, {"limits": {}}).limits.max_rate_cmd_rads)
    assert metrics is not None, "the bridge never engaged"
    axes, holds = metrics
    return {m.axis: {"t5_s": round(m.settling_time_5pct_s, 3), "os_pct": round(m.overshoot_pct, 1),
                     "steady_deg": round(m.steady_error_deg, 3), "pp_deg": round(h.hold_pp_deg, 3)}
            for m, h in zip(axes, holds)}


def test_bridge_flies_the_paper_steps_on_genuine_arducopter_with_solo_physics(arducopter_build, record):
    t_boot = time.monotonic()
    with boot_arducopter_solo_physics(arducopter_build, fast_prearm=True) as v, \
            tempfile.TemporaryDirectory(prefix="mavastsm-solo-json-") as logs:
        physics = v.sitl.companions[0]
        boot_s = time.monotonic() - t_boot
        t0 = time.monotonic()
        b = v.bridge(README_ARDUCOPTER + ["--no-dashboard", "--log", logs])
        rc = b.wait(150.0)
        flight_s = time.monotonic() - t0
        out = b.output
        assert rc == 0, out[-3000:]
        assert_no_traceback(out)
        assert "end: duration complete; hand-back: LAND accepted" in out, out[-2000:]
        v.wait_disarmed(90.0)
        tilt = v.observer.max_tilt_deg(t0)
        counters = physics.counters
        assert physics.error is None, repr(physics.error)
        # genuine ArduCopter never sends a bad packet over loopback and never skips a frame
        assert counters.rejected_total == 0 and counters.frames_missed == 0, counters.summary()
        assert counters.nonfinite_state == 0 and counters.clipped_values == 0, counters.summary()
        csvs = sorted(Path(logs).glob("*.csv"))
        assert csvs, f"no flight CSV in {logs}"
        metrics = _metrics(csvs[-1])
        record("ArduCopter 4.7 + Solo physics (JSON SITL): README command, paper steps",
               boot_s=round(boot_s, 1), flight_s=round(flight_s, 1), max_tilt_deg=round(tilt, 1),
               physics_steps=counters.stepped, physics_time_s=round(physics.physics.time_s, 1), **metrics)
        assert tilt < MAX_TILT_DEG, f"max tilt {tilt:.1f} deg"
        for axis, m in metrics.items():
            assert math.isfinite(m["t5_s"]), f"{axis} never settled within 5 %: {metrics}"


def test_mavastsm_sim_autopilot_arducopter_is_flown_by_the_readme_command(arducopter_build, tmp_path):
    """The README's way onto this rig as a user types it (the test above boots the same rig from Python):
    ``mavastsm sim --autopilot arducopter`` prints its progress until ArduCopter is armable; the README's command
    beside it flies a 3 s profile (exit 0, LAND accepted); SIGTERM then stops the pair cleanly (exit 0, its end line
    with the JSON frames counted, no traceback)."""
    with sim_pair_in_private_namespace(["sim", "--autopilot", "arducopter", "--arducopter", str(arducopter_build[0])]) as (sim, rig):
        sim.wait_line(r"^mavastsm sim: genuine ArduCopter .* connect with 'mavastsm connect udpin:0\.0\.0\.0:14550 ", 30.0)
        sim.wait_line(r"^mavastsm sim: ArduCopter is armable after \d+ s", 120.0)
        b = BridgeProcess(rig, README_ARDUCOPTER + ["--duration-s", "3", "--no-dashboard", "--log", str(tmp_path)])
        rc = b.wait(150.0)
        assert rc == 0, b.output[-3000:]
        assert_no_traceback(b.output)
        assert "end: duration complete; hand-back: LAND accepted" in b.output, b.output[-2000:]
        sim.signal(signal.SIGTERM)
        assert sim.wait(30.0) == 0, sim.output[-3000:]
    assert_no_traceback(sim.output)
    assert "mavastsm sim: waiting for ArduCopter's" in sim.output, sim.output[-2000:]
    assert sim.lines[-1].startswith("mavastsm sim: stopped at t=") and "JSON frames:" in sim.lines[-1], sim.output[-2000:]
