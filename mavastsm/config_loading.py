"""YAML configuration -> validated, frozen dataclasses.

Every tunable number in mavastsm lives in a YAML file under ``configs/`` (shipped inside the
package as ``mavastsm.configs``), never as a literal in code. A file is a mapping of sections;
each section maps a key to a *parameter spec* that carries its own metadata, in the spirit of
PX4's parameter YAML and ArduPilot's ``@Units/@Range``::

    gains:                      # section
      lambda:                   # key == dataclass field name
        value: [3.89, 3.89, 4.36]
        unit: 1/s
        symbol: "Λ (eq. 19)"
        range: [0.0, 100.0]     # inclusive; null for an open end; checked per element
        exclusive_min: true     # optional: lower bound is strict (value > lo)
        doc: Sliding-surface slope; larger = faster, stiffer convergence of e on sigma = 0.
        source: Hoang & Pham 2018, Table 2

String parameters use ``choices: [a, b]`` instead of ``range``. A top-level ``description``
string is allowed. Loading rejects, with one line naming file, key, value and rule:
missing/malformed YAML, a spec without ``value`` or ``unit``, non-finite numbers, out-of-range
values, unknown keys and missing keys.

A controller preset may be a delta of another (``extends: <preset name>``): it then gives only the spec
fields it changes (``mu: {value: 0.03, source: ...}``), merged field by field over the base's spec; its
``description`` replaces the base's. The base is a file next to the preset, else a packaged controller
preset or sim profile (``configs/sim_profiles``); it may itself extend another. An unknown base, a cycle, or a section or key the base does not have
is a ConfigError naming the file and key (:func:`read_config`).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .errors import ConfigError

_SPEC_KEYS = {"value", "unit", "symbol", "range", "exclusive_min", "choices", "doc", "source"}


@dataclass(frozen=True)
class Parameter:
    """One validated configuration value with its metadata."""

    key: str
    value: Any
    unit: str
    symbol: str = ""
    doc: str = ""
    source: str = ""
    range: tuple[float | None, float | None] | None = None
    choices: tuple[str, ...] | None = None


def packaged_config_dir() -> Path:
    """Folder of the configs shipped with the package.

    Installed (wheel or editable) they are the package ``mavastsm.configs``. When ``mavastsm`` is
    imported straight from a source checkout (e.g. ``python -m mavastsm.cli`` run in the repo root,
    which puts the source folder ahead of site-packages) that package does not exist there: the
    configs are the checkout's top-level ``configs/`` folder beside ``mavastsm/``.
    """
    try:
        return Path(str(resources.files("mavastsm.configs")))
    except ModuleNotFoundError:
        checkout = Path(__file__).resolve().parent.parent / "configs"
        if checkout.is_dir():
            return checkout
        raise ConfigError("packaged configs not found: mavastsm.configs is missing from this installation") from None


def resolve_config(name_or_path: str | Path, folder: str = "") -> Path:
    """Find a config file: an existing path as given, else ``<packaged configs>/<folder>/<name>[.yaml]``.

    Raises ConfigError naming what was looked for and listing the packaged choices.
    """
    candidate = Path(name_or_path)
    if candidate.is_file():
        return candidate
    base = packaged_config_dir() / folder
    for name in (str(name_or_path), f"{name_or_path}.yaml"):
        p = base / name
        if p.is_file():
            return p
    available = sorted(p.stem for p in base.glob("*.yaml")) if base.is_dir() else []
    hint = f"; packaged {folder or 'configs'}: {', '.join(available)}" if available else ""
    raise ConfigError(f"{name_or_path}: no such file or packaged config{hint}")


#: PyYAML's libyaml-based safe loader when available: parsing the packaged configs dominated setting up a batch of
#: the offline simulator or a sweep chunk (bridge.yaml alone took 0.2 s). Malformed YAML is re-parsed by the pure-Python
#: SafeLoader so the error message (problem, line, column) stays the same.
_FAST_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def read_yaml(path: str | Path) -> dict:
    """Parse a YAML file into a mapping; ConfigError (one line) when missing or malformed."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        try:  # libyaml when PyYAML has it (about 10x faster; the same data), PyYAML's own parser for the error message
            data = yaml.load(text, Loader=_FAST_LOADER)
        except yaml.YAMLError:
            data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise ConfigError(f"{path}: malformed YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping of sections, got {type(data).__name__}")
    return data


# where a base named by ``extends:`` is looked up when it is not next to the file: controller presets, sim profiles
EXTENDS_FOLDERS = ("controllers", "sim_profiles")


def _base_path(path: Path, name: Any) -> Path:
    """The file ``extends: name`` in ``path`` names: next to ``path``, else a packaged controller preset or sim
    profile."""
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"{path}: key 'extends' = {name!r} breaks rule: must be a preset name")
    for candidate in (path.parent / name, path.parent / f"{name}.yaml"):
        if candidate.is_file():
            return candidate
    for folder in EXTENDS_FOLDERS:
        candidate = packaged_config_dir() / folder / f"{name.removesuffix('.yaml')}.yaml"
        if candidate.is_file():
            return candidate
    packaged = {folder: sorted(p.stem for p in (packaged_config_dir() / folder).glob("*.yaml")) for folder in EXTENDS_FOLDERS}
    known = "; ".join(f"packaged {folder}: {', '.join(names)}" for folder, names in packaged.items())
    raise ConfigError(f"{path}: key 'extends' = {name!r} names no preset next to it nor packaged ({known})")


