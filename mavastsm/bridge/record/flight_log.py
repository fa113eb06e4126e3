"""Per-cycle CSV flight log: one row per ATTITUDE sample the bridge acted on, written and flushed from a timer.

The rows of every phase of the flight the bridge commands: ``takeoff`` (the bounded climb and its settle),
``engaged`` (the controller's cycles), ``level_hold`` (a stop or failsafe hold) and ``handback`` (while the
hand-back mode is requested and confirmed), plus one row per failsafe event. The ``phase`` column says which:
the controller's cycles are the rows whose phase is ``engaged`` (the only rows with a finite torque ``u_*_nm``).

The control thread only appends the (immutable) ``ControlSample`` to a list (a few hundred ns);
``flush()`` (called by the session's supervisor at least every ``timing.log_flush_s``) formats the
rows, writes and flushes them, so a kill loses at most that much. Angles in the CSV are in rad
(SI, column suffixes say so); ``refused_frames`` is how many frames the link had refused by then (bad CRC,
garbage, unsigned, bad signature, replayed; cumulative); ``failsafe`` is the FailsafeReason name or empty;
``mode`` and ``armed`` are the autopilot's last HEARTBEAT; ``altitude_m`` is GLOBAL_POSITION_INT.relative_alt
(above home, up positive). Every column's unit is in ``COLUMN_UNITS`` and the sidecar.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ...errors import ConfigError
from ...frames import AXES
from ...state_types import FailsafeReason
from ...telemetry import NAN3, ControlSample

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
# the columns of logs written before the phase columns existed (still read)
CONTROL_COLUMNS = (
    ("vehicle_time_s",)
    + tuple(pattern.format(axis) for _, pattern in _VEC_FIELDS for axis in AXES)
    + CMD_COLUMNS
    + ("thrust_norm", "latency_us", "refused_frames", "failsafe")
)
PHASE_COLUMNS = ("phase", "mode", "armed", "altitude_m")
COLUMNS = CONTROL_COLUMNS + PHASE_COLUMNS

# the phase column's values, by OffboardSession state (the states that write rows)
PHASE_OF_STATE = {"takeoff": "takeoff", "engage_pending": "engaged", "engaged": "engaged", "holding": "level_hold",
                  "handback": "handback", "paused": "paused", "done": "done", "waiting": "waiting", "prestream": "waiting"}
ENGAGED_PHASE = "engaged"
IDENTIFYING_PHASE = "identifying"  # the law's cycles of the in-flight identification phase, before the profile

# vehicle_time_s, the per-axis vectors and commanded rates (6 significant digits; alpha and the controller's
# other diagnostics at full precision, 17 digits: the adaptive gain is a state that is read back and compared),
# thrust, latency [us], refused frames so far, failsafe, phase, mode, armed (0/1), altitude [m, mm resolution]
FULL_PRECISION = "%.17g"
_ROW_FORMAT = ",".join(("%.3f",) + tuple(f for name, _ in _VEC_FIELDS for f in (FULL_PRECISION if name == "alpha" else "%.6g",) * len(AXES))
                       + ("%.6g",) * len(CMD_COLUMNS) + ("%.4f", "%.1f", "%d", "%s", "%s", "%s", "%d", "%.3f"))
_VEC_NAMES = tuple(name for name, _ in _VEC_FIELDS)
DIAGNOSTIC_PREFIX = "diag_"


def diagnostic_columns(keys) -> tuple[str, ...]:
    """CSV columns of a controller's other diagnostics (``ControlSample.extra``): ``diag_<key>_<axis>``, after COLUMNS."""
    return tuple(f"{DIAGNOSTIC_PREFIX}{k}_{a}" for k in keys for a in AXES)


def format_row(s: ControlSample, refused_frames: int = 0, phase: str = ENGAGED_PHASE, mode: str = "", armed: bool = False,
               altitude_m: float = float("nan"), diagnostic_keys: tuple[str, ...] = ()) -> str:
    """One CSV line (no newline) for a sample, in COLUMNS order (one precompiled %-format: about half the cost
    of formatting each field separately, which matters on the loop's two cores)."""
    values = [s.vehicle_time_s]
    for name in _VEC_NAMES:
        values.extend(getattr(s, name))
    values.extend(s.commanded_rates_rads)
    values.append(s.thrust_norm)
    values.append(s.latency_s * 1e6)
    values.append(refused_frames)
    values.append(s.failsafe.name if s.failsafe is not None else "")
    values.extend((phase, mode.replace(",", " "), bool(armed), altitude_m))
    line = _ROW_FORMAT % tuple(values)
    if diagnostic_keys:  # the controller's other diagnostics, NaN in rows without a controller cycle
        extra = dict(s.extra)
        line += "," + ",".join([FULL_PRECISION % v for k in diagnostic_keys for v in extra.get(k, NAN3)])
    return line


