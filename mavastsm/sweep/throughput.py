"""Sweep speed for ``mavastsm bench``: offline simulated seconds per wall second (ASTSM + plant at 1 kHz, every core,
simulation and metrics) and MAVLink-level runs per minute (one bridge + sim pair per core)."""

from __future__ import annotations

import math
import os
import tempfile
import time
from pathlib import Path


def _spec(folder: Path, runs: int, duration_s: float, chunk_runs: int):
    from .spec import load_sweep

    side = max(1, int(round(runs ** 0.5)))
    xs = [round(2.5 * i / max(side - 1, 1), 6) for i in range(side)]
    ys = [round(2.0 * j / max(-(-runs // side) - 1, 1), 6) for j in range(-(-runs // side))]
    path = folder / "bench_sweep.yaml"
    path.write_text(
        "sweep:\n  controllers: [astsm]\n  scenario: nominal\n"
        f"  duration_s: {duration_s}\n  chunk_runs: {chunk_runs}\n  variables:\n"
        f"    disturbance_roll_nm: {{grid: {xs}}}\n    inertia_table3_scale: {{grid: {ys}}}\n"
        f"    disturbance_start_s: {{grid: [{min(4.0, 0.6 * duration_s):g}]}}\n", encoding="utf-8")
    return load_sweep(path)


def offline_sweep_throughput(runs: int, duration_s: float, workers: int | None = None) -> dict:
    """Run an ASTSM sweep of about ``runs`` points x ``duration_s`` [s] at 1 kHz on local processes (one chunk per
    worker); {runs, workers, sim_s, wall_s, sim_s_per_wall_s}. Wall time from submission to the last row stored
    (process start-up and imports excluded by a warm-up unit); the table, margins and map written after the last row
    are timed apart (``reports_s``: the default map of a 32 x 32 grid takes about 1.4 s to draw)."""
    from .engine import run_sweep
    from .executors import make_executor
    from .offline_level import run_chunk

    n_workers = workers or os.cpu_count() or 1
    with tempfile.TemporaryDirectory(prefix="mavastsm-bench-sweep-") as tmp:
        folder = Path(tmp)
        probe = _spec(folder, runs, duration_s, 1)
        total = len(probe.runs())
        spec = _spec(folder, runs, duration_s, -(-total // n_workers))
        with make_executor(n_workers) as (ex, _):
            warm = _spec(folder, 2, 1.0, 1)
            list(ex.map(run_chunk, [warm] * n_workers, [warm.runs()[:1]] * n_workers))  # imports in every worker
            stored = [math.nan]

            def on_progress(done: int, total_runs: int) -> None:
                if done == total_runs:  # the last row is on disk (the table, margins and map are written after)
                    stored[0] = time.perf_counter()

            t0 = time.perf_counter()
            report = run_sweep(spec, "offline", folder / "out", ex, progress=on_progress)
            t_end = time.perf_counter()
    wall = stored[0] - t0
    sim_s = report.ran * duration_s
    return {"runs": report.ran, "workers": n_workers, "sim_s": sim_s, "wall_s": round(wall, 2), "sim_s_per_wall_s": round(sim_s / wall, 1),
            "reports_s": round(t_end - stored[0], 2)}


def mavlink_sweep_rate(runs: int, workers: int | None = None) -> dict:
    """Fly ``runs`` MAVLink-level runs of the shipped ``example_mavlink`` sweep (6 s each) with one pair per worker;
    {runs, workers, wall_s, runs_per_min}."""
    from .engine import run_sweep
    from .executors import make_executor
    from .spec import SweepSpec, load_sweep

    n_workers = workers or os.cpu_count() or 1
    base = load_sweep("example_mavlink")
    spec = SweepSpec(**{**base.__dict__, "draws": max(1, -(-runs // len(base.runs())))})
    with tempfile.TemporaryDirectory(prefix="mavastsm-bench-sweep-") as tmp, make_executor(n_workers) as (ex, _):
        t0 = time.perf_counter()
        report = run_sweep(spec, "mavlink", Path(tmp), ex)
        wall = time.perf_counter() - t0
    return {"runs": report.ran, "workers": n_workers, "wall_s": round(wall, 1), "runs_per_min": round(report.ran / wall * 60.0, 1)}
