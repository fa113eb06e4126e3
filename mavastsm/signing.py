"""MAVLink 2 signing as both ends of this project use it: one key-file format, and two repairs to pymavlink.

Key file (``--signing-key FILE`` of the bridge, the sim and MAVProxy-style setups), one format:

* exactly 32 bytes: the raw key, used as it is (no byte is stripped);
* otherwise UTF-8 text. Leading and trailing ASCII spaces, tabs, CR and LF are stripped, nothing else.
  64 hex digits are the key in hex; any other non-empty printable text is a passphrase, and the key is
  its SHA-256 (MAVProxy's ``signing setup PASSPHRASE``). Control characters, a non-breaking space and
  other non-printable characters inside the text are refused, so a raw key with a newline appended (33
  bytes) is an error, never a passphrase by accident.

pymavlink 2.4.x (checked up to 2.4.50), ``MAVLink.check_signature``, stores the frame's timestamp as its
stream's *before* it compares the signature::

    self.signing.stream_timestamps[stream_key] = timestamp      # committed first
    ...
    if sig1 != sig2: return False                                # then checked

so one forged frame with the victim stream's identity, the signed flag, a timestamp of "now" (or 2^48-1)
and a random signature makes the receiver refuse every genuine frame of that stream, no key needed.
:func:`harden` replaces the method on one ``MAVLink`` object by :func:`check_signature`, which commits
nothing (stream timestamp, new-stream entry, our own timestamp) until the signature is verified. Second,
pymavlink advances our outgoing timestamp by one unit (10 us) per signed frame, so a 400 Hz sender falls
behind the clock by almost a second per second, which is what made "now" a timestamp an attacker could
use and makes a restarted sender look like a replay; :func:`advance_timestamp`, called before each send,
keeps it at or above the clock (:func:`harden` installs both). Drop both when upstream verifies before it commits.
"""

from __future__ import annotations

import hashlib
import time
import types
from pathlib import Path

from .errors import ConfigError

SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01 00:00:00 UTC, the MAVLink 2 signing epoch
KEY_LEN = 32
NEW_STREAM_WINDOW = 6000 * 1000  # [10 us] a new stream may be at most 60 s behind our timestamp (MAVLink spec)
RESTART_TIMESTAMP_LEAD = 6000 * 1000  # [10 us] ArduPilot starts 60 s past its last saved timestamp
TIMESTAMP_SAVE_PERIOD_S = 30.0  # ArduPilot saves its signing timestamp every 30 s
_STRIPPED = " \t\r\n"


def timestamp_now() -> int:
    """MAVLink 2 signing timestamp of the current wall time [10 us since 2015-01-01 UTC]."""
    return int(max(time.time() - SIGNING_EPOCH_UNIX_S, 0.0) * 100_000)


def parse_signing_key(raw: bytes, source: str) -> bytes:
    """The 32-byte key a key file's bytes ``raw`` hold (format in the module docstring). ConfigError names
    ``source`` (the file) and the rule it broke."""
    if len(raw) == KEY_LEN:
        return bytes(raw)
    try:
        text = raw.decode("utf-8").strip(_STRIPPED)
    except UnicodeDecodeError:
        raise ConfigError(f"signing key {source}: {len(raw)} bytes that are not UTF-8 text; a raw key must be exactly "
                          f"{KEY_LEN} bytes (no newline), otherwise 64 hex digits or a passphrase") from None
    if not text:
        raise ConfigError(f"signing key {source}: empty (need {KEY_LEN} raw bytes, 64 hex digits or a passphrase)")
    if len(text) == 2 * KEY_LEN and all(c in "0123456789abcdefABCDEF" for c in text):
        return bytes.fromhex(text)
    if not text.isprintable():
        bad = next(c for c in text if not c.isprintable())
        raise ConfigError(f"signing key {source}: the passphrase contains the non-printable character U+{ord(bad):04X}; "
                          f"only leading/trailing spaces, tabs, CR and LF are stripped (a raw key must be exactly {KEY_LEN} bytes)")
    return hashlib.sha256(text.encode("utf-8")).digest()


