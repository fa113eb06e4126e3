"""A sweep as validated data: ``configs/sweeps/<name>.yaml`` or a path (see docs/sweep.md for the schema).

::

    description: free text
    sweep:
      controllers: [astsm, pid_fair]       # registry keys; ``key:preset`` picks a preset (offline level)
      scenario: nominal                    # the base scenario (reference, duration, its own disturbances)
      reference: paper_steps               # optional: fly another reference
      duration_s: 5.0                      # optional: default the scenario's
      seed: 1                              # base seed: run i uses seed + i (sensor noise, link faults, draws)
      draws: 1                             # runs per grid point (distribution variables are drawn anew each time)
      chunk_runs: 256                      # offline runs integrated as one batch (fixed: same table on any executor)
      dt_control_s: 0.001                  # offline controller period
      variables:                           # a grid, or a seeded distribution
        disturbance_roll_nm: {grid: [0.0, 0.5, 1.0, 2.0]}
        inertia_table3_scale: {grid: [0.0, 1.0, 2.0]}
        sensor_noise_scale: {uniform: [0.0, 2.0]}
        link_loss: {normal: [0.02, 0.01]}    # [mean, std], clipped into the variable's range
      map: {metric: max_abs_error_deg_roll, x: disturbance_roll_nm, y: inertia_table3_scale}
      bounds: {settling_5pct_s: [1.5, 1.5, 2.5], overshoot_pct: 10.0, steady_error_deg: 0.5}   # the default

Every variable has a unit (its suffix), a range and the levels it exists at (``VARIABLES``). Errors are
one line naming the file, the key, the value and the rule (ConfigError, exit status 2).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config_loading import read_yaml, resolve_config
from ..errors import ConfigError

LEVELS = ("offline", "mavlink")


@dataclass(frozen=True)
class Variable:
    """A sweepable input: name (unit suffix), range [lo, hi], nominal value, the levels it exists at, meaning."""

    name: str
    lo: float
    hi: float
    nominal: float
    levels: tuple[str, ...]
    doc: str


_BOTH = LEVELS
VARIABLES: dict[str, Variable] = {v.name: v for v in (
    Variable("disturbance_roll_nm", -5.0, 5.0, 0.0, _BOTH, "step torque on roll [N m, body FRD], from disturbance_start_s"),
    Variable("disturbance_pitch_nm", -5.0, 5.0, 0.0, _BOTH, "step torque on pitch [N m]"),
    Variable("disturbance_yaw_nm", -5.0, 5.0, 0.0, _BOTH, "step torque on yaw [N m]"),
    Variable("disturbance_start_s", 0.0, 60.0, 4.0, _BOTH, "onset of the swept step torque [s from the reference start]"),
    Variable("disturbance_duration_s", 0.0, 60.0, math.inf, _BOTH, "length of the swept torque (a pulse) [s]; absent = a step to the end"),
    Variable("inertia_table3_scale", 0.0, 3.0, 0.0, _BOTH, "multiple of the paper's Table 3 relative inertia variation (1 = Table 3) [-]"),
    Variable("inertia_xx_rel", -0.9, 3.0, 0.0, _BOTH, "relative change of the true Ixx (I_true,xx = (1 + x) I0,xx) [-]"),
    Variable("inertia_yy_rel", -0.9, 3.0, 0.0, _BOTH, "relative change of the true Iyy [-]"),
    Variable("inertia_zz_rel", -0.9, 3.0, 0.0, _BOTH, "relative change of the true Izz [-]"),
    Variable("mass_rel", 0.0, 1.0, 0.0, _BOTH, "payload as a fraction of the vehicle mass [-] (no effect on the torque-level attitude dynamics)"),
    Variable("sensor_noise_scale", 0.0, 20.0, 0.0, _BOTH, "multiple of the vehicle's sensor_noise (attitude and gyro white noise std) [-]"),
    Variable("rate_time_constant_s", 0.001, 1.0, 0.05, ("mavlink",), "rate-loop time constant the bridge's mapping assumes, every axis [s]"),
    Variable("loop_delay_s", 0.001, 1.0, 0.04, ("mavlink",), "loop delay the bridge's mapping assumes (roll, pitch; yaw keeps its own) [s]"),
    Variable("link_loss", 0.0, 0.9, 0.0, ("mavlink",), "datagram loss probability, each direction, through the impairment proxy [-]"),
    Variable("link_delay_s", 0.0, 0.5, 0.0, ("mavlink",), "one-way link delay, each direction [s, vehicle clock]"),
    Variable("link_jitter_s", 0.0, 0.5, 0.0, ("mavlink",), "extra one-way delay drawn uniformly from [0, jitter] per datagram [s]"),
)}

#: bounds a run must meet to be ``settled`` (issue 14's control-quality bounds); any subset may be set
#: a number applies to every axis, a list of 3 gives [roll, pitch, yaw]
DEFAULT_BOUNDS = {"settling_5pct_s": (1.5, 1.5, 2.5), "overshoot_pct": (10.0,) * 3, "steady_error_deg": (0.5,) * 3}
_SWEEP_KEYS = {"controllers", "scenario", "reference", "duration_s", "seed", "draws", "chunk_runs", "dt_control_s", "variables", "map", "bounds"}


@dataclass(frozen=True)
class ControllerChoice:
    key: str
    preset: str | None = None

    @property
    def label(self) -> str:
        return f"{self.key}:{self.preset}" if self.preset else self.key


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep (see module docstring). ``variables``: name -> ('grid', values) | ('uniform', lo, hi) |
    ('normal', mean, std)."""

    path: str
    controllers: tuple[ControllerChoice, ...]
    scenario: str
    reference: str | None
    duration_s: float | None
    seed: int
    draws: int
    chunk_runs: int
    dt_control_s: float
    variables: dict[str, tuple]
    map_metric: str
    map_x: str
    map_y: str
    bounds: dict[str, tuple[float, float, float]]
    raw: dict = field(default_factory=dict, repr=False)

    @property
    def digest(self) -> str:
        """Hash of the sweep section: a rerun resumes only the same sweep."""
        return hashlib.sha256(json.dumps(self.raw, sort_keys=True, default=str).encode()).hexdigest()[:16]

    def check_level(self, level: str) -> None:
        """ConfigError when a variable does not exist at ``level``."""
        for name in self.variables:
            if level not in VARIABLES[name].levels:
                raise ConfigError(f"{self.path}: key 'sweep.variables.{name}' breaks rule: exists at level(s) "
                                  f"{', '.join(VARIABLES[name].levels)} only, not --level {level}")

    def runs(self) -> list[dict]:
        """Every run in a fixed order: controller outermost, then the grid (first variable slowest), then draws.

        Each row: run_id, controller, seed, and one value per swept variable (drawn with the run's own seed)."""
        grid_names = [n for n, v in self.variables.items() if v[0] == "grid"]
        grids = [self.variables[n][1] for n in grid_names]
        rows = []
        i = 0
        for ctrl in self.controllers:
            for point in itertools.product(*grids) if grids else [()]:
                for _ in range(self.draws):
                    seed = self.seed + i
                    rng = np.random.default_rng(seed)
                    row = {"run_id": i, "controller": ctrl.label, "seed": seed}
                    row.update(zip(grid_names, (float(x) for x in point)))
                    for name, (kind, *args) in self.variables.items():
                        if kind == "grid":
                            continue
                        var = VARIABLES[name]
                        x = rng.uniform(args[0], args[1]) if kind == "uniform" else rng.normal(args[0], args[1])
                        row[name] = float(min(max(x, var.lo), var.hi))
                    rows.append(row)
                    i += 1
        return rows


