"""Frames, attitude kinematics and angle conventions (pure NumPy, no I/O).

Conventions used everywhere in mavastsm (and by MAVLink / ArduPilot / PX4):

* World frame **NED** (x north, y east, z down). Body frame **FRD** (x forward, y right, z down).
* Euler angles are **ZYX intrinsic** (yaw psi, then pitch theta, then roll phi), rotating NED into FRD.
  Arrays of Euler angles are ordered ``[roll, pitch, yaw]`` in rad.
  Positive roll = right side down; positive pitch = nose up; positive yaw = nose east of north
  (clockwise seen from above).
* Body rates ``omega = [p, q, r]`` in rad/s are angular velocity in FRD body axes (what MAVLink
  ATTITUDE.rollspeed/pitchspeed/yawspeed and SET_ATTITUDE_TARGET.body_*_rate carry).
  **Euler rates** ``[phi_dot, theta_dot, psi_dot]`` are different quantities; convert with
  :func:`euler_rates_from_body_rates` / :func:`body_rates_from_euler_rates`.
* Quaternions are scalar-first ``[w, x, y, z]`` and rotate NED -> FRD (MAVLink's convention).

Every NumPy function accepts arrays whose last axis has length 3 (or 4 for quaternions) and
broadcasts over leading axes, so a batch of simulations can share one call. The ``q_*`` functions at the end
are the same quaternion algebra on plain float tuples ``(w, x, y, z)``, for the loops that run per sample
(the sim's 400 Hz autopilot, the bridge's autopilot-target model): one copy, used by both, tested here
against the NumPy functions and hand-computed values (tests/unit/test_frames.py).
"""

from __future__ import annotations

import math

import numpy as np

AXES = ("roll", "pitch", "yaw")  # the order of every per-axis tuple: Euler [phi, theta, psi], body [p, q, r]
TWO_PI = 2.0 * np.pi


def wrap_angle(angle_rad):
    """Wrap an angle [rad] into (-pi, pi]. Used for the yaw error e_psi."""
    return np.pi - np.mod(np.pi - np.asarray(angle_rad, dtype=float), TWO_PI)


def wrap_angle_float(angle_rad: float) -> float:
    """Scalar twin of :func:`wrap_angle` for one Python float [rad] -> (-pi, pi] (same operations)."""
    return math.pi - (math.pi - angle_rad) % TWO_PI


def euler_rate_matrix(euler_rad):
    """W(Theta): body rates = W @ Euler rates (the paper's eq. 1, with the missing ``Theta_dot`` factor).

    omega = [[1, 0, -s_theta], [0, c_phi, c_theta s_phi], [0, -s_phi, c_theta c_phi]] @ Theta_dot

    Parameters
    ----------
    euler_rad : [rad] array (..., 3), [roll, pitch, yaw]

    Returns
    -------
    array (..., 3, 3)
    """
    e = np.asarray(euler_rad, dtype=float)
    sphi, cphi = np.sin(e[..., 0]), np.cos(e[..., 0])
    sth, cth = np.sin(e[..., 1]), np.cos(e[..., 1])
    zero, one = np.zeros_like(sphi), np.ones_like(sphi)
    return np.stack(
        [
            np.stack([one, zero, -sth], axis=-1),
            np.stack([zero, cphi, cth * sphi], axis=-1),
            np.stack([zero, -sphi, cth * cphi], axis=-1),
        ],
        axis=-2,
    )


def body_rates_from_euler_rates(euler_rad, euler_rate_rads):
    """omega [rad/s, body FRD] from Euler rates [rad/s] at attitude ``euler_rad`` (eq. 1)."""
    e = np.asarray(euler_rad, dtype=float)
    d = np.asarray(euler_rate_rads, dtype=float)
    sphi, cphi = np.sin(e[..., 0]), np.cos(e[..., 0])
    sth, cth = np.sin(e[..., 1]), np.cos(e[..., 1])
    p = d[..., 0] - d[..., 2] * sth
    q = d[..., 1] * cphi + d[..., 2] * cth * sphi
    r = -d[..., 1] * sphi + d[..., 2] * cth * cphi
    return np.stack([p, q, r], axis=-1)


def euler_rates_from_body_rates(euler_rad, body_rates_rads):
    """Euler rates [rad/s] from body rates omega [rad/s, FRD]; inverse of eq. 1.

    phi_dot   = p + (q s_phi + r c_phi) tan(theta)
    theta_dot = q c_phi - r s_phi
    psi_dot   = (q s_phi + r c_phi) / cos(theta)

    Singular at |pitch| = 90 deg (assumption A.5 of the paper keeps us away from it).
    """
    e = np.moveaxis(np.asarray(euler_rad, dtype=float), -1, 0)
    w = np.moveaxis(np.asarray(body_rates_rads, dtype=float), -1, 0)
    return np.moveaxis(euler_rates_axis_first(e, w), 0, -1)


