"""ASTSM over MAVLink against the in-repo simulated Solo (lockstep, 400 Hz ATTITUDE requested):
the paper's nominal steps meet issue 4's bounds on every axis; under the paper's 0.5 N m roll torque the
bridge ends closer to the reference than ArduCopter's own attitude controller but peaks higher; with the
adaptive gain unbounded it limit-cycles, as on genuine ArduCopter, and the bridge's saturation failsafe ends it.

Metrics come from the bridge's recorded attitude against the *raw* (unshaped) paper reference; the
SITL suite (tests/sitl) repeats this with the sim's own attitude as ground truth.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.lockstep_pair import LockstepPair
from mavastsm.state_types import FailsafeReason
from mavastsm.scenarios import load_scenario
from mavastsm_sim.vehicle_server import VehicleServer

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from faulty_controller import RaisingController  # noqa: E402

pytestmark = pytest.mark.sitl
UNBOUNDED_ALPHA = {"mapping.bound_adaptive_gain": False}  # the preset's own alpha bounds (see the disturbance tests)


@pytest.fixture
def sim():
    """A lockstep pair's sim (``mavastsm.lockstep_pair``); ``sim.bridge_options(...)`` for the bridge that flies it."""
    with LockstepPair(sim=dict(lockstep_timeout_s=0.1)) as pair:
        yield pair


