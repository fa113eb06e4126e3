"""Per-cycle CSV flight log: one row per control cycle, written and flushed from a timer.

The control thread only appends the (immutable) ``ControlSample`` to a list (a few hundred ns);
``flush()`` (called by the session's supervisor at least every ``timing.log_flush_s``) formats the
rows, writes and flushes them, so a kill loses at most that much. Angles in the CSV are in rad
(SI, column suffixes say so); ``refused_frames`` is how many frames the link had refused by then (bad CRC,
garbage, unsigned, bad signature, replayed; cumulative); ``failsafe`` is the FailsafeReason name or empty.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from ..state_types import FailsafeReason
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
    + ("thrust_norm", "latency_us", "refused_frames", "failsafe")
)


# vehicle_time_s, the per-axis vectors and commanded rates (6 significant digits), thrust, latency [us],
# refused frames so far, failsafe
_ROW_FORMAT = ",".join(("%.3f",) + ("%.6g",) * (len(AXES) * len(_VEC_FIELDS) + len(CMD_COLUMNS)) + ("%.4f", "%.1f", "%d", "%s"))
_VEC_NAMES = tuple(name for name, _ in _VEC_FIELDS)


def format_row(s: ControlSample, refused_frames: int = 0) -> str:
    """One CSV line (no newline) for a sample, in COLUMNS order (one precompiled %-format: about 7 us,
    half the cost of formatting each field separately, which matters on the loop's two cores)."""
    values = [s.vehicle_time_s]
    for name in _VEC_NAMES:
        values.extend(getattr(s, name))
    values.extend(s.commanded_rates_rads)
    values.append(s.thrust_norm)
    values.append(s.latency_s * 1e6)
    values.append(refused_frames)
    values.append(s.failsafe.name if s.failsafe is not None else "")
    return _ROW_FORMAT % tuple(values)


# the unit of every CSV column (the sidecar's "columns"; the names carry them too where they can)
COLUMN_UNITS = {"vehicle_time_s": "s"}
for _name, _pattern in _VEC_FIELDS:
    for _axis in AXES:
        COLUMN_UNITS[_pattern.format(_axis)] = {"reference_rad": "rad", "euler_rad": "rad", "euler_rate_rads": "rad/s", "error_rad": "rad",
                                                "sigma": "rad/s", "alpha": "controller gain units", "beta": "controller gain units",
                                                "nu": "N m or rad/s^2 (gain_units)", "u_eq": "N m", "u_d": "N m", "u_nm": "N m"}[_name]
COLUMN_UNITS.update({c: "rad/s (body FRD)" for c in CMD_COLUMNS})
COLUMN_UNITS.update({"thrust_norm": "0..1 (climb rate or collective, see thrust_semantics)", "latency_us": "us",
                     "refused_frames": "count (cumulative)", "failsafe": "FailsafeReason name or empty"})


def metadata_path(csv_path: str | Path) -> Path:
    """The sidecar of a flight CSV: same name, ``.json``."""
    return Path(csv_path).with_suffix(".json")


def write_metadata(csv_path: str | Path, meta: dict) -> Path:
    """Write the sidecar (what flew: controller and gains, vehicle, autopilot and version, URL, project version,
    and the unit of every column) next to the CSV."""
    import json

    path = metadata_path(csv_path)
    path.write_text(json.dumps({**meta, "columns": COLUMN_UNITS}, indent=1, default=str) + "\n", encoding="utf-8")
    return path


def read_metadata(csv_path: str | Path) -> dict:
    """The sidecar of a flight CSV, or {} when it has none (an older log) or it is unreadable."""
    import json

    try:
        return json.loads(metadata_path(csv_path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


ROWS_PER_WRITE = 32  # rows formatted between two GIL hand-overs (about 0.2 ms of CPU)


class FlightLog:
    """CSV writer fed by the control thread, written by ``flush``. ``path=None`` keeps nothing."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = None if path is None else str(path)
        self._pending: list[tuple[ControlSample, int]] = []
        self._lock = threading.Lock()
        self._f = None
        self.rows = 0
        if path is not None:
            self._f = open(path, "w", encoding="utf-8", buffering=256 * 1024)
            self._f.write(",".join(COLUMNS) + "\n")
            self._f.flush()

    def append(self, sample: ControlSample, refused_frames: int = 0) -> None:
        """Queue one row; ``refused_frames`` = the link's refused-frame count at this cycle."""
        if self._f is None:
            return
        with self._lock:
            self._pending.append((sample, refused_frames))

    def flush(self) -> None:
        if self._f is None:
            return
        with self._lock:
            rows, self._pending = self._pending, []
        for i in range(0, len(rows), ROWS_PER_WRITE):
            if i:
                # let a waiting control thread have the GIL: formatting 200 rows in one go held it for 5-8 ms,
                # which made the reader miss ATTITUDE samples at 400 Hz every flush (docs/bridge.md, latency)
                time.sleep(0)
            chunk = rows[i:i + ROWS_PER_WRITE]
            self._f.write("".join([format_row(r, n) + "\n" for r, n in chunk]))
            self.rows += len(chunk)
        self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self.flush()
            self._f.close()
            self._f = None


def read_flight_log(path: str | Path) -> list[ControlSample]:
    """The rows of a flight CSV written by FlightLog, back as ControlSamples (the inverse of ``format_row``).

    A row cut short by a kill (the last line) is skipped. Raises OSError for an unreadable file and
    ValueError naming the file when the header is not this format's.
    """
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    if not lines or tuple(lines[0].split(",")) != COLUMNS:
        raise ValueError(f"{path}: not a mavastsm flight log (header differs from mavastsm.bridge.flight_log.COLUMNS)")
    n_vec = len(AXES) * len(_VEC_FIELDS)
    out = []
    for line in lines[1:]:
        cells = line.split(",")
        if len(cells) != len(COLUMNS):
            continue
        try:
            nums = [float(c) for c in cells[:-1]]
        except ValueError:
            continue
        vecs = {name: tuple(nums[1 + 3 * i: 4 + 3 * i]) for i, name in enumerate(_VEC_NAMES)}
        cmd = tuple(nums[1 + n_vec: 4 + n_vec])
        thrust, latency_us = nums[4 + n_vec], nums[5 + n_vec]  # nums[6 + n_vec]: refused_frames
        out.append(ControlSample(nums[0], commanded_rates_rads=cmd, thrust_norm=thrust, latency_s=latency_us * 1e-6,
                                 failsafe=FailsafeReason[cells[-1]] if cells[-1] else None, **vecs))
    return out
