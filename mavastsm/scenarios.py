"""Simulation scenarios of the paper (nominal, disturbance, parametric variation) as plain data.

Shared by the offline simulator (``mavastsm.offline``) and the MAVLink-speaking simulated Solo
(``mavastsm_sim``): both read the **same** YAML files for the reference, the external disturbance
torque and the inertia variation. Pure data + pure functions of time; no I/O beyond loading.

YAML schema (``configs/scenarios/<name>.yaml``; units in key names)::

    description: free text
    scenario:
      reference: paper_steps          # packaged reference name, or a path (relative to this file)
      duration_s: 7.0                 # optional; default = the reference's duration_s
      disturbances:                   # optional list of body-FRD torques [N m], summed
        - {type: step,  start_s: 4.0, torque_nm: [0.5, 0.5, 0.5]}
        - {type: pulse, start_s: 4.0, end_s: 5.0, torque_nm: [0.5, 0.0, 0.0]}
      inertia_variation:              # optional; default: none (true inertia = nominal I0)
        mode: relative                # none | relative | absolute
        delta: [[0.4825, 0.0044, -0.0077],
                [0.0044, 0.2437, 0.0115],
                [-0.0077, 0.0115, 0.2437]]
      payload_mass_kg: 0.8            # optional, default 0; mass does not enter the attitude dynamics

Inertia variation (paper Table 3; docs/design-decisions.md, CTL-11). With s = sqrt(diag(I0)):

* ``relative`` (default reading): I_true = I0 + delta o (s s^T), i.e. diagonals scale by (1 + delta_ii),
  off-diagonals become delta_ij sqrt(I_ii I_jj) [kg m^2]. Symmetric positive definite.
* ``absolute`` (literal reading, a stress test): I_true = I0 + delta, delta in kg m^2.

A step starts at ``start_s`` and lasts to the end; a pulse is on for start_s <= t < end_s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .config_loading import packaged_config_dir, read_yaml, resolve_config
from .errors import ConfigError
from .frames import AXES
from .references import ReferenceProfile, load_reference

_INERTIA_MODES = ("none", "relative", "absolute")


@dataclass(frozen=True)
class TorqueEvent:
    """A body-FRD torque [N m] (3,) on for start_s <= t < end_s (end_s = inf for a step)."""

    start_s: float
    end_s: float
    torque_nm: tuple[float, float, float]


@dataclass(frozen=True)
class Scenario:
    """One simulation scenario (see module docstring for the YAML schema).

    Attributes
    ----------
    name : scenario name (file stem)
    duration_s : [s] run length
    reference : ReferenceProfile for Theta_d(t)
    disturbances : tuple of TorqueEvent (body FRD, N m)
    inertia_mode : 'none' | 'relative' | 'absolute'
    inertia_delta : (3, 3) nested tuple, dimensionless (relative) or kg m^2 (absolute)
    payload_mass_kg : [kg] added mass (reported only; does not change attitude dynamics)
    """

    name: str
    duration_s: float
    reference: ReferenceProfile
    disturbances: tuple[TorqueEvent, ...] = ()
    inertia_mode: str = "none"
    inertia_delta: tuple = field(default=((0.0,) * 3,) * 3)
    payload_mass_kg: float = 0.0
    description: str = ""

    def disturbance_torque_nm(self, t_s):
        """External torque d(t) [N m, body FRD]: (3,) for a scalar t, (n, 3) for t of shape (n,)."""
        t = np.asarray(t_s, dtype=float)
        out = np.zeros(t.shape + (3,))
        for ev in self.disturbances:
            on = (t >= ev.start_s) & (t < ev.end_s)
            out += on[..., None] * np.asarray(ev.torque_nm)
        return out

    def true_inertia(self, inertia_diag) -> np.ndarray:
        """Plant inertia I_true [kg m^2] (3, 3) from the controllers' nominal diagonal I0 (3,)."""
        i0 = np.asarray(inertia_diag, dtype=float)
        nominal = np.diag(i0)
        delta = np.asarray(self.inertia_delta, dtype=float)
        if self.inertia_mode == "relative":
            s = np.sqrt(i0)
            return nominal + delta * np.outer(s, s)
        if self.inertia_mode == "absolute":
            return nominal + delta
        return nominal

    @property
    def disturbance_start_s(self) -> float | None:
        """Earliest disturbance onset [s], or None without disturbance."""
        return min((ev.start_s for ev in self.disturbances), default=None)


def beyond_authority(scenario: Scenario, authority_nm) -> list[str]:
    """The axes on which the scenario's disturbance torque exceeds the vehicle's torque authority [N m] (roll, pitch,
    yaw), as ``"yaw 0.50 N m > 0.23 N m"``; [] when every axis is within it. The largest |d| is taken over the
    events' start times (overlapping events add). No controller can hold such an axis: the attitude runs away."""
    starts = [ev.start_s for ev in scenario.disturbances]
    if not starts:
        return []
    peak = np.abs(scenario.disturbance_torque_nm(np.asarray(starts, dtype=float))).max(axis=0)
    return [f"{axis} {d:.2f} N m > {float(a):.2f} N m" for axis, d, a in zip(AXES, peak.tolist(), authority_nm) if d > float(a)]