def _number(path, key, x) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: must be a finite number")
    return float(x)


def _in_range(path, key, var: Variable, x) -> float:
    x = _number(path, key, x)
    if not (var.lo <= x <= var.hi):
        raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: outside the variable's range [{var.lo:g}, {var.hi:g}]")
    return x


def _parse_variable(path, name, raw) -> tuple:
    key = f"sweep.variables.{name}"
    if name not in VARIABLES:
        raise ConfigError(f"{path}: unknown variable '{key}'; known: {', '.join(VARIABLES)}")
    var = VARIABLES[name]
    if not isinstance(raw, dict) or len(raw) != 1 or next(iter(raw)) not in ("grid", "uniform", "normal"):
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: one of {{grid: [...]}}, {{uniform: [lo, hi]}}, {{normal: [mean, std]}}")
    kind, val = next(iter(raw.items()))
    if kind == "grid":
        if not isinstance(val, list) or not val:
            raise ConfigError(f"{path}: key '{key}.grid' = {val!r} breaks rule: a non-empty list of numbers")
        values = tuple(_in_range(path, f"{key}.grid", var, x) for x in val)
        if len(set(values)) != len(values):
            raise ConfigError(f"{path}: key '{key}.grid' = {val!r} breaks rule: values must be distinct")
        return ("grid", values)
    if not isinstance(val, list) or len(val) != 2:
        raise ConfigError(f"{path}: key '{key}.{kind}' = {val!r} breaks rule: two numbers")
    if kind == "uniform":
        lo, hi = (_in_range(path, f"{key}.uniform", var, x) for x in val)
        if not lo < hi:
            raise ConfigError(f"{path}: key '{key}.uniform' = {val!r} breaks rule: needs lo < hi")
        return ("uniform", lo, hi)
    mean = _in_range(path, f"{key}.normal", var, val[0])
    std = _number(path, f"{key}.normal", val[1])
    if std < 0:
        raise ConfigError(f"{path}: key '{key}.normal' = {val!r} breaks rule: std must be >= 0")
    return ("normal", mean, std)


