"""Running a sweep: cut the run list into units of work, skip the finished ones, submit the rest to an executor,
store each result as it arrives, and write the reports (table, margins, map).

Units of work: at the offline level a chunk of ``spec.chunk_runs`` runs (one batch); at the MAVLink level one run
(one bridge + sim pair). Ctrl-C keeps every finished unit (already on disk) and writes the table of what finished.
"""

from __future__ import annotations

import time
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .outputs import draw_maps, margin_rows, write_margins
from .spec import SweepSpec
from .store import SweepStore


@dataclass
class SweepReport:
    """What a sweep call did: runs in the sweep, already done before it, run by it; output paths; wall time [s]."""

    total: int
    resumed: int
    ran: int
    interrupted: bool
    wall_s: float
    rows: list[dict] = field(default_factory=list)
    margins: list[dict] = field(default_factory=list)
    paths: dict[str, Path] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def units(spec: SweepSpec, level: str, rows: list[dict]) -> list[list[dict]]:
    """The units of work in submission order (fixed by the spec alone)."""
    size = spec.chunk_runs if level == "offline" else 1
    return [rows[i:i + size] for i in range(0, len(rows), size)]


def _work(level: str) -> Callable:
    if level == "offline":
        from .offline_level import run_chunk

        return run_chunk
    from .mavlink_level import run_unit

    return run_unit


def run_sweep(spec: SweepSpec, level: str, out_dir: str | Path, executor, progress: Callable[[int, int], None] | None = None,
              on_unit_done: Callable[[int], None] | None = None) -> SweepReport:
    """Run (or resume) the sweep into ``out_dir``. ``progress(done, total)`` after each unit; ``on_unit_done(n)``
    after the n-th unit of this call was stored (tests raise KeyboardInterrupt there to interrupt)."""
    spec.check_level(level)
    store = SweepStore(out_dir, spec, level)
    rows = spec.runs()
    done = store.finished()
    todo = [u for u in units(spec, level, rows) if not all(r["run_id"] in done for r in u)]
    resumed = len(done)
    t0 = time.perf_counter()
    work = _work(level)
    report = progress or (lambda d, t: None)
    report(len(done), len(rows))
    pending = {executor.submit(work, spec, u) for u in todo}
    ran = 0
    interrupted = False
    try:
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                result = fut.result()
                store.append(result)
                done.update({r["run_id"]: r for r in result})
                ran += len(result)
                report(len(done), len(rows))
                if on_unit_done is not None:
                    on_unit_done(ran)
    except KeyboardInterrupt:
        interrupted = True
        for fut in pending:
            fut.cancel()
        done = store.finished()  # runs.jsonl is the record: a unit stored just before Ctrl-C was not counted yet
        ran = len(done) - resumed
    final = [done[k] for k in sorted(done)]
    out = SweepReport(len(rows), resumed, ran, interrupted, time.perf_counter() - t0, final)
    out.paths["table"] = store.write_table(final)
    if not interrupted:
        out.margins = margin_rows(spec, final)
        out.paths["margins"] = write_margins(store.dir / "margins.csv", out.margins)
        if final and spec.map_x and spec.map_metric not in final[0]:
            out.notes.append(f"map: no column {spec.map_metric!r} at level {level} (see table.csv for the columns)")
        else:
            png = draw_maps(spec, final, store.dir / f"map_{spec.map_metric}.png", level)
            if png is not None:
                out.paths["map"] = png
            elif spec.map_x:
                out.notes.append("map: not drawn (needs matplotlib: pip install \"mavastsm[plot]\")")
    return out
