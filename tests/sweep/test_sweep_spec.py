"""Sweep specs: validation (one line naming the file, key, value and rule; exit status 2), the run list, and the
CLI's refusal of an unreachable Dask scheduler."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from mavastsm.errors import ConfigError
from mavastsm.sweep.spec import load_sweep


def _spec(tmp_path: Path, variables: str, extra: str = "") -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(f"sweep:\n  controllers: [astsm]\n  scenario: nominal\n{extra}  variables:\n{variables}", encoding="utf-8")
    return p


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mavastsm.cli", "sweep", *args], capture_output=True, text=True, timeout=120)


def test_unknown_variable_is_one_line_naming_it(tmp_path):
    path = _spec(tmp_path, "    wind_speed_mps: {grid: [1, 2]}\n")
    with pytest.raises(ConfigError, match="unknown variable 'sweep.variables.wind_speed_mps'"):
        load_sweep(path)
    proc = _cli(str(path), "--no-progress")
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and "wind_speed_mps" in proc.stderr, proc.stderr


def test_grid_outside_the_variables_range_is_refused(tmp_path):
    path = _spec(tmp_path, "    disturbance_roll_nm: {grid: [0.0, 9.0]}\n")
    proc = _cli(str(path), "--no-progress")
    assert proc.returncode == 2
    line = proc.stderr.strip()
    assert len(line.splitlines()) == 1 and "disturbance_roll_nm" in line and "9.0" in line and "range [-5, 5]" in line, line


def test_a_mavlink_only_variable_is_refused_at_the_offline_level(tmp_path):
    spec = load_sweep(_spec(tmp_path, "    link_loss: {grid: [0.0, 0.1]}\n"))
    with pytest.raises(ConfigError, match="link_loss.*not --level offline"):
        spec.check_level("offline")
    spec.check_level("mavlink")


def test_unreachable_scheduler_is_one_line_and_exit_2(tmp_path):
    pytest.importorskip("distributed")
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    proc = _cli("example", "--scheduler", f"tcp://127.0.0.1:{port}", "--out-dir", str(tmp_path / "o"), "--no-progress")
    assert proc.returncode == 2
    line = proc.stderr.strip()
    assert len(line.splitlines()) == 1 and f"tcp://127.0.0.1:{port}" in line and "unreachable" in line, proc.stderr


def test_runs_grid_order_and_seeded_draws(tmp_path):
    path = _spec(tmp_path, "    disturbance_roll_nm: {grid: [0.0, 1.0]}\n    sensor_noise_scale: {uniform: [0.0, 2.0]}\n", "  draws: 2\n  seed: 7\n")
    spec = load_sweep(path)
    runs = spec.runs()
    assert [r["run_id"] for r in runs] == [0, 1, 2, 3]
    assert [r["disturbance_roll_nm"] for r in runs] == [0.0, 0.0, 1.0, 1.0]
    assert [r["seed"] for r in runs] == [7, 8, 9, 10]
    assert all(0.0 <= r["sensor_noise_scale"] <= 2.0 for r in runs)
    assert runs == load_sweep(path).runs()  # the same spec draws the same values
    assert len({r["sensor_noise_scale"] for r in runs}) == 4


def test_docs_list_every_variable_with_its_range_and_levels():
    from mavastsm.sweep.spec import VARIABLES

    doc = (Path(__file__).resolve().parents[2] / "docs" / "sweep.md").read_text(encoding="utf-8")
    table = {line.split("|")[1]: line for line in doc.splitlines() if line.startswith("| `")}
    for name, var in VARIABLES.items():
        row = next((line for key, line in table.items() if f"`{name}`" in key), None)
        assert row is not None, f"docs/sweep.md does not list {name}"
        assert ("both" if len(var.levels) == 2 else var.levels[0]) in row, name
        assert f"{var.lo:g}".replace("-", "−") in row and f"{var.hi:g}" in row, (name, row)


def test_check_config_validates_and_lists_a_sweep(tmp_path, capsys):
    from mavastsm.cli import main

    spec_path = Path(__file__).resolve().parents[2] / "configs" / "sweeps" / "example.yaml"
    assert main(["check-config", str(spec_path)]) == 0
    out = capsys.readouterr().out
    assert "valid sweep" in out and "disturbance_roll_nm" in out and "36 runs" in out
    bad = _spec(tmp_path, "    disturbance_roll_nm: {grid: [7.0]}\n")
    assert main(["check-config", str(bad)]) == 2
    assert "disturbance_roll_nm" in capsys.readouterr().err
