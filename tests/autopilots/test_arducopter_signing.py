"""What genuine ArduCopter does with MAVLink 2 signing (docs/security.md): SETUP_SIGNING over an unsigned link
while signing is off, unsigned frames on channel 0 (serial0), and its signing timestamp across a restart. The
in-repo sim is made to do the same where it applies (tests/sim/test_mavlink_signing.py)."""

from __future__ import annotations

import hashlib
import os
import struct
import tempfile
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from mavastsm import signing  # noqa: E402
from mavastsm_sim.genuine_sitl import start_arducopter  # noqa: E402

pytestmark = pytest.mark.ardupilot
mavlink = mavutil.mavlink
KEY = hashlib.sha256(b"mavastsm genuine signing test").digest()
REQUEST_AUTOPILOT_VERSION = (mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)


def _recv(conn, types, timeout_s, cond=None):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(type=types, blocking=True, timeout=0.2)
        if msg is not None and (cond is None or cond(msg)):
            return msg
    return None


def _answered(conn) -> bool:
    """An (unsigned or signed, as ``conn`` is set up) REQUEST_MESSAGE gets its COMMAND_ACK."""
    while conn.recv_match(blocking=False) is not None:
        pass
    conn.mav.command_long_send(1, 1, *REQUEST_AUTOPILOT_VERSION)
    return _recv(conn, "COMMAND_ACK", 2.0, lambda m: m.command == mavlink.MAV_CMD_REQUEST_MESSAGE) is not None


def _stamp(buf: bytes) -> int:
    low, high = struct.unpack("<IH", bytes(buf[-12:-6]))
    return low + (high << 32)


def test_arducopter_signing_setup_channel0_and_restart(arducopter_build, record):
    with tempfile.TemporaryDirectory(prefix="mavastsm-apsign-") as work:
        sitl = start_arducopter(*arducopter_build, workdir=Path(work))
        try:
            def first_run():
                c0 = mavutil.mavlink_connection("udpin:0.0.0.0:14550", source_system=255, source_component=190)
                c1 = mavutil.mavlink_connection("udpin:127.0.0.1:14551", source_system=254, source_component=190)
                for c in (c0, c1):
                    assert _recv(c, "HEARTBEAT", 90.0) is not None, sitl.log_tail()
                    c.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                assert _answered(c0) and _answered(c1)  # signing off: unsigned frames taken everywhere
                c1.mav.setup_signing_send(1, 1, list(KEY), signing.timestamp_now())  # unsigned, on serial1
                time.sleep(1.0)
                unsigned_ch1, unsigned_ch0 = _answered(c1), _answered(c0)
                c1.setup_signing(KEY, sign_outgoing=True, link_id=5)
                signed_ch1 = _answered(c1)
                msg = c1.mav.command_long_encode(1, 1, *REQUEST_AUTOPILOT_VERSION)
                c1.mav.send(msg)
                captured = bytes(msg.get_msgbuf())
                hb = _recv(c1, "HEARTBEAT", 3.0)
                lead_s = (_stamp(hb.get_msgbuf()) - signing.timestamp_now()) / 1e5
                c0.close()
                c1.close()
                return unsigned_ch1, unsigned_ch0, signed_ch1, captured, lead_s

            unsigned_ch1, unsigned_ch0, signed_ch1, captured, lead_before_s = sitl.netns.call(first_run)
            assert not unsigned_ch1, "after an unsigned SETUP_SIGNING, serial1 still took unsigned frames"
            assert unsigned_ch0, "channel 0 (serial0) refused an unsigned frame: ArduPilot's USB exemption changed"
            assert signed_ch1
            time.sleep(signing.TIMESTAMP_SAVE_PERIOD_S + 2.0)  # past ArduPilot's timestamp save period (wall clock)
        finally:
            sitl.stop()
        again = start_arducopter(*arducopter_build, workdir=Path(work), wipe=False)
        try:
            def second_run():
                c1 = mavutil.mavlink_connection("udpin:127.0.0.1:14551", source_system=254, source_component=190)
                c1.setup_signing(KEY, sign_outgoing=True, link_id=6)
                hb = _recv(c1, "HEARTBEAT", 90.0)
                assert hb is not None, again.log_tail()
                vehicle_stamp = _stamp(hb.get_msgbuf())
                lead_s = (vehicle_stamp - signing.timestamp_now()) / 1e5
                c1.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                time.sleep(1.0)
                while c1.recv_match(blocking=False) is not None:
                    pass
                c1.write(captured)  # the signed frame recorded before the restart, byte for byte
                replay = _recv(c1, "COMMAND_ACK", 2.0, lambda m: m.command == mavlink.MAV_CMD_REQUEST_MESSAGE) is not None
                fresh = _answered(c1)
                c1.close()
                return bool(hb.get_signed()), lead_s, replay, fresh, (vehicle_stamp - _stamp(captured)) / 1e5

            signed_after, lead_after_s, replay_answered, fresh_answered, replay_behind_s = again.netns.call(second_run)
        finally:
            again.stop()
    record("arducopter signing", unsigned_setup_signing_taken_on_serial1=not unsigned_ch1, unsigned_taken_on_serial0=unsigned_ch0,
           timestamp_lead_before_restart_s=round(lead_before_s, 1), timestamp_lead_after_restart_s=round(lead_after_s, 1),
           replayed_frame_behind_vehicle_s=round(replay_behind_s, 1), replay_answered=replay_answered)
    assert signed_after, "the key did not survive the restart"
    assert lead_after_s >= 30.0, lead_after_s  # saved timestamp + 60 s, saved at most 30 s before the kill
    assert replay_behind_s > 60.0, replay_behind_s  # so it is refused as a "new stream" more than 60 s old ...
    assert not replay_answered, "a signed frame from before the restart was taken after it"  # ... and it was
    assert fresh_answered  # a genuine new stream, timestamped now, is taken
