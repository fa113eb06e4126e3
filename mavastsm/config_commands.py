"""``mavastsm check-config FILE`` and ``mavastsm list-controllers``."""

from __future__ import annotations

import argparse

from rich.console import Console
from rich.table import Table

from .config_loading import load_section, read_yaml, resolve_config


def configure_check_config(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="config file path, or a packaged name such as vehicle/solo, controllers/astsm, scenarios/disturbance, references/paper_steps")


def _print_scenario_or_reference(console: Console, path, data: dict) -> None:
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
        table.add_row(("roll", "pitch", "yaw")[c.axis], c.kind, f"{c.start_s:g}", end, f"{np.degrees(c.angle_rad):g}", freq)
    console.print(table)


def run_check_config(args: argparse.Namespace) -> int:
    path = resolve_config(args.file)
    data = read_yaml(path)
    console = Console()
    console.print(f"[bold]{path}[/]")
    if isinstance(data.get("description"), str):
        console.print(data["description"].strip())
    if "scenario" in data or "reference" in data:
        _print_scenario_or_reference(console, path, data)
        console.print("[green]valid[/]")
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
            table.add_row(p.key.split(".", 1)[1], value, p.unit, p.symbol, allowed, p.doc)
        console.print(table)
    console.print("[green]valid[/]")
    return 0


def configure_list_controllers(parser: argparse.ArgumentParser) -> None:
    pass


def run_list_controllers(args: argparse.Namespace) -> int:
    from .control import CONTROLLERS

    table = Table(title="registered attitude controllers")
    for col in ("key", "law", "default config"):
        table.add_column(col)
    for key, cls in CONTROLLERS.items():
        table.add_row(key, getattr(cls, "summary", (cls.__doc__ or "").strip().splitlines()[0]), f"controllers/{cls.default_config}")
    Console().print(table)
    return 0
