"""The supervisor thread's duties besides the session's own tick: say what is new in the session, once each, and keep
the ATTITUDE stream coming. Each class holds only what it needs to say or ask a thing once; ``Bridge._supervise``
calls them every tick (at ``timing.hold_send_hz``)."""

from __future__ import annotations

import math
import time
from typing import Callable

from ..errors import LinkError
from .link.mavlink_link import MSG_ID_ATTITUDE
from .session.offboard_session import SessionState
from .autopilots.preflight import HoverMeasurement


class SessionNews:
    """Says, once each, what the session and the link learned since the last tick: new vehicle sessions (restarts,
    the link back), HEARTBEATs still showing the old mode after the ACKed switch, the hover collective of each
    engagement, and a second vehicle on the target's id (which it also hands to the session as IDENTITY_CONFLICT).
    The reader thread may append to the session's lists meanwhile: what is counted is said, the rest next tick."""

    def __init__(self, say: Callable[[str], None], requested_mode: str | None) -> None:
        self._say = say
        self._mode = requested_mode
        self._events_said = 0
        self._late_said = 0  # session.sample_stage.late_mode_heartbeats already said
        self._conflict_said = False  # the link's clock conflict (two vehicles, one id) said and acted on
        self._hover_said_at = 0  # the engagement whose hover collective was last said

    def tell(self, session, link, preflight) -> None:
        conflict = link.clock.conflict
        if conflict is not None and not self._conflict_said:
            self._conflict_said = True
            text = conflict.text(link.target_system)
            self._say(f"bridge: {text}")
            session.identity_conflict(text)
        new_events, new_late = session.session_events[self._events_said:], session.sample_stage.late_mode_heartbeats[self._late_said:]
        self._events_said += len(new_events)
        self._late_said += len(new_late)
        for why in new_events:
            self._say(f"new vehicle session: {why}")
        for mode in new_late:
            self._say(f"HEARTBEAT still showing {mode} after the vehicle ACKed {self._mode}: taken as sent "
                      f"before the switch (the next one decides)")
        self._tell_hover(session, preflight)

    def _tell_hover(self, s, preflight) -> None:
        """Once per engagement, where the hover collective flown comes from (PX4: measured from its hold, or why not)."""
        if s.hover_source is None or s.counters.engagements <= self._hover_said_at:
            return
        self._hover_said_at = s.counters.engagements
        with s.lock:
            m, hover = s.hover_measurement, s.cycle.profile.hover_thrust_norm
        if isinstance(m, HoverMeasurement):
            text = m.text(s.cycle.profile.name, s.cycle.profile.hover_thrust_param)
        else:
            text = f"hover collective {hover:.3f} from {preflight.hover_source.split(';')[0]}: not measured from the hold ({m})"
        preflight.hover_collective_norm = hover
        self._say(text)


class AttitudeStreamKeeper:
    """Asks the vehicle for ATTITUDE again when it sends too little: in flight below half the configured rate (every
    ``timing.interval_reassert_s``), and while waiting to engage or paused with no ATTITUDE for 1 s, once after each
    HEARTBEAT (a restarted autopilot streams nothing until asked: ArduCopter 4.7's MAVn_EXTRA1 defaults to 0; its new
    clock is then confirmed, vehicle_clock). Asking right after each HEARTBEAT, not on the supervisor's own 1 s grid,
    puts the request in front of a new boot as soon as it is heard: SITL's watchdog reboot lives about 0.6 s from its
    first HEARTBEAT to its PANIC, and a request up to 1 s late missed it (docs/bridge.md). No ACK wait; a link that is
    going is the supervisor's to report."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self._say = say
        self._last_reassert = 0.0
        self._heartbeats_asked = 0  # link.heartbeat_count at the last idle request

    def keep(self, session, link, config, now: float) -> None:
        """Called every supervisor tick (host monotonic ``now`` [s])."""
        self._reassert_interval(session, link, config.timing, now)
        self._request_while_idle(session, link, config.timing.attitude_rate_hz)

    def _reassert_interval(self, s, link, t, now: float) -> None:
        achieved_hz = s.sample_stage.achieved_rate_hz
        if not math.isfinite(achieved_hz) or achieved_hz >= 0.5 * t.attitude_rate_hz:
            return
        if now - self._last_reassert < t.interval_reassert_s:
            return
        self._last_reassert = now
        try:
            link.requests.set_message_interval_nowait(MSG_ID_ATTITUDE, t.attitude_rate_hz)
            self._say(f"ATTITUDE at {achieved_hz:.0f} Hz < half of {t.attitude_rate_hz:g} Hz: SET_MESSAGE_INTERVAL re-sent")
        except LinkError as exc:
            self._say(f"ATTITUDE interval not re-sent ({exc})")

    def _request_while_idle(self, s, link, rate_hz: float) -> None:
        heartbeats = link.heartbeat_count
        if heartbeats == self._heartbeats_asked or s.state not in (SessionState.WAITING, SessionState.PAUSED):
            return
        fresh_ns = s.sample_stage.last_fresh_ns
        if fresh_ns is not None and (time.monotonic_ns() - fresh_ns) * 1e-9 < 1.0:
            return
        self._heartbeats_asked = heartbeats
        try:
            link.requests.set_message_interval_nowait(MSG_ID_ATTITUDE, rate_hz)
        except LinkError as exc:  # the vehicle is not reachable yet: asked again after its next HEARTBEAT
            self._say(f"ATTITUDE interval not re-sent while {s.state.value} ({exc})")


def phase_text(session, mode: str | None, takeoff_alt_m: float | None, reference_name: str, on_failsafe: str,
               on_exit: str) -> str:
    """What the bridge is doing now, in words, for the dashboard and the status line (``mode``: the guided mode the
    options request, None when the pilot selects it)."""
    s = session
    if s is None:
        return "connecting"
    state = s.state
    if state in (SessionState.WAITING, SessionState.PRESTREAM) and mode is None:
        modes = "/".join(s.cycle.profile.guided_modes)
        return f"waiting for the pilot or ground station to select {modes} and arm"
    if state == SessionState.PRESTREAM:
        return f"pre-streaming setpoints before requesting {mode}"
    if state == SessionState.WAITING:
        return f"waiting for {mode} and armed"
    if state == SessionState.ENGAGE_PENDING:
        return "engaging"
    if state == SessionState.TAKEOFF:
        return f"takeoff to {takeoff_alt_m:g} m (level, bounded climb)"
    if state == SessionState.ENGAGED:
        return f"flying {reference_name}"
    if state == SessionState.HOLDING:
        return f"level hold ({s.active_reason.label if s.active_reason else 'stop'})"
    if state == SessionState.HANDBACK:
        action = on_failsafe if s.failsafe is not None else on_exit
        return f"handing back ({action})" if action != "none" else "stopping (no hand-back: the autopilot's timeout takes over)"
    if state == SessionState.PAUSED:
        return "paused after a failsafe: waiting for a guided mode and armed (--reengage)"
    return str(state)
