"""What the bridge asks of the autopilot outside the control cycle: arm, take off, change mode, hand back, restore.

Each is only called when the options ask for it (``Bridge`` decides; this module only carries it out), and each
waits on the vehicle's answer with progress said and a bound: pre-arm checks (``link.arm_timeout_s``), a vertical
estimate at rest before the autopilot's own takeoff (``REST_TIMEOUT_S``), the takeoff itself
(``thrust.takeoff_timeout_s``). Waits sleep through the bridge's ``sleep`` (the vehicle's clock in lockstep, an
operator stop ends it), and read time from an injected ``monotonic`` clock so that tests need no real waiting.
"""

from __future__ import annotations

import math
import time
from typing import Callable

from ..errors import ConfigError, Interrupted, LinkError, OffboardRejected
from .autopilots.profile import arming_fix
from .autopilots import adapter_for
from .bridge_config import LinkConfig, ThrustConfig
from .link.mavlink_link import MAV_CMD_DO_SET_MODE, MAV_CMD_NAV_TAKEOFF, MSG_ID_GLOBAL_POSITION_INT, MSG_ID_LOCAL_POSITION_NED
from .session.offboard_session import SessionState

REST_VZ_MS = 0.1  # [m/s] before the autopilot's own takeoff: |vz| estimate at most this ...
REST_HOLD_S = 2.0  # [s] ... for this long: the vertical estimate is at rest (wait_vertical_estimate_at_rest)
# [s] else the takeoff is refused. SIH's estimate wanders +-0.4 m/s on the ground for minutes, with a 2 s window at
# rest now and then (first after 11.2-11.5 s in 3 boots of 2026-12-04); once (CI) none came in 60 s.
REST_TIMEOUT_S = 120.0
SECOND_SOURCE_WAIT_S = 1.5  # [s] start-up: at most this long for the verdict on a second address sending the target's id


