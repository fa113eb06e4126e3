"""Checklist F6-F7 (docs/design-decisions.md, MAV-4 and MAV-6): what a GCS needs at connect, the PARAM
protocol, telemetry fields."""

from __future__ import annotations

import math

from mavlink_peer_tools import mavlink

CMAC_LAT_E7, CMAC_LON_E7 = -353632610, 1491652300


def request(gcs, msg_id: int, msg_type: str):
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, msg_id, 0, 0, 0, 0, 0, 0)
    return gcs.recv(msg_type)


def test_autopilot_version_after_ack_with_42plus_version_and_no_ftp(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 0, 1, 0, 0, 0, 0, 0, 0)
    first = gcs.recv(["COMMAND_ACK", "AUTOPILOT_VERSION"])
    assert first.get_type() == "COMMAND_ACK" and first.result == mavlink.MAV_RESULT_ACCEPTED
    version = gcs.recv("AUTOPILOT_VERSION")
    major, minor = version.flight_sw_version >> 24, (version.flight_sw_version >> 16) & 0xFF
    assert (major, minor) >= (4, 2) and version.flight_sw_version & 0xFF == 255
    caps = version.capabilities
    assert caps & mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    assert caps & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 and caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    assert caps & mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT and caps & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert not caps & mavlink.MAV_PROTOCOL_CAPABILITY_FTP
    ack = gcs.command(mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 0)
    assert ack.result == mavlink.MAV_RESULT_FAILED  # p1 must be 1
    gcs.mav.autopilot_version_request_send(1, 1)  # legacy message 183
    assert gcs.recv("AUTOPILOT_VERSION") is not None
    assert request(gcs, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION") is not None


def test_protocol_version_announces_mavlink2(server_and_gcs):
    """PROTOCOL_VERSION (300) is not in PyPI pymavlink's dialect: the peer sees an unknown message, so check the
    frame by hand: MAVLink 2, from 1/1, CRC valid with the CRC extra derived from common.xml's field list."""
    import struct

    from pymavlink.generator.mavcrc import x25crc

    server, gcs = server_and_gcs
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION, 0, 1, 0, 0, 0, 0, 0, 0)
    ack = gcs.recv("COMMAND_ACK", condition=lambda m: m.command == mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    frame = bytes(gcs.recv("UNKNOWN_300")._msgbuf)
    assert frame[0] == 0xFD and frame[5:7] == bytes([1, 1])
    payload = frame[10:10 + frame[1]] + bytes(22 - frame[1])  # MAVLink 2 trims trailing zeros
    crc = x25crc(frame[1:10 + frame[1]])
    extra = x25crc()
    extra.accumulate_str("PROTOCOL_VERSION ")
    for ftype, name, length in (("uint16_t", "version", 0), ("uint16_t", "min_version", 0),
                                ("uint16_t", "max_version", 0), ("uint8_t", "spec_version_hash", 8),
                                ("uint8_t", "library_version_hash", 8)):
        extra.accumulate_str(f"{ftype} {name} ")
        if length:
            extra.accumulate([length])
    crc.accumulate([(extra.crc & 0xFF) ^ (extra.crc >> 8)])
    assert struct.unpack("<H", frame[10 + frame[1]:12 + frame[1]])[0] == crc.crc
    assert struct.unpack("<HHH", payload[:6]) == (200, 100, 200)
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 300).result == mavlink.MAV_RESULT_ACCEPTED


