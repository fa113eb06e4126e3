"""Which ArduCopter the sim emulates: an autopilot profile (``configs/sim_profiles/*.yaml``), every habit in one record.

A profile file holds every habit of one ArduCopter version as measured (the version it claims, its stream timing,
its parameter protocol, its start-up, its take-off, the SITL rig's command latency, the motors' density
compensation, its tuning, loop rate and position estimate), each with unit, range or choices, doc and source.
``arducopter-4.5-quick`` (the default) defines every habit; the others are deltas of it (``extends:``, read by
``mavastsm.config_loading`` like the controller presets). The emulator (``ArduCopterEmulator``), the copter and the
MAVLink face (``MavlinkVehicle``) read the one :class:`ArduCopterProfile` they are built with.

``mavastsm sim --profile NAME|FILE [--set KEY=VALUE ...]``; the Python API: ``load_profile(name, overrides)``.
Docs: docs/sim.md, "Sim profiles".
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

from mavastsm.config_loading import build_dataclass, packaged_config_dir, read_yaml, resolve_config
from mavastsm.errors import ConfigError

from .parameters import PARAMETER_SETS

PROFILES_FOLDER = "sim_profiles"  # under the packaged configs
DEFAULT_PROFILE = "arducopter-4.5-quick"  # docs/sim.md, "Sim profiles": why it is the default
SECTION = "habits"
# FIRMWARE_VERSION_TYPE (common.xml): the low byte of AUTOPILOT_VERSION.flight_sw_version
RELEASE_TYPES = {"dev": 0, "alpha": 64, "beta": 128, "rc": 192, "official": 255}
DENIES_FAST_INTERVALS_FROM = (4, 6)  # ArduCopter >= 4.6 refuses an interval its loop cannot keep (DENIED + text)


@dataclass(frozen=True)
class FirmwareVersion:
    """The ArduCopter version the sim claims to be: it fills AUTOPILOT_VERSION and the banner, and it decides the
    SET_MESSAGE_INTERVAL rule (>= 4.6 denies what the loop cannot keep; older versions cap it silently), because a
    bridge must cope with whichever its user flies."""

    major: int
    minor: int
    patch: int
    release: str = "official"   # a key of RELEASE_TYPES
    suffix: str = ""            # as written after the patch number, e.g. "-dev", "-beta2"

    @classmethod
    def parse(cls, text: str) -> "FirmwareVersion":
        """``4.5.7``, ``4.7.0-dev``, ``4.6.0-beta2``, ``4.6.0-rc1``; ConfigError naming the rule otherwise."""
        match = re.fullmatch(r"(\d{1,3})\.(\d{1,3})\.(\d{1,3})(-(dev|alpha|beta|rc)\d*)?", str(text).strip())
        if match is None or any(int(match.group(i)) > 255 for i in (1, 2, 3)):
            raise ConfigError(f"firmware version {text!r} must be MAJOR.MINOR.PATCH (each 0-255), optionally "
                              "followed by -dev, -alpha, -beta or -rc, e.g. 4.5.7 or 4.7.0-dev")
        return cls(int(match.group(1)), int(match.group(2)), int(match.group(3)), match.group(5) or "official",
                   match.group(4) or "")

    @property
    def text(self) -> str:
        return f"{self.major}.{self.minor}.{self.patch}{self.suffix}"

    @property
    def flight_sw_version(self) -> int:
        """AUTOPILOT_VERSION.flight_sw_version: 0xMMmmPPTT, TT the release type (0x00 dev ... 0xFF official)."""
        return (self.major << 24) | (self.minor << 16) | (self.patch << 8) | RELEASE_TYPES[self.release]

    @property
    def denies_fast_message_intervals(self) -> bool:
        return (self.major, self.minor) >= DENIES_FAST_INTERVALS_FROM


@dataclass(frozen=True)
class ArduCopterProfile:
    """The habits of one emulated ArduCopter; field names == the ``habits:`` keys of a profile file, where each is
    defined once with its unit, range or choices, meaning and measurement (``arducopter-4.5-quick.yaml``; units
    are SI as the names say). ``name`` is the profile file's stem (for the banner), not a habit.
    """

    firmware_version: str
    stream_timing: str
    param_index_65535: bool
    param_read_interval_s: float
    unsolicited_param_values: bool
    prearm_delay_s: float
    takeoff_timing: str
    command_latency_s: float
    density_compensation: bool
    parameter_set: str
    sched_loop_rate_hz: float
    position_estimate: bool
    heartbeat_autopilot: int
    name: str = ""

    def validate(self) -> list[tuple[str, str]]:
        """Cross-checks the file's specs cannot state: (key, rule) per violation (``build_dataclass`` reports them)."""
        problems = []
        try:
            FirmwareVersion.parse(self.firmware_version)
        except ConfigError as exc:
            problems.append(("firmware_version", "must " + str(exc).split(" must ", 1)[1]))
        if self.parameter_set not in PARAMETER_SETS:
            problems.append(("parameter_set", f"must be one of {', '.join(PARAMETER_SETS)}"))
        return problems

    @property
    def firmware(self) -> FirmwareVersion:
        return FirmwareVersion.parse(self.firmware_version)


def load_profile(name_or_path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> ArduCopterProfile:
    """The profile a packaged name or a file stands for (default ``DEFAULT_PROFILE``), ``overrides`` (habit ->
    value, checked against the same specs, as ``--set``) on top. ConfigError (one line) for an unknown profile, a
    bad key or value."""
    path = resolve_config(DEFAULT_PROFILE if name_or_path is None else name_or_path, PROFILES_FOLDER)
    # a text habit's value is text even where YAML would read a number (``--set firmware_version=4.7``)
    text = {f.name for f in dataclasses.fields(ArduCopterProfile) if f.type == "str"}
    changed = tuple(sorted((k, str(v) if k in text and v is not None else v) for k, v in (overrides or {}).items()))
    try:
        hash(changed)
    except TypeError:  # a list or mapping given as a value: no cache, the spec check names the key
        return _load.__wrapped__(str(path), 0, changed)
    return _load(str(path), path.stat().st_mtime_ns, changed)


@lru_cache(maxsize=32)
def _load(path: str, mtime_ns: int, changed: tuple[tuple[str, Any], ...]) -> ArduCopterProfile:
    """One profile file version with ``changed`` habits, parsed once (every SimulatedCopter built reads its profile)."""
    profile = build_dataclass(ArduCopterProfile, path, SECTION, dict(changed))
    return dataclasses.replace(profile, name=Path(path).stem)


def packaged_profiles() -> dict[str, str]:
    """Packaged profile name -> the first sentence of its description (for ``sim --help``)."""
    folder = packaged_config_dir() / PROFILES_FOLDER
    out = {}
    for path in sorted(folder.glob("*.yaml")):
        text = " ".join(str(read_yaml(path).get("description", "")).split())
        out[path.stem] = text.split(". ", 1)[0].rstrip(".")
    return out
