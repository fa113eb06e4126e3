"""Faults of the peers rather than the link: the vehicle dies and comes back, garbage on both ports,
signing keys, the pilot leaving GUIDED, and a ground station fighting over the stream rates.

All in-process (sim + proxy + bridge), lockstep unless stated. The vehicle's view comes from the
proxy tap and the sim's own counters; the bridge's view from its summary and session.
"""

from __future__ import annotations

import math
import os
import random
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402  (test code is a MAVLink peer)
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from mavastsm.errors import LinkError, OffboardRejected  # noqa: E402
from mavastsm.state_types import FailsafeReason  # noqa: E402
from mavastsm_sim.vehicle_server import VehicleServer  # noqa: E402

pytestmark = pytest.mark.sitl

PERIOD_S = 1.0 / 400.0
COPTER_MODES = {"GUIDED": 4, "LOITER": 5, "LAND": 9, "ALT_HOLD": 2}


class GroundStation:
    """A minimal pymavlink GCS (sysid 255) talking straight to the sim's port."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        self.conn.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def set_mode(self, mode: str) -> None:
        self.conn.mav.command_long_send(1, 1, mavlink2.MAV_CMD_DO_SET_MODE, 0,
                                        mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, COPTER_MODES[mode], 0, 0, 0, 0, 0)

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def ground_station():
    made: list[GroundStation] = []

    def make(port: int) -> GroundStation:
        gcs = GroundStation(port)
        made.append(gcs)
        return gcs

    yield make
    for gcs in made:
        gcs.close()


# ---------------------------------------------------------------- the vehicle dies, then comes back
def test_sim_killed_midflight_stale_detected_hold_then_handback_to_restarted_vehicle(flight_factory, sitl_record):
    flight = flight_factory(controller="astsm", bridge=dict(on_failsafe="LAND"))
    engage_s = flight.wait_engaged()
    flight.wait_vehicle_time(engage_s + 1.5)
    session, timing = flight.bridge.session, flight.bridge.config.timing
    port = flight.server.port
    flight.server.stop()  # the vehicle vanishes mid-flight: no more datagrams, its port is closed
    flight.wait_for(lambda: session.active_reason is not None, 10.0, "the bridge to notice the loss")
    t_noticed = time.monotonic()
    reaction_s = t_noticed - session.sample_stage.last_fresh_ns * 1e-9  # from the last sample's arrival, not the kill
    assert session.active_reason is FailsafeReason.STALE_ATTITUDE
    holds_before = len(flight.setpoints)
    flight.wait_for(lambda: session.state in ("handback", "done"), 10.0, "the hold period to end")
    hold_wall_s = time.monotonic() - t_noticed
    hold_setpoints = flight.setpoints[holds_before:]
    # The vehicle reboots on the same port while the bridge is handing back (retrying the mode command).
    _drain_proxy(flight)
    restarted = VehicleServer(listen=("127.0.0.1", port), clock="lockstep", lockstep_timeout_s=0.05,
                              sched_loop_rate_hz=500.0, seed=1)
    flight.server = restarted  # the fixture stops it at teardown
    restarted.start()
    summary = flight.finish()
    mode_after = restarted.call(lambda c: c.mode_name)
    controller_cmds_after = restarted.counters["attitude_targets_received"]
    sitl_record("sim killed mid-flight, then restarted",
                f"STALE_ATTITUDE within stale_timeout_s = {timing.stale_timeout_s:g} s (host), level hold sent for "
                f"failsafe_hold_s = {timing.failsafe_hold_s:g} s, hand-back LAND reaches the restarted vehicle, "
                "no re-engagement (reengage off)",
                reaction_wall_s=round(reaction_s, 3), hold_wall_s=round(hold_wall_s, 3),
                hold_setpoint_masks=sorted({m.type_mask for _, m in hold_setpoints}),
                failsafe=summary.failsafe.name if summary.failsafe else "none", handback=summary.handback,
                mode_after=mode_after, setpoints_to_restarted_vehicle=controller_cmds_after)
    assert timing.stale_timeout_s <= reaction_s <= timing.stale_timeout_s + 1.0
    assert hold_setpoints and all(m.type_mask in (0x07, 0x87) for _, m in hold_setpoints), "hold must be a level hold"
    assert hold_wall_s >= timing.failsafe_hold_s - 0.05
    assert summary.failsafe is FailsafeReason.STALE_ATTITUDE
    assert summary.handback.startswith("LAND accepted") and mode_after == "LAND"
    assert controller_cmds_after == 0, "the bridge commanded the restarted vehicle without being configured to re-engage"
    assert session.counters.engagements == 1
    assert flight.setpoint_violations() == []



def _drain_proxy(flight) -> None:
    """Wait until the proxy has read *and sent on* (to the dead port) every setpoint the bridge has sent.

    Under load the relay thread can be starved with a hold setpoint for the *old* vehicle still in its
    socket buffer, or already read and shown to the tap but not yet sent; sent after the restarted vehicle
    binds the port, it is counted against the new vehicle although the bridge sent it before the restart.
    This was the intermittent failure of the re-engagement test in loaded CI runs (1 setpoint to the
    disarmed, restarted vehicle): forcing a 30 ms stall between tap and sendto reproduces it every time
    (the old vehicle's last 0x07 hold, same MAVLink sequence number, from the proxy's target socket, with
    no new setpoint from the bridge), and this drain makes it pass every time.
    """
    stats = flight.bridge.link.stats
    flight.wait_for(lambda: len(flight.setpoints) >= stats.sent_setpoints, 10.0, "the proxy to read every setpoint already sent")
    flight.proxy.settle()  # ... and to have sent on the last one it read (tap and sendto are one locked step)


def _fly_second_engagement(flight, session, seconds: float):
    """Wait for the re-engagement, fly ``seconds`` of vehicle time after it, stop. Returns (engage2_s, summary)."""
    flight.wait_for(lambda: session.counters.engagements == 2, 10.0, "re-engagement")
    engage2_s = flight.engage_time_s
    flight.wait_vehicle_time(engage2_s + seconds)
    flight.bridge.request_stop()
    return engage2_s, flight.finish()


def test_sim_killed_then_restarted_bridge_reengages_only_when_guided_and_armed_with_fresh_gains(
        flight_factory, ground_station, sitl_record):
    flight = flight_factory(controller="astsm", bridge=dict(reengage=True, on_failsafe="none"))
    engage_s = flight.wait_engaged()
    # long enough that the restarted sim's clock is clearly behind (restart detection: back by > 3 s)
    flight.wait_vehicle_time(engage_s + 3.5)
    session, timing = flight.bridge.session, flight.bridge.config.timing
    port = flight.server.port
    flight.server.stop()
    flight.wait_for(lambda: session.active_reason is not None, 10.0, "the bridge to notice the loss")
    # from the arrival of the last sample the bridge got (host monotonic), not from the kill: that sample can arrive
    # before the test's own clock reading at the kill (a CI run measured 0.489 s from the kill against 0.5 s)
    reaction_s = time.monotonic() - session.sample_stage.last_fresh_ns * 1e-9
    flight.wait_for(lambda: session.state == "paused", 10.0, "the hand-back and the pause (--reengage)")
    _drain_proxy(flight)
    restarted = VehicleServer(listen=("127.0.0.1", port), clock="lockstep", lockstep_timeout_s=0.05,
                              sched_loop_rate_hz=500.0, seed=1)
    flight.server = restarted  # the fixture stops it at teardown
    restarted.start()
    flight.wait_for(lambda: session.counters.vehicle_restarts >= 1, 10.0, "the restart to be detected")
    gcs = ground_station(port)
    gcs.set_mode("GUIDED")  # guided but still disarmed: not enough to engage
    flight.wait_for(lambda: session.last_heartbeat is not None and session.last_heartbeat.mode == "GUIDED", 10.0, "GUIDED")
    flight.wait_for(lambda: session.last_ms is not None and session.last_ms >= 500, 10.0, "0.5 s of the restarted vehicle's stream")
    to_restarted_before_armed = restarted.counters["attitude_targets_received"]
    state_before_armed = session.state
    n_samples = len(session.output.samples)
    gcs.conn.mav.command_long_send(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    engage2_s, summary = _fly_second_engagement(flight, session, 1.0)
    rows = [r for r in summary.samples if r.failsafe is None and math.isfinite(r.alpha[0])]
    alpha_at_engage1 = next(r.alpha for r in rows if r.vehicle_time_s >= engage_s)
    first_flight = [r for r in summary.samples[:n_samples] if r.failsafe is None and math.isfinite(r.alpha[0])]
    alpha_peak_before_kill = max(max(r.alpha) for r in first_flight)
    after = [r for r in summary.samples[n_samples:] if r.failsafe is None and math.isfinite(r.alpha[0])]
    # The restarted sim is on the ground and the re-engaged hold thrust is zero climb rate (no re-takeoff): it stays
    # landed and does not rotate, so the error after the first reference step is the step itself (recorded, not asserted).
    worst_err_1s_deg = max(math.degrees(max(abs(r.error_rad[0]), abs(r.error_rad[1]))) for r in after)
    sitl_record("sim killed mid-flight, then restarted (reengage on)",
                f"STALE_ATTITUDE within stale_timeout_s = {timing.stale_timeout_s:g} s, hand-back (none), pause; restart "
                "detected; no setpoint until GUIDED and armed; re-engages with alpha = alpha_m; control stream resumes",
                reaction_wall_s=round(reaction_s, 3), state_before_armed=state_before_armed,
                setpoints_to_restarted_vehicle_before_armed=to_restarted_before_armed,
                alpha_first_cycle=[round(a, 4) for a in alpha_at_engage1], alpha_peak_before_kill=round(alpha_peak_before_kill, 4),
                alpha_first_cycle_after_reengage=[round(a, 4) for a in after[0].alpha], cycles_after_reengage=len(after),
                worst_roll_pitch_error_first_1s_landed_deg=round(worst_err_1s_deg, 3), recovered=[r.name for r in summary.recovered_failsafes])
    assert timing.stale_timeout_s <= reaction_s <= timing.stale_timeout_s + 1.0
    assert summary.recovered_failsafes == (FailsafeReason.STALE_ATTITUDE,)
    assert state_before_armed == "paused" and to_restarted_before_armed == 0, "commanded the restarted vehicle before GUIDED + armed"
    assert session.counters.engagements == 2 and summary.vehicle_restarts == 1
    assert after[0].alpha == pytest.approx(alpha_at_engage1, rel=1e-9, abs=1e-12)
    assert alpha_peak_before_kill > max(alpha_at_engage1) * 1.01, "alpha never adapted: the reset check would be vacuous"
    # the control loop resumed at the stream rate (1 s of vehicle time at 400 Hz requested)
    assert len(after) >= 200 and restarted.counters["attitude_targets_received"] >= 200
    assert flight.setpoint_violations() == []


# ---------------------------------------------------------------- garbage on both ports
def _frame(mav, msg) -> bytes:
    return msg.pack(mav)


def garbage_for_bridge(rng: random.Random, vehicle_ms: int) -> list[tuple[str, bytes]]:
    """Datagrams that must not disturb the bridge (what, bytes). The invalid ATTITUDEs are stamped 1 s
    ahead of the vehicle clock so they are never 'old' (an old sample is dropped on its time stamp
    before its values are looked at): they must be rejected on their values."""
    v1 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    other = mavlink2.MAVLink(None, srcSystem=2, srcComponent=1)
    att = _frame(v1, v1.attitude_encode(vehicle_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    unknown = bytes([0xFD, 4, 0, 0, 0, 1, 1, 0x39, 0x30, 0x00]) + bytes(4) + b"\x12\x34"  # msg id 12345
    out = [("random bytes", bytes(rng.randrange(256) for _ in range(rng.randrange(1, 280)))) for _ in range(5)]
    out += [
        ("truncated ATTITUDE", att[: len(att) // 2]),
        ("ATTITUDE with NaN roll", _frame(v1, v1.attitude_encode(vehicle_ms + 1000, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0))),
        ("ATTITUDE with inf rate", _frame(v1, v1.attitude_encode(vehicle_ms + 1000, 0.0, 0.0, 0.0, math.inf, 0.0, 0.0))),
        ("ATTITUDE with absurd roll 100 rad", _frame(v1, v1.attitude_encode(vehicle_ms + 1000, 100.0, 0.0, 0.0, 0.0, 0.0, 0.0))),
        ("unknown message id", unknown),
        ("ATTITUDE from sysid 2 (tilted 30 deg)", _frame(other, other.attitude_encode(vehicle_ms + 1, 0.52, 0.0, 0.0, 0.0, 0.0, 0.0))),
        ("HEARTBEAT from sysid 2 in LAND", _frame(other, other.heartbeat_encode(2, 3, 217, COPTER_MODES["LAND"], 4))),
    ]
    return out


def garbage_for_vehicle(rng: random.Random) -> list[tuple[str, bytes]]:
    b = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
    stranger = mavlink2.MAVLink(None, srcSystem=42, srcComponent=1)
    good = _frame(b, b.set_attitude_target_encode(0, 1, 1, 0x80, [0, 0, 0, 0], 0.0, 0.0, 0.0, 0.5))
    out = [("random bytes", bytes(rng.randrange(256) for _ in range(rng.randrange(1, 280)))) for _ in range(5)]
    out += [
        ("truncated SET_ATTITUDE_TARGET", good[: len(good) // 2]),
        ("SET_ATTITUDE_TARGET for system 7", _frame(b, b.set_attitude_target_encode(0, 7, 1, 0x80, [0, 0, 0, 0], 3.0, 0.0, 0.0, 0.5))),
        ("arm/disarm COMMAND_LONG for system 9", _frame(stranger, stranger.command_long_encode(9, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0))),
        ("unknown message id", bytes([0xFD, 4, 0, 0, 0, 1, 191, 0x39, 0x30, 0x00]) + bytes(4) + b"\x12\x34"),
        ("PARAM_SET GUID_TIMEOUT = NaN", _frame(b, b.param_set_encode(1, 1, b"GUID_TIMEOUT", math.nan, 9))),
    ]
    return out


def test_garbage_on_both_ports_is_counted_and_never_reaches_the_wire(flight_factory, sitl_record):
    flight = flight_factory(controller="astsm")
    engage_s = flight.wait_engaged()
    rng = random.Random(2024)
    sim_before = flight.server.counters
    to_bridge_sent = to_vehicle_sent = 0
    # one garbage datagram each way every 20 ms of vehicle time, through the first 3 s of the run
    items_b = garbage_for_bridge(rng, 0)
    items_v = garbage_for_vehicle(rng)
    for k in range(max(len(items_b), len(items_v))):
        flight.wait_vehicle_time(engage_s + 0.6 + 0.02 * k)
        if k < len(items_b):
            vehicle_ms = int(round(flight.proxy.vehicle_time_s * 1000))
            what, data = garbage_for_bridge(random.Random(k), vehicle_ms)[k]
            to_bridge_sent += flight.proxy.inject("from_target", data)
        if k < len(items_v):
            to_vehicle_sent += flight.proxy.inject("to_target", items_v[k][1])
    summary = flight.finish()
    sim_after = flight.server.counters
    stats = flight.bridge.link.stats
    sim_delta = {k: sim_after[k] - sim_before.get(k, 0) for k in sim_after if k in (
        "garbage_bytes", "crc_errors", "malformed_frames", "truncated_frames", "unknown_message_ids",
        "wrong_target", "bad_field_values", "bad_input_total")}
    axes = flight.axis_metrics()
    sitl_record("garbage on both ports", "neither side crashes, every bad input is counted, no setpoint outside the "
                "limits, flight completes", datagrams=[to_bridge_sent, to_vehicle_sent],
                bridge={"invalid": summary.invalid, "superseded": summary.superseded, "foreign_attitude": summary.foreign_attitude,
                        "bad_data": stats.bad_data, "reader_errors": stats.reader_errors},
                vehicle=sim_delta, end=summary.end_reason,
                steady_deg=[round(a["steady_deg"], 3) for a in axes])
    assert to_bridge_sent == len(items_b) and to_vehicle_sent == len(items_v)
    assert flight.server.error is None and flight.server.running
    assert summary.failsafe is None and summary.end_reason == "duration complete"
    # NaN, inf and absurd ATTITUDE: each is either rejected on its values (invalid) or, when the next
    # real ATTITUDE was already queued behind it, superseded unseen; none may drive a cycle.
    # (which of the two is a race with the sim's next ATTITUDE; the property test shows the invalid
    # path with dozens of samples). The absurd roll is finite, so it meets the vehicle clock first: stamped
    # 1 s ahead of a stream heard a few ms ago it continues no clock, and is held, then refuted by the stream:
    # a clock outlier (vehicle_clock). The sum passed only when another one was superseded (seen failing once:
    # invalid 2, superseded 0).
    assert summary.invalid + summary.superseded + summary.clock_outliers >= 3, (
        summary.invalid, summary.superseded, summary.clock_outliers)
    assert summary.foreign_attitude >= 1
    assert stats.bad_data >= 1
    assert sim_delta["wrong_target"] >= 2 and sim_delta["bad_field_values"] >= 1
    assert sim_delta["bad_input_total"] >= len(items_v) - 1
    assert flight.setpoint_violations() == []
    assert flight.server.call(lambda c: c.armed) and flight.server.call(lambda c: c.mode_name) == "GUIDED"


# ---------------------------------------------------------------- signing
KEY = bytes(range(32))


def test_signing_with_the_right_key_flies_and_every_packet_is_signed(flight_factory, sitl_record):
    flight = flight_factory(controller="astsm", sim=dict(signing_key=KEY), bridge=dict(signing_key=KEY, duration_s=1.5))
    raw_unsigned = []
    tap = flight.tap

    def signing_tap(direction, datagram, t):
        if direction == "to_target" and datagram[:1] == b"\xfd" and not datagram[2] & 0x01:
            raw_unsigned.append(datagram)
        tap(direction, datagram, t)

    flight.proxy.tap = signing_tap
    summary = flight.finish() if flight.wait_engaged() else None
    counters = flight.server.counters
    sitl_record("signing, right key on both ends", "engages and flies; nothing unsigned on the wire",
                end=summary.end_reason, unsigned_from_bridge=len(raw_unsigned),
                vehicle_rejections=counters["unsigned_rejected"] + counters["bad_signature"])
    assert summary.failsafe is None and summary.end_reason == "duration complete"
    assert raw_unsigned == []
    assert counters["unsigned_rejected"] == 0 and counters["bad_signature"] == 0


@pytest.mark.parametrize("bridge_key", [bytes(reversed(range(32))), None], ids=["wrong key", "unsigned"])
def test_signing_wrong_key_or_unsigned_is_rejected_and_reported(flight_factory, sitl_record, bridge_key):
    flight = flight_factory(controller="astsm", sim=dict(signing_key=KEY), start=False,
                            bridge=dict(signing_key=bridge_key),
                            overrides={"link.heartbeat_wait_s": 1.0, "link.command_ack_timeout_s": 0.2,
                                       "link.command_retries": 1, "link.param_timeout_s": 0.2})
    t0 = time.monotonic()
    with pytest.raises((LinkError, OffboardRejected)) as err:
        flight.start_bridge()
    counters = flight.server.counters
    rejected = counters["bad_signature"] + counters["unsigned_rejected"]
    name = "signing, wrong key on the bridge" if bridge_key else "signing, unsigned bridge"
    sitl_record(name, "the vehicle rejects and counts the bridge's commands; the bridge stops at start-up with a "
                "one-line error", error=f"{type(err.value).__name__}: {err.value}", vehicle_rejected=rejected,
                wall_s=round(time.monotonic() - t0, 2))
    assert rejected > 0
    assert "\n" not in str(err.value)
    assert flight.server.call(lambda c: not c.armed and c.mode_name != "GUIDED")
    assert flight.setpoints == [] or all(m.type_mask != 0x80 for _, m in flight.setpoints)


# ---------------------------------------------------------------- the pilot takes over
def test_pilot_leaves_guided_bridge_stops_commanding_at_once(flight_factory, ground_station, sitl_record):
    flight = flight_factory(controller="astsm")
    engage_s = flight.wait_engaged()
    flight.wait_vehicle_time(engage_s + 1.5)
    gcs = ground_station(flight.server.port)
    gcs.set_mode("LOITER")
    assert flight.server.wait_until(lambda c: c.mode_name == "LOITER", 10.0)
    summary = flight.finish()
    loiter = COPTER_MODES["LOITER"]
    t_mode = next(t for t, mode, _ in flight.vehicle_heartbeats if mode == loiter)
    after = [(t, m) for t, m in flight.setpoints if t > t_mode + 1e-9]
    last_cmd_t = max(t for t, _ in flight.setpoints if math.isfinite(t))
    sitl_record("pilot switches away from GUIDED (LOITER)", "no setpoint after the first HEARTBEAT in the new mode; "
                "MODE_CHANGED; the bridge does not switch back", setpoints_after_mode_heartbeat=len(after),
                last_setpoint_minus_mode_heartbeat_s=round(last_cmd_t - t_mode, 4),
                failsafe=summary.failsafe.name if summary.failsafe else "none",
                mode_at_end=flight.server.call(lambda c: c.mode_name))
    assert after == [], f"{len(after)} setpoints after the mode change"
    assert summary.failsafe is FailsafeReason.MODE_CHANGED
    assert flight.server.call(lambda c: c.mode_name) == "LOITER"
    assert flight.setpoint_violations() == []


def test_pilot_returns_to_guided_bridge_reengages_with_fresh_gains_when_configured(flight_factory, ground_station, sitl_record):
    # The bridge's default ASTSM preset (astsm_mavlink, alpha_m = 5) keeps alpha at its floor on the paper
    # steps, which would make the reset check vacuous; astsm_400hz (alpha_m = 0.01) adapts on the steps.
    flight = flight_factory(controller="astsm", bridge=dict(reengage=True, duration_s=30.0, controller_config="astsm_400hz"))
    engage_s = flight.wait_engaged()
    flight.wait_vehicle_time(engage_s + 1.5)
    session = flight.bridge.session
    gcs = ground_station(flight.server.port)
    # the pause must come while alpha is above its floor, or a reset to the floor proves nothing: after each step's
    # transient alpha decays back to alpha_m, and on a loaded machine the ground station's start-up took long enough
    # for that (CI, 2026-12-02). So the mode change is sent the moment alpha is seen above 1.5 alpha_m.
    alpha_m = flight.bridge.controller.gains.alpha_min

    def adapted():
        s = flight.bridge.telemetry.snapshot(max_samples=1).latest
        return s is not None and s.failsafe is None and any(a > 1.5 * m for a, m in zip(s.alpha, alpha_m))

    flight.wait_for(adapted, 20.0, "alpha to adapt above its floor on the paper steps")
    gcs.set_mode("LOITER")
    flight.wait_for(lambda: session.state == "paused", 10.0, "the bridge to pause")
    n_before = len(flight.setpoints)
    gcs.set_mode("GUIDED")
    engage2_s, summary = _fly_second_engagement(flight, session, 0.5)
    first = [s for s in summary.samples if s.failsafe is None and math.isfinite(s.alpha[0])]
    alpha_at_engage1 = next(s.alpha for s in first if s.vehicle_time_s >= engage_s)
    alpha_before_pause = [s.alpha for s in first if s.vehicle_time_s < engage2_s][-1]
    alpha_at_engage2 = next(s.alpha for s in first if s.vehicle_time_s >= engage2_s)
    sitl_record("pilot leaves GUIDED and comes back (reengage on)", "pauses, then re-engages with reset adaptive gains",
                engagements=session.counters.engagements, alpha_first_cycle=[round(a, 4) for a in alpha_at_engage1],
                alpha_before_pause=[round(a, 4) for a in alpha_before_pause],
                alpha_first_cycle_after_reengage=[round(a, 4) for a in alpha_at_engage2],
                setpoints_while_paused=len([1 for t, m in flight.setpoints[n_before:] if t < engage2_s - 1e-9]))
    assert session.counters.engagements == 2
    assert alpha_at_engage2 == pytest.approx(alpha_at_engage1, rel=1e-9, abs=1e-12)
    assert alpha_before_pause != pytest.approx(alpha_at_engage1), "alpha never adapted: the reset check would be vacuous"
    assert flight.setpoint_violations() == []


# ---------------------------------------------------------------- a ground station fights over the streams
MAVPROXY = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent)) or shutil.which("mavproxy.py")


def test_mavproxy_rerequesting_streams_bridge_reasserts_attitude_rate_and_keeps_control(
        flight_factory, spawn, tmp_path, sitl_record):
    """Real time (a 4 Hz ATTITUDE stream in lockstep would let the sim race ahead between samples)."""
    assert MAVPROXY is not None, "MAVProxy is in the test extras (pip install -e .[test])"
    flight = flight_factory(controller="astsm", reference="hold", sim=dict(clock="realtime"),
                            bridge=dict(duration_s=60.0))
    engage_s = flight.wait_engaged(60.0)
    vehicle = flight.server.vehicle
    attitude_us = lambda: flight.server.call(lambda c: vehicle.effective_interval_us(30))  # noqa: E731
    nominal_us = attitude_us()
    mavproxy = spawn(MAVPROXY, f"--master=udpout:127.0.0.1:{flight.server.port}", f"--state-basedir={tmp_path}",
                     "--streamrate=4", stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                     cwd=tmp_path, env_home=str(tmp_path))
    reasserts = []
    for round_no, command in enumerate((None, "set streamrate 5\n")):
        if command:
            mavproxy.stdin.write(command)
            mavproxy.stdin.flush()
        flight.wait_for(lambda: attitude_us() != nominal_us, 60.0, f"MAVProxy to override the ATTITUDE rate ({round_no})")
        t_override = time.monotonic()
        overridden_us = attitude_us()
        flight.wait_for(lambda: attitude_us() == nominal_us, 30.0, f"the bridge to re-assert ({round_no})")
        reasserts.append((overridden_us, round(time.monotonic() - t_override, 2)))
    t_check = flight.server.sim_time_s
    flight.wait_vehicle_time(t_check + 1.0)
    flight.bridge.request_stop()
    summary = flight.finish()
    recent = [t for t, *_ in flight.truth_between(t_check, t_check + 1.0)]
    achieved_hz = (len(recent) - 1) / (recent[-1] - recent[0])
    max_tilt = flight.max_tilt_deg(engage_s)
    timing = flight.bridge.config.timing
    sitl_record("MAVProxy re-requesting streams (REQUEST_DATA_STREAM)", "the bridge re-sends SET_MESSAGE_INTERVAL "
                f"(at most every interval_reassert_s = {timing.interval_reassert_s:g} s once the achieved rate is below "
                "half the request) and keeps control", reasserts_us_then_wall_s=reasserts,
                attitude_hz_after=round(achieved_hz, 1), engagements=summary.engagements,
                end=summary.end_reason, max_tilt_deg=round(max_tilt, 1))
    assert len(reasserts) == 2 and all(us > nominal_us for us, _ in reasserts)
    assert achieved_hz > 0.9 * 1e6 / nominal_us
    assert summary.failsafe is None and summary.engagements == 1 and summary.end_reason == "operator stop"
    assert max_tilt < 10.0
    assert flight.setpoint_violations() == []
