"""Checklist F1-F3 (docs/design-decisions.md, MAV-12): identity and HEARTBEAT contents, mode changes, arming
and disarming."""

from __future__ import annotations

from mavastsm_sim.arducopter_profile import load_profile
from mavlink_peer_tools import GCS_COMPID, GCS_SYSID, fly, guided_and_armed, mavlink, rates_command

GUIDED, LAND, STABILIZE, GUIDED_NOGPS = 4, 9, 0, 20


def test_heartbeat_identifies_an_arducopter_quad_on_the_ground(server_and_gcs):
    server, gcs = server_and_gcs
    hb = gcs.recv("HEARTBEAT")
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.base_mode == 81  # custom mode + stabilize + manual input, disarmed
    assert hb.custom_mode == STABILIZE
    assert hb.system_status == mavlink.MAV_STATE_STANDBY  # landed
    assert hb.mavlink_version == 3
    assert hb.get_header().incompat_flags == 0 and hb._msgbuf[0] == mavlink.PROTOCOL_MARKER_V2


def test_heartbeat_is_1hz_of_simulated_time_and_only_heartbeat_flows_by_default(make_server, make_gcs):
    server = make_server(speedup=4.0)  # 1 Hz of simulated time, 4 Hz of wall time
    gcs = make_gcs(server.port)
    gcs.hello()
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, 50)  # a clock to read heartbeat spacing against
    last_time_ms, beats, others = None, [], set()
    while len(beats) < 4:
        msg = gcs.recv(["HEARTBEAT", "SYSTEM_TIME", "ATTITUDE", "SYS_STATUS", "GLOBAL_POSITION_INT", "VFR_HUD"],
                       timeout_s=5.0)
        assert msg is not None
        if msg.get_type() == "SYSTEM_TIME":
            last_time_ms = msg.time_boot_ms
        elif msg.get_type() == "HEARTBEAT":
            if last_time_ms is not None:
                beats.append(last_time_ms)
        else:
            others.add(msg.get_type())
    spacing = [b - a for a, b in zip(beats, beats[1:])]
    assert all(abs(s - 1000) <= 20 for s in spacing), spacing  # 1 Hz, read on the 50 Hz SYSTEM_TIME grid
    assert others == set(), f"streams must be off until requested, got {others}"


def test_set_mode_message_acks_command_11_and_sends_an_extra_heartbeat(make_server, make_gcs):
    server = make_server(speedup=0.5)  # heartbeats 2 s apart in wall time: an extra one stands out
    gcs = make_gcs(server.port)
    gcs.hello()
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, 50)
    gcs.recv("HEARTBEAT", timeout_s=5.0)
    t_before = gcs.recv("SYSTEM_TIME").time_boot_ms
    gcs.mav.set_mode_send(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    ack = gcs.recv("COMMAND_ACK", condition=lambda m: m.command == mavlink.MAVLINK_MSG_ID_SET_MODE)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (GCS_SYSID, GCS_COMPID)
    hb = gcs.recv("HEARTBEAT", timeout_s=3.0)
    t_after = gcs.conn.messages["SYSTEM_TIME"].time_boot_ms
    assert hb.custom_mode == GUIDED and hb.base_mode == 89  # disarmed GUIDED
    assert t_after - t_before < 500, "the mode-change HEARTBEAT must not wait for the 1 Hz slot"
    assert server.call(lambda c: c.mode_number) == GUIDED


def test_do_set_mode_by_command_long_and_command_int(server_and_gcs):
    server, gcs = server_and_gcs
    ack = gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.recv("HEARTBEAT", condition=lambda m: m.custom_mode == GUIDED_NOGPS) is not None
    ack = gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED, use_int=True)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert server.call(lambda c: c.mode_number) == GUIDED


def test_mode_request_without_custom_flag_is_denied_and_changes_nothing(server_and_gcs):
    server, gcs = server_and_gcs
    ack = gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 0, GUIDED)
    assert ack.result == mavlink.MAV_RESULT_DENIED
    assert server.call(lambda c: c.mode_number) == STABILIZE


