"""Pure parts of the bridge: mask constants, torque -> rate mapping, thrust semantics, safety gate,
thrust-semantics rules, version refusal, reference shaping and metrics. No sockets."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavastsm.bridge.autopilots.ardupilot import body_rate_support as ardupilot_body_rate_support, thrust_semantics as ardupilot_thrust_semantics
from mavastsm.bridge.link.messages import decode_flight_sw_version
from mavastsm.bridge.cycle.reference_shaping import AccelLimitedShaper, sqrt_controller
from mavastsm.bridge.cycle.safety import (
    attitude_sample_problem,
    envelope_breach,
    highest_priority,
    OutputGate,
    AdmittedSetpoint,
)
from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
from mavastsm.bridge.autopilots.px4 import OFFBOARD_CUSTOM_MODE as PX4_OFFBOARD_CUSTOM_MODE, px4_profile
from mavastsm.bridge.link.messages import TYPE_MASK_ATTITUDE, TYPE_MASK_RATES, TYPE_MASK_ZERO_RATES, Setpoint
from mavastsm.bridge.cycle.setpoint_mapping import (
    RateMapping,
    commanded_body_accel,
    hold_thrust,
    level_hold_setpoint,
    rate_setpoint,
    takeoff_approach,
)
from mavastsm.bridge.record.tracking_metrics import axis_metrics
from mavastsm.errors import ConfigError
from mavastsm.solo_model import load_solo, nominal_drift_torque
from mavastsm.state_types import FailsafeReason

MAX_RATE = (3.5, 3.5, 2.0)


def test_type_mask_constants_match_mavlink():
    # docs/design-decisions.md, MAV-10: only 0x80 (rates), 0x07 (attitude), 0x87 (zero rates) are ever sent
    assert (TYPE_MASK_RATES, TYPE_MASK_ATTITUDE, TYPE_MASK_ZERO_RATES) == (0x80, 0x07, 0x87)
    assert PX4_OFFBOARD_CUSTOM_MODE == 393216


def test_commanded_accel_is_rigid_body_inverse():
    solo = load_solo()
    i0 = solo.inertia_diag
    w = np.array([0.4, -0.7, 1.1])
    u = np.array([0.05, -0.02, 0.01])
    a = np.array(commanded_body_accel(u, w, i0))
    # I0 a = u + f(omega), f = -omega x I0 omega (eq. 17)
    assert np.allclose(i0 * a, u + nominal_drift_torque(i0, w))
    assert np.allclose(i0 * a, u - np.cross(w, i0 * w))


def test_mapping_methods():
    i0 = (0.01, 0.02, 0.03)
    fo = RateMapping("first_order", i0, (0.05, 0.05, 0.1))
    cmd = fo((0.001, 0.0, 0.003), (0.0, 0.0, 0.0), 0.0025)
    assert cmd == pytest.approx((0.05 * 0.1, 0.0, 0.1 * 0.1))
    it = RateMapping("integrate", i0, 0.05)
    it.reset((0.2, 0.0, 0.0))
    c1 = it((0.001, 0.0, 0.0), (0.2, 0.0, 0.0), 0.01)
    c2 = it((0.001, 0.0, 0.0), (5.0, 0.0, 0.0), 0.01)  # integrates its own target, not the measurement
    assert c1[0] == pytest.approx(0.2 + 0.1 * 0.01)
    assert c2[0] == pytest.approx(c1[0] + 0.1 * 0.01)
    clipped = RateMapping("first_order", i0, 1.0, accel_limit_radss=(1.0, 1.0, 1.0))
    assert clipped((1.0, -1.0, 0.0), (0.0, 0.0, 0.0), 0.01) == pytest.approx((1.0, -1.0, 0.0))
    with pytest.raises(ValueError):
        RateMapping("torque", i0, 0.05)


def test_first_order_command_is_built_on_the_given_base_rates():
    i0 = (0.01, 0.02, 0.03)
    fo = RateMapping("first_order", i0, (0.05, 0.05, 0.05))
    measured, base = (0.3, -0.2, 0.5), (0.3, -0.2, 0.1)
    cmd = fo((0.0, 0.0, 0.003), measured, 0.0025, base)
    p, q, r = measured  # f(omega) = -omega x I0 omega from the *measured* rates (eq. 17), whatever the base
    a = ((i0[1] - i0[2]) * q * r / i0[0], (i0[2] - i0[0]) * p * r / i0[1], (0.003 + (i0[0] - i0[1]) * p * q) / i0[2])
    assert cmd == pytest.approx(tuple(b + 0.05 * ai for b, ai in zip(base, a)))
    assert fo((0.0, 0.0, 0.003), measured, 0.0025) == pytest.approx(tuple(w + 0.05 * ai for w, ai in zip(measured, a)))


def test_yaw_from_reference_only_on_ardupilot_first_order():
    from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
    from mavastsm.bridge.autopilots.px4 import px4_profile
    from mavastsm.bridge.cycle.setpoint_mapping import yaw_from_reference

    ap = ardupilot_profile("climb_rate")
    assert yaw_from_reference("first_order", "reference", ap)
    assert not yaw_from_reference("first_order", "measured", ap)
    assert not yaw_from_reference("integrate", "reference", ap)  # builds on its own integrated target
    assert not yaw_from_reference("first_order", "reference", px4_profile())  # no attitude target to hold the heading


def test_the_cycle_models_the_hidden_target_consistently_with_its_yaw_command():
    """One decision (M6) sets both the yaw command's base and whether the target model cancels yaw."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import ControlCycle
    from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
    from mavastsm.bridge.autopilots.px4 import px4_profile
    from mavastsm.references import load_reference

    def cycle(profile, angle_p=(4.5, 4.5, 3.42), **mapping):
        cfg = load_bridge_config(overrides={"mapping": mapping})
        return ControlCycle(_ScriptedController([(0.0, 0.0, 0.0)], alpha_max=None), load_reference("hold"), _solo_i0(), profile, cfg,
                            None, (6.28, 6.28, 1.22), angle_p)

    ap = ardupilot_profile("climb_rate")
    m6 = cycle(ap, yaw_command_base="reference")
    assert m6.yaw_from_reference and not m6.target_model.compensate_yaw
    measured = cycle(ap, yaw_command_base="measured")
    assert not measured.yaw_from_reference and measured.target_model.compensate_yaw
    assert measured.target_model.ang_p == (4.5, 4.5, 3.42)
    assert cycle(px4_profile()).target_model is None  # PX4: no hidden attitude target behind body rates
    assert cycle(ap, angle_p=None).target_model is None  # ATC_ANG_*_P not read
    assert cycle(ap, compensate_autopilot_target=False).target_model is None


