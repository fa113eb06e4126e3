"""Closed-loop parity of ``mavastsm sim`` with genuine ArduCopter (``pytest -m ardupilot``; MAVASTSM_ARDUCOPTER).

The same README command (astsm, the paper steps) flies our emulated ArduCopter + Solo (``mavastsm sim``'s vehicle,
real time, sim profile ``arducopter-4.7-sitl-armable``: genuine 4.7 SITL's habits but the pre-arm wait, that is its
wire timing, its take-off, SITL's 3 ms command latency and the air-density compensation) and genuine ArduCopter 4.7 SITL tuned as a Solo on the same
physics (JSON SITL), and the two flights are compared as ``benchmarks/sim_parity.py`` does (docs/sim.md,
"Closed-loop parity"). The goal per axis is 5 % settling within +-15 % of genuine's, overshoot within +-3 points, RMS
difference of the attitude traces aligned on engagement <= 0.5 deg, and the same verdict on a limit cycle; this test
holds all of them at the goal's bounds for astsm (2026-12-02: settling within 0-3 %, overshoot within 0.2 points,
trace RMS roll 0.05-0.10, pitch 0.02-0.16, yaw 0.14-0.39 deg over the benchmark's runs; with the attitude
comparison that no longer interpolates errors across a reference step, roll 0.02-0.06, pitch 0.02-0.03, yaw 0.11-0.30
deg over four runs). pid and the disturbance run
meet the goal too except pid's roll settling in some runs (its 9 Hz limit cycle's phase decides it, on genuine as
well: 2.43-4.40 s over six genuine flights); they are in the benchmark's table, not here (wall time: one boot and
two flights here, about 60 s).
"""

from __future__ import annotations

import importlib.util
import math
import sys
import tempfile
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ardupilot, pytest.mark.timeout(300)]

FLIGHT = ("astsm", "nominal")


def _parity_module():
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "sim_parity.py"
    sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location("sim_parity_for_tests", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_emulated_arducopter_flies_the_paper_steps_like_genuine_arducopter(arducopter_build, record):
    sp = _parity_module()
    with tempfile.TemporaryDirectory(prefix="mavastsm-parity-test-") as tmp:
        root = Path(tmp)
        sim = sp.fly_side("sim", [FLIGHT], root, on_row=lambda r: None)
        genuine = sp.fly_side("genuine", [FLIGHT], root, str(arducopter_build[0]), on_row=lambda r: None)
        for side, rows in (("sim", sim), ("genuine", genuine)):
            row = rows[FLIGHT]
            assert "error" not in row, (side, row)
            assert "duration complete" in row["end"], (side, row["end"])
        (r,) = sp.compare([FLIGHT], sim, genuine)
    record("parity: astsm paper steps, our sim vs genuine ArduCopter on the Solo physics",
           **{a: {k: v for k, v in r[a].items() if not k.startswith("cycle_")} | {"cycle_sim": r[a]["cycle_sim"]["cycle"],
                                                                                   "cycle_genuine": r[a]["cycle_genuine"]["cycle"]}
              for a in sp.pg.AXES})
    for axis, criterion in PARITY_AXES:
        assert r[axis][criterion], (axis, criterion, r[axis])
    for axis in sp.pg.AXES:
        assert math.isfinite(r[axis]["t5_sim_s"]) and math.isfinite(r[axis]["t5_genuine_s"]), r[axis]


PARITY_AXES = tuple((axis, criterion) for axis in ("roll", "pitch", "yaw") for criterion in ("t5_ok", "os_ok", "rms_ok", "cycle_ok"))