def packaged_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``configs/scenarios``."""
    return sorted(p.stem for p in (packaged_config_dir() / "scenarios").glob("*.yaml"))


def _vec3(path: Path, key: str, raw: Any) -> tuple[float, float, float]:
    if not isinstance(raw, list) or len(raw) != 3:
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be a list of 3 numbers")
    out = []
    for x in raw:
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
            raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be finite numbers")
        out.append(float(x))
    return tuple(out)  # type: ignore[return-value]


def _time(path: Path, key: str, raw: Any) -> float:
    if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not np.isfinite(raw) or raw < 0:
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be a time >= 0 [s]")
    return float(raw)


def _parse_event(path: Path, key: str, raw: Any) -> TorqueEvent:
    if not isinstance(raw, dict) or raw.get("type") not in ("step", "pulse"):
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: needs 'type' step or pulse")
    allowed = {"type", "start_s", "torque_nm"} | ({"end_s"} if raw["type"] == "pulse" else set())
    if set(raw) != allowed:
        raise ConfigError(f"{path}: key '{key}' breaks rule: {raw['type']} takes exactly {sorted(allowed)}, got {sorted(raw)}")
    start = _time(path, f"{key}.start_s", raw["start_s"])
    end = _time(path, f"{key}.end_s", raw["end_s"]) if raw["type"] == "pulse" else float("inf")
    if end <= start:
        raise ConfigError(f"{path}: key '{key}.end_s' = {end!r} breaks rule: must be > start_s")
    return TorqueEvent(start, end, _vec3(path, f"{key}.torque_nm", raw["torque_nm"]))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a scenario: a packaged name (``nominal``, ``disturbance``, ``variation``, ...) or a YAML path.

    Raises ConfigError (one line) naming the file/key for an unknown name (listing the packaged
    ones), missing/malformed YAML, an unknown key or a bad value.
    """
    path = resolve_config(name_or_path, "scenarios")
    data = read_yaml(path)
    body = data.get("scenario")
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: missing section 'scenario'")
    allowed = {"reference", "duration_s", "disturbances", "inertia_variation", "payload_mass_kg"}
    unknown = set(body) - allowed
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {sorted('scenario.' + u for u in unknown)}; allowed {sorted(allowed)}")
    if "reference" not in body:
        raise ConfigError(f"{path}: missing key 'scenario.reference'")
    ref_name = body["reference"]
    local = path.parent / str(ref_name)
    reference = load_reference(local if local.is_file() else ref_name)
    duration = body.get("duration_s", reference.duration_s)
    if isinstance(duration, bool) or not isinstance(duration, (int, float)) or not (np.isfinite(duration) and duration > 0):
        raise ConfigError(f"{path}: key 'scenario.duration_s' = {duration!r} breaks rule: must be > 0 [s]")
    events_raw = body.get("disturbances") or []
    if not isinstance(events_raw, list):
        raise ConfigError(f"{path}: key 'scenario.disturbances' breaks rule: must be a list")
    events = tuple(_parse_event(path, f"scenario.disturbances[{i}]", e) for i, e in enumerate(events_raw))
    mode, delta = "none", ((0.0,) * 3,) * 3
    var = body.get("inertia_variation")
    if var is not None:
        if not isinstance(var, dict) or set(var) - {"mode", "delta"}:
            raise ConfigError(f"{path}: key 'scenario.inertia_variation' breaks rule: mapping with 'mode' and 'delta'")
        mode = var.get("mode", "relative")
        if mode not in _INERTIA_MODES:
            raise ConfigError(f"{path}: key 'scenario.inertia_variation.mode' = {mode!r} breaks rule: must be one of {list(_INERTIA_MODES)}")
        rows = var.get("delta")
        if not isinstance(rows, list) or len(rows) != 3:
            raise ConfigError(f"{path}: key 'scenario.inertia_variation.delta' breaks rule: must be a 3x3 list")
        delta = tuple(_vec3(path, f"scenario.inertia_variation.delta[{i}]", r) for i, r in enumerate(rows))
        d = np.asarray(delta)
        if not np.allclose(d, d.T):
            raise ConfigError(f"{path}: key 'scenario.inertia_variation.delta' breaks rule: must be symmetric")
    payload = body.get("payload_mass_kg", 0.0)
    if isinstance(payload, bool) or not isinstance(payload, (int, float)) or not (np.isfinite(payload) and payload >= 0):
        raise ConfigError(f"{path}: key 'scenario.payload_mass_kg' = {payload!r} breaks rule: must be >= 0 [kg]")
    desc = data.get("description", "")
    return Scenario(
        name=path.stem,
        duration_s=float(duration),
        reference=reference,
        disturbances=events,
        inertia_mode=mode,
        inertia_delta=delta,
        payload_mass_kg=float(payload),
        description=desc.strip() if isinstance(desc, str) else "",
    )
