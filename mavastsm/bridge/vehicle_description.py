"""``--save-vehicle FILE``: the vehicle description a flight flew, written for ``--vehicle FILE`` (issue 27).

What is written is what the flight plan decided (``flight_plan.plan_flight``): the flown description's rigid body, its
``offboard_loop`` with the values the loop flew (a yaw tau_z derived from the heading loop included), and in
``autopilot_tuning`` the autopilot parameters those numbers were chosen at, as the vehicle reported them at
preflight. A later ``--vehicle FILE`` flies the same numbers without deriving them again, and its preflight says when
the vehicle's tuning no longer is the one in the file (``flight_plan.tuning_drift``).
"""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path
from typing import Callable

import yaml

from ..config_loading import packaged_config_dir, read_config, resolve_config
from ..errors import ConfigError
from ..solo_model import OFFBOARD_LOOP_KEYS, OFFBOARD_LOOP_SCALARS


def saved_description(flown: str | Path, mapping, tuning: dict[str, float], outcome: str) -> dict:
    """The description to write: ``flown``'s sections, its offboard_loop set to ``mapping``'s values (MappingConfig)
    and its autopilot_tuning replaced by ``tuning`` (parameter name -> value in the autopilot's units)."""
    data = read_config(resolve_config(flown, "vehicle"))
    loop = dict(data.get("offboard_loop") or {})
    bridge_specs = read_config(packaged_config_dir() / "bridge.yaml")["mapping"]  # unit, range, choices of each key
    for key in OFFBOARD_LOOP_KEYS:
        value = getattr(mapping, key)
        value = value if isinstance(value, str) else float(value) if key in OFFBOARD_LOOP_SCALARS else [float(x) for x in value]
        spec = dict(loop.get(key) or {k: v for k, v in bridge_specs[key].items() if k != "doc"})
        spec["value"] = value
        loop[key] = spec
    data["offboard_loop"] = loop
    data["autopilot_tuning"] = {name: {"value": float(v), "unit": "autopilot units", "doc": "as the vehicle reported it at preflight"}
                                for name, v in sorted(tuning.items())}
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    data["description"] = (f"Saved by mavastsm --save-vehicle on {stamp}: the loop numbers a flight flew ({outcome}), starting "
                           f"from the description {Path(str(flown)).stem}, and the autopilot tuning they were chosen at. "
                           "Fly it with --vehicle FILE; the preflight says when the vehicle's tuning differs.")
    return data


def write_vehicle_description(path: str | Path, data: dict) -> Path:
    """Write ``data`` as YAML to ``path`` (ConfigError, one line, when it cannot be written)."""
    path = Path(path)
    try:
        path.write_text(yaml.safe_dump(data, sort_keys=False, width=110), encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"--save-vehicle {path}: cannot write ({exc.strerror})") from None
    return path


def save_flown_description(target: str | Path, summary, flown: str | Path, mapping, tau_s, tuning: dict[str, float],
                           say: Callable[[str], None]) -> None:
    """``--save-vehicle TARGET`` at the end of a flight: the description it flew (``mapping`` with the rate-loop
    ``tau_s`` [s] as flown, identified or not), unless a failsafe ended it (what it flew is then no description to
    keep). Says what it did; a file that cannot be written is said, never raised."""
    if summary is None:
        return
    if summary.failsafe is not None:
        say(f"--save-vehicle: {target} not written: the flight ended in {summary.failsafe.name}")
        return
    try:
        flown_mapping = dataclasses.replace(mapping, rate_time_constant_s=tuple(tau_s))
        path = write_vehicle_description(Path(target).expanduser(), saved_description(flown, flown_mapping, tuning, summary.end_reason))
    except ConfigError as exc:
        say(str(exc))
        return
    say(f"vehicle description saved: {path} (fly it with --vehicle {path})")
