"""Parts shared by the sliding-mode family: the manifold (eq. 19), the equivalent control (eqs. 24/27),
torque saturation with its anti-windup masks (docs/design-decisions.md, CTL-9), and the set-up every sliding-mode
controller class shares (``SlidingModeController``).

Pure functions on arrays of shape (..., 3) (per axis roll, pitch, yaw); no I/O (the gains come as an object;
reading them from YAML is ``mavastsm.control.from_config``'s job).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .controller_interface import torque_limit_overrides
from .single_sample import axis_floats


def sliding_variable(angle_error_rad, euler_rate_error_rads, surface_slope):
    """sigma = e_dot + Lambda e  [rad/s]  (paper eq. 19), per axis.

    Parameters
    ----------
    angle_error_rad : [rad] (..., 3) e = Theta - Theta_d (yaw wrapped)
    euler_rate_error_rads : [rad/s] (..., 3) e_dot = Theta_dot - Theta_dot_d
    surface_slope : [1/s] (3,) Lambda diagonal
    """
    return euler_rate_error_rads + surface_slope * angle_error_rad


def equivalent_control_axis(inertia_diag, surface_slope, euler_rate_error_rads, ref_euler_accel_radss, gyro_coef, omega_a, omega_b):
    """u_eq = I0 (Theta_ddot_d - Lambda e_dot) + coef omega_a omega_b  [N m] (eqs. 24, 27) per axis, for one law written
    once for both shapes (``single_sample.elementwise``): floats of one axis or arrays (..., 3). ``omega_a``,
    ``omega_b`` = [q, r, p], [r, p, q] (:func:`cyclic_rate_pairs`), so coef omega_a omega_b = omega x (I0 omega)."""
    return inertia_diag * (ref_euler_accel_radss - surface_slope * euler_rate_error_rads) + gyro_coef * omega_a * omega_b


def gyroscopic_coefficients(inertia_diag):
    """[Izz - Iyy, Ixx - Izz, Iyy - Ixx] [kg m^2] (..., 3): omega x (I0 omega) = coef * [q r, p r, p q]."""
    i = np.asarray(inertia_diag, dtype=float)
    return np.stack([i[..., 2] - i[..., 1], i[..., 0] - i[..., 2], i[..., 1] - i[..., 0]], axis=-1)


def cyclic_rate_pairs(body_rates_rads) -> tuple:
    """([q, r, p], [r, p, q]) of body rates omega = [p, q, r] (..., 3): coef * first * second = omega x (I0 omega)."""
    w5 = np.concatenate((body_rates_rads, body_rates_rads[..., :2]), axis=-1)  # [p q r p q]: no fancy indexing
    return w5[..., 1:4], w5[..., 2:5]


def pushes_further(saturated, u_raw, direction):
    """Mask of axes where an integrator moving in ``direction`` would push u deeper into saturation.

    Conditional integration (anti-windup, docs/design-decisions.md, CTL-9): freeze the state on those axes.
    """
    if saturated is None:
        return None
    return saturated & (direction * u_raw > 0.0)


def floats3(array_or_none) -> tuple | None:
    """(3,) constant (gain, limit, inertia) as a 3-tuple of floats for the single-sample path; None stays None."""
    return None if array_or_none is None else tuple(np.asarray(array_or_none, dtype=float).reshape(3).tolist())


def check_dt(dt_s: float) -> float:
    """Reject a non-positive or non-finite controller period [s] with ValueError (contract)."""
    dt = float(dt_s)
    if not (0.0 < dt < math.inf):
        raise ValueError(f"dt_s must be a finite time > 0 s, got {dt_s!r}")
    return dt


def torque_limit_or_none(enabled: bool, limit_nm) -> np.ndarray | None:
    """(3,) per-axis torque limit [N m] when enabled, else None."""
    return np.asarray(limit_nm, dtype=float) if enabled else None


def batch_zeros(batch_shape: tuple) -> np.ndarray:
    """Zero state array of shape batch_shape + (3,), stored axis-first like the simulator's batches
    (``frames.euler_rates_axis_first``): a state in another layout than its inputs makes every elementwise operation slow."""
    return np.moveaxis(np.zeros((3,) + tuple(batch_shape)), 0, -1)


class SlidingModeController:
    """Set-up shared by the sliding-mode laws (SMC, STSM, ATSM, ASTSM); the law itself is the subclass's.

    Built from a gains object (``gains_type``) and a model, and keeps the surface slope
    Lambda [1/s] (``_lam``), the optional torque limit [N m] (``_limit``, None when disabled), the nominal
    inertia I0 [kg m^2] (``inertia_diag``) with its gyroscopic coefficients (``_gyro``, eq. 17), and, for
    ``batch_shape == ()``, the constants as float 3-tuples (``_f``) for the single-sample path. A law written once
    per axis runs as ``elementwise(law, self._single, *self._law_inputs(err), <state>, *self._constants, ...)``.

    Subclasses set ``gains_type``, ``default_config``, ``name`` and ``summary``, and override:
    ``_setup_gains()`` for their own gain arrays, ``_on_inertia()`` for what depends on I0 (e.g. a limit in
    acceleration units), ``_float_constants()`` (the arrays behind ``_f``, in the order their single-sample
    law unpacks them) and ``reset()``.
    """

    gains_type: type
    default_config: str

    def __init__(self, gains, model, batch_shape: tuple = ()):
        """``gains``: a ``gains_type`` object; ``model``: the vehicle model (its ``inertia_diag`` I0 [kg m^2]);
        ``batch_shape``: leading shape of the inputs, () for one vehicle."""
        self.gains = gains
        self.batch_shape = tuple(batch_shape)
        self._lam = np.asarray(self.gains.surface_slope, dtype=float)
        self._limit = torque_limit_or_none(self.gains.torque_limit_enabled, self.gains.torque_limit_nm)
        self._setup_gains()
        self.set_model_inertia(model.inertia_diag)
        self.reset()

    def _setup_gains(self) -> None:
        """The law's own gain arrays from ``self.gains`` (called once, before the inertia is set)."""

    def _on_inertia(self) -> None:
        """Recompute what depends on the nominal inertia ``self.inertia_diag`` (called on every change)."""

    def _float_constants(self) -> tuple:
        """The law's constants, arrays (3,) or None, in the order its law takes them; ``self._constants`` holds them
        as float 3-tuples (also ``self._f``) for a single sample, as they are otherwise."""
        return (self.inertia_diag, self._lam, self._gyro, self._limit)

    def _cache_floats(self) -> None:
        self._single = self.batch_shape == ()
        if self._single:
            self._f = tuple(floats3(a) for a in self._float_constants())
        self._constants = self._f if self._single else self._float_constants()  # what a law written once reads

    def _law_inputs(self, err) -> tuple:
        """(e, e_dot, Theta_ddot_d, omega_a, omega_b) for a law written once (``single_sample.elementwise``): 3-tuples
        of floats for a single sample, else arrays (..., 3); omega_a, omega_b = [q, r, p], [r, p, q] (eq. 17's pairs)."""
        if self._single:
            p, q, r = axis_floats(err.body_rates_rads)
            return (axis_floats(err.angle_error_rad), axis_floats(err.euler_rate_error_rads), axis_floats(err.ref_euler_accel_radss),
                    (q, r, p), (r, p, q))
        return (err.angle_error_rad, err.euler_rate_error_rads, err.ref_euler_accel_radss, *cyclic_rate_pairs(err.body_rates_rads))

    def adaptive_gain(self):
        """None: the switching gain of this law does not adapt (ASTSM overrides)."""
        return None

    def limit_overrides(self, torque_limit_nm=None, adaptive_gain_range=None, integral_off=None) -> dict[str, Any]:
        """Every sliding-mode law has the torque clip with anti-windup (``torque_limit_enabled``); see the protocol."""
        return torque_limit_overrides(torque_limit_nm)

    def set_model_inertia(self, inertia_diag) -> None:
        """Use another nominal inertia I0 [kg m^2], (3,) or per batch row (..., 3) (batched model variants)."""
        self.inertia_diag = np.asarray(inertia_diag, dtype=float)
        self._gyro = gyroscopic_coefficients(self.inertia_diag)
        self._on_inertia()
        self._cache_floats()

    def reset(self) -> None:
        raise NotImplementedError
