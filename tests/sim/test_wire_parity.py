"""Wire parity with genuine ArduCopter (issue 16, D1-D8): black-box tests of the sim over real UDP with plain pymavlink.

Each test names the ArduCopter behaviour it reproduces; the genuine numbers (ArduCopter 4.7.0-dev SITL, default quad,
measured on the wire) are in docs/sim.md, "Wire parity with ArduCopter". Lockstep, simulated time from
``time_boot_ms`` or from the server's clock; wall-clock timeouts only bound the waits.
"""

from __future__ import annotations

import subprocess
import sys
from collections import Counter

import pytest
from mavlink_peer_tools import ATTITUDE_ID, fly, guided_and_armed, mavlink, rates_command

from mavastsm_sim.arducopter_profile import FirmwareVersion, load_profile


def habits(**changed):
    """The default profile with ``changed`` habits, as ``mavastsm sim --set KEY=VALUE``."""
    return load_profile(overrides=changed)


GUIDED, GUIDED_NOGPS = 4, 20
TOO_FAST_TEXT = "Requested rate for message ID 30 too fast. Increase SCHED_LOOP_RATE"
WIRE_4_7 = habits(firmware_version="4.7.0-dev")


def started(make_server, make_gcs, **server_options):
    server = make_server(**server_options)
    gcs = make_gcs(server.port)
    gcs.hello()
    return server, gcs


def statustexts_after(gcs, command_result, count: int, timeout_s: float = 2.0) -> list:
    texts = []
    while len(texts) < count:
        msg = gcs.recv("STATUSTEXT", timeout_s)
        assert msg is not None, f"only {len(texts)} STATUSTEXT of {count} after the ACK {command_result}"
        texts.append(msg)
    return texts


def answer_each_attitude(att):
    return 0x80, [1.0, 0.0, 0.0, 0.0], (0.0, 0.0, 0.0), 0.5


# --- D1: the version decides the SET_MESSAGE_INTERVAL rule ------------------------------------------------------------
def test_d1_arducopter_4_6_and_later_deny_an_interval_faster_than_the_loop_with_mav_result_2_and_a_text(make_server,
                                                                                                        make_gcs):
    server, gcs = started(make_server, make_gcs, profile=WIRE_4_7)
    for interval_us in (2500, 2999, 1000):  # 400 Hz, just faster than 3 ms, 1 kHz: faster than one per 2.5 ms loop
        ack = gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, interval_us)
        assert ack.result == mavlink.MAV_RESULT_DENIED, (interval_us, ack)
        chunks = statustexts_after(gcs, ack, 2)
        assert "".join(c.text for c in chunks) == TOO_FAST_TEXT
    assert not server.vehicle.attitude_streaming()
    for interval_us in (3000, 3003):  # whole milliseconds: 3 ms (333.3 Hz) is what a 400 Hz loop allows
        assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, interval_us).result == \
            mavlink.MAV_RESULT_ACCEPTED
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, ATTITUDE_ID, 0, 0, 0, 0, 0, 0)
    assert gcs.recv("MESSAGE_INTERVAL", condition=lambda m: m.message_id == ATTITUDE_ID).interval_us == 3000
    assert server.counters["message_intervals_denied"] == 3


def test_d1_a_faster_loop_lets_arducopter_4_7_accept_a_faster_interval(make_server, make_gcs):
    server, gcs = started(make_server, make_gcs, profile=WIRE_4_7, sched_loop_rate_hz=500)
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, 2000).result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, 1999).result == mavlink.MAV_RESULT_DENIED


@pytest.mark.parametrize("stream_timing, capped_interval_us", [("even", 3125), ("loop-ticks", 3000)])
def test_d1_arducopter_before_4_6_caps_a_fast_interval_silently(make_server, make_gcs, stream_timing,
                                                                capped_interval_us):
    server, gcs = started(make_server, make_gcs, profile=habits(firmware_version="4.5.7",
                                                                      stream_timing=stream_timing))
    ack = gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, 1000)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.recv("STATUSTEXT", timeout_s=0.3) is None  # no word about it
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, ATTITUDE_ID, 0, 0, 0, 0, 0, 0)
    reply = gcs.recv("MESSAGE_INTERVAL", condition=lambda m: m.message_id == ATTITUDE_ID)
    assert reply.interval_us == capped_interval_us  # 80 % of the 400 Hz loop; whole ms: ArduPilot's int(3.125 ms)