def test_pymavlink_set_mode_and_arm_helpers_work(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.conn.set_mode("GUIDED")
    assert gcs.recv("COMMAND_ACK", condition=lambda m: m.command == 176).result == mavlink.MAV_RESULT_ACCEPTED
    gcs.conn.arducopter_arm()
    assert gcs.recv("COMMAND_ACK", condition=lambda m: m.command == 400).result == mavlink.MAV_RESULT_ACCEPTED
    hb = gcs.recv("HEARTBEAT", timeout_s=3.0, condition=lambda m: m.base_mode & 128)
    assert hb.base_mode == 217 and hb.custom_mode == GUIDED
    assert gcs.conn.motors_armed()


def test_arm_refused_in_land_with_statustext_then_force_arm(server_and_gcs):
    server, gcs = server_and_gcs
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, LAND).result == mavlink.MAV_RESULT_ACCEPTED
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_FAILED
    text = gcs.recv("STATUSTEXT", condition=lambda m: m.text.startswith(("PreArm:", "Arm:")))
    assert text is not None and text.severity == mavlink.MAV_SEVERITY_CRITICAL
    assert not server.call(lambda c: c.armed)
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 7)  # neither 0 nor 1
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED


def test_arm_disarm_and_forced_disarm_in_flight(server_and_gcs):
    server, gcs = server_and_gcs
    guided_and_armed(gcs)
    assert server.call(lambda c: c.armed)
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED  # already armed: accepted
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_ATTITUDE, 50)
    fly(gcs, 2.0, rates_command(thrust=0.8))  # climb at ~1.5 m/s for 2 s
    assert server.call(lambda c: not c.landed and -c.position_ned_m[2] > 1.0)
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    assert ack.result == mavlink.MAV_RESULT_FAILED  # a plain disarm is refused in the air
    assert server.call(lambda c: c.armed)
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert server.call(lambda c: not c.armed)


def test_client_mode_sends_to_its_target_like_sitl_udpclient(make_server):
    from mavlink_peer_tools import mavutil

    listener = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255, source_component=190)
    try:
        port = listener.port.getsockname()[1]
        make_server(listen=None, target=("127.0.0.1", port))
        hb = listener.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0)  # without talking first
        assert hb is not None and hb.get_srcSystem() == 1
        listener.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, GUIDED, 0, 0, 0, 0, 0)
        ack = listener.recv_match(type="COMMAND_ACK", blocking=True, timeout=5.0)
        assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
    finally:
        listener.close()


def test_server_mode_answers_several_peers_at_once(server_and_gcs, make_gcs):
    server, bridge = server_and_gcs
    ground_station = make_gcs(server.port, source_component=191)
    ground_station.hello()
    bridge.set_interval(mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, 20)
    assert bridge.recv("SYSTEM_TIME") is not None and ground_station.recv("SYSTEM_TIME") is not None


def test_prearm_failure_without_position_estimate_then_guided_nogps_arms(make_server, make_gcs):
    server = make_server(profile=load_profile(overrides={"position_estimate": False}))
    gcs = make_gcs(server.port)
    gcs.hello()
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED).result == mavlink.MAV_RESULT_ACCEPTED  # disarmed
    assert gcs.command(mavlink.MAV_CMD_RUN_PREARM_CHECKS).result == mavlink.MAV_RESULT_ACCEPTED
    text = gcs.recv("STATUSTEXT", condition=lambda m: m.text.startswith("PreArm:"))
    assert text.text == "PreArm: Need Position Estimate" and text.severity == mavlink.MAV_SEVERITY_CRITICAL
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_FAILED
    assert gcs.recv("STATUSTEXT", condition=lambda m: m.text.startswith("PreArm:")) is not None
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED_NOGPS).result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.command(mavlink.MAV_CMD_RUN_PREARM_CHECKS).result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
