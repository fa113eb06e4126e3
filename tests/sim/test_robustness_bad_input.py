"""Bad input never kills the vehicle: random bytes, truncated frames, unknown ids, NaN / out-of-range fields,
commands for another system. Each class is counted (``server.counters``) and the vehicle keeps flying."""

from __future__ import annotations

import logging
import math
import random
import socket
import struct

import pytest
from mavlink_peer_tools import ATTITUDE_ID, fly, guided_and_armed, mavlink, rates_command


@pytest.fixture
def flying(server_and_gcs):
    server, gcs = server_and_gcs
    guided_and_armed(gcs)
    gcs.set_interval(ATTITUDE_ID, 50)
    fly(gcs, 1.5, rates_command(thrust=0.8))
    fly(gcs, 0.5, rates_command(thrust=0.5))
    return server, gcs


@pytest.fixture
def raw_socket(server_and_gcs):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield lambda data: sock.sendto(data, ("127.0.0.1", server_and_gcs[0].port))
    sock.close()


def still_flying(server, gcs) -> None:
    """Vehicle answers, holds altitude and attitude under valid commands, loop thread alive."""
    z0 = server.call(lambda c: c.position_ned_m[2])
    last = fly(gcs, 0.5, rates_command(thrust=0.5))[-1]
    assert server.running and server.error is None
    assert server.call(lambda c: (c.armed, c.landed, c.mode_number)) == (True, False, 4)
    assert abs(last.roll) < 0.05 and abs(last.pitch) < 0.05
    assert abs(server.call(lambda c: c.position_ned_m[2]) - z0) < 0.5
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION).result == 0


def frame(gcs, msg) -> bytes:
    return msg.pack(gcs.mav)


def test_random_bytes_are_counted_as_garbage_and_ignored(flying, raw_socket):
    server, gcs = flying
    rng = random.Random(1234)
    for _ in range(200):
        raw_socket(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
    still_flying(server, gcs)
    counters = server.counters
    assert counters["garbage_bytes"] + counters["crc_errors"] + counters["malformed_frames"] \
        + counters["truncated_frames"] + counters["unknown_message_ids"] > 100
    assert counters["internal_errors"] == 0


def test_truncated_and_corrupted_frames(flying, raw_socket):
    server, gcs = flying
    good = frame(gcs, gcs.mav.command_long_encode(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 0, 0, 0, 0, 0, 0))
    for cut in range(1, len(good)):
        raw_socket(good[:cut])
    corrupted = bytearray(good)
    corrupted[-1] ^= 0xFF
    raw_socket(bytes(corrupted))
    still_flying(server, gcs)  # the set-mode-to-STABILIZE in those pieces never took effect
    counters = server.counters
    assert counters["truncated_frames"] >= len(good) - 2 and counters["crc_errors"] >= 1


def test_unknown_message_ids_are_counted(flying, raw_socket):
    server, gcs = flying
    payload = bytes(range(20))
    for msg_id in (50000, 0xABCDE, 9999):  # ids no dialect in pymavlink defines
        assert msg_id not in mavlink.mavlink_map
        header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, 255, 190, msg_id & 0xFFFF, msg_id >> 16)
        raw_socket(header + payload + b"\x00\x00")
    still_flying(server, gcs)
    assert server.counters["unknown_message_ids"] == 3


def test_nan_and_out_of_range_fields(flying):
    server, gcs = flying
    nan, inf = math.nan, math.inf
    for rates, thrust in (((nan, 0, 0), 0.5), ((0, inf, 0), 0.5), ((0, 0, 0), nan), ((1e30, 0, 0), -inf)):
        gcs.mav.set_attitude_target_send(0, 1, 1, 0x80, [1.0, 0, 0, 0], *rates, thrust)
    gcs.mav.set_attitude_target_send(0, 1, 1, 0x00, [nan, 0, 0, 0], 0, 0, 0, 0.5)
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, nan).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, -5).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, nan).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, ATTITUDE_ID, inf).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 1e12).result == mavlink.MAV_RESULT_DENIED
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 12345).result == mavlink.MAV_RESULT_FAILED  # no such mode
    assert gcs.command(31999).result == mavlink.MAV_RESULT_UNSUPPORTED
    still_flying(server, gcs)
    counters = server.counters
    assert counters["bad_field_values"] >= 10 and counters["unsupported_commands"] == 1
    assert all(math.isfinite(v) for v in server.call(lambda c: c.body_rates_rads))


def test_commands_for_another_system_or_component_are_ignored(flying):
    server, gcs = flying
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 9, target_system=7, timeout_s=0.5) is None
    gcs.mav.command_long_send(1, 42, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0)
    gcs.mav.set_attitude_target_send(0, 9, 1, 0x80, [1.0, 0, 0, 0], 3.0, 0, 0, 0.0)
    gcs.mav.set_mode_send(3, 1, 9)
    gcs.mav.param_set_send(2, 1, b"GUID_TIMEOUT", 0.2, mavlink.MAV_PARAM_TYPE_REAL32)
    still_flying(server, gcs)
    assert server.counters["wrong_target"] == 5
    assert server.call(lambda c: c.params.get("GUID_TIMEOUT")) == 3.0


