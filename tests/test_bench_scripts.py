"""``mavastsm bench`` runs scripts from the repository's ``benchmarks/`` folder: in a source checkout it must find
them (a stale path once made ``bench --quick`` report ``.../mavastsm/benchmarks/sim_realtime_factor.py not found``)."""

from __future__ import annotations

from pathlib import Path

from mavastsm import bench

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_bench_finds_the_simulator_benchmark_script_of_the_source_checkout():
    assert bench.SOURCE_BENCHMARKS_DIR == REPO_ROOT / "benchmarks"
    assert bench.SIM_RTF_SCRIPT.is_file(), bench.SIM_RTF_SCRIPT


def test_every_benchmark_script_the_bench_names_exists():
    named = [value for value in vars(bench).values() if isinstance(value, Path) and value.suffix == ".py"]
    assert named, "the bench names no benchmark script"
    assert all(path.is_file() for path in named), [str(p) for p in named if not p.is_file()]