# --- D2: ATTITUDE on ArduCopter's loop ticks --------------------------------------------------------------------------
def attitude_gaps_ms(gcs, duration_s: float) -> list[int]:
    stamps = [m.time_boot_ms for m in fly(gcs, duration_s, answer_each_attitude)]
    return [b - a for a, b in zip(stamps, stamps[1:])]


def test_d2_attitude_at_333hz_from_a_400hz_loop_comes_on_loop_ticks_with_2_3_2_3_5_ms_gaps(make_server, make_gcs):
    """Genuine 4.7 SITL, 3 s at 333 Hz: time_boot_ms gaps 2 ms x398, 3 ms x401, 5 ms x197 (and 4 ms x2 from load):
    the scheduler sends when millis - last_sent >= 3 ms, on ticks 2.5 ms apart, skipping every sixth tick."""
    server, gcs = started(make_server, make_gcs, profile=WIRE_4_7)
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, 3000).result == mavlink.MAV_RESULT_ACCEPTED
    gaps = attitude_gaps_ms(gcs, 1.5)
    counts = Counter(gaps)
    assert set(counts) == {2, 3, 5}, counts
    assert abs(counts[2] - counts[3]) <= 1 and abs(counts[2] - 2 * counts[5]) <= 2, counts
    assert abs(len(gaps) / (sum(gaps) / 1000.0) - 1000.0 / 3.0) < 1.0  # 333.3 Hz on average
    window = tuple(gaps[10:15])
    assert window in {(2, 3, 2, 3, 5)[i:] + (2, 3, 2, 3, 5)[:i] for i in range(5)}, gaps[:20]
    assert all(tuple(gaps[i:i + 5]) == tuple(gaps[i + 5:i + 10]) for i in range(0, len(gaps) - 10, 5)), gaps[:40]


def test_d2_an_interval_the_loop_divides_comes_evenly(make_server, make_gcs):
    server, gcs = started(make_server, make_gcs, profile=WIRE_4_7)
    gcs.set_interval(ATTITUDE_ID, 200)
    assert set(attitude_gaps_ms(gcs, 0.5)) == {5}  # 5 ms = two 2.5 ms ticks


# --- D4: parameters as ArduCopter serves them --------------------------------------------------------------------------
def read_by_name(gcs, name: str):
    gcs.mav.param_request_read_send(1, 1, name.encode(), -1)
    return gcs.recv("PARAM_VALUE", condition=lambda m: m.param_id == name)


def test_d4_sitl_quad_parameter_set_reads_back_genuine_sitl_default_quad_controller(make_server, make_gcs):
    """Genuine SITL quad (copter.parm): ATC_ACCEL_R/P/Y_MAX 110000/110000/27000, ATC_ANG_*_P 4.5, ATC_RAT_RLL/PIT
    P=I 0.135 D 0.0036 FLTD 20, ATC_RAT_YAW P 0.3 I 0.02 FLTE 2.5; the Solo's are 36000/36000/7000, yaw P 3.42..."""
    genuine = {"ATC_ACCEL_R_MAX": 110000.0, "ATC_ACCEL_P_MAX": 110000.0, "ATC_ACCEL_Y_MAX": 27000.0,
               "ATC_ANG_RLL_P": 4.5, "ATC_ANG_PIT_P": 4.5, "ATC_ANG_YAW_P": 4.5, "ATC_RAT_RLL_P": 0.135,
               "ATC_RAT_PIT_I": 0.135, "ATC_RAT_RLL_D": 0.0036, "ATC_RAT_PIT_FLTD": 20.0, "ATC_RAT_YAW_P": 0.3,
               "ATC_RAT_YAW_I": 0.02, "ATC_RAT_YAW_FLTE": 2.5}
    server, gcs = started(make_server, make_gcs, profile=habits(parameter_set="sitl-quad"))
    for name, value in genuine.items():
        assert read_by_name(gcs, name).param_value == pytest.approx(value, rel=1e-6), name
    solo_server, solo_gcs = started(make_server, make_gcs)
    assert read_by_name(solo_gcs, "ATC_ACCEL_R_MAX").param_value == 36000.0
    # the emulated controller flies the Solo with them: a 1 s hover after take-off stays level
    guided_and_armed(gcs)
    gcs.set_interval(ATTITUDE_ID, 50)
    fly(gcs, 2.0, rates_command(thrust=0.8))
    hover = fly(gcs, 1.0, rates_command(thrust=0.5))
    assert max(abs(m.roll) + abs(m.pitch) for m in hover) < 0.05
    assert not server.call(lambda c: c.landed)


