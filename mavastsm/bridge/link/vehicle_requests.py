"""The request/reply half of the bridge's MAVLink link: a command or parameter sent, its answer awaited.

COMMAND_LONG with its COMMAND_ACK (timeout, retry, IN_PROGRESS extending the wait, and the vehicle's text that
explains a refusal; the flight mode goes through it, spelled by the autopilot's adapter), arming, message intervals, REQUEST_MESSAGE, and parameters read and set by
name (PARAM_VALUE). Each call blocks its caller (start-up, hand-back, the supervisor) until the answer, a timeout
or the link's stop; none runs on the reader thread.

It is ``link.requests``, built by the :class:`~mavastsm.bridge.link.mavlink_link.MavlinkLink` it belongs to, rather
than an object handed around on its own, because the two halves are one connection: the link's reader thread is
the only one that sees the answers (it hands each COMMAND_ACK addressed to us and each PARAM_VALUE of the target
here, :meth:`VehicleRequests.ack_received`, :meth:`VehicleRequests.param_value_received`), the requests go out
through the link's one locked sender, and every wait here is on the link's one condition (the reader notifies it
for every answer, HEARTBEAT, text and message a request waits on; with lockstep turns it is what lets the
simulated vehicle move while we wait, ``mavastsm.lockstep_turns.TurnCondition``) and ends on the link's stop.
So one link has exactly one requests half, and whoever holds the link (preflight, the session's actions, the
supervisor) reaches it as ``link.requests`` without a second parameter to pass along. The ACK and PARAM_VALUE
bookkeeping is this object's own; the link keeps the connection, the reader, the heartbeat and the typed latest
messages. Like the link, this module speaks pymavlink (tests/test_architecture.py, MAVLINK_MODULES).
"""

from __future__ import annotations

import struct
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # constants and ids: MAVLink 2 whatever the import order

from ...errors import OffboardRejected

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_IN_PROGRESS = 5
REFUSAL_TEXT_WAIT_S = 0.3   # longest wait for the STATUSTEXT that explains a refused command [s]


