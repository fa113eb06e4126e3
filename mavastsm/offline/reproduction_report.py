"""The markdown reproduction report (docs/reproduction.md) built from measured results only.

Explanatory sentences are fixed text about the set-up; every number in the report is read from the
runs, the claims or the loaded configs at generation time.
"""

from __future__ import annotations

import datetime as _dt
import platform
from typing import Mapping, Sequence

import numpy as np

from .. import __version__
from ..control import make_controller
from ..frames import AXES
from ..scenarios import load_scenario
from .claims import ClaimResult, ModeResults
from .report import axes_cell, metrics_markdown

_MODE_TEXT = {
    "P": "paper-faithful: Table 2 gains, switching term added as a torque (eq. 26)",
    "E1": "implementable at 1 kHz: switching term in acceleration units (u_D = I0 v), ϖ = 1000",
    "E2": "ArduCopter's 400 Hz loop: as E1 with μ = 0.03 rad/s",
}


def _v(x) -> str:
    if isinstance(x, tuple):
        return "(" + ", ".join(f"{v:g}" for v in x) + ")"
    return f"{x:g}" if isinstance(x, float) else str(x)


def _gains_table(solo) -> str:
    rows = ["| controller | preset | gains (per axis roll, pitch, yaw where a triple) |", "|---|---|---|"]
    for key, preset in (("astsm", "astsm_paper"), ("astsm", "astsm"), ("astsm", "astsm_400hz"), ("stsm", None), ("smc", None),
                        ("atsm", None), ("pid", None), ("pid_fair", None)):
        c = make_controller(key, solo, preset)
        g = c.gains
        shown = {k: getattr(g, k) for k in g.__dataclass_fields__ if not k.startswith("torque_limit")}
        rows.append(f"| {key} | {preset or c.default_config[:-5]} | " + "; ".join(f"{k} = {_v(v)}" for k, v in shown.items()) + " |")
    return "\n".join(rows)


def _claims_overview(results: Sequence[ModeResults], claims: Mapping[str, Sequence[ClaimResult]]) -> str:
    names = [r.name for r in results]
    head = "| claim | " + " | ".join(f"mode {n} (T = {r.dt_s * 1e3:g} ms)" for n, r in zip(names, results)) + " |"
    rows = [head, "|---|" + "---|" * len(names)]
    for i, c in enumerate(claims[names[0]]):
        rows.append(f"| **{c.key}** {c.statement} | " + " | ".join(f"**{claims[n][i].verdict}**" for n in names) + " |")
    return "\n".join(rows)


def _c1_explanation(r: ModeResults) -> str:
    """Which (controller, axis) miss C1 and whether it is the own step, later cross-coupling or a slow tail."""
    notes = []
    for k in ("astsm", "stsm", "smc", "atsm", "pid"):
        if not r.has(k, "nominal"):
            continue
        m = r.run(k, "nominal").metrics
        for i, ax in enumerate(AXES):
            ts, os_, own = m["settling_2pct_s"][i], m["overshoot_pct"][i], m["overshoot_own_step_pct"][i]
            if ts < 2.0 and os_ < 5.0:
                continue
            why = []
            if os_ >= 5.0:
                why.append(f"overshoot {os_:.1f} %, of which {own:.1f} % before the next step on another axis"
                           + (" (the rest is cross-coupling from the later steps)" if own < 5.0 else ""))
            if not ts < 2.0:
                ss = m["steady_error_deg"][i]
                why.append(f"2 % settling {'never' if np.isinf(ts) else f'{ts:.2f} s'}, steady error {ss:.3f} deg vs the 0.2 deg band")
            notes.append(f"{k} {ax}: " + "; ".join(why))
    return ("; ".join(notes) + ". Baseline gains are not published: ours are the notes' robust defaults (SMC/ATSM switching "
            "gains sized for the 0.5 N m disturbance; sampled switching leaves them an offset of tenths of a degree) and the "
            "stock Solo_AC35 PID.")