def test_parameter_list_is_complete_and_index_consistent(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.mav.param_request_list_send(1, 1)
    seen = {}
    while True:
        pv = gcs.recv("PARAM_VALUE", timeout_s=3.0)
        assert pv is not None, f"PARAM_VALUE stream stopped after {len(seen)}"
        seen[pv.param_index] = pv
        if len(seen) == pv.param_count:
            break
    count = server.copter.params.count
    assert sorted(seen) == list(range(count))
    assert all(pv.param_count == count for pv in seen.values())
    names = [seen[i].param_id for i in range(count)]
    for required in ("SYSID_THISMAV", "FRAME_CLASS", "FRAME_TYPE", "GUID_OPTIONS", "GUID_TIMEOUT", "DISARM_DELAY",
                     "MOT_THST_HOVER", "ATC_ACCEL_R_MAX", "WPNAV_SPEED_UP", "SR0_EXTRA1", "SCHED_LOOP_RATE"):
        assert required in names
    by_name = {pv.param_id: pv for pv in seen.values()}
    assert by_name["GUID_TIMEOUT"].param_type == mavlink.MAV_PARAM_TYPE_REAL32
    assert by_name["SCHED_LOOP_RATE"].param_type == mavlink.MAV_PARAM_TYPE_INT16


def test_param_read_by_name_and_index_and_set_with_echo(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.mav.param_request_read_send(1, 1, b"GUID_TIMEOUT", -1)
    by_name = gcs.recv("PARAM_VALUE")
    assert by_name.param_id == "GUID_TIMEOUT" and by_name.param_value == 3.0
    gcs.mav.param_request_read_send(1, 1, b"", by_name.param_index)
    assert gcs.recv("PARAM_VALUE").param_id == "GUID_TIMEOUT"
    echo = gcs.set_param("GUID_TIMEOUT", 1.5)
    assert echo.param_value == 1.5 and echo.param_index == by_name.param_index
    assert server.call(lambda c: c.params.get("GUID_TIMEOUT")) == 1.5


def test_param_write_to_read_only_is_denied_and_old_value_echoed(server_and_gcs):
    server, gcs = server_and_gcs
    before = server.call(lambda c: c.params.get("FORMAT_VERSION"))
    echo = gcs.set_param("FORMAT_VERSION", before + 1)
    assert echo.param_value == before
    assert gcs.recv("STATUSTEXT", condition=lambda m: "denied" in m.text) is not None


def test_unknown_param_and_nan_value_are_counted_not_applied(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.mav.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, mavlink.MAV_PARAM_TYPE_REAL32)
    gcs.mav.param_set_send(1, 1, b"GUID_TIMEOUT", math.nan, mavlink.MAV_PARAM_TYPE_REAL32)
    gcs.mav.param_request_read_send(1, 1, b"GUID_TIMEOUT", -1)
    assert gcs.recv("PARAM_VALUE", condition=lambda m: m.param_id == "GUID_TIMEOUT").param_value == 3.0
    counters = server.counters
    assert counters["unknown_params"] == 1 and counters["bad_field_values"] == 1


def test_empty_mission_for_mission_fence_rally(server_and_gcs):
    server, gcs = server_and_gcs
    for mission_type in (0, 1, 2):
        gcs.mav.mission_request_list_send(1, 1, mission_type)
        count = gcs.recv("MISSION_COUNT")
        assert count.count == 0 and count.mission_type == mission_type


def test_timesync_reply_carries_simulated_time_in_ns(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, 50)
    t_ms = gcs.recv("SYSTEM_TIME").time_boot_ms
    gcs.mav.timesync_send(0, 123456789)
    reply = gcs.recv("TIMESYNC", condition=lambda m: m.ts1 == 123456789)
    assert reply.tc1 > 0 and reply.tc1 % 1000 == 0
    assert 0 <= reply.tc1 / 1e6 - t_ms < 2000  # ns of simulated time, shortly after the SYSTEM_TIME sample


def test_telemetry_fields_on_the_ground(server_and_gcs):
    server, gcs = server_and_gcs
    gps = request(gcs, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, "GPS_RAW_INT")
    assert gps.fix_type >= 3 and gps.satellites_visible >= 6
    assert abs(gps.lat - CMAC_LAT_E7) < 100 and abs(gps.lon - CMAC_LON_E7) < 100
    pos = request(gcs, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, "GLOBAL_POSITION_INT")
    assert abs(pos.relative_alt) < 100 and abs(pos.alt - 584000) < 200 and 0 <= pos.hdg < 36000
    status = request(gcs, mavlink.MAVLINK_MSG_ID_SYS_STATUS, "SYS_STATUS")
    voltage_v = server.call(lambda c: c.battery_voltage_v)
    assert abs(status.voltage_battery - voltage_v * 1000) < 50
    assert status.onboard_control_sensors_present & mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    battery = request(gcs, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS, "BATTERY_STATUS")
    assert abs(battery.voltages[0] - voltage_v * 1000) < 50 and battery.voltages[1] == 65535
    ext = request(gcs, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, "EXTENDED_SYS_STATE")
    assert ext.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
    home = request(gcs, mavlink.MAVLINK_MSG_ID_HOME_POSITION, "HOME_POSITION")
    assert (home.latitude, home.longitude) == (CMAC_LAT_E7, CMAC_LON_E7)
    local = request(gcs, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, "LOCAL_POSITION_NED")
    assert abs(local.z) < 0.1
    hud = request(gcs, mavlink.MAVLINK_MSG_ID_VFR_HUD, "VFR_HUD")
    assert abs(hud.alt - 584.0) < 0.2 and hud.groundspeed < 0.1
    assert request(gcs, mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, "SERVO_OUTPUT_RAW") is not None
    assert request(gcs, mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, "SYSTEM_TIME").time_unix_usec > 1.4e15


def test_attitude_and_attitude_quaternion_agree(server_and_gcs):
    from mavastsm.frames import euler_from_quaternion

    server, gcs = server_and_gcs
    att = request(gcs, mavlink.MAVLINK_MSG_ID_ATTITUDE, "ATTITUDE")
    quat = request(gcs, mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, "ATTITUDE_QUATERNION")
    euler = euler_from_quaternion([quat.q1, quat.q2, quat.q3, quat.q4])
    for a, b in zip((att.roll, att.pitch, att.yaw), euler):
        assert abs(math.remainder(a - float(b), 2 * math.pi)) < 1e-3
    target = request(gcs, mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET, "ATTITUDE_TARGET")
    assert target.type_mask == 0 and abs(sum(v * v for v in target.q) - 1.0) < 1e-3


def test_vehicle_sends_its_own_timesync_request_every_10_s(make_server, make_gcs):
    server = make_server(speedup=20.0)
    gcs = make_gcs(server.port)
    gcs.hello()
    first = gcs.recv("TIMESYNC", timeout_s=5.0, condition=lambda m: m.tc1 == 0)
    second = gcs.recv("TIMESYNC", timeout_s=5.0, condition=lambda m: m.tc1 == 0)
    assert first.ts1 % 1000 == 1 and second.ts1 - first.ts1 == 10_000_000_000  # ns of simulated time + sysid
