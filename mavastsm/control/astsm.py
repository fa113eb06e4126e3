"""Adaptive Super-Twisting Sliding Mode (ASTSM) attitude controller of Hoang & Pham (2018).

Per axis i (three independent scalar laws; coupling counts as perturbation):

    sigma = e_dot + lambda e                                        (eq. 19)
    u     = u_eq + u_D,  u_eq = I0 (Theta_ddot_d - Lambda e_dot) + omega x I0 omega   (eqs. 24, 26, 27)
    v     = -alpha sqrt|sigma| sgn(sigma) + nu                      (eq. 25)
    nu   <- nu - T (beta / 2) sgn(sigma)                            (eq. 25, explicit Euler, ZOH)
    beta  = 2 epsilon alpha + beta_offset                           (eq. 35; beta_offset = 0 in the paper)
    alpha_dot = varpi sqrt(gamma1 / 2) sgn(|sigma| - mu)  if alpha > alpha_m,  else eta   (eq. 34)
    alpha <- clip(alpha + T alpha_dot, alpha_m, alpha_max)          (clamp: docs/design-decisions.md, CTL-7)
    u_D   = v            (gain_units = torque: the literal paper, eq. 26)
    u_D   = I0_ii v      (gain_units = accel: Shtessel's b0-normalised form, v in rad/s^2)

Update order per sample (docs/design-decisions.md, CTL-7): compute sigma_k; output u_k with (alpha_k, nu_k); then update
nu and alpha. sgn(0) = 0. With ``torque_limit_enabled`` the output is clipped per axis and, while an axis
is saturated, nu is frozen when it would push further into saturation and alpha may not grow
(conditional integration, docs/design-decisions.md, CTL-9); |nu| is clipped to the torque limit (in the units of v).

Not in the paper (our choices, documented in docs/reproduction.md): mu, alpha_max, alpha(0) = alpha_m,
nu(0) = 0, the clamp, and the gain-units choice. Presets in configs/controllers:
``astsm.yaml`` (default, "E1": accel units, varpi = 1000, 1 kHz), ``astsm_paper.yaml`` ("P": Table 2 in
torque units, needs a quasi-continuous controller period <= 0.1 ms), ``astsm_400hz.yaml`` ("E2": accel
units, mu = 0.03 for a 2.5 ms period).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .controller_interface import AdaptiveGain, TrackingError
from .single_sample import AxisState, clip, elementwise, outputs, root, sgn, where
from .sliding_surface import SlidingModeController, batch_zeros, check_dt, equivalent_control_axis, pushes_further, sliding_variable


@dataclass(frozen=True)
class AstsmGains:
    """ASTSM parameters (YAML keys == field names; units and paper symbols in the YAML).

    surface_slope [1/s] (3,) Lambda; varpi [-] and gamma1 [-] (adaptation speed varpi sqrt(gamma1/2)
    [1/s in alpha's units]); epsilon [-]; eta [alpha units / s]; alpha_min, alpha_max [alpha units] (3,);
    mu [rad/s] (3,); beta_offset [beta units]; gain_units 'torque' | 'accel'; torque limit [N m] (3,).
    alpha_min, alpha_max and mu are per axis (a scalar in the YAML applies to all three): the band an
    adaptive gain can hold depends on each axis's loop delay (docs/bridge.md, "Adaptive gain and loop delay").
    """

    surface_slope: tuple[float, float, float]
    varpi: float
    gamma1: float
    epsilon: tuple[float, float, float]
    eta: float
    alpha_min: tuple[float, float, float]
    alpha_max: tuple[float, float, float]
    mu: tuple[float, float, float]
    beta_offset: float
    gain_units: str
    torque_limit_enabled: bool
    torque_limit_nm: tuple[float, float, float]

    @property
    def adaptation_rate(self) -> float:
        """varpi sqrt(gamma1 / 2): |alpha_dot| above alpha_m (eq. 34) [alpha units / s]."""
        return self.varpi * float(np.sqrt(self.gamma1 / 2.0))

    def validate(self) -> list[tuple[str, str]]:
        if not all(lo < hi for lo, hi in zip(self.alpha_min, self.alpha_max)):
            return [("alpha_max", f"must be > alpha_min = {list(self.alpha_min)} on every axis")]
        if any(x <= 0 for x in self.torque_limit_nm):
            return [("torque_limit_nm", "every axis limit must be > 0")]
        return []


def astsm_switching_term(sigma, alpha, nu, sign_sigma):
    """v = -alpha sqrt|sigma| sgn(sigma) + nu  (eq. 25), per axis. Units of alpha, nu (torque or accel)."""
    return nu - alpha * root(abs(sigma)) * sign_sigma


def astsm_adapt(sigma, alpha, nu, dt_s, sign_sigma, saturated, u_raw, nu_limit, epsilon, alpha_min, alpha_max, mu, rate, eta,
                beta_offset):
    """One explicit-Euler step of nu (eq. 25) and alpha (eq. 34, clamped) with beta from eq. 35, per axis.

    ``saturated``: None (no torque limit) or whether u was clipped; then nu is frozen where it would push ``u_raw``
    further into saturation and alpha may not grow (conditional integration, CTL-9). ``nu_limit``: bound on |nu|
    (units of v) or None. ``rate`` = varpi sqrt(gamma1 / 2). Returns (alpha_{k+1}, nu_{k+1}, beta used in this step).
    """
    beta = 2.0 * epsilon * alpha + beta_offset
    dnu = (-0.5 * dt_s) * beta * sign_sigma
    if saturated is not None:
        dnu = where(pushes_further(saturated, u_raw, -sign_sigma), 0.0, dnu)
    nu_next = nu + dnu
    if nu_limit is not None:
        nu_next = clip(nu_next, -nu_limit, nu_limit)
    alpha_dot = where(alpha > alpha_min, rate * sgn(abs(sigma) - mu), eta)
    if saturated is not None:
        alpha_dot = where(saturated & (alpha_dot > 0.0), 0.0, alpha_dot)
    return clip(alpha + dt_s * alpha_dot, alpha_min, alpha_max), nu_next, beta


def astsm_law(e, edot, acc, omega_a, omega_b, alpha, nu, inertia, lam, gyro, limit, nu_limit, epsilon, alpha_min, alpha_max, mu,
              accel, rate, eta, beta_offset, dt_s):
    """One sample per axis in the update order of the module docstring (floats of one axis or arrays (..., 3)):
    (sigma, u_eq, u_d, u, beta, alpha_{k+1}, nu_{k+1}); the output uses (alpha_k, nu_k)."""
    sigma = sliding_variable(e, edot, lam)
    u_eq = equivalent_control_axis(inertia, lam, edot, acc, gyro, omega_a, omega_b)
    s = sgn(sigma)
    v = astsm_switching_term(sigma, alpha, nu, s)
    u_d = inertia * v if accel else v
    u_raw = u_eq + u_d
    u = u_raw if limit is None else clip(u_raw, -limit, limit)
    saturated = None if limit is None else u != u_raw
    alpha_next, nu_next, beta = astsm_adapt(sigma, alpha, nu, dt_s, s, saturated, u_raw, nu_limit, epsilon, alpha_min,
                                            alpha_max, mu, rate, eta, beta_offset)
    return sigma, u_eq, u_d, u, beta, alpha_next, nu_next


def sampling_warnings(gains: AstsmGains, dt_s: float) -> list[str]:
    """Known ways a preset fails at controller period ``dt_s`` [s] (rules: docs/design-decisions.md, CTL-7, and our runs).

    * mu below max(0.005, 10 T) rad/s: the sampling ripple of sigma keeps |sigma| > mu, alpha winds up;
    * torque units (the literal Table 2 law) above T = 0.5 ms: the adaptation runs away and the input chatters.
    """
    out = []
    need = max(0.005, 10.0 * dt_s)
    if min(gains.mu) < need:
        out.append(f"mu = {min(gains.mu):g} rad/s is below ~10 T = {need:g} rad/s at T = {dt_s * 1e3:g} ms: expect alpha wind-up and chattering")
    if gains.gain_units == "torque" and dt_s > 5e-4:
        out.append(f"gain_units = torque (Table 2 literally) needs T <= 0.5 ms; at T = {dt_s * 1e3:g} ms alpha runs away")
    return out


class AstsmController(SlidingModeController):
    """ASTSM (Hoang & Pham 2018, eqs. 18-27, 34, 35) behind the AttitudeController protocol.

    Parameters
    ----------
    gains : AstsmGains (from a preset: ``from_config("astsm", "astsm_paper", model, {"mu": 0.03})``)
    model : SoloRigidBody (its ``inertia_diag`` I0 [kg m^2] is the controller's model)
    batch_shape : leading shape of the inputs, () for one vehicle
    """

    name = "astsm"
    summary = "Adaptive super-twisting SMC (Hoang & Pham 2018, eqs. 25, 34, 35); alpha clamped, nu anti-windup"
    default_config = "astsm.yaml"
    alpha = AxisState()  # adaptive gain alpha (..., 3) [units of v]; an array when read
    nu = AxisState()  # super-twisting integral state nu (..., 3) [units of v]; an array when read

    gains_type = AstsmGains

    def _setup_gains(self) -> None:
        self._accel = self.gains.gain_units == "accel"
        self._adaptation_rate = self.gains.adaptation_rate
        self._diag: Mapping[str, np.ndarray] = {}

    def _on_inertia(self) -> None:
        # nu is clipped in the gains' units: torque [N m], or acceleration [rad/s^2] = limit / I0
        self._nu_limit = None if self._limit is None else (self._limit / self.inertia_diag if self._accel else self._limit)

    def _float_constants(self) -> tuple:
        g = self.gains
        return (self.inertia_diag, self._lam, self._gyro, self._limit, self._nu_limit, np.asarray(g.epsilon, dtype=float),
                np.asarray(g.alpha_min, dtype=float), np.asarray(g.alpha_max, dtype=float), np.asarray(g.mu, dtype=float))

    def adaptive_gain(self) -> AdaptiveGain:
        """alpha's clamp and mu per axis; alpha is in rad/s^2 (accel units) or N m (torque units, eq. 26)."""
        g = self.gains
        scale = (1.0, 1.0, 1.0) if self._accel else tuple(np.asarray(self.inertia_diag, dtype=float).reshape(-1)[:3].tolist())
        return AdaptiveGain(tuple(g.alpha_min), tuple(g.alpha_max), tuple(g.mu), scale)

    def limit_overrides(self, torque_limit_nm=None, adaptive_gain_range=None, integral_off=None) -> dict[str, Any]:
        """Torque clip (``torque_limit_*``), alpha's clamp (``alpha_min``, ``alpha_max``) and, per axis, the
        super-twisting integral nu off (``epsilon`` 0 on that axis: beta = 2 epsilon alpha = 0, eq. 35)."""
        out = super().limit_overrides(torque_limit_nm)
        if adaptive_gain_range is not None:
            lo, hi = adaptive_gain_range
            out.update({"alpha_min": [float(x) for x in lo], "alpha_max": [float(x) for x in hi]})
        if integral_off is not None and any(integral_off):
            out["epsilon"] = [0.0 if off else float(e) for e, off in zip(self.gains.epsilon, integral_off)]
        return out

    def reset(self) -> None:
        """alpha = alpha_m, nu = 0 on every axis (alpha(0), nu(0): docs/design-decisions.md, CTL-7)."""
        self.alpha = batch_zeros(self.batch_shape) + np.asarray(self.gains.alpha_min)
        self.nu = batch_zeros(self.batch_shape)
        zero = batch_zeros(self.batch_shape)
        self._diag = {"sigma": zero, "alpha": self.alpha, "beta": zero, "nu": zero, "u_eq": zero, "u_d": zero, "u": zero}

    def update(self, err: TrackingError, dt_s: float) -> np.ndarray:
        """One sample: body torque u [N m, FRD] (..., 3). Raises ValueError for dt_s <= 0."""
        dt = check_dt(dt_s)
        alpha_k, nu_k = self._alpha, self._nu
        g = self.gains
        sigma, u_eq, u_d, u, beta, self._alpha, self._nu = elementwise(
            astsm_law, self._single, *self._law_inputs(err), alpha_k, nu_k, *self._constants, self._accel,
            self._adaptation_rate, g.eta, g.beta_offset, dt)
        self._diag, u = outputs(self._single, {"sigma": sigma, "alpha": alpha_k, "beta": beta, "nu": nu_k, "u_eq": u_eq,
                                               "u_d": u_d, "u": u})
        return u

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """Internals of the last update, per axis: sigma [rad/s], alpha, beta, nu (values used for the
        output), u_eq, u_d, u [N m]. Zeros (alpha = alpha_m) before the first update."""
        return self._diag