def _merge_delta(path: Path, base_name: str, base: dict, delta: dict) -> dict:
    """``base`` with the sections and spec fields of ``delta`` laid over it; every key must exist in the base."""
    merged = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for section, body in delta.items():
        if section == "description":
            merged[section] = body
            continue
        if section not in base or not isinstance(base[section], dict):
            raise ConfigError(f"{path}: section '{section}' is not in base '{base_name}'; a delta may only change what its base has")
        if not isinstance(body, dict):
            raise ConfigError(f"{path}: section '{section}' must be a mapping of parameters")
        for key, spec in body.items():
            if key not in base[section]:
                raise ConfigError(f"{path}: key '{section}.{key}' is not in base '{base_name}'; known: {', '.join(base[section])}")
            if not isinstance(spec, dict):
                raise ConfigError(f"{path}: key '{section}.{key}' breaks rule: a delta gives a mapping of spec fields (e.g. value)")
            unknown = set(spec) - _SPEC_KEYS
            if unknown:
                raise ConfigError(f"{path}: key '{section}.{key}' has unknown spec field(s) {sorted(unknown)}; allowed {sorted(_SPEC_KEYS)}")
            base_spec = base[section][key]
            merged[section][key] = {**base_spec, **spec} if isinstance(base_spec, dict) else dict(spec)
    return merged


def config_bases(path: str | Path) -> list[Path]:
    """The chain of files ``path`` extends, nearest first ([] when it extends nothing); ConfigError as read_config."""
    chain: list[Path] = []
    current = Path(path)
    data = read_yaml(current)
    seen = [current.resolve()]
    while "extends" in data:
        base = _base_path(current, data["extends"])
        if base.resolve() in seen:
            cycle = " -> ".join(p.stem for p in [*seen, base.resolve()])
            raise ConfigError(f"{path}: key 'extends' = {data['extends']!r} makes a cycle ({cycle})")
        seen.append(base.resolve())
        chain.append(base)
        current, data = base, read_yaml(base)
    return chain


def read_config(path: str | Path) -> dict:
    """:func:`read_yaml` with ``extends`` resolved: the mapping the file stands for (no ``extends`` key left)."""
    path = Path(path)
    data = read_yaml(path)
    if "extends" not in data:
        return data
    chain = [path, *config_bases(path)]
    layers = [read_yaml(p) for p in chain]
    merged = layers[-1]
    for child, layer, base in zip(reversed(chain[:-1]), reversed(layers[:-1]), reversed(chain[1:])):
        delta = {k: v for k, v in layer.items() if k != "extends"}
        merged = _merge_delta(child, base.stem, merged, delta)
    return merged


def _check_number(path: Path, key: str, x: Any, spec: Mapping) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: must be a number")
    xf = float(x)
    if not math.isfinite(xf):
        raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: must be finite")
    rng = spec.get("range")
    if rng is not None:
        lo, hi = rng
        strict = bool(spec.get("exclusive_min", False))
        if lo is not None and (xf <= lo if strict else xf < lo):
            rule = f"must be > {lo}" if strict else f"must be >= {lo}"
            raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: {rule} (range {list(rng)})")
        if hi is not None and xf > hi:
            raise ConfigError(f"{path}: key '{key}' = {x!r} breaks rule: must be <= {hi} (range {list(rng)})")
    return xf


def parse_parameter(path: Path, key: str, spec: Any) -> Parameter:
    """Validate one parameter spec (see module docstring) and return it."""
    if not isinstance(spec, dict) or "value" not in spec:
        raise ConfigError(f"{path}: key '{key}' breaks rule: must be a mapping with 'value' and 'unit'")
    unknown = set(spec) - _SPEC_KEYS
    if unknown:
        raise ConfigError(f"{path}: key '{key}' has unknown spec field(s) {sorted(unknown)}; allowed {sorted(_SPEC_KEYS)}")
    if "unit" not in spec:
        raise ConfigError(f"{path}: key '{key}' breaks rule: every parameter must state its 'unit' ('-' if none)")
    rng = spec.get("range")
    if rng is not None and not (isinstance(rng, list) and len(rng) == 2):
        raise ConfigError(f"{path}: key '{key}' range {rng!r} breaks rule: must be [min, max]")
    value = spec["value"]
    choices = spec.get("choices")
    if isinstance(value, str) or choices is not None:
        if choices is not None and value not in choices:
            raise ConfigError(f"{path}: key '{key}' = {value!r} breaks rule: must be one of {list(choices)}")
        parsed: Any = value
    elif isinstance(value, bool):
        parsed = value
    elif isinstance(value, list):
        if not value:
            raise ConfigError(f"{path}: key '{key}' = [] breaks rule: must not be empty")
        parsed = tuple(_check_number(path, key, x, spec) for x in value)
    else:
        parsed = _check_number(path, key, value, spec)
    return Parameter(
        key=key,
        value=parsed,
        unit=str(spec["unit"]),
        symbol=str(spec.get("symbol", "")),
        doc=str(spec.get("doc", "")),
        source=str(spec.get("source", "")),
        range=tuple(rng) if rng is not None else None,
        choices=tuple(choices) if choices is not None else None,
    )


