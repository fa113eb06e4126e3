"""The PARAM protocol of the simulated ArduCopter, over ``copter.params`` (``sim/parameters.py``).

PARAM_REQUEST_LIST (the whole table, trickled out ``PARAMS_PER_SERVICE`` per emission), PARAM_REQUEST_READ by name
or index and PARAM_SET (echoed by PARAM_VALUE), with the profile's habits: index 65535 in replies to a read by name
and in echoes, reads answered one per ``param_read_interval_s``, and the statistics ArduPilot saves every 30 s
(STAT_RUNTIME, STAT_FLTTIME) announced by PARAM_VALUE.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .vehicle_link import VehicleLink

log = logging.getLogger("mavastsm_sim")

PARAMS_PER_SERVICE = 40        # PARAM_VALUE trickle per emit call
PARAM_INDEX_UNKNOWN = 65535  # PARAM_VALUE.param_index of ArduPilot's replies to a read by name and of PARAM_SET echoes
STATS_FLUSH_INTERVAL_US = 30_000_000  # ArduPilot saves STAT_RUNTIME / STAT_FLTTIME (and announces them) every 30 s


class ParameterService:
    """Answers the PARAM_* messages and sends the PARAM_VALUEs that are due.

    Parameters
    ----------
    link : VehicleLink
        The copter (its ``params``), the profile, the sender, clock and counters.
    """

    def __init__(self, link: VehicleLink) -> None:
        self.link = link
        self.copter: Any = link.copter
        self.profile = link.profile
        self.mav = link.mav
        self.counters = link.counters
        self._queue: deque[int] = deque()  # indices still to send of a PARAM_REQUEST_LIST
        # parameter reads answered on a schedule (the profile's param_read_interval_s): (index, reported index)
        self._read_replies: deque[tuple[int, int]] = deque()
        self._read_last_us = -(10 ** 12)  # [us] slot of the last reply (long ago: the first goes at once)
        self._next_stats_flush_us = STATS_FLUSH_INTERVAL_US
        self._flight_time_us = 0
        self._flight_time_counted_to_us = 0

    def listing(self) -> bool:
        """True while a PARAM_REQUEST_LIST is being answered (something to send on the next emission)."""
        return bool(self._queue)

    def earliest_due_us(self, bound_us: int) -> int:
        """[us] when the next paced read reply is due, or ``bound_us`` when that is earlier (or none is queued)."""
        if self._read_replies:
            return min(bound_us, self._read_last_us + self._read_interval_us())
        return bound_us

    def emit_due(self, now_us: int) -> None:
        """Send the PARAM_VALUEs due at ``now_us`` [us]: the next batch of a list, a paced read reply, statistics."""
        if self._queue:
            self._send_batch()
        if self._read_replies:
            self._send_due_read_reply(now_us)
        self._count_flight_time(now_us)
        if now_us >= self._next_stats_flush_us:
            self._next_stats_flush_us += STATS_FLUSH_INTERVAL_US
            self._flush_statistics()

    def _index_of(self, name: str) -> int | None:
        index = self.copter.params.index_of(name)
        return None if index < 0 else index

    def _send_value(self, index: int, reported_index: int | None = None) -> None:
        """PARAM_VALUE of the entry at ``index``; ``reported_index`` goes in param_index (default: ``index``)."""
        entry = self.copter.params.by_index(index)
        self.counters["param_values_sent"] += 1
        self.mav.param_value_send(entry.name.encode("ascii"), float(entry.value), int(entry.param_type),
                                  self.copter.params.count, index if reported_index is None else reported_index)

    def _send_batch(self) -> None:
        for _ in range(min(PARAMS_PER_SERVICE, len(self._queue))):
            self._send_value(self._queue.popleft())

    def on_request_list(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        self.link.send_statustext(mavlink.MAV_SEVERITY_INFO, f"ArduCopter V{self.link.firmware.text} (mavastsm sim)")
        self.link.send_statustext(mavlink.MAV_SEVERITY_INFO, "Frame: QUAD/X")
        self.counters["param_lists_requested"] += 1
        self._queue = deque(range(self.copter.params.count))

    @staticmethod
    def _name(raw: Any) -> str:
        if isinstance(raw, bytes):
            raw = raw.decode("ascii", errors="replace")
        return str(raw).rstrip("\x00")

    def on_request_read(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        if msg.param_index >= 0:
            index: int | None = msg.param_index if msg.param_index < self.copter.params.count else None
            reported_index = index
        else:
            index = self._index_of(self._name(msg.param_id))
            reported_index = PARAM_INDEX_UNKNOWN if self.profile.param_index_65535 else index
        if index is None:
            self.link.bad("unknown_params", f"read {self._name(msg.param_id)!r} index {msg.param_index}")
            return
        if self.profile.param_read_interval_s > 0:
            self._read_replies.append((index, reported_index))
        else:
            self._send_value(index, reported_index)

    def on_set(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        name = self._name(msg.param_id)
        index = self._index_of(name)
        if index is None:
            self.link.bad("unknown_params", f"set {name!r}")
            return
        value = float(msg.param_value)
        if not math.isfinite(value):
            self.link.bad("bad_field_values", f"PARAM_SET {name}={value}")
            return
        ok, reason = self.copter.params.set(name, value)
        if not ok:
            self.counters["param_writes_denied"] += 1
            self.link.pending_texts.append((mavlink.MAV_SEVERITY_WARNING, f"Param write denied ({name})"))
            log.debug("PARAM_SET %s=%g denied: %s", name, value, reason)
        # echo: the new value is the ACK; on refusal the unchanged one (ArduPilot's announces it with index 65535)
        self._send_value(index, PARAM_INDEX_UNKNOWN if self.profile.param_index_65535 else index)

    def _read_interval_us(self) -> int:
        return int(round(self.profile.param_read_interval_s * 1e6))

    def _send_due_read_reply(self, now_us: int) -> None:
        """One queued PARAM_REQUEST_READ reply per interval, on ArduPilot's deferred-message clock."""
        interval_us = self._read_interval_us()
        if now_us - self._read_last_us < interval_us:
            return
        index, reported_index = self._read_replies.popleft()
        self._send_value(index, reported_index)
        self._read_last_us += interval_us
        if now_us - self._read_last_us > interval_us:
            self._read_last_us = now_us

    def _count_flight_time(self, now_us: int) -> None:
        if self.copter.armed and not getattr(self.copter, "landed", True):
            self._flight_time_us += now_us - self._flight_time_counted_to_us
        self._flight_time_counted_to_us = now_us

    def _flush_statistics(self) -> None:
        """ArduPilot's statistics save every 30 s: STAT_RUNTIME [s] always changes, STAT_FLTTIME [s] once flown; with
        ``unsolicited_param_values`` each change is announced by PARAM_VALUE (index 65535) like any saved parameter."""
        values = {"STAT_RUNTIME": self.link.now_us // 1_000_000, "STAT_FLTTIME": self._flight_time_us // 1_000_000}
        for name, value in values.items():
            entry = self.copter.params.entry(name) if hasattr(self.copter.params, "entry") else None
            if entry is None or entry.value == float(value):
                continue
            entry.value = float(value)  # a statistic, not a setting: no change callbacks
            if self.profile.unsolicited_param_values:
                self._send_value(self.copter.params.index_of(name), PARAM_INDEX_UNKNOWN)
                self.counters["unsolicited_param_values"] += 1
