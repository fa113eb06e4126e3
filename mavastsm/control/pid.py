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
from .single_sample import AxisState, axis_floats, clip, elementwise, outputs, sgn, where
from .sliding_surface import batch_zeros, check_dt, floats3, torque_limit_or_none


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


def _euler_rate_target(angle_error_rad, angle_p, ref_euler_rate_rads):
    """K_ang (Theta_d - Theta) + ff Theta_dot_d [rad/s], per axis (ref None: no feed-forward)."""
    target = -angle_p * angle_error_rad
    return (target if ref_euler_rate_rads is None else target + ref_euler_rate_rads,)


def pid_rate_target(euler_rad, angle_error_rad, ref_euler_rate_rads, angle_p, feedforward: bool, single: bool = False):
    """omega_d [rad/s, body FRD] = W(Theta) (K_ang (Theta_d - Theta) + ff Theta_dot_d); arrays (..., 3), or 3-tuples of
    floats when ``single`` (eq. 1 through the kinematics of that shape)."""
    (target,) = elementwise(_euler_rate_target, single, angle_error_rad, angle_p, ref_euler_rate_rads if feedforward else None)
    if single:
        return body_rates_from_euler_rates_floats(euler_rad[0], euler_rad[1], *target)
    return body_rates_from_euler_rates(euler_rad, target)


def pid_law(rate_target, omega, rate_error_prev, derivative, integrator, kp, ki, kd, imax, scale, limit, dt_s, d_filter_hz,
            output_clip: bool):
    """The rate PID per axis (module docstring; floats of one axis or arrays (..., 3)): (e_w, D, I, u_n, u). The
    integrator is updated before the output is formed and, with the output clip, held where it would wind further
    (AC_PID "limit"); rate_error_prev None (the first sample) leaves D as it is."""
    e_w = rate_target - omega
    if rate_error_prev is not None:
        a = dt_s / (dt_s + 1.0 / (2.0 * math.pi * d_filter_hz))
        derivative = derivative + a * ((e_w - rate_error_prev) / dt_s - derivative)
    pd = kp * e_w + kd * derivative
    i_new = clip(integrator + ki * e_w * dt_s, -imax, imax)
    if output_clip:
        raw = pd + i_new
        i_new = where((abs(raw) > 1.0) & (sgn(i_new - integrator) * raw > 0.0), integrator, i_new)
    u_norm = pd + i_new
    if output_clip:
        u_norm = clip(u_norm, -1.0, 1.0)
    u = scale * u_norm if limit is None else clip(scale * u_norm, -limit, limit)
    return e_w, derivative, i_new, u_norm, u


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
        constants = (self._kang, self._kp, self._ki, self._kd, self._imax, self._scale, self._limit)
        self._c = tuple(floats3(x) for x in constants) if self._single else constants  # 3-tuples of floats for one sample
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
        g, single = self.gains, self._single
        vec = axis_floats if single else np.asarray
        euler, w = vec(err.euler_rad), vec(err.body_rates_rads)
        ref_rate = None if err.ref_euler_rate_rads is None else vec(err.ref_euler_rate_rads)
        if g.rate_feedforward_enabled and ref_rate is None:  # Theta_dot_d = Theta_dot - e_dot
            rates = euler_rates_from_body_rates_floats(euler[0], euler[1], *w) if single else euler_rates_from_body_rates(euler, w)
            (ref_rate,) = elementwise(lambda r, e_dot: (r - e_dot,), single, rates, vec(err.euler_rate_error_rads))
        kang, *gains = self._c
        rate_target = pid_rate_target(euler, vec(err.angle_error_rad), ref_rate, kang, g.rate_feedforward_enabled, single)
        e_w, self._derivative, self._integrator, u_norm, u = elementwise(
            pid_law, single, rate_target, w, self._rate_error_prev, self._derivative, self._integrator, *gains, dt, g.d_filter_hz,
            g.output_clip_enabled)
        self._rate_error_prev = e_w
        self._diag, u = outputs(single, {"rate_target": rate_target, "rate_error": e_w, "integrator": self._integrator,
                                         "derivative": self._derivative, "u_norm": u_norm, "u": u})
        return u

    def diagnostics(self) -> Mapping[str, np.ndarray]:
        """rate_target, rate_error [rad/s]; integrator, derivative, u_norm [-]; u [N m] per axis."""
        return self._diag


class PidFairController(PidController):
    """The same cascade with IMAX = 1 and no output clip (docs/design-decisions.md, CTL-4 "PID-fair")."""

    name = "pid_fair"
    summary = "ArduCopter-style cascade with IMAX = 1 and no output clip (a fairer baseline under disturbance)"
    default_config = "pid_fair.yaml"
