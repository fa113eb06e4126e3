"""Per-axis tracking metrics of a bridge run (pure; docs/design-decisions.md, CTL-13 definitions).

Computed from the recorded ``ControlSample`` rows (vehicle clock) and the reference's step events,
so the same numbers come out of a live run, a SITL test or a benchmark.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from ...frames import AXES, wrap_angle_float
from ...step_metrics import overshoot_pct, settling_time_s
from ...telemetry import ControlSample



@dataclass(frozen=True)
class AxisMetrics:
    """Tracking quality of one axis. Angles in deg (reporting edge), times in s from engagement.

    settling_time_5pct_s / overshoot_pct are NaN for an axis without a step; settling is +inf when the
    error is still outside the 5 % band at the end of the run.
    """

    axis: str
    step_time_s: float
    step_size_deg: float
    settling_time_5pct_s: float
    overshoot_pct: float
    steady_error_deg: float
    max_abs_error_deg: float
    rms_error_deg: float
    iae_deg_s: float


def axis_metrics(rows: Sequence[tuple[float, float]], axis: int, step_time_s: float | None,
                 step_size_rad: float, steady_window_s: float = 0.5) -> AxisMetrics:
    """Metrics of one axis from (time since engagement [s], error [rad]) rows."""
    rows = [(t, e) for t, e in rows if math.isfinite(e)]
    nan = float("nan")
    if not rows:
        return AxisMetrics(AXES[axis], nan, nan, nan, nan, nan, nan, nan, nan)
    t_end = rows[-1][0]
    errs = [e for _, e in rows]
    iae = 0.0
    for (t0, e0), (t1, _) in zip(rows, rows[1:]):
        iae += abs(e0) * (t1 - t0)
    steady = [abs(e) for t, e in rows if t >= t_end - steady_window_s]
    settle = over = nan
    if step_time_s is not None and step_size_rad != 0.0 and t_end >= step_time_s:
        t = [t for t, _ in rows]  # the one definition (step_metrics), as offline and the tests use it
        settle = settling_time_s(t, errs, 0.05 * abs(step_size_rad), step_time_s)
        over = overshoot_pct(t, errs, step_size_rad, step_time_s)
    return AxisMetrics(
        AXES[axis],
        step_time_s if step_time_s is not None else nan,
        math.degrees(step_size_rad) if step_time_s is not None else nan,
        settle,
        over,
        math.degrees(sum(steady) / len(steady)) if steady else nan,
        math.degrees(max(abs(e) for e in errs)),
        math.degrees(math.sqrt(sum(e * e for e in errs) / len(errs))),
        math.degrees(iae),
    )


def raw_errors(samples: Sequence[ControlSample], engage_time_s: float, reference) -> list[tuple[float, tuple[float, float, float]]]:
    """(t since engagement, Theta - Theta_d_raw) per controlled sample, against the *unshaped* reference
    (``reference.at``), yaw wrapped. Samples with a failsafe, and the identification phase's, are left out."""
    out = []
    for s in samples:
        if s.failsafe is not None or not math.isfinite(s.u_nm[0]) or s.identifying:
            continue
        t = s.vehicle_time_s - engage_time_s
        ref = reference.at(t)[0]
        e = [s.euler_rad[i] - float(ref[i]) for i in range(3)]
        e[2] = wrap_angle_float(e[2])
        out.append((t, tuple(e)))
    return out


def run_metrics(samples: Sequence[ControlSample], engage_time_s: float, reference) -> tuple[AxisMetrics, AxisMetrics, AxisMetrics]:
    """Metrics for roll, pitch, yaw against the raw reference; step events from ``reference.event_times_s``."""
    errs = raw_errors(samples, engage_time_s, reference) if math.isfinite(engage_time_s) else []
    out = []
    for axis in range(3):
        rows = [(t, e[axis]) for t, e in errs]
        step_t, size = None, 0.0
        events = getattr(reference, "event_times_s", None)
        if events is not None:
            times = events(axis)
            if times:
                step_t, size = times[0], float(reference.step_size_rad(axis))
        out.append(axis_metrics(rows, axis, step_t, size))
    return tuple(out)  # type: ignore[return-value]


def format_metrics_table(metrics: Sequence[AxisMetrics]) -> str:
    """Plain-text table, one line per axis. Never prints ``nan``: a figure that does not exist is "—" and a
    footnote says why (no step on that axis, or no engaged cycle at all); a settling time never reached is "never"."""
    def cell(x: float, spec: str, width: int) -> str:
        if math.isnan(x):
            return f"{'—':>{width}}"
        if math.isinf(x):
            return f"{'never':>{width}}"
        return f"{x:{width}{spec}}"

    if not metrics or all(math.isnan(m.max_abs_error_deg) for m in metrics):
        return "tracking metrics: none (the profile never engaged, so there is no tracking error to measure)"
    head = f"{'axis':6} {'step':>8} {'t_s5%':>7} {'OS%':>6} {'steady':>7} {'max|e|':>7} {'rms':>6}"
    lines = [head]
    for m in metrics:
        lines.append(
            f"{m.axis:6} {cell(m.step_size_deg, '.1f', 8)} {cell(m.settling_time_5pct_s, '.3f', 7)} {cell(m.overshoot_pct, '.1f', 6)} "
            f"{cell(m.steady_error_deg, '.3f', 7)} {cell(m.max_abs_error_deg, '.2f', 7)} {cell(m.rms_error_deg, '.2f', 6)}"
        )
    if any(math.isnan(m.settling_time_5pct_s) for m in metrics):
        lines.append("— = no step on that axis in the reference (settling and overshoot need one)")
    return "\n".join(lines)


