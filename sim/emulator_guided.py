"""The emulated ArduCopter's GUIDED angle interface: SET_ATTITUDE_TARGET as ArduCopter 4.2+ reads it
(``GCS_MAVLink_Copter::handle_message_set_attitude_target``, ``ModeGuided::angle_control_run``;
docs/design-decisions.md, MAV-5).

type_mask validation, quaternion or body-rate targets, thrust as climb rate (0.5 = hold, linear to
WPNAV_SPEED_UP/DN) or, with GUID_OPTIONS bit 3, as collective thrust; the GUID_TIMEOUT fallback to level at the
current yaw with zero climb. Split out of ``ArduCopterEmulator`` (issue 29), which applies the controller resets a
target implies.
"""

from __future__ import annotations

import math

from .attitude_math import q_from_euler, q_to_euler

# SET_ATTITUDE_TARGET type_mask bits (ATTITUDE_TARGET_TYPEMASK)
MASK_ROLL_RATE_IGNORE = 1
MASK_PITCH_RATE_IGNORE = 2
MASK_YAW_RATE_IGNORE = 4
MASK_THRUST_BODY_SET = 32
MASK_THROTTLE_IGNORE = 64
MASK_ATTITUDE_IGNORE = 128
GUID_OPTIONS_THRUST_AS_THRUST = 8

ZERO_RATES = (0.0, 0.0, 0.0)


class GuidedAngleTarget:
    """The angle submode's target: what was last accepted, when, and how many were rejected.

    ``submode`` is "hold" (position/level hold, no target) or "angle"; ``q`` the target quaternion or None (the
    zero quaternion: body-rate input); ``rates`` [rad/s]; ``climb_or_thrust`` a climb rate [m/s up] or, with
    ``use_thrust``, a collective thrust [-1, 1].
    """

    def __init__(self):
        self.rejected_targets = 0
        self.last_reject_reason = ""
        self.update_time_s = 0.0
        self.clear()

    def load_parameters(self, params) -> None:
        """GUID_TIMEOUT and GUID_OPTIONS from the table."""
        g = params.get
        self.timeout_s = max(g("GUID_TIMEOUT"), 0.1)
        self.thrust_as_thrust = (int(g("GUID_OPTIONS")) & GUID_OPTIONS_THRUST_AS_THRUST) != 0

    def clear(self) -> None:
        """No target (on entering a mode)."""
        self.submode = "hold"
        self.q = None
        self.rates = ZERO_RATES
        self.climb_or_thrust = 0.0
        self.use_thrust = False
        self.timed_out = False

    def stop(self, reason: str) -> None:
        """A target refused: counted, and the submode falls back to hold (``mode_guided.init(true)``)."""
        self.rejected_targets += 1
        self.last_reject_reason = reason
        self.submode = "hold"
        self.q = None
        self.rates = ZERO_RATES
        self.use_thrust = False

    def parse(self, type_mask, q_wxyz, body_rates_rads, thrust, speed_up: float, speed_dn: float):
        """A SET_ATTITUDE_TARGET's fields -> ((q or None, rates, climb_or_thrust, use_thrust), "") when usable,
        else (None, why it stops the vehicle). ``speed_up``/``speed_dn`` [m/s] scale thrust to a climb rate."""
        try:
            type_mask = int(type_mask)
            q0, q1, q2, q3 = q_wxyz
            q = (float(q0), float(q1), float(q2), float(q3))
            r0, r1, r2 = body_rates_rads
            rates = (float(r0), float(r1), float(r2))
            thrust = float(thrust)
        except (TypeError, ValueError):
            return None, "malformed attitude target"
        if type_mask & MASK_THROTTLE_IGNORE:
            return None, "THROTTLE_IGNORE set: stopped (guided hold)"
        if type_mask & MASK_ATTITUDE_IGNORE:
            q_target = None
        else:
            n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
            if not (abs(n2 - 1.0) < 1e-3):  # Quaternion::is_unit_length; NaN fails too
                return None, "quaternion not unit length: stopped (guided hold)"
            q_target = q
        rate_bits = type_mask & (MASK_ROLL_RATE_IGNORE | MASK_PITCH_RATE_IGNORE | MASK_YAW_RATE_IGNORE)
        if rate_bits == 7:
            rates = (0.0, 0.0, 0.0)
        elif rate_bits != 0:
            return None, "mixed body-rate ignore bits: stopped (guided hold)"
        elif not (math.isfinite(rates[0]) and math.isfinite(rates[1]) and math.isfinite(rates[2])):
            # ArduCopter does not check; the simulator refuses rather than fly NaN (counted).
            return None, "non-finite body rates: stopped (guided hold)"
        use_thrust = self.thrust_as_thrust
        return (q_target, rates, self._climb_or_thrust(thrust, use_thrust, speed_up, speed_dn), use_thrust), ""

    @staticmethod
    def _climb_or_thrust(thrust: float, use_thrust: bool, speed_up: float, speed_dn: float) -> float:
        """The thrust field as collective thrust [-1, 1] or as a climb rate [m/s up] (0.5 = hold)."""
        if not math.isfinite(thrust):
            thrust = 0.0 if use_thrust else 0.5  # AP constrain_float() returns the midpoint for NaN
        if use_thrust:
            return min(max(thrust, -1.0), 1.0)
        t = min(max(thrust, 0.0), 1.0)
        if t == 0.5:
            return 0.0
        if t > 0.5:
            return (t - 0.5) * 2.0 * speed_up
        return -(0.5 - t) * 2.0 * speed_dn

    def accept(self, target, now_s: float) -> None:
        """Store a target from ``parse`` received at ``now_s`` [s] (the GUID_TIMEOUT timer restarts)."""
        self.submode = "angle"
        self.q, self.rates, self.climb_or_thrust, self.use_thrust = target
        self.update_time_s = now_s
        self.timed_out = False

    def check_timeout(self, now_s: float, q_meas) -> bool:
        """GUID_TIMEOUT: no target for longer -> level at the current heading (of ``q_meas``), zero rates, zero
        climb. True only in the loop where a collective-thrust target timed out (the vertical controller takes
        over)."""
        if not now_s - self.update_time_s > self.timeout_s or self.timed_out:
            return False
        self.timed_out = True
        self.q = q_from_euler(0.0, 0.0, q_to_euler(q_meas)[2])
        self.rates = (0.0, 0.0, 0.0)
        self.climb_or_thrust = 0.0
        was_thrust, self.use_thrust = self.use_thrust, False
        return was_thrust

    def demand(self):
        """This loop's demand: (climb [m/s up], collective thrust or None, take-off demand, attitude input), the
        attitude input ("rate", rates) or ("quat", q, rates)."""
        value = self.climb_or_thrust
        attitude_input = ("rate", self.rates) if self.q is None else ("quat", self.q, self.rates)
        if self.use_thrust:
            return 0.0, value, value > 0.0, attitude_input
        return value, None, value > 0.0, attitude_input