def test_d4_param_value_for_a_read_by_name_or_a_set_carries_index_65535(make_server, make_gcs):
    server, gcs = started(make_server, make_gcs, profile=habits(param_index_65535=True))
    by_name = read_by_name(gcs, "GUID_TIMEOUT")
    assert by_name.param_index == 65535 and by_name.param_count == server.copter.params.count
    index = server.copter.params.index_of("GUID_TIMEOUT")
    gcs.mav.param_request_read_send(1, 1, b"", index)
    assert gcs.recv("PARAM_VALUE").param_index == index  # a read by index names its index
    assert gcs.set_param("GUID_TIMEOUT", 1.5).param_index == 65535


def test_d4_parameter_reads_are_answered_one_per_100ms(make_server, make_gcs):
    """Genuine 4.7 SITL: five reads by name in a row answered after 6, 105, 99, 100, 100 ms (its parameter slot)."""
    server, gcs = started(make_server, make_gcs, profile=habits(param_read_interval_s=0.1))
    gcs.set_interval(ATTITUDE_ID, 200)  # a 5 ms clock for the replies, answered in lockstep
    names = ["ATC_ACCEL_R_MAX", "ATC_ANG_RLL_P", "ATC_RAT_RLL_P", "SCHED_LOOP_RATE", "GUID_TIMEOUT"]
    first = fly(gcs, 0.02, answer_each_attitude)[-1].time_boot_ms
    for name in names:
        gcs.mav.param_request_read_send(1, 1, name.encode(), -1)
    got = fly(gcs, 0.6, answer_each_attitude, extra_types=("PARAM_VALUE",))
    replies, clock_ms = [], first
    for msg in got:
        if msg.get_type() == "ATTITUDE":
            clock_ms = msg.time_boot_ms
        else:
            replies.append((msg.param_id, clock_ms))
    assert [name for name, _ in replies] == names
    times = [t for _, t in replies]
    assert times[0] - first <= 10
    assert all(95 <= b - a <= 105 for a, b in zip(times, times[1:])), times


def test_d4_unsolicited_param_values_arrive_mid_flight(make_server, make_gcs):
    """ArduPilot saves its statistics every 30 s and announces each change: genuine SITL sent STAT_RUNTIME 30 (index
    65535) at 30.5 s; in flight STAT_FLTTIME too. A bridge must not take them for answers to its own reads."""
    server, gcs = started(make_server, make_gcs, profile=habits(unsolicited_param_values=True))
    guided_and_armed(gcs)
    gcs.set_interval(ATTITUDE_ID, 20)
    fly(gcs, 2.0, rates_command(thrust=0.8))
    got = fly(gcs, 29.0, rates_command(thrust=0.5), extra_types=("PARAM_VALUE",), timeout_s=60.0)
    announced = {m.param_id: m for m in got if m.get_type() == "PARAM_VALUE"}
    assert set(announced) == {"STAT_RUNTIME", "STAT_FLTTIME"}, announced
    assert announced["STAT_RUNTIME"].param_value == 30.0 and announced["STAT_RUNTIME"].param_index == 65535
    assert 25.0 <= announced["STAT_FLTTIME"].param_value < 30.0
    assert not server.call(lambda c: c.landed)


