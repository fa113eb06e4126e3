"""The state stage: what an inbound sample becomes before the session's state machine acts on it.

Runs on the link's reader thread under the session's lock. ``OffboardSession.on_attitude`` asks it, in this order:
is the ATTITUDE valid (counted, with the streak the INVALID_INPUT failsafe reads), does it come from a restarted
vehicle (the clock going back, or a BOOT HEARTBEAT across an ATTITUDE gap), is it the last one again or older
(dropped, counted), and with which dt to step it (with the periods it shows missed and the achieved ATTITUDE rate
measured from ``time_boot_ms``). ``on_heartbeat`` asks whether a HEARTBEAT comes back after a gap, and whether it is
late (sent before the mode switch the vehicle just ACKed). It decides no state: the session does, from what this
returns.
"""

from __future__ import annotations

import threading

from ..bridge_config import BridgeConfig
from ..link.messages import AttitudeSample, HeartbeatInfo, is_vehicle_restart
from ..cycle.safety import attitude_sample_problem
from .session_counters import SessionCounters

CONFIRMED_FRAME_MS = 1000  # [ms] a restart's first frame at most this much after the frame that confirmed the new clock
# [s] after the bridge's own mode request was ACKed, a HEARTBEAT still showing a mode outside the guided ones is taken
# as late (built before the switch: PX4 can send one right after the ACK) until the first guided one, at most this long;
# over one HEARTBEAT period (1 Hz on both autopilots), so the next HEARTBEAT decides. After it, leaving = the pilot.
LATE_HEARTBEAT_S = 1.5