def test_the_hidden_target_model_syncs_on_the_target_the_sample_carries():
    """The link hands the latest ATTITUDE_TARGET on with each ATTITUDE sample (``AttitudeSample.autopilot_target``);
    the cycle re-synchronises its model of ArduCopter's hidden target from it and never calls back into the link."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import ControlCycle
    from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
    from mavastsm.bridge.link.messages import AttitudeSample, AttitudeTarget
    from mavastsm.references import load_reference

    cycle = ControlCycle(_ScriptedController([(0.0, 0.0, 0.0)], alpha_max=None), load_reference("hold"), _solo_i0(),
                         ardupilot_profile("climb_rate"), load_bridge_config(), None, (6.28, 6.28, 1.22), (4.5, 4.5, 3.42))
    tilted = AttitudeTarget(10, (math.cos(0.05), math.sin(0.05), 0.0, 0.0), (0.2, 0.0, 0.0))
    cycle.engage(AttitudeSample(10, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, autopilot_target=tilted))
    model = cycle.target_model
    assert (model.syncs, model.last_sync_ms, model.w_t) == (1, 10, [0.2, 0.0, 0.0])
    cycle.step(AttitudeSample(13, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, autopilot_target=tilted), 0.0025)
    assert model.syncs == 1  # the same target again: nothing new to adopt
    cycle.step(AttitudeSample(15, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0), 0.0025)
    assert model.syncs == 1  # no target with the sample (before the first ATTITUDE_TARGET): the model runs on
    newer = AttitudeTarget(16, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    cycle.step(AttitudeSample(18, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, autopilot_target=newer), 0.0025)
    assert (model.syncs, model.last_sync_ms) == (2, 16)


def test_yaw_command_rides_on_the_reference_yaw_rate_not_the_measured_one():
    """M6: a vehicle turned at 0.5 rad/s by a yaw torque gets r_cmd = r_d + tau a, not r + tau a, so
    ArduCopter's attitude target keeps the reference heading instead of following the vehicle; with
    yaw_command_base = measured the command endorses the turn."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import ControlCycle
    from mavastsm.bridge.link.messages import AttitudeSample
    from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
    from mavastsm.bridge.autopilots.px4 import px4_profile
    from mavastsm.references import load_reference

    def yaw_cmd(base: str, profile) -> float:
        cfg = load_bridge_config(overrides={"mapping": {"yaw_command_base": base, "reference_shaping": False}})
        ctl = _ScriptedController([(0.0, 0.0, 0.0)], alpha_max=None)
        cycle = ControlCycle(ctl, load_reference("hold"), _solo_i0(), profile, cfg, None, (6.28, 6.28, 1.22),
                             torque_authority_nm=(2.9, 2.9, 0.03))
        cycle.engage(AttitudeSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0))
        res = cycle.step(AttitudeSample(3, (0.0, 0.0, 0.0), (0.0, 0.0, 0.5), 0), 0.0025)
        return res.setpoint.body_rates_rads[2]

    assert yaw_cmd("reference", ardupilot_profile("climb_rate")) == pytest.approx(0.0)  # hold: r_d = 0, zero torque
    assert yaw_cmd("measured", ardupilot_profile("climb_rate")) == pytest.approx(0.5)
    assert yaw_cmd("reference", px4_profile()) == pytest.approx(0.5)  # PX4: always the measured base


def test_yaw_trim_integrates_the_heading_error_beyond_the_band_up_to_the_bound():
    """M10's error (setpoint_mapping.yaw_trim_error): nothing inside the band, the excess beyond it with the error's
    sign, never more than the bound."""
    from mavastsm.bridge.cycle.setpoint_mapping import yaw_trim_error

    assert yaw_trim_error(0.005, 0.0087, 0.1) == 0.0 and yaw_trim_error(-0.005, 0.0087, 0.1) == 0.0
    assert yaw_trim_error(0.05, 0.0087, 0.1) == pytest.approx(0.0413)
    assert yaw_trim_error(-0.05, 0.0087, 0.1) == pytest.approx(-0.0413)
    assert yaw_trim_error(0.5, 0.0087, 0.1) == 0.1 and yaw_trim_error(-3.0, 0.0087, 0.1) == -0.1
    assert yaw_trim_error(0.05, 0.0, 0.1) == 0.05