# --- D5: AUTOPILOT_VERSION release type -------------------------------------------------------------------------------
@pytest.mark.parametrize("version, flight_sw_version", [("4.5.7", 0x040507FF), ("4.7.0-dev", 0x04070000),
                                                        ("4.6.0-beta2", 0x04060080), ("4.6.1-rc1", 0x040601C0)])
def test_d5_autopilot_version_carries_the_release_type_of_the_firmware_version(make_server, make_gcs, version,
                                                                               flight_sw_version):
    """Genuine 4.7.0-dev SITL: flight_sw_version 0x04070000 (type 0x00 dev); an official 4.5.7 is 0x040507FF."""
    server, gcs = started(make_server, make_gcs, profile=habits(firmware_version=version))
    ack = gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.recv("AUTOPILOT_VERSION").flight_sw_version == flight_sw_version
    gcs.mav.param_request_list_send(1, 1)
    banner = gcs.recv("STATUSTEXT", condition=lambda m: m.text.startswith("ArduCopter V"))
    assert banner.text.startswith(f"ArduCopter V{version} ")


def test_d5_a_malformed_firmware_version_is_one_line_and_exit_status_2():
    run = subprocess.run([sys.executable, "-m", "sim", "--set", "firmware_version=4.7", "--duration-s", "0.1",
                          "--listen", "127.0.0.1:0"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.strip().count("\n") == 0, run.stderr
    assert "MAJOR.MINOR.PATCH" in run.stderr
    assert FirmwareVersion.parse("4.7.0-dev").release == "dev"


# --- D6: a realistic pre-arm delay ----------------------------------------------------------------------------------
def arm(gcs):
    return gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)


def wait_sim_time(server, time_s: float) -> None:
    assert server.wait_until(lambda c: c.time_s >= time_s, timeout_s=10.0), server.sim_time_s


def test_d6_arming_is_refused_with_arducopters_reasons_until_the_prearm_delay_has_passed(make_server, make_gcs):
    """Genuine 4.7 SITL in GUIDED: MAV_RESULT 4 with "Arm: Gyros inconsistent" + "Arm: AHRS: waiting for home" until
    the EKF origin is set (20 s), then "Arm: Need Position Estimate"; the SYS_STATUS pre-arm bit clear meanwhile."""
    delay_s = 2.0
    server, gcs = started(make_server, make_gcs, speedup=4.0, profile=habits(prearm_delay_s=delay_s))
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_SYS_STATUS, 20)
    status = gcs.recv("SYS_STATUS")
    assert not status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    ack = arm(gcs)
    assert ack.result == mavlink.MAV_RESULT_FAILED
    assert [t.text for t in statustexts_after(gcs, ack, 2)] == ["Arm: Gyros inconsistent", "Arm: AHRS: waiting for home"]
    assert gcs.recv("STATUSTEXT", condition=lambda m: m.text == "EKF3 IMU0 origin set", timeout_s=5.0) is not None
    assert gcs.recv("GPS_GLOBAL_ORIGIN", timeout_s=1.0) is not None  # the EKF origin is announced when it is set
    ack = arm(gcs)
    assert ack.result == mavlink.MAV_RESULT_FAILED
    texts = [t.text for t in statustexts_after(gcs, ack, 2)]
    assert texts == ["Arm: Gyros inconsistent", "Arm: Need Position Estimate"], texts
    wait_sim_time(server, delay_s)
    assert gcs.recv("SYS_STATUS", condition=lambda m: m.onboard_control_sensors_health
                    & mavlink.MAV_SYS_STATUS_PREARM_CHECK, timeout_s=2.0) is not None
    assert arm(gcs).result == mavlink.MAV_RESULT_ACCEPTED
    assert server.counters["arming_refused_starting_up"] == 2