def load_section(path: str | Path, section: str) -> dict[str, Parameter]:
    """Load and validate every parameter of one section of a config file."""
    path = Path(path)
    data = read_config(path)
    if section not in data:
        raise ConfigError(f"{path}: missing section '{section}' (found: {', '.join(k for k in data if k != 'description')})")
    body = data[section]
    if not isinstance(body, dict):
        raise ConfigError(f"{path}: section '{section}' must be a mapping of parameters")
    return {str(k): parse_parameter(path, f"{section}.{k}", v) for k, v in body.items()}


def per_axis(value: Any) -> tuple[float, float, float]:
    """A value given once for all three axes or once per axis [roll, pitch, yaw], as a 3-tuple of floats
    (the same rule as a scalar YAML value for a 3-tuple key)."""
    return tuple(float(x) for x in np.broadcast_to(np.asarray(value, dtype=float), (3,)))  # type: ignore[return-value]


def _coerce(path: Path, key: str, value: Any, annotation: Any) -> Any:
    """Coerce a parsed value to the dataclass field type (float, int, bool, str, tuple[float, ...])."""
    ann = str(annotation)
    if "tuple" in ann:
        if not isinstance(value, tuple):
            if "float" in ann and isinstance(value, float):
                return (value, value, value)  # a scalar applies to all three axes
            raise ConfigError(f"{path}: key '{key}' = {value!r} breaks rule: must be a list of numbers")
        if ann.count("float") >= 2 and "..." not in ann and len(value) != ann.count("float"):
            raise ConfigError(f"{path}: key '{key}' = {list(value)!r} breaks rule: needs {ann.count('float')} values")
        return value
    if ann in ("float", "<class 'float'>"):
        if not isinstance(value, float):
            raise ConfigError(f"{path}: key '{key}' = {value!r} breaks rule: must be a single number")
        return value
    if ann in ("int", "<class 'int'>"):
        if not isinstance(value, float) or value != int(value):
            raise ConfigError(f"{path}: key '{key}' = {value!r} breaks rule: must be an integer")
        return int(value)
    if ann in ("bool", "<class 'bool'>"):
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: key '{key}' = {value!r} breaks rule: must be true or false")
        return value
    if ann in ("str", "<class 'str'>"):
        if not isinstance(value, str):
            raise ConfigError(f"{path}: key '{key}' = {value!r} breaks rule: must be a string")
        return value
    return value


T = typing.TypeVar("T")


def build_dataclass(cls: type[T], path: str | Path, section: str, overrides: Mapping[str, Any] | None = None) -> T:
    """Load ``section`` of ``path`` into dataclass ``cls`` (field names == YAML keys).

    ``overrides`` maps field name -> raw value (e.g. from ``--set mu=0.03``); overrides are
    validated against the same spec (range, choices) as the file's value.

    After construction, ``cls.validate(self)`` (if defined) may return a list of
    ``(key, rule)`` violations of cross-field conditions; each becomes a ConfigError.
    """
    path = Path(path)
    data = read_config(path)
    if section not in data or not isinstance(data[section], dict):
        raise ConfigError(f"{path}: missing section '{section}'")
    raw = dict(data[section])
    for k, v in (overrides or {}).items():
        if k not in raw:
            raise ConfigError(f"{path}: override '{section}.{k}' names no parameter; known: {', '.join(raw)}")
        raw[k] = {**raw[k], "value": v} if isinstance(raw[k], dict) else raw[k]
    params = {str(k): parse_parameter(path, f"{section}.{k}", v) for k, v in raw.items()}
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(params) - set(fields))
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {', '.join(f'{section}.{u}' for u in unknown)}; expected {', '.join(fields)}")
    kwargs = {}
    for name, f in fields.items():
        if name not in params:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:  # type: ignore[misc]
                raise ConfigError(f"{path}: missing key '{section}.{name}'")
            continue
        kwargs[name] = _coerce(path, f"{section}.{name}", params[name].value, hints.get(name, f.type))
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        problems = validate()
        if problems:
            key, rule = problems[0]
            value = getattr(obj, key, "?")
            raise ConfigError(f"{path}: key '{section}.{key}' = {value!r} breaks rule: {rule}")
    return obj


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """Parse CLI ``--set key=value`` items (value parsed as YAML: numbers, lists, strings)."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = yaml.safe_load(v)
        except yaml.YAMLError:
            raise ConfigError(f"--set {item!r}: value is not valid YAML") from None
    return out
