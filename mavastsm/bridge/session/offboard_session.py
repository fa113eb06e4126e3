"""Engagement state machine, the per-sample control cycle driver, failsafes and the supervisor tick.

Threads: the link's reader thread calls ``on_attitude`` / ``on_heartbeat`` (the control cycle runs
right there, so the ATTITUDE -> SET_ATTITUDE_TARGET path has no thread hand-off); the bridge's
supervisor thread calls ``tick`` at ``timing.hold_send_hz`` (stale ATTITUDE, link loss, duration,
pre-stream and level-hold sends, telemetry, log flushing). One lock guards the state. Nothing here
raises inside the loop: problems become a FailsafeReason. What a sample becomes before the state machine acts on it
(validation, vehicle restarts, duplicates, dt, the achieved rate, late HEARTBEATs) is ``sample_stage.SampleStage``'s;
where its decisions go (the setpoint gate, the samples kept, log rows, telemetry, latencies) is
``session_output.SessionOutput``'s; every count is in ``session_counters.SessionCounters``.

States::

    waiting --(guided mode and armed)--> engage_pending --(next sample)--> engaged
    prestream  (hold setpoints streamed before the mode request / while waiting on PX4)
    takeoff    (level attitude + bounded climb-rate thrust until the altitude is reached)
    engaged --(failsafe / stop / duration)--> holding --(hold time)--> handback --> done
    engaged/holding --(pilot leaves guided)--> paused (reengage) or done (MODE_CHANGED)
    handback after STALE_ATTITUDE/LINK_LOST/VEHICLE_RESTARTED --(reengage)--> paused --(guided and armed)--> engage_pending
    any --(vehicle restart: time_boot_ms back by > 3 s, or HEARTBEAT back after a gap)--> new vehicle session:
        bookkeeping reset; an active state stops commanding at once (paused with reengage, else done)
"""

from __future__ import annotations

import math
import threading
import time
from enum import Enum
from typing import Callable

from ...state_types import FailsafeReason
from ...telemetry import ControlSample, TelemetryBuffer
from ..bridge_config import BridgeConfig
from ..cycle.control_cycle import ControlCycle
from ..record.flight_log import FlightLog
from ..link.messages import AttitudeSample, HeartbeatInfo
from .sample_stage import SampleStage
from .session_counters import SessionCounters
from .session_output import SessionOutput
from ..link.messages import Setpoint
from ..cycle.setpoint_mapping import level_hold_setpoint, rate_setpoint, takeoff_approach

HOVER_FOLLOW_S = 0.25  # [s] host time between two looks at the vehicle's hover collective while pre-streaming
REENGAGE_AFTER = frozenset({FailsafeReason.STALE_ATTITUDE, FailsafeReason.LINK_LOST, FailsafeReason.VEHICLE_RESTARTED})  # --reengage


class SessionState(str, Enum):
    """The session's states. A ``str`` (equal to and hashing like its value), so ``state == "engaged"`` and
    lookups keyed by the words (flight_log.PHASE_OF_STATE) keep working."""

    WAITING = "waiting"  # for the pilot/ground station (or our requests) to select a guided mode and arm
    PRESTREAM = "prestream"  # streaming level setpoints before the mode request (PX4 OFFBOARD needs it)
    TAKEOFF = "takeoff"  # the bridge's bounded level climb (--takeoff)
    ENGAGE_PENDING = "engage_pending"  # guided + armed: the next ATTITUDE engages the controller
    ENGAGED = "engaged"  # the controller's cycles
    HOLDING = "holding"  # level hold after a stop or failsafe
    HANDBACK = "handback"  # the hold is over: the bridge hands the vehicle back (on_exit / on_failsafe)
    PAUSED = "paused"  # handed back, waiting to re-engage (--reengage)
    DONE = "done"

    def __hash__(self) -> int:
        return str.__hash__(self)

    def __str__(self) -> str:
        return self.value