def test_mavlink1_peer_is_tolerated(server_and_gcs, make_gcs):
    server, gcs = server_and_gcs
    v1 = make_gcs(server.port)
    msg = v1.mav.command_long_encode(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
    v1.conn.write(msg.pack(v1.mav, force_mavlink1=True))
    ack = v1.recv("COMMAND_ACK", condition=lambda m: m.command == mavlink.MAV_CMD_DO_SET_MODE)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED and server.call(lambda c: c.mode_number) == 4


def test_bad_input_is_visible_in_the_verbose_log(make_server, make_gcs, caplog):
    caplog.set_level(logging.DEBUG, logger="mavastsm_sim")
    server = make_server(verbose=True)
    gcs = make_gcs(server.port)
    gcs.hello()
    gcs.conn.write(b"\x01\x02\x03 not mavlink")
    gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 4, target_system=9, timeout_s=0.3)
    assert server.wait_until(lambda c: server.counters["bad_input_total"] >= 2, timeout_s=2.0)
    text = caplog.text
    assert "class garbage_bytes" in text and "class wrong_target" in text


class NanStateCopter:
    """A plant whose state has blown up to NaN: telemetry must be skipped and counted, never crash the loop."""

    def __init__(self, copter):
        self._copter = copter

    def __getattr__(self, name):
        value = getattr(self._copter, name)
        if name in ("position_ned_m", "velocity_ned_ms", "euler_rad"):
            return value * math.nan
        return value


def test_unencodable_state_is_counted_and_the_loop_survives(make_server, make_gcs):
    from mavastsm_sim.copter import SimulatedCopter

    server = make_server(copter=NanStateCopter(SimulatedCopter()))
    gcs = make_gcs(server.port)
    gcs.hello()
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT).result == 0
    assert server.wait_until(lambda c: server.counters.get("telemetry_encode_errors", 0) >= 1, timeout_s=2.0)
    assert gcs.recv("HEARTBEAT", timeout_s=3.0) is not None and server.running


def test_random_well_formed_commands_never_hit_a_handler_bug():
    """Property check in-process (no sockets): well-framed messages with arbitrary field values, for every
    message type the vehicle handles, are answered or refused, never crash a handler (internal_errors)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from mavastsm_sim.copter import SimulatedCopter
    from mavastsm_sim.mavlink_vehicle import MavlinkVehicle

    sent: list[bytes] = []
    vehicle = MavlinkVehicle(SimulatedCopter(), sent.append)
    peer = mavlink.MAVLink(None, 255, 190)
    floats = st.floats(allow_nan=True, allow_infinity=True, width=32)
    u8, u16 = st.integers(0, 255), st.integers(0, 65535)
    target = st.sampled_from([0, 1, 2, 255])
    commands = st.sampled_from([176, 400, 401, 510, 511, 512, 519, 520, 22, 0, 65535])
    messages = st.one_of(
        st.builds(lambda t, c, cmd, *p: peer.command_long_encode(t, c, cmd, 0, *p), target, target, commands,
                  *[floats] * 7),
        st.builds(lambda t, c, cmd, p1, p2, x, y, z: peer.command_int_encode(t, c, 0, cmd, 0, 0, p1, p2, 0, 0, x,
                                                                            y, z),
                  target, target, commands, floats, floats, st.integers(-2**31, 2**31 - 1),
                  st.integers(-2**31, 2**31 - 1), floats),
        st.builds(lambda t, c, m, q0, p, q, r, th: peer.set_attitude_target_encode(0, t, c, m, [q0, 0, 0, 0], p, q,
                                                                                   r, th),
                  target, target, u8, floats, floats, floats, floats, floats),
        st.builds(lambda t, b, cm: peer.set_mode_encode(t, b, cm), target, u8, st.integers(0, 2**32 - 1)),
        st.builds(lambda t, s, r, on: peer.request_data_stream_encode(t, 1, s, r, on), target, u8, u16, u8),
        st.builds(lambda t, name, v: peer.param_set_encode(t, 1, name, v, 9), target,
                  st.sampled_from([b"GUID_TIMEOUT", b"SCHED_LOOP_RATE", b"FORMAT_VERSION", b"\xff\xfe", b""]),
                  floats),
        st.builds(lambda t, name, i: peer.param_request_read_encode(t, 1, name, i), target,
                  st.sampled_from([b"GUID_TIMEOUT", b"NOPE", b""]), st.integers(-32768, 32767)),
        st.builds(lambda t, mt: peer.mission_request_list_encode(t, 1, mt), target, u8),
        st.builds(lambda a, b: peer.timesync_encode(a, b), st.integers(-2**63, 2**63 - 1),
                  st.integers(-2**63, 2**63 - 1)),
        st.builds(lambda t, data: peer.file_transfer_protocol_encode(0, t, 1, list(data)), target,
                  st.binary(min_size=251, max_size=251)),
    )

    @settings(max_examples=150, derandomize=True, deadline=None)
    @given(st.lists(messages, min_size=1, max_size=5), st.integers(0, 10**9))
    def check(batch, now_us):
        data = b"".join(m.pack(peer) for m in batch)
        vehicle.handle_datagram(data, now_us)
        vehicle.emit_due(now_us)
        assert vehicle.counters["internal_errors"] == 0
        assert vehicle.counters["telemetry_encode_errors"] == 0

    check()
    assert sent, "the vehicle answered something"
