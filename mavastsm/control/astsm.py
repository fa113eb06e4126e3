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

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .controller_interface import AdaptiveGain, TrackingError
from .single_sample import NO_LIMIT, AxisState, FloatDiagnostics, axis_floats, clip, sgn
from .sliding_surface import (
    SlidingModeController,
    batch_zeros,
    check_dt,
    equivalent_control,
    equivalent_control_floats,
    pushes_further,
    saturate,
    sliding_variable,
    sliding_variable_floats,
)


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


def astsm_switching_term(sigma, alpha, nu, sign_sigma=None):
    """v = -alpha sqrt|sigma| sgn(sigma) + nu  (eq. 25), per axis. Units of alpha, nu (torque or accel)."""
    s = np.sign(sigma) if sign_sigma is None else sign_sigma
    return nu - alpha * np.sqrt(np.abs(sigma)) * s


def astsm_adapt(sigma, alpha, nu, dt_s, gains: AstsmGains, freeze_nu=None, freeze_alpha_growth=None, nu_limit=None, sign_sigma=None):
    """One explicit-Euler step of nu (eq. 25) and alpha (eq. 34) with beta from eq. 35.

    Parameters
    ----------
    sigma : [rad/s] (..., 3) sliding variable at this sample
    alpha, nu : (..., 3) current gains/state (units of v)
    dt_s : [s] controller period T
    freeze_nu, freeze_alpha_growth : optional boolean masks (..., 3) for conditional integration
    nu_limit : optional (3,) bound on |nu| (units of v)

    Returns
    -------
    (alpha_next, nu_next, beta) ; beta is the value used in this step.
    ``sign_sigma`` may pass a precomputed sgn(sigma).
    """
    s = np.sign(sigma) if sign_sigma is None else sign_sigma
    beta = 2.0 * np.asarray(gains.epsilon) * alpha + gains.beta_offset
    dnu = (-0.5 * dt_s) * beta * s
    if freeze_nu is not None:
        dnu = np.where(freeze_nu, 0.0, dnu)
    nu_next = nu + dnu
    if nu_limit is not None:
        nu_next = np.clip(nu_next, -nu_limit, nu_limit)
    alpha_min, alpha_max = np.asarray(gains.alpha_min), np.asarray(gains.alpha_max)
    alpha_dot = np.where(alpha > alpha_min, gains.adaptation_rate * np.sign(np.abs(sigma) - np.asarray(gains.mu)), gains.eta)
    if freeze_alpha_growth is not None:
        alpha_dot = np.where(freeze_alpha_growth & (alpha_dot > 0.0), 0.0, alpha_dot)
    alpha_next = np.minimum(np.maximum(alpha + dt_s * alpha_dot, alpha_min), alpha_max)  # clamp (np.clip is slower)
    return alpha_next, nu_next, beta


def astsm_switching_term_axis(sigma: float, alpha: float, nu: float, sign_sigma: float) -> float:
    """Scalar twin of :func:`astsm_switching_term` for one axis (floats): v = -alpha sqrt|sigma| sgn(sigma) + nu (eq. 25)."""
    return nu - alpha * math.sqrt(abs(sigma)) * sign_sigma


