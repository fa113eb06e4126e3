"""Ctrl-C on the command: exit status 130, the finished runs kept in table.csv, and the same command again resumes
without redoing them (checked on runs.jsonl: every run_id once)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

SPEC = """sweep:
  controllers: [astsm, pid_fair]
  duration_s: 2.0
  chunk_runs: 2
  variables:
    disturbance_pitch_nm: {grid: [0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25]}
    disturbance_start_s: {grid: [1.2]}
    inertia_yy_rel: {grid: [-0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75]}
"""


def _lines(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()] if path.is_file() else []


def _signal_dispositions(pid: int) -> str:
    """The process's ignored and caught signal masks (/proc/PID/status): SIGINT is bit 2 (0x2)."""
    try:
        return " ".join(ln.strip() for ln in Path(f"/proc/{pid}/status").read_text().splitlines() if ln.startswith(("SigIgn", "SigCgt")))
    except OSError as exc:
        return f"unreadable ({exc})"


def _default_sigint() -> None:
    """As a shell starts a foreground command: SIGINT at its default, whatever the test process inherited."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt_after_progress(spec: Path, out: Path, more_than: int) -> subprocess.CompletedProcess:
    proc = subprocess.Popen([sys.executable, "-m", "mavastsm.cli", "sweep", str(spec), "--out-dir", str(out), "--workers", "1",
                             "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_default_sigint)
    try:
        deadline = time.monotonic() + 120.0
        while len(_lines(out / "runs.jsonl")) <= more_than and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # polling the file: the condition, not a fixed wait
        assert proc.poll() is None, "the sweep ended before it could be interrupted"
        at_signal = (len(_lines(out / "runs.jsonl")), _signal_dispositions(proc.pid))
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole process group
        try:
            stdout, stderr = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            # CI twice: no exit within 60 s of the SIGINT, nothing on stderr (the whole sweep takes about 75 s): say
            # whether the sweep ignored SIGINT and how far it went
            raise AssertionError(f"the sweep did not exit within 60 s of SIGINT; runs stored at the signal / now: "
                                 f"{at_signal[0]} / {len(_lines(out / 'runs.jsonl'))}; at the signal {at_signal[1]}; now "
                                 f"{_signal_dispositions(proc.pid)}") from None
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def test_ctrl_c_keeps_finished_runs_and_a_rerun_resumes_them(tmp_path):
    spec = tmp_path / "s.yaml"
    spec.write_text(SPEC, encoding="utf-8")
    out = tmp_path / "out"
    first = _interrupt_after_progress(spec, out, 0)
    assert first.returncode == 130, (first.stdout, first.stderr)
    assert "rerun the same command to resume" in first.stdout
    kept = _lines(out / "runs.jsonl")
    table = (out / "table.csv").read_text().splitlines()
    assert 0 < len(kept) < 200 and len(table) == len(kept) + 1
    second = _interrupt_after_progress(spec, out, len(kept))
    assert second.returncode == 130
    ids = [r["run_id"] for r in _lines(out / "runs.jsonl")]
    assert len(ids) > len(kept) and len(ids) == len(set(ids)), "a finished run was redone"
