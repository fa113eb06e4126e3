"""Accelerated twisting sliding-mode controller ("ATSM"): a RECONSTRUCTION, not the paper's law.

The paper compares against an "ATSM" from its reference [15] but gives neither its equations nor gains.
Its Fig. 5 shows the ATSM input chattering with high amplitude and frequency, so the law acts directly
on the torque (discontinuous). We implement (docs/design-decisions.md, CTL-1) a twisting law with fixed-time
("accelerating") terms that grow with |sigma| and |sigma_dot|:

    sigma       = e_dot + Lambda e                                             (eq. 19)
    sigma_dot_k = LPF_fc[(sigma_k - sigma_{k-1}) / T]        (first-order filter, fc = 100 Hz)
    v           = -(r1 + k1 |sigma|) sgn(sigma) - (r2 + k2 |sigma_dot|) sgn(sigma_dot)   [rad/s^2]
    u           = u_eq + I0 v                                                   [N m]

Conditions: r1 > r2 > 0 and r1 - r2 > D (D = d_max / I0_ii, the matched perturbation in accel units).
Defaults for d_max = 0.5 N m, corrected inertia: r1 = 1.25 D / 0.7 + 10, r2 = 0.3 r1, k1 = 10 1/s, k2 = 0.
State: sigma_{k-1} and the filtered sigma_dot (the first sample uses a zero difference).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .controller_interface import TrackingError
from .single_sample import AxisState, clip, elementwise, outputs, sgn
from .sliding_surface import SlidingModeController, batch_zeros, check_dt, equivalent_control_axis, sliding_variable


@dataclass(frozen=True)
class AtsmGains:
    """surface_slope [1/s]; r1, r2 [rad/s^2]; k1 [1/s^2 * s = 1/s]; k2 [1/s]; derivative_cutoff_hz [Hz];
    torque limit [N m]. Vectors are (3,) per axis."""

    surface_slope: tuple[float, float, float]
    r1: tuple[float, float, float]
    r2: tuple[float, float, float]
    k1: tuple[float, float, float]
    k2: tuple[float, float, float]
    derivative_cutoff_hz: float
    torque_limit_enabled: bool
    torque_limit_nm: tuple[float, float, float]

    def validate(self) -> list[tuple[str, str]]:
        if any(a <= b for a, b in zip(self.r1, self.r2)):
            return [("r1", f"must be > r2 = {list(self.r2)} on every axis (twisting condition)")]
        return []


def atsm_switching_term(sigma, sigma_dot, r1, r2, k1, k2):
    """v = -(r1 + k1|sigma|) sgn(sigma) - (r2 + k2|sigma_dot|) sgn(sigma_dot)  [rad/s^2]."""
    return -(r1 + k1 * abs(sigma)) * sgn(sigma) - (r2 + k2 * abs(sigma_dot)) * sgn(sigma_dot)


def filtered_derivative(x, x_prev, y_prev, dt_s: float, cutoff_hz: float):
    """First-order low-pass of the backward difference (x - x_prev)/T: y += a (raw - y), a = T/(T + 1/(2 pi fc))."""
    a = dt_s / (dt_s + 1.0 / (2.0 * math.pi * cutoff_hz))
    return y_prev + a * ((x - x_prev) / dt_s - y_prev)


def atsm_law(e, edot, acc, omega_a, omega_b, sigma_prev, sigma_dot, inertia, lam, gyro, limit, r1, r2, k1, k2, dt_s, cutoff_hz):
    """One sample per axis (module docstring; floats of one axis or arrays (..., 3)): (sigma, sigma_dot, u_eq, u_d, u);
    sigma_prev None (the first sample) is a zero difference."""
    sigma = sliding_variable(e, edot, lam)
    sigma_dot = filtered_derivative(sigma, sigma if sigma_prev is None else sigma_prev, sigma_dot, dt_s, cutoff_hz)
    u_eq = equivalent_control_axis(inertia, lam, edot, acc, gyro, omega_a, omega_b)
    u_d = inertia * atsm_switching_term(sigma, sigma_dot, r1, r2, k1, k2)
    u = u_eq + u_d if limit is None else clip(u_eq + u_d, -limit, limit)
    return sigma, sigma_dot, u_eq, u_d, u


class AtsmController(SlidingModeController):
    """Reconstructed ATSM baseline behind the AttitudeController protocol (see module docstring)."""

    name = "atsm"
    summary = "Accelerated twisting SMC, RECONSTRUCTED (paper gives no law): -(r1+k1|s|)sgn s - (r2+k2|s'|)sgn s'"
    default_config = "atsm.yaml"
    sigma_prev = AxisState()  # sigma at the previous sample (..., 3) [rad/s], None before the first
    sigma_dot = AxisState()  # filtered sigma derivative (..., 3) [rad/s^2]

    gains_type = AtsmGains

    def _setup_gains(self) -> None:
        g = self.gains
        self._r1, self._r2 = np.asarray(g.r1, dtype=float), np.asarray(g.r2, dtype=float)
        self._k1, self._k2 = np.asarray(g.k1, dtype=float), np.asarray(g.k2, dtype=float)

    def _float_constants(self) -> tuple:
        return (self.inertia_diag, self._lam, self._gyro, self._limit, self._r1, self._r2, self._k1, self._k2)

    def reset(self) -> None:
        """Forget sigma_{k-1} and the filtered derivative."""
        self.sigma_prev = None
        self.sigma_dot = batch_zeros(self.batch_shape)
        zero = batch_zeros(self.batch_shape)
        self._diag = {"sigma": zero, "sigma_dot": zero, "u_eq": zero, "u_d": zero, "u": zero}

    def update(self, err: TrackingError, dt_s: float) -> np.ndarray:
        """One sample: body torque u [N m, FRD] (..., 3). Raises ValueError for dt_s <= 0."""
        dt = check_dt(dt_s)
        sigma, self._sigma_dot, u_eq, u_d, u = elementwise(atsm_law, self._single, *self._law_inputs(err), self._sigma_prev, self._sigma_dot,
                                                           *self._constants, dt, self.gains.derivative_cutoff_hz)
        self._sigma_prev = sigma
        self._diag, u = outputs(self._single, {"sigma": sigma, "sigma_dot": self._sigma_dot, "u_eq": u_eq, "u_d": u_d, "u": u})
        return u

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """sigma [rad/s], sigma_dot [rad/s^2] (filtered), u_eq, u_d, u [N m] per axis."""
        return self._diag
