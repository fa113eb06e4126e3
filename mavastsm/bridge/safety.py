"""Safety predicates and the last gate on every outbound setpoint (pure, never raises).

Each predicate answers one question about one sample and returns a ``FailsafeReason`` or None;
``highest_priority`` combines them in the declaration order of ``FailsafeReason``. The limit
functions are applied *last*, just before a setpoint goes on the wire: whatever the controller or
the mapping produced, only finite values inside the configured limits and one of the allowed
type masks (0x80 rates, 0x07 level attitude, 0x87 zero rates) can leave the bridge.
"""

from __future__ import annotations

import math
from typing import Iterable

from ..state_types import FailsafeReason
from .setpoint_mapping import ALLOWED_TYPE_MASKS, TYPE_MASK_RATES, Setpoint

_PRIORITY = {reason: i for i, reason in enumerate(FailsafeReason)}


def highest_priority(reasons: Iterable[FailsafeReason | None]) -> FailsafeReason | None:
    """The most important of several active reasons (declaration order of FailsafeReason)."""
    best = None
    for r in reasons:
        if r is not None and (best is None or _PRIORITY[r] < _PRIORITY[best]):
            best = r
    return best


def all_finite(values: Iterable[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def attitude_sample_problem(euler_rad, body_rates_rads, max_input_rate_rads: float) -> str | None:
    """Why an ATTITUDE sample is unusable, or None when it is fine.

    Rules: every field finite; |roll| <= pi, |pitch| <= pi/2, |yaw| <= pi (+1e-3 rounding);
    |p|, |q|, |r| <= max_input_rate_rads.
    """
    if not all_finite(euler_rad) or not all_finite(body_rates_rads):
        return "non-finite field"
    roll, pitch, yaw = euler_rad
    tol = 1e-3
    if abs(roll) > math.pi + tol or abs(pitch) > math.pi / 2 + tol or abs(yaw) > math.pi + tol:
        return "angle out of range"
    if any(abs(w) > max_input_rate_rads for w in body_rates_rads):
        return "body rate out of range"
    return None


def envelope_breach(euler_rad, envelope_tilt_rad: float) -> FailsafeReason | None:
    """ENVELOPE_BREACH when |roll| or |pitch| exceeds the envelope."""
    if abs(euler_rad[0]) > envelope_tilt_rad or abs(euler_rad[1]) > envelope_tilt_rad:
        return FailsafeReason.ENVELOPE_BREACH
    return None


def clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def clip_reference_tilt(ref_rad, max_tilt_rad: float) -> tuple[float, float, float]:
    """Reference roll/pitch clipped to +-max_tilt_rad; yaw untouched."""
    return (clamp(ref_rad[0], -max_tilt_rad, max_tilt_rad), clamp(ref_rad[1], -max_tilt_rad, max_tilt_rad), ref_rad[2])


def limit_setpoint(sp: Setpoint, max_rate_rads, thrust_min_norm: float, thrust_max_norm: float) -> Setpoint | None:
    """Clamp rates to +-max_rate_rads and thrust to [min, max]; None when anything is non-finite or the mask is not allowed."""
    if sp.type_mask not in ALLOWED_TYPE_MASKS:
        return None
    if not (all_finite(sp.body_rates_rads) and all_finite(sp.q_wxyz) and math.isfinite(sp.thrust_norm)):
        return None
    rates = tuple(clamp(w, -m, m) for w, m in zip(sp.body_rates_rads, max_rate_rads))
    thrust = clamp(sp.thrust_norm, thrust_min_norm, thrust_max_norm)
    return Setpoint(sp.type_mask, sp.q_wxyz, rates, thrust)  # type: ignore[arg-type]


def setpoint_within_limits(sp: Setpoint, max_rate_rads, thrust_min_norm: float, thrust_max_norm: float) -> bool:
    """The final gate: True only for an allowed mask, finite fields, rates and thrust inside limits, unit (or zero) q."""
    if sp.type_mask not in ALLOWED_TYPE_MASKS:
        return False
    if not (all_finite(sp.body_rates_rads) and all_finite(sp.q_wxyz) and math.isfinite(sp.thrust_norm)):
        return False
    if any(abs(w) > m for w, m in zip(sp.body_rates_rads, max_rate_rads)):
        return False
    if not (thrust_min_norm <= sp.thrust_norm <= thrust_max_norm):
        return False
    qn = math.sqrt(sum(c * c for c in sp.q_wxyz))
    if sp.type_mask & 0x80:
        return qn == 0.0 or abs(qn - 1.0) < 1e-3
    return abs(qn - 1.0) < 1e-3 and (sp.type_mask != TYPE_MASK_RATES)