class SampleStage:
    """The last accepted sample (vehicle time, attitude), when a cycle last completed on one, the running rate
    measurement, the dt of each step, and what the HEARTBEATs said that a sample is judged by: their gaps, a BOOT
    state, lateness after an ACKed mode switch (see module docstring).

    Parameters
    ----------
    config : BridgeConfig (timing: nominal rate, dt clamp, stale timeout; limits: the input rate bound)
    counters : the session's SessionCounters (invalid, duplicate, dropped, missed, vehicle_restarts counted here)
    lock : the session's lock (taken here only by the bridge thread's calls: rate_window, record_achieved_rate)
    link : the link, for its vehicle clock's confirmation of a new clock (named in the restart's text)
    """

    def __init__(self, config: BridgeConfig, counters: SessionCounters, lock: threading.RLock, link) -> None:
        self.config = config
        self.counters = counters
        self.lock = lock
        self.link = link
        self.period_s = 1.0 / config.timing.attitude_rate_hz  # [s] nominal: the overrun bound, missed cycles' until measured
        self.last_ms: int | None = None  # vehicle time of the last sample accepted (None: no clock, or forgotten)
        self.last_fresh_ns: int | None = None  # host time a cycle last completed on a sample (the stale check's)
        self.last_yaw_rad = 0.0
        self.last_euler: tuple[float, float, float] | None = None
        self.consecutive_invalid = 0
        self._rate_win: tuple[int, int] | None = None  # (first_ms, count)
        self.achieved_rate_hz = float("nan")
        self._boot_heard = False  # a HEARTBEAT in MAV_STATE_BOOT since the last ATTITUDE frame (_boot_gap_s)
        self._heartbeat_rx_ns: int | None = None  # host time of the last HEARTBEAT (heartbeat_back)
        self._late_heartbeats_until_ns: int | None = None  # set by mode_request_acked, cleared by a guided HEARTBEAT
        self.late_mode_heartbeats: list[str] = []  # modes of the HEARTBEATs taken as late (LATE_HEARTBEAT_S)

    def set_nominal_rate(self, config: BridgeConfig) -> None:
        """The loop's nominal ATTITUDE rate changed (OffboardSession.set_nominal_rate, lock held)."""
        self.config = config
        self.period_s = 1.0 / config.timing.attitude_rate_hz

    def problem(self, s: AttitudeSample) -> str | None:
        """Why ``s`` cannot be used (counted invalid, the streak grows), or None (the streak ends). Validated before
        anything is decided on it: an invalid sample's time_boot_ms is not evidence of a restart."""
        problem = attitude_sample_problem(s.euler_rad, s.body_rates_rads, self.config.limits.max_input_rate_rads)
        if problem is None:
            self.consecutive_invalid = 0
            return None
        self.counters.invalid += 1
        self.consecutive_invalid += 1
        return problem

    def heartbeat_back(self, hb: HeartbeatInfo, now_ns: int) -> str | None:
        """A HEARTBEAT arrived at host time ``now_ns``: why it starts a new vehicle session (it comes back after a gap
        longer than ``link.link_loss_timeout_s``), or None. Its MAV_STATE_BOOT is kept until the next ATTITUDE frame
        (``_boot_gap_s``)."""
        prev, self._heartbeat_rx_ns = self._heartbeat_rx_ns, now_ns
        self._boot_heard = self._boot_heard or hb.booting
        if prev is not None and (now_ns - prev) * 1e-9 > self.config.link.link_loss_timeout_s:
            return f"HEARTBEAT back after {(now_ns - prev) * 1e-9:.1f} s"
        return None

    def mode_request_acked(self, now_ns: int) -> None:
        """The vehicle ACKed the bridge's own request for a guided mode at host time ``now_ns``: for LATE_HEARTBEAT_S,
        until a HEARTBEAT shows a guided mode, one still showing the old mode is late, not the pilot leaving."""
        self._late_heartbeats_until_ns = now_ns + int(LATE_HEARTBEAT_S * 1e9)

    def late_heartbeat(self, hb: HeartbeatInfo, guided: bool, now_ns: int) -> bool:
        """Whether ``hb`` (``guided``: its mode is a guided one) is late, sent before the ACKed switch (see
        mode_request_acked): its mode is kept in ``late_mode_heartbeats`` and the state machine does not act on it.
        A guided HEARTBEAT ends the grace."""
        if guided:
            self._late_heartbeats_until_ns = None
        elif self._late_heartbeats_until_ns is not None and now_ns < self._late_heartbeats_until_ns:
            self.late_mode_heartbeats.append(hb.mode)
            return True
        return False

    def restart(self, s: AttitudeSample) -> str | None:
        """Why the valid sample ``s`` comes from a restarted vehicle (counted), or None: its clock went back by more
        than the restart threshold, or the autopilot said it was booting in the gap before it (``_boot_gap_s``)."""
        boot_gap_s = self._boot_gap_s(s)
        if self.last_ms is None or (boot_gap_s is None and not is_vehicle_restart(self.last_ms, s.time_boot_ms)):
            return None
        self.counters.vehicle_restarts += 1
        booted = f"; HEARTBEAT said MAV_STATE_BOOT in {boot_gap_s:.1f} s without ATTITUDE" if boot_gap_s is not None else ""
        return (f"vehicle restarted (time_boot_ms {self.last_ms} -> {s.time_boot_ms} ms"
                f"{self._confirmation_note(s.time_boot_ms)}{booted})")

    def forget_clock(self) -> None:
        """A new vehicle session: the old clock, its rate window and the invalid streak are forgotten."""
        self.last_ms = None
        self._rate_win = None
        self.consecutive_invalid = 0

    def accept(self, s: AttitudeSample, engaged: bool) -> float | None:
        """The dt [s] to step the valid sample ``s`` with (clamped to ``[dt_min_s, dt_max_s]``; the nominal period for
        the first of a clock), or None when it is the last one again or older (counted duplicate / dropped). Counts
        the periods missed before it when ``engaged`` (the span ``cycles`` counts, no other)."""
        if self.last_ms is not None:
            if s.time_boot_ms == self.last_ms:
                self.counters.duplicate += 1
                return None
            if s.time_boot_ms < self.last_ms:
                self.counters.dropped += 1
                return None
        self._update_rate(s.time_boot_ms, 1 + s.superseded)
        if self.last_ms is None:
            dt = self.period_s
        else:
            dt_raw = (s.time_boot_ms - self.last_ms) / 1000.0
            period = 1.0 / self.achieved_rate_hz if self.achieved_rate_hz > 0 else self.period_s
            if dt_raw > 2.0 * period and engaged:
                # samples the vehicle never sent or we never saw; a burst's superseded ones were seen. The
                # threshold is two periods, not 1.5: an autopilot sends on its own loop grid (ArduCopter at
                # 333 Hz on a 400 Hz loop alternates 2.5 and 5 ms gaps), so 1.67 periods is on schedule
                self.counters.missed += max(0, round(dt_raw / period) - 1 - s.superseded)
            if s.superseded and engaged and s.burst_start_ns:
                # the burst's first sample waited unanswered until this one arrived: a vehicle's own burst (pairs
                # microseconds apart) is not late; a bridge busy for a period or more is, once per period it sat on it
                self.counters.superseded_waits += round((s.rx_ns - s.burst_start_ns) * 1e-9 / period)
            dt = min(max(dt_raw, self.config.timing.dt_min_s), self.config.timing.dt_max_s)
        self.last_ms = s.time_boot_ms
        self.last_euler = s.euler_rad
        self.last_yaw_rad = s.euler_rad[2]
        return dt

    def mark_fresh(self, s: AttitudeSample) -> None:
        """A cycle completed on ``s``: fresh only then, so a cycle that keeps failing goes stale."""
        self.last_fresh_ns = s.rx_ns

    def _update_rate(self, t_ms: int, samples: int = 1) -> None:
        """Achieved rate from vehicle time: ``samples`` the vehicle sent up to ``t_ms`` (a burst's superseded ones too)."""
        if self._rate_win is None:
            self._rate_win = (t_ms, 0)
            return
        first, n = self._rate_win
        n += samples
        if t_ms - first >= 1000:
            self.achieved_rate_hz = n * 1000.0 / (t_ms - first)
            self._rate_win = (t_ms, 0)
        else:
            self._rate_win = (first, n)

    def _boot_gap_s(self, s: AttitudeSample) -> float | None:
        """The ATTITUDE gap [s] before ``s`` when the autopilot said it was booting in it (HEARTBEAT system_status
        MAV_STATE_BOOT, as ArduCopter sends until it is ready) and the gap lasted at least the stale timeout: a restart
        even when the new clock reads later than the old one (a short uptime before the reboot). Otherwise None.
        Neither alone is one: a forged BOOT HEARTBEAT inside a live stream is forgotten at the next frame, and a gap
        is only a gap."""
        booted, self._boot_heard = self._boot_heard, False
        if not booted or self.last_fresh_ns is None:
            return None
        gap_s = (s.rx_ns - self.last_fresh_ns) * 1e-9
        return gap_s if gap_s >= self.config.timing.stale_timeout_s else None

    def _confirmation_note(self, t_ms: int) -> str:
        """How long the link's vehicle clock took to confirm the new clock whose frame ``t_ms`` is (vehicle_clock;
        the frame delivered may be a newer one of the same burst)."""
        confirmed = getattr(getattr(self.link, "clock", None), "confirmed", None)
        if confirmed is None or not 0 <= t_ms - confirmed[0] <= CONFIRMED_FRAME_MS:
            return ""
        return f"; new clock confirmed {confirmed[1]:.0f} ms after its first frame"

    # ------------------------------------------------------------------ bridge thread (start-up rate measurement)
    def rate_window(self) -> tuple[int, int, int] | None:
        """(first time_boot_ms, samples counted since, last time_boot_ms) of the running ATTITUDE rate measurement,
        or None before it has two samples."""
        with self.lock:
            win, last = self._rate_win, self.last_ms
        if win is None or last is None or win[1] < 2:
            return None
        return win[0], win[1], last

    def record_achieved_rate(self, rate_hz: float) -> None:
        """The achieved ATTITUDE rate [Hz] measured at start-up (what missed cycles and overruns are judged by)."""
        with self.lock:
            self.achieved_rate_hz = float(rate_hz)