def test_d6_a_forced_arm_skips_the_startup_checks_and_a_vehicle_starts_in_boot_state(make_server, make_gcs):
    server = make_server(profile=habits(prearm_delay_s=30.0))
    gcs = make_gcs(server.port)
    assert gcs.hello().system_status == mavlink.MAV_STATE_BOOT  # genuine: 1 until "ArduPilot Ready" (2.45 s)
    assert gcs.command(mavlink.MAV_CMD_RUN_PREARM_CHECKS).result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.recv("STATUSTEXT").text == "PreArm: Gyros inconsistent"
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, 2989).result == mavlink.MAV_RESULT_ACCEPTED


def test_d6_without_a_prearm_delay_the_sim_arms_at_once(make_server, make_gcs):
    server, gcs = started(make_server, make_gcs)
    assert server.sim_time_s < 1.0
    guided_and_armed(gcs)


# --- D7: STATUSTEXT chunks ------------------------------------------------------------------------------------------
def test_d7_statustext_longer_than_50_characters_is_split_into_chunks_with_id_and_chunk_seq(make_server, make_gcs):
    """Genuine: "Requested rate for message ID 30 too fast. Increas" + "e SCHED_LOOP_RATE", id 1 then 2, 3 ..."""
    server, gcs = started(make_server, make_gcs, profile=WIRE_4_7)
    ids = []
    for _ in range(2):
        ack = gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, 2500)
        chunks = statustexts_after(gcs, ack, 2)
        assert [c.text for c in chunks] == [TOO_FAST_TEXT[:50], TOO_FAST_TEXT[50:]]
        assert [c.chunk_seq for c in chunks] == [0, 1] and chunks[0].id == chunks[1].id != 0
        ids.append(chunks[0].id)
    assert ids[1] == ids[0] + 1
    gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    assert arm(gcs).result == mavlink.MAV_RESULT_ACCEPTED
    short = gcs.recv("STATUSTEXT", condition=lambda m: m.text == "Arming motors")
    assert short.id == 0 and short.chunk_seq == 0  # one piece: no id


# --- D8: after arming -------------------------------------------------------------------------------------------------
def test_d8_home_position_and_gps_global_origin_follow_arming_and_status_is_standby_until_airborne(make_server,
                                                                                                  make_gcs):
    """Genuine 4.7 SITL: GPS_GLOBAL_ORIGIN then HOME_POSITION with the arm ACK; HEARTBEAT system_status 3 (STANDBY)
    while armed on the ground, 4 (ACTIVE) from lift-off."""
    server, gcs = started(make_server, make_gcs)
    guided_and_armed(gcs)
    origin = gcs.recv("GPS_GLOBAL_ORIGIN", timeout_s=1.0)
    home = gcs.recv("HOME_POSITION", timeout_s=1.0)
    assert origin is not None and home is not None
    assert (origin.latitude, origin.longitude, origin.altitude) == (-353632610, 1491652300, 584000)
    assert (home.latitude, home.longitude) == (origin.latitude, origin.longitude)
    assert gcs.recv("HEARTBEAT", condition=lambda m: m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED).system_status \
        == mavlink.MAV_STATE_STANDBY
    gcs.set_interval(ATTITUDE_ID, 50)
    got = fly(gcs, 3.0, rates_command(thrust=0.8), extra_types=("HEARTBEAT",))
    assert [m.system_status for m in got if m.get_type() == "HEARTBEAT"][-1] == mavlink.MAV_STATE_ACTIVE
    assert not server.call(lambda c: c.landed)


def test_d8_a_vehicle_without_a_position_estimate_announces_no_home(make_server, make_gcs):
    server, gcs = started(make_server, make_gcs, profile=habits(position_estimate=False))
    gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED_NOGPS)
    assert arm(gcs).result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.recv(["HOME_POSITION", "GPS_GLOBAL_ORIGIN"], timeout_s=0.5) is None


# --- D9: take-off timing ----------------------------------------------------------------------------------------------
TAKEOFF_M = 2.0


