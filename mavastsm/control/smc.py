"""Conventional first-order sliding-mode controller (the paper's "SMC" baseline; gains not published).

Per axis (docs/design-decisions.md, CTL-5; constant + proportional reaching law, Gao-Hung type):

    sigma = e_dot + Lambda e                                  (eq. 19)
    v     = -K sgn(sigma) - Q sigma                 [rad/s^2]
    u     = u_eq + I0 v                             [N m]      (eqs. 24, 26 with u_D = I0 v)

sgn(0) = 0. No boundary layer by default (the paper's point is that SMC chatters); ``boundary_layer``
> 0 replaces sgn(sigma) by sat(sigma / phi) for hardware. Stateless. Default gains (docs/design-decisions.md, CTL-5):
K = 1.25 D + 5 with D = 0.5 N m / I0_ii (corrected inertia), Q = 2 1/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .controller_interface import TrackingError
from .single_sample import clip, elementwise, outputs, sgn
from .sliding_surface import SlidingModeController, batch_zeros, check_dt, equivalent_control_axis, sliding_variable


@dataclass(frozen=True)
class SmcGains:
    """surface_slope [1/s] (3,); switching_gain K [rad/s^2] (3,); proportional_gain Q [1/s] (3,);
    boundary_layer phi [rad/s] (0 = pure sign); torque limit [N m] (3,)."""

    surface_slope: tuple[float, float, float]
    switching_gain: tuple[float, float, float]
    proportional_gain: tuple[float, float, float]
    boundary_layer: float
    torque_limit_enabled: bool
    torque_limit_nm: tuple[float, float, float]


def smc_switching_term(sigma, switching_gain, proportional_gain, boundary_layer: float = 0.0):
    """v = -K sgn(sigma) - Q sigma [rad/s^2]; sgn -> sat(sigma/phi) when boundary_layer phi > 0."""
    s = clip(sigma / boundary_layer, -1.0, 1.0) if boundary_layer > 0.0 else sgn(sigma)
    return -switching_gain * s - proportional_gain * sigma


def smc_law(e, edot, acc, omega_a, omega_b, inertia, lam, gyro, limit, k, q, boundary_layer):
    """One sample per axis (module docstring; floats of one axis or arrays (..., 3)): (sigma, u_eq, u_d, u)."""
    sigma = sliding_variable(e, edot, lam)
    u_eq = equivalent_control_axis(inertia, lam, edot, acc, gyro, omega_a, omega_b)
    u_d = inertia * smc_switching_term(sigma, k, q, boundary_layer)
    u = u_eq + u_d if limit is None else clip(u_eq + u_d, -limit, limit)
    return sigma, u_eq, u_d, u


class SmcController(SlidingModeController):
    """First-order SMC baseline behind the AttitudeController protocol (see module docstring)."""

    name = "smc"
    summary = "First-order sliding mode, v = -K sgn(sigma) - Q sigma (paper's SMC baseline; gains ours)"
    default_config = "smc.yaml"

    gains_type = SmcGains

    def _setup_gains(self) -> None:
        self._k = np.asarray(self.gains.switching_gain, dtype=float)
        self._q = np.asarray(self.gains.proportional_gain, dtype=float)

    def _float_constants(self) -> tuple:
        return (self.inertia_diag, self._lam, self._gyro, self._limit, self._k, self._q)

    def reset(self) -> None:
        """Stateless law: only clears the diagnostics."""
        zero = batch_zeros(self.batch_shape)
        self._diag = {"sigma": zero, "u_eq": zero, "u_d": zero, "u": zero}

    def update(self, err: TrackingError, dt_s: float) -> np.ndarray:
        """One sample: body torque u [N m, FRD] (..., 3). Raises ValueError for dt_s <= 0."""
        check_dt(dt_s)
        sigma, u_eq, u_d, u = elementwise(smc_law, self._single, *self._law_inputs(err), *self._constants, self.gains.boundary_layer)
        self._diag, u = outputs(self._single, {"sigma": sigma, "u_eq": u_eq, "u_d": u_d, "u": u})
        return u

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """sigma [rad/s], u_eq, u_d, u [N m] per axis from the last update."""
        return self._diag
