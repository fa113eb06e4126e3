"""Checklist F8 / A7: MAVLink 2 signing. With a key, only frames signed with that key are acted on."""

from __future__ import annotations

import hashlib

from mavlink_peer_tools import mavlink

KEY = hashlib.sha256(b"mavastsm test key").digest()
WRONG_KEY = hashlib.sha256(b"not the key").digest()
GUIDED = 4


def signed(gcs, key: bytes, link_id: int = 1):
    gcs.conn.setup_signing(key, sign_outgoing=True, link_id=link_id)
    return gcs


def test_signed_commands_with_the_right_key_are_accepted(make_server, make_gcs):
    server = make_server(signing_key=KEY)
    gcs = signed(make_gcs(server.port), KEY)
    hb = gcs.hello()
    assert hb._signed, "the vehicle signs its own frames when signing is on"
    ack = gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED)
    assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert server.counters["bad_signature"] == 0 and server.counters["unsigned_rejected"] == 0


def test_unsigned_and_wrongly_signed_commands_are_rejected_and_counted(make_server, make_gcs):
    server = make_server(signing_key=KEY)
    good = signed(make_gcs(server.port), KEY)
    good.hello()
    unsigned = make_gcs(server.port)
    assert unsigned.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED, timeout_s=1.0) is None
    wrong = signed(make_gcs(server.port), WRONG_KEY, link_id=2)
    assert wrong.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED, timeout_s=1.0) is None
    assert server.call(lambda c: c.mode_number) != GUIDED
    counters = server.counters
    assert counters["unsigned_rejected"] >= 1 and counters["bad_signature"] >= 1
    ack = good.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED)  # the legitimate peer still gets through
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED


def test_setup_signing_message_enables_then_all_zero_key_disables(server_and_gcs, make_gcs):
    server, gcs = server_and_gcs
    gcs.mav.setup_signing_send(1, 1, list(KEY), 0)
    assert server.wait_until(lambda c: server.vehicle.signing_enabled, timeout_s=2.0)
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED, timeout_s=1.0) is None  # we are unsigned now
    signed(gcs, KEY)
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, GUIDED).result == mavlink.MAV_RESULT_ACCEPTED
    gcs.mav.setup_signing_send(1, 1, [0] * 32, 0)
    assert server.wait_until(lambda c: not server.vehicle.signing_enabled, timeout_s=2.0)
    plain = make_gcs(server.port)
    assert plain.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 0).result == mavlink.MAV_RESULT_ACCEPTED


def test_signing_key_file_forms(tmp_path):
    from mavastsm_sim.mavlink_vehicle import load_signing_key

    raw = tmp_path / "raw.key"
    raw.write_bytes(KEY)
    hexfile = tmp_path / "hex.key"
    hexfile.write_text(KEY.hex() + "\n")
    phrase = tmp_path / "phrase.key"
    phrase.write_text("mavastsm test key\n")
    assert load_signing_key(raw) == load_signing_key(hexfile) == load_signing_key(phrase) == KEY
