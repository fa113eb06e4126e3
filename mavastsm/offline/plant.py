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

from ..frames import euler_rates_from_body_rates


def attitude_derivative(x, torque_nm, inertia, inertia_inv, out, exact_kinematics: bool = True):
    """Write x_dot = [Theta_dot, omega_dot] (6, n) into ``out`` and return it; torque = u + d (3, n)."""
    w = x[3:6]
    iw = np.einsum("ijn,jn->in", inertia, w)  # I omega
    w5, h5 = np.concatenate((w, w[:2])), np.concatenate((iw, iw[:2]))  # [p q r p q], cyclic rows
    gyro = w5[1:4] * h5[2:5] - w5[2:5] * h5[1:4]  # omega x (I omega), no fancy indexing (cheaper)
    out[3:6] = np.einsum("ijn,jn->in", inertia_inv, torque_nm - gyro)
    if not exact_kinematics:
        out[0:3] = w
        return out
    out[0:3] = euler_rates_from_body_rates(x[0:3].T, w.T).T  # the one kinematics (frames), on (n, 3) views
    return out


class Rk4AttitudePlant:
    """RK4 integrator for n runs with per-run true inertia (3, 3) [kg m^2]; holds its scratch buffers."""

    def __init__(self, inertia_n33, exact_kinematics: bool = True):
        inertia = np.asarray(inertia_n33, dtype=float)
        self.inertia = np.ascontiguousarray(inertia.transpose(1, 2, 0))
        self.inertia_inv = np.ascontiguousarray(np.linalg.inv(inertia).transpose(1, 2, 0))
        self.exact_kinematics = exact_kinematics
        n = inertia.shape[0]
        self._k = [np.empty((6, n)) for _ in range(4)]

    def step(self, x, control_nm, dist_start_nm, dist_mid_nm, dist_end_nm, h_s: float):
        """One RK4 step of length h_s [s]: u (3, n) held, d (3, n) at t, t + h/2, t + h. Returns new x (6, n)."""
        k1, k2, k3, k4 = self._k
        f, ex = attitude_derivative, self.exact_kinematics
        f(x, control_nm + dist_start_nm, self.inertia, self.inertia_inv, k1, ex)
        mid = control_nm + dist_mid_nm
        f(x + (0.5 * h_s) * k1, mid, self.inertia, self.inertia_inv, k2, ex)
        f(x + (0.5 * h_s) * k2, mid, self.inertia, self.inertia_inv, k3, ex)
        f(x + h_s * k3, control_nm + dist_end_nm, self.inertia, self.inertia_inv, k4, ex)
        return x + (h_s / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