def _differences(results: Sequence[ModeResults], claims: Mapping[str, Sequence[ClaimResult]], solo) -> list[str]:
    """Generated explanations for claims that fail, with the numbers behind them."""
    out = []
    by = {r.name: r for r in results}
    for r in results:
        cs = {c.key: c for c in claims[r.name]}
        tag = f"Mode {r.name}"
        if not cs["C1"].passed:
            out.append(f"{tag}, C1: " + _c1_explanation(r))
        if not cs["C2"].passed:
            out.append(f"{tag}, C2: {cs['C2'].evidence}. Whether ASTSM 'converges fastest' depends on the baseline gains, which the "
                       "paper does not give; our SMC/ATSM gains exceed the perturbation bound, so their peaks are small but they keep a "
                       "sampled-switching offset.")
        if cs["C2"].passed:
            a_pk = r.m("astsm", "disturbance", "dist_peak_deg")
            larger = [k for k in ("smc", "atsm") if np.any(a_pk > r.m(k, "disturbance", "dist_peak_deg"))]
            if larger:
                out.append(f"{tag}, C2 passes on recovery time and IAE, but ASTSM's peak deviation ({axes_cell(a_pk, 2)} deg) is "
                           f"larger than {', '.join(larger)}'s on some axes; those keep a steady sampled-switching offset "
                           "instead (recovery to 0.2 deg never completes). Both readings are in the C2 numbers above.")
        if not cs["C4"].passed:
            a = r.m("astsm", "nominal", "peak_u_nm")
            out.append(f"{tag}, C4: ASTSM's peak torques are {axes_cell(a, 2)} N m (roll/pitch/yaw); failing comparisons: "
                       + cs["C4"].evidence.split(". Fails: ")[-1] + ". ASTSM's largest torques come at the reference steps: "
                       "u_eq = -I0 Λ ė applies the step demand at once (no input shaping) and the adaptive term grows with α "
                       "during the transient; the PID's output is clipped at ±τ_scale (0.4 N m on yaw) and the SMC's switching "
                       "magnitude is fixed, so they cap their peaks (and pay for it in settling or chattering).")
        if not cs["C6"].passed:
            tn, tv = r.m("astsm", "nominal", "settling_2pct_s"), r.m("astsm", "variation", "settling_2pct_s")
            out.append(f"{tag}, C6: failing comparisons: {cs['C6'].evidence.split('. Fails: ')[-1]}. ASTSM's 2 % settling goes "
                       f"from {axes_cell(tn, 2)} s (nominal) to {axes_cell(tv, 2)} s (variation). The 2 % band of a 10° step "
                       "(0.2°) is close to ASTSM's accuracy floor μ/λ ≈ 0.15°, so a small change of the residual moves its "
                       "settling time a lot, while the baselines' fixed gains are sized for a 0.5 N m disturbance and hardly "
                       "notice a +24–48 % inertia error. 'Faster than all others' is therefore decided by tuning choices the "
                       "paper does not publish.")
        if not cs["C7"].passed:
            out.append(f"{tag}, C7: {cs['C7'].evidence}. α3 does rise at events and return to α_m, but it takes longer than 0.5 s: "
                       "α decays at ϖ√(γ1/2) per second only once |σ| < μ, and |σ| stays above μ until the error has mostly converged.")
        if cs["C8"].passed is False:
            out.append(f"{tag}, C8: {cs['C8'].evidence}. Adaptation overshoots: α is driven by sgn(|σ| − μ) at a fixed rate during the "
                       "whole transient, so its peak exceeds the fixed STSM gain that reaches the same accuracy (a fixed STSM relies on "
                       "its large integral gain k2 instead).")
        if cs["C8"].passed is None:
            out.append(f"{tag}, C8 is inconclusive: no swept fixed-gain STSM (k1 up to 10x its default) reaches ASTSM's "
                       f"disturbance peak on every axis: {cs['C8'].evidence}.")
    if "E1" in by and by["E1"].has("astsm_paper", "nominal"):
        p1 = by["E1"].run("astsm_paper", "nominal").metrics
        out.append("The literal Table-2 law (torque units, ϖ = 200) does not survive a 1 ms controller period: at T = 1 ms its "
                   f"nominal run reaches α peaks {axes_cell(p1['alpha_peak'], 1)}, torque peaks {axes_cell(p1['peak_u_nm'], 1)} N m and a "
                   f"steady-window total variation of {axes_cell(p1['tv_steady_nm'], 0)} N m (see the E1 table, row astsm[astsm_paper]). "
                   "This is why the package default is the accel-units preset E1.")
    return out