def load_signing_key(path: str | Path) -> bytes:
    """The 32-byte key in the key file ``path``; ConfigError (one line naming the file and the rule) otherwise."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"signing key {p}: cannot read ({exc.strerror or exc})") from None
    return parse_signing_key(raw, str(p))


def signing_key_option(key: bytes | bytearray | str | Path | None) -> bytes | None:
    """The MAVLink2 signing key an option gives (bytes, or a key file for ``load_signing_key``), checked to be 32
    bytes; None to fly unsigned. ConfigError (one line) otherwise."""
    if key is not None and not isinstance(key, (bytes, bytearray)):
        key = load_signing_key(key)
    if key is not None and len(key) != 32:
        raise ConfigError(f"signing key must be 32 bytes, got {len(key)}")
    return key


def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:
    """pymavlink's ``MAVLink.check_signature`` with the signature verified before any state changes.

    Same acceptance rules (timestamp strictly newer than the stream's; a new stream at most 60 s behind our
    own timestamp), but a frame whose signature is wrong changes nothing. ``self`` is the ``MAVLink`` object.
    """
    signing = self.signing
    h = hashlib.sha256()
    h.update(signing.secret_key)
    h.update(msgbuf[:-6])
    self.signing_refusal = "bad_signature"  # why the last refused frame was refused (classify_bad_data)
    if h.digest()[:6] != bytes(msgbuf[-6:]):
        return False
    self.signing_refusal = "replayed"
    tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
    timestamp = tlow + (thigh << 32)
    stream_key = (msgbuf[-13], srcSystem, srcComponent)
    last = signing.stream_timestamps.get(stream_key)
    if last is not None:
        if timestamp <= last:
            return False  # replayed or reordered
    elif timestamp + NEW_STREAM_WINDOW < signing.timestamp:
        return False  # a "new" stream from more than a minute ago: a replay
    signing.stream_timestamps[stream_key] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True


REFUSED_FRAME_CLASSES = ("garbage_bytes", "crc_errors", "malformed_frames", "truncated_frames", "unsigned_rejected", "bad_signature",
                         "replayed")


def classify_bad_data(msg, mav) -> str:
    """Which of REFUSED_FRAME_CLASSES a pymavlink BAD_DATA ``msg`` (parsed by ``mav``) is. Signature refusals
    are split by :func:`check_signature`'s verdict: a wrong signature, or a right one on an old timestamp."""
    reason = str(getattr(msg, "reason", ""))
    if reason.startswith("Bad prefix"):
        return "garbage_bytes"
    if "CRC" in reason:
        return "crc_errors"
    if "signature" in reason.lower():
        data = bytes(getattr(msg, "data", b""))
        signed = len(data) > 2 and data[0] == 0xFD and bool(data[2] & 0x01)  # MAVLink 2, MAVLINK_IFLAG_SIGNED
        return getattr(mav, "signing_refusal", "bad_signature") if signed else "unsigned_rejected"
    return "malformed_frames"


def harden(mav) -> None:
    """Repair the pymavlink ``MAVLink`` object ``mav`` (only that object; idempotent): :func:`check_signature`
    for inbound frames, and every send (``send`` and each ``*_send`` helper, which calls it) preceded by
    :func:`advance_timestamp`."""
    if getattr(mav, "_mavastsm_hardened", False):
        return
    mav.check_signature = types.MethodType(check_signature, mav)
    unpatched_send = mav.send

    def send(mavmsg, force_mavlink1: bool = False):
        advance_timestamp(mav)
        return unpatched_send(mavmsg, force_mavlink1=force_mavlink1)

    mav.send = send
    mav._mavastsm_hardened = True


def advance_timestamp(mav) -> None:
    """Before a send: our next signing timestamp is at least the clock (pymavlink adds 1 per signed frame)."""
    signing = mav.signing
    if signing.secret_key is not None:
        signing.timestamp = max(signing.timestamp, timestamp_now())