S = SessionState
# The one transition table: every change of OffboardSession.state goes through OffboardSession._go, which checks it.
TRANSITIONS: dict[SessionState, frozenset[SessionState]] = {
    S.WAITING: frozenset({S.WAITING, S.PRESTREAM, S.TAKEOFF, S.ENGAGE_PENDING, S.HOLDING, S.DONE}),
    S.PRESTREAM: frozenset({S.PRESTREAM, S.WAITING, S.TAKEOFF, S.ENGAGE_PENDING, S.HOLDING, S.DONE}),
    S.TAKEOFF: frozenset({S.ENGAGE_PENDING, S.HOLDING, S.HANDBACK, S.PAUSED, S.DONE}),
    # engage_pending is set again by start-up when the mode ACK lands after the HEARTBEAT already engaged
    S.ENGAGE_PENDING: frozenset({S.ENGAGE_PENDING, S.ENGAGED, S.WAITING, S.HOLDING, S.HANDBACK, S.PAUSED, S.DONE}),
    S.ENGAGED: frozenset({S.ENGAGE_PENDING, S.HOLDING, S.HANDBACK, S.PAUSED, S.DONE}),
    S.HOLDING: frozenset({S.HANDBACK, S.PAUSED, S.DONE}),
    S.HANDBACK: frozenset({S.PAUSED, S.DONE}),
    S.PAUSED: frozenset({S.ENGAGE_PENDING, S.DONE}),
    S.DONE: frozenset({S.DONE}),
}
ACTIVE_STATES = frozenset({S.ENGAGED, S.ENGAGE_PENDING, S.HOLDING, S.TAKEOFF})


