"""``mavastsm simulate`` and ``mavastsm reproduce`` (composition only: parse, build, run, print, write)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ..config_loading import parse_overrides, resolve_config
from ..console_output import report_console
from ..control import LAW_HELP, law_class, law_preset, split_law_and_preset
from ..errors import ConfigError
from ..scenarios import load_scenario
from ..solo_model import load_solo
from .claims import evaluate_claims
from .figures import INSTALL_HINT, matplotlib_available, plot_runs
from .metrics import compute_metrics
from .reproduction import DEFAULT_MODES, DEFAULT_PAPER_PERIOD_S, plan_modes, run_plans
from .reproduction_report import reproduction_markdown
from .report import (
    claims_rich_table,
    metrics_rich_tables,
    write_claims_csv,
    write_metrics_csv,
    write_timeseries_csv,
)
from .simulator import RunSpec, simulate_runs


def _positive_ms(name: str, value: float) -> float:
    if not (value == value and value > 0 and value != float("inf")):
        raise ConfigError(f"--{name} = {value!r} breaks rule: must be a time > 0 ms")
    return value * 1e-3


def _progress(console: Console) -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(),
                    console=console, transient=False)


# ---------------------------------------------------------------------------------------------- simulate
def configure_simulate(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--controller", default="astsm",
                        help="comma-separated controllers, each optionally with :PRESET (astsm:astsm_paper,pid,"
                             f"my_laws:PdController:pd_soft.yaml); a controller is {LAW_HELP}")
    parser.add_argument("--scenario", default="nominal", help="packaged scenario name (nominal, disturbance, variation, ...) or YAML path")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", help="controller parameter override (repeatable), validated against the YAML")
    parser.add_argument("--dt-ms", type=float, default=1.0, help="controller period T [ms] (ZOH), default 1.0; 2.5 = ArduCopter 400 Hz")
    parser.add_argument("--substep-ms", type=float, default=0.25, help="largest RK4 step of the plant [ms], default 0.25")
    parser.add_argument("--inertia", choices=("corrected", "paper_literal"), default="corrected", help="Table 1 Iyy variant (default corrected = 15.5e-3)")
    parser.add_argument("--paper-kinematics", action="store_true", help="plant uses the paper's Theta_dot = omega instead of exact ZYX kinematics")
    parser.add_argument("--csv", type=Path, help="write the time histories (2 ms rows) to this CSV")
    parser.add_argument("--plot", type=Path, help="write a PNG of angles and torques (needs matplotlib)")


def run_simulate(args: argparse.Namespace) -> int:
    console = report_console()
    dt = _positive_ms("dt-ms", args.dt_ms)
    sub = _positive_ms("substep-ms", args.substep_ms)
    scenario = load_scenario(args.scenario)
    overrides = parse_overrides(args.set) or None
    specs = []
    for item in [s.strip() for s in args.controller.split(",") if s.strip()]:
        key, preset = split_law_and_preset(item)
        law = law_class(key)  # an unknown law or a missing preset: one line before anything runs
        if preset:
            resolve_config(preset, "controllers")
        else:
            law_preset(law)
        specs.append(RunSpec(key, scenario, config=preset or None, overrides=overrides, inertia_variant=args.inertia))
    if not specs:
        raise ConfigError("--controller: give at least one controller key")
    for spec in specs:  # known failure modes of ASTSM presets at this sample period: say so before running
        if spec.controller == "astsm":
            from ..control import make_controller
            from ..control.astsm import sampling_warnings

            gains = make_controller("astsm", load_solo(inertia_variant=args.inertia), spec.config, spec.overrides).gains
            for w in sampling_warnings(gains, dt):
                console.print(f"[yellow]warning: {escape(spec.display)}: {escape(w)}[/]")
    if args.plot and not matplotlib_available():  # asked for a figure that cannot be made: say so before running
        raise ConfigError(f"--plot {args.plot}: needs matplotlib ({INSTALL_HINT})")
    t0 = time.perf_counter()
    with _progress(Console(stderr=True)) as prog:
        task = prog.add_task(f"simulating {scenario.name} ({len(specs)} run(s), T = {args.dt_ms:g} ms)", total=1.0)
        runs = simulate_runs(specs, dt, sub, exact_kinematics=not args.paper_kinematics, progress=lambda f: prog.update(task, completed=f))
    wall = time.perf_counter() - t0
    for r in runs:
        r.metrics = compute_metrics(r)
    for table in metrics_rich_tables(runs, f"{escape(scenario.name)}: T = {args.dt_ms:g} ms, inertia {args.inertia}, "
                                           f"{'paper' if args.paper_kinematics else 'exact ZYX'} kinematics"):
        console.print(table)
    for r in runs:
        if r.nonfinite_outputs or r.diverged_at_s == r.diverged_at_s:
            console.print(f"[red]{escape(r.spec.display)}: diverged at {r.diverged_at_s:.3f} s, {r.nonfinite_outputs} non-finite outputs replaced by 0[/]")
    console.print(f"simulated {scenario.duration_s * len(runs):.1f} s of flight in {wall:.2f} s wall")
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        write_timeseries_csv(args.csv, runs)
        console.print(f"wrote {args.csv}")
    if args.plot and matplotlib_available():
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot_runs(runs, args.plot, f"{scenario.name}, T = {args.dt_ms:g} ms")
        console.print(f"wrote {args.plot}")
    return 0


# --------------------------------------------------------------------------------------------- reproduce
def configure_reproduce(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out-dir", "--out", dest="out", type=Path, default=Path("out/reproduce"),
                        help="output folder (CSV, PNG, report.md); default out/reproduce (--out: the older spelling)")
    parser.add_argument("--modes", default=",".join(DEFAULT_MODES), help="comma-separated from P (paper-faithful), E1 (1 kHz), E2 (400 Hz); default P,E1")
    parser.add_argument("--paper-period-ms", type=float, default=DEFAULT_PAPER_PERIOD_S * 1e3, help="controller period of mode P [ms], default 0.5")
    parser.add_argument("--workers", type=int, choices=(1, 2), default=2,
                        help="processes, 1 or 2 (the heaviest batch runs in a second process); default 2")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    parser.add_argument("--docs", type=Path, help="also copy the markdown report here (e.g. docs/reproduction.md)")


def run_reproduce(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    console = report_console()
    modes = tuple(m.strip() for m in args.modes.split(",") if m.strip())
    bad = [m for m in modes if m not in ("P", "E1", "E2")]
    if bad or not modes:
        raise ConfigError(f"--modes {args.modes!r}: unknown mode(s) {bad}; choose from P, E1, E2")
    period = _positive_ms("paper-period-ms", args.paper_period_ms)
    plans = plan_modes(modes, period)
    n_runs = sum(len(p.specs) + len(p.sweep_specs) for p in plans)
    console.print(f"reproduce: {n_runs} runs in {len(plans)} batch(es) ({', '.join(p.name for p in plans)}), {args.workers if len(plans) >= 2 else 1} process(es)")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    plotting = not args.no_plots and matplotlib_available()
    if not args.no_plots and not plotting:
        console.print(f"[yellow]no figures: {escape(INSTALL_HINT)}[/]")
    for p in plans:  # whole lines, also when piped (a progress bar's description is cut to the terminal's width)
        console.print(f"mode {p.name:<2} {p.description}", highlight=False, soft_wrap=True)
    with _progress(Console(stderr=True)) as prog:
        tasks = {p.name: prog.add_task(f"mode {p.name:<2}", total=1.0) for p in plans}
        results = run_plans(plans, workers=args.workers, progress=lambda name, f: prog.update(tasks[name], completed=f),
                            figures_dir=(out / "figures") if plotting else None)
    figures = [out / "figures" / f for r in results for f in r.figures]
    sim_wall = time.perf_counter() - t0  # simulation, metrics and (in the lanes) figures
    solo = load_solo()
    claims = {r.name: evaluate_claims(r, solo.inertia_diag) for r in results}

    for r in results:
        shown = [run for (lab, scn, var), run in r.runs.items() if var == "corrected"]
        for table in metrics_rich_tables(shown, f"mode {r.name}: T = {r.dt_s * 1e3:g} ms, ASTSM preset {r.astsm_preset}, corrected inertia"):
            console.print(table)
        console.print(claims_rich_table(r, claims[r.name]))

    files = [
        write_metrics_csv(out / "metrics.csv", [(r.name, run) for r in results for run in list(r.runs.values()) + r.sweep]),
        write_claims_csv(out / "claims.csv", [(name, c) for name, cs in claims.items() for c in cs]),
    ]
    for r in results:
        files.append(write_timeseries_csv(out / f"timeseries_{r.name}.csv", [run for (_, _, var), run in r.runs.items() if var == "corrected"]))
    wall = time.perf_counter() - t0
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    command = "mavastsm reproduce " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["reproduce"] else "mavastsm reproduce"
    md = reproduction_markdown(results, claims, solo, wall_s=wall, sim_wall_s=sim_wall, load_avg=load, command=command,
                               figures=[f.name for f in figures], workers=args.workers)
    report = out / "report.md"
    report.write_text(md, encoding="utf-8")
    files.append(report)
    if args.docs:
        args.docs.parent.mkdir(parents=True, exist_ok=True)
        if args.docs.resolve() != report.resolve():
            shutil.copyfile(report, args.docs)
        figdir = args.docs.parent / "figures"
        if figures:
            figdir.mkdir(exist_ok=True)
            for f in figures:
                shutil.copyfile(f, figdir / f.name)
        files.append(args.docs)
    passed = {name: sum(c.passed is True for c in cs) for name, cs in claims.items()}
    console.print("claims passed: " + ", ".join(f"mode {n}: {k}/{len(claims[n])}" for n, k in passed.items()))
    console.print(f"wrote {len(files)} files and {len(figures)} figures to {out}; wall time {wall:.1f} s "
                  f"(simulation + figures {sim_wall:.1f} s, 1-min load average {load:.1f})")
    return 0
