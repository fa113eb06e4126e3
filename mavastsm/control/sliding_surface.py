"""Parts shared by the sliding-mode family: the manifold (eq. 19), the equivalent control (eqs. 24/27),
torque saturation with its anti-windup masks (control-notes section 2.8), and config loading.

Pure functions on arrays of shape (..., 3) (per axis roll, pitch, yaw); no state, no I/O.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..config_loading import build_dataclass, resolve_config


def sliding_variable(angle_error_rad, euler_rate_error_rads, surface_slope):
    """sigma = e_dot + Lambda e  [rad/s]  (paper eq. 19), per axis.

    Parameters
    ----------
    angle_error_rad : [rad] (..., 3) e = Theta - Theta_d (yaw wrapped)
    euler_rate_error_rads : [rad/s] (..., 3) e_dot = Theta_dot - Theta_dot_d
    surface_slope : [1/s] (3,) Lambda diagonal
    """
    return euler_rate_error_rads + surface_slope * angle_error_rad


_NEXT1, _NEXT2 = np.array([1, 2, 0]), np.array([2, 0, 1])
_PAIR_A, _PAIR_B = np.array([1, 0, 0]), np.array([2, 2, 1])


def equivalent_control(inertia_diag, surface_slope, euler_rate_error_rads, ref_euler_accel_radss, body_rates_rads):
    """u_eq = I0 (Theta_ddot_d - Lambda e_dot) + omega x (I0 omega)  [N m, body FRD]  (eqs. 24, 27).

    ``inertia_diag`` is (3,) or, for a batch of runs with different models, (..., 3).
    ``omega x (I0 omega)`` equals -f(X) of eq. 17, evaluated with the body rates omega = [p, q, r]:
    [(Izz - Iyy) q r, (Ixx - Izz) p r, (Iyy - Ixx) p q].
    """
    i = inertia_diag  # (3,) or per run (..., 3)
    w = body_rates_rads
    coef = i[..., _NEXT2] - i[..., _NEXT1]  # [Izz - Iyy, Ixx - Izz, Iyy - Ixx]
    gyro = coef * w[..., _PAIR_A] * w[..., _PAIR_B]  # [q r, p r, p q]
    return i * (ref_euler_accel_radss - surface_slope * euler_rate_error_rads) + gyro


def saturate(u_raw, limit_nm):
    """Clip u [N m] to +-limit_nm per axis; returns (u, saturated_mask). ``limit_nm`` None = no limit."""
    if limit_nm is None:
        return u_raw, None
    u = np.clip(u_raw, -limit_nm, limit_nm)
    return u, u != u_raw


def pushes_further(saturated, u_raw, direction):
    """Mask of axes where an integrator moving in ``direction`` would push u deeper into saturation.

    Conditional integration (anti-windup, control-notes 2.8): freeze the state on those axes.
    """
    if saturated is None:
        return None
    return saturated & (direction * u_raw > 0.0)


def check_dt(dt_s: float) -> float:
    """Reject a non-positive or non-finite controller period [s] with ValueError (contract)."""
    dt = float(dt_s)
    if not (0.0 < dt < math.inf):
        raise ValueError(f"dt_s must be a finite time > 0 s, got {dt_s!r}")
    return dt


def load_gains(cls: type, default_config: str, config: str | Path | None, overrides: Mapping[str, Any] | None):
    """Load the ``gains`` section of a controller YAML (packaged name or path) into dataclass ``cls``."""
    path = resolve_config(config or default_config, "controllers")
    return build_dataclass(cls, path, "gains", overrides), path


def torque_limit_or_none(enabled: bool, limit_nm) -> np.ndarray | None:
    """(3,) per-axis torque limit [N m] when enabled, else None."""
    return np.asarray(limit_nm, dtype=float) if enabled else None


def batch_zeros(batch_shape: tuple) -> np.ndarray:
    """Zero state array of shape batch_shape + (3,)."""
    return np.zeros(tuple(batch_shape) + (3,))
