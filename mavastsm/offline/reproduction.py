"""The paper reproduction: which runs make up each simulation mode, and running them (in parallel).

Modes (docs/design-decisions.md, CTL-7; the ASTSM preset differs, every other controller keeps its default gains):

* ``P``  paper-faithful: ASTSM preset ``astsm_paper`` (Table 2, u_D as torque), controller period
  0.5 ms by default (quasi-continuous for this law: 0.25 ms gives the same alpha peaks, 1 ms breaks it;
  the paper gives no sample time). Every controller runs at that period.
* ``E1`` implementable at 1 kHz: ASTSM preset ``astsm`` (accel units, varpi = 1000). Also runs
  ``astsm_paper`` at 1 ms to show that the literal Table-2 law does not survive a 1 ms sample period.
* ``E2`` ArduCopter's 400 Hz loop (2.5 ms): ASTSM preset ``astsm_400hz`` (mu = 0.03). Not in the
  default set (it costs as much as E1); ``mavastsm reproduce --modes P,E1,E2``.

Every mode runs ASTSM, STSM, SMC, ATSM and PID on the nominal, disturbance (D-A) and variation scenarios
with the corrected inertia, plus the literal-Iyy inertia for every scenario where cheap (rows of one batch
cost little), and a fixed-gain STSM gain sweep on the disturbance scenario for claim C8.
Modes run as separate batches; with ``workers=2`` the heaviest mode runs in a child process.
"""

from __future__ import annotations

import multiprocessing as mp
import queue as queue_mod
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..control import make_controller
from ..scenarios import load_scenario
from ..solo_model import load_solo
from .claims import ModeResults
from .metrics import compute_metrics
from .simulator import RunResult, RunSpec, simulate_runs

SCENARIOS = ("nominal", "disturbance", "variation")
BASELINES = ("stsm", "smc", "atsm", "pid")
STSM_SWEEP_SCALES = (0.01, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 10.0, 20.0, 50.0, 100.0)
DECIMATE_TO_S = 1e-3  # time series kept for CSV/figures are thinned to at most one sample per ms


@dataclass(frozen=True)
class ModePlan:
    """One batch: mode name, controller period [s], ASTSM preset, runs, sweep runs, one-line description."""

    name: str
    dt_s: float
    astsm_preset: str
    specs: tuple
    sweep_specs: tuple
    description: str
    extra_labels: tuple = field(default=())


def _stsm_sweep(dt_tag: str) -> tuple:
    solo_gains = make_controller("stsm", load_solo()).gains
    k1, k2 = np.asarray(solo_gains.k1), np.asarray(solo_gains.k2)
    dist = load_scenario("disturbance")
    return tuple(
        RunSpec("stsm", dist, label=f"stsm_x{s:g}", gain_matrix={"k1": tuple(k1 * np.sqrt(s)), "k2": tuple(k2 * s)})
        for s in STSM_SWEEP_SCALES
    )


DEFAULT_MODES = ("P", "E1")
DEFAULT_PAPER_PERIOD_S = 5e-4


def plan_modes(modes: tuple[str, ...] = DEFAULT_MODES, paper_period_s: float = DEFAULT_PAPER_PERIOD_S) -> list[ModePlan]:
    """Build the run lists of the requested modes (see module docstring)."""
    scn = {n: load_scenario(n) for n in SCENARIOS}
    plans = []
    presets = {"P": ("astsm_paper", paper_period_s), "E1": ("astsm", 1e-3), "E2": ("astsm_400hz", 2.5e-3)}
    for mode in modes:
        preset, dt = presets[mode]
        specs = []
        for variant in ("corrected", "paper_literal"):
            for name in SCENARIOS:
                specs.append(RunSpec("astsm", scn[name], config=preset, inertia_variant=variant, label="astsm"))
                for b in BASELINES:
                    specs.append(RunSpec(b, scn[name], inertia_variant=variant, label=b))
        extra = ()
        if mode == "E1":
            for name in SCENARIOS:
                specs.append(RunSpec("pid_fair", scn[name], label="pid_fair"))
                specs.append(RunSpec("astsm", scn[name], config="astsm_paper", label="astsm_paper"))
            extra = ("pid_fair", "astsm_paper")
        desc = {
            "P": f"paper-faithful: ASTSM Table 2 in torque units, every controller at {dt * 1e3:g} ms",
            "E1": "implementable 1 kHz: ASTSM in accel units (varpi = 1000, mu = 0.01), every controller at 1 ms",
            "E2": "ArduCopter 400 Hz: ASTSM in accel units (varpi = 1000, mu = 0.03), every controller at 2.5 ms",
        }[mode]
        plans.append(ModePlan(mode, dt, preset, tuple(specs), _stsm_sweep(mode), desc, extra))
    return plans


