"""The wire state the parts of the simulated ArduCopter's MAVLink face share (``sim/mavlink_vehicle.py``).

One :class:`VehicleLink` per vehicle: its identity (``SYSID_THISMAV`` / compid 1), the pymavlink ``MAVLink`` object
every part sends through, the counters (bad-input classes in ``BAD_INPUT_COUNTERS``), the simulated time of the
datagram or tick being handled, and our own STATUSTEXTs waiting to go out after the current reply. The parts
(``vehicle_*.py``) read and write these here rather than through each other.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, Callable

# The MAVLink 2 dialect module itself: every MAVLink object here is built from it, so the vehicle speaks MAVLink 2
# from its first byte without touching pymavlink's process-wide MAVLINK20 switch (it opens no mavutil connection).
from pymavlink.dialects.v20 import ardupilotmega as mavlink

log = logging.getLogger("mavastsm_sim")

AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1  # 1

BAD_INPUT_COUNTERS = (
    "garbage_bytes",          # bytes before a MAVLink start marker (events)
    "crc_errors",             # frames with a wrong checksum
    "malformed_frames",       # bad length / incompat flags / undecodable payload
    "truncated_frames",       # a datagram ending inside a frame
    "unknown_message_ids",    # well-formed frames of ids this dialect does not know
    "wrong_target",           # addressed to another system or component
    "bad_field_values",       # NaN / inf / out-of-range fields (message dropped)
    "unsigned_rejected",      # unsigned frame while signing is required
    "bad_signature",          # signed with the wrong key (or a forged signature)
    "replayed",               # signed with our key, but a timestamp not newer than its stream's (replay)
    "unsupported_commands",   # COMMAND_LONG/INT ids we do not implement (ACK UNSUPPORTED)
    "unknown_params",         # PARAM_* for a name or index that does not exist
    "internal_errors",        # a handler raised (bug); the message is dropped, the vehicle keeps flying
)


class _DatagramSink:
    """File-like adapter so ``MAVLink.send`` writes each packed frame as one datagram."""

    def __init__(self, send_datagram: Callable[[bytes], None]) -> None:
        self.write = send_datagram


class VehicleLink:
    """Identity, sender, counters, clock and queued STATUSTEXTs of one simulated vehicle.

    Parameters
    ----------
    copter : SimulatedCopter
        The plant and autopilot emulation; ``SYSID_THISMAV`` is read from its parameters once, here.
    send_datagram : callable(bytes)
        Sends one datagram to every peer.
    """

    def __init__(self, copter: Any, send_datagram: Callable[[bytes], None]) -> None:
        self.copter = copter
        self.profile = copter.profile  # the habits of the ArduCopter emulated, one record for copter and wire
        self.firmware = self.profile.firmware
        self.counters: Counter[str] = Counter()
        self.sysid = int(self.param("SYSID_THISMAV", 1.0))
        self.compid = AUTOPILOT_COMPONENT_ID
        self.mav = mavlink.MAVLink(_DatagramSink(send_datagram), srcSystem=self.sysid, srcComponent=self.compid)
        self.mav.robust_parsing = True
        self.now_us = 0  # [us] simulated time of the datagram or emission being handled
        self.pending_texts: list[tuple[int, str]] = []  # our own STATUSTEXTs, sent after the ACK like ArduPilot
        self._statustext_id = 0

    def param(self, name: str, default: float) -> float:
        """The copter's parameter ``name`` as a float; ``default`` when it does not exist or is unset."""
        try:
            value = self.copter.params.get(name)
        except (KeyError, AttributeError):
            return default
        return default if value is None else float(value)

    def bad(self, counter: str, detail: str) -> None:
        """Count one bad input of class ``counter`` (logged at DEBUG, the first 5 and every 1000th)."""
        self.counters[counter] += 1
        n = self.counters[counter]
        if log.isEnabledFor(logging.DEBUG) and (n <= 5 or n % 1000 == 0):
            log.debug("bad input #%d of class %s: %s", n, counter, detail)

    def bad_input_total(self) -> int:
        """Sum of all bad-input counters [count]."""
        return sum(self.counters[name] for name in BAD_INPUT_COUNTERS)

    def for_us(self, target_system: int, target_component: int | None = None) -> bool:
        """True when a message's target is us (0 = broadcast); otherwise counted as ``wrong_target``."""
        ok = target_system in (0, self.sysid) and (target_component is None or target_component in (0, self.compid))
        if not ok:
            self.bad("wrong_target", f"for {target_system}/{target_component}, we are {self.sysid}/{self.compid}")
        return ok

    def send_statustext(self, severity: int, text: str) -> None:
        """Send STATUSTEXT, chunked into 50-byte pieces with id/chunk_seq when longer (MAVLink 2)."""
        data = text.encode("ascii", errors="replace")
        if len(data) <= 50:
            self.mav.statustext_send(severity, data)
            return
        self._statustext_id = self._statustext_id % 65535 + 1
        for seq, start in enumerate(range(0, len(data), 50)):
            self.mav.statustext_send(severity, data[start:start + 50], id=self._statustext_id, chunk_seq=seq)
