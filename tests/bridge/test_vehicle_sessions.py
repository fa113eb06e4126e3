"""Reordered ATTITUDE, vehicle restarts (time_boot_ms reset, HEARTBEAT gap) and re-engagement after a
link-loss failsafe: the offboard session driven directly with a fake link and an injected clock."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.bridge.bridge_config import load_bridge_config
from mavastsm.bridge.cycle.control_cycle import ControlCycle
from mavastsm.bridge.record.flight_log import FlightLog
from mavastsm.bridge.link.messages import (
    MAV_STATE_BOOT,
    AttitudeSample,
    HeartbeatInfo,
    is_vehicle_restart,
    newest_attitude,
)
from mavastsm.bridge.session.offboard_session import OffboardSession
from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
from mavastsm.references import load_reference
from mavastsm.solo_model import load_solo
from mavastsm.state_types import FailsafeReason
from mavastsm.telemetry import TelemetryBuffer

ARMED = 128


def _att(t_ms: int, roll: float = 0.0, rx_ns: int = 0) -> AttitudeSample:
    return AttitudeSample(t_ms, (roll, 0.0, 0.1), (0.0, 0.0, 0.0), rx_ns)


def _hb(mode: str, armed: bool = True, system_status: int = 4) -> HeartbeatInfo:
    return HeartbeatInfo(1, 1, "ArduPilot", 2, ARMED if armed else 0, 4, system_status, mode, 0.0)



# ---------------------------------------------------------------------------- issue: reordering in the reader
def test_reader_keeps_the_newest_attitude_by_vehicle_time_not_by_arrival():
    newer, older = _att(5_000, 0.2), _att(4_990, 0.1)
    assert newest_attitude(newer, older) is newer  # reordered: the older one arrived last and loses
    assert newest_attitude(older, newer) is newer
    rebooted = _att(120)
    assert newest_attitude(newer, rebooted) is rebooted  # clock back by > 3 s: a restarted autopilot wins
    assert not is_vehicle_restart(5_000, 4_990) and not is_vehicle_restart(5_000, 2_001)
    assert is_vehicle_restart(5_000, 1_999)


class _FakeLink:
    def __init__(self) -> None:
        from mavastsm.bridge.link.mavlink_link import LinkStats

        self.sent = []
        self.heartbeat_age_s = 0.0
        self.stats = LinkStats()

    def send_setpoint(self, sp) -> None:
        self.sent.append(sp)

    def seconds_since_heartbeat(self) -> float:
        return self.heartbeat_age_s


class _Clock:
    def __init__(self) -> None:
        self.ns = 1_000_000_000

    def __call__(self) -> int:
        return self.ns

    def advance(self, s: float) -> None:
        self.ns += int(s * 1e9)


class _Ctl:
    """Minimal adaptive controller: alpha grows every update, reset() brings it back to alpha_m."""

    alpha_m = 0.5

    def __init__(self) -> None:
        self.alpha = self.alpha_m
        self.resets = 0

    def reset(self) -> None:
        self.alpha = self.alpha_m
        self.resets += 1

    def update(self, err, dt_s):
        self.alpha += 0.1
        return -0.01 * np.asarray(err.angle_error_rad, dtype=float)

    def diagnostics(self):
        return {"alpha": np.full(3, self.alpha)}


def _session(tmp_path, reengage: bool):
    cfg = load_bridge_config()
    solo = load_solo()
    ctl = _Ctl()
    cycle = ControlCycle(ctl, load_reference("hold"), tuple(float(x) for x in solo.inertia_diag), ardupilot_profile("climb_rate"), cfg,
                         alpha_max=None, accel_limit_radss=(6.28, 6.28, 1.22))
    link, clock = _FakeLink(), _Clock()
    log = FlightLog(tmp_path / "flight.csv")
    s = OffboardSession(link, cycle, cfg, TelemetryBuffer(), log, reengage=reengage, clock_ns=clock)
    return s, link, clock, ctl, log


def _feed(s, clock, t0_ms: int, n: int, period_ms: int = 10) -> int:
    for k in range(n):
        clock.advance(period_ms / 1000.0)
        s.on_attitude(_att(t0_ms + k * period_ms, rx_ns=clock()))
    return t0_ms + n * period_ms


def test_session_drops_reordered_samples_but_follows_a_rebooted_vehicle_without_commanding_it(tmp_path):
    s, link, clock, ctl, log = _session(tmp_path, reengage=False)
    try:
        s.on_heartbeat(_hb("GUIDED"))
        assert s.state == "engage_pending"
        t = _feed(s, clock, 60_000, 20)
        assert s.state == "engaged" and s.counters.cycles == 20  # the engaging sample runs a cycle too
        s.on_attitude(_att(t - 50, rx_ns=clock()))  # reordered: older by 50 ms
        assert s.counters.dropped == 1 and s.counters.vehicle_restarts == 0
        n_sent = len(link.sent)
        # the autopilot reboots: its clock restarts near zero
        clock.advance(0.01)
        s.on_attitude(_att(200, rx_ns=clock()))
        assert s.counters.vehicle_restarts == 1 and s.counters.vehicle_sessions == 2
        assert s.state == "handback" and s.failsafe is FailsafeReason.VEHICLE_RESTARTED and "restarted" in s.end_reason
        _feed(s, clock, 210, 20)  # later samples are accepted as fresh, not dropped forever ...
        assert s.counters.dropped == 1 and s.last_ms == 210 + 19 * 10
        assert len(link.sent) == n_sent  # ... and the new vehicle session is never commanded
    finally:
        log.close()


def test_heartbeat_back_after_a_gap_is_a_new_vehicle_session(tmp_path):
    s, link, clock, ctl, log = _session(tmp_path, reengage=True)
    try:
        s.on_heartbeat(_hb("GUIDED", armed=False))
        _feed(s, clock, 1_000, 5)
        assert s.state == "waiting"
        clock.advance(s.config.link.link_loss_timeout_s + 1.0)
        s.on_heartbeat(_hb("GUIDED", armed=False))  # a restarted sim whose clock is only a little behind
        assert s.counters.vehicle_sessions == 2 and s.counters.vehicle_restarts == 0 and s.last_ms is None
        _feed(s, clock, 900, 3)
        assert s.counters.dropped == 0 and s.last_ms == 920 and not link.sent
    finally:
        log.close()


def test_a_boot_heartbeat_in_a_gap_is_a_restart_even_when_the_new_clock_reads_later(tmp_path):
    """A reboot soon after boot: the new clock (2.5 s) is not behind the old one by the restart threshold, so the
    clock alone cannot tell it from a gap. ArduCopter says MAV_STATE_BOOT until it is ready; that HEARTBEAT inside an
    ATTITUDE gap of at least the stale timeout makes it a restart, named on the first frame back."""
    s, link, clock, ctl, log = _session(tmp_path, reengage=True)
    try:
        s.on_heartbeat(_hb("GUIDED", armed=False))
        t = _feed(s, clock, 4_000, 50)
        clock.advance(1.5)  # the reboot: no ATTITUDE, HEARTBEATs in MAV_STATE_BOOT (less than the link-loss timeout)
        s.on_heartbeat(_hb("STABILIZE", armed=False, system_status=MAV_STATE_BOOT))
        _feed(s, clock, 2_500, 1)
        assert s.counters.vehicle_restarts == 1 and s.counters.vehicle_sessions == 2, s.session_events
        assert "HEARTBEAT said MAV_STATE_BOOT in 1.5 s without ATTITUDE" in s.session_events[-1], s.session_events
        assert not is_vehicle_restart(t - 10, 2_500)  # the clock alone: back by less than the restart threshold
    finally:
        log.close()


def test_a_boot_heartbeat_inside_a_live_stream_or_a_gap_without_one_is_not_a_restart(tmp_path):
    """Neither half alone: a (forged) MAV_STATE_BOOT HEARTBEAT while the stream goes on is forgotten at the next frame,
    and a gap longer than the stale timeout with no such HEARTBEAT is a gap."""
    s, link, clock, ctl, log = _session(tmp_path, reengage=True)
    try:
        s.on_heartbeat(_hb("GUIDED", armed=False))
        t = _feed(s, clock, 4_000, 50)
        s.on_heartbeat(_hb("GUIDED", armed=False, system_status=MAV_STATE_BOOT))
        t = _feed(s, clock, t, 5)
        clock.advance(1.5)
        t = _feed(s, clock, t + 1_500, 5)
        assert s.counters.vehicle_restarts == 0 and s.counters.vehicle_sessions == 1, s.session_events
    finally:
        log.close()


def test_reengage_after_stale_failsafe_waits_for_guided_and_armed_then_resets(tmp_path):
    s, link, clock, ctl, log = _session(tmp_path, reengage=True)
    try:
        s.on_heartbeat(_hb("GUIDED"))
        t = _feed(s, clock, 60_000, 50)
        assert s.state == "engaged" and ctl.alpha > ctl.alpha_m + 4
        # ATTITUDE stops: stale within the configured timeout, then the hold, then the hand-back
        tm = s.config.timing
        clock.advance(tm.stale_timeout_s * 1.2)
        s.tick()
        assert s.state == "holding" and s.failsafe is FailsafeReason.STALE_ATTITUDE
        clock.advance(tm.failsafe_hold_s)
        s.tick()
        assert s.state == "handback"
        s.pause_after_handback()  # what Bridge._hand_back does with reengage after STALE/LINK_LOST
        assert s.state == "paused"
        # the vehicle comes back rebooted, disarmed, in STABILIZE: no setpoint, no engagement
        n_sent = len(link.sent)
        s.on_heartbeat(_hb("STABILIZE", armed=False))
        _feed(s, clock, 100, 20)
        s.on_heartbeat(_hb("GUIDED", armed=False))
        _feed(s, clock, 400, 5)
        assert s.counters.vehicle_restarts == 1 and s.state == "paused" and len(link.sent) == n_sent and s.counters.engagements == 1
        # guided and armed: re-engage with a reset controller, reference relative to the new attitude
        s.on_heartbeat(_hb("GUIDED", armed=True))
        assert s.state == "engage_pending"
        _feed(s, clock, 500, 1)
        assert s.state == "engaged" and s.counters.engagements == 2 and ctl.resets == 2
        assert s.cycle.engage_ms == 500  # reference restarted at the new engagement
        assert s.output.samples[-1].alpha[0] == ctl.alpha_m + 0.1  # first engaged cycle: one update after the reset to alpha_m
        assert len(link.sent) == n_sent + 1 and s.failsafe is None
        assert s.recovered_failsafes == [FailsafeReason.STALE_ATTITUDE]
    finally:
        log.close()


@pytest.mark.parametrize("reengage", [True, False])
def test_a_manual_mode_during_a_stale_hold_pauses_with_reengage_and_ends_without(tmp_path, reengage):
    """The level hold after STALE_ATTITUDE, and a HEARTBEAT in a manual mode, disarmed: what an in-flight watchdog
    reboot of genuine ArduCopter shows before its first ATTITUDE (the old boot's last HEARTBEATs said guided and
    armed). With --reengage the bridge waits for guided + armed, as after the hand-back the hold was heading for, so
    the new boot's ATTITUDE is still asked for and its restart named; without, the pilot's takeover ends the run."""
    s, link, clock, ctl, log = _session(tmp_path, reengage=reengage)
    try:
        s.on_heartbeat(_hb("GUIDED"))
        _feed(s, clock, 60_000, 50)
        clock.advance(s.config.timing.stale_timeout_s * 1.2)
        s.tick()
        assert s.state == "holding" and s.failsafe is FailsafeReason.STALE_ATTITUDE
        n_sent = len(link.sent)
        s.on_heartbeat(_hb("STABILIZE", armed=False))
        assert "pilot took over in STABILIZE during the level hold" in s.end_reason
        if not reengage:
            assert s.state == "done" and s.done.is_set()
            return
        assert s.state == "paused" and not s.done.is_set()
        clock.advance(0.5)
        _feed(s, clock, 300, 20)  # the new boot's clock
        assert s.counters.vehicle_restarts == 1 and "vehicle restarted" in s.session_events[-1], s.session_events
        assert s.state == "paused" and len(link.sent) == n_sent  # the new boot is never commanded unasked
    finally:
        log.close()


def test_latency_percentiles_cover_the_whole_run_or_only_the_recent_window(tmp_path):
    s, *_ , log = _session(tmp_path, reengage=False)
    assert all(np.isnan(s.output.latencies_s.percentiles()))
    s.output.latencies_s.extend([1e-3] * 900 + [5e-3] * 100)  # an early slow spell, then 1000 fast cycles
    s.output.latencies_s.extend([float(k) * 1e-6 for k in range(1, 1001)])
    p50, p99, pmax = s.output.latencies_s.percentiles()
    # order statistics over all 2000 cycles, from the bounded 1 us histogram (LatencyRecord): exact to 1 us
    assert p50 == pytest.approx(1e-3, abs=1e-6) and p99 == pytest.approx(5e-3, abs=1e-6) and pmax == pytest.approx(5e-3, abs=1e-6)
    p50, p99, pmax = s.output.latencies_s.percentiles(last_n=1000)  # the live view: the last 1000 only
    assert (p50, p99, pmax) == (500e-6, 991e-6, 1000e-6)
    s.output.latencies_s.extend([0.25, 0.5])  # slower than the histogram's range: kept as measured
    assert s.output.latencies_s.percentiles()[2] == 0.5
    log.close()


def test_a_late_heartbeat_after_the_acked_mode_request_is_forgiven_once_and_never_after(tmp_path):
    """After the bridge's own ACKed mode request, a HEARTBEAT still in the old mode is late (PX4 sends one built
    before the switch) until a guided one arrives or LATE_HEARTBEAT_S passes; after either, leaving is the pilot's."""
    from mavastsm.bridge.session.sample_stage import LATE_HEARTBEAT_S

    for confirmed in (True, False):
        (tmp_path / str(confirmed)).mkdir()
        s, link, clock, ctl, log = _session(tmp_path / str(confirmed), reengage=False)
        try:
            s.on_heartbeat(_hb("LOITER"))
            s.mode_request_acked()
            s.set_state("engage_pending")
            s.on_heartbeat(_hb("LOITER"))  # built before the switch
            assert s.state == "engage_pending" and s.sample_stage.late_mode_heartbeats == ["LOITER"]
            _feed(s, clock, 10_000, 5)
            assert s.state == "engaged"
            if confirmed:
                s.on_heartbeat(_hb("GUIDED"))  # the switch is seen: from now on leaving is the pilot's, at once
            else:
                clock.advance(LATE_HEARTBEAT_S)  # no guided HEARTBEAT within the grace
            s.on_heartbeat(_hb("LOITER"))
            assert s.state == "done" and s.failsafe is FailsafeReason.MODE_CHANGED and s.sample_stage.late_mode_heartbeats == ["LOITER"]
        finally:
            log.close()


def test_a_guided_armed_heartbeat_before_the_bridges_own_takeoff_does_not_engage_on_the_ground(tmp_path):
    """The README's ArduCopter command: mode, arm, then the bridge's takeoff. A HEARTBEAT showing the guided mode and
    armed can arrive before ``start_takeoff``; in CI (2026-12-06) it engaged the law for one cycle on the ground and
    the takeoff then left the engaged state (an unexpected transition). With the takeoff expected it waits; the
    takeoff, then its engagement, follow as designed."""
    s, link, clock, ctl, log = _session(tmp_path, reengage=False)
    try:
        s.expect_takeoff()
        s.on_heartbeat(_hb("GUIDED"))
        t = _feed(s, clock, 60_000, 5)
        assert s.state == "waiting" and s.counters.engagements == 0 and ctl.resets == 0 and not link.sent
        s.start_takeoff(2.0)
        assert s.state == "takeoff" and not s.unexpected_transitions
        s.on_heartbeat(_hb("GUIDED"))  # a later HEARTBEAT changes nothing during the takeoff
        assert s.state == "takeoff"
        _feed(s, clock, t, 3)
        assert s.counters.engagements == 0
    finally:
        log.close()
