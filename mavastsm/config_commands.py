"""``mavastsm check-config FILE`` and ``mavastsm list-controllers``."""

from __future__ import annotations

import argparse

from rich.markup import escape
from rich.table import Table

from .config_loading import config_bases, load_section, read_config, read_yaml, resolve_config
from .console_output import report_console
from .errors import ConfigError
from .frames import AXES


def configure_check_config(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="config file path, or a packaged name such as vehicle/solo, controllers/astsm, scenarios/disturbance, references/paper_steps, sim_profiles/arducopter-4.7-sitl")
    from .control import LAW_HELP

    parser.add_argument("--controller", default=None, metavar="NAME",
                        help=f"for a controller file: the law it is for, {LAW_HELP} (default: from the file name, else "
                             "the registered or installed law whose default preset has the most keys in common with it)")


BRIDGE_SECTIONS = ("link", "timing", "mapping", "thrust", "limits", "presets")  # = bridge_config.SECTIONS (tests/unit/test_check_config_matches_commands.py)
VEHICLE_SECTIONS = ("rigid_body", "offboard_loop", "autopilot_tuning", "propulsion", "airframe", "battery", "sensor_noise", "autopilot")


def _controller_for(path, data: dict, requested: str | None) -> str:
    """Which law a controller file is for: ``requested`` (any name ``law_class`` takes); the longest registered or
    installed name its file name starts with (astsm_paper -> astsm); else the law whose default preset shares the
    most gain keys with it."""
    from .control import CONTROLLERS, installed_laws, law_class, law_preset

    if requested is not None:
        law_class(requested)
        return requested
    names = [*CONTROLLERS, *installed_laws()]
    stem = path.stem
    by_name = [k for k in names if stem == k or stem.startswith(k + "_")]
    if by_name:
        return max(by_name, key=len)
    keys = set(data.get("gains") or {})
    return max(names, key=lambda k: len(keys & set(read_config(resolve_config(law_preset(law_class(k)), "controllers")).get("gains", {}))))


def validate_config_file(path, data: dict, controller: str | None = None) -> str:
    """Run on ``path`` exactly the loaders the commands run on a file of its kind; returns what it was checked as.
    ConfigError (one line: file, key, value, rule) on the first problem, as ``connect``, ``simulate`` and ``sim`` give.

    Kinds, from the top-level sections: a bridge config (``connect --set`` targets; every section required), a
    vehicle description (``connect --vehicle``, ``sim --vehicle-config``, offline runs), a controller preset
    (``--controller-config``), a scenario or a reference (``--scenario``, ``--reference``), a sweep (``mavastsm sweep``),
    a sim profile (``sim --profile``).
    A preset that ``extends`` another is checked as what it resolves to (and the ``extends`` chain itself: base, cycle,
    keys)."""
    if "extends" in data:
        data = read_config(path)
    sections = {k for k in data if k != "description"}
    if "sweep" in data:
        from .sweep.spec import load_sweep

        load_sweep(path)
        return "sweep"
    if "scenario" in data:
        from .scenarios import load_scenario

        load_scenario(path)
        return "scenario"
    if "gains" in data:
        extra = sections - {"gains"}
        if extra:
            raise ConfigError(f"{path}: unknown section(s) {', '.join(sorted(extra))} in a controller preset; expected gains")
        from .control import make_controller
        from .solo_model import load_solo

        name = _controller_for(path, data, controller)
        make_controller(name, load_solo(), config=path)
        return f"controller preset for {name}"
    if sections & set(BRIDGE_SECTIONS):
        extra = sections - set(BRIDGE_SECTIONS)
        if extra:
            raise ConfigError(f"{path}: unknown section(s) {', '.join(sorted(extra))} in a bridge config; expected {', '.join(BRIDGE_SECTIONS)}")
        from .bridge.bridge_config import load_bridge_config

        load_bridge_config(path)
        return "bridge config"
    if sections & set(VEHICLE_SECTIONS):
        extra = sections - set(VEHICLE_SECTIONS)
        if extra:
            raise ConfigError(f"{path}: unknown section(s) {', '.join(sorted(extra))} in a vehicle description; expected {', '.join(VEHICLE_SECTIONS)}")
        from mavastsm_sim.vehicle_config import load_vehicle_config

        from .solo_model import load_autopilot_tuning, load_offboard_loop, load_solo

        load_solo(path)
        load_offboard_loop(path)
        load_autopilot_tuning(path)
        if sections & {"propulsion", "airframe", "battery"}:
            load_vehicle_config(path)  # the simulated vehicle's physics (mavastsm sim --vehicle-config)
        return "vehicle description"
    if "habits" in data:
        from mavastsm_sim.arducopter_profile import load_profile

        load_profile(path)
        return "sim profile (mavastsm sim --profile)"
    if "components" in data or "reference" in data:
        from .references import load_reference

        load_reference(path)
        return "reference"
    raise ConfigError(f"{path}: not a mavastsm config (top-level sections {', '.join(sorted(sections)) or 'none'}; expected a "
                      f"bridge config, vehicle description, controller preset, scenario, reference, sweep or sim profile)")