def test_yaw_trim_turns_the_heading_target_back_by_k_times_the_heading_error():
    """M10 (``mapping.yaw_trim_gain_per_s``): with the yaw command on the reference (M6), a vehicle pushed 0.05 rad past
    the reference heading gets r_cmd = r_d + tau a - k_I e_trim (e_trim: the error beyond the 0.007 rad band, bounded
    at 0.1 rad), so ArduCopter's attitude target (the integral of the command) turns back; off (0, bridge.yaml's
    default) the command is r_d + tau a alone; PX4 (M2 on yaw) never gets the trim."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import ControlCycle
    from mavastsm.bridge.link.messages import AttitudeSample
    from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
    from mavastsm.bridge.autopilots.px4 import px4_profile
    from mavastsm.references import load_reference

    def yaw_cmd(gain: float, profile, yaw_rad: float = 0.05) -> float:
        cfg = load_bridge_config(overrides={"mapping": {"yaw_trim_gain_per_s": gain, "reference_shaping": False}})
        ctl = _ScriptedController([(0.0, 0.0, 0.0)], alpha_max=None)
        cycle = ControlCycle(ctl, load_reference("hold"), _solo_i0(), profile, cfg, None, (6.28, 6.28, 1.22),
                             torque_authority_nm=(2.9, 2.9, 0.03))
        cycle.engage(AttitudeSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0))
        res = cycle.step(AttitudeSample(3, (0.0, 0.0, yaw_rad), (0.0, 0.0, 0.0), 0), 0.0025)
        return res.setpoint.body_rates_rads[2]

    ap = ardupilot_profile("climb_rate")
    m = load_bridge_config().mapping
    assert (m.yaw_trim_gain_per_s, m.yaw_trim_error_limit_rad, m.yaw_trim_band_rad) == (0.0, 0.1, 0.007)  # off by default
    assert yaw_cmd(0.0, ap) == pytest.approx(0.0)
    assert yaw_cmd(1.0, ap) == pytest.approx(-(0.05 - 0.007))  # turned right of the reference: the target turns back left
    assert yaw_cmd(1.0, ap, yaw_rad=-0.05) == pytest.approx(0.05 - 0.007)
    assert yaw_cmd(1.0, ap, yaw_rad=0.005) == pytest.approx(0.0)  # inside the band: left to the law
    assert yaw_cmd(1.0, ap, yaw_rad=0.5) == pytest.approx(-0.1)  # bounded
    assert yaw_cmd(1.0, px4_profile()) == pytest.approx(0.0)  # PX4: the measured base (r = 0 here), no trim


def test_sign_convention_positive_roll_torque_commands_roll_right():
    cmd = RateMapping("first_order", (0.01, 0.01, 0.01), 0.05)((0.01, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0025)
    assert cmd[0] > 0  # +p (FRD) = right wing down, same sign as +roll torque


def test_thrust_semantics_in_one_place():
    climb = ardupilot_profile("climb_rate")
    coll = ardupilot_profile("collective", hover_collective_norm=0.4)
    assert hold_thrust(climb, 0.5, 0.5) == 0.5  # climb rate: 0.5 holds altitude whatever the tilt
    assert hold_thrust(coll) == pytest.approx(0.4)
    assert hold_thrust(coll, math.radians(20), 0.0) == pytest.approx(0.4 / math.cos(math.radians(20)))
    assert hold_thrust(coll, math.radians(80), 0.0, max_tilt_factor=1.5) == pytest.approx(0.6)
    assert hold_thrust(coll, math.radians(20), 0.0, tilt_compensation=False) == pytest.approx(0.4)
    assert px4_profile().thrust_semantics == "collective" and px4_profile().guided_modes == ("OFFBOARD",)


def test_level_hold_is_unit_level_quaternion_at_heading():
    sp = level_hold_setpoint(math.radians(120), 0.5)
    assert sp.type_mask == TYPE_MASK_ATTITUDE
    w, x, y, z = sp.q_wxyz
    assert math.hypot(math.hypot(w, x), math.hypot(y, z)) == pytest.approx(1.0)
    assert x == 0 and y == 0
    assert math.degrees(2 * math.atan2(z, w)) == pytest.approx(120)


def test_the_takeoff_climb_tapers_over_its_approach_and_never_stops_short():
    """The climb thrust's excess share: whole until approach_m below the target, then the distance left over
    approach_m, never under TAKEOFF_CREEP (a climb that stopped short would never reach the target); whole when the
    altitude is unknown or the approach is off (0)."""
    assert takeoff_approach(3.0, 1.0) == 1.0 and takeoff_approach(1.0, 1.0) == 1.0
    assert takeoff_approach(0.5, 1.0) == pytest.approx(0.5) and takeoff_approach(0.25, 0.5) == pytest.approx(0.5)
    assert takeoff_approach(0.01, 1.0) == pytest.approx(0.1) and takeoff_approach(-0.3, 1.0) == pytest.approx(0.1)
    assert takeoff_approach(float("nan"), 1.0) == 1.0 and takeoff_approach(0.2, 0.0) == 1.0


def test_attitude_sample_validation():
    assert attitude_sample_problem((0.1, 0.2, 3.0), (0.0, 0.0, 0.0), 20.0) is None
    assert attitude_sample_problem((math.nan, 0, 0), (0, 0, 0), 20.0) == "non-finite field"
    assert attitude_sample_problem((0, 0, 0), (0, math.inf, 0), 20.0) == "non-finite field"
    assert attitude_sample_problem((0, 2.0, 0), (0, 0, 0), 20.0) == "angle out of range"
    assert attitude_sample_problem((0, 0, 0), (0, 0, 25.0), 20.0) == "body rate out of range"
    assert envelope_breach((0.7, 0, 0), math.radians(35)) is FailsafeReason.ENVELOPE_BREACH
    assert envelope_breach((0.1, -0.1, 3.0), math.radians(35)) is None


def test_failsafe_priority_is_declaration_order():
    assert highest_priority([None, FailsafeReason.LOOP_OVERRUN, FailsafeReason.STALE_ATTITUDE]) is FailsafeReason.STALE_ATTITUDE
    assert highest_priority([FailsafeReason.ENVELOPE_BREACH, FailsafeReason.OPERATOR_STOP]) is FailsafeReason.OPERATOR_STOP
    assert highest_priority([None, None]) is None


finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e6, 1e6))


GATE = OutputGate(MAX_RATE, 0.0, 0.8)


@settings(max_examples=300, deadline=None)
@given(rates=st.tuples(finite_or_not, finite_or_not, finite_or_not), thrust=finite_or_not,
       mask=st.sampled_from([0x80, 0x07, 0x87, 0x00, 0x40, 0x83, 0x01]))
def test_output_gate_never_lets_an_out_of_limit_setpoint_through(rates, thrust, mask):
    q = (0.0, 0.0, 0.0, 0.0) if mask & 0x80 else (1.0, 0.0, 0.0, 0.0)
    sp = Setpoint(mask, q, rates, thrust)
    out = GATE.admit(sp)
    finite = all(math.isfinite(v) for v in (*rates, thrust))
    if mask not in (0x80, 0x07, 0x87) or not finite:
        assert out is None and GATE.verify(sp) is None
        return
    assert type(out) is AdmittedSetpoint and GATE.verify(out) is out
    assert all(abs(r) <= m for r, m in zip(out.body_rates_rads, MAX_RATE))
    assert 0.0 <= out.thrust_norm <= 0.8
    inside = all(abs(r) <= m for r, m in zip(rates, MAX_RATE)) and 0.0 <= thrust <= 0.8
    assert (GATE.verify(sp) == out) if inside else GATE.verify(sp) is None  # verify never clamps


def test_output_gate_rejects_bad_quaternions_and_masks_and_verify_clamps_nothing():
    inside = rate_setpoint((0.1, 0.1, 0.1), 0.5)
    passed = GATE.verify(inside)
    assert type(passed) is AdmittedSetpoint and dataclasses.astuple(passed) == dataclasses.astuple(inside)
    assert GATE.verify(rate_setpoint((4.0, 0.1, 0.1), 0.5)) is None
    assert GATE.admit(rate_setpoint((4.0, 0.1, 0.1), 0.5)).body_rates_rads == (MAX_RATE[0], 0.1, 0.1)
    for bad in (Setpoint(0x07, (0.5, 0.0, 0.0, 0.0), (0, 0, 0), 0.5), Setpoint(0x40, (0, 0, 0, 0), (0, 0, 0), 0.5),
                Setpoint(0x80, (0.5, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.5)):
        assert GATE.admit(bad) is None and GATE.verify(bad) is None
    assert GATE.verify(rate_setpoint((0.1, 0.1, 0.1), 0.9)) is None


def test_version_decoding_and_refusal():
    v = decode_flight_sw_version((4 << 24) | (1 << 16) | (5 << 8) | 255)
    assert v == (4, 1, 5)
    assert "4.2" in ardupilot_body_rate_support(v)
    assert ardupilot_body_rate_support((4, 2, 0)) is None and ardupilot_body_rate_support((4, 6, 1)) is None


class _Parameters(dict):
    """The vehicle's parameters as an adapter sees them (``VehicleParameters``), from a dict; writes kept."""

    def read(self, name):
        return self.get(name)

    read_with_retries = read

    def write(self, name, value):
        self[name] = value
        return True


