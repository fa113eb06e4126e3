"""The single-frame parse shortcut of ``MavlinkVehicle.handle_datagram`` behaves exactly like pymavlink's own
parser: two vehicles get the same datagrams (valid, signed, MAVLink 1, corrupted, truncated, concatenated,
garbage); one takes the shortcut, the other is forced through ``MAVLink.parse_char``. Counters, parser
statistics, the copter's response and every byte sent back must be identical. In-process, no sockets."""

from __future__ import annotations

import random

# the MAVLink 2 dialect itself, as the sim imports it: pymavlink's process-wide mavutil.mavlink is whichever dialect
# the first importer chose (MAVLink 1 when another test module imported pymavlink first without MAVLINK20), and
# MAVLink 1 frames never take the shortcut (seen: taken 0 with tests/autopilots left out of the run)
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavastsm_sim.copter import SimulatedCopter
from mavastsm_sim.mavlink_vehicle import MavlinkVehicle

KEY = bytes(range(32))


def _peer(signing: bool = False) -> mavlink.MAVLink:
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    if signing:
        mav.signing.secret_key = KEY
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = 10**13
    return mav


def _valid_frames(mav: mavlink.MAVLink, mavlink1: bool = False) -> list[bytes]:
    msgs = [
        mav.heartbeat_encode(6, 8, 0, 0, 4),
        mav.command_long_encode(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0),
        mav.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0),
        mav.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 30, 2500, 0, 0, 0, 0, 0),
        mav.set_attitude_target_encode(0, 1, 1, 0x80, [1.0, 0.0, 0.0, 0.0], 0.1, -0.2, 0.05, 0.7),
        mav.set_attitude_target_encode(0, 1, 1, 0x00, [0.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5),  # bad quaternion
        mav.set_attitude_target_encode(0, 2, 1, 0x80, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5),  # other sysid
        mav.param_request_read_encode(1, 1, b"SYSID_THISMAV", -1),
        mav.timesync_encode(0, 12345),
    ]
    return [m.pack(mav, force_mavlink1=mavlink1) for m in msgs]


def _datagrams() -> list[bytes]:
    rng = random.Random(20261122)
    plain = _valid_frames(_peer())
    signed = _valid_frames(_peer(signing=True))
    v1 = _valid_frames(_peer(), mavlink1=True)
    out = list(plain) + list(v1)
    for frame in plain + signed:  # one random byte changed: bad CRC, bad length, bad flags, other ids...
        for _ in range(12):
            data = bytearray(frame)
            data[rng.randrange(len(data))] = rng.randrange(256)
            out.append(bytes(data))
    out += [plain[4][:-3], plain[4][:5], plain[0] + plain[4], plain[4] + b"\x00\x01", b"\x55" + plain[4], b""]
    out += list(signed) + [signed[4], signed[4][:-1]]  # a replayed signed frame, a short signature
    rng.shuffle(out)
    return out


def _vehicle(shortcut: bool, sent: list[bytes]) -> MavlinkVehicle:
    vehicle = MavlinkVehicle(SimulatedCopter(), sent.append, unix_time_at_boot_s=1.7e9)
    if not shortcut:
        vehicle.inbound._is_single_v2_frame = lambda data: False  # force pymavlink's byte-wise parser
    return vehicle


def _state(vehicle: MavlinkVehicle) -> tuple:
    mav = vehicle.mav
    c = vehicle.copter
    return (dict(vehicle.counters), vehicle.attitude_targets_received, mav.total_packets_received,
            mav.total_receive_errors, mav.total_bytes_received, mav.buf_len(), c.mode_number, c.armed,
            tuple(c.attitude_target[1].tolist()), c.rejected_attitude_targets)


def test_single_frame_shortcut_matches_pymavlink_parser_on_valid_and_bad_input() -> None:
    datagrams = _datagrams()
    sent_fast: list[bytes] = []
    sent_ref: list[bytes] = []
    fast, ref = _vehicle(True, sent_fast), _vehicle(False, sent_ref)
    taken = 0
    for phase in ("unsigned", "signed"):
        if phase == "signed":
            for v in (fast, ref):
                v.signing.enable(KEY, initial_timestamp=10**14)  # fixed timestamps: identical signed output
        for k, data in enumerate(datagrams):
            now_us = (k + 1) * 2500
            taken += fast.inbound._is_single_v2_frame(data)
            fast.handle_datagram(data, now_us)
            ref.handle_datagram(data, now_us)
            fast.emit_due(now_us)
            ref.emit_due(now_us)
            assert _state(fast) == _state(ref), f"{phase} datagram #{k}: {data.hex()}"
    assert sent_fast == sent_ref
    assert taken > 100  # the shortcut was exercised, not bypassed
    counters = fast.counters
    for name in ("crc_errors", "garbage_bytes", "truncated_frames", "unsigned_rejected", "bad_signature",
                 "wrong_target"):
        assert counters[name] > 0, name  # the bad-input classes were exercised
    assert fast.attitude_targets_received > 0
