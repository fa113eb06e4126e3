"""ArduCopter-like parameter table of the simulated vehicle (static, index-consistent).

The table is what the MAVLink PARAM protocol serves (``sim/mavlink_vehicle.py``) and what the
autopilot emulation reads: setting GUID_OPTIONS, GUID_TIMEOUT, DISARM_DELAY, ATC_*, MOT_*,
WPNAV_SPEED_UP/DN, PSC_*, LAND_SPEED really changes behaviour through the change callbacks.

Defaults are ArduCopter 4.2+ firmware defaults (the ``ARDUCOPTER_DEFAULTS`` table below, cited per
group); the vehicle YAML's ``autopilot:`` section then overrides the Solo-specific ones
(Solo_AC35.param). Like ArduPilot, ``set`` stores any finite value of the right type (documented
ranges are not enforced: consumers clamp, e.g. GUID_TIMEOUT is used as max(GUID_TIMEOUT, 0.1)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

from mavastsm.config_loading import load_section, resolve_config
from mavastsm.errors import ConfigError
from mavastsm.solo_model import DEFAULT_VEHICLE_CONFIG

# MAV_PARAM_TYPE values (common.xml)
MAV_PARAM_TYPE_UINT8 = 1
MAV_PARAM_TYPE_INT8 = 2
MAV_PARAM_TYPE_INT16 = 4
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9

_INT_RANGES = {
    MAV_PARAM_TYPE_UINT8: (0, 255),
    MAV_PARAM_TYPE_INT8: (-128, 127),
    MAV_PARAM_TYPE_INT16: (-32768, 32767),
    MAV_PARAM_TYPE_INT32: (-(2**31), 2**31 - 1),
}

_F, _I8, _I16, _I32 = MAV_PARAM_TYPE_REAL32, MAV_PARAM_TYPE_INT8, MAV_PARAM_TYPE_INT16, MAV_PARAM_TYPE_INT32

# (name, default, MAV_PARAM_TYPE, read_only). ArduCopter 4.2+ defaults: AC_AttitudeControl(_Multi),
# AC_PosControl, AC_WPNav, AP_MotorsMulticopter, ArduCopter/Parameters.cpp, GCS_MAVLink stream rates.
ARDUCOPTER_DEFAULTS: tuple[tuple[str, float, int, bool], ...] = (
    ("ANGLE_MAX", 3000.0, _I16, False),
    ("ARMING_CHECK", 1.0, _I32, False),
    ("ATC_ACCEL_P_MAX", 110000.0, _F, False),
    ("ATC_ACCEL_R_MAX", 110000.0, _F, False),
    ("ATC_ACCEL_Y_MAX", 27000.0, _F, False),
    ("ATC_ANG_PIT_P", 4.5, _F, False),
    ("ATC_ANG_RLL_P", 4.5, _F, False),
    ("ATC_ANG_YAW_P", 4.5, _F, False),
    ("ATC_INPUT_TC", 0.15, _F, False),
    ("ATC_RATE_FF_ENAB", 1.0, _I8, False),
    ("ATC_RAT_PIT_D", 0.0036, _F, False),
    ("ATC_RAT_PIT_FF", 0.0, _F, False),
    ("ATC_RAT_PIT_FLTD", 20.0, _F, False),
    ("ATC_RAT_PIT_I", 0.135, _F, False),
    ("ATC_RAT_PIT_IMAX", 0.5, _F, False),
    ("ATC_RAT_PIT_P", 0.135, _F, False),
    ("ATC_RAT_RLL_D", 0.0036, _F, False),
    ("ATC_RAT_RLL_FF", 0.0, _F, False),
    ("ATC_RAT_RLL_FLTD", 20.0, _F, False),
    ("ATC_RAT_RLL_I", 0.135, _F, False),
    ("ATC_RAT_RLL_IMAX", 0.5, _F, False),
    ("ATC_RAT_RLL_P", 0.135, _F, False),
    ("ATC_RAT_YAW_D", 0.0, _F, False),
    ("ATC_RAT_YAW_FF", 0.0, _F, False),
    ("ATC_RAT_YAW_FLTE", 2.5, _F, False),
    ("ATC_RAT_YAW_I", 0.018, _F, False),
    ("ATC_RAT_YAW_IMAX", 0.5, _F, False),
    ("ATC_RAT_YAW_P", 0.18, _F, False),
    ("ATC_THR_MIX_MAX", 0.5, _F, False),
    ("BATT_CAPACITY", 3300.0, _I32, False),
    ("BATT_MONITOR", 4.0, _I8, False),
    ("DISARM_DELAY", 10.0, _I8, False),
    ("FORMAT_VERSION", 120.0, _I16, True),
    ("FRAME_CLASS", 1.0, _I8, False),
    ("FRAME_TYPE", 1.0, _I8, False),
    ("GUID_OPTIONS", 0.0, _I32, False),
    ("GUID_TIMEOUT", 3.0, _F, False),
    ("LAND_SPEED", 50.0, _I16, False),
    ("MOT_SPIN_ARM", 0.1, _F, False),
    ("MOT_SPIN_MAX", 0.95, _F, False),
    ("MOT_SPIN_MIN", 0.15, _F, False),
    ("MOT_THST_EXPO", 0.65, _F, False),
    ("MOT_THST_HOVER", 0.35, _F, False),
    ("MOT_YAW_HEADROOM", 200.0, _I16, False),
    ("PILOT_ACCEL_Z", 250.0, _I16, False),
    ("PSC_ACCZ_I", 1.0, _F, False),
    ("PSC_ACCZ_IMAX", 800.0, _F, False),
    ("PSC_ACCZ_P", 0.5, _F, False),
    ("PSC_POSXY_P", 1.0, _F, False),
    ("PSC_POSZ_P", 1.0, _F, False),
    ("PSC_VELXY_P", 2.0, _F, False),
    ("PSC_VELZ_P", 5.0, _F, False),
    ("SCHED_LOOP_RATE", 400.0, _I16, False),  # set at start-up from the sim profile's sched_loop_rate_hz
    ("SR0_ADSB", 0.0, _I16, False),
    ("SR0_EXTRA1", 0.0, _I16, False),
    ("SR0_EXTRA2", 0.0, _I16, False),
    ("SR0_EXTRA3", 0.0, _I16, False),
    ("SR0_EXT_STAT", 0.0, _I16, False),
    ("SR0_PARAMS", 0.0, _I16, False),
    ("SR0_POSITION", 0.0, _I16, False),
    ("SR0_RAW_CTRL", 0.0, _I16, False),
    ("SR0_RAW_SENS", 0.0, _I16, False),
    ("SR0_RC_CHAN", 0.0, _I16, False),
    ("STAT_FLTTIME", 0.0, _I32, False),  # [s] statistics ArduPilot saves every 30 s (the sim's MAVLink side keeps them)
    ("STAT_RUNTIME", 0.0, _I32, False),
    ("SYSID_MYGCS", 255.0, _I16, False),
    ("SYSID_THISMAV", 1.0, _I16, False),
    ("WPNAV_SPEED", 1000.0, _F, False),
    ("WPNAV_SPEED_DN", 150.0, _F, False),
    ("WPNAV_SPEED_UP", 250.0, _F, False),
)


# Attitude controller of genuine ArduCopter 4.7 SITL's default quad (``arducopter --model quad --defaults
# copter.parm``), read back with PARAM_REQUEST_LIST (docs/sim.md, "Wire parity"). Only what tunes the controller:
# the frame, motor and battery parameters describe an airframe, and the airframe stays the Solo's.
SITL_QUAD_CONTROLLER = {
    "ANGLE_MAX": 3000.0,
    "ATC_ACCEL_P_MAX": 110000.0, "ATC_ACCEL_R_MAX": 110000.0, "ATC_ACCEL_Y_MAX": 27000.0,
    "ATC_ANG_PIT_P": 4.5, "ATC_ANG_RLL_P": 4.5, "ATC_ANG_YAW_P": 4.5,
    "ATC_INPUT_TC": 0.15, "ATC_RATE_FF_ENAB": 1.0, "ATC_THR_MIX_MAX": 0.5,
    "ATC_RAT_RLL_P": 0.135, "ATC_RAT_RLL_I": 0.135, "ATC_RAT_RLL_D": 0.0036, "ATC_RAT_RLL_FF": 0.0,
    "ATC_RAT_RLL_IMAX": 0.5, "ATC_RAT_RLL_FLTD": 20.0,
    "ATC_RAT_PIT_P": 0.135, "ATC_RAT_PIT_I": 0.135, "ATC_RAT_PIT_D": 0.0036, "ATC_RAT_PIT_FF": 0.0,
    "ATC_RAT_PIT_IMAX": 0.5, "ATC_RAT_PIT_FLTD": 20.0,
    "ATC_RAT_YAW_P": 0.3, "ATC_RAT_YAW_I": 0.02, "ATC_RAT_YAW_D": 0.0, "ATC_RAT_YAW_FF": 0.0,
    "ATC_RAT_YAW_IMAX": 0.5, "ATC_RAT_YAW_FLTE": 2.5,
}


# Tunings a sim profile's ``parameter_set`` names: parameter -> value put on the table (sim/arducopter_profile.py)
PARAMETER_SETS: dict[str, dict[str, float]] = {
    "solo": {},  # ArduCopter defaults + the Solo_AC35 values of the vehicle YAML, as the table is built
    "sitl-quad": SITL_QUAD_CONTROLLER,
}


def apply_parameter_set(table: "ParameterTable", name: str) -> None:
    """Tune ``table`` as parameter set ``name`` (a key of PARAMETER_SETS, checked by the profile that names it), so the
    sim can be compared with genuine SITL gain for gain. ConfigError if the table refuses a value."""
    for param, value in PARAMETER_SETS[name].items():
        ok, reason = table.set(param, value)
        if not ok:
            raise ConfigError(f"parameter set {name}: {reason}")


@dataclass
class ParameterEntry:
    """One row of the table. ``value`` is the native value cast to float (PARAM_VALUE semantics)."""

    name: str
    value: float
    param_type: int
    read_only: bool = False


ChangeCallback = Callable[[str, float], None]


@lru_cache(maxsize=16)
def _autopilot_section(path_str: str, mtime_ns: int) -> tuple[tuple[str, float], ...]:
    """(name, value) pairs of a vehicle file's ``autopilot:`` section, parsed once per file version."""
    section = load_section(path_str, "autopilot")
    out = []
    for key, p in section.items():
        if not isinstance(p.value, float):
            raise ConfigError(f"{path_str}: key 'autopilot.{key}' = {p.value!r} breaks rule: must be a single number")
        out.append((key.split(".", 1)[-1], p.value))
    return tuple(out)