def test_astsm_tracks_paper_steps_over_mavlink(sim):
    opts = sim.bridge_options(controller="astsm", reference="paper_steps", duration_s=5.0,
                         mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=2.0, on_exit="LAND",
                         overrides={"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5})
    s = Bridge(opts).run()
    assert s.failsafe is None and s.end_reason == "duration complete", s.end_reason
    assert s.blocked_setpoints == 0
    roll, pitch, yaw = s.axes
    for m in (roll, pitch):
        assert m.settling_time_5pct_s <= 1.5, m
        assert m.overshoot_pct < 10.0, m
        assert m.steady_error_deg < 0.5, m
    assert yaw.settling_time_5pct_s <= 2.5, yaw
    assert yaw.overshoot_pct < 10.0, yaw
    assert yaw.steady_error_deg < 0.5, yaw  # measured 0.2-0.4 deg (the first design: 0.50-0.63 deg)
    assert s.handback == "LAND accepted" and s.handback_confirmed
    # issue 14's hold bounds, as on genuine ArduCopter (tests/autopilots/test_arducopter.py): no limit cycle after
    # settling, commands off their limit, alpha back within 2 alpha_m
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.record.tracking_metrics import flight_metrics
    from mavastsm.references import load_reference

    _, holds = flight_metrics(s.samples, load_reference("paper_steps"), load_bridge_config(None, {"limits": {}}).limits.max_rate_cmd_rads)
    for h in holds:
        assert h.hold_pp_deg < 0.3 and h.cmd_at_limit_pct < 1.0 and h.alpha_recovery_s <= 2.0, holds


def _bridge_scenarios():
    """benchmarks/bridge_scenarios.py (fly a scenario over MAVLink; ArduCopter's emulation alone as the reference)."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bridge_scenarios.py"
    spec = importlib.util.spec_from_file_location("bridge_scenarios_for_tests", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("scenario", ["disturbance_roll", "disturbance_pitch", "disturbance_within_authority"])
def test_astsm_with_its_adaptive_gain_unbounded_limit_cycles_and_the_bridge_catches_it(scenario):
    """The paper's disturbances flown with the adaptive gain unbounded (``mapping.bound_adaptive_gain=false``; the
    bridge's default bounds alpha by the loop delay). On genuine ArduCopter this limit-cycles at about 9 Hz (issue
    16). This test used to assert that ASTSM rejected the torques better than ArduCopter alone here, because the
    sim had no gyro filter, rate-target filter or loop-order delay and tolerated alpha in the hundreds; with those
    modelled (docs/sim.md, "Closed-loop parity") the sim limit-cycles like the firmware, in every one of these
    scenarios before the 4 s onset (measured 2026-12-02). What must hold is the safety net: the bridge ends it
    itself with COMMAND_SATURATION and the level hold, never an envelope breach or any other failsafe."""
    bs = _bridge_scenarios()
    s, _ = bs.fly("astsm", scenario, UNBOUNDED_ALPHA)
    assert s.failsafe is FailsafeReason.COMMAND_SATURATION, s.end_reason
    assert "level hold" in s.end_reason, s.end_reason
    assert s.blocked_setpoints == 0


@pytest.mark.parametrize("scenario", ["disturbance_roll", "disturbance_pitch", "disturbance_within_authority"])
def test_astsm_rejects_within_authority_torques_better_than_arducopter_alone(scenario):
    """Issue 25 on our sim, bridge defaults (the Solo's description: roll/pitch commands integrated, M9): every within-authority torque scenario
    completes, each disturbed axis peaks at most 0.8 x ArduCopter's emulation alone flying the same reference, and roll
    and pitch are back inside 0.5 deg within 1.5 s of the onset (ArduCopter alone never is). Measured 2026-12-03:
    roll 7.3 / 14.5 deg, 0.71 s; pitch 8.7 / 14.7 deg, 0.78 s; within-authority 8.4 / 9.4 / 32.5 deg against 26.5 /
    14.8 / 56.4 deg, 0.68 / 0.74 s. Yaw (0.2 N m, 87 % of its authority at hover) comes back only with M10, opt-in
    (4.1 s; the next test). With the earlier default (M2, measured) roll peaked at 30 deg, pitch ended in
    COMMAND_SATURATION and the within-authority run in ENVELOPE_BREACH."""
    bs = _bridge_scenarios()
    s, t_d = bs.fly("astsm", scenario)
    assert s.failsafe is None and s.end_reason == "duration complete", s.end_reason
    assert s.blocked_setpoints == 0
    ap_peak, _, _, _, _ = bs.fly_autopilot_alone(scenario)
    torque = next(iter(load_scenario(scenario).disturbances)).torque_nm
    for axis in range(3):
        if torque[axis] != 0.0:
            peak, recovery = bs.disturbance_metrics(s, t_d, axis)
            assert peak <= 0.8 * ap_peak[axis], (axis, peak, ap_peak)
            if axis < 2:
                assert recovery <= 1.5, (axis, recovery)


def test_astsm_trims_the_heading_back_under_a_yaw_torque_that_arducopter_alone_never_recovers_from():
    """Issue 25, yaw (M10, opt-in: mapping.yaw_trim_gain_per_s 1.0 with bridge.yaml's bound 0.1 rad and band 0.007 rad):
    0.2 N m about yaw, 87 % of the Solo's yaw authority at hover and more than ArduCopter's yaw rate integrator holds. Measured
    2026-12-03: peak 27.9 deg (ArduCopter's emulation alone 29.3 deg), back inside 0.5 deg 3.96 s after the onset;
    alone ends 21.8 deg off; without the trim (the default) ours ended 5.5 deg off. Genuine ArduCopter with the Solo
    physics: 25.5 deg (alone 27.4), 3.6 s. The issue's 3 s and 0.8 x alone's peak are not met on yaw (docs/bridge.md,
    M10): asserted is what the trim delivers."""
    bs = _bridge_scenarios()
    scenario = "disturbance_yaw_within_authority"
    s, t_d = bs.fly("astsm", scenario, {"mapping.yaw_trim_gain_per_s": 1.0})
    assert s.failsafe is None and s.end_reason == "duration complete", s.end_reason
    peak, recovery = bs.disturbance_metrics(s, t_d, 2)
    ap_peak, ap_recovery, _, _, ap_steady = bs.fly_autopilot_alone(scenario)
    assert ap_recovery[2] == math.inf and ap_steady[2] > 10.0, (ap_recovery, ap_steady)  # alone: the heading stays off
    assert recovery <= 5.5, recovery
    assert peak <= ap_peak[2], (peak, ap_peak)
    off, _ = bs.fly("astsm", scenario)  # the default: no trim
    assert off.failsafe is None
    assert bs.disturbance_metrics(off, t_d, 2)[1] == math.inf  # the trim is what brings it back


def test_a_controller_that_raises_mid_flight_is_a_named_failsafe_within_one_cycle(sim):
    """Issue 19: an exception inside the control cycle is CONTROLLER_FAULT at the very cycle it happens (never a
    swallowed error with the last rate command held), then the level hold and the configured hand-back."""
    ctl = RaisingController(after=600)
    opts = sim.bridge_options(controller=ctl, reference="paper_steps", duration_s=5.0,
                         mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=2.0, on_exit="LAND", on_failsafe="LAND",
                         overrides={"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5})
    s = Bridge(opts).run()
    assert s.failsafe is FailsafeReason.CONTROLLER_FAULT, s.end_reason
    assert "ZeroDivisionError: the law divided by zero" in s.end_reason, s.end_reason
    assert s.handback.startswith("LAND accepted"), s.handback
    assert ctl.updates == 601  # the raising update was the last one: no retry of a broken law
    engaged = [x for x in s.samples if x.failsafe is None and math.isfinite(x.u_nm[0])]
    fault = next(i for i, x in enumerate(s.samples) if x.failsafe is FailsafeReason.CONTROLLER_FAULT)
    assert len(engaged) == 600 and all(x.failsafe is None for x in s.samples[:fault])  # flagged at the faulty cycle itself
    assert s.blocked_setpoints == 0


def test_bridge_ends_with_a_summary_when_the_vehicle_process_vanishes():
    """udpout to a vehicle that is gone: every send then fails with ECONNREFUSED. The bridge must still end
    (stale ATTITUDE / link loss, hand-back refused, GUID_TIMEOUT not restorable) with a summary: once, a
    socket error in the finishing steps killed the supervisor and left `run()` polling forever at 100 % CPU."""
    import time

    server = VehicleServer(clock="realtime", listen=("127.0.0.1", 0))
    server.start()
    stopped = False
    try:
        bridge = Bridge(BridgeOptions(f"udpout:127.0.0.1:{server.port}", controller="astsm", reference="hold", duration_s=60.0,
                                      mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=0.5, on_exit="LAND", on_failsafe="LAND",
                                      overrides={"timing.prestream_s": 0.2}))
        bridge.start()
        deadline = time.monotonic() + 60.0
        while bridge.state != "engaged":
            assert time.monotonic() < deadline, bridge.state
            assert bridge.wait(0.05) is None
        server.stop()
        stopped = True
        summary = None
        deadline = time.monotonic() + 30.0
        while summary is None:
            assert time.monotonic() < deadline, "bridge never ended after its vehicle vanished"
            summary = bridge.wait(0.2)
    finally:
        if not stopped:
            server.stop()
    assert summary.failsafe in (FailsafeReason.STALE_ATTITUDE, FailsafeReason.LINK_LOST), summary.end_reason
    assert summary.exit_code == 1


FAST_START = {"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5}


def _hold_flight(sim, duration_s: float) -> BridgeOptions:
    """ASTSM holding level after a 1 m takeoff, then LAND."""
    return sim.bridge_options(controller="astsm", reference="hold", duration_s=duration_s,
                         mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=1.0, on_exit="LAND", overrides=FAST_START)


def test_the_autopilot_target_reaches_the_cycle_as_a_typed_value(sim):
    """Issue 19, item 6: no raw pymavlink message past the link. The link hands ATTITUDE_TARGET on as an
    AttitudeTarget, and the cycle's autopilot-target model re-synchronises from it during the flight."""
    from mavastsm.bridge.link.messages import AttitudeTarget

    b = Bridge(_hold_flight(sim, 1.5))
    s = b.run()
    assert s.failsafe is None, s.end_reason
    target = b.link.autopilot_target
    assert isinstance(target, AttitudeTarget) and len(target.q_wxyz) == 4 and all(isinstance(c, float) for c in target.q_wxyz)
    assert b.session.cycle.target_model is not None and b.session.cycle.target_model.syncs > 0


def test_session_states_are_an_enum_and_flights_keep_to_the_one_transition_table(sim):
    """Issue 19, item 4: the states are SessionState members, every change goes through the transition table; a
    flight with takeoff, the controller, a stop, the level hold and the hand-back makes no change the table does not
    list, and so does a controller fault."""
    from mavastsm.bridge.session.offboard_session import ACTIVE_STATES, TRANSITIONS, SessionState

    assert set(TRANSITIONS) == set(SessionState) and all(t <= set(SessionState) for t in TRANSITIONS.values())
    assert TRANSITIONS[SessionState.DONE] == {SessionState.DONE} and ACTIVE_STATES <= set(SessionState)
    b = Bridge(_hold_flight(sim, 1.0))
    s = b.run()
    assert s.failsafe is None, s.end_reason
    assert isinstance(b.session.state, SessionState) and b.session.state is SessionState.DONE
    assert b.session.unexpected_transitions == []
    faulty = Bridge(sim.bridge_options(controller=RaisingController(after=50), reference="hold",
                                  duration_s=5.0, mode="GUIDED_NOGPS", arm=True, on_exit="LAND", on_failsafe="LAND",
                                  overrides=FAST_START))
    assert faulty.run().failsafe is FailsafeReason.CONTROLLER_FAULT
    assert faulty.session.unexpected_transitions == []
