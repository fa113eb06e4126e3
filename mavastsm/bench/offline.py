"""Offline-simulator benchmarks for ``mavastsm bench``: ``reproduce`` wall time and throughput.

Throughput = simulated seconds per wall second of helper A's batched RK4 simulator
(``mavastsm.offline.simulator.simulate_runs``) with ASTSM on the nominal scenario at the default
1 ms controller period: one run alone, and ``batch`` identical runs integrated as one batch
(simulated seconds summed over the runs).
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import tempfile
import time


def offline_throughput(sim_seconds: float, batch: int) -> tuple[float, float]:
    """(single-run, batched) throughput [simulated s / wall s] over ``sim_seconds`` of the nominal scenario."""
    from ..offline.simulator import RunSpec, simulate_runs
    from ..scenarios import load_scenario

    scenario = dataclasses.replace(load_scenario("nominal"), duration_s=float(sim_seconds))
    simulate_runs([RunSpec("astsm", scenario)])  # warm-up: imports, config loading, first allocation
    t0 = time.perf_counter()
    (single,) = simulate_runs([RunSpec("astsm", scenario)])
    t1 = time.perf_counter()
    runs = simulate_runs([RunSpec("astsm", scenario) for _ in range(batch)])
    t2 = time.perf_counter()
    span = float(single.t_s[-1] - single.t_s[0]) + single.dt_s
    return span / (t1 - t0), batch * span / (t2 - t1) if len(runs) == batch else float("nan")


def reproduce_wall_time(timeout_s: float = 600.0) -> float:
    """[s] wall time of ``mavastsm reproduce`` as a user runs it (a fresh process, output to a temp dir)."""
    with tempfile.TemporaryDirectory(prefix="mavastsm-bench-reproduce-") as out:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "mavastsm.cli", "reproduce", "--out", out],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=timeout_s)
        wall = time.perf_counter() - t0
    if proc.returncode != 0:
        tail = " | ".join(proc.stdout.strip().splitlines()[-2:])
        raise RuntimeError(f"mavastsm reproduce exited {proc.returncode}: {tail}")
    return wall
