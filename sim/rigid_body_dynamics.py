"""6-DoF rigid-body dynamics of the multirotor (pure math, plain floats for speed).

Frames: world **NED**, body **FRD**; attitude quaternion ``[w, x, y, z]`` rotating NED -> FRD
(equivalently R(q) maps body vectors into NED, ``mavastsm.frames.rotation_frd2ned_from_quaternion``).

State vector ``x`` (13 floats)::

    x[0:3]   position_ned      [m]
    x[3:6]   velocity_ned      [m/s]
    x[6:10]  q_wxyz            [-]     unit quaternion
    x[10:13] omega_frd         [rad/s] body rates p, q, r

Input vector ``u`` (10 floats, held constant over one step)::

    u[0:3]   force_frd         [N]     propulsive force in body axes (thrust is -z)
    u[3:6]   torque_frd        [N m]   motor torques + external disturbance torque
    u[6]     rotor_momentum_z  [kg m^2/s] sum of rotor angular momenta along body +z (down)
    u[7:10]  wind_ned          [m/s]   air velocity for the translational drag

Equations (paper eqs. 6-10 without the small-angle Euler simplification)::

    p_dot     = v
    m v_dot   = R(q) f + m g e_z - c_lin (v - wind)
    q_dot     = 1/2 q (x) [0, omega]
    I omega_dot = tau - omega x (I omega)  [tau_b, eq. 7]
                      - omega x (0, 0, h_r) [tau_p, eq. 8: = (I_r Omega_r q, -I_r Omega_r p, 0) with h_r = -I_r Omega_r]
                      - k_a omega |omega|   [tau_a, eq. 9, signed so it opposes rotation]

The full 3x3 inertia is used (symmetric, positive definite), so a payload's products of inertia
(paper Table 3) couple the axes.

Ground contact is handled by :func:`resolve_ground_contact` after each step: the vehicle cannot sink
below the ground plane, does not bounce, and rests level (legs) at its current heading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

STATE_SIZE = 13
INPUT_SIZE = 10


@dataclass(frozen=True)
class RigidBodyParams:
    """Constants of :func:`state_derivative`.

    Attributes
    ----------
    mass_kg : [kg]
    gravity_ms2 : [m/s^2] along NED +z
    inertia : [kg m^2] 3x3 (row-major tuple of tuples), body FRD
    drag_torque_coeff : [N m s^2/rad^2] (3,) k_a (paper eq. 9); zeros switch tau_a off
    linear_drag_coeff : [N s/m] (3,) per NED axis
    gyroscopic : include the propeller gyroscopic torque tau_p (paper eq. 8)
    """

    mass_kg: float
    gravity_ms2: float
    inertia: tuple
    drag_torque_coeff: tuple = (0.0, 0.0, 0.0)
    linear_drag_coeff: tuple = (0.0, 0.0, 0.0)
    gyroscopic: bool = True

    @property
    def inertia_inverse(self) -> tuple:
        """[1/(kg m^2)] 3x3 inverse of ``inertia`` (computed once, cached by callers)."""
        return invert_3x3(self.inertia)


def invert_3x3(m):
    """Inverse of a 3x3 matrix given as nested sequences (cofactor formula); raises on singular."""
    (a, b, c), (d, e, f), (g, h, i) = m
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if abs(det) < 1e-300:
        raise ValueError("inertia matrix is singular")
    s = 1.0 / det
    return (
        ((e * i - f * h) * s, (c * h - b * i) * s, (b * f - c * e) * s),
        ((f * g - d * i) * s, (a * i - c * g) * s, (c * d - a * f) * s),
        ((d * h - e * g) * s, (b * g - a * h) * s, (a * e - b * d) * s),
    )


def state_derivative(t, x, u, params: RigidBodyParams, inertia_inverse=None):
    """Time derivative of the state (see module docstring). Pure; returns a list of 13 floats.

    Parameters
    ----------
    t : [s] time (unused: the model is time-invariant; inputs carry any time dependence)
    x : (13,) state
    u : (10,) input, held constant
    params : constants
    inertia_inverse : optional precomputed inverse of ``params.inertia`` (speed)
    """
    ii = inertia_inverse or params.inertia_inverse
    return _derivative(x, u, params.mass_kg, params.gravity_ms2, params.inertia, ii,
                       params.drag_torque_coeff, params.linear_drag_coeff, params.gyroscopic)


def _derivative(x, u, m, g, inertia, ii, ka, cl, gyroscopic):
    _, _, _, vn, ve, vd, qw, qx, qy, qz, p, q, r = x
    fx, fy, fz, tx, ty, tz, hz, wn, we, wd = u
    # Rotation body->NED from q (unit).
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz = qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    inv_m = 1.0 / m
    an = ((1.0 - 2.0 * (yy + zz)) * fx + 2.0 * (xy - wz) * fy + 2.0 * (xz + wy) * fz - cl[0] * (vn - wn)) * inv_m
    ae = (2.0 * (xy + wz) * fx + (1.0 - 2.0 * (xx + zz)) * fy + 2.0 * (yz - wx) * fz - cl[1] * (ve - we)) * inv_m
    ad = (2.0 * (xz - wy) * fx + 2.0 * (yz + wx) * fy + (1.0 - 2.0 * (xx + yy)) * fz - cl[2] * (vd - wd)) * inv_m + g
    # Quaternion kinematics q_dot = 0.5 q (x) (0, omega).
    dqw = 0.5 * (-qx * p - qy * q - qz * r)
    dqx = 0.5 * (qw * p + qy * r - qz * q)
    dqy = 0.5 * (qw * q - qx * r + qz * p)
    dqz = 0.5 * (qw * r + qx * q - qy * p)
    # Euler's equation with full inertia.
    (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = inertia
    hx = i00 * p + i01 * q + i02 * r
    hy = i10 * p + i11 * q + i12 * r
    hzb = i20 * p + i21 * q + i22 * r
    mx = tx - (q * hzb - r * hy) - ka[0] * p * abs(p)
    my = ty - (r * hx - p * hzb) - ka[1] * q * abs(q)
    mz = tz - (p * hy - q * hx) - ka[2] * r * abs(r)
    if gyroscopic:
        # tau_p = -omega x (0, 0, hz) = (-q hz, p hz, 0)
        mx -= q * hz
        my += p * hz
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = ii
    return [
        vn, ve, vd, an, ae, ad, dqw, dqx, dqy, dqz,
        j00 * mx + j01 * my + j02 * mz,
        j10 * mx + j11 * my + j12 * mz,
        j20 * mx + j21 * my + j22 * mz,
    ]


def rk4_step(x, u, dt_s, params: RigidBodyParams, inertia_inverse=None, t=0.0):
    """One classical Runge-Kutta step of :func:`state_derivative` with ``u`` held constant.

    The quaternion is renormalised afterwards. Returns a new list of 13 floats.
    """
    ii = inertia_inverse or params.inertia_inverse
    m, g, inertia = params.mass_kg, params.gravity_ms2, params.inertia
    ka, cl, gy = params.drag_torque_coeff, params.linear_drag_coeff, params.gyroscopic
    h2 = 0.5 * dt_s
    k1 = _derivative(x, u, m, g, inertia, ii, ka, cl, gy)
    k2 = _derivative([a + h2 * b for a, b in zip(x, k1)], u, m, g, inertia, ii, ka, cl, gy)
    k3 = _derivative([a + h2 * b for a, b in zip(x, k2)], u, m, g, inertia, ii, ka, cl, gy)
    k4 = _derivative([a + dt_s * b for a, b in zip(x, k3)], u, m, g, inertia, ii, ka, cl, gy)
    h6 = dt_s / 6.0
    out = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
    qw, qx, qy, qz = out[6:10]
    n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    out[6], out[7], out[8], out[9] = qw * n, qx * n, qy * n, qz * n
    return out


def _make_stage_derivative(params: RigidBodyParams):
    """The derivative the RK4 stages of :func:`make_rk4_stepper` evaluate, and the setter of the input it holds:
    ``(load(u), f(vn, ve, vd, qw, qx, qy, qz, p, q, r) -> (an, ae, ad, dqw, dqx, dqy, dqz, dp, dq, dr))``.

    The equations of :func:`state_derivative` (paper eqs. 6-10, module docstring) without the position rates
    (the velocities themselves), with the constants bound once and the input in closure cells that ``load`` sets
    once per step: force per unit mass (body), torque, gyroscopic momentum, wind.
    """
    m_inv = 1.0 / params.mass_kg
    g = params.gravity_ms2
    (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = params.inertia
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = params.inertia_inverse
    kax, kay, kaz = params.drag_torque_coeff
    # translational drag per unit mass [1/s]
    cln, cle, cld = (c * m_inv for c in params.linear_drag_coeff)
    gyro = 1.0 if params.gyroscopic else 0.0
    diagonal = i01 == i02 == i10 == i12 == i20 == i21 == 0.0
    fx = fy = fz = tx = ty = tz = ghz = wn = we = wd = 0.0

    def load(u):
        nonlocal fx, fy, fz, tx, ty, tz, ghz, wn, we, wd
        fx, fy, fz, tx, ty, tz, hz, wn, we, wd = u
        fx, fy, fz, ghz = fx * m_inv, fy * m_inv, fz * m_inv, gyro * hz

    def f(vn, ve, vd, qw, qx, qy, qz, p, q, r):
        an = -cln * (vn - wn)
        ae = -cle * (ve - we)
        ad = g - cld * (vd - wd)
        if fz != 0.0:
            an += 2.0 * (qx * qz + qw * qy) * fz
            ae += 2.0 * (qy * qz - qw * qx) * fz
            ad += (1.0 - 2.0 * (qx * qx + qy * qy)) * fz
        if fx != 0.0 or fy != 0.0:
            xx, yy, zz = qx * qx, qy * qy, qz * qz
            an += (1.0 - 2.0 * (yy + zz)) * fx + 2.0 * (qx * qy - qw * qz) * fy
            ae += 2.0 * (qx * qy + qw * qz) * fx + (1.0 - 2.0 * (xx + zz)) * fy
            ad += 2.0 * (qx * qz - qw * qy) * fx + 2.0 * (qy * qz + qw * qx) * fy
        if diagonal:
            hx, hy, hzb = i00 * p, i11 * q, i22 * r
        else:
            hx = i00 * p + i01 * q + i02 * r
            hy = i10 * p + i11 * q + i12 * r
            hzb = i20 * p + i21 * q + i22 * r
        mx = tx - (q * hzb - r * hy) - kax * p * abs(p) - q * ghz
        my = ty - (r * hx - p * hzb) - kay * q * abs(q) + p * ghz
        mz = tz - (p * hy - q * hx) - kaz * r * abs(r)
        if diagonal:
            dp, dq, dr = j00 * mx, j11 * my, j22 * mz
        else:
            dp = j00 * mx + j01 * my + j02 * mz
            dq = j10 * mx + j11 * my + j12 * mz
            dr = j20 * mx + j21 * my + j22 * mz
        return (an, ae, ad,
                0.5 * (-qx * p - qy * q - qz * r), 0.5 * (qw * p + qy * r - qz * q),
                0.5 * (qw * q - qx * r + qz * p), 0.5 * (qw * r + qx * q - qy * p),
                dp, dq, dr)

    return load, f


def make_rk4_stepper(params: RigidBodyParams):
    """Fast equivalent of :func:`rk4_step` for the 1 kHz loop: ``step(x, u, dt_s) -> new x (list)``.

    Same equations and the same classical RK4 (tests check it against :func:`rk4_step`), written with
    the constants bound once and the stages on plain locals, because per-call overhead dominates at
    this size in CPython. The input ``u`` is held over the step (closure cells of
    :func:`_make_stage_derivative`, set once per step).
    """
    load, f = _make_stage_derivative(params)

    def step(x, u, h):
        load(u)
        pn, pe, pd, vn, ve, vd, qw, qx, qy, qz, p, q, r = x
        a = 0.5 * h
        # stage derivatives: velocities (= position rates) v*, accelerations a*, quaternion rates d*,
        # angular accelerations w*
        an1, ae1, ad1, dw1, dx1, dy1, dz1, wp1, wq1, wr1 = f(vn, ve, vd, qw, qx, qy, qz, p, q, r)
        vn2, ve2, vd2 = vn + a * an1, ve + a * ae1, vd + a * ad1
        an2, ae2, ad2, dw2, dx2, dy2, dz2, wp2, wq2, wr2 = f(
            vn2, ve2, vd2, qw + a * dw1, qx + a * dx1, qy + a * dy1, qz + a * dz1, p + a * wp1, q + a * wq1, r + a * wr1)
        vn3, ve3, vd3 = vn + a * an2, ve + a * ae2, vd + a * ad2
        an3, ae3, ad3, dw3, dx3, dy3, dz3, wp3, wq3, wr3 = f(
            vn3, ve3, vd3, qw + a * dw2, qx + a * dx2, qy + a * dy2, qz + a * dz2, p + a * wp2, q + a * wq2, r + a * wr2)
        vn4, ve4, vd4 = vn + h * an3, ve + h * ae3, vd + h * ad3
        an4, ae4, ad4, dw4, dx4, dy4, dz4, wp4, wq4, wr4 = f(
            vn4, ve4, vd4, qw + h * dw3, qx + h * dx3, qy + h * dy3, qz + h * dz3, p + h * wp3, q + h * wq3, r + h * wr3)
        c = h / 6.0
        qw += c * (dw1 + 2.0 * (dw2 + dw3) + dw4)
        qx += c * (dx1 + 2.0 * (dx2 + dx3) + dx4)
        qy += c * (dy1 + 2.0 * (dy2 + dy3) + dy4)
        qz += c * (dz1 + 2.0 * (dz2 + dz3) + dz4)
        n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        return [
            pn + c * (vn + 2.0 * (vn2 + vn3) + vn4),
            pe + c * (ve + 2.0 * (ve2 + ve3) + ve4),
            pd + c * (vd + 2.0 * (vd2 + vd3) + vd4),
            vn + c * (an1 + 2.0 * (an2 + an3) + an4),
            ve + c * (ae1 + 2.0 * (ae2 + ae3) + ae4),
            vd + c * (ad1 + 2.0 * (ad2 + ad3) + ad4),
            qw * n, qx * n, qy * n, qz * n,
            p + c * (wp1 + 2.0 * (wp2 + wp3) + wp4),
            q + c * (wq1 + 2.0 * (wq2 + wq3) + wq4),
            r + c * (wr1 + 2.0 * (wr2 + wr3) + wr4),
        ]

    return step


def yaw_of(qw, qx, qy, qz):
    """ZYX yaw [rad] of a NED->FRD quaternion."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def resolve_ground_contact(x, ground_down_m):
    """Enforce the ground plane after a step. Returns ``(x, in_contact)`` (x modified in place).

    If the vehicle is at or below the ground (``x[2] >= ground_down_m``) and not moving up, it is
    put on the ground at rest: no sinking, no bounce, velocity and body rates zero, attitude level
    at its current heading (the landing gear levels it). A vehicle whose thrust exceeds its weight
    leaves the ground by itself on the next step, because its derivative points up.
    """
    if x[2] < ground_down_m or x[5] < 0.0:
        return x, False
    yaw = yaw_of(x[6], x[7], x[8], x[9])
    x[2] = ground_down_m
    x[3] = x[4] = x[5] = 0.0
    x[6], x[7], x[8], x[9] = math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)
    x[10] = x[11] = x[12] = 0.0
    return x, True


def initial_state(position_ned_m=(0.0, 0.0, 0.0), yaw_rad=0.0):
    """State at rest, level, at ``position_ned_m`` [m] facing ``yaw_rad`` [rad]."""
    return [float(position_ned_m[0]), float(position_ned_m[1]), float(position_ned_m[2]), 0.0, 0.0, 0.0,
            math.cos(0.5 * yaw_rad), 0.0, 0.0, math.sin(0.5 * yaw_rad), 0.0, 0.0, 0.0]
