"""Same seeds, same table, whatever the executor: a small sweep on local processes and on a real Dask LocalCluster
(scheduler + two worker processes) writes byte-identical tables."""

from __future__ import annotations

import pytest

from mavastsm.sweep.engine import run_sweep
from mavastsm.sweep.executors import make_executor
from mavastsm.sweep.spec import load_sweep


def test_local_processes_and_dask_local_cluster_give_identical_tables(tmp_path):
    pytest.importorskip("distributed")
    p = tmp_path / "s.yaml"
    p.write_text("sweep:\n  controllers: [astsm, pid_fair]\n  duration_s: 2.0\n  chunk_runs: 3\n  seed: 5\n  variables:\n"
                 "    disturbance_pitch_nm: {grid: [0.0, 1.0]}\n    disturbance_start_s: {grid: [1.2]}\n"
                 "    sensor_noise_scale: {uniform: [0.0, 2.0]}\n", encoding="utf-8")
    spec = load_sweep(p)
    with make_executor(workers=2) as (ex, where):
        assert where.startswith("local processes")
        local = run_sweep(spec, "offline", tmp_path / "local", ex)
    with make_executor(dask_local=2) as (ex, where):
        assert "LocalCluster" in where
        dask = run_sweep(spec, "offline", tmp_path / "dask", ex)
    assert local.ran == dask.ran == 4
    assert (tmp_path / "local" / "table.csv").read_bytes() == (tmp_path / "dask" / "table.csv").read_bytes()
