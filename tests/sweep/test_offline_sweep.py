"""The offline level: the shipped example gives the table, the margins and the map; a known-unstable corner is a
failure with its reason; an interrupted sweep resumes without redoing finished runs; a run's row does not depend on
the batch it was integrated in."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import pytest

from mavastsm.sweep.engine import run_sweep
from mavastsm.sweep.offline_level import run_chunk
from mavastsm.sweep.spec import load_sweep
from mavastsm.sweep.store import read_table


def test_shipped_example_gives_table_margins_and_map(tmp_path):
    pytest.importorskip("matplotlib")
    from mavastsm.cli import main

    assert main(["sweep", "example", "--out-dir", str(tmp_path), "--workers", "1", "--no-progress"]) == 0
    rows = read_table(tmp_path / "table.csv")
    spec = load_sweep("example")
    assert len(rows) == len(spec.runs()) == 36
    assert {"run_id", "seed", "controller", "outcome", "disturbance_roll_nm", "inertia_table3_scale", "settling_5pct_s_roll",
            "dist_peak_deg_roll", "alpha_peak_roll", "max_tilt_deg"} <= set(rows[0])
    margins = read_table(tmp_path / "margins.csv")
    assert {(m["controller"], m["variable"]) for m in margins} == {(c, v) for c in ("astsm", "pid_fair") for v in spec.variables}
    png = tmp_path / "map_dist_peak_deg_roll.png"
    assert png.is_file() and png.read_bytes()[:4] == b"\x89PNG"


def test_known_unstable_corner_is_a_failure_with_its_reason(tmp_path):
    spec = load_sweep("example")
    with ThreadPoolExecutor(1) as ex:
        report = run_sweep(spec, "offline", tmp_path, ex)
    corner = [r for r in report.rows if r["controller"] == "pid_fair" and r["disturbance_roll_nm"] == 2.5]
    assert corner and all(r["outcome"] == "envelope_breach" for r in corner), [r["outcome"] for r in corner]
    assert all(4.0 < r["failure_time_s"] < 5.0 for r in corner)  # after the torque's onset at 4 s
    nominal = next(r for r in report.rows if r["controller"] == "astsm" and r["disturbance_roll_nm"] == 0 and r["inertia_table3_scale"] == 0)
    assert nominal["outcome"] == "settled" and math.isnan(nominal["failure_time_s"])
    pid = {m["variable"]: m for m in report.margins if m["controller"] == "pid_fair"}
    assert pid["disturbance_roll_nm"]["survives_up_to"] == 1.5  # 2.0 and 2.5 N m leave the envelope


def test_interrupted_sweep_resumes_without_redoing_finished_runs(tmp_path, monkeypatch):
    import mavastsm.sweep.spec as spec_mod

    spec = load_sweep("example")
    spec = spec_mod.SweepSpec(**{**spec.__dict__, "chunk_runs": 8})  # 5 units of work
    calls: list[list[int]] = []
    import mavastsm.sweep.offline_level as level

    real = level.run_chunk

    def counting(s, rows):
        calls.append([r["run_id"] for r in rows])
        return real(s, rows)

    monkeypatch.setattr(level, "run_chunk", counting)

    def interrupt(n_done):
        if n_done >= 16:
            raise KeyboardInterrupt

    with ThreadPoolExecutor(1) as ex:
        first = run_sweep(spec, "offline", tmp_path, ex, on_unit_done=interrupt)
    assert first.interrupted and len(first.rows) == 16 and len(read_table(tmp_path / "table.csv")) == 16
    done_first = {i for c in calls for i in c if i < 16}
    calls.clear()
    with ThreadPoolExecutor(1) as ex:
        second = run_sweep(spec, "offline", tmp_path, ex)
    assert not second.interrupted and second.resumed == 16 and second.ran == 20
    assert not done_first & {i for c in calls for i in c}, "finished runs were redone"
    fresh = tmp_path / "fresh"
    with ThreadPoolExecutor(1) as ex:
        run_sweep(spec, "offline", fresh, ex)
    assert (tmp_path / "table.csv").read_text() == (fresh / "table.csv").read_text()


def test_ctrl_c_between_storing_a_unit_and_counting_it_keeps_that_unit_in_the_table(tmp_path, monkeypatch):
    """CI once saw runs.jsonl hold 2 runs and table.csv none: Ctrl-C landed after a unit was appended to runs.jsonl and
    before the engine counted it. runs.jsonl is the record; the table written on the interrupt is built from it."""
    import mavastsm.sweep.spec as spec_mod
    from mavastsm.sweep.store import SweepStore

    spec = load_sweep("example")
    spec = spec_mod.SweepSpec(**{**spec.__dict__, "chunk_runs": 8})
    real_append = SweepStore.append

    def append_then_ctrl_c(self, rows):
        real_append(self, rows)
        raise KeyboardInterrupt

    monkeypatch.setattr(SweepStore, "append", append_then_ctrl_c)
    with ThreadPoolExecutor(1) as ex:
        report = run_sweep(spec, "offline", tmp_path, ex)
    stored = SweepStore(tmp_path, spec, "offline").finished()
    assert report.interrupted and len(stored) == 8
    assert len(report.rows) == 8 and [r["run_id"] for r in read_table(tmp_path / "table.csv")] == sorted(stored)


def test_a_runs_row_does_not_depend_on_its_batch(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("sweep:\n  controllers: [astsm, stsm]\n  duration_s: 2.0\n  variables:\n"
                 "    sensor_noise_scale: {grid: [0.0, 3.0]}\n    inertia_xx_rel: {grid: [-0.3, 0.5]}\n", encoding="utf-8")
    spec = load_sweep(p)
    rows = spec.runs()
    together = run_chunk(spec, rows)
    alone = [run_chunk(spec, [r])[0] for r in rows]
    for a, b in zip(together, alone):
        assert a.keys() == b.keys()
        for k in a:
            assert a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])), (k, a[k], b[k])
    assert together[1]["steady_error_deg_roll"] != together[0]["steady_error_deg_roll"]  # the noise is on
