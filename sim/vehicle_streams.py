"""The message streams of the simulated ArduCopter: requested intervals, due times and the send schedule.

ArduCopter's stream model (GCS_MAVLink_Copter.cpp): streams off by default except HEARTBEAT (1 Hz) and what the
``SR0_*`` parameters pre-seed; REQUEST_DATA_STREAM groups and MAV_CMD_SET_MESSAGE_INTERVAL share one interval per
message (the last writer wins); no interval shorter than 1 / (0.8 * SCHED_LOOP_RATE). Sent either on an interval
grid counted from boot, or, with the profile's loop-tick ``stream_timing``, from ArduCopter's loop ticks in whole
milliseconds.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .vehicle_link import VehicleLink

# --- streams (ArduCopter GCS_MAVLink_Copter.cpp stream tables, the subset we emit) ----------------------
STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: (mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,),
    mavlink.MAV_DATA_STREAM_POSITION: (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                       mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    mavlink.MAV_DATA_STREAM_EXTRA1: (mavlink.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA2: (mavlink.MAVLINK_MSG_ID_VFR_HUD,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS),
}
STREAM_RATE_PARAMS = {  # stream id -> the SR0_* parameter that seeds its default rate [Hz]
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: "SR0_EXT_STAT", mavlink.MAV_DATA_STREAM_RC_CHANNELS: "SR0_RC_CHAN",
    mavlink.MAV_DATA_STREAM_POSITION: "SR0_POSITION", mavlink.MAV_DATA_STREAM_EXTRA1: "SR0_EXTRA1",
    mavlink.MAV_DATA_STREAM_EXTRA2: "SR0_EXTRA2", mavlink.MAV_DATA_STREAM_EXTRA3: "SR0_EXTRA3",
}
GROUP_OF_MESSAGE = {mid: group for group, mids in STREAM_GROUPS.items() for mid in mids}
HEARTBEAT_INTERVAL_US = 1_000_000
LOOP_RATE_FRACTION = 0.8       # streams capped at 80 % of SCHED_LOOP_RATE


class StreamScheduler:
    """Which message goes out when: the requested interval of each message, its next due time, and the sending.

    Parameters
    ----------
    link : VehicleLink
        Clock (``now_us``), parameters (``SR0_*``, ``SCHED_LOOP_RATE``) and the profile's ``stream_timing``.
    send_now : callable(msg_id)
        Encodes and sends one message (``TelemetryEncoder.send_now``).
    """

    def __init__(self, link: VehicleLink, send_now: Callable[[int], None]) -> None:
        self.link = link
        self._param = link.param
        self._send_now = send_now
        profile, firmware = link.profile, link.firmware
        # ArduCopter's whole-millisecond intervals, sent from loop ticks (the profile's stream_timing)
        auto_loop_ticks = profile.stream_timing == "auto" and firmware.denies_fast_message_intervals
        self.loop_tick_streams = profile.stream_timing == "loop-ticks" or auto_loop_ticks
        self.whole_ms_intervals = self.loop_tick_streams or firmware.denies_fast_message_intervals
        self._requested_us: dict[int, int | None] = {}   # msg id -> requested interval [us]; None = stopped
        self._next_due_us: dict[int, int] = {}
        self._last_sent_ms: dict[int, int] = {}  # loop-tick streams: ArduPilot's per-message last_sent_ms [ms]
        # stream-rate cap cache: the SCHED_LOOP_RATE value it was computed from, and the cap [us]
        self._cap_loop_rate_hz: float | None = None
        self._cap_interval_us = 0
        self._requested_us[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = HEARTBEAT_INTERVAL_US
        self._next_due_us[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = 0
        self._last_sent_ms[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = -HEARTBEAT_INTERVAL_US // 1000
        for mid in GROUP_OF_MESSAGE:
            self.set_interval(mid, self.default_interval_us(mid))

    def earliest_due_us(self, bound_us: int) -> int:
        """[us] the earliest due time of a live stream, or ``bound_us`` when that is earlier."""
        # every entry in _next_due_us is a live stream (set_interval drops stopped ones)
        return min(bound_us, *self._next_due_us.values())

    def emit_due(self, now_us: int) -> bool:
        """Send every stream message due at simulated time ``now_us`` [us]; True if an ATTITUDE went out."""
        if self.loop_tick_streams:
            return self._emit_on_loop_ticks(now_us)
        attitude_sent = False
        due_now = [(mid, due) for mid, due in self._next_due_us.items() if due <= now_us]
        for mid, due in due_now:
            interval = self.effective_interval_us(mid)
            if interval is None:
                continue
            self._send_now(mid)
            if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
                attitude_sent = True
            nxt = due + interval
            self._next_due_us[mid] = nxt if nxt > now_us else now_us + interval
        return attitude_sent

    def _emit_on_loop_ticks(self, now_us: int) -> bool:
        """ArduCopter's stream scheduler (GCS_MAVLINK::update_send) for every loop tick up to ``now_us``: on a tick,
        a message is due when ``millis - last_sent_ms >= interval_ms``; then ``last_sent_ms += interval_ms``, reset to
        ``millis`` when more than one interval behind. A stream faster than the tick grid therefore comes in runs
        of ticks with a skipped one (333 Hz from 400 Hz: 2, 3, 2, 3, 5 ms); time_boot_ms is the tick's millis.
        True if an ATTITUDE went out."""
        attitude_sent = False
        physics_now_us = now_us
        period_us = self.loop_period_us()
        while self._next_due_us:
            tick_us = min(self._next_due_us.values())
            if tick_us > physics_now_us:
                break
            self.link.now_us = tick_us
            tick_ms = tick_us // 1000
            for mid in [m for m, due in self._next_due_us.items() if due == tick_us]:
                interval = self.effective_interval_us(mid)
                if interval is None:
                    self._next_due_us.pop(mid, None)
                    continue
                interval_ms = interval // 1000
                last_ms = self._last_sent_ms.get(mid, tick_ms - interval_ms)
                while tick_ms - last_ms >= interval_ms:  # at most twice: ArduPilot's "pairs" when exactly one behind
                    self._send_now(mid)
                    attitude_sent = attitude_sent or mid == mavlink.MAVLINK_MSG_ID_ATTITUDE
                    last_ms += interval_ms
                    if tick_ms - last_ms > interval_ms:
                        last_ms = tick_ms
                self._last_sent_ms[mid] = last_ms
                self._next_due_us[mid] = self._first_tick_at_ms(last_ms + interval_ms, period_us)
        self.link.now_us = physics_now_us
        return attitude_sent

    @staticmethod
    def _first_tick_at_ms(ms: int, period_us: int) -> int:
        """[us] the first loop tick whose millis() reads at least ``ms``."""
        return -(-ms * 1000 // period_us) * period_us

    def loop_period_us(self) -> int:
        """[us] ArduCopter's main-loop period, 1/SCHED_LOOP_RATE as whole microseconds (2500 at 400 Hz)."""
        loop_hz = self._param("SCHED_LOOP_RATE", 400.0)
        if not (math.isfinite(loop_hz) and loop_hz > 0):
            loop_hz = 400.0
        return max(int(1e6 // loop_hz), 1)

    def _min_interval_us(self) -> int:
        """[us] the shortest interval a stream is capped to: 80 % of SCHED_LOOP_RATE; with whole-millisecond intervals
        ArduPilot's own rounding of it (cap_message_interval: 3 ms at 400 Hz, 2 ms at 500 Hz)."""
        loop_hz = self._param("SCHED_LOOP_RATE", 400.0)
        if loop_hz != self._cap_loop_rate_hz:  # recomputed only when the parameter changed (called per message)
            self._cap_loop_rate_hz = loop_hz
            hz = loop_hz if math.isfinite(loop_hz) and loop_hz > 0 else 400.0
            if self.whole_ms_intervals:
                self._cap_interval_us = max(int(self.loop_period_us() / (1000 * LOOP_RATE_FRACTION)), 1) * 1000
            else:
                self._cap_interval_us = int(math.ceil(1e6 / (LOOP_RATE_FRACTION * hz)))
        return self._cap_interval_us

    def whole_ms(self, interval_us: int | None) -> int | None:
        """An interval as ArduPilot keeps it (whole milliseconds, at least 1) when the wire model says so [us]."""
        if interval_us is None or not self.whole_ms_intervals:
            return interval_us
        return max(interval_us // 1000, 1) * 1000

    def effective_interval_us(self, msg_id: int) -> int | None:
        """Interval at which ``msg_id`` is emitted now [us], after the loop-rate cap; None when off."""
        requested = self._requested_us.get(msg_id)
        if requested is None:
            return None
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return requested
        return max(requested, self._min_interval_us())

    def default_interval_us(self, msg_id: int) -> int | None:
        """[us] the interval ``msg_id`` has before any request: 1 s for HEARTBEAT, its SR0_* rate, else None (off)."""
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return HEARTBEAT_INTERVAL_US
        group = GROUP_OF_MESSAGE.get(msg_id)
        if group is None:
            return None
        rate_hz = self._param(STREAM_RATE_PARAMS[group], 0.0)
        return self.whole_ms(int(1e6 / rate_hz)) if math.isfinite(rate_hz) and rate_hz > 0 else None

    def set_interval(self, msg_id: int, interval_us: int | None) -> None:
        """Set the requested interval of one message [us] (None = off); keeps the phase if unchanged."""
        before = self.effective_interval_us(msg_id)
        self._requested_us[msg_id] = interval_us
        after = self.effective_interval_us(msg_id)
        if after is None:
            self._next_due_us.pop(msg_id, None)
        elif self.loop_tick_streams:
            if after != before or msg_id not in self._next_due_us:
                # ArduPilot files the message with last_sent_ms = now: the first copy one interval later
                self._last_sent_ms[msg_id] = self.link.now_us // 1000
                self._next_due_us[msg_id] = self._first_tick_at_ms(self.link.now_us // 1000 + after // 1000,
                                                                   self.loop_period_us())
        elif after != before or msg_id not in self._next_due_us:
            # first copy on the interval grid counted from boot, so the sampling phase (and a lockstep
            # run) does not depend on the wall-clock moment the request arrived. Strictly after now:
            # what is due now was emitted before inbound data is handled at this instant, so a copy
            # due "now" would go out one physics tick late, off the grid, and shift the whole run
            self._next_due_us[msg_id] = (self.link.now_us // after + 1) * after

    def on_request_data_stream(self, msg: Any) -> None:
        """REQUEST_DATA_STREAM: one rate for every message of a group (or of all groups); 0 or stop turns them off."""
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        if msg.start_stop == 0:
            rate_hz = 0
        elif msg.req_message_rate > 0:
            rate_hz = msg.req_message_rate
        else:
            return
        groups = list(STREAM_GROUPS) if msg.req_stream_id == mavlink.MAV_DATA_STREAM_ALL else [msg.req_stream_id]
        for group in groups:
            for mid in STREAM_GROUPS.get(group, ()):
                self.set_interval(mid, self.whole_ms(int(1e6 / rate_hz)) if rate_hz > 0 else None)
