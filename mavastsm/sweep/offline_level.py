"""The torque-level sweep: a chunk of runs is one batch of the offline simulator (``simulate_runs``: one batched
RK4 plant, one batched controller state per controller), then every run's metrics (``compute_metrics``).

A chunk is the unit of work handed to an executor. Chunks are cut from the run list by the spec's
``chunk_runs`` alone, so the same runs are always integrated together: the table does not depend on the
executor, the number of workers or on a resume.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..offline.metrics import compute_metrics
from ..offline.simulator import RunSpec, simulate_runs
from ..solo_model import load_solo
from .run_inputs import AXES, base_scenario, classify, run_scenario, value
from .spec import SweepSpec

#: [s] largest RK4 step of the sweep's plant: one step per 1 ms control period (``mavastsm simulate`` uses 0.25 ms;
#: on the example sweep the metrics differ by well under the bounds' resolution, docs/sweep.md)
SWEEP_RK4_STEP_S = 1e-3


def _envelope_tilt_rad() -> float:
    from ..bridge.bridge_config import load_bridge_config

    return load_bridge_config(None, {}).limits.envelope_tilt_rad


def _sensor_noise_std() -> tuple[float, float]:
    """(attitude [rad], gyro [rad/s]) white-noise std of the packaged vehicle (its ``sensor_noise`` section)."""
    from ..config_loading import load_section, resolve_config

    sec = load_section(resolve_config("solo", "vehicle"), "sensor_noise")
    return float(sec["attitude_noise_std"].value), float(sec["gyro_noise_std"].value)


def run_specs(spec: SweepSpec, rows: list[dict]) -> list[RunSpec]:
    """The offline simulator's RunSpec of each sweep row."""
    solo = load_solo()
    base = base_scenario(spec)
    att, gyro = _sensor_noise_std()
    by_label = {c.label: c for c in spec.controllers}
    out = []
    for row in rows:
        c = by_label[row["controller"]]
        k = value(row, "sensor_noise_scale")
        out.append(RunSpec(c.key, run_scenario(base, row, solo.mass), config=c.preset, label=c.label,
                           sensor_noise_std=(k * att, k * gyro), noise_seed=int(row["seed"])))
    return out


def run_chunk(spec: SweepSpec, rows: list[dict]) -> list[dict]:
    """Simulate ``rows`` as one batch; returns one table row per run: its inputs, ``level``, ``outcome``,
    ``failure_time_s`` and every metric of ``compute_metrics`` per axis, plus max |e| per axis and the max tilt."""
    results = simulate_runs(run_specs(spec, rows), dt_control_s=spec.dt_control_s, max_substep_s=min(SWEEP_RK4_STEP_S, spec.dt_control_s))
    envelope = _envelope_tilt_rad()
    out = []
    for row, res in zip(rows, results):
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            m = compute_metrics(res)
            err_deg = np.degrees(np.abs(res.error_rad))
            tilt = np.max(np.abs(res.euler_rad[:, 0:2]), axis=1)
        metrics = {f"{k}_{a}": float(v[i]) for k, v in m.items() for i, a in enumerate(AXES)}
        metrics.update({f"max_abs_error_deg_{a}": float(np.nanmax(err_deg[:, i])) for i, a in enumerate(AXES)})
        metrics["max_tilt_deg"] = float(np.degrees(np.nanmax(tilt)))
        breach = np.nonzero(~(tilt <= envelope))[0]
        failure, t_fail = None, math.nan
        if math.isfinite(res.diverged_at_s):
            failure, t_fail = "diverged", res.diverged_at_s
        if breach.size:  # the bridge would have stopped at the first sample beyond the envelope
            failure, t_fail = "envelope_breach", float(res.t_s[breach[0]])
        out.append({**row, "level": "offline", "outcome": classify(metrics, failure, spec.bounds), "failure_time_s": t_fail,
                    "nonfinite_outputs": res.nonfinite_outputs, **metrics})
    return out
