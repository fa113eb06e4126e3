"""The step-response metrics, written once: the offline simulator, the bridge's summary and the tests use these.

Settling time: from the step until the error is back inside the band for good, i.e. the time of the first sample
after the last one outside the band (0 when it never left, inf when the last sample is still outside, NaN for an
empty window; a NaN error counts as outside). Overshoot: the largest error past the new value, in the step's
direction, as % of the step size (never negative; NaN for an empty window).
"""

from __future__ import annotations

import math

import numpy as np


def settling_time_s(t_s, err, band, t_start, t_end=math.inf) -> float:
    """Settling time [s] after ``t_start`` of ``err`` within ``band`` (same unit as err), samples in [t_start, t_end)."""
    t_s, err = np.asarray(t_s, dtype=float), np.asarray(err, dtype=float)
    m = (t_s >= t_start) & (t_s < t_end)
    tt, ee = t_s[m], np.abs(err[m])
    if tt.size == 0:
        return float("nan")
    outside = np.nonzero(~(ee <= band))[0]  # NaN counts as outside
    if outside.size == 0:
        return 0.0
    if outside[-1] == tt.size - 1:
        return float("inf")
    return float(tt[outside[-1] + 1] - t_start)


def overshoot_pct(t_s, err, step_size, t_start, t_end=math.inf) -> float:
    """Overshoot [%] of a step of ``step_size`` (err = measured - reference, same unit), samples in [t_start, t_end)."""
    t_s, err = np.asarray(t_s, dtype=float), np.asarray(err, dtype=float)
    win = (t_s >= t_start) & (t_s < t_end)
    if not win.any():
        return float("nan")
    return max(float(np.max(np.sign(step_size) * err[win]) / abs(step_size) * 100.0), 0.0)