def _reference_duration(name: str) -> float:
    from ..references import load_reference

    return load_reference(name).duration_s


def _int(path, key, x, lo, hi) -> int:
    if isinstance(x, bool) or not isinstance(x, int) or not lo <= x <= hi:
        raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: an integer within [{lo}, {hi}]")
    return x


def _parse_controllers(path: Path, ctrl_raw) -> tuple[ControllerChoice, ...]:
    """``sweep.controllers``: each a law key, optionally ``KEY[preset]``, whose law and preset exist; each once."""
    from ..control import law_class, law_preset, split_law_and_preset

    if not isinstance(ctrl_raw, list) or not ctrl_raw or not all(isinstance(c, str) for c in ctrl_raw):
        raise ConfigError(f"{path}: key 'sweep.controllers' = {ctrl_raw!r} breaks rule: a non-empty list of controller names")
    controllers = []
    for c in ctrl_raw:
        key, preset = split_law_and_preset(c)
        try:
            law = law_class(key)
            if preset:
                resolve_config(preset, "controllers")
            else:
                law_preset(law)
        except ConfigError as exc:
            raise ConfigError(f"{path}: key 'sweep.controllers' = {c!r} breaks rule: {exc}") from None
        controllers.append(ControllerChoice(key, preset))
    if len({c.label for c in controllers}) != len(controllers):
        raise ConfigError(f"{path}: key 'sweep.controllers' = {ctrl_raw!r} breaks rule: each controller once")
    return tuple(controllers)


def _check_variables_fit_scenario(path: Path, variables: dict, scenario: str, base, end_s: float) -> None:
    """Swept inertia needs a relative (or no) inertia variation in the scenario; a swept torque must start before
    the run ends."""
    if base.inertia_mode == "absolute" and any(n.startswith("inertia_") for n in variables):
        raise ConfigError(f"{path}: key 'sweep.scenario' = {scenario!r} breaks rule: its inertia variation is absolute (kg m^2); "
                          f"swept inertia variables are relative: use a scenario without one or with a relative one")
    if any(n.startswith("disturbance_") and n.endswith("_nm") for n in variables):
        onset = variables.get("disturbance_start_s", ("grid", (VARIABLES["disturbance_start_s"].nominal,)))
        latest = max(onset[1]) if onset[0] == "grid" else onset[2] if onset[0] == "uniform" else onset[1]
        if not latest < end_s:
            raise ConfigError(f"{path}: key 'sweep.variables.disturbance_start_s' = {latest:g} s breaks rule: the swept torque must "
                              f"start before the run ends at {end_s:g} s (default onset {VARIABLES['disturbance_start_s'].nominal:g} s)")