# the unit of every CSV column (the sidecar's "columns"; the names carry them too where they can)
COLUMN_UNITS = {"vehicle_time_s": "s"}
for _name, _pattern in _VEC_FIELDS:
    for _axis in AXES:
        COLUMN_UNITS[_pattern.format(_axis)] = {"reference_rad": "rad", "euler_rad": "rad", "euler_rate_rads": "rad/s", "error_rad": "rad",
                                                "sigma": "rad/s", "alpha": "controller gain units", "beta": "controller gain units",
                                                "nu": "N m or rad/s^2 (gain_units)", "u_eq": "N m", "u_d": "N m", "u_nm": "N m"}[_name]
COLUMN_UNITS.update({c: "rad/s (body FRD)" for c in CMD_COLUMNS})
COLUMN_UNITS.update({"thrust_norm": "- (0..1: climb rate or collective, see thrust_semantics)", "latency_us": "us",
                     "refused_frames": "count (cumulative)", "failsafe": "FailsafeReason name or empty"})
COLUMN_UNITS.update({
    "phase": "text: takeoff | engaged (the controller's cycles) | level_hold | handback | paused | done",
    "mode": "text: the autopilot's flight mode in its last HEARTBEAT (empty before the first)",
    "armed": "0 or 1: armed in the autopilot's last HEARTBEAT",
    "altitude_m": "m above home (GLOBAL_POSITION_INT.relative_alt), up positive; nan before the vehicle sends it",
})


def metadata_path(csv_path: str | Path) -> Path:
    """The sidecar of a flight CSV: same name, ``.json``."""
    return Path(csv_path).with_suffix(".json")


def write_metadata(csv_path: str | Path, meta: dict, diagnostic_keys: tuple[str, ...] = ()) -> Path:
    """Write the sidecar (what flew: controller and gains, vehicle, autopilot and version, URL, project version,
    and the unit of every column, the controller's own diagnostics columns included) next to the CSV."""
    import json

    path = metadata_path(csv_path)
    columns = {**COLUMN_UNITS, **{c: "the controller's diagnostics() value, in its own units (docs/controllers.md)"
                                  for c in diagnostic_columns(diagnostic_keys)}}
    path.write_text(json.dumps({**meta, "columns": columns}, indent=1, default=str) + "\n", encoding="utf-8")
    return path


def add_metadata(csv_path: str | Path, more: dict) -> None:
    """Add keys to an existing sidecar (e.g. the run's counters when it ends); OSError when it cannot be written."""
    import json

    meta = read_metadata(csv_path)
    metadata_path(csv_path).write_text(json.dumps({**meta, **more}, indent=1, default=str) + "\n", encoding="utf-8")


