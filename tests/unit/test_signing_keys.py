"""One key-file format for the bridge and the sim (mavastsm.signing): same file, same key on both sides, and a
malformed file is one line naming the file and the rule on both sides (hostile issue, defect 6)."""

from __future__ import annotations

import hashlib
import os

import pytest

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.errors import ConfigError
from mavastsm.signing import load_signing_key
from mavastsm_sim.vehicle_server import VehicleServer

KEY = hashlib.sha256(b"mavastsm test key").digest()


@pytest.mark.parametrize("content,expected", [
    (KEY, KEY),                                            # 32 raw bytes, used as they are
    (KEY.hex().encode() + b"\n", KEY),                     # 64 hex digits
    (KEY.hex().upper().encode() + b"\r\n", KEY),
    (b"mavastsm test key\n", KEY),                         # a passphrase: SHA-256
    (b"  \tmavastsm test key \r\n", KEY),                  # ASCII spaces, tabs, CR, LF stripped at both ends
    ("pässwörd".encode(), hashlib.sha256("pässwörd".encode()).digest()),
    (b" " * 32, b" " * 32),                                # 32 bytes are raw even when they look like text
])
def test_key_file_forms(tmp_path, content, expected):
    path = tmp_path / "key"
    path.write_bytes(content)
    assert load_signing_key(path) == expected


@pytest.mark.parametrize("content,rule", [
    (b"", "empty"),
    (b"\n \n", "empty"),
    ("passphrase\u00a0".encode(), "U+00A0"),               # str.strip() took it in the sim, bytes.strip() kept it
    (b"passphrase\x1c", "U+001C"),
    (os.urandom(31) + b"\xff\n", "not UTF-8"),                # 32 raw bytes plus a newline: an error, never a passphrase
])
def test_malformed_key_files_are_one_line_naming_the_file_and_rule_on_both_sides(tmp_path, content, rule):
    path = tmp_path / "bad.key"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as sim_err:
        VehicleServer(clock="lockstep", listen=("127.0.0.1", 0), signing_key=path)
    with pytest.raises(ConfigError) as bridge_err:
        Bridge(BridgeOptions("udpout:127.0.0.1:9", signing_key=str(path))).start()
    for err in (sim_err, bridge_err):
        msg = str(err.value)
        assert str(path) in msg and rule in msg and "\n" not in msg, msg
    assert str(sim_err.value) == str(bridge_err.value)


def test_a_missing_key_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="nothere.key: cannot read"):
        load_signing_key(tmp_path / "nothere.key")