@dataclass(frozen=True)
class HoldMetrics:
    """Whether an axis *stays* settled (the limit-cycle checks). Angles in deg, times in s.

    hold_pp_deg : peak-to-peak of the error over the last ``window_s`` of the run (a limit cycle shows here)
    cmd_at_limit_pct : share of the cycles after the axis settled whose body-rate command sat at its limit
    alpha_recovery_s : after the run's last step on this axis, the time until alpha is back within
        ``2 alpha_min`` (NaN without an adaptive gain, +inf when it never comes back)
    """

    axis: str
    hold_pp_deg: float
    cmd_at_limit_pct: float
    alpha_recovery_s: float


def hold_metrics(samples: Sequence[ControlSample], engage_time_s: float, reference, axes: Sequence[AxisMetrics],
                 max_rate_rads: Sequence[float], alpha_min: float | Sequence[float] | None, window_s: float = 1.0) -> tuple[HoldMetrics, ...]:
    """HoldMetrics per axis from the same rows as ``run_metrics`` (errors against the raw reference).

    A command is "at its limit" within 1 % of ``max_rate_rads``. The settled part of an axis starts at its
    step time + 5 % settling time (an axis that never settles has no settled part: 100 %). ``alpha_min`` is per axis
    (or one value for all): the adaptive gain's floor alpha_m on each axis. (With the bridge's loop-delay bound
    alpha_max = 2 alpha_m, so alpha is within 2 alpha_m by construction; the check catches a runaway gain. The
    comparison allows 1e-4 relative: a flight CSV keeps 6 significant digits.)"""
    floors = None if alpha_min is None else (tuple(float(a) for a in alpha_min) if hasattr(alpha_min, "__len__") else (float(alpha_min),) * 3)
    rows = engaged_samples(samples)
    errs = raw_errors(rows, engage_time_s, reference) if math.isfinite(engage_time_s) else []
    out = []
    for axis in range(3):
        if not errs:
            out.append(HoldMetrics(AXES[axis], float("nan"), float("nan"), float("nan")))
            continue
        t_end = errs[-1][0]
        last = [e[axis] for t, e in errs if t >= t_end - window_s]
        pp = math.degrees(max(last) - min(last)) if last else float("nan")
        m = axes[axis]
        settled_from = (m.step_time_s + m.settling_time_5pct_s) if math.isfinite(m.step_time_s) else 0.0
        at_limit = at_limit_pct(rows, engage_time_s, settled_from, axis, max_rate_rads[axis])
        recovery = float("nan")
        if floors is not None and math.isfinite(m.step_time_s):
            # back within 2 alpha_m and staying there: after the last sample above it (0 when it never left)
            above = [s.vehicle_time_s - engage_time_s for s in rows
                     if s.vehicle_time_s - engage_time_s >= m.step_time_s and s.alpha[axis] > 2.0 * floors[axis] * (1.0 + 1e-4)]
            recovery = 0.0 if not above else (math.inf if above[-1] >= t_end - 1e-9 else above[-1] - m.step_time_s)
        out.append(HoldMetrics(AXES[axis], pp, at_limit, recovery))
    return tuple(out)


def at_limit_pct(engaged: Sequence[ControlSample], engage_time_s: float, from_s: float, axis: int, max_rate_rads: float) -> float:
    """The share [%] of the ``engaged`` rows from ``from_s`` [s after engagement] on whose body-rate command on ``axis``
    sat at its limit, within 1 % of ``max_rate_rads`` [rad/s]; 100 when no row is that late (an axis that never got
    there: ``from_s`` inf)."""
    after = [s for s in engaged if s.vehicle_time_s - engage_time_s >= from_s]
    lim = 0.99 * float(max_rate_rads)
    return 100.0 * sum(abs(s.commanded_rates_rads[axis]) >= lim for s in after) / len(after) if after else 100.0


def engaged_samples(samples: Sequence[ControlSample]) -> list[ControlSample]:
    """The control cycles of a flight: rows with a finite torque and no failsafe (takeoff, level hold and hand-back
    rows of a flight log have neither), the in-flight identification phase's excitation left out."""
    return [s for s in samples if s.failsafe is None and math.isfinite(s.u_nm[0]) and not s.identifying]


def heading_at_engagement_rad(engaged: Sequence[ControlSample]) -> float:
    """[rad, NED yaw] the heading a flight's reference is relative to: the reference's yaw at the first engaged row,
    else (a flight whose rows carry no reference) the vehicle's yaw there."""
    yaw = engaged[0].reference_rad[2]
    return yaw if math.isfinite(yaw) else engaged[0].euler_rad[2]


def flight_metrics(samples: Sequence[ControlSample], reference, max_rate_rads: Sequence[float]):
    """(run_metrics, hold_metrics) of one flight against the raw ``reference`` (a ReferenceProfile whose yaw is
    relative to the heading at engagement, as the bridge flies it); the adaptive gain's floor per axis is its value
    at engagement (the law starts each flight at alpha_m). None when the flight never engaged."""
    engaged = engaged_samples(samples)
    if not engaged:
        return None
    engage_t = engaged[0].vehicle_time_s
    ref = reference.relative_to((0.0, 0.0, heading_at_engagement_rad(engaged)))
    axes = run_metrics(samples, engage_t, ref)
    alpha0 = engaged[0].alpha
    holds = hold_metrics(samples, engage_t, ref, axes, max_rate_rads, alpha0 if all(map(math.isfinite, alpha0)) else None)
    return axes, holds