def bridge_takeoff(server, gcs, duration_s: float = 9.0, timeout_s: float = 60.0) -> tuple[float, list, list]:
    """GUIDED_NOGPS, arm, then the bridge's ``--takeoff 2`` climb as genuine SITL was measured with it, before its
    approach taper (``thrust.takeoff_approach_m=0``, mavastsm/bridge/session/offboard_session.py): level attitude,
    climb-rate thrust ramped 0.5 -> 0.7 (1 m/s) over 1 s, 0.5 (hold) once 2 m is reached; lockstep, one answer per
    ATTITUDE. Returns the simulated time of the arm ACK [s], (t [s], altitude [m]) from GLOBAL_POSITION_INT and
    (t [s], four motor PWM [us]) from SERVO_OUTPUT_RAW."""
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED_NOGPS).result == \
        mavlink.MAV_RESULT_ACCEPTED
    assert arm(gcs).result == mavlink.MAV_RESULT_ACCEPTED
    t_ack = server.sim_time_s
    for msg_id, hz in ((ATTITUDE_ID, 100), (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 20),
                       (mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, 20)):
        gcs.set_interval(msg_id, hz)
    alts, pwms, reached = [], [], False
    t_end = t_ack + duration_s
    import time
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = gcs.conn.recv_match(type=["ATTITUDE", "GLOBAL_POSITION_INT", "SERVO_OUTPUT_RAW"], blocking=True, timeout=1.0)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            alts.append((msg.time_boot_ms / 1000.0, msg.relative_alt / 1000.0))
            reached = reached or alts[-1][1] >= TAKEOFF_M
        elif kind == "SERVO_OUTPUT_RAW":
            pwms.append((msg.time_usec / 1e6, (msg.servo1_raw, msg.servo2_raw, msg.servo3_raw, msg.servo4_raw)))
        else:
            t = msg.time_boot_ms / 1000.0
            thrust = 0.5 if reached else 0.5 + 0.2 * min(1.0, max(t - t_ack, 0.0))
            gcs.mav.set_attitude_target_send(msg.time_boot_ms, 1, 1, 0x07, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, thrust)
            if t >= t_end:
                return t_ack, alts, pwms
    raise AssertionError(f"take-off of {duration_s} s simulated did not finish in {timeout_s} s wall")


def liftoff_and_overshoot(t_ack: float, alts: list) -> tuple[float, float]:
    """Lift-off (first altitude above 5 cm) after the arm ACK [s], and the peak's overshoot of 2 m [m]."""
    lift = next(t for t, a in alts if a > 0.05) - t_ack
    return lift, max(a for _, a in alts) - TAKEOFF_M


def test_d9_arducopter_holds_the_motors_for_its_arming_delay_and_spools_up_before_lifting_off(make_server, make_gcs):
    """Genuine 4.7 SITL on the Solo physics, the bridge's --takeoff 2: motor commands 0 until 2.0 s after the arm, a
    ramp to 0.15 (MOT_SPIN_MIN) by 2.5 s, lift-off 3.57-3.68 s after the arm ACK (EKF altitude above 5 cm), peak 0.75-0.80 m
    over 2 m (three flights). ArduCopter's causes: the motor interlock is off for ARMING_DELAY_SEC (2 s), the motors spool
    to MOT_SPIN_MIN over MOT_SPOOL_TIME (0.5 s), the vertical controller starts from zero throttle (its integrator at
    minus the hover throttle) and its velocity target is jerk-limited (PSC_JERK_Z), so the climb overshoots."""
    server, gcs = started(make_server, make_gcs, profile=habits(takeoff_timing="arducopter"))
    t_ack, alts, pwms = bridge_takeoff(server, gcs)
    stopped = [p for t, p in pwms if t - t_ack < 1.95]
    assert stopped and all(p == (1000, 1000, 1000, 1000) for p in stopped), stopped[:5]  # interlock off: not even idle
    spooling = [(t - t_ack, p[0]) for t, p in pwms if 2.05 < t - t_ack < 2.45]
    assert spooling and all(abs(pwm - (1000 + 150 * (t - 2.0) / 0.5)) <= 10 for t, pwm in spooling), spooling
    lift, overshoot = liftoff_and_overshoot(t_ack, alts)
    assert 3.3 <= lift <= 3.9, lift  # measured here 3.50 s
    assert 0.6 <= overshoot <= 1.0, overshoot  # measured here 0.80 m


