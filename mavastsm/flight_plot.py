"""``mavastsm plot LOG``: the figures a control engineer wants of one flight, as a PNG (needs the ``plot`` extra).

LOG is a flight CSV written by ``--log`` (``mavastsm-<time>.csv``), its folder (the newest CSV in it), or a
``.tlog``: a .tlog is read only when its CSV is absent, and then gives the attitude and the commands alone.

Panels, one column per axis (roll, pitch, yaw; angles in deg at this edge, SI in the files):

1. attitude and reference [deg]; 2. tracking error e = Θ − Θ_d [deg]; 3. and 4. the controller's sliding
variable σ [rad/s] and adaptive gain α (only when the controller reports them); 5. body rates, commanded
(what SET_ATTITUDE_TARGET carried) and measured (ω = W(Θ) Θ̇ from the logged Euler rates, eq. 1) [deg/s];
6. thrust sent [-] (0..1), altitude above home [m], and loop latency [ms] with the frames the link refused
marked. Every panel shades the flight's phases from the CSV's ``phase`` column (takeoff, level hold, hand-back;
the controller's cycles unshaded) and marks each failsafe with its reason; the title says what flew
(controller, vehicle, autopilot and version, from the CSV's ``.json`` sidecar when there is one) and when each
phase began.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import ConfigError
from .frames import AXES, body_rates_from_euler_rates

INSTALL_HINT = 'plots need matplotlib: pip install "mavastsm[plot]"'
ALPHA_UNITS = {"accel": "rad/s²", "torque": "N·m"}  # the ASTSM gain_units setting -> the unit of α


@dataclass
class Flight:
    """One flight's time series (SI), from a CSV or a .tlog. Arrays are (n,) or (n, 3); NaN where absent."""

    source: Path
    kind: str  # "csv" | "tlog"
    t_s: np.ndarray  # [s] from the first row
    euler_rad: np.ndarray
    reference_rad: np.ndarray
    error_rad: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    commanded_rates_rads: np.ndarray
    measured_rates_rads: np.ndarray
    thrust_norm: np.ndarray
    latency_s: np.ndarray
    refused_frames: np.ndarray
    failsafe: list[str]
    cmd_t_s: np.ndarray | None = None  # .tlog: commands have their own times
    meta: dict = field(default_factory=dict)
    phase: list[str] = field(default_factory=list)  # per row (flight_log.PHASE_OF_STATE values); empty: unknown
    altitude_m: np.ndarray | None = None  # [m] above home, up positive; None: not in this log


def find_log(path: str | Path) -> tuple[Path, str]:
    """(file, "csv" | "tlog") for what the user named; ConfigError saying what was looked for."""
    p = Path(path)
    if p.is_dir():
        csvs = sorted(p.glob("mavastsm-*.csv"), key=lambda f: f.stat().st_mtime)
        tlogs = sorted(p.glob("mavastsm-*.tlog"), key=lambda f: f.stat().st_mtime)
        if csvs:
            return csvs[-1], "csv"
        if tlogs:
            return tlogs[-1], "tlog"
        raise ConfigError(f"{p}: no mavastsm-*.csv or mavastsm-*.tlog in this folder (written by --log DIR)")
    if not p.exists():
        raise ConfigError(f"{p}: no such file")
    if p.suffix == ".tlog":
        csv = p.with_suffix(".csv")
        return (csv, "csv") if csv.exists() else (p, "tlog")
    return p, "csv"


def load_flight(path: str | Path) -> Flight:
    from .bridge.record.flight_log import read_flight_rows, read_metadata

    file, kind = find_log(path)
    if kind == "tlog":
        return _load_tlog(file)
    try:
        rows = read_flight_rows(file)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{file}: {exc}") from None
    if not rows:
        raise ConfigError(f"{file}: no complete row to plot")
    samples = [row.sample for row in rows]
    refused = np.array([row.refused_frames for row in rows])
    t = np.array([s.vehicle_time_s for s in samples])
    euler = np.array([s.euler_rad for s in samples])
    euler_rates = np.array([s.euler_rate_rads for s in samples])
    return Flight(
        source=file, kind="csv", t_s=t - t[np.isfinite(t)][0], euler_rad=euler, reference_rad=np.array([s.reference_rad for s in samples]),
        error_rad=np.array([s.error_rad for s in samples]), sigma=np.array([s.sigma for s in samples]),
        alpha=np.array([s.alpha for s in samples]), commanded_rates_rads=np.array([s.commanded_rates_rads for s in samples]),
        measured_rates_rads=body_rates_from_euler_rates(euler, euler_rates), thrust_norm=np.array([s.thrust_norm for s in samples]),
        latency_s=np.array([s.latency_s for s in samples]), refused_frames=refused,
        failsafe=[s.failsafe.name if s.failsafe is not None else "" for s in samples], meta=read_metadata(file),
        phase=[row.phase for row in rows], altitude_m=np.array([row.altitude_m for row in rows]),
    )