def test_thrust_semantics_rules():
    from mavastsm.bridge.autopilots.px4 import ADAPTER as PX4
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.autopilots.preflight import PreflightReport

    assert ardupilot_thrust_semantics("auto", 0.0) == "climb_rate"
    assert ardupilot_thrust_semantics("auto", 8.0) == "collective"
    assert ardupilot_thrust_semantics("auto", 9.0) == "collective"
    with pytest.raises(ConfigError, match="GUID_OPTIONS could not be read"):
        ardupilot_thrust_semantics("auto", None)
    with pytest.raises(ConfigError, match="means climb_rate"):
        ardupilot_thrust_semantics("collective", 0.0)
    rep = PreflightReport("udpout:127.0.0.1:9", 1, 1, "12")
    assert PX4.configure(_Parameters(MPC_THR_HOVER=0.4), load_bridge_config(), rep).thrust_semantics == "collective"
    assert rep.thrust_semantics == "collective" and rep.hover_collective_norm == 0.4
    with pytest.raises(ConfigError, match="PX4"):
        PX4.configure(_Parameters(), load_bridge_config(overrides={"thrust": {"semantics": "climb_rate"}}), rep)


def test_shaper_respects_accel_limit_and_arrives():
    sh = AccelLimitedShaper((6.0, 6.0, 1.0), p=4.0)
    sh.reset((0.0, 0.0, 3.0))
    dt, peak = 0.0025, [0.0, 0.0, 0.0]
    target = (math.radians(-10), math.radians(10), 3.0 + math.radians(45) - 2 * math.pi)  # yaw target across the wrap
    for _ in range(int(6.0 / dt)):
        r, v, a = sh.step(target, (0.0, 0.0, 0.0), dt)
        peak = [max(p, abs(x)) for p, x in zip(peak, a)]
    assert all(p <= m + 1e-12 for p, m in zip(peak, (6.0, 6.0, 1.0)))
    assert r[0] == pytest.approx(target[0], abs=1e-4) and r[1] == pytest.approx(target[1], abs=1e-4)
    assert math.remainder(r[2] - target[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-4)
    assert sqrt_controller(0.01, 4.0, 10.0) == pytest.approx(0.04)  # linear region near zero


def test_axis_metrics_on_a_known_response():
    # first-order approach to a +0.2 rad step at t=1 with time constant 0.2 s: 5 % band at 3 tau = 0.6 s
    ts = np.arange(0.0, 4.0, 0.0025)
    y = np.where(ts < 1.0, 0.0, 0.2 * (1 - np.exp(-(ts - 1.0) / 0.2)))
    rows = list(zip(ts, y - np.where(ts < 1.0, 0.0, 0.2)))
    m = axis_metrics(rows, 0, 1.0, 0.2)
    assert m.settling_time_5pct_s == pytest.approx(0.2 * math.log(20), abs=0.005)
    assert m.overshoot_pct == 0.0
    assert m.steady_error_deg < 0.01


def test_autopilot_target_model_compensation_gives_the_wanted_demand():
    from mavastsm.bridge.cycle.autopilot_target_model import (
        AutopilotTargetModel, q_conj, q_from_euler, q_mul, q_to_rotation_vector)
    from mavastsm.frames import quaternion_from_euler

    assert np.allclose(q_from_euler(0.1, -0.2, 2.5), quaternion_from_euler([0.1, -0.2, 2.5]))
    m = AutopilotTargetModel((4.5, 4.5, 3.42), (6.28, 6.28, 1.22))
    q_meas = q_from_euler(0.0, 0.0, 0.5)
    m.reset(q_from_euler(0.01, 0.0, 0.52), (0.0, 0.0, 0.1))
    w_des = (0.2, -0.1, 0.3)
    w_cmd = m.compensate(q_meas, w_des)
    e = q_to_rotation_vector(q_mul(q_conj(q_meas), m.q_t))
    # ArduCopter's demand (eq. 1) = angle term + omega_t; with omega_t -> w_cmd it equals w_des
    from mavastsm.bridge.cycle.reference_shaping import sqrt_controller
    demand = [sqrt_controller(ei, p, a) + wc for ei, p, a, wc in zip(e, m.ang_p, m.ang_accel, w_cmd)]
    assert demand == pytest.approx(list(w_des))
    m.sync(100, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    m.sync(90, q_from_euler(0.3, 0, 0), (0.0, 0.0, 0.0))  # older message ignored
    assert m.q_t == pytest.approx((1.0, 0.0, 0.0, 0.0))
    m.advance((0.0, 0.0, 10.0), 0.01)  # omega_t slews at ATC_ACCEL_Y_MAX
    assert m.w_t[2] == pytest.approx(1.22 * 0.01)
    # M6: roll and pitch compensated exactly as above, yaw passed through (ArduCopter's yaw angle loop is kept)
    roll_pitch_only = AutopilotTargetModel((4.5, 4.5, 3.42), (6.28, 6.28, 1.22), compensate_yaw=False)
    roll_pitch_only.reset(q_from_euler(0.01, 0.0, 0.52), (0.0, 0.0, 0.1))
    partial = roll_pitch_only.compensate(q_meas, w_des)
    assert partial[:2] == pytest.approx(w_cmd[:2]) and partial[2] == w_des[2] and w_cmd[2] != pytest.approx(w_des[2])


def test_float_fast_paths_match_the_reference_implementations():
    from mavastsm.bridge.cycle.control_cycle import ReferenceTable
    from mavastsm.control.controller_interface import tracking_error, tracking_error_and_euler_rates
    from mavastsm.references import load_reference

    rng = np.random.default_rng(4)
    for _ in range(50):
        eu = rng.uniform([-0.6, -0.6, -math.pi], [0.6, 0.6, math.pi])
        w, ref, rr, ra = rng.normal(size=3), rng.uniform(-3, 3, 3), rng.normal(size=3), rng.normal(size=3)
        fast, rates = tracking_error_and_euler_rates(tuple(eu), tuple(w), ref, rr, ra)
        slow = tracking_error(eu, w, ref, rr, ra)
        for name in ("angle_error_rad", "euler_rate_error_rads", "ref_euler_accel_radss", "body_rates_rads", "euler_rad"):
            assert np.allclose(getattr(fast, name), getattr(slow, name)), name
    prof = load_reference("paper_steps_prefiltered").relative_to((0.0, 0.0, 2.0))
    table = ReferenceTable(prof, chunk_ms=700)
    for t_ms in (0, 499, 500, 1234, 2000, 4999, 12345):
        for got, want in zip(table.at_ms(t_ms), prof.at(t_ms / 1000.0)):
            assert np.allclose(got, want)


# ---------------------------------------------------------------------------- command limits and the pinned rule
def _solo_i0():
    from mavastsm.solo_model import load_solo

    return tuple(float(x) for x in load_solo().inertia_diag)


def test_command_torque_limit_per_axis_modes():
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import command_torque_limit_nm

    i0, atc = _solo_i0(), (6.28, 6.28, 1.22)  # the Solo's ATC_ACCEL_R/P/Y_MAX [rad/s^2]
    default = load_bridge_config().mapping
    assert default.command_accel_clip == "auto"
    # auto: an adaptive-gain law (ASTSM) gets the roll/pitch authority, fixed-gain laws keep ATC_ACCEL
    lim = command_torque_limit_nm(default, i0, atc, adaptive_gain=True)
    assert lim[:2] == pytest.approx(default.torque_authority_nm[:2]) and lim[0] > 0.5 and lim[1] > 0.5
    assert lim[2] == pytest.approx(i0[2] * 1.22)  # yaw stays at I0_zz * ATC_ACCEL_Y
    fixed = command_torque_limit_nm(default, i0, atc, adaptive_gain=False)
    assert fixed == pytest.approx(tuple(i * a for i, a in zip(i0, atc)))
    assert fixed[0] < 0.06  # 0.056 N m: why the first design could not reject 0.5 N m
    first = load_bridge_config(overrides={"mapping": {"command_accel_clip": "autopilot"}}).mapping
    assert command_torque_limit_nm(first, i0, atc, adaptive_gain=True) == pytest.approx(fixed)
    every = load_bridge_config(overrides={"mapping": {"command_accel_clip": "authority"}}).mapping
    assert command_torque_limit_nm(every, i0, atc) == pytest.approx(every.torque_authority_nm)


class _ScriptedController:
    """Returns scripted torques with alpha at alpha_max on every axis (a stand-in for a wound-up ASTSM)."""

    name = "scripted"

    def __init__(self, torques, alpha_max=1000.0):
        self.torques = list(torques)
        self.k = 0
        self.alpha_max = alpha_max

    def reset(self):
        self.k = 0

    def update(self, err, dt_s):
        u = self.torques[min(self.k, len(self.torques) - 1)]
        self.k += 1
        return np.array(u, dtype=float)

    def diagnostics(self):
        return {"alpha": np.full(3, self.alpha_max)}


def _run_cycle(torques, n=200, dt=0.0025):
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import ControlCycle
    from mavastsm.bridge.link.messages import AttitudeSample
    from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
    from mavastsm.references import load_reference

    cfg = load_bridge_config()
    ctl = _ScriptedController(torques)
    cycle = ControlCycle(ctl, load_reference("hold"), _solo_i0(), ardupilot_profile("climb_rate"), cfg, ctl.alpha_max,
                         (6.28, 6.28, 1.22), torque_authority_nm=(2.9, 2.9, 0.03))
    cycle.engage(AttitudeSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0))
    for k in range(1, n + 1):
        res = cycle.step(AttitudeSample(int(k * dt * 1000), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0), dt)
        if res.failsafe is not None:
            return res.failsafe, k * dt
    return None, n * dt


def test_alpha_at_max_on_an_axis_held_at_its_authority_is_not_wind_up():
    # yaw pushed against its limit (a disturbance larger than the authority), roll/pitch inside their limits
    # but their alpha also at max -> wind-up on roll/pitch is still caught ...
    fs, t = _run_cycle([(0.1, 0.1, -0.03)])
    assert fs is FailsafeReason.ADAPTIVE_GAIN_PINNED and t == pytest.approx(0.25, abs=0.01)
    # ... every axis held at its limit on one side: physics, not the law -> no failsafe
    fs, _ = _run_cycle([(2.9, -2.9, -0.03)])
    assert fs is None
    # chattering from one limit to the other is the law winding up -> failsafe
    fs, _ = _run_cycle([(2.9, -2.9, 0.03), (2.9, -2.9, -0.03)] * 200)
    assert fs is FailsafeReason.ADAPTIVE_GAIN_PINNED


# ------------------------------------------------------------------ flight log rows
_finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3))


