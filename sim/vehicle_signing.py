"""MAVLink 2 signing of the simulated ArduCopter (key from a file or SETUP_SIGNING), as ArduPilot signs.

Unsigned or badly signed frames are dropped and counted (by pymavlink's checks and ``mavastsm.signing``, in the
parse); here: turning signing on and off, our outgoing timestamp and its keeping across runs (docs/security.md).
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

from mavastsm import signing
from mavastsm.errors import ConfigError

from .vehicle_link import VehicleLink

log = logging.getLogger("mavastsm_sim")


class SigningSession:
    """The vehicle's signing key and timestamp, on its ``MAVLink`` object.

    Parameters
    ----------
    link : VehicleLink
        The ``MAVLink`` object whose signing state this is, and the counters.
    state_path : path or None
        File that keeps our signing timestamp across runs (saved every 30 s and at the end; the next run starts
        60 s past it), as ArduPilot keeps it in its storage. None: the timestamp starts at the clock.
    """

    def __init__(self, link: VehicleLink, state_path: str | Path | None) -> None:
        self.link = link
        self.mav = link.mav
        self.counters = link.counters
        self.state_path = None if state_path is None else Path(state_path)
        self._saved_at = -math.inf

    @property
    def enabled(self) -> bool:
        """True when inbound frames must carry a valid MAVLink 2 signature."""
        return self.mav.signing.secret_key is not None

    def enable(self, key: bytes, initial_timestamp: int | None = None) -> None:
        """Require and produce MAVLink 2 signatures with ``key`` [32 bytes].

        Our timestamp starts as ArduPilot's does (GCS_Signing.cpp, load_signing_key): 60 s past the given
        ``initial_timestamp`` (SETUP_SIGNING) or past the one saved in ``state_path`` by the last run, and never
        behind the clock. The 60 s lead refuses, as a stream more than 60 s old, every frame signed before the
        last save: a replay across a restart. Without a saved timestamp only the clock bounds it (docs/security.md)."""
        if len(key) != 32:
            raise ValueError(f"signing key must be 32 bytes, got {len(key)}")
        s = self.mav.signing
        s.secret_key = bytes(key)
        s.sign_outgoing = True
        s.allow_unsigned_callback = None  # like ArduPilot on a network link (not its channel 0): nothing unsigned gets in
        s.link_id = 0
        base = max(initial_timestamp or 0, self._saved_timestamp() or 0)
        s.timestamp = max(s.timestamp, base + signing.RESTART_TIMESTAMP_LEAD if base else 0, signing.timestamp_now())
        signing.harden(self.mav)
        self.save_timestamp(force=True)

    def _saved_timestamp(self) -> int | None:
        path = self.state_path
        if path is None or not path.exists():
            return None
        text = path.read_text(encoding="ascii", errors="replace").strip()
        if not text.isdigit():
            raise ConfigError(f"signing state {path}: {text[:40]!r} is not a signing timestamp (decimal, 10 us since 2015)")
        return int(text)

    def save_timestamp(self, force: bool = False) -> None:
        """Write our signing timestamp to ``state_path`` every TIMESTAMP_SAVE_PERIOD_S of wall time (now when
        ``force``), as ArduPilot does; nothing without signing or a state file. Never raises (counted)."""
        path = self.state_path
        if path is None or self.mav.signing.secret_key is None:
            return
        now = time.monotonic()
        if not force and now - self._saved_at < signing.TIMESTAMP_SAVE_PERIOD_S:
            return
        self._saved_at = now
        try:
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(f"{self.mav.signing.timestamp}\n", encoding="ascii")
            tmp.replace(path)
        except OSError as exc:
            self.counters["signing_state_errors"] += 1
            log.warning("cannot save the signing timestamp to %s: %s", path, exc)

    def disable(self) -> None:
        """Stop signing and accept unsigned frames again."""
        s = self.mav.signing
        s.secret_key = None
        s.sign_outgoing = False
        s.allow_unsigned_callback = None

    def on_setup_signing(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        key = bytes(msg.secret_key)
        if not any(key) and msg.initial_timestamp == 0:
            self.disable()
            self.counters["signing_disabled"] += 1
        else:
            self.enable(key, int(msg.initial_timestamp))
            self.counters["signing_setups"] += 1