def _decimate(run: RunResult, keep_series: bool) -> RunResult:
    if not keep_series:
        empty = np.empty((0, 3))
        return replace(run, t_s=np.empty(0), euler_rad=empty, ref_rad=empty, omega_rads=empty, u_nm=empty, dist_nm=empty, alpha=empty, sigma=empty)
    stride = max(1, int(round(DECIMATE_TO_S / run.dt_s)))
    if stride == 1:
        return run
    sl = slice(None, None, stride)
    return replace(run, t_s=run.t_s[sl], euler_rad=run.euler_rad[sl], ref_rad=run.ref_rad[sl], omega_rads=run.omega_rads[sl],
                   u_nm=run.u_nm[sl], dist_nm=run.dist_nm[sl], alpha=run.alpha[sl], sigma=run.sigma[sl])


def run_plan(plan: ModePlan, progress: Callable[[float], None] | None = None, figures_dir=None) -> ModeResults:
    """Simulate one mode (one batch), compute every run's metrics, thin the kept time series.

    With ``figures_dir`` the mode's PNG figures are drawn here too (so parallel lanes also plot in
    parallel); their file names are in ``ModeResults.figures``.
    """
    all_specs = list(plan.specs) + list(plan.sweep_specs)
    results = simulate_runs(all_specs, dt_control_s=plan.dt_s, progress=progress)
    out = ModeResults(plan.name, plan.dt_s, plan.astsm_preset)
    n_main = len(plan.specs)
    for i, res in enumerate(results):
        res.metrics = compute_metrics(res)
        if i < n_main:
            out.runs[(res.spec.label, res.spec.scenario.name, res.spec.inertia_variant)] = _decimate(res, True)
        else:
            out.sweep.append(_decimate(res, False))
    if figures_dir is not None:
        from .figures import paper_figures

        out.figures = [p.name for p in paper_figures(out, figures_dir)]
    return out


def _child(plan: ModePlan, q, figures_dir) -> None:  # pragma: no cover - runs in a subprocess
    try:
        res = run_plan(plan, progress=lambda f: q.put(("progress", plan.name, f)), figures_dir=figures_dir)
        q.put(("done", plan.name, res))
    except BaseException as exc:  # report, never hang the parent
        q.put(("error", plan.name, f"{type(exc).__name__}: {exc}"))


def run_plans(plans: list[ModePlan], workers: int = 2, progress: Callable[[str, float], None] | None = None,
              figures_dir=None) -> list[ModeResults]:
    """Run every plan; with workers >= 2 the first (heaviest) plan runs in a child process meanwhile.

    ``figures_dir``: also draw each mode's figures (needs matplotlib) in the lane that simulated it.
    """
    report = progress or (lambda name, f: None)
    done: dict[str, ModeResults] = {}
    child = None
    q = None
    pending_child: str | None = None
    if workers >= 2 and len(plans) >= 2:
        # spawn, not fork: the caller may be running threads (e.g. a rich progress bar) when we start the child
        ctx = mp.get_context("spawn")
        q = ctx.Queue()
        child = ctx.Process(target=_child, args=(plans[0], q, figures_dir), daemon=True)
        child.start()
        pending_child = plans[0].name
        local = plans[1:]
    else:
        local = plans

    def drain(block: bool) -> None:
        nonlocal pending_child
        while q is not None and pending_child is not None:
            try:
                kind, name, payload = q.get(timeout=0.5) if block else q.get_nowait()
            except queue_mod.Empty:
                if block and child is not None and not child.is_alive() and child.exitcode not in (None, 0):
                    raise RuntimeError(f"simulation worker for mode {pending_child} died (exit code {child.exitcode})")
                if not block:
                    return
                continue
            if kind == "progress":
                report(name, payload)
            elif kind == "done":
                done[name] = payload
                pending_child = None
            else:
                raise RuntimeError(f"simulation worker for mode {name} failed: {payload}")

    try:
        for plan in local:
            done[plan.name] = run_plan(plan, progress=lambda f, n=plan.name: (report(n, f), drain(False)), figures_dir=figures_dir)
        drain(True)
    finally:
        if child is not None:
            child.join(timeout=5)
            if child.is_alive():
                child.terminate()
                child.join(timeout=5)
    return [done[p.name] for p in plans]
