"""Attitude reference profiles Theta_d(t): pure, vectorised functions of time (no I/O beyond loading).

A profile gives, at any time t [s], the desired ZYX Euler attitude Theta_d [rad] (roll, pitch, yaw;
NED -> FRD), its Euler-rate derivative Theta_dot_d [rad/s] and second derivative Theta_ddot_d [rad/s^2]
-- the quantities of the paper's eqs. (19)-(24). The paper's nominal scenario uses steps (roll -10 deg
at 0.5 s, pitch +10 deg at 1.0 s, yaw +45 deg at 2.0 s) with Theta_dot_d = Theta_ddot_d = 0, i.e. the
derivative impulses of the steps are ignored (docs/design-decisions.md, CTL-3).

Optional prefilter (a deviation from the paper, off by default): a critically damped 2nd-order filter
``wn^2 / (s + wn)^2`` applied to the step and ramp components, evaluated in closed form so the profile
stays a pure function of time and its derivatives are exact. Sine components are smooth already and are
never filtered; their analytic derivatives are always used.

YAML schema (``configs/references/<name>.yaml``; units in the key names)::

    description: free text
    reference:
      duration_s: 5.0                # suggested run length [s]
      prefilter_wn_rads: 0.0         # 0 = off (paper); e.g. 10.0 for a smooth 2nd-order prefilter
      offset_deg: [0, 0, 0]          # optional constant attitude [roll, pitch, yaw] added to everything
      roll:                          # per axis: a list of components, summed (any axis may be omitted)
        - {type: step, time_s: 0.5, angle_deg: -10.0}
      pitch:
        - {type: ramp, start_time_s: 1.0, end_time_s: 2.0, angle_deg: 10.0}   # 0 -> angle over [start, end]
      yaw:
        - {type: sine, start_time_s: 0.0, amplitude_deg: 5.0, frequency_hz: 0.5, phase_deg: 0.0}

A step/ramp component changes the reference *by* ``angle_deg`` (relative to what came before), so
``relative_to(engage_attitude)`` simply shifts the offset: the bridge applies the paper's steps on top
of the attitude (and heading) held when control engages. Yaw of Theta_d is wrapped to (-pi, pi].
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from .config_loading import read_yaml, resolve_config
from .errors import ConfigError
from .frames import AXES, wrap_angle

_COMPONENT_KEYS = {
    "step": {"time_s", "angle_deg"},
    "ramp": {"start_time_s", "end_time_s", "angle_deg"},
    "sine": {"start_time_s", "amplitude_deg", "frequency_hz", "phase_deg"},
}
_OPTIONAL_KEYS = {"sine": {"phase_deg", "start_time_s"}}


@dataclass(frozen=True)
class ReferenceComponent:
    """One additive component on one axis (angles in rad, times in s, frequency in Hz)."""

    kind: str  # 'step' | 'ramp' | 'sine'
    axis: int  # 0 roll, 1 pitch, 2 yaw
    angle_rad: float = 0.0  # step/ramp size, or sine amplitude
    start_s: float = 0.0  # step time / ramp start / sine start
    end_s: float = 0.0  # ramp end
    frequency_hz: float = 0.0
    phase_rad: float = 0.0


def _filtered_step(tau, wn):
    """Critically damped 2nd-order response to a unit step at tau = 0: (y, y', y''). tau >= 0 only."""
    ex = np.exp(-wn * tau)
    return 1.0 - (1.0 + wn * tau) * ex, wn * wn * tau * ex, wn * wn * (1.0 - wn * tau) * ex


def _filtered_ramp(tau, wn):
    """Same filter's response to a unit-slope ramp starting at tau = 0: (y, y', y''). tau >= 0 only."""
    ex = np.exp(-wn * tau)
    return tau - 2.0 / wn + (2.0 / wn + tau) * ex, 1.0 - (1.0 + wn * tau) * ex, wn * wn * tau * ex


def _component_value(c: ReferenceComponent, t, wn: float):
    """(angle, rate, accel) of one component at times t (array) [rad, rad/s, rad/s^2]."""
    zero = np.zeros_like(t)
    if c.kind == "step":
        tau = np.maximum(t - c.start_s, 0.0)
        on = t >= c.start_s
        if wn > 0.0:
            y, yd, ydd = _filtered_step(tau, wn)
            return c.angle_rad * y * on, c.angle_rad * yd * on, c.angle_rad * ydd * on
        return c.angle_rad * on, zero, zero
    if c.kind == "ramp":
        slope = c.angle_rad / (c.end_s - c.start_s)
        tau0 = np.maximum(t - c.start_s, 0.0)
        tau1 = np.maximum(t - c.end_s, 0.0)
        if wn > 0.0:
            y0, yd0, ydd0 = _filtered_ramp(tau0, wn)
            y1, yd1, ydd1 = _filtered_ramp(tau1, wn)
            on0, on1 = t >= c.start_s, t >= c.end_s
            return (
                slope * (y0 * on0 - y1 * on1),
                slope * (yd0 * on0 - yd1 * on1),
                slope * (ydd0 * on0 - ydd1 * on1),
            )
        inside = (t >= c.start_s) & (t < c.end_s)
        return slope * (tau0 - tau1), slope * inside, zero
    # sine: A sin(2 pi f (t - t0) + phase) - A sin(phase), starting at t0 (continuous angle at t0)
    on = t >= c.start_s
    w = 2.0 * np.pi * c.frequency_hz
    arg = w * (t - c.start_s) + c.phase_rad
    a = c.angle_rad
    return a * (np.sin(arg) - np.sin(c.phase_rad)) * on, a * w * np.cos(arg) * on, -a * w * w * np.sin(arg) * on


@dataclass(frozen=True)
class ReferenceProfile:
    """A reference Theta_d(t) made of additive per-axis components (see module docstring).

    Attributes
    ----------
    name : profile name (file stem)
    duration_s : [s] suggested run length
    components : tuple of ReferenceComponent
    offset_rad : [rad] (3,) constant attitude added to everything (set by ``relative_to``)
    prefilter_wn_rads : [rad/s] natural frequency of the critically damped prefilter; 0 = off (paper)
    """

    name: str
    duration_s: float
    components: tuple[ReferenceComponent, ...] = ()
    offset_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    prefilter_wn_rads: float = 0.0

    def at(self, t_s):
        """Reference at time(s) ``t_s`` [s].

        Returns
        -------
        (theta_d_rad, theta_dot_d_rads, theta_ddot_d_radss) : each (3,) for a scalar t, (n, 3) for t of
        shape (n,). Euler angles [roll, pitch, yaw] (ZYX, NED -> FRD) and their time derivatives (Euler
        rates, not body rates). Yaw of theta_d is wrapped to (-pi, pi].
        """
        t = np.asarray(t_s, dtype=float)
        scalar = t.ndim == 0
        t = np.atleast_1d(t)
        angle = np.tile(np.asarray(self.offset_rad, dtype=float), (t.shape[0], 1))
        rate = np.zeros_like(angle)
        accel = np.zeros_like(angle)
        for c in self.components:
            a, r, acc = _component_value(c, t, self.prefilter_wn_rads)
            angle[:, c.axis] += a
            rate[:, c.axis] += r
            accel[:, c.axis] += acc
        angle[:, 2] = wrap_angle(angle[:, 2])
        if scalar:
            return angle[0], rate[0], accel[0]
        return angle, rate, accel

    def relative_to(self, initial_euler_rad) -> "ReferenceProfile":
        """The same profile applied on top of ``initial_euler_rad`` [rad] (3,), e.g. the engage attitude.

        Steps and ramps change the reference *by* their angle, so the yaw step is relative to the
        heading held at engagement. The profile's own offset is added to the initial attitude.
        """
        base = np.asarray(initial_euler_rad, dtype=float).reshape(3) + np.asarray(self.offset_rad)
        return replace(self, offset_rad=tuple(float(x) for x in base))

    def with_prefilter(self, wn_rads: float) -> "ReferenceProfile":
        """Copy with the critically damped prefilter set to ``wn_rads`` [rad/s] (0 = off)."""
        if not (np.isfinite(wn_rads) and wn_rads >= 0.0):
            raise ConfigError(f"reference '{self.name}': prefilter_wn_rads = {wn_rads!r} breaks rule: must be >= 0")
        return replace(self, prefilter_wn_rads=float(wn_rads))

    def event_times_s(self, axis: int) -> list[float]:
        """Start times [s] of the components on ``axis`` (used by metrics to find step responses)."""
        return sorted(c.start_s for c in self.components if c.axis == axis)

    def step_size_rad(self, axis: int) -> float:
        """Total step/ramp angle [rad] commanded on ``axis`` (0 when the axis only holds)."""
        return float(sum(c.angle_rad for c in self.components if c.axis == axis and c.kind in ("step", "ramp")))


def _number(path: Path, key: str, raw: Any, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not np.isfinite(raw):
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be a finite number")
    if positive and raw <= 0:
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be > 0")
    if nonneg and raw < 0:
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: must be >= 0")
    return float(raw)


def _parse_component(path: Path, key: str, axis: int, raw: Any) -> ReferenceComponent:
    if not isinstance(raw, dict) or raw.get("type") not in _COMPONENT_KEYS:
        raise ConfigError(f"{path}: key '{key}' = {raw!r} breaks rule: needs 'type' one of {sorted(_COMPONENT_KEYS)}")
    kind = raw["type"]
    fields = set(raw) - {"type"}
    allowed = _COMPONENT_KEYS[kind]
    if fields - allowed:
        raise ConfigError(f"{path}: key '{key}' has unknown field(s) {sorted(fields - allowed)}; {kind} takes {sorted(allowed)}")
    missing = allowed - fields - _OPTIONAL_KEYS.get(kind, set())
    if missing:
        raise ConfigError(f"{path}: key '{key}' ({kind}) is missing {sorted(missing)}")
    g = {k: _number(path, f"{key}.{k}", v) for k, v in raw.items() if k != "type"}
    if kind == "step":
        return ReferenceComponent("step", axis, np.radians(g["angle_deg"]), start_s=g["time_s"])
    if kind == "ramp":
        if g["end_time_s"] <= g["start_time_s"]:
            raise ConfigError(f"{path}: key '{key}.end_time_s' = {g['end_time_s']!r} breaks rule: must be > start_time_s")
        return ReferenceComponent("ramp", axis, np.radians(g["angle_deg"]), start_s=g["start_time_s"], end_s=g["end_time_s"])
    _number(path, f"{key}.frequency_hz", g["frequency_hz"], nonneg=True)
    return ReferenceComponent(
        "sine", axis, np.radians(g["amplitude_deg"]), start_s=g.get("start_time_s", 0.0),
        frequency_hz=g["frequency_hz"], phase_rad=np.radians(g.get("phase_deg", 0.0)),
    )


def parse_reference(path: Path, body: Any, name: str) -> ReferenceProfile:
    """Build a ReferenceProfile from the ``reference`` mapping of a YAML file (see module docstring)."""
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: section 'reference' must be a mapping")
    allowed = {"duration_s", "prefilter_wn_rads", "offset_deg", *AXES}
    unknown = set(body) - allowed
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {sorted('reference.' + u for u in unknown)}; allowed {sorted(allowed)}")
    if "duration_s" not in body:
        raise ConfigError(f"{path}: missing key 'reference.duration_s'")
    duration = _number(path, "reference.duration_s", body["duration_s"], positive=True)
    wn = _number(path, "reference.prefilter_wn_rads", body.get("prefilter_wn_rads", 0.0), nonneg=True)
    offset = body.get("offset_deg", [0.0, 0.0, 0.0])
    if not isinstance(offset, list) or len(offset) != 3:
        raise ConfigError(f"{path}: key 'reference.offset_deg' = {offset!r} breaks rule: must be [roll, pitch, yaw]")
    offset_rad = tuple(float(np.radians(_number(path, "reference.offset_deg", x))) for x in offset)
    comps: list[ReferenceComponent] = []
    for axis, axis_name in enumerate(AXES):
        items = body.get(axis_name) or []
        if not isinstance(items, list):
            raise ConfigError(f"{path}: key 'reference.{axis_name}' breaks rule: must be a list of components")
        comps += [_parse_component(path, f"reference.{axis_name}[{i}]", axis, c) for i, c in enumerate(items)]
    return ReferenceProfile(name=name, duration_s=duration, components=tuple(comps), offset_rad=offset_rad, prefilter_wn_rads=wn)


def load_reference(name_or_path: str | Path) -> ReferenceProfile:
    """Load a reference profile: a packaged name (``paper_steps``, ``hold``, ...) or a YAML path.

    Raises ConfigError (one line) for an unknown name, missing/malformed YAML or a bad field.
    """
    path = resolve_config(name_or_path, "references")
    data = read_yaml(path)
    if "reference" not in data:
        raise ConfigError(f"{path}: missing section 'reference'")
    return parse_reference(path, data["reference"], path.stem)


def reference_from_option(reference: Any) -> tuple[Any, str]:
    """(profile, name) for a ``--reference`` value: a packaged name or YAML path (``load_reference``), or a ready
    profile object (its ``name``, else "custom")."""
    if not isinstance(reference, (str, Path)):
        return reference, getattr(reference, "name", "custom")
    return load_reference(reference), str(reference)
