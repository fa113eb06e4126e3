"""Value types shared across layers: the failsafe reasons.

Kept at the bottom layer so telemetry and the dashboard can show a failsafe without importing
the bridge.
"""

from __future__ import annotations

import enum


class FailsafeReason(enum.Enum):
    """Why the bridge is not (or no longer) sending controller output. Values are the sentences shown to people.

    Priority order (highest first) is the order of declaration; `bridge.cycle.safety` combines
    predicates in this order.
    """

    OPERATOR_STOP = "operator stop (q, Ctrl-C or SIGTERM): level hold, then hand back"
    LINK_LOST = "link lost: no HEARTBEAT from the autopilot within the link timeout"
    VEHICLE_RESTARTED = "the autopilot restarted (its clock went back): stopped commanding, hand back"
    IDENTITY_CONFLICT = "two vehicles send the target's system id (two clocks): level hold, hand back"
    MODE_CHANGED = "pilot or ground station left the guided mode: stopped commanding"
    STALE_ATTITUDE = "stale or missing ATTITUDE: adaptation frozen, level hold sent"
    INVALID_INPUT = "NaN/inf or out-of-range ATTITUDE input: sample rejected, level hold sent"
    ENVELOPE_BREACH = "attitude envelope breached: level hold sent"
    NON_FINITE_COMMAND = "controller produced a non-finite command: level hold sent"
    CONTROLLER_FAULT = "the control cycle raised an exception: level hold sent"
    ADAPTIVE_GAIN_PINNED = "adaptive gain alpha pinned at alpha_max: level hold sent"
    COMMAND_SATURATION = "body-rate command saturated or limit-cycling: level hold sent"
    LOOP_OVERRUN = "control cycles overran their period repeatedly"
    TAKEOFF_TIMEOUT = "bounded --takeoff climb did not reach its altitude in time: level hold sent"

    @property
    def label(self) -> str:
        """Short upper-case name for logs and CSV columns."""
        return self.name