def _parse_map(path: Path, m, variables: dict) -> tuple[str, str, str]:
    """``sweep.map``: (metric, x, y); x and y are distinct grid variables (drawn values do not tile), by default the
    first two."""
    if not isinstance(m, dict) or set(m) - {"metric", "x", "y"}:
        raise ConfigError(f"{path}: key 'sweep.map' = {m!r} breaks rule: a mapping with metric, x, y")
    swept = [n for n, v in variables.items() if v[0] == "grid"]
    map_x = m.get("x", swept[0] if swept else "")
    map_y = m.get("y", swept[1] if len(swept) > 1 else "")
    for k, v in (("x", map_x), ("y", map_y)):
        if v and v not in swept:
            raise ConfigError(f"{path}: key 'sweep.map.{k}' = {v!r} breaks rule: must be one of the grid variables {swept}")
    if map_x and map_x == map_y:
        raise ConfigError(f"{path}: key 'sweep.map' breaks rule: x and y must differ")
    return str(m.get("metric", "max_abs_error_deg_roll")), map_x, map_y


def _parse_bounds(path: Path, bounds_raw) -> dict[str, tuple[float, float, float]]:
    """``sweep.bounds``: per key a number (every axis) or [roll, pitch, yaw]."""
    if not isinstance(bounds_raw, dict) or set(bounds_raw) - set(DEFAULT_BOUNDS):
        raise ConfigError(f"{path}: key 'sweep.bounds' = {bounds_raw!r} breaks rule: keys among {', '.join(DEFAULT_BOUNDS)}")
    bounds = {}
    for k, v in bounds_raw.items():
        vals = list(v) if isinstance(v, (list, tuple)) else [v] * 3
        if len(vals) != 3:
            raise ConfigError(f"{path}: key 'sweep.bounds.{k}' = {v!r} breaks rule: a number or a list of 3 [roll, pitch, yaw]")
        bounds[k] = tuple(_number(path, f"sweep.bounds.{k}", x) for x in vals)
    return bounds


def load_sweep(name_or_path: str | Path) -> SweepSpec:
    """Load and validate a sweep (packaged name in ``configs/sweeps`` or a path). ConfigError (one line) on bad input."""
    from ..scenarios import load_scenario

    path = resolve_config(name_or_path, "sweeps")
    data = read_yaml(path)
    body = data.get("sweep")
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: missing section 'sweep'")
    unknown = sorted(set(body) - _SWEEP_KEYS)
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {', '.join('sweep.' + k for k in unknown)}; allowed {', '.join(sorted(_SWEEP_KEYS))}")
    controllers = _parse_controllers(path, body.get("controllers"))
    scenario = str(body.get("scenario", "nominal"))
    reference = body.get("reference")
    if reference is not None:
        from ..references import load_reference

        load_reference(str(reference))
    duration = body.get("duration_s")
    if duration is not None and not (1.0 <= _number(path, "sweep.duration_s", duration) <= 600.0):
        raise ConfigError(f"{path}: key 'sweep.duration_s' = {duration!r} breaks rule: within [1, 600] s (the metrics need a 1 s window)")
    dt = _number(path, "sweep.dt_control_s", body.get("dt_control_s", 1e-3))
    if not 1e-5 <= dt <= 0.02:
        raise ConfigError(f"{path}: key 'sweep.dt_control_s' = {dt!r} breaks rule: within [1e-05, 0.02] s")
    vars_raw = body.get("variables") or {}
    if not isinstance(vars_raw, dict):
        raise ConfigError(f"{path}: key 'sweep.variables' breaks rule: a mapping name -> grid or distribution")
    variables = {str(n): _parse_variable(path, str(n), r) for n, r in vars_raw.items()}
    base = load_scenario(scenario)  # one line naming the scenario when it does not exist
    end_s = float(duration) if duration is not None else (_reference_duration(reference) if reference is not None else base.duration_s)
    _check_variables_fit_scenario(path, variables, scenario, base, end_s)
    map_metric, map_x, map_y = _parse_map(path, body.get("map") or {}, variables)
    return SweepSpec(
        path=str(path), controllers=controllers, scenario=scenario,
        reference=None if reference is None else str(reference),
        duration_s=None if duration is None else float(duration),
        seed=_int(path, "sweep.seed", body.get("seed", 1), 0, 2**31), draws=_int(path, "sweep.draws", body.get("draws", 1), 1, 100000),
        chunk_runs=_int(path, "sweep.chunk_runs", body.get("chunk_runs", 256), 1, 100000), dt_control_s=dt,
        variables=variables, map_metric=map_metric, map_x=map_x, map_y=map_y,
        bounds=_parse_bounds(path, body.get("bounds", DEFAULT_BOUNDS)), raw=body,
    )
