"""External disturbances of the simulated vehicle: body torques and wind gusts (pure functions of time).

Torque events come from the same scenario YAML as the offline simulator
(``mavastsm.scenarios.Scenario.disturbances``: steps and pulses, body FRD, N m) and/or are added in
code; wind is a steady NED wind plus "1 - cos" gusts that act through the translational drag.
Everything is evaluated with plain floats because it runs at the 1 kHz physics rate.

Times are seconds on the *disturbance clock*: simulated time minus ``origin_s``. The origin is 0
(boot) unless :meth:`DisturbanceModel.restart_clock` moves it (e.g. when an experiment starts).

Wind is simulator-only, so it lives in an optional top-level ``wind:`` section of a scenario YAML
(the offline simulator, which reads only ``scenario:``, ignores it)::

    wind:
      steady_ned_ms: [2.0, 0.0, 0.0]          # optional, default zero
      gusts:                                  # optional list of "1 - cos" gusts
        - {start_s: 3.0, duration_s: 2.0, peak_ned_ms: [3.0, 1.0, 0.0]}
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from mavastsm.config_loading import read_yaml, resolve_config
from mavastsm.errors import ConfigError
from mavastsm.scenarios import TorqueEvent  # one definition, shared with the offline simulator

PARKED_S = 1.0e9  # [s] disturbance-clock origin that keeps every scenario event in the far future (``park``)


@dataclass(frozen=True)
class Gust:
    """A "1 - cos" gust: wind adds ``peak_ned_ms`` * (1 - cos(2 pi (t - start)/duration)) / 2 for
    ``start_s <= t < start_s + duration_s``. [s], [m/s NED]."""

    start_s: float
    duration_s: float
    peak_ned_ms: tuple[float, float, float]


class DisturbanceModel:
    """Sum of torque events and wind (steady + gusts).

    Parameters
    ----------
    torque_events : TorqueEvent-like objects (anything with start_s, end_s, torque_nm)
    gusts : Gust objects
    steady_wind_ned_ms : [m/s] (3,) constant wind, NED
    origin_s : [s] simulated time at which the disturbance clock reads 0
    """

    def __init__(self, torque_events=(), gusts=(), steady_wind_ned_ms=(0.0, 0.0, 0.0), origin_s: float = 0.0):
        self.torque_events = [
            (float(e.start_s), float(e.end_s), tuple(float(v) for v in e.torque_nm)) for e in torque_events
        ]
        self.gusts = [(float(g.start_s), float(g.duration_s), tuple(float(v) for v in g.peak_ned_ms)) for g in gusts]
        self.steady_wind = tuple(float(v) for v in steady_wind_ned_ms)
        self.origin_s = float(origin_s)
        for t0, t1, tau in self.torque_events:
            if not (math.isfinite(t0) and t1 >= t0 and all(math.isfinite(v) for v in tau)):
                raise ValueError(f"bad torque event start={t0} end={t1} torque={tau}")
        for t0, dur, peak in self.gusts:
            if not (math.isfinite(t0) and dur > 0.0 and all(math.isfinite(v) for v in peak)):
                raise ValueError(f"bad gust start={t0} duration={dur} peak={peak}")

    def restart_clock(self, now_s: float) -> None:
        """Make the disturbance clock read 0 at simulated time ``now_s`` [s]."""
        self.origin_s = float(now_s)

    def park(self) -> None:
        """Hold every scenario event in the far future until ``restart_clock`` (a takeoff flown undisturbed)."""
        self.restart_clock(PARKED_S)

    def add_torque_event(self, event) -> None:
        """Add a TorqueEvent (times on the disturbance clock)."""
        self.torque_events.append((float(event.start_s), float(event.end_s), tuple(float(v) for v in event.torque_nm)))

    def add_wind(self, steady_ned_ms=(0.0, 0.0, 0.0), gusts=()) -> None:
        """Add a steady wind [m/s NED] and Gust objects to the model."""
        self.steady_wind = tuple(a + float(b) for a, b in zip(self.steady_wind, steady_ned_ms))
        for g in gusts:
            if not (math.isfinite(g.start_s) and g.duration_s > 0.0 and all(math.isfinite(v) for v in g.peak_ned_ms)):
                raise ValueError(f"bad gust {g!r}")
            self.gusts.append((float(g.start_s), float(g.duration_s), tuple(float(v) for v in g.peak_ned_ms)))

    def torque_nm(self, sim_time_s: float):
        """Disturbance torque d(t) [N m, body FRD] as a 3-tuple."""
        t = sim_time_s - self.origin_s
        dx = dy = dz = 0.0
        for t0, t1, (a, b, c) in self.torque_events:
            if t0 <= t < t1:
                dx += a
                dy += b
                dz += c
        return dx, dy, dz

    def wind_ned_ms(self, sim_time_s: float):
        """Wind velocity [m/s, NED] as a 3-tuple."""
        t = sim_time_s - self.origin_s
        wn, we, wd = self.steady_wind
        for t0, dur, (a, b, c) in self.gusts:
            if t0 <= t < t0 + dur:
                k = 0.5 * (1.0 - math.cos(2.0 * math.pi * (t - t0) / dur))
                wn += k * a
                we += k * b
                wd += k * c
        return wn, we, wd


def _vec3(path, key, raw) -> tuple[float, float, float]:
    if not (isinstance(raw, list) and len(raw) == 3) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in raw
    ):
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be 3 finite numbers [m/s, NED]")
    return (float(raw[0]), float(raw[1]), float(raw[2]))


def load_wind(scenario_name_or_path: str | Path) -> tuple[tuple[float, float, float], tuple[Gust, ...]]:
    """Read the optional ``wind:`` section of a scenario file: (steady wind [m/s NED], gusts).

    Returns zero wind and no gusts when the section is absent. Raises ConfigError (one line naming
    file, key, value and rule) on a malformed section.
    """
    path = resolve_config(scenario_name_or_path, "scenarios")
    data = read_yaml(path)
    wind = data.get("wind")
    if wind is None:
        return (0.0, 0.0, 0.0), ()
    if not isinstance(wind, dict) or set(wind) - {"steady_ned_ms", "gusts"}:
        raise ConfigError(f"{path}: key 'wind' breaks rule: mapping with optional 'steady_ned_ms' and 'gusts'")
    steady = _vec3(path, "wind.steady_ned_ms", wind.get("steady_ned_ms", [0.0, 0.0, 0.0]))
    raw_gusts = wind.get("gusts") or []
    if not isinstance(raw_gusts, list):
        raise ConfigError(f"{path}: key 'wind.gusts' breaks rule: must be a list")
    gusts = []
    for i, g in enumerate(raw_gusts):
        key = f"wind.gusts[{i}]"
        if not isinstance(g, dict) or set(g) != {"start_s", "duration_s", "peak_ned_ms"}:
            raise ConfigError(f"{path}: key '{key}' = {g!r} breaks rule: needs start_s, duration_s, peak_ned_ms")
        t0, dur = g["start_s"], g["duration_s"]
        for name, v in (("start_s", t0), ("duration_s", dur)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{path}: key '{key}.{name}' = {v!r} breaks rule: must be a finite number [s]")
        if dur <= 0:
            raise ConfigError(f"{path}: key '{key}.duration_s' = {dur!r} breaks rule: must be > 0 [s]")
        gusts.append(Gust(float(t0), float(dur), _vec3(path, f"{key}.peak_ned_ms", g["peak_ned_ms"])))
    return steady, tuple(gusts)