def reproduction_markdown(results: Sequence[ModeResults], claims: Mapping[str, Sequence[ClaimResult]], solo, *, wall_s: float,
                          sim_wall_s: float, load_avg: float, command: str, figures: Sequence[str], workers: int) -> str:
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    var = load_scenario("variation").true_inertia(solo.inertia_diag)
    lines = [
        "# Reproduction of Hoang & Pham (2018): measured results",
        "",
        f"> Generated by `{command}` (mavastsm {__version__}, Python {platform.python_version()}, NumPy {np.__version__}) on {now}. "
        f"Do not edit by hand: rerun the command. Wall time {wall_s:.1f} s (simulation and figures {sim_wall_s:.1f} s) with {workers} "
        f"process(es) on a machine whose 1-minute load average was {load_avg:.1f} (shared, so timings are noisy).",
        "",
        "## What was simulated",
        "",
        f"* Vehicle: Table 1 of the paper with the **corrected** Iyy = {solo.inertia_yy_corrected:g} kg m² (Table 1 prints "
        f"{solo.inertia_yy_paper_literal:g}, which violates Izz ≤ Ixx + Iyy). Runs with the literal Iyy are in the tables marked "
        "'literal Iyy' and enter claim C5. Controllers know only the nominal diagonal I0.",
        "* Plant: `I ω̇ = −ω × Iω + u + d` with the full 3×3 true inertia, exact ZYX Euler kinematics, fixed-step RK4 with steps "
        "≤ 0.25 ms, controller sampled at T and held (ZOH). No sensor noise, no motor dynamics, no torque limits (paper mode).",
        "* Scenarios: *nominal* — roll −10° at 0.5 s, pitch +10° at 1.0 s, yaw +45° at 2.0 s, 5 s, Θ̇d = Θ̈d = 0; "
        "*disturbance* (D-A) — the same steps plus 0.5 N m on all three axes from 4.0 s, 7 s; *variation* — Table 3 applied as "
        "relative changes, I_true diag = (" + ", ".join(f"{x * 1e3:.2f}" for x in np.diag(var)) + ") × 10⁻³ kg m² with products "
        "of inertia (" + ", ".join(f"{x * 1e3:+.2f}" for x in (var[0, 1], var[0, 2], var[1, 2])) + ") × 10⁻³.",
        "* Modes (only the ASTSM preset and the controller period differ; every other controller keeps its default gains):",
        "",
        "| mode | controller period | ASTSM preset | meaning |",
        "|---|---|---|---|",
    ]
    for r in results:
        lines.append(f"| {r.name} | {r.dt_s * 1e3:g} ms | `{r.astsm_preset}` | {_MODE_TEXT[r.name]} |")
    lines += [
        "",
        "Controller gains used (from `configs/controllers/*.yaml`; SMC/STSM/ATSM defaults are sized for a 0.5 N m disturbance "
        "with the corrected inertia, ATSM is a reconstruction because the paper gives no ATSM law, PID is ArduCopter's cascade with "
        "the Solo_AC35 gains mapped to torque by τ_scale):",
        "",
        _gains_table(solo),
        "",
        "Choices the numbers depend on and that the paper does not fix: inertia variant, gain units of the switching term, μ "
        "(0.01 rad/s; the steady accuracy is about μ/λ ≈ 0.15°), α_max, the baseline gains, the disturbance timing and the "
        "relative reading of Table 3 (see docs/design-decisions.md, CTL-3 to CTL-12).",
        "",
        "## Claims C1–C8",
        "",
        _claims_overview(results, claims),
        "",
    ]
    for r in results:
        lines += [f"### Mode {r.name}: criteria and measured numbers", ""]
        for c in claims[r.name]:
            lines.append(f"* **{c.key} {c.verdict}** — criterion: {c.criterion}. Measured: {c.evidence}.")
        lines.append("")
    lines += ["## Where our results differ from the paper's text, and why", ""]
    lines += [f"* {t}" for t in _differences(results, claims, solo)] or ["* Every claim held."]
    lines += ["", "## Metrics", "",
              "Each cell is roll / pitch / yaw. t_s2% is judged before the disturbance onset; ∞ = still outside the band; "
              "'recovery' is the time after the disturbance onset until |e| stays below 0.2°; TV steady is the total variation of u "
              "over the 1 s before the disturbance (last 1 s without one); α peak is in the preset's units (N m for `astsm_paper`, "
              "rad/s² otherwise).", ""]
    for r in results:
        corrected = [run for (lab, scn, var_), run in r.runs.items() if var_ == "corrected"]
        literal = [run for (lab, scn, var_), run in r.runs.items() if var_ != "corrected"]
        lines += [f"### Mode {r.name} (T = {r.dt_s * 1e3:g} ms), corrected inertia", "", metrics_markdown(corrected), ""]
        if literal:
            lines += [f"<details><summary>Mode {r.name}, literal Iyy = 1.55e-3</summary>", "", metrics_markdown(literal), "", "</details>", ""]
    if figures:
        lines += ["## Figures", "", "In the spirit of the paper's Figs. 3–7 (written by `mavastsm reproduce` next to the report).", ""]
        lines += [f"![{f}](figures/{f})" for f in figures]
        lines.append("")
    return "\n".join(lines)
