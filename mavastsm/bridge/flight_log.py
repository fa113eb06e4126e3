"""Per-cycle CSV flight log: one row per control cycle, written and flushed from a timer.

The control thread only appends the (immutable) ``ControlSample`` to a list (a few hundred ns);
``flush()`` (called by the session's supervisor at least every ``timing.log_flush_s``) formats the
rows, writes and flushes them, so a kill loses at most that much. Angles in the CSV are in rad
(SI, column suffixes say so); ``failsafe`` is the FailsafeReason name or empty.
"""

from __future__ import annotations

import threading
from pathlib import Path

from ..telemetry import ControlSample

AXES = ("roll", "pitch", "yaw")
_VEC_FIELDS = (
    ("reference_rad", "ref_{}_rad"),
    ("euler_rad", "{}_rad"),
    ("euler_rate_rads", "{}_euler_rate_rads"),
    ("error_rad", "err_{}_rad"),
    ("sigma", "sigma_{}"),
    ("alpha", "alpha_{}"),
    ("beta", "beta_{}"),
    ("nu", "nu_{}"),
    ("u_eq", "u_eq_{}_nm"),
    ("u_d", "u_d_{}_nm"),
    ("u_nm", "u_{}_nm"),
)
CMD_COLUMNS = ("p_cmd_rads", "q_cmd_rads", "r_cmd_rads")
COLUMNS = (
    ("vehicle_time_s",)
    + tuple(pattern.format(axis) for _, pattern in _VEC_FIELDS for axis in AXES)
    + CMD_COLUMNS
    + ("thrust_norm", "latency_us", "failsafe")
)


def format_row(s: ControlSample) -> str:
    """One CSV line (no newline) for a sample, in COLUMNS order."""
    parts = [f"{s.vehicle_time_s:.3f}"]
    for name, _ in _VEC_FIELDS:
        parts.extend(f"{v:.6g}" for v in getattr(s, name))
    parts.extend(f"{v:.6g}" for v in s.commanded_rates_rads)
    parts.append(f"{s.thrust_norm:.4f}")
    parts.append(f"{s.latency_s * 1e6:.1f}")
    parts.append(s.failsafe.name if s.failsafe is not None else "")
    return ",".join(parts)


class FlightLog:
    """CSV writer fed by the control thread, written by ``flush``. ``path=None`` keeps nothing."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = None if path is None else str(path)
        self._pending: list[ControlSample] = []
        self._lock = threading.Lock()
        self._f = None
        self.rows = 0
        if path is not None:
            self._f = open(path, "w", encoding="utf-8", buffering=256 * 1024)
            self._f.write(",".join(COLUMNS) + "\n")
            self._f.flush()

    def append(self, sample: ControlSample) -> None:
        if self._f is None:
            return
        with self._lock:
            self._pending.append(sample)

    def flush(self) -> None:
        if self._f is None:
            return
        with self._lock:
            rows, self._pending = self._pending, []
        if rows:
            self._f.write("\n".join(format_row(r) for r in rows) + "\n")
            self.rows += len(rows)
        self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self.flush()
            self._f.close()
            self._f = None
