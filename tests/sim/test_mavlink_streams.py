"""Checklist F5 (docs/design-decisions.md, MAV-4): stream control and achieved rates measured from ``time_boot_ms``."""

from __future__ import annotations

from mavlink_peer_tools import ATTITUDE_ID, fly, mavlink

from mavastsm_sim.copter import SimulatedCopter
from mavastsm_sim.mavlink_vehicle import MavlinkVehicle


def answer_each_attitude(att):
    """Lockstep answer that changes nothing (the copter is disarmed / not in GUIDED)."""
    return 0x80, [1.0, 0.0, 0.0, 0.0], (0.0, 0.0, 0.0), 0.5


def achieved_rate_hz(gcs, duration_s: float, msg_type: str = "ATTITUDE") -> float:
    """Rate of ``msg_type`` over ``duration_s`` of simulated time, from its time_boot_ms stamps [Hz]."""
    msgs = [m for m in fly(gcs, duration_s, answer_each_attitude, extra_types=(msg_type,)) if m.get_type() == msg_type]
    times = [m.time_boot_ms for m in msgs]
    return (len(times) - 1) / ((times[-1] - times[0]) / 1000.0)


def test_attitude_200hz_requested_is_achieved_within_5_percent(server_and_gcs):
    server, gcs = server_and_gcs
    ack = gcs.set_interval(ATTITUDE_ID, 200)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    rate = achieved_rate_hz(gcs, 2.0)
    assert abs(rate - 200.0) <= 0.05 * 200.0, rate


def test_rate_above_the_loop_rate_cap_is_capped_at_80_percent_of_sched_loop_rate(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.set_interval(ATTITUDE_ID, 1000)
    rate = achieved_rate_hz(gcs, 1.0)
    assert abs(rate - 320.0) <= 0.05 * 320.0, rate  # SCHED_LOOP_RATE 400 -> 320 Hz
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, ATTITUDE_ID, 0, 0, 0, 0, 0, 0)
    reply = gcs.recv("MESSAGE_INTERVAL", condition=lambda m: m.message_id == ATTITUDE_ID)
    assert reply.interval_us == 3125


def test_raising_sched_loop_rate_allows_1khz_attitude(make_server, make_gcs):
    server = make_server(sched_loop_rate_hz=1250)
    gcs = make_gcs(server.port)
    gcs.hello()
    gcs.set_interval(ATTITUDE_ID, 1000)
    rate = achieved_rate_hz(gcs, 0.5)
    assert abs(rate - 1000.0) <= 0.05 * 1000.0, rate


def test_sched_loop_rate_parameter_set_over_mavlink_moves_the_cap(server_and_gcs):
    server, gcs = server_and_gcs
    echo = gcs.set_param("SCHED_LOOP_RATE", 500)
    assert echo.param_value == 500
    gcs.set_interval(ATTITUDE_ID, 1000)
    rate = achieved_rate_hz(gcs, 1.0)
    assert abs(rate - 400.0) <= 0.05 * 400.0, rate


