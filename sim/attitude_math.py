"""Tiny quaternion and shaping helpers on plain floats for the 400 Hz autopilot loop.

Quaternions are tuples ``(w, x, y, z)``; attitude quaternions rotate NED -> FRD (body-to-NED
rotation matrix), as in ``mavastsm.frames`` (which works on NumPy arrays and is too slow per call
for the inner loop; tests check the two agree).
"""

from __future__ import annotations

import math


def q_mul(a, b):
    """Hamilton product a (x) b."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def q_conj(a):
    """Conjugate (inverse of a unit quaternion)."""
    return (a[0], -a[1], -a[2], -a[3])


def q_normalize(a):
    """a / |a| (identity if |a| is zero or not finite)."""
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3])
    if not (n > 0.0 and math.isfinite(n)):
        return (1.0, 0.0, 0.0, 0.0)
    return (a[0] / n, a[1] / n, a[2] / n, a[3] / n)


def q_from_rotation_vector(vx, vy, vz):
    """Quaternion of a rotation by angle |v| [rad] about axis v (body frame)."""
    ang = math.sqrt(vx * vx + vy * vy + vz * vz)
    if ang < 1e-12:
        return (1.0, 0.5 * vx, 0.5 * vy, 0.5 * vz)
    s = math.sin(0.5 * ang) / ang
    return (math.cos(0.5 * ang), vx * s, vy * s, vz * s)


def q_to_rotation_vector(a):
    """Rotation vector [rad] (axis * angle, angle in [0, pi]) of quaternion a (shortest path)."""
    w, x, y, z = a
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-12:
        return (2.0 * x, 2.0 * y, 2.0 * z)
    k = 2.0 * math.atan2(n, w) / n
    return (x * k, y * k, z * k)


def q_rotate_inverse(a, vx, vy, vz):
    """Express vector v (given in the frame a rotates into) in a's source frame: conj(a) v a."""
    w, x, y, z = a
    # R(a)^T v, with R the body->parent rotation matrix of a
    return (
        (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y + w * z) * vy + 2 * (x * z - w * y) * vz,
        2 * (x * y - w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z + w * x) * vz,
        2 * (x * z + w * y) * vx + 2 * (y * z - w * x) * vy + (1 - 2 * (x * x + y * y)) * vz,
    )


def q_rotate(a, vx, vy, vz):
    """Rotate vector v by quaternion a: R(a) v (a vector of a's body frame expressed in its parent)."""
    w, x, y, z = a
    return (
        (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - w * z) * vy + 2 * (x * z + w * y) * vz,
        2 * (x * y + w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - w * x) * vz,
        2 * (x * z - w * y) * vx + 2 * (y * z + w * x) * vy + (1 - 2 * (x * x + y * y)) * vz,
    )


def q_from_euler(roll, pitch, yaw):
    """NED->FRD quaternion from ZYX Euler angles [rad]."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def q_to_euler(a):
    """ZYX Euler angles (roll, pitch, yaw) [rad] of a NED->FRD quaternion."""
    w, x, y, z = a
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    s = 2.0 * (w * y - z * x)
    pitch = math.asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def sqrt_controller(error, p, second_ord_lim, dt):
    """ArduPilot's ``sqrt_controller`` (AP_Math/control.cpp): P near zero, sqrt (constant deceleration)
    far away, and never more than ``|error| / dt`` so it cannot overshoot in one step."""
    if second_ord_lim <= 0.0:
        correction = error * p
    elif p == 0.0:
        correction = math.copysign(math.sqrt(2.0 * second_ord_lim * abs(error)), error)
    else:
        linear_dist = second_ord_lim / (p * p)
        if error > linear_dist:
            correction = math.sqrt(2.0 * second_ord_lim * (error - linear_dist / 2.0))
        elif error < -linear_dist:
            correction = -math.sqrt(2.0 * second_ord_lim * (-error - linear_dist / 2.0))
        else:
            correction = error * p
    if dt > 0.0:
        lim = abs(error) / dt
        correction = min(max(correction, -lim), lim)
    return correction


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
