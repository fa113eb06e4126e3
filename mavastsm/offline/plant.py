"""Batched rigid-body attitude plant for the offline paper simulator (pure NumPy, no I/O).

    I omega_dot = -omega x (I omega) + u + d        [N m, body FRD]   (paper eqs. 6-7, 12-14)
    Theta_dot   = E(Theta) omega                    (exact ZYX kinematics, inverse of eq. 1)
    Theta_dot   = omega                             (option: the paper's simplification, X2 = Theta_dot)

I is the full 3x3 true inertia of each run (parametric variation gives products of inertia).
Integrated with classic fixed-step RK4 (no variable-step solver: sign functions would make results depend
on solver tolerances, docs/design-decisions.md, CTL-8); the control torque u is held over the step (ZOH) and the
disturbance d is evaluated at the RK4 stage times t, t + h/2, t + h.

Layout (chosen for speed: per-call NumPy overhead dominates at small batch sizes, so rows of a
component are kept contiguous): the state of n runs is ``x`` (6, n) = [roll, pitch, yaw, p, q, r]
[rad, rad/s]; torques are (3, n) [N m]; inertia and its inverse are (3, 3, n) [kg m^2, 1/(kg m^2)].
"""

from __future__ import annotations

import numpy as np

from ..frames import euler_rates_axis_first


def attitude_derivative(x, torque_nm, inertia, inertia_inv, out, exact_kinematics: bool = True):
    """Write x_dot = [Theta_dot, omega_dot] (6, n) into ``out`` and return it; torque = u + d (3, n).

    ``inertia`` may carry the cyclic rows [0 1 2 0 1] of I (5, 3, n) (``Rk4AttitudePlant.inertia5``) so that I omega
    comes out as the cyclic [h0 h1 h2 h0 h1] the cross product needs; (3, 3, n) works too. Every element is computed
    by the same operations in the same order either way. Theta_dot is eq. 1 inverted by ``frames`` (the one copy).
    """
    w = x[3:6]
    h5 = np.einsum("ijn,jn->in", inertia, w)  # I omega
    if h5.shape[0] == 3:
        h5 = np.concatenate((h5, h5[:2]))
    w5 = np.concatenate((w, w[:2]))  # [p q r p q], cyclic rows
    gyro = w5[1:4] * h5[2:5]
    gyro -= w5[2:5] * h5[1:4]  # omega x (I omega), no fancy indexing (cheaper)
    np.einsum("ijn,jn->in", inertia_inv, np.subtract(torque_nm, gyro, out=gyro), out=out[3:6])
    if not exact_kinematics:
        out[0:3] = w
        return out
    euler_rates_axis_first(x[0:3], w, out=out[0:3])  # the one kinematics (frames), written in place
    return out


class Rk4AttitudePlant:
    """RK4 integrator for n runs with per-run true inertia (3, 3) [kg m^2]; holds its scratch buffers.

    Per step it makes few, whole-batch NumPy calls (the batch's cost is mostly per call, docs/sweep.md "Speed"):
    preallocated stage buffers, ``out=`` writes, I omega with the cyclic rows the cross product needs."""

    def __init__(self, inertia_n33, exact_kinematics: bool = True):
        inertia = np.asarray(inertia_n33, dtype=float)
        self.inertia = np.ascontiguousarray(inertia.transpose(1, 2, 0))
        self.inertia5 = np.ascontiguousarray(self.inertia[[0, 1, 2, 0, 1]])
        self.inertia_inv = np.ascontiguousarray(np.linalg.inv(inertia).transpose(1, 2, 0))
        self.exact_kinematics = exact_kinematics
        n = inertia.shape[0]
        self._k = [np.empty((6, n)) for _ in range(4)]
        self._stage = np.empty((6, n))
        self._torque = np.empty((3, n))

    def step(self, x, control_nm, dist_start_nm, dist_mid_nm, dist_end_nm, h_s: float):
        """One RK4 step of length h_s [s]: u (3, n) held, d (3, n) at t, t + h/2, t + h. Returns new x (6, n)."""
        k1, k2, k3, k4 = self._k
        xs, tq = self._stage, self._torque
        f, ex, i5, iinv = attitude_derivative, self.exact_kinematics, self.inertia5, self.inertia_inv
        f(x, np.add(control_nm, dist_start_nm, out=tq), i5, iinv, k1, ex)
        np.add(control_nm, dist_mid_nm, out=tq)
        np.multiply(k1, 0.5 * h_s, out=xs)
        f(np.add(x, xs, out=xs), tq, i5, iinv, k2, ex)
        np.multiply(k2, 0.5 * h_s, out=xs)
        f(np.add(x, xs, out=xs), tq, i5, iinv, k3, ex)
        np.multiply(k3, h_s, out=xs)
        f(np.add(x, xs, out=xs), np.add(control_nm, dist_end_nm, out=tq), i5, iinv, k4, ex)
        acc = k2 + k3
        acc *= 2.0
        np.add(k1, acc, out=acc)
        acc += k4
        acc *= h_s / 6.0
        return np.add(x, acc, out=acc)