def _load_tlog(file: Path) -> Flight:
    from .bridge.link.mavlink_link import read_tlog_flight

    attitude, setpoints = read_tlog_flight(file)
    att, sp = np.array(attitude, dtype=float).reshape(-1, 8), np.array(setpoints, dtype=float).reshape(-1, 6)
    t0 = att[0, 0]
    n = len(att)
    nan3 = np.full((n, 3), np.nan)
    rates = sp[sp[:, 1].astype(int) & 0x80 != 0] if len(sp) else sp  # body-rate setpoints (attitude ignored)
    return Flight(
        source=file, kind="tlog", t_s=att[:, 0] - t0, euler_rad=att[:, 1:4], reference_rad=nan3, error_rad=nan3, sigma=nan3, alpha=nan3,
        commanded_rates_rads=rates[:, 2:5] if len(rates) else np.empty((0, 3)), measured_rates_rads=att[:, 4:7],
        thrust_norm=rates[:, 5] if len(rates) else np.empty(0), latency_s=np.full(n, np.nan), refused_frames=np.full(n, np.nan),
        failsafe=[""] * n, cmd_t_s=(rates[:, 0] - t0) if len(rates) else np.empty(0),
    )


# how each phase is shaded (the controller's cycles, "engaged", are not)
PHASE_SHADES = {"takeoff": ("tab:blue", "takeoff"), "level_hold": ("tab:orange", "level hold"),
                "handback": ("tab:gray", "hand-back"), "paused": ("tab:olive", "paused")}


def phase_spans(t: np.ndarray, phases: list[str]) -> list[tuple[float, float, str]]:
    """(start [s], end [s], phase) for each run of rows in one phase; a span ends where the next one starts."""
    spans: list[tuple[float, float, str]] = []
    keep = np.isfinite(t)
    times = t[keep]
    names = [p for p, k in zip(phases, keep) if k]
    for i, (ti, name) in enumerate(zip(times, names)):
        if spans and spans[-1][2] == name:
            continue
        if spans:
            spans[-1] = (spans[-1][0], ti, spans[-1][2])
        spans.append((ti, times[-1], name))
    return spans


def failsafe_events(t: np.ndarray, failsafe: list[str]) -> list[tuple[float, str]]:
    """(time [s], reason) of each failsafe record (the rows whose failsafe column is set), first of a run only."""
    events, previous = [], ""
    for ti, f in zip(t, failsafe):
        if f and f != previous and np.isfinite(ti):
            events.append((float(ti), f))
        previous = f
    return events


def _has(a: np.ndarray) -> bool:
    return a.size > 0 and bool(np.isfinite(a).any())


def _rows(flight: Flight) -> list[tuple[str, str | None]]:
    """(what, y label) of each row of the figure: only the signals the log has."""
    rows = [("attitude", "angle [deg]")]
    if _has(flight.error_rad):
        rows.append(("error", "error e [deg]"))
    if _has(flight.sigma):
        rows.append(("sigma", "sliding variable σ [rad/s]"))
    if _has(flight.alpha):
        gain_units = flight.meta.get("gains", {}).get("gain_units", "")
        alpha_unit = ALPHA_UNITS.get(gain_units, f"{gain_units or 'gain'} units")
        rows.append(("alpha", f"adaptive gain α [{alpha_unit}]"))
    rows.append(("rates", "body rate [deg/s]"))
    rows.append(("misc", None))
    return rows


def _plot_axis_row(axes_row, flight: Flight, what: str, ylabel: str) -> None:
    """One per-axis row (roll, pitch, yaw): attitude and reference, error, σ, α or body rates."""
    deg = math.degrees(1.0)
    t = flight.t_s
    for c, axis in enumerate(AXES):
        ax = axes_row[c]
        if what == "attitude":
            ax.plot(t, flight.euler_rad[:, c] * deg, label="measured")
            if _has(flight.reference_rad):
                ax.plot(t, flight.reference_rad[:, c] * deg, "--", label="reference Θ_d")
            ax.set_title(axis)
        elif what == "error":
            ax.plot(t, flight.error_rad[:, c] * deg)
        elif what == "sigma":
            ax.plot(t, flight.sigma[:, c])
        elif what == "alpha":
            ax.plot(t, flight.alpha[:, c])
        elif what == "rates":
            tc = flight.cmd_t_s if flight.cmd_t_s is not None else t
            if len(flight.commanded_rates_rads):
                ax.plot(tc, flight.commanded_rates_rads[:, c] * deg, label="commanded")
            ax.plot(t, flight.measured_rates_rads[:, c] * deg, label="measured", alpha=0.8)
        ax.set_ylabel(ylabel)
        if what in ("attitude", "rates"):
            ax.legend(loc="best", fontsize="small")