class OffboardSession:
    """Runs the control cycle for one link. See module docstring for states.

    Parameters
    ----------
    link : object with ``send_setpoint(Setpoint)`` and ``seconds_since_heartbeat()``
    cycle : ControlCycle
    config : BridgeConfig
    telemetry : TelemetryBuffer (written every cycle, never waited on)
    flight_log : FlightLog
    reengage : resume (with reset) when the pilot returns to the guided mode
    duration_s : engaged time on the vehicle clock after which the session stops (inf = until stopped)
    clock_ns : host monotonic clock [ns] (injectable for tests)
    """

    def __init__(self, link, cycle: ControlCycle, config: BridgeConfig, telemetry: TelemetryBuffer, flight_log: FlightLog,
                 reengage: bool = False, duration_s: float = math.inf, clock_ns=time.monotonic_ns) -> None:
        self.link = link
        self.cycle = cycle
        self.config = config
        self.reengage = reengage
        self.duration_s = duration_s
        self.clock_ns = clock_ns
        self.guided_modes = cycle.profile.guided_modes
        self.lock = threading.RLock()
        self.state = SessionState.WAITING
        self.unexpected_transitions: list[tuple[str, str]] = []  # against TRANSITIONS (a bug if any)
        self.failsafe: FailsafeReason | None = None
        self.active_reason: FailsafeReason | None = None
        self.end_reason = ""
        self.handback_due = threading.Event()
        self.done = threading.Event()
        self.require_armed = True
        self.counters = SessionCounters()
        self.sample_stage = SampleStage(config, self.counters, self.lock, link)  # dt, duplicates, restarts, rate
        self.output = SessionOutput(link, cycle.gate, self.counters, telemetry, flight_log, config.timing.samples_in_memory)
        self.fault_summary = ""  # the first line of the last one
        self._consecutive_overrun = 0
        self._last_prestream_ns = 0
        self.first_prestream_ms: int | None = None  # vehicle time of the first pre-stream setpoint's sample
        self._activated_ns = 0  # when the current active state began (stale timing starts there)
        self._hold_start_ms: int | None = None
        self._hold_start_ns = 0
        self._takeoff = None  # (target_alt_m, start_ms)
        self.altitude_fn = lambda: float("nan")  # [m] above home, read on the reader thread (set by the bridge)
        self._takeoff_reached_ms: int | None = None
        self.last_heartbeat: HeartbeatInfo | None = None
        self.recovered_failsafes: list[FailsafeReason] = []  # failsafes followed by a re-engagement (reengage)
        self.session_events: list[str] = []  # why each new vehicle session was declared (logged by the bridge)
        # called with the engagement sample's vehicle time [s] before its first setpoint goes out (set by the bridge)
        self.on_engage: Callable[[float], None] | None = None
        self.takeoff_expected = False  # expect_takeoff .. start_takeoff: a guided, armed HEARTBEAT does not engage
        # the hover collective the vehicle flies now (set by the bridge where the autopilot gives it, PX4): vehicle
        # time [ms] -> a measurement with ``hover_norm``, or why there is none (str); asked while pre-streaming (at most
        # every HOVER_FOLLOW_S) and at each engagement, never while engaged
        self.hover_source: Callable[[int], object] | None = None
        self.hover_measurement: object | None = None  # the last answer (the measurement flown, or why none)
        self._hover_asked_ns: int | None = None

    @property
    def last_ms(self) -> int | None:  # [ms] the last sample accepted (None: none yet, or a new vehicle session)
        return self.sample_stage.last_ms

    # ------------------------------------------------------------------ helpers (lock held)
    def _record(self, sample: ControlSample) -> None:
        self.output.record(sample, self.state, self.last_heartbeat, self.altitude_fn)

    def _log_phase_row(self, state: str, s: AttitudeSample, sp: Setpoint | None = None) -> None:
        self.output.log_phase_row(state, s, sp, self.last_heartbeat, self.altitude_fn)

    def _hold_setpoint(self) -> Setpoint:
        return self.cycle.level_hold(self.sample_stage.last_yaw_rad)

    def _trigger(self, reason: FailsafeReason, end_reason: str = "") -> None:
        """Enter the level hold because of ``reason`` (first reason wins; stop requests keep their own)."""
        if self.state not in ACTIVE_STATES and self.state not in ("waiting", "prestream"):
            return
        if self.state == SessionState.HOLDING:
            return
        if reason is not FailsafeReason.OPERATOR_STOP:
            self.failsafe = reason
        self.active_reason = reason
        self.end_reason = end_reason or reason.value
        self._go(S.HOLDING)
        self._hold_start_ms = self.last_ms
        self._hold_start_ns = self.clock_ns()
        shown = None if end_reason == "duration complete" else reason  # a normal end is not shown as a failsafe
        self._record(ControlSample(self.last_ms / 1000.0 if self.last_ms else float("nan"), euler_rad=self.sample_stage.last_euler or (float("nan"),) * 3, failsafe=shown))

    # ------------------------------------------------------------------ reader thread
    def on_attitude(self, s: AttitudeSample) -> None:
        """One ATTITUDE from the target autopilot (reader thread). Never raises."""
        with self.lock:
            stage = self.sample_stage
            problem = stage.problem(s)
            if problem is not None:
                if self.state in ACTIVE_STATES:
                    if stage.consecutive_invalid >= self.config.timing.invalid_samples:
                        self._trigger(FailsafeReason.INVALID_INPUT, f"{FailsafeReason.INVALID_INPUT.value} ({problem})")
                    self.output.send(self._hold_setpoint())
                return
            restarted = stage.restart(s)
            if restarted is not None:
                self._new_vehicle_session(restarted, FailsafeReason.VEHICLE_RESTARTED)
            dt = stage.accept(s, engaged=self.state == SessionState.ENGAGED)
            if dt is None:
                return
            try:
                self._run_state(s, dt)
            except Exception as exc:  # the controller, mapping, reference or telemetry failed: never silent
                self._controller_fault(exc)
                return
            stage.mark_fresh(s)

    def _controller_fault(self, exc: Exception) -> None:
        """An exception inside the cycle (lock held): CONTROLLER_FAULT with its one-line summary, level hold."""
        self.counters.controller_faults += 1
        text = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
        self.fault_summary = text
        reason = FailsafeReason.CONTROLLER_FAULT
        try:
            if self.state in ACTIVE_STATES and self.state != "holding":
                self._trigger(reason, f"{reason.value} ({text})")
            if self.state in ACTIVE_STATES:
                self.output.send(self._hold_setpoint())
        except Exception:  # the hold itself must not take the reader thread down; the stale check still runs
            self.counters.blocked_setpoints += 1

    def _run_state(self, s: AttitudeSample, dt: float) -> None:
        """The per-sample action of the current state (lock held); may raise, see on_attitude."""
        state = self.state
        if state == SessionState.ENGAGE_PENDING:
            self._follow_vehicle_hover()
            self.cycle.engage(s)
            self.counters.engagements += 1
            if self.on_engage is not None and not self.cycle.identifying:  # with a phase: when the profile starts
                self.on_engage(s.time_boot_ms / 1000.0)
            self._go(S.ENGAGED)
            state = self.state
            dt = self.sample_stage.period_s
        if state == SessionState.ENGAGED:
            self._control(s, dt)
        elif state == SessionState.HOLDING:
            hold = self._hold_setpoint()
            self.output.send(hold)
            self._log_phase_row(state, s, hold)
            if self._hold_start_ms is not None and (s.time_boot_ms - self._hold_start_ms) / 1000.0 >= self.config.timing.failsafe_hold_s:
                self._go(S.HANDBACK)
                self.handback_due.set()
        elif state == SessionState.TAKEOFF:
            sent = self._takeoff_step(s)
            if self.state != "holding":  # a takeoff timeout has already written its failsafe record
                self._log_phase_row(state, s, sent)  # the state it was in: the step may have ended it
        elif state == SessionState.HANDBACK:
            self._log_phase_row(state, s)
        elif state == SessionState.PRESTREAM:
            self._prestream()

    def _follow_vehicle_hover(self) -> None:
        """Ask ``hover_source`` for the hover collective the vehicle flies now and fly it (lock held). A failed
        measurement keeps the hover flown so far (the last measurement, or the preflight's)."""
        if self.hover_source is None or self.last_ms is None:
            return
        self._hover_asked_ns = self.clock_ns()
        answer = self.hover_source(self.last_ms)
        hover = getattr(answer, "hover_norm", None)
        if hover is not None:
            self.cycle.set_hover_collective(hover)
            self.hover_measurement = answer
        elif not hasattr(self.hover_measurement, "hover_norm"):
            self.hover_measurement = answer

    def _prestream(self) -> None:
        """Neutral setpoint (zero body rates, hold thrust, mask 0x80) streamed before/while waiting for the mode."""
        now = self.clock_ns()
        if self._hover_asked_ns is None or (now - self._hover_asked_ns) * 1e-9 >= HOVER_FOLLOW_S:
            self._follow_vehicle_hover()
        self._last_prestream_ns = self.clock_ns()
        if self.first_prestream_ms is None:
            self.first_prestream_ms = self.last_ms
        self.output.send(rate_setpoint((0.0, 0.0, 0.0), self.cycle.thrust_hold((0.0, 0.0, 0.0))))

    def _control(self, s: AttitudeSample, dt: float) -> None:
        res = self.cycle.step(s, dt)
        if res.failsafe is not None:
            self._record(res.telemetry())
            self._trigger(res.failsafe, f"{res.failsafe.value} ({res.detail})" if res.detail else "")
            self.output.send(self._hold_setpoint())
            return
        assert res.setpoint is not None
        if res.profile_started and self.on_engage is not None:
            self.on_engage(s.time_boot_ms / 1000.0)
        latency = self.output.send_cycle(res.setpoint, s.rx_ns, self.clock_ns)
        self._record(res.telemetry(latency))
        if latency > self.sample_stage.period_s:
            self._consecutive_overrun += 1
            self.counters.overruns += 1
            if self._consecutive_overrun >= self.config.timing.overrun_cycles:
                self._trigger(FailsafeReason.LOOP_OVERRUN)
        else:
            self._consecutive_overrun = 0
        if not self.cycle.identifying and self.cycle.reference_time_s(s.time_boot_ms) >= self.duration_s:
            self._trigger(FailsafeReason.OPERATOR_STOP, "duration complete")

    def _takeoff_step(self, s: AttitudeSample) -> Setpoint | None:
        """Bounded climb at level attitude (climb-rate thrust ramped, never above takeoff_climb_norm, tapered over
        the last takeoff_approach_m: ``takeoff_approach``), then a level hold at zero climb for takeoff_settle_s,
        then the profile engages (all on the vehicle clock).
        Returns the setpoint sent (None when none was)."""
        target_m, start_ms = self._takeoff
        tc = self.config.thrust
        elapsed = (s.time_boot_ms - start_ms) / 1000.0
        alt = self.altitude_fn()
        if self._takeoff_reached_ms is None and math.isfinite(alt) and alt >= target_m:
            self._takeoff_reached_ms = s.time_boot_ms
        if self._takeoff_reached_ms is not None:
            sp = self.cycle.limited(level_hold_setpoint(self._takeoff_yaw, tc.climb_hold_norm))
            sent = self.output.send(sp)
            if (s.time_boot_ms - self._takeoff_reached_ms) / 1000.0 >= tc.takeoff_settle_s:
                self._go(S.ENGAGE_PENDING)
            return sp if sent else None
        if elapsed > tc.takeoff_timeout_s:
            self._trigger(FailsafeReason.TAKEOFF_TIMEOUT, f"takeoff did not reach {target_m:g} m in {tc.takeoff_timeout_s:g} s")
            return None
        ramp = min(1.0, elapsed / tc.takeoff_ramp_s) if tc.takeoff_ramp_s > 0 else 1.0
        thrust = tc.climb_hold_norm + min(ramp, takeoff_approach(target_m - alt, tc.takeoff_approach_m)) \
            * (tc.takeoff_climb_norm - tc.climb_hold_norm)
        sp = self.cycle.limited(level_hold_setpoint(self._takeoff_yaw, thrust))
        if sp is not None and self.output.send(sp):
            return sp
        return None

    def _new_vehicle_session(self, why: str, reason: FailsafeReason = FailsafeReason.LINK_LOST) -> None:
        """The autopilot restarted or came back after a link loss (lock held): forget its old clock; an active
        state stops commanding at once (never command a new vehicle session without re-engagement)."""
        self.counters.vehicle_sessions += 1
        self.sample_stage.forget_clock()
        self.session_events.append(why)
        if self.state in ACTIVE_STATES:
            # no setpoint (not even the level hold) to the new session: straight to the hand-back (a mode
            # request per on_failsafe); with reengage the bridge then waits for guided + armed again
            if self.failsafe is None:
                self.failsafe = reason
                self.end_reason = f"{reason.value}; {why}"
            self.active_reason = reason
            self._record(ControlSample(float("nan"), failsafe=reason))
            self._go(S.HANDBACK)
            self.handback_due.set()

    def pause_after_handback(self) -> None:
        """Hand-back done after a STALE_ATTITUDE/LINK_LOST/VEHICLE_RESTARTED failsafe with reengage: wait for the vehicle to come
        back in a guided mode and armed (bridge thread)."""
        with self.lock:
            self._pause()

    def _pause(self) -> None:  # wait for guided + armed again (--reengage; lock held)
        self._go(S.PAUSED)
        self._hold_start_ms = None

    def on_heartbeat(self, hb: HeartbeatInfo) -> None:
        """Autopilot HEARTBEAT (reader thread): mode/arming changes engage, pause or stop us at once."""
        with self.lock:
            now = self.clock_ns()
            back = self.sample_stage.heartbeat_back(hb, now)
            if back is not None:
                self._new_vehicle_session(back)
            self.last_heartbeat = hb
            guided = hb.mode in self.guided_modes
            ready = guided and (hb.armed or not self.require_armed)
            if self.sample_stage.late_heartbeat(hb, guided, now):
                return
            if self.state in ACTIVE_STATES and not guided:
                if self.state == SessionState.HOLDING:
                    # a stop or failsafe hold was in progress and the pilot took over: nothing to hand back;
                    # the reason that started the hold stays the run's reason
                    self.end_reason = f"{self.end_reason}; pilot took over in {hb.mode} during the level hold"
                    if self.reengage and self.failsafe in REENGAGE_AFTER:
                        # as the hand-back would have (a watchdog-rebooted vehicle says a manual mode first)
                        self._pause()
                        return
                    self._go(S.DONE)
                    self.done.set()
                    return
                self.active_reason = FailsafeReason.MODE_CHANGED
                if self.reengage:
                    self._go(S.PAUSED)
                    self._record(ControlSample(self.last_ms / 1000.0 if self.last_ms else float("nan"), failsafe=FailsafeReason.MODE_CHANGED))
                else:
                    self.failsafe = FailsafeReason.MODE_CHANGED
                    self.end_reason = f"{FailsafeReason.MODE_CHANGED.value} (now {hb.mode})"
                    self._go(S.DONE)
                    self._record(ControlSample(self.last_ms / 1000.0 if self.last_ms else float("nan"), failsafe=FailsafeReason.MODE_CHANGED))
                    self.done.set()
            elif self.state in (SessionState.WAITING, SessionState.PAUSED, SessionState.PRESTREAM) and ready and not self.takeoff_expected:
                if self.state == SessionState.PAUSED and self.failsafe in REENGAGE_AFTER:
                    self.recovered_failsafes.append(self.failsafe)
                    self.failsafe = None  # recovered: the run's end decides its own hand-back again
                    self.end_reason = ""
                self.active_reason = None
                self._enter("engage_pending")

    # ------------------------------------------------------------------ control from the bridge thread
    def set_nominal_rate(self, config: BridgeConfig) -> None:
        """The loop's nominal ATTITUDE rate changed (the vehicle sends slower than it accepted): missed cycles
        and overruns are judged against ``config.timing.attitude_rate_hz`` from now on (bridge thread)."""
        with self.lock:
            self.config = config
            self.sample_stage.set_nominal_rate(config)
            self.output.limits = config.limits

    def expect_takeoff(self) -> None:
        """The bridge's own takeoff follows its mode and arming requests (bridge thread): until ``start_takeoff``, a
        guided, armed HEARTBEAT must not engage the law on the ground (it did once, in CI: one cycle of the law
        before the takeoff, then an engaged -> takeoff transition)."""
        with self.lock:
            self.takeoff_expected = True

    def start_takeoff(self, target_alt_m: float) -> None:
        with self.lock:
            self.takeoff_expected = False
            self._takeoff_reached_ms = None
            self._takeoff = (target_alt_m, self.last_ms or 0)
            self._takeoff_yaw = self.sample_stage.last_yaw_rad
            self._enter("takeoff")

    def finish(self) -> None:
        """End the session for good (state done, ``done`` set): the bridge's last word after the hand-back, or
        after a failed start."""
        with self.lock:
            self._go(S.DONE)
            self.done.set()

    def mode_request_acked(self) -> None:
        """The vehicle ACKed the bridge's own request for a guided mode (bridge thread): see SampleStage.late_heartbeat."""
        with self.lock:
            self.sample_stage.mode_request_acked(self.clock_ns())

    def set_state(self, state: str) -> None:
        with self.lock:
            self._enter(state)

    def _enter(self, state: str) -> None:
        if state in ACTIVE_STATES and self.state not in ACTIVE_STATES:
            self._activated_ns = self.clock_ns()
        self._go(SessionState(state))

    def _go(self, state: SessionState) -> None:
        """The one place the state changes (lock held). A change the table does not list is a bug: it is made
        (never an exception mid-flight) and recorded in ``unexpected_transitions`` for the tests to catch."""
        if state not in TRANSITIONS[self.state]:
            self.unexpected_transitions.append((self.state.value, state.value))
        self.state = state

    def request_stop(self, reason: FailsafeReason = FailsafeReason.OPERATOR_STOP, end_reason: str = "operator stop") -> None:
        with self.lock:
            if self.state in ACTIVE_STATES and self.state != "holding":
                self._trigger(reason, end_reason)
            elif self.state in (SessionState.WAITING, SessionState.PRESTREAM, SessionState.PAUSED):
                self.end_reason = end_reason
                self._go(S.DONE)
                self.done.set()

    def identity_conflict(self, text: str) -> None:
        """Two vehicles claim the target's identity (the link's clock, ``vehicle_clock``; ``text`` names both): in
        flight the named failsafe (level hold, hand-back), before engagement the run's end with that failsafe."""
        reason = FailsafeReason.IDENTITY_CONFLICT
        with self.lock:
            if self.state in ACTIVE_STATES:
                self._trigger(reason, f"{reason.value}: {text}")
            elif self.state in (SessionState.WAITING, SessionState.PRESTREAM, SessionState.PAUSED):
                self.failsafe = reason
                self.end_reason = text
                self._go(S.DONE)
                self.done.set()

    def tick(self) -> None:
        """Supervisor step (bridge thread, ``timing.hold_send_hz``): stale/link checks and hold sends."""
        tm = self.config.timing
        with self.lock:
            now = self.clock_ns()
            state = self.state
            if state == SessionState.PRESTREAM:
                if (now - self._last_prestream_ns) * 1e-9 * tm.hold_send_hz >= 1.0:
                    self._prestream()
                return
            if state not in ACTIVE_STATES:
                return
            fresh_ns = max(self.sample_stage.last_fresh_ns or 0, self._activated_ns)
            stale = (now - fresh_ns) * 1e-9 > tm.stale_timeout_s
            link_lost = self.link.seconds_since_heartbeat() > self.config.link.link_loss_timeout_s
            if link_lost and state != "holding":
                self._trigger(FailsafeReason.LINK_LOST)
            elif stale and state != "holding":
                self._trigger(FailsafeReason.STALE_ATTITUDE)
            if self.state == SessionState.HOLDING and (stale or link_lost):
                self.output.send(self._hold_setpoint())
                if (now - self._hold_start_ns) * 1e-9 >= tm.failsafe_hold_s:
                    self._go(S.HANDBACK)
                    self.handback_due.set()
