"""PNG figures in the spirit of the paper's Figs. 3-7 (needs the ``plot`` extra: matplotlib).

Import of matplotlib is deferred to the call so the rest of the package works without it; callers
check :func:`matplotlib_available` first and print :data:`INSTALL_HINT` otherwise.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Sequence

import numpy as np

from .simulator import RunResult

INSTALL_HINT = 'figures need matplotlib: pip install "mavastsm[plot]"'
AXIS_LABELS = ("roll φ", "pitch θ", "yaw ψ")
# one colour per controller in every figure (matplotlib's default cycle, fixed to the key)
CONTROLLER_COLOURS = {"astsm": "tab:blue", "stsm": "tab:orange", "smc": "tab:green", "atsm": "tab:red", "pid": "tab:purple"}
# ASTSM, the paper's controller, on top and solid; the others under it, thinner and translucent
TRACE_STYLE = {"astsm": {"lw": 1.6, "alpha": 1.0}, "other": {"lw": 0.9, "alpha": 0.55}}


def matplotlib_available() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_runs(runs: Sequence[RunResult], path: str | Path, title: str = "") -> Path:
    """Angles vs reference (deg) and torques u (N m) per axis for several runs on one figure."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex=True)
    # as in Fig. 3: the most chattering run drawn first (lowest) and translucent, ASTSM solid on top, so a
    # chattering band covers no other trace; colours keep the order the runs were given in
    colours = {id(run): f"C{n}" for n, run in enumerate(runs)}
    others = sorted((run for run in runs if run.spec.controller != "astsm"), key=lambda run: -torque_chattering_nm(run))
    for layer, run in enumerate(others + [run for run in runs if run.spec.controller == "astsm"]):
        lab = run.spec.display
        style = {**TRACE_STYLE["astsm" if run.spec.controller == "astsm" else "other"], "zorder": 2 + 0.1 * layer}
        for i in range(3):
            axes[i, 0].plot(run.t_s, np.degrees(run.euler_rad[:, i]), label=lab, color=colours[id(run)], **style)
            axes[i, 1].plot(run.t_s, run.u_nm[:, i], label=lab, color=colours[id(run)], **style)
    if runs:
        r0 = runs[0]
        for i in range(3):
            axes[i, 0].plot(r0.t_s, np.degrees(r0.ref_rad[:, i]), "k--", lw=0.8, label="reference", zorder=4)
    for i in range(3):
        axes[i, 0].set_ylabel(f"{AXIS_LABELS[i]} [deg]")
        axes[i, 1].set_ylabel(f"u{i + 1} [N m]")
    axes[2, 0].set_xlabel("t [s]")
    axes[2, 1].set_xlabel("t [s]")
    handles, names = axes[0, 0].get_legend_handles_labels()
    canonical = [run.spec.display for run in runs] + ["reference"]
    order = sorted(range(len(names)), key=lambda n: canonical.index(names[n]))
    axes[0, 0].legend([handles[n] for n in order], [names[n] for n in order], fontsize=7, ncol=2)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def _fig3_nominal(plt, mode, labels: list[str], tag: str):
    """Fig. 3: responses in nominal condition (angles and body rates). The comparison controllers are drawn thin and
    translucent, the most chattering first (lowest), so a chattering band (ATSM's rates) covers no other trace;
    ASTSM, the paper's controller, goes on top."""
    fig, ax = plt.subplots(3, 2, figsize=(12, 8), sharex=True)
    runs = {k: mode.run(k, "nominal") for k in labels}
    others = sorted((k for k in labels if k != "astsm"), key=lambda k: -rate_chattering_rads(runs[k]))
    for layer, k in enumerate(others + [k for k in labels if k == "astsm"]):
        r = runs[k]
        style = {**TRACE_STYLE.get(k, TRACE_STYLE["other"]), "zorder": 2 + 0.1 * layer}
        for i in range(3):
            ax[i, 0].plot(r.t_s, np.degrees(r.euler_rad[:, i]), label=k, color=CONTROLLER_COLOURS.get(k), **style)
            ax[i, 1].plot(r.t_s, np.degrees(r.omega_rads[:, i]), label=k, color=CONTROLLER_COLOURS.get(k), **style)
    r = mode.run(labels[0], "nominal")
    for i in range(3):
        ax[i, 0].plot(r.t_s, np.degrees(r.ref_rad[:, i]), "k--", lw=0.8, label="reference", zorder=4)
        ax[i, 0].set_ylabel(f"{AXIS_LABELS[i]} [deg]")
        ax[i, 1].set_ylabel(f"body rate {'pqr'[i]} [deg/s]")
    for a in ax[2]:
        a.set_xlabel("t [s]")
    handles, names = ax[0, 0].get_legend_handles_labels()
    canonical = labels + ["reference"]  # the legend in the usual order, whatever the drawing order
    order = sorted(range(len(names)), key=lambda n: canonical.index(names[n]))
    ax[0, 0].legend([handles[n] for n in order], [names[n] for n in order], fontsize=7, ncol=3)
    fig.suptitle(f"Fig. 3 analogue: nominal responses, {tag}", fontsize=9)
    return fig