def astsm_adapt_axis(sigma: float, alpha: float, nu: float, dt_s: float, gains: AstsmGains, freeze_nu: bool, freeze_alpha_growth: bool,
                     nu_limit: float | None, sign_sigma: float, adaptation_rate: float, axis: int) -> tuple[float, float, float]:
    """Scalar twin of :func:`astsm_adapt` for one axis: nu (eq. 25), alpha (eq. 34, clamped), beta (eq. 35).

    Floats in, (alpha_next, nu_next, beta) out; the masks are bools (False = no conditional integration),
    ``adaptation_rate`` = ``gains.adaptation_rate`` precomputed; ``axis`` picks the per-axis mu and alpha bounds.
    """
    alpha_min, alpha_max, mu = gains.alpha_min[axis], gains.alpha_max[axis], gains.mu[axis]
    beta = 2.0 * gains.epsilon[axis] * alpha + gains.beta_offset
    nu_next = nu if freeze_nu else nu + (-0.5 * dt_s) * beta * sign_sigma
    if nu_limit is not None:
        nu_next = clip(nu_next, -nu_limit, nu_limit)
    alpha_dot = adaptation_rate * sgn(abs(sigma) - mu) if alpha > alpha_min else gains.eta
    if freeze_alpha_growth and alpha_dot > 0.0:
        alpha_dot = 0.0
    return clip(alpha + dt_s * alpha_dot, alpha_min, alpha_max), nu_next, beta


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
        return (self.inertia_diag, self._lam, self._gyro, self._limit, self._nu_limit)

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
        if self._single:
            return self._update_single(err, dt)
        sigma = sliding_variable(err.angle_error_rad, err.euler_rate_error_rads, self._lam)
        u_eq = equivalent_control(self.inertia_diag, self._lam, err.euler_rate_error_rads, err.ref_euler_accel_radss, err.body_rates_rads, self._gyro)
        s = np.sign(sigma)
        v = astsm_switching_term(sigma, self.alpha, self.nu, s)
        u_d = self.inertia_diag * v if self._accel else v
        u_raw = u_eq + u_d
        u, saturated = saturate(u_raw, self._limit)
        freeze_nu = pushes_further(saturated, u_raw, -s)
        alpha_k, nu_k = self.alpha, self.nu
        self.alpha, self.nu, beta = astsm_adapt(sigma, alpha_k, nu_k, dt, self.gains, freeze_nu, saturated, self._nu_limit, s)
        self._diag = {"sigma": sigma, "alpha": alpha_k, "beta": beta, "nu": nu_k, "u_eq": u_eq, "u_d": u_d, "u": u}
        return u

    def _update_single(self, err: TrackingError, dt: float) -> np.ndarray:
        """Floats twin of the array update above for batch_shape () (same equations and order, per axis)."""
        inertia, lam, gyro, limit, nu_limit = self._f
        sigma = sliding_variable_floats(axis_floats(err.angle_error_rad), edot := axis_floats(err.euler_rate_error_rads), lam)
        u_eq = equivalent_control_floats(inertia, lam, edot, axis_floats(err.ref_euler_accel_radss), axis_floats(err.body_rates_rads), gyro)
        alpha_k, nu_k = self._alpha, self._nu
        accel, gains, rate = self._accel, self.gains, self._adaptation_rate
        u, u_d, alpha_next, nu_next, beta = [], [], [], [], []
        for axis, (sig, ueq, a_k, n_k, inertia_i, lim, nu_lim) in enumerate(zip(sigma, u_eq, alpha_k, nu_k, inertia, limit or NO_LIMIT, nu_limit or NO_LIMIT)):
            s = sgn(sig)
            v = astsm_switching_term_axis(sig, a_k, n_k, s)
            u_di = inertia_i * v if accel else v
            u_raw = ueq + u_di
            u_i = u_raw if lim is None else clip(u_raw, -lim, lim)
            saturated = lim is not None and u_i != u_raw
            freeze_nu = saturated and -s * u_raw > 0.0  # pushes further into saturation (CTL-9)
            a, n, b = astsm_adapt_axis(sig, a_k, n_k, dt, gains, freeze_nu, saturated, nu_lim, s, rate, axis)
            u.append(u_i), u_d.append(u_di), alpha_next.append(a), nu_next.append(n), beta.append(b)
        self._alpha, self._nu = tuple(alpha_next), tuple(nu_next)
        u = tuple(u)
        self._diag = FloatDiagnostics({"sigma": sigma, "alpha": alpha_k, "beta": tuple(beta), "nu": nu_k, "u_eq": u_eq, "u_d": tuple(u_d), "u": u})
        return np.array(u)

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """Internals of the last update, per axis: sigma [rad/s], alpha, beta, nu (values used for the
        output), u_eq, u_d, u [N m]. Zeros (alpha = alpha_m) before the first update."""
        return self._diag