def read_metadata(csv_path: str | Path) -> dict:
    """The sidecar of a flight CSV, or {} when it has none (an older log) or it is unreadable."""
    import json

    try:
        return json.loads(metadata_path(csv_path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


ROWS_PER_WRITE = 32  # rows formatted between two GIL hand-overs (well under one control period of CPU)


class FlightLog:
    """CSV writer fed by the control thread, written by ``flush``. ``path=None`` keeps nothing."""

    def __init__(self, path: str | Path | None, diagnostic_keys: tuple[str, ...] = ()) -> None:
        """``diagnostic_keys``: the controller's diagnostics keys without a field of their own
        (``telemetry.extra_diagnostic_keys``), written as ``diag_<key>_<axis>`` columns after COLUMNS."""
        self.path = None if path is None else str(path)
        self.diagnostic_keys = tuple(diagnostic_keys)
        self._pending: list[tuple] = []  # format_row's arguments
        self._lock = threading.Lock()
        self._f = None
        self.rows = 0
        if path is not None:
            self._f = open(path, "w", encoding="utf-8", buffering=256 * 1024)
            self._f.write(",".join(COLUMNS + diagnostic_columns(self.diagnostic_keys)) + "\n")
            self._f.flush()

    def append(self, sample: ControlSample, refused_frames: int = 0, phase: str = ENGAGED_PHASE, mode: str = "",
               armed: bool = False, altitude_m: float = float("nan")) -> None:
        """Queue one row; ``refused_frames`` = the link's refused-frame count at this cycle; ``phase`` one of
        PHASE_OF_STATE's values; ``mode``/``armed`` from the last HEARTBEAT; ``altitude_m`` [m] above home."""
        if self._f is None:
            return
        with self._lock:
            self._pending.append((sample, refused_frames, phase, mode, armed, altitude_m))

    def flush(self) -> None:
        if self._f is None:
            return
        with self._lock:
            rows, self._pending = self._pending, []
        for i in range(0, len(rows), ROWS_PER_WRITE):
            if i:
                # let a waiting control thread have the GIL: formatting a whole flush in one go held it for
                # several control periods, which made the reader miss ATTITUDE samples at 400 Hz every flush
                # (docs/bridge.md, latency)
                time.sleep(0)
            chunk = rows[i:i + ROWS_PER_WRITE]
            keys = self.diagnostic_keys
            self._f.write("".join([format_row(*row, keys) + "\n" for row in chunk]))
            self.rows += len(chunk)
        self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self.flush()
            self._f.close()
            self._f = None


def open_flight_log(log_dir: str | Path | None, diagnostic_keys: tuple[str, ...]) -> tuple[FlightLog, Path | None, tuple[str, ...]]:
    """(the flight CSV, the .tlog path beside it, every path the run writes) in ``log_dir`` (``--log``), named by the
    start time; without a folder a no-op log, no tlog and no paths. ConfigError when the folder cannot be made."""
    if log_dir is None:
        return FlightLog(None), None, ()
    d = Path(log_dir)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--log {d}: cannot create ({exc.strerror})") from None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    log = FlightLog(d / f"mavastsm-{stamp}.csv", diagnostic_keys)
    tlog_path = d / f"mavastsm-{stamp}.tlog"
    return log, tlog_path, (str(log.path), str(tlog_path), str(metadata_path(log.path)))


@dataclass(frozen=True)
class FlightRow:
    """One CSV row read back: the sample and the columns a ControlSample does not hold."""

    sample: ControlSample
    refused_frames: float
    phase: str
    mode: str
    armed: bool
    altitude_m: float


def read_flight_rows(path: str | Path) -> list[FlightRow]:
    """Every row of a flight CSV written by FlightLog (the inverse of ``format_row``), in order.

    A log from before the phase columns (header ``CONTROL_COLUMNS``) holds the engaged cycles and the failsafe
    records only: its rows read as phase ``engaged``, mode unknown, altitude NaN. A row cut short by a kill
    (the last line) is skipped. Raises OSError for an unreadable file and ValueError naming the file when the
    header is not this format's.
    """
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    header = tuple(lines[0].split(",")) if lines else ()
    extra_columns = header[len(COLUMNS):] if header[:len(COLUMNS)] == COLUMNS else ()
    diag_keys = tuple(c[len(DIAGNOSTIC_PREFIX):-len("_roll")] for c in extra_columns[::3])
    if header not in (COLUMNS, CONTROL_COLUMNS) and (not extra_columns or extra_columns != diagnostic_columns(diag_keys)):
        raise ValueError(f"{path}: not a mavastsm flight log (header differs from mavastsm.bridge.record.flight_log.COLUMNS)")
    n_control = len(CONTROL_COLUMNS)
    n_vec = len(AXES) * len(_VEC_FIELDS)
    nan = float("nan")
    out = []
    for line in lines[1:]:
        cells = line.split(",")
        if len(cells) != len(header):
            continue
        try:
            nums = [float(c) for c in cells[:n_control - 1]]
            failsafe = FailsafeReason[cells[n_control - 1]] if cells[n_control - 1] else None
            extra_nums = [float(c) for c in cells[len(COLUMNS):]] if diag_keys else ()
            if len(header) > n_control:
                phase, mode, armed, altitude_m = cells[n_control], cells[n_control + 1], cells[n_control + 2] == "1", float(cells[n_control + 3])
            else:
                phase, mode, armed, altitude_m = ENGAGED_PHASE, "", False, nan
        except (ValueError, KeyError):
            continue
        vecs = {name: tuple(nums[1 + 3 * i: 4 + 3 * i]) for i, name in enumerate(_VEC_NAMES)}
        cmd = tuple(nums[1 + n_vec: 4 + n_vec])
        thrust, latency_us, refused = nums[4 + n_vec], nums[5 + n_vec], nums[6 + n_vec]
        sample = ControlSample(nums[0], commanded_rates_rads=cmd, thrust_norm=thrust, latency_s=latency_us * 1e-6,
                               failsafe=failsafe, extra=tuple((k, tuple(extra_nums[3 * i: 3 * i + 3])) for i, k in enumerate(diag_keys)),
                               identifying=phase == IDENTIFYING_PHASE, **vecs)
        out.append(FlightRow(sample, refused, phase, mode, armed, altitude_m))
    return out


def read_flight_log(path: str | Path) -> list[ControlSample]:
    """The rows of a flight CSV written by FlightLog, back as ControlSamples, every phase (see ``read_flight_rows``;
    the controller's cycles are the samples with a finite torque ``u_nm``, the rows of phase ``engaged``)."""
    return [row.sample for row in read_flight_rows(path)]
