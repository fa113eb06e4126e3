"""The closed-loop sweep: one run = the offboard bridge flying the simulated Solo over loopback UDP, through the
impairment proxy (``mavastsm_sim.impairment_proxy``), in lockstep (the sim waits for each answer, so a loaded
machine slows a run down and never changes its result), each pair on its own ephemeral ports.

The run: GUIDED, arm, climb to 0.5 m, then the spec's reference for its duration with the run's torques (their
clock starts at engagement), inertia variation and payload in the sim, the sim's sensor noise scaled by
``sensor_noise_scale``, the link's loss / delay / jitter in both directions, and the bridge's assumed rate-loop
time constant and loop delay when swept. Metrics: the bridge's own (``tracking_metrics.flight_metrics``: per
axis settling, overshoot, steady, max and RMS error, IAE, hold peak-to-peak, commands at their limit, alpha
recovery), the largest tilt, and the failsafe that ended the run, if any.
"""

from __future__ import annotations

import dataclasses
import math

from ..errors import ConfigError, LinkError, OffboardRejected
from .run_inputs import AXES, base_scenario, classify, run_scenario, value
from .spec import SweepSpec

CONTROL_RATE_HZ = 400.0
TAKEOFF_ALT_M = 0.5
RUN_TIMEOUT_S = 300.0  # [s] wall time one run may take before it is reported as stuck


def _bridge_overrides(row: dict) -> dict:
    from ..lockstep_pair import IN_PROCESS_OVERRIDES

    over = dict(IN_PROCESS_OVERRIDES)
    if "rate_time_constant_s" in row:
        over["mapping.rate_time_constant_s"] = [row["rate_time_constant_s"]] * 3
    if "loop_delay_s" in row:
        from ..bridge.bridge_config import load_bridge_config

        yaw = load_bridge_config(None, {}).mapping.loop_delay_s[2]
        over["mapping.loop_delay_s"] = [row["loop_delay_s"], row["loop_delay_s"], yaw]
    return over


def fly(spec: SweepSpec, row: dict) -> dict:
    """One run; returns its table row (inputs, ``level``, ``outcome``, ``failure_time_s``, metrics)."""
    from mavastsm_sim.impairment_proxy import ImpairmentSettings

    from ..bridge.bridge_config import load_bridge_config
    from ..bridge.record.tracking_metrics import engaged_samples, flight_metrics
    from ..lockstep_pair import LockstepPair
    from ..solo_model import load_solo

    by_label = {c.label: c for c in spec.controllers}
    ctrl = by_label[row["controller"]]
    seed = int(row["seed"])
    scenario = run_scenario(base_scenario(spec), row, load_solo().mass)
    noise_scale = value(row, "sensor_noise_scale")
    link = ImpairmentSettings(loss=value(row, "link_loss"), delay_s=value(row, "link_delay_s"), jitter_s=value(row, "link_jitter_s"))
    # the link is clean for connect, arm and take-off; its faults start with the profile, at engagement (as the torques do)
    pair = LockstepPair(scenario, seed=seed, sim=dict(noise=noise_scale > 0.0, sched_loop_rate_hz=500.0), proxy={},
                        on_engage=lambda _t: pair.proxy.configure("both", settings=link))
    if noise_scale > 0.0:
        cfg = pair.server.copter.config
        n = cfg.sensor_noise
        pair.server.copter.config = dataclasses.replace(cfg, sensor_noise=dataclasses.replace(
            n, **{f.name: getattr(n, f.name) * noise_scale for f in dataclasses.fields(n)}))
    summary = None
    error = ""
    try:
        pair.start()
        pair.start_bridge(controller=ctrl.key, controller_config=ctrl.preset, reference=scenario.reference,
                          duration_s=scenario.duration_s, rate_hz=CONTROL_RATE_HZ, mode="GUIDED", arm=True,
                          takeoff_alt_m=TAKEOFF_ALT_M, on_exit="none", on_failsafe="none", overrides=_bridge_overrides(row))
        summary = pair.wait(RUN_TIMEOUT_S)
        if summary is None:
            summary = pair.bridge.stop(timeout_s=15.0)
    except (LinkError, ConfigError, OffboardRejected) as exc:  # this run could not fly: a row, not the end of the sweep
        error = f"{type(exc).__name__}: {exc}"
    finally:
        pair.stop()
    return _row(spec, row, summary, error, load_bridge_config(None, {}).limits, flight_metrics, engaged_samples)


def _row(spec: SweepSpec, row: dict, summary, error: str, limits, flight_metrics, engaged_samples) -> dict:
    metrics: dict[str, float] = {}
    fm = flight_metrics(summary.samples, base_scenario(spec).reference, limits.max_rate_cmd_rads) if summary is not None else None
    if fm is not None:
        axes, holds = fm
        for m, h, a in zip(axes, holds, AXES):
            metrics.update({f"settling_5pct_s_{a}": m.settling_time_5pct_s, f"overshoot_pct_{a}": m.overshoot_pct,
                            f"steady_error_deg_{a}": m.steady_error_deg, f"max_abs_error_deg_{a}": m.max_abs_error_deg,
                            f"rms_error_deg_{a}": m.rms_error_deg, f"iae_deg_s_{a}": m.iae_deg_s, f"hold_pp_deg_{a}": h.hold_pp_deg,
                            f"cmd_at_limit_pct_{a}": h.cmd_at_limit_pct, f"alpha_recovery_s_{a}": h.alpha_recovery_s})
    engaged = engaged_samples(summary.samples) if summary is not None else []
    metrics["max_tilt_deg"] = max((math.degrees(max(abs(s.euler_rad[0]), abs(s.euler_rad[1]))) for s in engaged), default=math.nan)
    failure, t_fail = None, math.nan
    if error:
        failure = "error:start"
    elif summary is None or not engaged:
        failure = f"failsafe:{summary.failsafe.name if summary is not None and summary.failsafe else 'NOT_ENGAGED'}"
    elif summary.failsafe is not None:
        failure = f"failsafe:{summary.failsafe.name}"
        t_fail = next((s.vehicle_time_s - summary.engage_time_s for s in summary.samples if s.failsafe is not None), math.nan)
    extra = {"end_reason": summary.end_reason if summary is not None else (error or "no summary"),
             "cycles": summary.cycles if summary is not None else 0,
             "latency_p99_s": summary.latency_p99_s if summary is not None else math.nan}
    return {**row, "level": "mavlink", "outcome": classify(metrics, failure, spec.bounds), "failure_time_s": t_fail, **extra, **metrics}


def run_unit(spec: SweepSpec, rows: list[dict]) -> list[dict]:
    """The executor's unit of work at this level: each row flown by its own bridge + sim pair."""
    return [fly(spec, r) for r in rows]
