"""A sweep's output folder: what finished survives an interrupt, and a rerun resumes from it.

* ``sweep.json``: the spec's digest and the level; a rerun into the same folder must be the same sweep.
* ``runs.jsonl``: one JSON object per finished run, appended (and flushed to disk) as each unit of work
  finishes. A line cut short by a kill is ignored; a run written twice keeps its last row.
* ``table.csv``: the tidy table, one row per run sorted by run_id, rewritten from ``runs.jsonl`` at the end
  (and when interrupted).
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

from ..errors import ConfigError
from .spec import SweepSpec

LEAD_COLUMNS = ("run_id", "level", "controller", "seed")


class SweepStore:
    def __init__(self, out_dir: str | Path, spec: SweepSpec, level: str) -> None:
        self.dir = Path(out_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.runs_path = self.dir / "runs.jsonl"
        manifest = self.dir / "sweep.json"
        want = {"digest": spec.digest, "level": level, "spec": spec.path}
        if manifest.is_file():
            have = json.loads(manifest.read_text(encoding="utf-8"))
            if (have.get("digest"), have.get("level")) != (want["digest"], want["level"]):
                raise ConfigError(f"--out-dir {self.dir}: holds another sweep ({have.get('spec')}, level {have.get('level')}); "
                                  f"choose another folder or delete it to start over")
        else:
            manifest.write_text(json.dumps(want, indent=1) + "\n", encoding="utf-8")

    def finished(self) -> dict[int, dict]:
        """run_id -> row of every run already in ``runs.jsonl``."""
        rows: dict[int, dict] = {}
        if not self.runs_path.is_file():
            return rows
        for line in self.runs_path.read_text(encoding="utf-8").splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue  # cut short by a kill: that run is redone
            rows[int(row["run_id"])] = row
        return rows

    def append(self, rows: list[dict]) -> None:
        text = "".join(json.dumps(row) + "\n" for row in rows)  # one write: Ctrl-C cannot split a unit of work
        with self.runs_path.open("a", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    def write_table(self, rows: list[dict]) -> Path:
        """table.csv, one row per run sorted by run_id; columns: the lead ones, the inputs, outcome, then metrics."""
        path = self.dir / "table.csv"
        rows = sorted(rows, key=lambda r: r["run_id"])
        cols: list[str] = list(LEAD_COLUMNS)
        for row in rows:
            cols.extend(k for k in row if k not in cols)
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(cols)
            for row in rows:
                w.writerow([_cell(row.get(c, "")) for c in cols])
        return path


def _cell(x):
    if isinstance(x, float):
        return "nan" if math.isnan(x) else repr(x)
    return x


def read_table(path: str | Path) -> list[dict]:
    """table.csv back as rows (numbers as float where they parse)."""
    out = []
    with Path(path).open(newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            parsed = {}
            for k, v in row.items():
                try:
                    parsed[k] = float(v)
                except ValueError:
                    parsed[k] = v
            out.append(parsed)
    return out
