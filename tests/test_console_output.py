"""The ux issue, item 4: output that is not a terminal lost numbers ("0.0…", key names cut, tables wrapped). Reports
printed to a pipe now keep every cell whole on one line, without colour codes."""

from __future__ import annotations

import subprocess
import sys


def _piped(*argv: str, stderr_too: bool = False) -> str:
    out = subprocess.run([sys.executable, "-m", "mavastsm.cli", *argv], capture_output=True, text=True, timeout=120,
                         env={"PATH": "/usr/bin:/bin", "COLUMNS": "80"})
    assert out.returncode == 0, out.stderr
    return out.stdout + (out.stderr if stderr_too else "")


def test_check_config_piped_keeps_every_key_and_value():
    text = _piped("check-config", "bridge.yaml")
    assert "…" not in text and "\x1b[" not in text
    for key in ("attitude_rate_min_hz", "setpoint_timeout_s", "shaping_envelope_fraction", "samples_in_memory"):
        assert any(line.split("│")[1].strip() == key for line in text.splitlines() if line.count("│") > 2), key


def test_simulate_piped_keeps_every_number():
    text = _piped("simulate", "--controller", "astsm", "--scenario", "nominal")
    assert "…" not in text and "\x1b[" not in text
    rows = [line for line in text.splitlines() if "│ roll" in line or "│ pitch" in line or "│ yaw" in line]
    assert rows and all(len(line) <= 200 for line in rows)  # one line per row, not wrapped
    assert all(any(ch.isdigit() for ch in cell) for line in rows[:3] for cell in line.split("│")[4:8]), rows[:3]


def test_simulate_table_headers_keep_their_units():
    """Unit notation (ux issue, item 10): "t_s2% [s]", "IAE [deg s]", "e_ss [deg]" lost their brackets, which the
    console read as markup tags; only "OS [%]" kept its unit."""
    from mavastsm.offline.report import SUMMARY_COLUMNS

    text = _piped("simulate", "--controller", "astsm", "--scenario", "nominal")
    for _, header, _ in SUMMARY_COLUMNS:
        assert header in text, header


def test_reproduce_piped_prints_each_modes_description_whole(tmp_path):
    """Issue 28: ``mavastsm reproduce | cat`` cut the mode lines of its header with "…" (they were the progress bar's
    description, cut to the 80 columns a pipe gets); they are now lines of their own, the bar only names the mode."""
    text = _piped("reproduce", "--modes", "P", "--no-plots", "--out", str(tmp_path), stderr_too=True)
    assert "…" not in text and "\x1b[" not in text
    assert "mode P  paper-faithful: ASTSM Table 2 in torque units, every controller at 0.5 ms" in text.splitlines(), text[:600]
