"""The in-flight identification phase (issue 27; mavastsm/bridge/cycle/loop_identification.py) on our sim in lockstep.

The Solo's roll and pitch flown on the measured rates (M2, where tau is the mapping's gain) with a tau far off the
loop's, once too small and once too large: the phase must find the same loop from both, fly it, say it, record it,
stay short and inside the envelope, and hand the profile a mapping that realises what the law asks for (k near 1
when `mavastsm identify` looks at the profile's own cycles).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from mavastsm.bridge.record.flight_log import ENGAGED_PHASE, IDENTIFYING_PHASE, read_flight_rows


def _fly(log_dir, tau_s: float):
    from mavastsm.bridge.bridge_api import Bridge
    from mavastsm.lockstep_pair import LockstepPair

    engaged_at: list[float] = []
    with LockstepPair(sim=dict(lockstep_timeout_s=0.1), on_engage=engaged_at.append) as pair:
        opts = pair.bridge_options(controller="astsm", reference="paper_steps", duration_s=5.0, mode="GUIDED_NOGPS", arm=True,
                                   takeoff_alt_m=2.0, on_exit="LAND", log_dir=log_dir,
                                   overrides={"timing.prestream_s": 0.2, "timing.stale_timeout_s": 0.5,
                                              "mapping.roll_pitch_command_base": "measured", "mapping.identify_in_flight": "always",
                                              "mapping.rate_time_constant_s": [tau_s, tau_s, 0.03]})
        return Bridge(opts).run(), engaged_at


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("phase")
    return {tau: (*_fly(root / str(tau), tau), root / str(tau)) for tau in (0.03, 0.1)}


@pytest.mark.parametrize("tau_s", [0.03, 0.1])
def test_the_phase_finds_the_loop_flies_it_and_says_so(flights, tau_s):
    summary, engaged_at, log_dir = flights[tau_s]
    assert summary.failsafe is None and summary.end_reason == "duration complete", summary.end_reason
    assert summary.identified.startswith("loop identified in flight (4.6 s"), summary.identified
    assert "roll tau" in summary.identified and "yaw tau 0.03 s kept" in summary.identified, summary.identified
    csv = next(log_dir.glob("*.csv"))
    found = json.loads(csv.with_suffix(".json").read_text())["mapping"]
    axes = found["identified_in_flight"]["axes"]
    assert axes["roll"]["applied"] and axes["pitch"]["applied"], axes
    assert not axes["yaw"]["applied"] and "M6" in axes["yaw"]["why_not"], axes["yaw"]
    assert found["rate_time_constant_s"][:2] == [round(axes[a]["tau_eff_s"], 4) for a in ("roll", "pitch")]
    # short and inside the envelope: 5 deg doublets, nothing near the 35 deg envelope
    rows = read_flight_rows(csv)
    phase = [r.sample for r in rows if r.phase == IDENTIFYING_PHASE]
    assert phase[-1].vehicle_time_s - phase[0].vehicle_time_s <= 5.0
    assert max(math.degrees(max(abs(s.euler_rad[0]), abs(s.euler_rad[1]))) for s in phase) < 10.0
    # the profile starts after the phase, and that is when on_engage tells the caller (disturbance clocks align there)
    profile = [r.sample for r in rows if r.phase == ENGAGED_PHASE]
    assert profile[0].vehicle_time_s > phase[-1].vehicle_time_s
    assert engaged_at == [phase[-1].vehicle_time_s], (engaged_at, phase[-1].vehicle_time_s)  # the phase's last sample engages the profile
    assert summary.axes[0].settling_time_5pct_s < 1.5, summary.format()  # metrics from the profile's start


def test_a_wrong_tau_either_way_is_moved_towards_the_loops(flights):
    """Flown with tau 0.03 s (too small) and 0.1 s (too large) on our sim, whose loop is no first-order lag (the
    emulated ArduCopter rate PID behind its filters; a whole flight at 0.06 s identifies 0.064 s): the phase moves tau
    towards the loop's from either side, and on the profile's own cycles `mavastsm identify` then finds the command
    realising the law's acceleration better than during the phase (|k - 1| smaller on roll and pitch together).
    Measured 2026-12-06: phase k 0.73 / 0.50 (tau 0.03 s) and 1.43 / 1.24 (0.1 s); tau flown after it 0.041 / 0.060 and
    0.070 / 0.080 s; profile k 0.88 / 0.72 and 0.95 / 1.24. One round of a fit is not the loop's fixed point on a loop
    of this shape; docs/bridge.md, "Identifying the loop in flight", says so."""
    for tau, (_, _, log_dir) in flights.items():
        axes = json.loads(next(log_dir.glob("*.json")).read_text())["mapping"]["identified_in_flight"]["axes"]
        out = subprocess.run([sys.executable, "-m", "mavastsm.cli", "identify", str(log_dir), "--json"],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        profile = json.loads(out.stdout)["axes"]
        phase_miss = profile_miss = 0.0
        for axis in ("roll", "pitch"):
            found = axes[axis]["tau_eff_s"]
            assert (tau < found < 0.1) if tau < 0.06 else (0.03 < found < tau), (tau, axis, found)
            phase_miss += abs(axes[axis]["effectiveness"] - 1.0)
            profile_miss += abs(profile[axis]["effectiveness"] - 1.0)
        assert profile_miss < phase_miss, (tau, axes, profile)
