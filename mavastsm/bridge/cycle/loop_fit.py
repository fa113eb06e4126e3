"""The loop through the autopilot's rate controller, fitted from flown cycles (pure; ``mavastsm identify`` on a log
and the bridge's in-flight identification phase both use it).

The torque -> rate mapping (docs/bridge.md, M2) models the autopilot's closed rate loop per body axis as a
first-order lag, ``omega_dot = (omega_cmd - omega) / tau``, and sends ``omega_cmd = omega + tau_b a`` so that the
vehicle realises the body acceleration ``a = I0^-1 (u + f(omega))`` the law asks for (eq. 17). What matters to
the mapping is therefore one number per axis, the **control effectiveness** of the command: the ratio ``k`` of
the acceleration the vehicle realised to the one the law asked for, behind the loop's delay ``L``::

    omega_dot(t) = k a(t - L)                                                                              (I1)

``k = 1`` when the mapping's ``tau_b`` is the loop's. A wrong ``tau_b`` scales the realised acceleration: for a
first-order loop with time constant ``tau`` and delay ``L``, ``omega_dot (1 + L / tau) = (tau_b / tau) a(t - L)``
at low frequency, so ``k = tau_b / (tau + L)`` and the time constant the mapping should use is::

    tau_eff = tau_b / k   (= tau + L for a first-order loop with delay)                                    (I2)

whatever ``tau_b`` the flight was flown with (a flight with the wrong value identifies the right one; the tests
check it on a simulated loop, docs/bridge.md measures it on genuine ArduCopter). (I1) is fitted in its
integrated form over windows of length ``h`` (no differentiation of noisy rates; long windows weigh the
frequencies the attitude loop works at, not the chattering)::

    omega(t_k + h) - omega(t_k) = k integral_{t_k - L}^{t_k - L + h} a(s) ds                               (I3)

by least squares in ``k`` for each ``L`` of a grid, keeping the ``L`` with the best fit. ``a`` is the commanded
acceleration ``clip(I0^-1 (u + f(omega)))`` of each cycle (from a log: rebuilt from the logged torque with the
mapping its sidecar records).

Which axes a fitted tau may replace: ``tau_is_no_loop_constant``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_WINDOW_S = 0.1
DEFAULT_MAX_DELAY_S = 0.15
MIN_FIT_R2 = 0.5  # below this the fit explains too little of the rate's motion to propose a value
MIN_SAMPLES = 20  # per axis: fewer samples than this are no fit
MIN_WINDOWS = 10  # per axis and delay: integrated windows (I3) in the least squares


@dataclass(frozen=True)
class AxisFit:
    """(I1) fitted on one axis.

    Attributes
    ----------
    effectiveness : [-] k, realised / commanded body acceleration (NaN when the data cannot determine it)
    delay_s : [s] L
    r2 : [-] share of the variance of the rate increments (I3) that the fit explains
    windows : [-] windows used
    why_not : why the data could not determine k ("" when it did)
    """

    effectiveness: float
    delay_s: float
    r2: float
    windows: int
    why_not: str = ""


def fit_effectiveness(t_s, accel_radss, rate_rads, window_s: float = DEFAULT_WINDOW_S,
                      max_delay_s: float = DEFAULT_MAX_DELAY_S) -> AxisFit:
    """Fit ``rate_dot(t) = k accel(t - L)`` (I1) on one axis in its integrated form (I3).

    Parameters
    ----------
    t_s : [s] (n,) sample times (irregular spacing and repeated times allowed: resampled to a uniform grid at the
        median spacing)
    accel_radss : [rad/s^2] (n,) the body acceleration the law asked for
    rate_rads : [rad/s] (n,) the measured body rate
    window_s : [s] h of (I3)
    max_delay_s : [s] largest L tried (grid step = the resampling step)
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(accel_radss, dtype=float)
    w = np.asarray(rate_rads, dtype=float)
    ok = np.isfinite(t) & np.isfinite(a) & np.isfinite(w)
    t, a, w = t[ok], a[ok], w[ok]
    def none(why: str) -> AxisFit:
        return AxisFit(float("nan"), float("nan"), float("nan"), 0, why)

    order = np.argsort(t, kind="stable")
    t, a, w = t[order], a[order], w[order]
    keep = np.concatenate(([True], np.diff(t) > 0)) if t.size else np.zeros(0, dtype=bool)
    t, a, w = t[keep], a[keep], w[keep]  # ATTITUDE pairs with one time_boot_ms: the first of each
    if t.size < MIN_SAMPLES:
        return none(f"{t.size} samples (the fit needs at least {MIN_SAMPLES})")
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], dt)
    ag, wg = np.interp(grid, t, a), np.interp(grid, t, w)
    m = max(1, int(round(window_s / dt)))
    integral = np.concatenate(([0.0], np.cumsum(0.5 * (ag[1:] + ag[:-1]) * dt)))
    moved = wg[m:] - wg[:-m]  # omega(t_k + h) - omega(t_k), k = 0 .. N - m - 1
    pushed = integral[m:] - integral[:-m]  # integral of a over [t_k, t_k + h]
    if moved.size < MIN_WINDOWS:
        return none(f"{t[-1] - t[0]:.2f} s of data, shorter than the {window_s:g} s window and {MIN_WINDOWS} samples")
    best: AxisFit | None = None
    still = True
    for n in range(0, int(round(max_delay_s / dt)) + 1):
        y, x = moved[n:], pushed[:pushed.size - n]  # a delayed by n steps
        if x.size < MIN_WINDOWS:
            break
        sxx, syy = float(x @ x), float(((y - y.mean()) ** 2).sum())
        if sxx <= 0.0 or syy <= 0.0:
            continue
        still = False
        k = float(x @ y) / sxx
        r2 = 1.0 - float(((y - k * x) ** 2).sum()) / syy
        if best is None or r2 > best.r2:
            best = AxisFit(k, n * dt, r2, int(x.size))
    if best is None:
        return none("neither the command nor the rate moved" if still else "no delay in the grid leaves windows to fit")
    if not best.effectiveness > 0:
        return none(f"the rate moved against the command (k {best.effectiveness:.2f}, R² {best.r2:.2f}): "
                    "something else (a disturbance, a limit) drove this axis")
    return best


def effective_time_constant(flown_tau_s: float, fit: AxisFit) -> float:
    """tau_eff = tau_b / k (I2) [s]."""
    return flown_tau_s / fit.effectiveness if fit.effectiveness > 0 else float("nan")


def tau_is_no_loop_constant(axis: int, yaw_from_reference: bool, roll_pitch_integrated: bool) -> bool:
    """tau is a tuning gain, not a rate-loop constant a fit can replace: yaw built on the reference (M6), roll and
    pitch integrated (M9, where tau only adds to the delay that bounds the adaptive gain)."""
    return (axis == 2 and yaw_from_reference) or (axis < 2 and roll_pitch_integrated)
