"""Motor model: first-order lag (63 % at tau), thrust/speed at full command, limits, reaction-torque sign."""

from __future__ import annotations

import math

import pytest

from mavastsm_sim.mixer import QUAD_X_LAYOUT, motor_positions_frd, motor_spin_ccw
from mavastsm_sim.motor_model import MotorBank
from mavastsm_sim.vehicle_config import load_vehicle_config

CFG = load_vehicle_config()
PROP = CFG.propulsion


def _bank(enabled=True):
    return MotorBank(PROP, motor_positions_frd(CFG.rigid_body.arm_length), motor_spin_ccw(), enabled=enabled)


@pytest.mark.parametrize("dt", [1e-3, 2.5e-3])
def test_step_response_reaches_63_percent_at_time_constant(dt):
    bank = _bank()
    tau = PROP.motor_time_constant
    n = round(tau / dt)
    assert abs(n * dt - tau) < 1e-12  # the grid hits tau exactly for these dt
    for _ in range(n):
        bank.step([1.0] * 4, dt)
    frac = bank.speed_rads[0] / PROP.max_motor_speed
    assert frac == pytest.approx(1.0 - math.exp(-1.0), abs=1e-9)


def test_full_command_gives_max_speed_and_thrust_and_commands_are_clipped():
    bank = _bank()
    for _ in range(1000):
        thrust, *_ = bank.step([5.0, 1.0, 1.0, 1.0], 1e-3)  # 5.0 is clipped to 1 (speed limit)
    assert max(bank.speed_rads) == pytest.approx(PROP.max_motor_speed, rel=1e-9)
    assert thrust == pytest.approx(4 * PROP.max_thrust_per_motor, rel=1e-9)
    for _ in range(1000):
        bank.step([-3.0] * 4, 1e-3)
    assert max(bank.speed_rads) < 1e-6


def test_reaction_torque_ccw_motors_yaw_body_clockwise():
    """Speeding up only the CCW propellers (ArduPilot motors 1, 2) gives positive (clockwise) yaw torque,
    and no net roll/pitch torque since they sit diagonally opposite."""
    bank = _bank()
    ccw = [1.0 if s > 0 else 0.0 for s in motor_spin_ccw(QUAD_X_LAYOUT)]
    assert ccw == [1.0, 1.0, 0.0, 0.0]
    for _ in range(500):
        _, tx, ty, tz, hz = bank.step(ccw, 1e-3)
    assert tz > 0.0
    assert abs(tx) < 1e-9 and abs(ty) < 1e-9
    assert tz == pytest.approx(2 * PROP.yaw_torque_per_thrust * PROP.max_thrust_per_motor, rel=1e-6)
    # CCW seen from above = angular velocity along body -z: momentum along +z is negative
    assert hz == pytest.approx(-2 * PROP.rotor_inertia * PROP.max_motor_speed, rel=1e-6)


def test_disabled_bank_produces_nothing():
    bank = _bank(enabled=False)
    assert bank.step([1.0] * 4, 1e-3) == (0.0, 0.0, 0.0, 0.0, 0.0)
