"""What one sweep run flies, the same at both levels: its scenario (reference, torques, inertia, payload), its sensor
noise, and how its outcome is classified from its metrics.

Outcomes (the table's ``outcome`` column): ``settled`` (flown to the end within the spec's bounds), ``degraded``
(flown to the end, a bound missed), and failures: ``envelope_breach`` (offline: |roll| or |pitch| beyond the
bridge's envelope_tilt_deg, which at the MAVLink level is the ENVELOPE_BREACH failsafe), ``diverged`` (offline:
the body rate ran away), ``failsafe:<REASON>`` (MAVLink: the bridge's failsafe that ended the run), ``error:start`` (MAVLink: the run could
not start flying, e.g. the link closed during connect; the message is in ``end_reason``).
"""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache

import numpy as np

from ..frames import AXES
from ..scenarios import Scenario, TorqueEvent, load_scenario
from .spec import VARIABLES, SweepSpec

FAILURES = ("envelope_breach", "diverged")  # plus every "failsafe:*"


def is_failure(outcome: str) -> bool:
    return outcome in FAILURES or outcome.startswith(("failsafe:", "error:"))


@lru_cache(maxsize=None)
def _table3_delta() -> np.ndarray:
    """The paper's Table 3 relative inertia variation (the packaged ``variation`` scenario's delta) [-]."""
    return np.asarray(load_scenario("variation").inertia_delta, dtype=float)


def value(row: dict, name: str) -> float:
    """The run's value of a variable, its nominal one when the sweep does not vary it."""
    return float(row.get(name, VARIABLES[name].nominal))


def base_scenario(spec: SweepSpec) -> Scenario:
    """The spec's scenario with its reference and duration replaced as the spec says."""
    scn = load_scenario(spec.scenario)
    if spec.reference is not None:
        from ..references import load_reference

        ref = load_reference(spec.reference)
        scn = dataclasses.replace(scn, reference=ref, duration_s=ref.duration_s)
    if spec.duration_s is not None:
        scn = dataclasses.replace(scn, duration_s=spec.duration_s)
    return scn


def run_scenario(base: Scenario, row: dict, vehicle_mass_kg: float) -> Scenario:
    """``base`` plus the run's swept torque (a step, or a pulse with disturbance_duration_s), inertia variation
    (relative, paper Table 3 form: I_true = I0 + delta o sqrt(diag I0) sqrt(diag I0)^T) and payload."""
    torque = tuple(value(row, f"disturbance_{a}_nm") for a in AXES)
    events = base.disturbances
    if any(torque):
        start = value(row, "disturbance_start_s")
        events = events + (TorqueEvent(start, start + value(row, "disturbance_duration_s"), torque),)
    mode, delta = base.inertia_mode, np.asarray(base.inertia_delta, dtype=float)
    swept = value(row, "inertia_table3_scale") * _table3_delta() + np.diag([value(row, f"inertia_{a}_rel") for a in ("xx", "yy", "zz")])
    if np.any(swept):  # load_sweep refuses swept inertia on a base scenario with an absolute (kg m^2) variation
        delta = (delta if mode == "relative" else 0.0) + swept
        mode = "relative"
    payload = base.payload_mass_kg + value(row, "mass_rel") * vehicle_mass_kg
    return dataclasses.replace(base, disturbances=events, inertia_mode=mode, inertia_delta=tuple(map(tuple, delta.tolist())),
                               payload_mass_kg=payload)


def classify(metrics: dict, failure: str | None, bounds: dict[str, tuple[float, float, float]]) -> str:
    """``failure`` when set, else ``settled`` when every bound holds on every axis that has the metric, else ``degraded``."""
    if failure:
        return failure
    for key, limits in bounds.items():
        for axis, limit in zip(AXES, limits):
            x = metrics.get(f"{key}_{axis}", math.nan)
            if isinstance(x, float) and math.isnan(x):
                continue  # no step on that axis: no settling time or overshoot to judge
            if not x <= limit:
                return "degraded"
    return "settled"
