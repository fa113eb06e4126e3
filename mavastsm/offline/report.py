"""Tables, CSV files and the markdown reproduction report (I/O only; the numbers come from metrics/claims)."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from .claims import ClaimResult, ModeResults
from .metrics import AXES
from .simulator import RunResult

# (metric key, column title, decimals) shown in the console and markdown tables
SUMMARY_COLUMNS = (
    ("settling_2pct_s", "t_s2% [s]", 2),
    ("overshoot_pct", "OS [%]", 1),
    ("iae_deg_s", "IAE [deg s]", 2),
    ("steady_error_deg", "e_ss [deg]", 3),
    ("peak_u_nm", "max|u| [N m]", 2),
    ("energy_nm2s", "∫u² [N²m²s]", 3),
    ("tv_steady_nm", "TV steady [N m]", 3),
    ("dist_peak_deg", "dist peak [deg]", 2),
    ("dist_recovery_s", "recovery [s]", 2),
    ("alpha_peak", "α peak", 1),
)
TIMESERIES_STRIDE_S = 2e-3  # CSV time series are thinned to one row per 2 ms (metrics use every sample)


def fmt(x: float, nd: int) -> str:
    x = float(x)
    if np.isnan(x):
        return "–"
    if np.isinf(x):
        return "∞"
    if abs(x) >= 1e4:
        return f"{x:.3g}"
    return f"{x:.{nd}f}"


def axes_cell(v, nd: int) -> str:
    return " / ".join(fmt(x, nd) for x in v)


TRACKING_COLUMNS = SUMMARY_COLUMNS[:4] + SUMMARY_COLUMNS[7:9]
EFFORT_COLUMNS = SUMMARY_COLUMNS[4:7] + SUMMARY_COLUMNS[9:]


def metrics_rich_table(runs: Sequence[RunResult], title: str, columns=SUMMARY_COLUMNS) -> Table:
    """One row per (run, axis) so every cell holds one number and the table fits a terminal."""
    table = Table(title=title, title_justify="left", show_lines=False)
    for col in ("controller", "scenario", "axis"):
        table.add_column(col, no_wrap=True)
    for _, col, _ in columns:  # Text: "[s]" or "[deg]" would otherwise be read as console markup and vanish
        table.add_column(Text(col), justify="right")
    for n, run in enumerate(runs):
        m = run.metrics
        scn = escape(run.spec.scenario.name) + ("" if run.spec.inertia_variant == "corrected" else " (Iyy lit.)")
        for i, ax in enumerate(AXES):
            table.add_row(escape(run.spec.display) if i == 0 else "", scn if i == 0 else "", ax,
                          *[fmt(m[k][i], nd) for k, _, nd in columns], end_section=(i == 2 and n < len(runs) - 1))
    return table


def metrics_rich_tables(runs: Sequence[RunResult], title: str) -> list[Table]:
    """The metrics split into a tracking table and a control-effort table (each fits 100 columns)."""
    return [metrics_rich_table(runs, f"{title}: tracking", TRACKING_COLUMNS),
            metrics_rich_table(runs, f"{title}: control effort and adaptation", EFFORT_COLUMNS)]


def claims_rich_table(mode: ModeResults, claims: Sequence[ClaimResult]) -> Table:
    table = Table(title=f"Paper claims, mode {mode.name} (T = {mode.dt_s * 1e3:g} ms, ASTSM preset {mode.astsm_preset})",
                  title_justify="left", show_lines=True)
    table.add_column("claim")
    table.add_column("verdict")
    table.add_column("criterion")
    table.add_column("measured", overflow="fold")
    for c in claims:
        table.add_row(escape(f"{c.key}: {c.statement}"), {True: "[green]PASS[/]", False: "[red]FAIL[/]", None: "[yellow]INCONCLUSIVE[/]"}[c.passed], escape(c.criterion), escape(c.evidence))
    return table


def metrics_markdown(runs: Iterable[RunResult]) -> str:
    head = "| controller | scenario | " + " | ".join(c for _, c, _ in SUMMARY_COLUMNS) + " |"
    sep = "|---|---|" + "---:|" * len(SUMMARY_COLUMNS)
    rows = [head, sep]
    for run in runs:
        m = run.metrics
        scn = run.spec.scenario.name + ("" if run.spec.inertia_variant == "corrected" else " (literal Iyy)")
        rows.append(f"| {run.spec.display} | {scn} | " + " | ".join(axes_cell(m[k], nd) for k, _, nd in SUMMARY_COLUMNS) + " |")
    return "\n".join(rows)


def write_metrics_csv(path: Path, rows: Iterable[tuple[str, RunResult]]) -> Path:
    """Long-format metrics: one line per (mode, run, axis) with every metric as a column."""
    rows = list(rows)
    keys = sorted(rows[0][1].metrics) if rows else []
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["mode", "dt_s", "controller", "config", "scenario", "inertia_variant", "axis", *keys])
        for mode_name, run in rows:
            for i, ax in enumerate(AXES):
                w.writerow([mode_name, run.dt_s, run.spec.display, run.spec.config or "", run.spec.scenario.name,
                            run.spec.inertia_variant, ax, *(repr(float(run.metrics[k][i])) for k in keys)])
    return path


def write_claims_csv(path: Path, rows: Iterable[tuple[str, ClaimResult]]) -> Path:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["mode", "claim", "verdict", "statement", "criterion", "measured"])
        for mode_name, c in rows:
            w.writerow([mode_name, c.key, c.verdict, c.statement, c.criterion, c.evidence])
    return path


def write_timeseries_csv(path: Path, runs: Sequence[RunResult], stride_s: float | None = TIMESERIES_STRIDE_S) -> Path:
    """Time histories (angles/references in deg, body rates in deg/s, u and d in N m, alpha, sigma) of runs."""
    cols = ["controller", "scenario", "t_s"]
    for q in ("angle_deg", "ref_deg", "rate_degs", "u_nm", "dist_nm", "alpha", "sigma_rads"):
        cols += [f"{ax}_{q}" for ax in AXES]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for run in runs:
            n = len(run.t_s)
            step = 1 if (stride_s is None or n < 2) else max(1, int(round(stride_s / (run.t_s[1] - run.t_s[0]))))
            block = np.column_stack([
                run.t_s, np.degrees(run.euler_rad), np.degrees(run.ref_rad), np.degrees(run.omega_rads),
                run.u_nm, run.dist_nm, run.alpha, run.sigma,
            ])[::step]
            for row in block:
                w.writerow([run.spec.display, run.spec.scenario.name, *(f"{x:.6g}" for x in row)])
    return path
