"""ArduCopter-style cascaded PID attitude controller ("the PID implemented on the Solo" in the paper).

Per axis (docs/design-decisions.md, CTL-4; ArduCopter AC_AttitudeControl + AC_PID, simplified to Euler angles):

    omega_d = W(Theta) [K_ang (Theta_d - Theta) + ff Theta_dot_d]   [rad/s, body FRD]   (angle P loop;
              W maps Euler rates to body rates, eq. 1; ff = rate_feedforward_enabled)
    e_w     = omega_d - omega
    I      <- clip(I + K_I e_w T, +-IMAX)       (normalised units; frozen while the output is clipped
                                                 and the increment would push further: AC_PID "limit")
    D       = LPF_fc[(e_w,k - e_w,k-1) / T]     (fc = d_filter_hz, like ATC_RAT_*_FILT; 0 on the first sample)
    u_n     = clip(K_P e_w + I + K_D D, -1, 1)  (ArduPilot normalised output; clip optional)
    tau     = tau_scale u_n                     [N m]

As in AC_PID the integrator is updated before the output is formed. Gains: Solo_AC35.param (the 2017
Solo firmware). tau_scale = (2.9, 2.9, 0.4) N m maps ArduPilot's normalised output to torque (X-frame
mixer estimate, docs/design-decisions.md, CTL-4). With the stock yaw IMAX the integrator can hold only
0.1 * 0.4 = 0.04 N m of yaw torque, so the AP-faithful PID cannot reject a 0.5 N m yaw disturbance: a
property of the stock tune. ``pid_fair`` (IMAX = 1, no output clip) removes that handicap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..frames import body_rates_from_euler_rates, body_rates_from_euler_rates_floats, euler_rates_from_body_rates, euler_rates_from_body_rates_floats
from .controller_interface import TrackingError, torque_limit_overrides
from .single_sample import AxisState, FloatDiagnostics, axis_floats, clip, sgn
from .sliding_surface import batch_zeros, check_dt, floats3, saturate, torque_limit_or_none


@dataclass(frozen=True)
class PidGains:
    """angle_p [1/s]; rate_p [1/(rad/s)] ; rate_i [1/rad]; rate_d [s/rad] (normalised output per rad/s);
    imax [-]; d_filter_hz [Hz]; torque_scale_nm [N m per unit output]; vectors are (3,) per axis."""

    angle_p: tuple[float, float, float]
    rate_p: tuple[float, float, float]
    rate_i: tuple[float, float, float]
    rate_d: tuple[float, float, float]
    imax: tuple[float, float, float]
    d_filter_hz: float
    torque_scale_nm: tuple[float, float, float]
    output_clip_enabled: bool
    rate_feedforward_enabled: bool
    torque_limit_enabled: bool
    torque_limit_nm: tuple[float, float, float]


def pid_rate_target(euler_rad, angle_error_rad, ref_euler_rate_rads, angle_p, feedforward: bool):
    """omega_d [rad/s, body FRD] = W(Theta) (K_ang (Theta_d - Theta) + ff Theta_dot_d)."""
    euler_rate_target = -angle_p * angle_error_rad
    if feedforward:
        euler_rate_target = euler_rate_target + ref_euler_rate_rads
    return body_rates_from_euler_rates(euler_rad, euler_rate_target)


def pid_rate_target_floats(euler_rad, angle_error_rad, ref_euler_rate_rads, angle_p, feedforward: bool) -> tuple[float, float, float]:
    """Scalar twin of :func:`pid_rate_target` for one sample (3-tuples of floats; eq. 1 via the floats kinematics)."""
    d = [-k * e for k, e in zip(angle_p, angle_error_rad)]
    if feedforward:
        d = [x + r for x, r in zip(d, ref_euler_rate_rads)]
    return body_rates_from_euler_rates_floats(euler_rad[0], euler_rad[1], *d)


class PidController:
    """ArduCopter-style cascade (angle P -> rate PID) behind the AttitudeController protocol."""

    name = "pid"
    summary = "ArduCopter-style cascade: angle P -> rate PID, Solo_AC35 gains, normalised output x tau_scale"
    default_config = "pid.yaml"
    gains_type = PidGains
    integrator = AxisState()  # rate-loop integrator I (..., 3) [normalised output]
    derivative = AxisState()  # filtered rate-error derivative D (..., 3) [rad/s^2]
    rate_error_prev = AxisState()  # e_w at the previous sample (..., 3) [rad/s], None before the first

    def __init__(self, gains: PidGains, model, batch_shape: tuple = ()):
        """``gains``: the cascade's gains; ``model``: the vehicle model (unused: the cascade's output is normalised and
        scaled by ``torque_scale_nm``, not by I0); ``batch_shape``: leading shape of the inputs, () for one vehicle."""
        self.gains = gains
        self.batch_shape = tuple(batch_shape)
        g = self.gains
        self._kang, self._kp = np.asarray(g.angle_p), np.asarray(g.rate_p)
        self._ki, self._kd = np.asarray(g.rate_i), np.asarray(g.rate_d)
        self._imax, self._scale = np.asarray(g.imax), np.asarray(g.torque_scale_nm)
        self._limit = torque_limit_or_none(g.torque_limit_enabled, g.torque_limit_nm)
        self._single = self.batch_shape == ()
        if self._single:  # constants as 3-tuples of floats for the single-sample path
            self._f = tuple(floats3(x) for x in (self._kang, self._kp, self._ki, self._kd, self._imax, self._scale, self._limit))
        self.reset()

    def adaptive_gain(self) -> None:
        """None: the PID's gains are fixed."""
        return None

    def limit_overrides(self, torque_limit_nm=None, adaptive_gain_range=None, integral_off=None) -> dict[str, Any]:
        """The torque clip (``torque_limit_*``, the integrator frozen while it pushes further). Its integrator acts on
        the rate error, not on the attitude error, so ``integral_off`` (M7) leaves it on."""
        return torque_limit_overrides(torque_limit_nm)

    def reset(self) -> None:
        """Integrator, previous rate error and derivative filter back to zero."""
        self.integrator = batch_zeros(self.batch_shape)
        self.derivative = batch_zeros(self.batch_shape)
        self.rate_error_prev = None
        zero = batch_zeros(self.batch_shape)
        self._diag = {"rate_target": zero, "rate_error": zero, "integrator": zero, "derivative": zero, "u_norm": zero, "u": zero}

    def update(self, err: TrackingError, dt_s: float) -> np.ndarray:
        """One sample: body torque u [N m, FRD] (..., 3). Raises ValueError for dt_s <= 0."""
        dt = check_dt(dt_s)
        if self._single:
            return self._update_single(err, dt)
        ref_rate = err.ref_euler_rate_rads
        if self.gains.rate_feedforward_enabled and ref_rate is None:  # Theta_dot_d = Theta_dot - e_dot
            ref_rate = euler_rates_from_body_rates(err.euler_rad, err.body_rates_rads) - err.euler_rate_error_rads
        rate_target = pid_rate_target(err.euler_rad, err.angle_error_rad, ref_rate, self._kang, self.gains.rate_feedforward_enabled)
        e_w = rate_target - err.body_rates_rads
        if self.rate_error_prev is not None:
            a = dt / (dt + 1.0 / (2.0 * np.pi * self.gains.d_filter_hz))
            self.derivative = self.derivative + a * ((e_w - self.rate_error_prev) / dt - self.derivative)
        self.rate_error_prev = e_w
        pd = self._kp * e_w + self._kd * self.derivative
        i_new = np.clip(self.integrator + self._ki * e_w * dt, -self._imax, self._imax)
        if self.gains.output_clip_enabled:
            raw = pd + i_new
            winding = (np.abs(raw) > 1.0) & (np.sign(i_new - self.integrator) * raw > 0.0)
            i_new = np.where(winding, self.integrator, i_new)
        self.integrator = i_new
        u_norm = pd + i_new
        if self.gains.output_clip_enabled:
            u_norm = np.clip(u_norm, -1.0, 1.0)
        u, _ = saturate(self._scale * u_norm, self._limit)
        self._diag = {"rate_target": rate_target, "rate_error": e_w, "integrator": i_new, "derivative": self.derivative, "u_norm": u_norm, "u": u}
        return u

    def _update_single(self, err: TrackingError, dt: float) -> np.ndarray:
        """Floats twin of the array update above for batch_shape () (same equations and order, per axis)."""
        kang, kp, ki, kd, imax, scale, limit = self._f
        g = self.gains
        euler, e, w = axis_floats(err.euler_rad), axis_floats(err.angle_error_rad), axis_floats(err.body_rates_rads)
        ref_rate = None if err.ref_euler_rate_rads is None else axis_floats(err.ref_euler_rate_rads)
        if g.rate_feedforward_enabled and ref_rate is None:  # Theta_dot_d = Theta_dot - e_dot
            rates, edot = euler_rates_from_body_rates_floats(euler[0], euler[1], *w), axis_floats(err.euler_rate_error_rads)
            ref_rate = tuple([rates[i] - edot[i] for i in range(3)])
        rate_target = pid_rate_target_floats(euler, e, ref_rate, kang, g.rate_feedforward_enabled)
        e_w = tuple([rate_target[i] - w[i] for i in range(3)])
        deriv, prev, integ = self._derivative, self._rate_error_prev, self._integrator
        if prev is not None:
            a = dt / (dt + 1.0 / (2.0 * math.pi * g.d_filter_hz))
            deriv = tuple([deriv[i] + a * ((e_w[i] - prev[i]) / dt - deriv[i]) for i in range(3)])
        i_new, u_norm = [], []
        output_clip = g.output_clip_enabled
        for e_wi, d_i, i_k, kp_i, ki_i, kd_i, imax_i in zip(e_w, deriv, integ, kp, ki, kd, imax):
            pd = kp_i * e_wi + kd_i * d_i
            i_i = clip(i_k + ki_i * e_wi * dt, -imax_i, imax_i)
            if output_clip:
                raw = pd + i_i
                if abs(raw) > 1.0 and sgn(i_i - i_k) * raw > 0.0:  # AC_PID limit: no further wind-up
                    i_i = i_k
            out = pd + i_i
            i_new.append(i_i), u_norm.append(clip(out, -1.0, 1.0) if output_clip else out)
        u = tuple([scale[i] * u_norm[i] if limit is None else clip(scale[i] * u_norm[i], -limit[i], limit[i]) for i in range(3)])
        self._derivative, self._rate_error_prev, self._integrator = deriv, e_w, tuple(i_new)
        self._diag = FloatDiagnostics({"rate_target": rate_target, "rate_error": e_w, "integrator": self._integrator, "derivative": deriv,
                                       "u_norm": tuple(u_norm), "u": u})
        return np.array(u)

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """rate_target, rate_error [rad/s]; integrator, derivative, u_norm [-]; u [N m] per axis."""
        return self._diag


class PidFairController(PidController):
    """The same cascade with IMAX = 1 and no output clip (docs/design-decisions.md, CTL-4 "PID-fair")."""

    name = "pid_fair"
    summary = "ArduCopter-style cascade with IMAX = 1 and no output clip (a fairer baseline under disturbance)"
    default_config = "pid_fair.yaml"