@settings(max_examples=60, deadline=None)
@given(values=st.lists(_finite_or_not, min_size=40, max_size=40), failsafe=st.sampled_from([None, *FailsafeReason]))
def test_flight_log_row_has_every_column_in_order_with_its_documented_format(values, failsafe):
    import csv
    import io

    from mavastsm.bridge.record.flight_log import COLUMNS, format_row
    from mavastsm.telemetry import ControlSample

    vec = [tuple(values[1 + 3 * k: 4 + 3 * k]) for k in range(12)]
    s = ControlSample(values[0], *vec, thrust_norm=values[37], latency_s=values[38], failsafe=failsafe)
    cells = next(csv.reader(io.StringIO(format_row(s, 17))))
    assert len(cells) == len(COLUMNS) == 45
    # the per-field rule: time in ms resolution, 6 significant digits (alpha, columns 16-18: full precision, 17
    # digits, safe-simple issue), thrust 4 decimals, latency in us, a count
    expected = ([f"{values[0]:.3f}"] + [f"{v:.17g}" if 16 <= i <= 18 else f"{v:.6g}" for i, v in enumerate(values[1:37], 1)]
                + [f"{values[37]:.4f}", f"{values[38] * 1e6:.1f}", "17"])
    assert COLUMNS[16:19] == ("alpha_roll", "alpha_pitch", "alpha_yaw")
    assert cells[:40] == expected
    assert cells[40] == (failsafe.name if failsafe is not None else "")
    # the phase columns (ux issue, item 11), after every older column: a row defaults to the engaged phase
    assert COLUMNS[41:] == ("phase", "mode", "armed", "altitude_m") and cells[41:] == ["engaged", "", "0", "nan"]
    cells = next(csv.reader(io.StringIO(format_row(s, 17, "takeoff", "GUIDED_NOGPS", True, values[39]))))
    assert cells[:41] == expected + [failsafe.name if failsafe is not None else ""]
    assert cells[41:] == ["takeoff", "GUIDED_NOGPS", "1", f"{values[39]:.3f}"]


def test_flight_log_flush_writes_every_pending_row_in_chunks(tmp_path):
    import csv

    from mavastsm.bridge.record.flight_log import COLUMNS, ROWS_PER_WRITE, FlightLog
    from mavastsm.telemetry import ControlSample

    log = FlightLog(tmp_path / "f.csv")
    n = 5 * ROWS_PER_WRITE + 7
    for k in range(n):
        log.append(ControlSample(k / 400.0, euler_rad=(0.1, -0.2, k * 1e-3)))
    log.flush()
    with open(tmp_path / "f.csv") as f:
        rows = list(csv.DictReader(f))
    assert log.rows == n and len(rows) == n and list(rows[0]) == list(COLUMNS)
    assert [float(r["vehicle_time_s"]) for r in rows] == [round(k / 400.0, 3) for k in range(n)]
    log.close()


