"""Plain (fixed-gain) super-twisting sliding-mode controller, the paper's "STSM" without adaptation.

Per axis (docs/design-decisions.md, CTL-6; Levant's algorithm in the paper's notation, k2 = beta / 2):

    sigma = e_dot + Lambda e                                   (eq. 19)
    v     = -k1 sqrt|sigma| sgn(sigma) + nu        [rad/s^2]   (eq. 25 with alpha = k1)
    nu   <- nu - T k2 sgn(sigma)                                (explicit Euler, ZOH; nu(0) = 0)
    u     = u_eq + I0 v                            [N m]

Default gains (docs/design-decisions.md, CTL-6): k1 = 1.5 sqrt(C), k2 = 1.1 C with C = 10 D, D = 0.5 N m / I0_ii
(corrected inertia). With ``torque_limit_enabled``: u clipped, nu frozen while it would push further into
saturation and |nu| <= tau_max / I0 (anti-windup, docs/design-decisions.md, CTL-9).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .controller_interface import TrackingError
from .single_sample import AxisState, clip, elementwise, outputs, root, sgn, where
from .sliding_surface import SlidingModeController, batch_zeros, check_dt, equivalent_control_axis, pushes_further, sliding_variable


@dataclass(frozen=True)
class StsmGains:
    """surface_slope [1/s] (3,); k1 [rad^0.5 s^-1.5] (3,); k2 [rad/s^3] (3,); torque limit [N m] (3,)."""

    surface_slope: tuple[float, float, float]
    k1: tuple[float, float, float]
    k2: tuple[float, float, float]
    torque_limit_enabled: bool
    torque_limit_nm: tuple[float, float, float]


def stsm_switching_term(sigma, nu, k1):
    """v = -k1 sqrt|sigma| sgn(sigma) + nu  [rad/s^2]."""
    return nu - k1 * root(abs(sigma)) * sgn(sigma)


def stsm_integrate(sigma, nu, k2, dt_s, freeze=None, nu_limit=None):
    """nu_{k+1} = nu_k - T k2 sgn(sigma_k), optionally frozen (mask) and clipped to +-nu_limit."""
    dnu = -dt_s * k2 * sgn(sigma)
    if freeze is not None:
        dnu = where(freeze, 0.0, dnu)
    nu_next = nu + dnu
    return nu_next if nu_limit is None else clip(nu_next, -nu_limit, nu_limit)


def stsm_law(e, edot, acc, omega_a, omega_b, nu, inertia, lam, gyro, limit, nu_limit, k1, k2, dt_s):
    """One sample per axis (module docstring; floats of one axis or arrays (..., 3)): (sigma, u_eq, u_d, u, nu_{k+1});
    with a torque limit nu is frozen while it would push u further into saturation (CTL-9)."""
    sigma = sliding_variable(e, edot, lam)
    u_eq = equivalent_control_axis(inertia, lam, edot, acc, gyro, omega_a, omega_b)
    u_d = inertia * stsm_switching_term(sigma, nu, k1)
    u_raw = u_eq + u_d
    u = u_raw if limit is None else clip(u_raw, -limit, limit)
    freeze = None if limit is None else pushes_further(u != u_raw, u_raw, -sgn(sigma))
    return sigma, u_eq, u_d, u, stsm_integrate(sigma, nu, k2, dt_s, freeze, nu_limit)


class StsmController(SlidingModeController):
    """Fixed-gain super-twisting baseline behind the AttitudeController protocol (see module docstring)."""

    name = "stsm"
    summary = "Super-twisting sliding mode with fixed gains (Levant tuning k1 = 1.5 sqrt C, k2 = 1.1 C)"
    default_config = "stsm.yaml"
    nu = AxisState()  # super-twisting integral state nu (..., 3) [rad/s^2]; an array when read

    gains_type = StsmGains

    def _setup_gains(self) -> None:
        self._k1 = np.asarray(self.gains.k1, dtype=float)
        self._k2 = np.asarray(self.gains.k2, dtype=float)

    def _on_inertia(self) -> None:
        self._nu_limit = None if self._limit is None else self._limit / self.inertia_diag  # [rad/s^2]

    def _float_constants(self) -> tuple:
        return (self.inertia_diag, self._lam, self._gyro, self._limit, self._nu_limit, self._k1, self._k2)

    def set_gains(self, k1=None, k2=None) -> None:
        """Replace k1/k2 by arrays broadcastable to batch_shape + (3,) (batched gain sweeps, e.g. claim C8).

        Values must be finite and >= 0 (ValueError otherwise); state is not reset.
        """
        for name, value in (("k1", k1), ("k2", k2)):
            if value is None:
                continue
            arr = np.broadcast_to(np.asarray(value, dtype=float), self.batch_shape + (3,)).copy()
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
            setattr(self, f"_{name}", arr)
        self._cache_floats()

    def reset(self) -> None:
        """nu = 0 on every axis."""
        self.nu = batch_zeros(self.batch_shape)
        zero = batch_zeros(self.batch_shape)
        self._diag = {"sigma": zero, "nu": zero, "u_eq": zero, "u_d": zero, "u": zero}

    def update(self, err: TrackingError, dt_s: float) -> np.ndarray:
        """One sample: body torque u [N m, FRD] (..., 3). Raises ValueError for dt_s <= 0."""
        dt = check_dt(dt_s)
        nu_k = self._nu
        sigma, u_eq, u_d, u, self._nu = elementwise(stsm_law, self._single, *self._law_inputs(err), nu_k, *self._constants, dt)
        self._diag, u = outputs(self._single, {"sigma": sigma, "nu": nu_k, "u_eq": u_eq, "u_d": u_d, "u": u})
        return u

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """sigma [rad/s], nu [rad/s^2] (value used for the output), u_eq, u_d, u [N m] per axis."""
        return self._diag
