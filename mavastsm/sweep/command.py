"""``mavastsm sweep SPEC.yaml``: robustness maps over swept disturbances, inertia, noise, loop and link (docs/sweep.md).

Composition only: load the spec, pick the executor, run (resuming), print the margin table and where the outputs are.
Exit status: 0 done, 2 bad spec/option/scheduler (one line), 130 interrupted (what finished is kept; rerun resumes).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..errors import ConfigError
from .spec import LEVELS


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 1")
    return n


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", metavar="SPEC", help="sweep YAML (a path, or a packaged name: example, example_mavlink; docs/sweep.md)")
    parser.add_argument("--level", choices=LEVELS, default="offline",
                        help="offline: torque-level batched simulator; mavlink: the bridge against the simulated Solo, "
                             "one lockstep pair per run (default offline)")
    parser.add_argument("--out-dir", "--out", dest="out", type=Path, default=None, metavar="DIR",
                        help="output folder: table.csv, margins.csv, map PNG, runs.jsonl (default out/sweep/<spec>-<level>); "
                             "rerunning into it resumes")
    parser.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                        help="local worker processes (default: one per core)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="run on this Dask scheduler (needs the cluster extra: pip install \"mavastsm[cluster]\")")
    parser.add_argument("--dask-local", type=_positive_int, default=None, metavar="N",
                        help="run on a Dask LocalCluster with N worker processes (cluster extra)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _fmt(x) -> str:
    if isinstance(x, float):
        return "-" if math.isnan(x) else f"{x:g}"
    return str(x)


def run(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from ..console_output import report_console
    from .engine import run_sweep
    from .executors import make_executor
    from .run_inputs import is_failure
    from .spec import load_sweep

    console = report_console()
    spec = load_sweep(args.spec)
    spec.check_level(args.level)
    out_dir = args.out or Path("out") / "sweep" / f"{Path(spec.path).stem}-{args.level}"
    if args.workers and (args.scheduler or args.dask_local):
        raise ConfigError("--workers applies to local processes; with Dask give the workers to the cluster")
    with make_executor(args.workers, args.scheduler, args.dask_local) as (executor, where):
        n = len(spec.runs())
        console.print(f"sweep {spec.path}: {n} runs at level {args.level} on {where}; output {out_dir}", highlight=False)
        progress = Progress(TextColumn("runs"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console,
                            disable=args.no_progress)
        with progress:
            task = progress.add_task("runs", total=n)
            result = run_sweep(spec, args.level, out_dir, executor, progress=lambda d, t: progress.update(task, completed=d))
    if result.interrupted:
        console.print(f"stopped: {len(result.rows)} of {result.total} runs kept in {result.paths['table']}; "
                      f"rerun the same command to resume", highlight=False)
        return 130
    rate = result.ran / result.wall_s * 60.0 if result.wall_s > 0 else math.nan
    failures = sum(is_failure(r["outcome"]) for r in result.rows)
    console.print(f"{result.ran} runs in {result.wall_s:.1f} s ({rate:.0f} runs/min)"
                  + (f", {result.resumed} resumed from an earlier call" if result.resumed else "")
                  + f"; {failures} of {result.total} failed", highlight=False)
    table = Table(title="margins: largest |value| each controller survives / settles within the bounds")
    for col in ("controller", "variable", "survives_up_to", "settled_up_to", "swept_max", "failures"):
        table.add_column(col, justify="left" if col in ("controller", "variable") else "right")
    for m in result.margins:
        table.add_row(*(_fmt(m[c]) for c in ("controller", "variable", "survives_up_to", "settled_up_to", "swept_max")),
                      f"{m['failures']}/{m['runs']}")
    console.print(table)
    for name, path in result.paths.items():
        console.print(f"{name}: {path}", highlight=False)
    for note in result.notes:
        console.print(note, highlight=False)
    return 0