class ParameterTable:
    """Ordered, index-consistent parameter table with change callbacks.

    Parameters
    ----------
    entries : (name, default, MAV_PARAM_TYPE, read_only) rows; names <= 16 characters, unique
    overrides : name -> value applied on top of the defaults (e.g. the vehicle YAML's ``autopilot:``)
    """

    def __init__(self, entries=ARDUCOPTER_DEFAULTS, overrides: dict[str, float] | None = None):
        self._entries: list[ParameterEntry] = []
        self._index: dict[str, int] = {}
        for name, value, ptype, ro in entries:
            if len(name) > 16:
                raise ValueError(f"parameter name {name!r} is longer than 16 characters")
            if name in self._index:
                raise ValueError(f"duplicate parameter {name!r}")
            self._index[name] = len(self._entries)
            self._entries.append(ParameterEntry(name, float(value), int(ptype), bool(ro)))
        for name, value in (overrides or {}).items():
            if name not in self._index:
                raise ValueError(f"override names unknown parameter {name!r}")
            self._entries[self._index[name]].value = self._coerce(self._entries[self._index[name]], float(value))
        self._callbacks: list[ChangeCallback] = []

    @classmethod
    def from_vehicle_config(cls, name_or_path: str | Path | None = None) -> "ParameterTable":
        """ArduCopter defaults overridden by the vehicle YAML's ``autopilot:`` section (ConfigError on bad file)."""
        path = resolve_config(name_or_path or DEFAULT_VEHICLE_CONFIG, "vehicle")
        table = cls()
        for name, value in _autopilot_section(str(path), path.stat().st_mtime_ns):
            if name not in table._index:
                raise ConfigError(f"{path}: key 'autopilot.{name}' names no simulated ArduCopter parameter")
            entry = table._entries[table._index[name]]
            entry.value = table._coerce(entry, value)
        return table

    # --- reading ---------------------------------------------------------------------------
    @property
    def count(self) -> int:
        """Number of parameters (PARAM_VALUE.param_count)."""
        return len(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def get(self, name: str) -> float:
        """Value of ``name`` (KeyError if unknown)."""
        return self._entries[self._index[name]].value

    def entry(self, name: str) -> ParameterEntry | None:
        """The entry called ``name`` or None."""
        i = self._index.get(name)
        return None if i is None else self._entries[i]

    def index_of(self, name: str) -> int:
        """Index of ``name`` or -1 if unknown."""
        return self._index.get(name, -1)

    def by_index(self, i: int) -> ParameterEntry | None:
        """Entry at index ``i`` (0..count-1) or None when out of range."""
        return self._entries[i] if 0 <= i < len(self._entries) else None

    def entries(self) -> list[ParameterEntry]:
        """All entries in index order (a copy of the list; entries are live)."""
        return list(self._entries)

    # --- writing ---------------------------------------------------------------------------
    @staticmethod
    def _coerce(entry: ParameterEntry, value: float) -> float:
        lim = _INT_RANGES.get(entry.param_type)
        if lim is None:
            return float(value)
        return float(min(max(int(round(value)), lim[0]), lim[1]))

    def set(self, name: str, value: float) -> tuple[bool, str]:
        """Set ``name`` to ``value``. Returns (ok, reason); callbacks run only on success.

        Refused: unknown name, NaN/inf, read-only entries ("Param write denied", as ArduPilot says).
        Integer types are rounded and clamped to their type's range, as the MAVLink cast does.
        """
        i = self._index.get(name)
        if i is None:
            return False, f"unknown parameter {name!r}"
        try:
            v = float(value)
        except (TypeError, ValueError):
            return False, f"{name}: value {value!r} is not a number"
        if not math.isfinite(v):
            return False, f"{name}: value {value!r} is not finite"
        entry = self._entries[i]
        if entry.read_only:
            return False, f"Param write denied ({name})"
        entry.value = self._coerce(entry, v)
        for cb in list(self._callbacks):
            cb(name, entry.value)
        return True, "ok"

    def on_change(self, callback: ChangeCallback) -> None:
        """Register ``callback(name, new_value)`` run after every successful ``set``."""
        self._callbacks.append(callback)