def _plot_misc_row(axes_row, flight: Flight) -> None:
    """The last row: thrust sent, altitude, loop latency with the refused frames marked."""
    t = flight.t_s
    tc = flight.cmd_t_s if flight.cmd_t_s is not None else t
    axes_row[0].plot(tc, flight.thrust_norm)
    axes_row[0].set_ylabel(f"thrust sent [-]\n(0..1, {flight.meta.get('thrust_semantics', 'see thrust_semantics')})")
    if flight.altitude_m is not None and _has(flight.altitude_m):
        axes_row[1].plot(t, flight.altitude_m)
    axes_row[1].set_ylabel("altitude above home [m]")
    axes_row[2].plot(t, flight.latency_s * 1e3, label="ATTITUDE → setpoint")
    axes_row[2].set_ylabel("loop latency [ms]")
    refused = np.nan_to_num(flight.refused_frames, nan=0.0)
    new_refusals = np.flatnonzero(np.diff(refused, prepend=refused[:1]) > 0) if refused.size else []
    if len(new_refusals):
        axes_row[2].plot(t[new_refusals], np.zeros(len(new_refusals)), "|", color="tab:red", ms=12,
                         label=f"frames refused ({int(refused.max())} in all)")
    axes_row[2].legend(loc="best", fontsize="small")


def _shade_legend(fig, spans, events) -> None:
    """The legend of the phase shades and the failsafe line, when there are phases."""
    from matplotlib.patches import Patch

    shown = [name for name in PHASE_SHADES if any(s[2] == name for s in spans)]
    handles = [Patch(color=PHASE_SHADES[n][0], alpha=0.25, label=PHASE_SHADES[n][1]) for n in shown]
    if events:
        from matplotlib.lines import Line2D

        handles.append(Line2D([], [], color="tab:red", ls="--", label="failsafe"))
    if handles:
        fig.legend(handles=handles, loc="upper right", fontsize="small", title="shaded", title_fontsize="small")


def _title(flight: Flight, spans, events) -> str:
    """The log's name, what flew where, when each phase began and each failsafe fired."""
    m = flight.meta
    what = ", ".join(x for x in (m.get("controller"), f"vehicle {m['vehicle']}" if m.get("vehicle") else "",
                                 f"{m.get('autopilot', '')} {m.get('firmware_version', '')}".strip(), m.get("url")) if x)
    phases = ", ".join(f"{PHASE_SHADES.get(name, (None, name))[1]} {a:.1f} s" for a, _, name in spans)
    failsafes = "; ".join(f"{name} at {when:.2f} s (dashed)" for when, name in events)
    return (f"{flight.source.name}{' (.tlog: attitude and commands only)' if flight.kind == 'tlog' else ''}"
            + (f"\n{what}" if what else "") + (f"\nphases from: {phases}" if phases else "")
            + (f"\nfailsafe: {failsafes}" if failsafes else ""))


def flight_figure(flight: Flight):
    """The matplotlib Figure of ``flight`` (Agg backend; nothing shown)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _rows(flight)
    fig, axes = plt.subplots(len(rows), 3, figsize=(15, 2.3 * len(rows) + 1.0), sharex=True, squeeze=False)
    t = flight.t_s
    spans = phase_spans(t, flight.phase) if flight.phase else []
    events = failsafe_events(t, flight.failsafe)
    for r, (what, ylabel) in enumerate(rows):
        if what == "misc":
            _plot_misc_row(axes[r], flight)
        else:
            _plot_axis_row(axes[r], flight, what, ylabel)
        for c in range(3):
            for a, b, name in spans:
                if name in PHASE_SHADES:
                    axes[r][c].axvspan(a, b, color=PHASE_SHADES[name][0], alpha=0.12, lw=0)
            for when, _ in events:
                axes[r][c].axvline(when, color="tab:red", lw=1.0, ls="--")
            axes[r][c].grid(True, alpha=0.3)
    for c in range(3):
        axes[-1][c].set_xlabel("time since the first row [s]")
    if spans:
        _shade_legend(fig, spans, events)
    fig.suptitle(_title(flight, spans, events))
    fig.tight_layout(rect=(0, 0, 0.93, 1) if spans else (0, 0, 1, 1))
    return fig


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = __doc__.split("\n\n")[0] + " " + __doc__.split("\n\n")[1]
    parser.add_argument("log", help="flight CSV (mavastsm-<time>.csv from --log DIR), its folder, or a .tlog")
    parser.add_argument("--png", type=Path, default=None, metavar="FILE", help="PNG to write; default: the log's name with .png")


def run(args: argparse.Namespace) -> int:
    from .offline.figures import matplotlib_available

    if not matplotlib_available():
        raise ConfigError(f"mavastsm plot needs matplotlib ({INSTALL_HINT})")
    flight = load_flight(args.log)
    out = args.png or flight.source.with_suffix(".png")
    fig = flight_figure(flight)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    print(f"wrote {out} ({len(flight.t_s)} rows from {flight.source})")
    return 0
