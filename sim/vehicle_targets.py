"""SET_ATTITUDE_TARGET into the simulated copter: checked, counted, and acted on now or after the profile's
``command_latency_s`` (in arrival order)."""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import Any

from .vehicle_link import VehicleLink

log = logging.getLogger("mavastsm_sim")


class AttitudeTargetIntake:
    """Hands SET_ATTITUDE_TARGET to ``copter.handle_attitude_target``; ``received`` counts those addressed to us.

    Parameters
    ----------
    link : VehicleLink
        The copter, the profile (``command_latency_s``), clock and counters.
    """

    def __init__(self, link: VehicleLink) -> None:
        self.link = link
        self.copter: Any = link.copter
        self.counters = link.counters
        self.received = 0  # SET_ATTITUDE_TARGETs addressed to us, sane or not [count]
        self._held_targets: deque[tuple[int, int, list, tuple, float]] = deque()  # the profile's command_latency_s
        self._command_latency_us = int(round(link.profile.command_latency_s * 1e6))

    def earliest_due_us(self, bound_us: int) -> int:
        """[us] when the oldest held target is due, or ``bound_us`` when that is earlier (or none is held)."""
        if self._held_targets:
            return min(bound_us, self._held_targets[0][0])
        return bound_us

    def apply_due(self, now_us: int) -> None:
        """Act on the held targets due by ``now_us`` [us], oldest first."""
        while self._held_targets and self._held_targets[0][0] <= now_us:
            self._apply_attitude_target(*self._held_targets.popleft()[1:])

    def on_set_attitude_target(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        self.received += 1
        q = [float(v) for v in msg.q]
        rates = (float(msg.body_roll_rate), float(msg.body_pitch_rate), float(msg.body_yaw_rate))
        thrust = float(msg.thrust)
        if not math.isfinite(sum(q) + sum(rates) + thrust):  # NaN/inf anywhere; float32 inputs cannot overflow
            self.link.bad("bad_field_values", f"SET_ATTITUDE_TARGET non-finite q={q} rates={rates} thrust={thrust}")
            return
        if self._command_latency_us > 0:  # acted on later (the profile's command_latency_s), in arrival order
            due_us = self.link.now_us + self._command_latency_us
            self._held_targets.append((due_us, int(msg.type_mask), q, rates, thrust))
            return
        self._apply_attitude_target(int(msg.type_mask), q, rates, thrust)

    def _apply_attitude_target(self, type_mask: int, q: list, rates: tuple, thrust: float) -> None:
        accepted, reason = self.copter.handle_attitude_target(type_mask, q, rates, thrust)
        if not accepted:
            self.counters["attitude_targets_refused"] += 1
            n = self.counters["attitude_targets_refused"]
            if n <= 5 or n % 1000 == 0:
                log.debug("SET_ATTITUDE_TARGET mask=0x%02x refused (#%d): %s", type_mask, n, reason)
