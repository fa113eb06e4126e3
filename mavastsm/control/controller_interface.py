"""The one small interface every attitude controller implements, and its input type.

Units: SI. Frames: Euler angles ZYX [roll, pitch, yaw] (NED -> FRD), body rates FRD.
Output: the paper's control input u = [u_phi, u_theta, u_psi] = body torque [N m] (eq. 11, 18).

Arrays broadcast over leading (batch) axes: a controller built for batch shape ``(n,)`` takes
inputs of shape ``(n, 3)`` and returns ``(n, 3)``; the default batch shape ``()`` takes ``(3,)``.
For one sample (every input a 3-vector) ``tracking_error`` and the controllers compute with Python
floats (``single_sample.py``: same equations, ~10x less overhead than NumPy on 3-vectors).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Protocol, runtime_checkable

import numpy as np

from ..frames import euler_rates_from_body_rates, euler_rates_from_body_rates_floats, wrap_angle, wrap_angle_float


@dataclass(frozen=True, slots=True)
class TrackingError:
    """Everything a controller sees at one sample (paper eqs. 15, 19-24).

    Attributes
    ----------
    angle_error_rad : [rad] (..., 3) e = Theta - Theta_d, yaw component wrapped to (-pi, pi]
    euler_rate_error_rads : [rad/s] (..., 3) e_dot = Theta_dot - Theta_dot_d (Euler rates, not body rates)
    ref_euler_accel_radss : [rad/s^2] (..., 3) Theta_ddot_d, feed-forward of eq. 24
    body_rates_rads : [rad/s, body FRD] (..., 3) omega = [p, q, r], used by f(X) (eq. 17) and rate loops
    euler_rad : [rad] (..., 3) measured attitude Theta (for laws that need it, e.g. kinematic maps)
    ref_euler_rate_rads : [rad/s] (..., 3) Theta_dot_d (Euler rates), or None when not supplied; used
        by rate feed-forward (PID). Optional so older call sites stay valid.
    """

    angle_error_rad: np.ndarray
    euler_rate_error_rads: np.ndarray
    ref_euler_accel_radss: np.ndarray
    body_rates_rads: np.ndarray
    euler_rad: np.ndarray
    ref_euler_rate_rads: np.ndarray | None = None


def tracking_error(euler_rad, body_rates_rads, ref_euler_rad, ref_euler_rate_rads=None, ref_euler_accel_radss=None) -> TrackingError:
    """Build a TrackingError from a measurement (attitude, body rates) and a reference.

    The Euler-rate error uses the exact ZYX kinematics (inverse of eq. 1), not omega ~ Theta_dot.
    When every input is a single 3-vector (tuple, list or shape-(3,) array) the floats path
    :func:`tracking_error_single` computes the same values without NumPy per operation.
    """
    single = tracking_error_single(euler_rad, body_rates_rads, ref_euler_rad, ref_euler_rate_rads, ref_euler_accel_radss)
    if single is not None:
        return single
    euler = np.asarray(euler_rad, dtype=float)
    omega = np.asarray(body_rates_rads, dtype=float)
    ref = np.asarray(ref_euler_rad, dtype=float)
    ref_rate = np.zeros_like(ref) if ref_euler_rate_rads is None else np.asarray(ref_euler_rate_rads, dtype=float)
    ref_acc = np.zeros_like(ref) if ref_euler_accel_radss is None else np.asarray(ref_euler_accel_radss, dtype=float)
    e = euler - ref  # a new array: the yaw component is wrapped in place
    e[..., 2] = wrap_angle(e[..., 2])
    edot = euler_rates_from_body_rates(euler, omega) - ref_rate
    return TrackingError(e, edot, np.broadcast_to(ref_acc, e.shape).copy(order="K"), omega, euler, np.broadcast_to(ref_rate, e.shape))


def _three_floats(vec):
    """(a, b, c) as floats when ``vec`` is one 3-vector, else None (batches, wrong shapes, non-numbers)."""
    if type(vec) is np.ndarray and vec.shape != (3,):
        return None  # a batch: never convert it to a list only to find it is not one 3-vector
    try:
        a, b, c = vec.tolist() if type(vec) is np.ndarray else vec
        return float(a), float(b), float(c)
    except (TypeError, ValueError):
        return None


_ZERO3 = (0.0, 0.0, 0.0)


def tracking_error_single(euler_rad, body_rates_rads, ref_euler_rad, ref_euler_rate_rads=None, ref_euler_accel_radss=None) -> TrackingError | None:
    """Floats twin of :func:`tracking_error` for one sample (eq. 15 and the inverse of eq. 1), or None.

    e = Theta - Theta_d (yaw wrapped to (-pi, pi]), e_dot = W^-1(Theta) omega - Theta_dot_d, in the same
    operation order as the array version. Returns None (caller uses the array path) when an input is not a
    single 3-vector.
    """
    both = tracking_error_and_euler_rates(euler_rad, body_rates_rads, ref_euler_rad, ref_euler_rate_rads, ref_euler_accel_radss)
    return None if both is None else both[0]


def tracking_error_and_euler_rates(euler_rad, body_rates_rads, ref_euler_rad, ref_euler_rate_rads=None,
                                   ref_euler_accel_radss=None) -> tuple[TrackingError, tuple[float, float, float]] | None:
    """(TrackingError, Theta_dot [rad/s] as 3 floats) for one sample: the one tracking error of the package (the
    bridge's control cycle needs the Euler rates too). None when an input is not a single 3-vector."""
    euler = _three_floats(euler_rad)
    omega = _three_floats(body_rates_rads)
    ref = _three_floats(ref_euler_rad)
    ref_rate = _ZERO3 if ref_euler_rate_rads is None else _three_floats(ref_euler_rate_rads)
    ref_acc = _ZERO3 if ref_euler_accel_radss is None else _three_floats(ref_euler_accel_radss)
    if euler is None or omega is None or ref is None or ref_rate is None or ref_acc is None:
        return None
    rates = euler_rates_from_body_rates_floats(euler[0], euler[1], *omega)
    e = (euler[0] - ref[0], euler[1] - ref[1], wrap_angle_float(euler[2] - ref[2]))
    edot = (rates[0] - ref_rate[0], rates[1] - ref_rate[1], rates[2] - ref_rate[2])
    arr = np.array
    return TrackingError(arr(e), arr(edot), arr(ref_acc), arr(omega), arr(euler), arr(ref_rate)), rates


Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class AdaptiveGain:
    """A law's adaptive switching gain, as a controller declares it (``AttitudeController.adaptive_gain``).

    alpha_min, alpha_max : per-axis clamp of the gain [the law's gain units]
    mu : [rad/s] per axis, the sigma band the gain adapts towards; None when the law has no such band (the
        bridge then cannot bound the gain by the loop delay and watches it for ADAPTIVE_GAIN_PINNED)
    units_per_accel : per axis, one rad/s^2 of gain in the law's units (1 for a gain in acceleration units,
        I0 [kg m^2] for a gain acting as a torque); the bridge's loop-delay ceiling is computed in rad/s^2
    """

    alpha_min: Vec3
    alpha_max: Vec3
    mu: Vec3 | None = None
    units_per_accel: Vec3 = (1.0, 1.0, 1.0)


@runtime_checkable
class AttitudeController(Protocol):
    """Contract for attitude controllers (see tests/controllers/test_controller_contract.py).

    * ``update(err, dt_s)``: one sample; returns u [N m] (..., 3). ``dt_s`` is the time since the
      previous sample, > 0 (raise ValueError otherwise). Never reads a clock.
    * ``reset()``: restore the state it had right after construction (integrators, adaptive gains).
    * ``diagnostics()``: mapping name -> array (..., 3) of internals after the last update,
      with stable keys. Sliding-mode laws expose at least ``sigma``, ``u_eq``, ``u_d``, ``u``;
      ASTSM adds ``alpha``, ``beta``, ``nu``; PID ``rate_target``, ``integrator``, ... Any key reaches the
      telemetry, the CSV and the dashboard. Missing quantities are simply absent.
    * ``adaptive_gain()``: the law's adaptive switching gain (:class:`AdaptiveGain`), or None when its gains do
      not adapt. The bridge bounds it by the loop delay and watches it for ADAPTIVE_GAIN_PINNED only through this.
    * ``limit_overrides(torque_limit_nm=None, adaptive_gain_range=None, integral_off=None)``: the config overrides
      that make the same law, built again from its preset (``make_controller(..., overrides=...)``), clip its
      torque at ``torque_limit_nm`` [N m] per axis (with its anti-windup), keep its adaptive gain in
      ``(alpha_min, alpha_max)`` per axis and switch its attitude-error integral off on the axes where
      ``integral_off`` is True (M7). A law that has no such limit or integral leaves it out ({} = nothing to set).
      :class:`NoLimits` gives both members for a law with neither.
    """

    name: str

    def update(self, err: TrackingError, dt_s: float) -> np.ndarray: ...

    def reset(self) -> None: ...

    def diagnostics(self) -> Mapping[str, np.ndarray]: ...

    def adaptive_gain(self) -> AdaptiveGain | None: ...

    def limit_overrides(self, torque_limit_nm: Vec3 | None = None, adaptive_gain_range: tuple[Vec3, Vec3] | None = None,
                        integral_off: tuple[bool, bool, bool] | None = None) -> dict[str, Any]: ...


class NoLimits:
    """The two limit members of :class:`AttitudeController` for a law with no torque clip, no adaptive gain and no
    integral the bridge may switch off: inherit it, or write the two methods yourself."""

    def adaptive_gain(self) -> AdaptiveGain | None:
        return None

    def limit_overrides(self, torque_limit_nm=None, adaptive_gain_range=None, integral_off=None) -> dict[str, Any]:
        return {}


def torque_limit_overrides(torque_limit_nm) -> dict[str, Any]:
    """Overrides for the packaged laws' ``torque_limit_enabled`` / ``torque_limit_nm`` keys ({} for None)."""
    if torque_limit_nm is None:
        return {}
    return {"torque_limit_enabled": True, "torque_limit_nm": [float(x) for x in torque_limit_nm]}


PROTOCOL_MEMBERS = ("name", "update", "reset", "diagnostics", "adaptive_gain", "limit_overrides")


def missing_members(controller) -> list[str]:
    """The :class:`AttitudeController` members ``controller`` lacks ([] when it implements the protocol)."""
    return [m for m in PROTOCOL_MEMBERS if not hasattr(controller, m)]
