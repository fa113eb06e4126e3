"""Shaping helpers on plain floats for the 400 Hz autopilot loop.

The quaternion algebra on float tuples lives in ``mavastsm.frames`` and ArduPilot's ``sqrt_controller`` in
``mavastsm.ap_math`` (one copy each, shared with the bridge); they are imported here under their old names.
"""

from __future__ import annotations

import math

from mavastsm.ap_math import sqrt_controller  # noqa: F401  (re-exported: sim modules import it from here)
from mavastsm.frames import (  # noqa: F401  (re-exported)
    q_conj, q_from_euler, q_from_rotation_vector, q_mul, q_normalize, q_rotate, q_rotate_inverse, q_to_euler, q_to_rotation_vector,
)


def inv_sqrt_controller(output, p, second_ord_lim):
    """ArduPilot's ``inv_sqrt_controller`` (AP_Math/control.cpp): the error for which :func:`sqrt_controller` gives
    ``output``, i.e. the largest error a limited output can still remove without overshoot."""
    if second_ord_lim > 0.0 and p == 0.0:
        return output * output / (2.0 * second_ord_lim)
    if second_ord_lim <= 0.0 and p != 0.0:
        return output / p
    if p == 0.0:
        return 0.0
    linear_velocity = second_ord_lim / p
    if abs(output) < linear_velocity:
        return output / p
    stopping_dist = second_ord_lim / (p * p) * 0.5 + output * output / (2.0 * second_ord_lim)
    return stopping_dist if output > 0.0 else -stopping_dist


def shape_ang_vel(target, desired, accel_max, dt):
    """``input_shaping_ang_vel`` with no input time constant: slew ``target`` toward ``desired``
    [rad/s] at no more than ``accel_max`` [rad/s^2] (0 = no limit)."""
    if accel_max > 0.0:
        d = accel_max * dt
        lo, hi = target - d, target + d
        return lo if desired < lo else (hi if desired > hi else desired)
    return desired


def shape_angle(error_angle, input_tc, accel_max, target_ang_vel, desired_ang_vel, dt):
    """``input_shaping_angle``: angular velocity [rad/s] that brings an angle error [rad] to rest with
    limited deceleration and an exponential tail of time constant ``input_tc`` [s]."""
    desired_ang_vel += sqrt_controller(error_angle, 1.0 / max(input_tc, 0.01), accel_max, dt)
    return shape_ang_vel(target_ang_vel, desired_ang_vel, accel_max, dt)


def lowpass_alpha(cutoff_hz, dt):
    """Discrete first-order low-pass gain for cutoff [Hz] at step dt [s] (1 = no filtering)."""
    if cutoff_hz <= 0.0:
        return 1.0
    rc = 1.0 / (2.0 * math.pi * cutoff_hz)
    return dt / (dt + rc)