def test_summaries_never_print_nan():
    """The ux issue, item 8: Ctrl-C before engagement and `--reference hold` printed `nan` in the summary. A figure
    that does not exist is "—" or a sentence saying why."""
    import dataclasses

    from mavastsm.bridge.bridge_api import BridgeSummary
    from mavastsm.bridge.record.tracking_metrics import AxisMetrics

    nan = float("nan")
    never = BridgeSummary(url="udpout:127.0.0.1:9", autopilot="ArduPilot", firmware_version="4.5.7", thrust_semantics="climb_rate",
                          controller="astsm", reference="paper_steps", end_reason="operator stop", failsafe=None, handback="not performed",
                          engagements=0, cycles=0, missed=0, dropped=0, duplicate=0, superseded=0, invalid=0, foreign_attitude=0,
                          blocked_setpoints=0, overruns=0, latency_p50_s=nan, latency_p99_s=nan, latency_max_s=nan,
                          attitude_rate_achieved_hz=nan, engage_time_s=nan,
                          axes=tuple(AxisMetrics(a, nan, nan, nan, nan, nan, nan, nan, nan) for a in ("roll", "pitch", "yaw")))
    text = never.format()
    assert "nan" not in text.lower(), text
    assert "never engaged" in text and "no control cycle ran" in text
    hold = dataclasses.replace(never, cycles=800, latency_p50_s=2e-4, latency_p99_s=5e-4, latency_max_s=9e-4, attitude_rate_achieved_hz=320.0,
                               axes=tuple(AxisMetrics(a, nan, 0.0, nan, nan, 0.1, 0.5, 0.2, 0.3) for a in ("roll", "pitch", "yaw")))
    text = hold.format()
    assert "nan" not in text.lower(), text
    assert "no step on that axis" in text


def test_failsafe_reasons_combine_by_declaration_order():
    """The safe-simple issue: `highest_priority` was documented as how failsafes combine but never called; the cycle
    returned whichever check came first in the code (COMMAND_SATURATION before ADAPTIVE_GAIN_PINNED, against
    the declared order). It is now the one rule the cycle applies."""
    from mavastsm.bridge.cycle.safety import highest_priority

    R = FailsafeReason
    assert highest_priority([R.COMMAND_SATURATION, R.ADAPTIVE_GAIN_PINNED]) is R.ADAPTIVE_GAIN_PINNED
    assert highest_priority([None, R.STALE_ATTITUDE, R.LINK_LOST]) is R.LINK_LOST
    assert highest_priority([None, None]) is None
    order = list(R)
    assert order.index(R.ADAPTIVE_GAIN_PINNED) < order.index(R.COMMAND_SATURATION)


def test_the_default_controller_preset_is_declared_in_bridge_yaml():
    """Issue 19, item 5: which preset connect/demo fly for --controller astsm is bridge.yaml's presets.astsm (it was a
    dict in bridge_api.py, so editing the config changed nothing); a preset that does not exist fails at load."""
    from mavastsm.bridge import Bridge, BridgeOptions
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.errors import ConfigError

    assert load_bridge_config().presets.astsm == "astsm_mavlink"
    assert Bridge(BridgeOptions("udpout:127.0.0.1:9")).controller.config_path.name == "astsm_mavlink.yaml"
    other = Bridge(BridgeOptions("udpout:127.0.0.1:9", overrides={"presets.astsm": "astsm_400hz"}))
    assert other.controller.config_path.name == "astsm_400hz.yaml"
    assert Bridge(BridgeOptions("udpout:127.0.0.1:9", controller="pid")).controller.config_path.name == "pid.yaml"
    with pytest.raises(ConfigError, match="presets.astsm"):
        load_bridge_config(None, {"presets": {"astsm": "no_such_preset"}})


def test_integrated_roll_pitch_command_is_its_own_integral_not_the_measured_rate_plus_a_lead():
    """M9 (``mapping.roll_pitch_command_base: integrated``, the Solo description's choice): a vehicle rolled at 0.5 rad/s by a torque,
    with the law asking for no acceleration, gets p_cmd = p_cmd(previous) + a dt = the rate at engagement (0), not
    p + tau a (0.5, which endorses the roll: M2). Yaw keeps its first-order command."""
    from mavastsm.bridge.cycle.setpoint_mapping import RateMapping, integrated_axes

    m9 = RateMapping("first_order", _solo_i0(), (0.025, 0.04, 0.03), None, (True, True, False))
    m9.reset((0.0, 0.0, 0.0))
    cmd = m9((0.0, 0.0, 0.0), (0.5, 0.0, 0.2), 0.0025)
    assert cmd[0] == pytest.approx(0.0, abs=1e-9) and cmd[2] == pytest.approx(0.2)
    cmd = m9((0.0885, 0.0, 0.0), (0.5, 0.0, 0.2), 0.01)  # a_roll = 0.0885 / I_xx = 10 rad/s^2 for 10 ms
    assert cmd[0] == pytest.approx(0.1, rel=1e-3)
    m2 = RateMapping("first_order", _solo_i0(), (0.025, 0.04, 0.03))
    assert m2((0.0, 0.0, 0.0), (0.5, 0.0, 0.2), 0.0025)[0] == pytest.approx(0.5)
    from mavastsm.bridge.bridge_config import load_bridge_config

    assert integrated_axes(load_bridge_config().mapping) == (False, False, False)  # bridge.yaml: M2; the Solo's description: M9
    assert integrated_axes(load_bridge_config(overrides={"mapping": {"roll_pitch_command_base": "integrated"}}).mapping) == (True, True, False)
    assert integrated_axes(load_bridge_config(overrides={"mapping": {"method": "integrate"}}).mapping) == (True, True, True)


