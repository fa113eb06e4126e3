"""Helpers shared by the SimulatedCopter tests: fly with a steady SET_ATTITUDE_TARGET stream in lockstep."""

from __future__ import annotations

import math

import numpy as np

from mavastsm_sim.copter import SimulatedCopter

RATES_THRUST = 0x80  # ATTITUDE_IGNORE: body rates + thrust
ATTITUDE_THRUST = 0x07  # all rate-ignore bits: quaternion + thrust
IDENTITY = (1.0, 0.0, 0.0, 0.0)
GUIDED_NOGPS = 20


def fly(copter: SimulatedCopter, seconds: float, rates=(0.0, 0.0, 0.0), thrust: float = 0.5,
        mask: int = RATES_THRUST, q=IDENTITY, rate_hz: float = 50.0, record=None):
    """Send the same target at ``rate_hz`` (like a bridge) and step the sim for ``seconds``."""
    dt = 1.0 / rate_hz
    for _ in range(int(round(seconds * rate_hz))):
        ok, reason = copter.handle_attitude_target(mask, q, rates, thrust)
        assert ok, reason
        copter.step(dt)
        if record is not None:
            record.append((copter.time_s, copter.euler_rad.copy(), copter.position_ned_m.copy(),
                           copter.velocity_ned_ms.copy()))


def coast(copter: SimulatedCopter, seconds: float, dt: float = 0.02, record=None):
    """Step without sending anything."""
    for _ in range(int(round(seconds / dt))):
        copter.step(dt)
        if record is not None:
            record.append((copter.time_s, copter.euler_rad.copy(), copter.position_ned_m.copy(),
                           copter.velocity_ned_ms.copy()))


def airborne_copter(altitude_m: float = 2.0, **kwargs) -> SimulatedCopter:
    """A copter armed in GUIDED_NOGPS, climbed to about ``altitude_m`` and settled in hover."""
    c = SimulatedCopter(**kwargs)
    assert c.set_mode(GUIDED_NOGPS)[0]
    assert c.arm()[0]
    # thrust 1.0 -> +2.5 m/s (WPNAV_SPEED_UP); stop climbing when the stopping distance at the
    # vertical acceleration limit (PILOT_ACCEL_Z 2.5 m/s^2) would reach the requested altitude
    for _ in range(1000):
        up, climb = -c.position_ned_m[2], -c.velocity_ned_ms[2]
        if up + climb * climb / (2.0 * 2.5) >= altitude_m:
            break
        fly(c, 0.02, thrust=1.0)
    fly(c, 2.0, thrust=0.5)
    assert not c.landed and c.armed
    return c


def degrees(v) -> np.ndarray:
    return np.degrees(np.asarray(v))


def heading_change_deg(yaw0: float, yaw1: float) -> float:
    return math.degrees(math.atan2(math.sin(yaw1 - yaw0), math.cos(yaw1 - yaw0)))


def offline_plant_stepper(inertia_33):
    """Step function of the offline simulator's attitude plant (mavastsm.offline.plant) for one run:
    ``step(euler (3,), omega (3,), torque (3,), h) -> (euler, omega)``."""
    from mavastsm.offline import plant

    p = plant.Rk4AttitudePlant(np.asarray(inertia_33, dtype=float)[None], exact_kinematics=True)
    zero = np.zeros((3, 1))

    def step(euler, omega, torque, h):
        x = np.concatenate([euler, omega])[:, None]
        x = p.step(x, np.asarray(torque, dtype=float)[:, None], zero, zero, zero, h)
        return x[0:3, 0], x[3:6, 0]

    return step