class VehicleRequests:
    """Commands and parameter exchanges with the link's target autopilot, each waiting for its answer.

    Parameters
    ----------
    link : the MavlinkLink this belongs to: its encoder (``mav``), sender (``send_message``), target ids,
        ``last_heartbeat``, ``latest`` and ``stats.statustext``, all filled by its reader thread
    cond : the link's condition, notified by the reader for every answer; guards this object's bookkeeping too
    stop : the link's stop event (set by ``close``): an ACK or text wait ends at once
    """

    def __init__(self, link, cond: threading.Condition, stop: threading.Event) -> None:
        self._link = link
        self._cond = cond
        self._stop = stop
        self._acks: dict[int, int] = {}
        self._params: dict[str, float] = {}  # PARAM_VALUE of the names being asked for only (bounded)
        self._awaited_params: set[str] = set()

    # ------------------------------------------------------------------ answers (the link's reader thread)
    def ack_received(self, command: int, result: int) -> None:
        """A COMMAND_ACK from the target addressed to us (or to everybody)."""
        with self._cond:
            self._acks[command] = result
            self._cond.notify_all()

    def param_value_received(self, name: str, value: float) -> None:
        """A PARAM_VALUE from the target; kept only while ``name`` is being asked for."""
        with self._cond:
            if name in self._awaited_params:  # an autopilot's unsolicited (or anyone's) other names are not kept
                self._params[name] = value
            self._cond.notify_all()

    # ------------------------------------------------------------------ requests (callers' threads)
    def command_long(self, command: int, params: tuple[float, ...], label: str, timeout_s: float, retries: int, ack_command: int | None = None) -> int:
        """COMMAND_LONG with COMMAND_ACK check, timeout and retry. Returns MAV_RESULT ACCEPTED or raises OffboardRejected."""
        link = self._link
        ack_id = command if ack_command is None else ack_command
        p = tuple(params) + (0.0,) * (7 - len(params))
        last: int | None = None
        sent_at = time.monotonic()
        for attempt in range(retries):
            with self._cond:
                self._acks.pop(ack_id, None)
            msg = link.mav.command_long_encode(link.target_system, link.target_component, command, attempt, *p)
            link.send_message(msg)
            deadline = time.monotonic() + timeout_s
            with self._cond:
                while True:
                    result = self._acks.get(ack_id)
                    if result == MAV_RESULT_IN_PROGRESS:
                        self._acks.pop(ack_id, None)
                        deadline = time.monotonic() + timeout_s
                        result = None
                    if result is not None:
                        break
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or self._stop.is_set():
                        break
                    self._cond.wait(remaining)
            last = result
            if result == MAV_RESULT_ACCEPTED:
                return result
            if result is not None and result != MAV_RESULT_TEMPORARILY_REJECTED:
                break
        raise OffboardRejected(label, last, "; ".join(self._refusal_reasons(sent_at - 0.05, last)))

    def _refusal_reasons(self, since_monotonic: float, result: int | None) -> list[str]:
        """The vehicle's last two texts since ``since_monotonic`` [s], the reason that goes with a refusal.

        ArduPilot queues its STATUSTEXT and may send it after the COMMAND_ACK it explains, so after a
        refusal (an ACK that is not ACCEPTED) without a text yet, wait up to REFUSAL_TEXT_WAIT_S for one."""
        deadline = time.monotonic() + (REFUSAL_TEXT_WAIT_S if result is not None else 0.0)
        with self._cond:
            while not self.texts_since(since_monotonic):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    break
                self._cond.wait(remaining)
        return self.texts_since(since_monotonic)[-2:]

    def texts_since(self, t_monotonic: float) -> list[str]:
        """The vehicle's reassembled texts received since host monotonic time ``t_monotonic`` [s], oldest first."""
        return [text for t, _, text in list(self._link.stats.statustext) if t >= t_monotonic]

    def wait_heartbeat_mode(self, mode: str, timeout_s: float) -> bool:
        """Wait (bounded) until the autopilot's HEARTBEAT reports ``mode``; True when it does."""
        link = self._link
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while link.last_heartbeat is None or link.last_heartbeat.mode != mode:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    return False
                self._cond.wait(remaining)
        return True

    def arm(self, timeout_s: float, retries: int) -> None:
        self.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "COMMAND_LONG COMPONENT_ARM_DISARM arm", timeout_s, retries)

    def set_message_interval(self, msg_id: int, rate_hz: float, timeout_s: float, retries: int) -> None:
        interval_us = -1.0 if rate_hz <= 0 else 1e6 / rate_hz
        self.command_long(
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(msg_id), interval_us),
            f"SET_MESSAGE_INTERVAL msg {msg_id} at {rate_hz:g} Hz", timeout_s, retries,
        )

    def set_message_interval_nowait(self, msg_id: int, rate_hz: float) -> None:
        """SET_MESSAGE_INTERVAL without waiting for the ACK (re-assertion from the supervisor)."""
        link = self._link
        link.send_message(link.mav.command_long_encode(
            link.target_system, link.target_component, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, float(msg_id), 1e6 / rate_hz, 0, 0, 0, 0, 0))

    def request_message(self, msg_id: int, timeout_s: float) -> bool:
        """MAV_CMD_REQUEST_MESSAGE; True once the message arrived (read it with the link's typed accessor, e.g.
        ``link.autopilot_version()``), False on refusal or timeout (no raise)."""
        latest = self._link.latest
        name = mavlink.mavlink_map[msg_id].msgname if msg_id in mavlink.mavlink_map else str(msg_id)
        with self._cond:
            latest.pop(name, None)
        try:
            self.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, (float(msg_id),), f"REQUEST_MESSAGE {name}", timeout_s, 1)
        except OffboardRejected:
            return False
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while name not in latest:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(remaining)
            return True

    def _param_exchange(self, name: str, request, timeout_s: float, retries: int, accept=lambda value: True) -> float | None:
        """Send ``request`` (PARAM_REQUEST_READ or PARAM_SET for ``name``) up to ``retries`` times, each time
        waiting ``timeout_s`` [s] for a PARAM_VALUE of ``name``; the first value ``accept`` takes (a value it
        refuses starts the next try at once), or None."""
        try:
            for _ in range(retries):
                with self._cond:
                    self._params.pop(name, None)
                    self._awaited_params.add(name)
                self._link.send_message(request)
                deadline = time.monotonic() + timeout_s
                with self._cond:
                    while name not in self._params:
                        remaining = deadline - time.monotonic()
                        if remaining <= 0:
                            break
                        self._cond.wait(remaining)
                    if name in self._params and accept(self._params[name]):
                        return self._params[name]
            return None
        finally:
            with self._cond:
                self._awaited_params.discard(name)
                self._params.pop(name, None)

    def param_read(self, name: str, timeout_s: float, retries: int) -> float | None:
        """PARAM_REQUEST_READ by name; the value, or None when the autopilot does not answer."""
        link = self._link
        request = link.mav.param_request_read_encode(link.target_system, link.target_component, name.encode(), -1)
        return self._param_exchange(name, request, timeout_s, retries)

    def param_set(self, name: str, value: float, timeout_s: float, retries: int) -> bool:
        """PARAM_SET; True when the PARAM_VALUE echo carries the new value."""
        link = self._link
        request = link.mav.param_set_encode(
            link.target_system, link.target_component, name.encode(), float(value), mavlink.MAV_PARAM_TYPE_REAL32)
        wanted = struct.unpack("<f", struct.pack("<f", float(value)))[0]  # PARAM_VALUE carries a float32
        return self._param_exchange(name, request, timeout_s, retries, accept=lambda echoed: echoed == wanted) is not None