def test_d9_without_it_the_sim_lifts_off_at_once_with_a_small_overshoot(make_server, make_gcs):
    server, gcs = started(make_server, make_gcs)
    t_ack, alts, pwms = bridge_takeoff(server, gcs, duration_s=5.0)
    lift, overshoot = liftoff_and_overshoot(t_ack, alts)
    assert lift < 1.0 and overshoot < 0.4, (lift, overshoot)


# --- the closed loop of genuine SITL: command latency and air-density compensation (docs/sim.md, "Closed-loop parity")
def roll_response_delay_s(server, gcs) -> float:
    """Airborne in GUIDED (climb at 1.5 m/s, then hold), then a 1 rad/s roll-rate step: simulated time [s] from the
    ATTITUDE answered with the first step command to the first ATTITUDE whose roll rate exceeds 0.05 rad/s."""
    guided_and_armed(gcs)
    gcs.set_interval(ATTITUDE_ID, 333)
    fly(gcs, 2.0, rates_command(thrust=0.8))
    fly(gcs, 0.5, rates_command(thrust=0.5))
    got = fly(gcs, 0.3, rates_command(p=1.0, thrust=0.5))
    t_step = got[0].time_boot_ms / 1000.0
    return next(m.time_boot_ms / 1000.0 for m in got if m.rollspeed > 0.05) - t_step


def test_genuine_sitl_acts_on_a_bridge_answer_milliseconds_after_it_arrives(make_server, make_gcs):
    """Genuine SITL runs its loop in bursts against the wall clock (ATTITUDE in bursts of 2-3 every 5.6-6.0 ms), so an
    answer reaches ArduCopter milliseconds of simulated time after the ATTITUDE it answers (5.1 ms mean measured at the
    physics); ``command_latency_s`` holds each SET_ATTITUDE_TARGET that long after its arrival."""
    delays = {}
    for latency_s in (0.0, 0.02):
        server, gcs = started(make_server, make_gcs, profile=habits(command_latency_s=latency_s))
        delays[latency_s] = roll_response_delay_s(server, gcs)
    assert delays[0.0] < 0.06, delays  # measured 44 ms: the rate shaping, rate loop and gyro filter of any answer
    assert 0.016 <= delays[0.02] - delays[0.0] <= 0.024, delays


def test_arducopter_compensates_its_motors_for_the_air_density_at_the_home_altitude(make_server, make_gcs):
    """AP_MotorsMulticopter::get_compensation_gain: roll, pitch, yaw and throttle demands times 1 / (air density ratio),
    1.058 at SITL's home (584 m AMSL). With it on, a collective of MOT_THST_HOVER (GUID_OPTIONS bit 3) climbs, because
    the emulator, unlike ArduCopter, does not learn its hover throttle."""
    from mavastsm_sim.autopilot_emulator import isa_density_ratio

    assert abs(1.0 / isa_density_ratio(584.0) - 1.058) < 0.001 and isa_density_ratio(0.0) == 1.0
    climbs = {}
    for on in (False, True):
        server, gcs = started(make_server, make_gcs, profile=habits(density_compensation=on))
        assert server.call(lambda c: round(c.autopilot.compensation_gain, 3)) == (1.058 if on else 1.0)
        guided_and_armed(gcs)
        gcs.set_interval(ATTITUDE_ID, 100)
        fly(gcs, 2.0, rates_command(thrust=0.8))
        fly(gcs, 0.5, rates_command(thrust=0.5))
        assert gcs.set_param("GUID_OPTIONS", 8).param_value == 8
        hover = server.call(lambda c: c.params.get("MOT_THST_HOVER"))
        fly(gcs, 1.5, rates_command(thrust=hover))
        climbs[on] = -server.call(lambda c: c.velocity_ned_ms[2])
    assert abs(climbs[False]) < 0.5 and climbs[True] > 0.5, climbs