def _print_scenario_or_reference(console, path, data: dict) -> None:
    """Scenarios and references use event lists (units in key names), not parameter specs."""
    import numpy as np

    from .references import load_reference
    from .scenarios import load_scenario

    if "scenario" in data:
        scn = load_scenario(path)
        ref = scn.reference
        console.print(f"scenario {scn.name}: {scn.duration_s:g} s, reference {ref.name}, inertia variation {scn.inertia_mode}, "
                      f"payload {scn.payload_mass_kg:g} kg")
        for ev in scn.disturbances:
            end = "end" if ev.end_s == float("inf") else f"{ev.end_s:g} s"
            console.print(f"  disturbance {list(ev.torque_nm)} N m (body FRD) from {ev.start_s:g} s to {end}")
    else:
        ref = load_reference(path)
        console.print(f"reference {ref.name}: {ref.duration_s:g} s, prefilter wn {ref.prefilter_wn_rads:g} rad/s")
    table = Table(title="reference components", title_justify="left")
    for col in ("axis", "type", "start [s]", "end [s]", "angle / amplitude [deg]", "frequency [Hz]"):
        table.add_column(col)
    for c in ref.components:
        end = f"{c.end_s:g}" if c.kind == "ramp" else ""
        freq = f"{c.frequency_hz:g}" if c.kind == "sine" else ""
        table.add_row(AXES[c.axis], c.kind, f"{c.start_s:g}", end, f"{np.degrees(c.angle_rad):g}", freq)
    console.print(table)


def _print_sweep(console, path) -> None:
    """The swept variables with unit, range, levels and values, and the run count (docs/sweep.md)."""
    from .sweep.spec import VARIABLES, load_sweep

    spec = load_sweep(path)
    table = Table(title=f"sweep: {len(spec.runs())} runs of {', '.join(c.label for c in spec.controllers)} on {spec.scenario}",
                  title_justify="left")
    for col in ("variable", "values", "range", "levels", "meaning"):
        table.add_column(col)
    for name, (kind, *args) in spec.variables.items():
        var = VARIABLES[name]
        values = ", ".join(f"{v:g}" for v in args[0]) if kind == "grid" else f"{kind}({args[0]:g}, {args[1]:g})"
        table.add_row(name, values, f"[{var.lo:g}, {var.hi:g}]", ", ".join(var.levels), var.doc)
    console.print(table)


def run_check_config(args: argparse.Namespace) -> int:
    path = resolve_config(args.file)
    own = read_yaml(path)
    kind = validate_config_file(path, own, args.controller)  # before printing anything: ConfigError -> one line, exit 2
    data = read_config(path)  # a delta (extends) shows its resolved values
    console = report_console()
    console.print(f"[bold]{path}[/]")
    bases = config_bases(path)
    if bases:
        console.print(f"extends {' -> '.join(str(b) for b in bases)}: resolved values; * marks a key this file sets")
    if isinstance(data.get("description"), str):
        console.print(data["description"].strip())
    if "sweep" in data:
        _print_sweep(console, path)
        console.print(f"[green]valid[/] {kind}")
        return 0
    if "scenario" in data or "reference" in data:
        _print_scenario_or_reference(console, path, data)
        console.print(f"[green]valid[/] {kind}")
        return 0
    for section, body in data.items():
        if section == "description" or not isinstance(body, dict):
            continue
        params = load_section(path, section)
        table = Table(title=section, title_justify="left")
        for col in ("key", "value", "unit", "symbol", "range / choices", "meaning"):
            table.add_column(col)
        for p in params.values():
            allowed = str(list(p.range)) if p.range else (", ".join(p.choices) if p.choices else "")
            value = ", ".join(f"{v:g}" for v in p.value) if isinstance(p.value, tuple) else (f"{p.value:g}" if isinstance(p.value, float) else str(p.value))
            key = p.key.split(".", 1)[1]
            mark = " *" if bases and key in (own.get(section) or {}) else ""
            table.add_row(key + mark, value, p.unit, p.symbol, allowed, p.doc)
        console.print(table)
    console.print(f"[green]valid[/] {kind}")
    return 0


def configure_list_controllers(parser: argparse.ArgumentParser) -> None:
    pass


def run_list_controllers(args: argparse.Namespace) -> int:
    """The packaged laws, then those installed distributions register (entry-point group mavastsm.controllers)."""
    from .control import CONTROLLERS, ENTRY_POINT_GROUP, installed_laws, law_class, law_preset

    table = Table(title="registered attitude controllers", caption=f"installed: entry-point group {ENTRY_POINT_GROUP}; "
                  "your own: --controller MODULE:CLASS or FILE.py:CLASS (docs/controllers.md)")
    for col in ("key", "law", "default config"):
        table.add_column(col)
    for key, cls in CONTROLLERS.items():
        table.add_row(key, cls.summary, f"controllers/{cls.default_config}")
    for key, entry in installed_laws().items():
        try:
            cls = law_class(key)
            table.add_row(key, f"{getattr(cls, 'summary', '')} (installed: {entry.value})", str(law_preset(cls)))
        except ConfigError as exc:  # one broken installed law does not hide the others
            table.add_row(key, f"[red]{escape(str(exc))}[/]", "")
    report_console().print(table)
    return 0