def euler_rates_axis_first(euler_rad, body_rates_rads, out=None):
    """:func:`euler_rates_from_body_rates` on arrays stored axis-first, (3, ...) [rad] and [rad/s], written into
    ``out`` (3, ...) when given (the batched plant's stage buffer: no array is stacked per call) and returned.
    The same operations in the same order, so the same floats."""
    sphi, cphi = np.sin(euler_rad[0]), np.cos(euler_rad[0])
    cth, tth = np.cos(euler_rad[1]), np.tan(euler_rad[1])
    p, q, r = body_rates_rads[0], body_rates_rads[1], body_rates_rads[2]
    qs_rc = q * sphi + r * cphi
    if out is None:
        out = np.empty((3,) + np.shape(qs_rc))
    np.add(p, qs_rc * tth, out=out[0, ...])  # [i, ...]: a view even of a single sample's (3,)
    np.subtract(q * cphi, r * sphi, out=out[1, ...])
    np.divide(qs_rc, cth, out=out[2, ...])
    return out


def _nan_if_inf(angle_rad: float) -> float:
    return math.nan if math.isinf(angle_rad) else angle_rad


def euler_rates_from_body_rates_floats(roll_rad: float, pitch_rad: float, p: float, q: float, r: float) -> tuple[float, float, float]:
    """Scalar twin of :func:`euler_rates_from_body_rates` for one sample (floats, same operation order).

    Inverse of eq. 1; body rates p, q, r [rad/s, FRD] -> (phi_dot, theta_dot, psi_dot) [rad/s].
    An infinite angle gives NaN like ``np.sin`` (``math.sin`` would raise).
    """
    roll_rad, pitch_rad = _nan_if_inf(roll_rad), _nan_if_inf(pitch_rad)
    sphi, cphi = math.sin(roll_rad), math.cos(roll_rad)
    qs_rc = q * sphi + r * cphi
    return p + qs_rc * math.tan(pitch_rad), q * cphi - r * sphi, qs_rc / math.cos(pitch_rad)


def body_rates_from_euler_rates_floats(roll_rad: float, pitch_rad: float, phi_dot: float, theta_dot: float, psi_dot: float) -> tuple[float, float, float]:
    """Scalar twin of :func:`body_rates_from_euler_rates` for one sample (eq. 1; floats, same operation order).

    An infinite angle gives NaN like ``np.sin`` (``math.sin`` would raise).
    """
    roll_rad, pitch_rad = _nan_if_inf(roll_rad), _nan_if_inf(pitch_rad)
    sphi, cphi = math.sin(roll_rad), math.cos(roll_rad)
    sth, cth = math.sin(pitch_rad), math.cos(pitch_rad)
    return phi_dot - psi_dot * sth, theta_dot * cphi + psi_dot * cth * sphi, -theta_dot * sphi + psi_dot * cth * cphi


def quaternion_from_euler(euler_rad):
    """Quaternion [w, x, y, z] (NED -> FRD) from ZYX Euler angles [roll, pitch, yaw] in rad."""
    e = np.asarray(euler_rad, dtype=float) * 0.5
    cr, sr = np.cos(e[..., 0]), np.sin(e[..., 0])
    cp, sp = np.cos(e[..., 1]), np.sin(e[..., 1])
    cy, sy = np.cos(e[..., 2]), np.sin(e[..., 2])
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def euler_from_quaternion(q_wxyz):
    """ZYX Euler angles [roll, pitch, yaw] in rad from a quaternion [w, x, y, z] (NED -> FRD).

    The quaternion need not be normalised. Pitch is clipped to [-pi/2, pi/2] at the singularity.
    """
    q = np.asarray(q_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def rotation_frd2ned_from_quaternion(q_wxyz):
    """Rotation matrix R (3x3) taking body-FRD vectors into NED: v_ned = R @ v_frd."""
    q = np.asarray(q_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def quaternion_multiply(a_wxyz, b_wxyz):
    """Hamilton product a * b of scalar-first quaternions."""
    a = np.asarray(a_wxyz, dtype=float)
    b = np.asarray(b_wxyz, dtype=float)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


# ---------------------------------------------------------------- quaternions on plain floats (per-sample loops)
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