def test_integrated_command_loses_what_the_safety_clamp_did_not_send():
    """Anti-windup by back-calculation: when the clamps cut an integrated command, the integral keeps only what was
    sent, so it never runs ahead of what the vehicle was told (first-order axes keep no state)."""
    from mavastsm.bridge.cycle.setpoint_mapping import RateMapping

    m9 = RateMapping("first_order", _solo_i0(), 0.05, None, (True, True, False))
    m9.reset((0.0, 0.0, 0.0))
    requested = m9((0.885, 0.0, 0.0), (0.0, 0.0, 0.0), 0.01)  # +1 rad/s on roll
    m9.saturated_to(requested, (0.6, requested[1], 0.3))  # roll cut to 0.6; yaw "cut" is ignored (not integrated)
    nxt = m9((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.01)
    assert nxt[0] == pytest.approx(0.6) and nxt[2] == pytest.approx(0.0)


def test_the_adaptive_gain_ceiling_counts_the_rate_loops_lag_on_integrated_axes():
    """M9: on an integrated axis the switching term sees the loop delay plus the rate loop's lag tau (the first-order
    lead omega + tau a no longer cancels it), so the ceiling sqrt(mu) / (0.709 L) is taken at L + tau there."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.setpoint_mapping import switching_delay_s

    over = {"loop_delay_s": [0.04, 0.04, 0.2], "rate_time_constant_s": [0.025, 0.04, 0.03], "roll_pitch_command_base": "integrated"}
    assert switching_delay_s(load_bridge_config(overrides={"mapping": over}).mapping) == pytest.approx((0.065, 0.08, 0.2))
    measured = load_bridge_config(overrides={"mapping": {**over, "roll_pitch_command_base": "measured"}}).mapping
    assert switching_delay_s(measured) == pytest.approx((0.04, 0.04, 0.2))


# ---------------------------------------------------------------------- PX4's hover collective from its own hold (issue 26)
def _targets(samples):
    """[(time_boot_ms, thrust, mode, armed[, q_wxyz])] -> TargetInMode list."""
    from mavastsm.bridge.link.messages import AttitudeTarget, TargetInMode

    return [TargetInMode(AttitudeTarget(t, (q[0] if q else (1.0, 0.0, 0.0, 0.0)), (0.0, 0.0, 0.0), thr), mode, armed)
            for t, thr, mode, armed, *q in samples]


def test_hover_measurement_averages_the_last_window_of_the_hold_and_ignores_offboard_repeats():
    from mavastsm.bridge.autopilots.preflight import measure_hover_collective

    climb = [(1000 + 20 * i, 0.75, "TAKEOFF", True) for i in range(50)]  # PX4's takeoff: not in the window
    hold = [(2000 + 20 * i, 0.55 + 0.02 * (i % 2), "LOITER", True) for i in range(100)]  # 2 s of hold at 0.56 +- 0.01
    repeats = [(3980, 0.56, "OFFBOARD", True)] * 5 + [(3980, 0.9, "LOITER", True)]  # stale copies: old timestamp
    m = measure_hover_collective(_targets(climb + hold + repeats), ("OFFBOARD",), 1.0, now_ms=4100, parameter_norm=0.364)
    assert not isinstance(m, str), m
    assert m.hover_norm == pytest.approx((25 * 0.55 + 26 * 0.57) / 51)  # the 51 targets of [2980, 3980] ms
    assert m.samples == 51 and m.span_s == pytest.approx(1.0) and m.mode == "LOITER" and m.std_norm == pytest.approx(0.01, abs=1e-3)
    assert m.text() == ("hover collective 0.560 from PX4's hold (ATTITUDE_TARGET thrust, 51 targets over 1.00 s in LOITER, "
                        "std 0.010; MPC_THR_HOVER 0.364)")


def test_hover_measurement_keeps_the_hold_only_not_the_takeoff_before_it():
    """PX4's takeoff hands over to its hold still climbing: a window reaching back into TAKEOFF averages the hold only."""
    from mavastsm.bridge.autopilots.preflight import measure_hover_collective

    takeoff = [(1000 + 20 * i, 0.62, "TAKEOFF", True) for i in range(50)]
    hold = [(2000 + 20 * i, 0.56, "LOITER", True) for i in range(31)]  # 0.6 s of hold
    m = measure_hover_collective(_targets(takeoff + hold), ("OFFBOARD",), 1.0, now_ms=2700, parameter_norm=0.364)
    assert m.hover_norm == pytest.approx(0.56) and m.samples == 31 and m.span_s == pytest.approx(0.6) and m.mode == "LOITER"


def test_hover_measurement_takes_the_vertical_component_of_a_tilted_hold():
    from mavastsm.bridge.autopilots.preflight import measure_hover_collective
    from mavastsm.frames import q_from_euler

    q = tuple(float(x) for x in q_from_euler(math.radians(10.0), math.radians(-5.0), 1.0))
    m = measure_hover_collective(_targets([(1000 + 20 * i, 0.6, "POSCTL", True, q) for i in range(60)]), ("OFFBOARD",), 1.0, 2300)
    assert m.hover_norm == pytest.approx(0.6 * math.cos(math.radians(10.0)) * math.cos(math.radians(5.0)), rel=1e-6)


@pytest.mark.parametrize("samples, now_ms, why", [
    ([], 1000, "no ATTITUDE_TARGET from a hold of its own"),
    ([(1000 + 20 * i, 0.56, "OFFBOARD", True) for i in range(60)], 2300, "no ATTITUDE_TARGET from a hold of its own"),
    ([(1000 + 20 * i, 0.56, "LOITER", False) for i in range(60)], 2300, "no ATTITUDE_TARGET from a hold of its own"),
    ([(1000 + 20 * i, 0.56, "LOITER", True) for i in range(60)], 5300, "its hold's last target is 3.1 s old"),
    ([(1000 + 20 * i, 0.56, "LOITER", True) for i in range(10)], 1300, "10 targets over 0.18 s of its hold"),
    ([(1000 + 20 * i, 0.4 + 0.2 * (i % 2), "LOITER", True) for i in range(60)], 2300, "its collective scatters (std 0.100"),
    ([(1000 + 20 * i, 0.12, "LOITER", True) for i in range(60)], 2300, "mean collective 0.120 of its hold is outside 0.5-2 x"),
    ([(1000 + 20 * i, 0.99, "LOITER", True) for i in range(60)], 2300, "mean collective 0.990 of its hold is outside [0.05, 0.95]"),
    ([(1000 + 20 * i, float("nan"), "LOITER", True) for i in range(60)], 2300, "no ATTITUDE_TARGET from a hold of its own"),
])
def test_hover_measurement_refuses_what_is_no_steady_hold(samples, now_ms, why):
    """Each refusal is a reason (the bridge then flies MPC_THR_HOVER and says it), never a hover."""
    from mavastsm.bridge.autopilots.preflight import measure_hover_collective

    got = measure_hover_collective(_targets(samples), ("OFFBOARD",), 1.0, now_ms, parameter_norm=0.364)
    assert isinstance(got, str) and got.startswith(why), got


def test_cycle_flies_a_measured_hover_only_when_finite_within_the_thrust_limits():
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.cycle.control_cycle import ControlCycle
    from mavastsm.references import load_reference

    cfg = load_bridge_config(overrides={"limits": {"thrust_min_norm": 0.1, "thrust_max_norm": 0.8}})
    cycle = ControlCycle(_ScriptedController([(0.0, 0.0, 0.0)], alpha_max=None), load_reference("hold"), _solo_i0(),
                         px4_profile(0.364), cfg, None, (6.28, 6.28, 1.22))
    cycle.set_hover_collective(0.56)
    assert cycle.profile.hover_thrust_norm == 0.56 and cycle.level_hold(0.0).thrust_norm == pytest.approx(0.56)
    for bad in (float("nan"), float("inf"), 0.05, 0.9):
        cycle.set_hover_collective(bad)
        assert cycle.profile.hover_thrust_norm == 0.56, bad


class _FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def monotonic(self) -> float:
        return self.t


def _actions(link, said, clock=None):
    """VehicleActions on a stand-in link, saying into ``said``; with ``clock``, its waits advance the fake clock."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.vehicle_actions import VehicleActions

    cfg = load_bridge_config()
    if clock is None:
        return VehicleActions(link, cfg.link, cfg.thrust, said.append, lambda seconds: False)
    return VehicleActions(link, cfg.link, cfg.thrust, said.append,
                          lambda seconds: setattr(clock, "t", clock.t + seconds) or False, monotonic=clock.monotonic)


def test_autopilot_takeoff_waits_for_the_vertical_estimate_at_rest_and_refuses_one_that_never_is():
    """PX4 on SIH: |vz| 0.1-0.3 m/s for seconds after arming is first allowed, and a takeoff then ended on the ground
    in about half of the runs. The bridge arms only after |vz| <= REST_VZ_MS for REST_HOLD_S (said), and refuses the
    takeoff with the reason when that never comes within REST_TIMEOUT_S."""
    from types import SimpleNamespace

    from mavastsm.bridge.link.messages import LocalPosition
    from mavastsm.bridge.vehicle_actions import REST_HOLD_S, REST_TIMEOUT_S, REST_VZ_MS
    from mavastsm.errors import OffboardRejected

    for settles_after_s in (3.0, math.inf):
        clock, said = _FakeClock(), []
        start = clock.t

        def vz_now():
            return 0.05 if clock.t - start >= settles_after_s else (-1) ** int((clock.t - start) * 4) * 2 * REST_VZ_MS

        actions = _actions(SimpleNamespace(local_position=lambda: LocalPosition(0, (0.0, 0.0, 0.0), (0.0, 0.0, vz_now()))),
                           said, clock)
        if math.isfinite(settles_after_s):
            actions.wait_vertical_estimate_at_rest()
            assert clock.t - start == pytest.approx(settles_after_s + REST_HOLD_S, abs=0.11)  # polled every 0.05 s
            assert any(line.startswith("waiting for the vertical estimate to come to rest: vz +0.20 m/s") for line in said), said
            assert said[-1] == f"vertical estimate at rest after 5 s (|vz| <= {REST_VZ_MS:g} m/s for {REST_HOLD_S:g} s)"
        else:
            with pytest.raises(OffboardRejected, match=rf"vertical velocity estimate was not at rest within {REST_TIMEOUT_S:g} s \(vz [+-]0\.20 m/s"):
                actions.wait_vertical_estimate_at_rest()
            assert clock.t - start == pytest.approx(REST_TIMEOUT_S, abs=0.11)


def test_a_start_that_fails_after_the_bridge_armed_hands_back_as_asked_and_says_so():
    """PX4's own takeoff stalled on the ground (SIH, 5 of 12 cold starts before the rest wait): start-up failed with
    the vehicle armed in TAKEOFF, and the bridge used to leave it there. Now the hand-back asked for applies
    (--on-failsafe, else --on-exit, walking the profile's list); none asked: said, left to the autopilot; a vehicle
    the bridge did not arm is never touched."""
    from types import SimpleNamespace

    from mavastsm.bridge.bridge_api import Bridge, BridgeOptions
    from mavastsm.bridge.link.messages import HeartbeatInfo
    from mavastsm.errors import OffboardRejected

    armed_takeoff = HeartbeatInfo(1, 1, 12, 2, 0x80, 0, 4, "TAKEOFF", 0.0)  # MAV_AUTOPILOT_PX4
    assert armed_takeoff.armed

    def run(on_exit, on_failsafe, armed_by_bridge, refuse=()):
        said, requested = [], []

        def command_long(_command, _params, label, *_):
            mode = label.rsplit(" ", 1)[1]  # "COMMAND_LONG DO_SET_MODE ALTCTL"
            requested.append(mode)
            if mode in refuse:
                raise OffboardRejected(f"mode {mode}", 1)

        b = Bridge(BridgeOptions("udpout:127.0.0.1:9", print_fn=said.append, on_exit=on_exit, on_failsafe=on_failsafe))
        b.link = SimpleNamespace(last_heartbeat=armed_takeoff, requests=SimpleNamespace(command_long=command_long))
        b.session = SimpleNamespace(cycle=SimpleNamespace(profile=px4_profile()))
        b._actions = _actions(b.link, said)
        b._actions.armed_by_bridge = armed_by_bridge
        b._hand_back_after_failed_start()
        return requested, said

    assert run("LAND", "none", True) == (["LAND"], ["start-up failed with the vehicle armed: hand-back LAND accepted"])
    requested, said = run("LAND", "ALT_HOLD", True, refuse=("ALTCTL",))
    assert requested == ["ALTCTL", "LOITER"] and said[0].startswith("start-up failed with the vehicle armed: hand-back ALTCTL refused (") \
        and said[0].endswith("LOITER accepted")
    assert run("none", "none", True) == ([], ["start-up failed with the vehicle armed in TAKEOFF (armed by the bridge): no hand-back "
                                              "asked (--on-failsafe and --on-exit none); the autopilot has it"])
    assert run("LAND", "LAND", False) == ([], [])  # armed by somebody else: theirs


def test_the_rest_wait_asks_for_local_position_when_it_is_not_streamed_and_says_when_it_cannot_check():
    """thrust.altitude_hold false: LOCAL_POSITION_NED was never asked for, so the wait asks (50 Hz); refused, the
    takeoff goes on unchecked and the bridge says so, rather than waiting 60 s on an estimate it cannot see."""
    from types import SimpleNamespace

    from mavastsm.bridge.link.mavlink_link import MSG_ID_LOCAL_POSITION_NED
    from mavastsm.errors import OffboardRejected

    said, asked = [], []

    def refuse(msg_id, hz, *_):
        asked.append((msg_id, hz))
        raise OffboardRejected("SET_MESSAGE_INTERVAL LOCAL_POSITION_NED", 3)

    _actions(SimpleNamespace(local_position=lambda: None, requests=SimpleNamespace(set_message_interval=refuse)),
             said).wait_vertical_estimate_at_rest()
    assert asked == [(MSG_ID_LOCAL_POSITION_NED, 50.0)]
    assert len(said) == 1 and said[0].startswith("vertical estimate not checked before the takeoff: LOCAL_POSITION_NED refused ("), said