def test_request_data_stream_groups(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.mav.request_data_stream_send(1, 1, mavlink.MAV_DATA_STREAM_EXTRA1, 25, 1)
    gcs.mav.request_data_stream_send(1, 1, mavlink.MAV_DATA_STREAM_POSITION, 5, 1)
    got = fly(gcs, 2.0, answer_each_attitude, extra_types=("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "VFR_HUD"))
    kinds = [m.get_type() for m in got]
    att = [m.time_boot_ms for m in got if m.get_type() == "ATTITUDE"]
    assert abs((len(att) - 1) / ((att[-1] - att[0]) / 1000.0) - 25.0) < 1.0
    assert 8 <= kinds.count("GLOBAL_POSITION_INT") <= 12 and 8 <= kinds.count("LOCAL_POSITION_NED") <= 12
    assert "VFR_HUD" not in kinds  # EXTRA2 was not requested
    gcs.mav.request_data_stream_send(1, 1, mavlink.MAV_DATA_STREAM_ALL, 0, 0)  # stop everything
    assert server.wait_until(lambda c: not server.vehicle.attitude_streaming(), timeout_s=2.0)
    assert server.vehicle.effective_interval_us(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT) is None


def test_minus_one_stops_zero_restores_default_and_unknown_id_fails(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_VFR_HUD, 20)
    assert gcs.recv("VFR_HUD", timeout_s=2.0) is not None
    assert gcs.set_interval(mavlink.MAVLINK_MSG_ID_VFR_HUD, -1).result == mavlink.MAV_RESULT_ACCEPTED
    assert server.vehicle.effective_interval_us(mavlink.MAVLINK_MSG_ID_VFR_HUD) is None
    gcs.set_interval(mavlink.MAVLINK_MSG_ID_VFR_HUD, 20)
    assert gcs.set_interval(mavlink.MAVLINK_MSG_ID_VFR_HUD, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert server.vehicle.effective_interval_us(mavlink.MAVLINK_MSG_ID_VFR_HUD) is None  # SR0_EXTRA2 = 0
    ack = gcs.set_interval(mavlink.MAVLINK_MSG_ID_RAW_IMU, 10)  # a real id this vehicle does not produce
    assert ack.result == mavlink.MAV_RESULT_FAILED
    text = gcs.recv("STATUSTEXT", condition=lambda m: "No ap_message" in m.text)
    assert text.text == f"No ap_message for mavlink id ({mavlink.MAVLINK_MSG_ID_RAW_IMU})"
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_VFR_HUD,
                              0, 0, 0, 0, 0, 0)
    assert gcs.recv("MESSAGE_INTERVAL").interval_us == -1


def test_sr0_parameters_preseed_default_streams(make_server, make_gcs):
    server = make_server()
    assert server.call(lambda c: c.params.set("SR0_EXTRA2", 10))[0]
    gcs = make_gcs(server.port)
    gcs.hello()
    assert gcs.set_interval(mavlink.MAVLINK_MSG_ID_VFR_HUD, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert server.vehicle.effective_interval_us(mavlink.MAVLINK_MSG_ID_VFR_HUD) == 100_000


def test_last_writer_wins_between_request_data_stream_and_set_message_interval(server_and_gcs):
    """MAVProxy's periodic REQUEST_DATA_STREAM overrides SET_MESSAGE_INTERVAL (AP#17046); re-asserting wins back."""
    server, gcs = server_and_gcs
    gcs.set_interval(ATTITUDE_ID, 100)
    assert server.vehicle.effective_interval_us(ATTITUDE_ID) == 10_000
    gcs.mav.request_data_stream_send(1, 1, mavlink.MAV_DATA_STREAM_ALL, 4, 1)
    assert gcs.recv("VFR_HUD", timeout_s=3.0) is not None  # the request has been processed
    assert server.vehicle.effective_interval_us(ATTITUDE_ID) == 250_000
    gcs.set_interval(ATTITUDE_ID, 100)
    rate = achieved_rate_hz(gcs, 1.0)
    assert abs(rate - 100.0) <= 5.0, rate


def test_request_message_sends_one_copy_after_the_ack(server_and_gcs):
    server, gcs = server_and_gcs
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_HOME_POSITION,
                              0, 0, 0, 0, 0, 0)
    first = gcs.recv(["COMMAND_ACK", "HOME_POSITION"])
    assert first.get_type() == "COMMAND_ACK" and first.result == mavlink.MAV_RESULT_ACCEPTED
    assert gcs.recv("HOME_POSITION") is not None
    assert gcs.recv("HOME_POSITION", timeout_s=1.5) is None  # one copy, not a stream


def test_interval_set_at_a_grid_instant_starts_on_the_next_grid_point():
    """A request handled at a grid instant (after that instant's messages went out) must not send its first
    copy one physics tick late and off the grid: that shifted every later lockstep sample by 1 ms and made two
    identical flights differ by how long the climb lasted (test_lockstep_flight_is_repeatable)."""
    sent: list[bytes] = []
    vehicle = MavlinkVehicle(SimulatedCopter(), sent.append, unix_time_at_boot_s=1.7e9)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    request = gcs.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, ATTITUDE_ID, 20_000,
                                      0, 0, 0, 0, 0).pack(gcs)
    vehicle.emit_due(40_000)  # everything due at 40 ms has gone out
    vehicle.handle_datagram(request, 40_000)
    for now_us in range(41_000, 101_000, 1_000):  # the server's 1 kHz physics ticks
        vehicle.emit_due(now_us)
    parser = mavlink.MAVLink(None)
    stamps = [m.time_boot_ms for data in sent for m in parser.parse_buffer(data) or []
              if m.get_msgId() == ATTITUDE_ID]
    assert stamps == [60, 80, 100]
