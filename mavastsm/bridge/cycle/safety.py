"""Safety predicates and the last gate on every outbound setpoint (pure, never raises).

Each predicate answers one question about one sample and returns a ``FailsafeReason`` or None;
``highest_priority`` combines them in the declaration order of ``FailsafeReason`` (the one rule: the control
cycle applies it to the reasons one cycle raises; the session keeps the first reason that stopped the run,
and its supervisor checks LINK_LOST before STALE_ATTITUDE, their declaration order). The output gate
(``OutputGate``) is applied *last*, once to each setpoint, just before it goes on the wire: whatever the controller
or the mapping produced, only finite values inside the configured limits and one of the allowed type masks (0x80
rates, 0x07 level attitude, 0x87 zero rates) can leave the bridge. ``attitude_sample_problem`` is the input gate,
once to each ATTITUDE before anything is decided on it.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Iterable

from ...frames import AXES
from ...state_types import FailsafeReason
from ..link.messages import ALLOWED_TYPE_MASKS, TYPE_MASK_RATES, Setpoint

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


def predicted_excursion_rad(rate_rads: float, hold_s: float, decel_radss: float) -> float:
    """Signed angle [rad] an axis turns if ``rate_rads`` is held for ``hold_s`` and then braked at ``decel_radss``:
    w T + w |w| / (2 a)."""
    return rate_rads * hold_s + rate_rads * abs(rate_rads) / (2.0 * decel_radss)


def last_setpoint_rate_bound(angle_rad: float, hold_s: float, decel_radss: float, max_tilt_rad: float) -> float:
    """[rad/s] >= 0: the fastest rate *away from level* on one axis at ``angle_rad`` whose excursion
    (``predicted_excursion_rad``) keeps |angle| within ``max_tilt_rad``: the positive root of
    w T + w^2 / (2 a) = max_tilt - |angle|  ->  w = a (sqrt(T^2 + 2 (max_tilt - |angle|) / a) - T)."""
    room = max_tilt_rad - abs(angle_rad)
    if room <= 0.0:
        return 0.0
    return decel_radss * (math.sqrt(hold_s * hold_s + 2.0 * room / decel_radss) - hold_s)


def last_setpoint_safe_rates(body_rates_rads, euler_rad, hold_s: float, decel_radss, max_tilt_rad: float) -> tuple[float, float, float]:
    """Body rates [rad/s, FRD] whose roll/pitch part is survivable as the *last* setpoint (pure).

    If the bridge dies, the autopilot keeps obeying the last body-rate command for its setpoint timeout
    (ArduCopter GUID_TIMEOUT, PX4 COM_OF_LOSS_T), then levels the vehicle at its angular-acceleration
    limit. ``hold_s`` = that timeout plus the vehicle's lag; ``decel_radss`` = (roll, pitch) braking
    acceleration (ATC_ACCEL_R/P_MAX). With Euler rates from the commanded body rates (eq. 1 inverse at
    the measured angles), the predicted tilt is the norm of
    (phi + excursion(phi_dot), theta + excursion(theta_dot)); if it exceeds ``max_tilt_rad`` the roll and
    pitch commands are scaled down together (bisection on the scale) until it does not. Beyond the bound
    already, the components that tilt further are zeroed and those towards level are kept. Yaw is untouched.
    """
    p, q, r = body_rates_rads
    phi, theta = euler_rad[0], euler_rad[1]
    sphi, cphi, tth = math.sin(phi), math.cos(phi), math.tan(theta)

    def predicted(k: float) -> float:
        pk, qk = p * k, q * k
        phi_dot = pk + (qk * sphi + r * cphi) * tth
        theta_dot = qk * cphi - r * sphi
        return math.hypot(phi + predicted_excursion_rad(phi_dot, hold_s, decel_radss[0]),
                          theta + predicted_excursion_rad(theta_dot, hold_s, decel_radss[1]))

    if predicted(1.0) <= max_tilt_rad:
        return (p, q, r)
    if math.hypot(phi, theta) >= max_tilt_rad or predicted(0.0) > max_tilt_rad:
        return (p if p * phi < 0 else 0.0, q if q * theta < 0 else 0.0, r)
    lo, hi = 0.0, 1.0  # predicted(lo) <= bound < predicted(hi)
    for _ in range(16):
        mid = 0.5 * (lo + hi)
        if predicted(mid) <= max_tilt_rad:
            lo = mid
        else:
            hi = mid
    return (p * lo, q * lo, r)


@dataclass(frozen=True, slots=True)
class AdmittedSetpoint(Setpoint):
    """A setpoint the output gate let through; built only by :class:`OutputGate` (tests/test_architecture.py checks)."""


class OutputGate:
    """The one gate between the bridge and the link: every setpoint passes it once, and only what it admits is sent.

    ``admit`` (the control cycle, once per cycle; its level holds) clamps the body rates to +-``max_rate_rads`` and
    the thrust to [``thrust_min_norm``, ``thrust_max_norm``]; ``verify`` (the session's output, for a setpoint that
    has not passed ``admit``) lets it through unchanged only when it already is inside those limits. Both refuse
    (None) a mask not in ALLOWED_TYPE_MASKS, a non-finite field, and a quaternion that is not unit (attitude masks)
    or zero or unit (0x80, quaternion ignored). An AdmittedSetpoint is not checked twice.
    """

    def __init__(self, max_rate_rads, thrust_min_norm: float, thrust_max_norm: float) -> None:
        self.max_rate_rads = tuple(float(m) for m in max_rate_rads)
        self.thrust_min_norm, self.thrust_max_norm = float(thrust_min_norm), float(thrust_max_norm)

    def admit(self, sp: Setpoint) -> AdmittedSetpoint | None:
        """``sp`` clamped into the limits, or None (see the class docstring)."""
        if sp.type_mask not in ALLOWED_TYPE_MASKS:
            return None
        if not (all_finite(sp.body_rates_rads) and all_finite(sp.q_wxyz) and math.isfinite(sp.thrust_norm)):
            return None
        rates = tuple(clamp(w, -m, m) for w, m in zip(sp.body_rates_rads, self.max_rate_rads))
        thrust = clamp(sp.thrust_norm, self.thrust_min_norm, self.thrust_max_norm)
        return AdmittedSetpoint(sp.type_mask, sp.q_wxyz, rates, thrust) if _quaternion_allowed(sp) else None  # type: ignore[arg-type]

    def verify(self, sp: Setpoint) -> AdmittedSetpoint | None:
        """``sp`` itself when it passed ``admit`` or is inside every limit as it is, else None (nothing clamped)."""
        if type(sp) is AdmittedSetpoint:
            return sp
        admitted = self.admit(sp)
        if admitted is None or admitted.body_rates_rads != tuple(sp.body_rates_rads) or admitted.thrust_norm != sp.thrust_norm:
            return None
        return admitted


def _quaternion_allowed(sp: Setpoint) -> bool:
    """Unit quaternion for the attitude masks; zero or unit where 0x80 says it is ignored (0x87 is zero rates)."""
    qn = math.sqrt(sum(c * c for c in sp.q_wxyz))
    if sp.type_mask & 0x80:
        return qn == 0.0 or abs(qn - 1.0) < 1e-3
    return abs(qn - 1.0) < 1e-3 and sp.type_mask != TYPE_MASK_RATES


class CommandSaturationMonitor:
    """Sustained saturation or a limit cycle of the body-rate command (pure; fed once per cycle).

    Per cycle and axis, the command is *clipped* when the limits changed it (the rate limit or the
    last-setpoint bound), and it *reverses* when it swings from above +``swing_rads`` to below
    -``swing_rads`` or back (a Schmitt trigger, so hover noise around zero never counts). Over the trailing
    ``window_s`` of vehicle time, the condition is: some axis clipped in at least ``fraction`` of the cycles,
    or some axis reversing at ``max_hz`` or more (two reversals per period). ``update`` returns True once
    the condition has held for ``hold_s``.
    """

    def __init__(self, window_s: float, fraction: float, max_hz: float, swing_rads: float, hold_s: float) -> None:
        self.window_s, self.fraction, self.max_hz, self.swing, self.hold_s = window_s, fraction, max_hz, swing_rads, hold_s
        self.reset()

    def reset(self) -> None:
        self._clipped: collections.deque = collections.deque()  # (t, per-axis clipped flags)
        self._counts = [0, 0, 0]
        self._reversals = [collections.deque(), collections.deque(), collections.deque()]
        self._side = [0, 0, 0]
        self._since: float | None = None
        self.reason = ""

    def update(self, t_s: float, requested_rads, sent_rads) -> bool:
        flags = tuple(abs(r - s) > 1e-9 for r, s in zip(requested_rads, sent_rads))
        self._clipped.append((t_s, flags))
        for i, f in enumerate(flags):
            self._counts[i] += f
        while self._clipped and self._clipped[0][0] < t_s - self.window_s:
            _, old = self._clipped.popleft()
            for i, f in enumerate(old):
                self._counts[i] -= f
        for i, w in enumerate(sent_rads):
            side = 1 if w > self.swing else (-1 if w < -self.swing else 0)
            if side and side != self._side[i]:
                if self._side[i]:
                    self._reversals[i].append(t_s)
                self._side[i] = side
            rev = self._reversals[i]
            while rev and rev[0] < t_s - self.window_s:
                rev.popleft()
        n = len(self._clipped)
        span = t_s - self._clipped[0][0] if n else 0.0
        why = ""
        if span >= 0.5 * self.window_s:
            for i, c in enumerate(self._counts):
                if c >= self.fraction * n:
                    why = f"{AXES[i]} command clipped in {100.0 * c / n:.0f} % of the last {span:.2f} s"
                    break
                hz = len(self._reversals[i]) / (2.0 * self.window_s)
                if hz >= self.max_hz:
                    why = f"{AXES[i]} command reversing at {hz:.1f} Hz (swing > {self.swing:g} rad/s)"
                    break
        if not why:
            self._since = None
            return False
        if self._since is None:
            self._since = t_s
        self.reason = why
        return t_s - self._since >= self.hold_s