def _fig4_disturbance_yaw(plt, mode, labels: list[str], tag: str):
    """Fig. 4: yaw under disturbance."""
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for k in labels:
        r = mode.run(k, "disturbance")
        ax[0].plot(r.t_s, np.degrees(r.euler_rad[:, 2]), label=k, lw=1)
        ax[1].plot(r.t_s, np.degrees(r.omega_rads[:, 2]), label=k, lw=1)
    ax[0].set_ylabel("yaw ψ [deg]")
    ax[1].set_ylabel("r [deg/s]")
    ax[1].set_xlabel("t [s]")
    ax[0].set_ylim(40, 50)
    ax[0].legend(fontsize=7, ncol=3)
    fig.suptitle(f"Fig. 4 analogue: yaw with 0.5 N m on every axis from 4 s, {tag}", fontsize=9)
    return fig


def _fig5_roll_input(plt, mode, labels: list[str], tag: str):
    """Fig. 5: roll control input, nominal (a) and disturbance (b), zoomed."""
    fig, ax = plt.subplots(2, 1, figsize=(10, 6))
    for k in labels:
        for j, (scn, lo, hi) in enumerate((("nominal", 0.4, 1.5), ("disturbance", 3.9, 5.0))):
            r = mode.run(k, scn)
            m = (r.t_s >= lo) & (r.t_s <= hi)
            ax[j].plot(r.t_s[m], r.u_nm[m, 0], label=k, lw=0.7)
    ax[0].set_title("(a) nominal", fontsize=8)
    ax[1].set_title("(b) disturbance", fontsize=8)
    for a in ax:
        a.set_ylabel("u1 [N m]")
        a.set_xlabel("t [s]")  # the two panels show different time windows: each has its own axis
    ax[0].legend(fontsize=7, ncol=3)
    fig.suptitle(f"Fig. 5 analogue: roll control input, {tag}", fontsize=9)
    return fig


def _fig6_variation(plt, mode, labels: list[str], tag: str):
    """Fig. 6: pitch and yaw under parametric variation (solid) vs nominal (dotted)."""
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for k in labels:
        rv, rn = mode.run(k, "variation"), mode.run(k, "nominal")
        for j, i in enumerate((1, 2)):
            line = ax[j].plot(rv.t_s, np.degrees(rv.euler_rad[:, i]), label=k, lw=1)
            ax[j].plot(rn.t_s, np.degrees(rn.euler_rad[:, i]), ":", color=line[0].get_color(), lw=0.8)
    ax[0].set_ylabel("pitch θ [deg]")
    ax[1].set_ylabel("yaw ψ [deg]")
    ax[1].set_xlabel("t [s]")
    ax[0].legend(fontsize=7, ncol=3)
    fig.suptitle(f"Fig. 6 analogue: parametric variation (solid) vs nominal (dotted), {tag}", fontsize=9)
    return fig


def _fig7_alpha3(plt, mode, labels: list[str], tag: str):
    """Fig. 7: alpha_3(t) in the three scenarios, each over its own duration (the disturbance run is longer)."""
    alpha_unit = astsm_alpha_unit(mode.astsm_preset)
    fig, ax = plt.subplots(3, 1, figsize=(10, 7))
    for j, scn in enumerate(("nominal", "disturbance", "variation")):
        r = mode.run("astsm", scn)
        ax[j].plot(r.t_s, r.alpha[:, 2], lw=1)
        ax[j].set_ylabel(f"α3 [{alpha_unit}]\n({scn})")
        ax[j].set_yscale("log")
        ax[j].set_xlim(float(r.t_s[0]), float(r.t_s[-1]))
        ax[j].set_xlabel("t [s]")
    fig.suptitle(f"Fig. 7 analogue: adaptive gain α3(t), {tag}", fontsize=9)
    return fig


FIGURES = (("fig3_nominal", _fig3_nominal), ("fig4_disturbance_yaw", _fig4_disturbance_yaw),
           ("fig5_roll_input", _fig5_roll_input), ("fig6_variation", _fig6_variation), ("fig7_alpha3", _fig7_alpha3))


def paper_figures(mode, out_dir: str | Path) -> list[Path]:
    """Figs. 3-7 analogues for one mode (``claims.ModeResults``); returns the files written."""
    plt = _pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    labels = [k for k in ("astsm", "stsm", "smc", "atsm", "pid") if mode.has(k, "nominal")]
    tag = f"mode {mode.name} (T = {mode.dt_s * 1e3:g} ms, ASTSM preset {mode.astsm_preset}, corrected inertia)"
    files = []
    for name, draw in FIGURES:
        fig = draw(plt, mode, labels, tag)
        p = out / f"{name}_{mode.name}.png"
        fig.tight_layout()
        fig.savefig(p, dpi=100)
        plt.close(fig)
        files.append(p)
    return files


def torque_chattering_nm(run: RunResult) -> float:
    """Total variation of the torque over the run, summed over the axes [N m]: how much a trace chatters."""
    return float(np.nansum(np.abs(np.diff(run.u_nm, axis=0))))


def rate_chattering_rads(run: RunResult) -> float:
    """Total variation of the body rates over the run, summed over the axes [rad/s]: how much a trace chatters."""
    return float(np.nansum(np.abs(np.diff(run.omega_rads, axis=0))))


def astsm_alpha_unit(preset: str) -> str:
    """The unit of the adaptive gain α in an ASTSM preset (its ``alpha_min`` parameter's: N m or rad/s^2)."""
    from ..config_loading import load_section, resolve_config

    unit = load_section(resolve_config(preset, "controllers"), "gains")["alpha_min"].unit
    return unit.replace(" ", "·") if unit == "N m" else unit
