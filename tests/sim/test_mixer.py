"""Quad-X mixer (ArduPilot FRAME_TYPE 1 order and spins): signs through to physical torques, saturation
priorities (roll/pitch before yaw), output bounds, thrust linearisation."""

from __future__ import annotations

import math

import pytest

from mavastsm_sim.mixer import QuadXMixer, motor_positions_frd, motor_spin_ccw, thrust_to_actuator
from mavastsm_sim.motor_model import MotorBank
from mavastsm_sim.vehicle_config import load_vehicle_config

CFG = load_vehicle_config()


def _torques(thrust_fractions):
    """Steady-state body torque [N m] produced by motor thrust fractions (ESC = sqrt(fraction))."""
    bank = MotorBank(CFG.propulsion, motor_positions_frd(CFG.rigid_body.arm_length), motor_spin_ccw())
    esc = [math.sqrt(f) for f in thrust_fractions]
    for _ in range(1000):
        _, tx, ty, tz, _ = bank.step(esc, 1e-3)
    return tx, ty, tz


def test_motor_positions_follow_ardupilot_quad_x_order():
    pos = motor_positions_frd(0.2)
    # motor 1 front-right, 2 back-left, 3 front-left, 4 back-right (FRD: x forward, y right)
    signs = [(math.copysign(1, x), math.copysign(1, y)) for x, y in pos]
    assert signs == [(1, 1), (-1, -1), (1, -1), (-1, 1)]
    assert motor_spin_ccw() == [1.0, 1.0, -1.0, -1.0]


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_positive_demand_gives_positive_physical_torque_on_that_axis_only(axis):
    mixer = QuadXMixer()
    demand = [0.0, 0.0, 0.0]
    demand[axis] = 0.2
    out = mixer.mix(*demand, throttle=0.4, throttle_avg_max=0.4)
    tau = _torques(out)
    assert tau[axis] > 0.0
    for other in {0, 1, 2} - {axis}:
        assert abs(tau[other]) < 1e-9


def test_positive_roll_raises_left_motors():
    out = QuadXMixer().mix(0.2, 0.0, 0.0, 0.5, 0.5)
    left = [out[1], out[2]]  # motors 2 (back-left), 3 (front-left)
    right = [out[0], out[3]]
    assert min(left) > max(right)


def test_factors_normalised_to_half():
    m = QuadXMixer()
    for f in (m.roll_factor, m.pitch_factor, m.yaw_factor):
        assert max(abs(v) for v in f) == pytest.approx(0.5)


def _achieved(out):
    roll = (out[1] + out[2] - out[0] - out[3]) / 2.0  # equals the roll demand when nothing is scaled
    yaw = (out[0] + out[1] - out[2] - out[3]) / 2.0
    return roll, yaw


def test_yaw_is_limited_before_roll_pitch_when_saturated():
    m = QuadXMixer(yaw_headroom=0.0)
    out = m.mix(0.9, 0.0, 1.0, throttle=0.5, throttle_avg_max=0.5)
    assert all(0.0 <= o <= 1.0 for o in out)
    assert m.limit.yaw and not m.limit.roll
    roll, yaw = _achieved(out)
    assert roll == pytest.approx(0.9, abs=1e-9)  # roll kept in full
    assert 0.0 < yaw < 0.25


def test_yaw_headroom_keeps_minimum_yaw_by_scaling_roll_pitch():
    """MOT_YAW_HEADROOM (0.2): ArduPilot always allows that much yaw and scales roll/pitch/yaw to fit."""
    m = QuadXMixer(yaw_headroom=0.2)
    out = m.mix(0.9, 0.0, 1.0, throttle=0.5, throttle_avg_max=0.5)
    roll, yaw = _achieved(out)
    assert m.limit.yaw and m.limit.roll
    assert roll == pytest.approx(0.9 / 1.1, abs=1e-9)
    assert yaw == pytest.approx(0.2 / 1.1, abs=1e-9)


def test_outputs_always_within_bounds_and_flags_on_saturation():
    m = QuadXMixer()
    for r in (-1.0, -0.3, 0.0, 0.7, 1.0):
        for y in (-1.0, 0.0, 1.0):
            for t in (0.0, 0.1, 0.5, 0.95, 1.0):
                out = m.mix(r, -r, y, t, max(t, 0.5))
                assert all(0.0 <= o <= 1.0 for o in out)
    m.mix(0.0, 0.0, 0.0, 0.0, 0.0)
    assert m.limit.throttle_lower
    m.mix(0.0, 0.0, 0.0, 1.0, 1.0)
    assert m.limit.throttle_upper


def test_thrust_linearisation_inverts_expo_curve():
    e, lo, hi = 0.8, 0.15, 0.95
    for t in (0.0, 0.1, 0.37, 0.8, 1.0):
        a = (thrust_to_actuator(t, e, lo, hi) - lo) / (hi - lo)
        assert (1 - e) * a + e * a * a == pytest.approx(t, abs=1e-12)
    assert thrust_to_actuator(0.3, 0.0, 0.0, 1.0) == pytest.approx(0.3)


@pytest.mark.parametrize("expo", [0.0, 0.65, 0.8, -0.3])
def test_bound_thrust_curve_equals_reference(expo):
    from mavastsm_sim.mixer import make_thrust_to_actuator

    f = make_thrust_to_actuator(expo, 0.15, 0.95)
    thrusts = [-0.1, 0.0, 0.2, 0.37, 0.9, 1.0, 1.2]
    assert f(thrusts) == pytest.approx([thrust_to_actuator(t, expo, 0.15, 0.95) for t in thrusts], abs=1e-12)