class VehicleActions:
    """The autopilot commands of start-up and hand-back, on one link.

    Parameters
    ----------
    link : MavlinkLink (or anything with its members used here)
    link_cfg, thrust_cfg : the bridge config's ``link`` and ``thrust`` sections (timeouts, retries)
    say : callable(str), progress and outcomes in words
    sleep : callable(seconds) -> True when an operator stop ended the wait
    monotonic : [s] the clock the waits are bounded by
    """

    def __init__(self, link, link_cfg: LinkConfig, thrust_cfg: ThrustConfig, say: Callable[[str], None],
                 sleep: Callable[[float], bool], monotonic: Callable[[], float] = time.monotonic) -> None:
        self.link, self.lc, self.tc = link, link_cfg, thrust_cfg
        self._say, self._sleep, self._now = say, sleep, monotonic
        self.armed_by_bridge = False  # our own arm request was ACKed (a failed start hands back)
        self.mode_changed = False  # we requested a mode (a failed start puts the old one back)

    def check_one_vehicle(self) -> None:
        """Start-up ends here (one line, exit 2) when two vehicles already claim the target's id (vehicle_clock):
        checked after preflight and again right before each mode request and arming attempt (a second vehicle whose
        stream began during start-up is named only once its clock has run RIVAL_SPAN_MS); while a second address is
        being heard, its verdict is awaited (at most SECOND_SOURCE_WAIT_S)."""
        deadline = time.monotonic() + SECOND_SOURCE_WAIT_S
        while self.link.clock.second_source_heard(time.monotonic_ns()) and time.monotonic() < deadline:
            if self._sleep(0.05):
                raise Interrupted("interrupted (waiting to tell whether a second vehicle shares the id)")
        conflict = self.link.clock.conflict
        if conflict is not None:
            raise LinkError(conflict.text(self.link.target_system))

    def request_stream(self, msg_id: int, rate_hz: float, what: str, why: str) -> None:
        """SET_MESSAGE_INTERVAL ``msg_id`` at ``rate_hz`` (ACKed, retried); refused: OffboardRejected naming ``what``
        it was for and ``why`` the flight needs it."""
        try:
            self.link.requests.set_message_interval(msg_id, rate_hz, self.lc.command_ack_timeout_s, self.lc.command_retries)
        except OffboardRejected as exc:
            raise OffboardRejected(what, exc.result, why) from None

    def request_vertical_state(self, hold_altitude: bool) -> None:
        """With ``hold_altitude`` (collective thrust and ``thrust.altitude_hold``), ask for LOCAL_POSITION_NED: the
        height the thrust holds."""
        if hold_altitude:
            self.request_stream(MSG_ID_LOCAL_POSITION_NED, 50.0, "LOCAL_POSITION_NED for thrust.altitude_hold",
                                "the collective thrust needs it; set thrust.altitude_hold=false to fly without")

    def request_altitude_for_takeoff(self, takeoff_alt_m: float | None, rate_hz: float) -> None:
        """With ``--takeoff-m``, ask for GLOBAL_POSITION_INT at ``rate_hz``: the climb needs the altitude."""
        if takeoff_alt_m is not None:
            self.request_stream(MSG_ID_GLOBAL_POSITION_INT, rate_hz, "altitude for --takeoff", "GLOBAL_POSITION_INT not available")

    def set_mode(self, mode: str) -> None:
        """Request ``mode`` (ACKed, retried); raises OffboardRejected when refused."""
        self.check_one_vehicle()
        self.mode_changed = True
        self.request_mode(mode, self.lc.command_retries)

    def request_mode(self, mode: str, retries: int) -> None:
        """MAV_CMD_DO_SET_MODE for ``mode`` as the vehicle's autopilot adapter spells it (ACKed); OffboardRejected when
        refused, ConfigError for a mode its autopilot does not have."""
        hb = self.link.last_heartbeat
        if hb is None:
            raise OffboardRejected(f"set mode {mode}", None, "no heartbeat yet")
        adapter = adapter_for(hb.autopilot_id)
        if adapter is None:
            raise ConfigError(f"mode {mode!r}: no adapter for HEARTBEAT autopilot {hb.autopilot_id}")
        self.link.requests.command_long(MAV_CMD_DO_SET_MODE, adapter.mode_command(mode, hb.mav_type),
                               f"COMMAND_LONG DO_SET_MODE {mode}", self.lc.command_ack_timeout_s, retries)

    def arm_when_ready(self) -> None:
        """Arm, waiting for the vehicle's pre-arm checks: retry every ``link.arm_retry_s`` with the vehicle's
        reason and the elapsed time shown, give up after ``link.arm_timeout_s`` with the reason and its fix.
        An operator stop (Ctrl-C, SIGTERM) ends the wait at once."""
        lc, link = self.lc, self.link
        start = self._now()
        reason = ""
        while True:
            self.check_one_vehicle()  # a second vehicle on the id may be named only now (its clock takes 0.5 s)
            try:
                link.requests.arm(lc.command_ack_timeout_s, 1)
                self.armed_by_bridge = True
                if reason:
                    self._say(f"armed after {self._now() - start:.0f} s of pre-arm checks")
                return
            except OffboardRejected as exc:
                detail = exc.detail
                if not detail and exc.result is not None and not self._sleep(lc.arm_reason_wait_s):
                    detail = "; ".join(link.requests.texts_since(time.monotonic() - lc.arm_reason_wait_s - 0.05)[-2:])  # text after the ACK
                reason = detail or reason or f"MAV_RESULT {exc.result}"
                elapsed = self._now() - start
                if elapsed >= lc.arm_timeout_s:
                    fix = arming_fix(reason) or "fix the reason the vehicle gives"
                    raise OffboardRejected("arm", exc.result, f"{reason}; pre-arm checks not passed within "
                                           f"link.arm_timeout_s = {lc.arm_timeout_s:g} s; {fix}") from None
                self._say(f"waiting for pre-arm checks: {reason} … {elapsed:.0f} s")
            if self._sleep(lc.arm_retry_s):
                raise Interrupted(f"while waiting for pre-arm checks ({reason or 'no reason yet'}, {self._now() - start:.0f} s)")

    def vertical_state(self) -> tuple[float, float] | None:
        """(z [m, NED down], vz [m/s, down]) from the latest LOCAL_POSITION_NED, None before the first."""
        pos = self.link.local_position()
        return (pos.position_ned_m[2], pos.velocity_ned_ms[2]) if pos is not None else None

    def altitude_m(self) -> float:
        """[m] above home from the latest GLOBAL_POSITION_INT (relative_alt mm), NaN before the first."""
        pos = self.link.global_position()
        return pos.relative_alt_m if pos is not None else float("nan")

    def wait_vertical_estimate_at_rest(self) -> None:
        """Before the autopilot's own takeoff, wait until its vertical velocity estimate (LOCAL_POSITION_NED vz) has
        stayed within REST_VZ_MS for REST_HOLD_S: the vehicle stands still, so a larger one is an estimator still
        converging. PX4's estimator on SIH reports 0.1-0.3 m/s for seconds after it first allows arming, and a
        takeoff started then ended on the ground in 5 of 12 runs (its height estimate drifted up while the climb
        ramped; docs/bridge.md, "What the genuine firmware does differently"). Bounded by REST_TIMEOUT_S, with progress."""
        if self.vertical_state() is None:  # not streamed for the altitude hold (thrust.altitude_hold false): ask
            try:
                self.link.requests.set_message_interval(MSG_ID_LOCAL_POSITION_NED, 50.0, self.lc.command_ack_timeout_s, self.lc.command_retries)
            except OffboardRejected as exc:
                self._say(f"vertical estimate not checked before the takeoff: LOCAL_POSITION_NED refused ({exc})")
                return
        start = self._now()
        rest_since = None
        last_said = 0.0
        while True:
            vert = self.vertical_state()
            now = self._now()
            vz = vert[1] if vert is not None else float("nan")
            rest_since = (rest_since or now) if abs(vz) <= REST_VZ_MS else None
            if rest_since is not None and now - rest_since >= REST_HOLD_S:
                if now - start > REST_HOLD_S + 0.5:
                    self._say(f"vertical estimate at rest after {now - start:.0f} s (|vz| <= {REST_VZ_MS:g} m/s for {REST_HOLD_S:g} s)")
                return
            if now - start > REST_TIMEOUT_S:
                raise OffboardRejected("takeoff", None, f"the vehicle's vertical velocity estimate was not at rest within {REST_TIMEOUT_S:g} s "
                                       f"(vz {vz:+.2f} m/s, LOCAL_POSITION_NED); the vehicle must stand still on the ground before its takeoff",
                                       failed="estimator not at rest")
            if now - start >= 1.0 and now - last_said >= 1.0:
                last_said = now
                self._say(f"waiting for the vertical estimate to come to rest: vz {vz:+.2f} m/s … {now - start:.0f} s")
            if self._sleep(0.05):
                raise Interrupted("while waiting for the vertical estimate to come to rest")

    def autopilot_takeoff(self, alt_m: float) -> None:
        """The autopilot's own takeoff (PX4): MAV_CMD_NAV_TAKEOFF to home + ``alt_m`` AMSL, then wait (with progress,
        bounded by thrust.takeoff_timeout_s) until it holds within 10 % of the altitude in its hold mode."""
        link, lc, tc = self.link, self.lc, self.tc
        deadline = self._now() + 5.0
        while link.global_position() is None:
            if self._now() > deadline or self._sleep(0.05):
                raise OffboardRejected("takeoff", None, "no GLOBAL_POSITION_INT from the vehicle", failed="no altitude")
        home_amsl_m = link.global_position().home_amsl_m
        nan = float("nan")
        link.requests.command_long(MAV_CMD_NAV_TAKEOFF, (0.0, 0.0, 0.0, nan, nan, nan, home_amsl_m + alt_m),
                                   f"COMMAND_LONG NAV_TAKEOFF to {alt_m:g} m", lc.command_ack_timeout_s, lc.command_retries)
        start, start_host = self._now(), time.monotonic()  # the link stamps the vehicle's texts with the host clock
        last_said = 0.0
        still_since = None  # PX4 hands over to its hold below the altitude and creeps up: settled = |vz| < 0.2 m/s for 1 s
        while True:
            alt, hb, vert = self.altitude_m(), link.last_heartbeat, self.vertical_state()
            now = self._now()
            elapsed = now - start
            holding = hb is not None and hb.mode != "TAKEOFF" and math.isfinite(alt) and alt >= 0.5 * alt_m
            still_since = (still_since or now) if holding and vert is not None and abs(vert[1]) < 0.2 else None
            if holding and (alt >= 0.9 * alt_m or (still_since is not None and now - still_since >= 1.0)):
                self._say(f"takeoff: holding {alt:.2f} m in {hb.mode} after {elapsed:.0f} s; switching to the guided mode")
                return
            if elapsed > tc.takeoff_timeout_s:
                raise OffboardRejected("takeoff", None, f"at {alt:.2f} of {alt_m:g} m after {tc.takeoff_timeout_s:g} s "
                                       f"(thrust.takeoff_timeout_s); vehicle text: {'; '.join(link.requests.texts_since(start_host)[-2:]) or 'none'}",
                                       failed="did not reach a hold at the altitude")
            if elapsed - last_said >= 1.0:
                last_said = elapsed
                self._say(f"taking off ({hb.mode if hb else '?'}): {alt:.2f} / {alt_m:g} m … {elapsed:.0f} s")
            if self._sleep(0.05):
                raise OffboardRejected("takeoff", None, f"during the takeoff at {alt:.2f} m (hand-back above)", failed="operator stop")

    def request_guided_flight(self, session, mode: str, arm: bool, takeoff_alt_m: float | None, prestream_s: float,
                              stop) -> bool:
        """The start-up requests ``--mode`` (and ``--arm``, ``--takeoff-m``) ask for, in order: PX4's own takeoff
        (arm in its current mode after the vertical estimate is at rest, climb, let the hold show the hover), the
        pre-stream, the mode, arming; then the session's next state. True when that state is decided here (the bounded
        climb, or engagement on our ACKs); False when the next HEARTBEAT decides. ``stop`` set: Interrupted before
        any mode change."""
        s, link = session, self.link
        profile = s.cycle.profile
        if takeoff_alt_m is not None and profile.autopilot_takeoff:
            # PX4: arm in its current mode and take off with its own takeoff; OFFBOARD once it holds at altitude
            if not (link.last_heartbeat and link.last_heartbeat.armed):
                self.wait_vertical_estimate_at_rest()
                self.arm_when_ready()
            self.autopilot_takeoff(takeoff_alt_m)
            self.let_hold_show_hover(s)
        if s.state == SessionState.PRESTREAM:
            self.wait_prestream(s, prestream_s)
        if stop.is_set():
            raise Interrupted("during the pre-stream, before any mode change")
        if takeoff_alt_m is not None and not profile.autopilot_takeoff:
            s.expect_takeoff()  # the guided, armed HEARTBEAT that may come first must not engage on the ground
        hb = link.last_heartbeat
        if hb is None or hb.mode != mode:
            self.set_mode(mode)
            s.mode_request_acked()
        armed_by_us = False
        if arm and not (link.last_heartbeat and link.last_heartbeat.armed):
            self.arm_when_ready()
            armed_by_us = True
        if takeoff_alt_m is not None and not profile.autopilot_takeoff:
            s.start_takeoff(takeoff_alt_m)
            return True
        if armed_by_us or link.last_heartbeat.armed:  # mode ACKed and armed: engage on the ACK, not the next HEARTBEAT
            s.set_state("engage_pending")
            return True
        if not profile.prestream_required:
            s.set_state("waiting")
        return False

    def let_hold_show_hover(self, session) -> None:
        """After the autopilot's own takeoff, where the hover collective is measured from its hold (PX4): let the hold
        fly ``thrust.hover_measure_s`` of vehicle time before the guided mode, so the measurement sees the hold alone
        (the takeoff hands over to the hold still climbing, and the pre-stream ran during the takeoff)."""
        if session.hover_source is None:
            return
        hb = self.link.last_heartbeat
        self._say(f"measuring the hover collective in {hb.mode if hb else 'its hold'} for {self.tc.hover_measure_s:g} s")
        if self._sleep(self.tc.hover_measure_s):
            raise OffboardRejected("takeoff", None, "while measuring the hover collective (hand-back above)", failed="operator stop")

    def wait_prestream(self, session, duration_s: float) -> None:
        """Block until setpoints have streamed for ``duration_s`` of vehicle time since the first one was sent (PX4
        needs >= 1 s on its clock); at most ``duration_s`` + 5 s of host time; an operator stop ends it."""
        deadline = self._now() + duration_s + 5.0
        while self._now() < deadline:
            first, last = session.first_prestream_ms, session.last_ms
            if first is not None and last is not None and (last - first) / 1000.0 >= duration_s:
                return
            if self._sleep(0.01):
                return

    def hand_back_after_failed_start(self, action: str, modes) -> None:
        """start() failed after the bridge armed the vehicle (PX4's own takeoff stalled, timed out or was stopped, or
        the guided mode was refused after it): the run ends, so the vehicle gets the hand-back the operator asked for
        (``action``: --on-failsafe, else --on-exit; ``modes``: the profile's list for it), never stays armed in a
        mode the bridge chose without a word. A PX4 takeoff that stalled on the ground left it armed in TAKEOFF, with
        its land detector saying airborne. A vehicle we did not arm is not touched."""
        hb = self.link.last_heartbeat
        if not self.armed_by_bridge or hb is None or not hb.armed:
            return
        if action == "none":
            self._say(f"start-up failed with the vehicle armed in {hb.mode} (armed by the bridge): no hand-back asked "
                      f"(--on-failsafe and --on-exit none); the autopilot has it")
            return
        text, _ = self.request_handback(modes)
        self._say(f"start-up failed with the vehicle armed: hand-back {text}")

    def hand_back(self, action: str, modes) -> tuple[str, bool, bool]:
        """The end of a run: (what happened, said in the summary; the autopilot's HEARTBEAT showed the accepted mode
        within ``link.handback_confirm_s``; every mode was refused). ``action`` "none" leaves the vehicle to the
        autopilot's own setpoint timeout."""
        if action == "none":
            return "none (autopilot's own timeout takes over)", False, False
        text, mode = self.request_handback(modes)
        if mode is None:
            return text, False, True
        return text, self.link.requests.wait_heartbeat_mode(mode, self.lc.handback_confirm_s), False

    def request_handback(self, modes) -> tuple[str, str | None]:
        """Walk ``modes`` (the profile's list for the hand-back action) until one is accepted: (what happened, as said
        in the summary, e.g. "ALTCTL refused (…); LOITER accepted" or "FAILED: …"; the accepted mode, None if all
        refused)."""
        refused = []
        for mode in modes:
            try:
                self.request_mode(mode, self.lc.command_retries)
            except (OffboardRejected, ConfigError, LinkError) as exc:
                refused.append(f"{mode} refused ({exc})")
                continue
            return "; ".join(refused + [f"{mode} accepted"]), mode
        return "FAILED: " + "; ".join(refused), None

    def restore_mode(self, before: str) -> None:
        """After a failed start: put back the mode the vehicle was in (``before``) when we changed it and nobody armed
        it since (armed: somebody flies it, the mode is left alone). Never raises."""
        hb = self.link.last_heartbeat
        if not self.mode_changed or not before or hb is None or hb.armed or hb.mode == before:
            return
        try:
            self.request_mode(before, 1)
            self._say(f"start-up failed: mode set back to {before}")
        except (OffboardRejected, ConfigError, LinkError) as exc:
            self._say(f"start-up failed: could not set the mode back to {before} ({exc})")

    def restore_setpoint_timeout(self, report) -> None:
        """Put back the setpoint timeout the preflight changed (``report.setpoint_timeout_restore``), once; never raises."""
        if report is None or report.setpoint_timeout_restore is None:
            return
        name, value = report.setpoint_timeout_restore
        report.setpoint_timeout_restore = None
        try:
            ok = self.link.requests.param_set(name, value, self.lc.param_timeout_s, self.lc.command_retries)
        except LinkError:  # the link turns socket errors into LinkError
            ok = False
        self._say(f"{name} restored to {value:g} s" if ok else f"{name} could not be restored to {value:g} s (no echo)")
