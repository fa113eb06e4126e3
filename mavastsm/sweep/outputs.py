"""The reports of a finished sweep: the margin table and the robustness maps (pure functions of the table rows).

Margin of a controller for a swept variable: the largest |value| such that every run of that controller with
|value'| <= |value| survives (no failure), and the same for ``settled`` (within the bounds), with every other
grid variable at its grid value nearest its nominal one (no torque, no variation: ``spec.VARIABLES``) and the
distribution variables anywhere. "-" when even the smallest value fails.

Map: a metric over two swept variables, one panel per controller; a cell holds the worst (largest) value over
the other variables' values and draws; failed cells are hatched and the failure boundary is drawn (the 0.5
contour of the share of failed runs). Needs matplotlib (the ``plot`` extra).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from .run_inputs import is_failure
from .spec import VARIABLES, SweepSpec


def _margin(rows: list[dict], name: str, ok) -> float:
    values = sorted({abs(float(r[name])) for r in rows})
    best = math.nan
    for v in values:
        if all(ok(r["outcome"]) for r in rows if abs(float(r[name])) <= v + 1e-12):
            best = v
        else:
            break
    return best


def _at_nominal(spec: SweepSpec, rows: list[dict], free: str) -> list[dict]:
    """``rows`` with every grid variable but ``free`` at its grid value nearest its nominal value."""
    for name, (kind, *args) in spec.variables.items():
        if name == free or kind != "grid":
            continue
        nominal = VARIABLES[name].nominal
        pick = min(args[0], key=lambda v: (abs(v - nominal), abs(v)))
        rows = [r for r in rows if float(r[name]) == pick]
    return rows


def margin_rows(spec: SweepSpec, rows: list[dict]) -> list[dict]:
    """One row per (controller, variable): largest |value| survived and largest |value| settled (the others at
    nominal), the largest |value| swept, and the failures of that controller over the whole sweep."""
    out = []
    for c in spec.controllers:
        everything = [r for r in rows if r["controller"] == c.label]
        for name in spec.variables:
            mine = _at_nominal(spec, everything, name)
            out.append({
                "controller": c.label, "variable": name,
                "survives_up_to": _margin(mine, name, lambda o: not is_failure(o)),
                "settled_up_to": _margin(mine, name, lambda o: o == "settled"),
                "swept_max": max((abs(float(r[name])) for r in mine), default=math.nan),
                "runs": len(everything), "failures": sum(is_failure(r["outcome"]) for r in everything),
            })
    return out


def write_margins(path: Path, margins: list[dict]) -> Path:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(margins[0]) if margins else ["controller"])
        w.writeheader()
        w.writerows(margins)
    return path


def map_grid(rows: list[dict], x: str, y: str, metric: str):
    """(xs, ys, worst metric (ny, nx), failed share (ny, nx)) of one controller's rows."""
    xs = sorted({float(r[x]) for r in rows})
    ys = sorted({float(r[y]) for r in rows}) if y else [0.0]
    val = np.full((len(ys), len(xs)), np.nan)
    fail = np.zeros_like(val)
    count = np.zeros_like(val)
    for r in rows:
        i, j = ys.index(float(r[y])) if y else 0, xs.index(float(r[x]))
        m = float(r.get(metric, math.nan))
        if not math.isnan(m):
            val[i, j] = m if math.isnan(val[i, j]) else max(val[i, j], m)
        fail[i, j] += is_failure(r["outcome"])
        count[i, j] += 1
    return np.array(xs), np.array(ys), val, np.divide(fail, count, out=np.zeros_like(fail), where=count > 0)


def draw_maps(spec: SweepSpec, rows: list[dict], path: Path, level: str) -> Path | None:
    """The robustness map PNG; None when matplotlib is missing or fewer than one swept variable."""
    if not spec.map_x:
        return None
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    n = len(spec.controllers)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n + 0.8, 3.8), squeeze=False, constrained_layout=True)
    grids = [map_grid([r for r in rows if r["controller"] == c.label], spec.map_x, spec.map_y, spec.map_metric) for c in spec.controllers]
    finite = np.concatenate([g[2][np.isfinite(g[2])].ravel() for g in grids] + [np.array([0.0])])
    vmax = float(np.percentile(finite, 95)) if finite.size > 1 else 1.0
    image = None
    for ax, c, (xs, ys, val, fail) in zip(axes[0], spec.controllers, grids):
        ix, iy = np.arange(xs.size), np.arange(ys.size)
        image = ax.pcolormesh(ix, iy, np.ma.masked_invalid(val), shading="nearest", cmap="viridis", vmin=0.0, vmax=vmax or 1.0)
        for i in iy:
            for j in ix:
                if fail[i, j] > 0:
                    ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, hatch="xx", edgecolor="red", lw=0))
        if fail.any() and not fail.all() and xs.size > 1 and ys.size > 1:
            ax.contour(ix, iy, fail, levels=[0.5], colors="red", linewidths=2.0)
        ax.set_xticks(ix, [f"{v:g}" for v in xs], rotation=45)
        ax.set_yticks(iy, [f"{v:g}" for v in ys])
        ax.set_xlabel(spec.map_x)
        ax.set_ylabel(spec.map_y or "")
        ax.set_title(f"{c.label} ({level})")
    fig.colorbar(image, ax=axes[0].tolist(), label=f"{spec.map_metric} (worst over other variables)")
    fig.suptitle("red hatching: failure (envelope breach, divergence or failsafe); red line: failure boundary", fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
