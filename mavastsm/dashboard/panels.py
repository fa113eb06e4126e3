"""Pure view functions: ``TelemetrySnapshot`` in, rich renderable out. No I/O, no clocks, no threads.

Every ``render_*`` function takes plain data and returns a renderable whose height is known in
advance (``no_wrap`` everywhere, ``PanelBlock.height``), so :func:`build_view` can decide which
panels fit a terminal of ``width`` x ``height`` without rendering twice, and drop the least important
ones first (never crash, never scroll).

Units: telemetry is SI (rad, rad/s, N m, s); angles and rates are shown in degrees and deg/s, the
sliding variable sigma in rad/s (its band mu is specified in rad/s, eq. 34), torques in N m.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from rich import box
from rich.cells import cell_len
from rich.console import Console, Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from ..frames import AXES
from ..state_types import FailsafeReason
from ..telemetry import ControlSample, SessionInfo, TelemetrySnapshot

RAD2DEG = 180.0 / math.pi
SPARK_LEVELS = "▁▂▃▄▅▆▇█"
HISTORY_WINDOW_S = 5.0

# Only used to word-wrap text for height accounting (never printed to).
_WRAP_CONSOLE = Console(file=io.StringIO(), width=200, color_system=None)

KEY_HELP = "q stop (level hold, hand back, exit; same as Ctrl-C)   p pause/resume dashboard (control keeps running)"


@dataclass(frozen=True)
class PanelBlock:
    """A renderable plus the number of terminal lines it occupies at the width it was built for."""

    renderable: RenderableType
    height: int


# --------------------------------------------------------------------------- item flow (no cut values)


ITEM_SEPARATOR = " · "


def flow_items(items: Sequence[Text], width: int) -> list[Text]:
    """Lay ``items`` out left to right, separated by " · ", starting a new line where the next item would not
    fit in ``width`` cells. An item is never cut: one wider than a whole line is folded over several lines."""
    width = max(1, width)
    lines: list[Text] = []
    line = Text(no_wrap=True)
    for item in items:
        need = item.cell_len if not line.plain else cell_len(ITEM_SEPARATOR) + item.cell_len
        if line.plain and line.cell_len + need > width:
            lines.append(line)
            line = Text(no_wrap=True)
        if line.plain:
            line.append(ITEM_SEPARATOR, style="dim")
        if item.cell_len <= width - line.cell_len:
            line.append_text(item)
            continue
        for piece in item.wrap(_WRAP_CONSOLE, width, overflow="fold", no_wrap=False):  # wider than a line: fold, never cut
            if line.plain:
                lines.append(line)
            line = Text(no_wrap=True)
            line.append_text(piece)
    if line.plain:
        lines.append(line)
    return lines


def fit_items(items: Sequence[tuple[int, Text]], width: int, max_lines: int) -> list[Text]:
    """The lines of the most important items that flow into at most ``max_lines`` lines of ``width`` cells.

    ``items`` are (rank, text) in display order; rank 0 is the most important. Items are taken by rank and an
    item that would need one line too many is left out whole (later, less important ones may still fit), so
    what is shown is always complete; the display order is kept."""
    chosen: list[int] = []
    for index in sorted(range(len(items)), key=lambda i: items[i][0]):
        trial = sorted(chosen + [index])
        if len(flow_items([items[i][1] for i in trial], width)) <= max_lines:
            chosen = trial
    return flow_items([items[i][1] for i in chosen], width)


# --------------------------------------------------------------------------- number formatting


def _finite(x: float) -> bool:
    return x is not None and math.isfinite(x)


def fmt(x: float, spec: str) -> str:
    """Format a number, or an em dash when it is missing (NaN/inf/None)."""
    return format(x, spec) if _finite(x) else "—"


def fmt_deg(x_rad: float, spec: str = "+.2f") -> str:
    return fmt(x_rad * RAD2DEG, spec) if _finite(x_rad) else "—"


def fmt_ms(x_s: float) -> str:
    return f"{x_s * 1e3:.2f} ms" if _finite(x_s) else "— ms"


def sigma_outside_band(sigma: float, mu: float) -> bool:
    """True when |sigma| > mu (eq. 34: alpha grows outside the band). False when either is missing."""
    return _finite(sigma) and _finite(mu) and abs(sigma) > mu


def torque_saturated(u_eq: float, u_d: float, u_total: float) -> bool:
    """True when the total torque sent is smaller in magnitude than u_eq + u_D (eq. 18): clipped."""
    return (_finite(u_eq) and _finite(u_d) and _finite(u_total)
            and abs(u_total) < abs(u_eq + u_d) * (1.0 - 1e-6) - 1e-12)


def alpha_pinned(alpha: float, alpha_max: float) -> bool:
    """True when alpha sits at its upper clamp alpha_max (adaptation can no longer grow the gain)."""
    return _finite(alpha) and _finite(alpha_max) and alpha >= alpha_max * (1.0 - 1e-9)


# --------------------------------------------------------------------------- history math


@dataclass(frozen=True)
class HistoryArrays:
    """The samples of one window as arrays: t [s, vehicle clock] shape (n,), others (n, 3)."""

    t_s: np.ndarray
    error_rad: np.ndarray
    alpha: np.ndarray
    commanded_rates_rads: np.ndarray
    u_nm: np.ndarray


def history_arrays(history: Sequence[ControlSample], window_s: float = HISTORY_WINDOW_S) -> HistoryArrays:
    """Samples whose vehicle time lies within ``window_s`` of the newest one, as float arrays."""
    if not history:
        empty3 = np.empty((0, 3))
        return HistoryArrays(np.empty(0), empty3, empty3, empty3, empty3)
    t_end = history[-1].vehicle_time_s
    start = len(history)
    # walk back from the newest sample; history is in arrival order
    while start > 0 and t_end - history[start - 1].vehicle_time_s <= window_s + 1e-9:
        start -= 1
    window = history[start:]
    return HistoryArrays(
        t_s=np.fromiter((s.vehicle_time_s for s in window), float, len(window)),
        error_rad=np.array([s.error_rad for s in window], float).reshape(-1, 3),
        alpha=np.array([s.alpha for s in window], float).reshape(-1, 3),
        commanded_rates_rads=np.array([s.commanded_rates_rads for s in window], float).reshape(-1, 3),
        u_nm=np.array([s.u_nm for s in window], float).reshape(-1, 3),
    )


def chattering_nm_per_s(t_s: np.ndarray, u_nm: np.ndarray) -> np.ndarray:
    """Total variation of u per second over the window, per axis [N m / s].

    TV = sum_k |u_k - u_{k-1}| / (t_last - t_first). Steps touching a NaN sample are skipped.
    NaN per axis when fewer than two samples or zero duration.
    """
    if len(t_s) < 2 or not (t_s[-1] - t_s[0]) > 0.0:
        return np.full(3, np.nan)
    du = np.abs(np.diff(u_nm, axis=0))
    valid = np.isfinite(du)
    tv = np.where(valid, du, 0.0).sum(axis=0)
    tv[~valid.any(axis=0)] = np.nan
    return tv / (t_s[-1] - t_s[0])


def sparkline(t_s: np.ndarray, values: np.ndarray, width: int, window_s: float,
              lo: float | None = None, hi: float | None = None) -> str:
    """Unicode block sparkline of ``values`` (shape (n,)) over the last ``window_s`` seconds.

    The window is split into ``width`` equal time slots; each slot shows the newest sample at or
    before its end (so chattering appears as ragged blocks instead of being averaged away). Slots
    before the first sample, and NaN samples, are blank. Scaling is min..max of the shown values
    unless ``lo``/``hi`` are given; a flat signal draws the lowest block.
    """
    if width <= 0:
        return ""
    if len(t_s) == 0:
        return " " * width
    t_end = t_s[-1]
    slot_ends = t_end - window_s + window_s * (np.arange(1, width + 1) / width)
    idx = np.searchsorted(t_s, slot_ends + 1e-12, side="right") - 1
    vals = np.where(idx >= 0, values[np.clip(idx, 0, None)], np.nan)
    finite = np.isfinite(vals)
    if not finite.any():
        return " " * width
    lo_v = float(np.min(vals[finite])) if lo is None else lo
    hi_v = float(np.max(vals[finite])) if hi is None else hi
    hi_v = max(hi_v, lo_v)
    span = hi_v - lo_v
    levels = len(SPARK_LEVELS) - 1
    if span > 0:
        level = np.clip(np.round((vals - lo_v) / span * levels), 0, levels)
    else:
        level = np.zeros_like(vals)
    return "".join(SPARK_LEVELS[int(lv)] if ok else " " for lv, ok in zip(level, finite))


# --------------------------------------------------------------------------- panels


HEADLINE_ESSENTIAL_RANK = 3  # controller, failsafe or pause, phase, mode and armed


def render_headline(snapshot: TelemetrySnapshot, paused: bool = False, width: int = 200, max_lines: int = 1) -> PanelBlock:
    """Controller · vehicle state · phase · reference progress · ATTITUDE rate · latency, on as few lines as the
    important items need (at most ``max_lines``). The ATTITUDE rate and p99 are left out first when the line is
    full (the link panel or its compact lines show them too); nothing is ever cut."""
    link, session = snapshot.link, snapshot.session
    items: list[tuple[int, Text]] = [(0, Text(session.controller or "—", style="bold"))]  # (rank, text), display order
    items.append((3, Text(("ARMED " if link.armed else "disarmed ") + (link.mode or "—"),
                          style="bold green" if link.armed else "yellow")))
    if link.phase:
        items.append((2, Text(link.phase, style="bold cyan")))
    ref = reference_progress(session, snapshot.latest)
    if ref:
        items.append((4, Text(ref)))
    items.append((5, Text(f"ATT {fmt(link.attitude_rate_achieved_hz, '.0f')}/{fmt(link.attitude_rate_requested_hz, '.0f')} Hz")))
    items.append((6, Text(f"p99 {fmt_ms(link.latency_p99_s)}")))
    fs = snapshot.active_failsafe
    if fs is FailsafeReason.OPERATOR_STOP:
        items.append((1, Text(f"STOPPING {fs.label}", style="bold black on yellow")))
    elif fs is not None:
        items.append((1, Text(f"FAILSAFE {fs.label}", style="bold white on red")))
    if paused:
        items.append((1, Text("PAUSED", style="bold reverse")))
    # a second line only when the essential items (rank <= 3) need it; the rest fill what is left
    essential_lines = len(flow_items([text for rank, text in items if rank <= HEADLINE_ESSENTIAL_RANK], width))
    lines = fit_items(items, width, max(1, min(max_lines, essential_lines)))
    return PanelBlock(Group(*lines), len(lines))


def reference_progress(session: SessionInfo, latest: ControlSample | None) -> str:
    """'ref NAME t=3.2/12.0 s' or '' when no reference is named."""
    if not session.reference_name:
        return ""
    text = f"ref {session.reference_name}"
    if latest is not None and _finite(session.reference_start_vehicle_time_s):
        t_in = latest.vehicle_time_s - session.reference_start_vehicle_time_s
        total = f"/{session.reference_duration_s:.1f}" if _finite(session.reference_duration_s) else ""
        text += f" t={t_in:.1f}{total} s"
    return text


def render_failsafe_banner(snapshot: TelemetrySnapshot, width: int) -> PanelBlock | None:
    """Prominent banner naming the active failsafe and the hand-back action that follows; None when clear.

    Red ``FAILSAFE`` for every reason except an operator stop (q, Ctrl-C, SIGTERM, or the profile's
    duration completing), which is an orderly end and shows as a yellow ``STOPPING`` with the
    ``on_exit`` action.
    """
    reason = snapshot.active_failsafe
    if reason is None:
        return None
    orderly = reason is FailsafeReason.OPERATOR_STOP
    action = snapshot.session.on_exit if orderly else snapshot.session.on_failsafe
    body = f"{'STOPPING' if orderly else 'FAILSAFE'} {reason.label}: {reason.value}"
    if action:
        body += f"  →  {action}"
    inner = max(1, width - 4)
    style, border = ("bold black on yellow", "bold yellow") if orderly else ("bold white on red", "bold red")
    text = Text(body, style=style, overflow="fold")
    lines = max(1, len(text.wrap(_WRAP_CONSOLE, inner)))  # the same word wrapping rich will do
    panel = Panel(text, box=box.HEAVY, border_style=border, padding=(0, 1))
    return PanelBlock(panel, lines + 2)


def render_axis_table(snapshot: TelemetrySnapshot) -> PanelBlock:
    """Per-axis table (rows = quantities, columns = roll/pitch/yaw) of the newest control cycle.

    sigma is marked '>mu' (red) when |sigma| > mu; alpha is marked 'MAX' (red) when pinned at
    alpha_max; the total torque is marked 'sat' (yellow) when it is smaller than u_eq + u_D (clipped). Missing quantities (controller without them, or no sample yet) show '—'.
    """
    s = snapshot.latest
    session = snapshot.session
    table = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, padding=(0, 1),
                  title=None, expand=False)
    table.add_column("axis", no_wrap=True, overflow="ellipsis", style="bold")
    for axis in AXES:
        table.add_column(axis, justify="right", no_wrap=True, overflow="ellipsis", min_width=8)

    rows: list[tuple[str, Sequence[Text | str]]] = []

    def row(label: str, cells: Sequence[Text | str]) -> None:
        rows.append((label, cells))

    def emit() -> int:
        # Text, not str: "[deg]" would otherwise be parsed as console markup
        for label, cells in rows:
            table.add_row(Text(label), *(c if isinstance(c, Text) else Text(c) for c in cells))
        return len(rows)

    if s is None:
        for label in _AXIS_ROW_LABELS:
            row(label, ["—"] * 3)
        return PanelBlock(table, emit() + 2)

    row("reference Θd [deg]", [fmt_deg(v) for v in s.reference_rad])
    row("angle Θ [deg]", [fmt_deg(v) for v in s.euler_rad])
    row("error e [deg]", [fmt_deg(v) for v in s.error_rad])
    row("Euler rate [deg/s]", [fmt_deg(v, "+.1f") for v in s.euler_rate_rads])
    row("σ [rad/s]", _marked_cells(s.sigma, session.mu, sigma_outside_band, "+.4f", ">μ"))
    row("μ band [rad/s]", [("±" + fmt(mu, ".4f")) if _finite(mu) else "—" for mu in session.mu])
    row("α", _marked_cells(s.alpha, session.alpha_max, alpha_pinned, ".3g", "MAX"))
    row(ALPHA_RANGE_LABEL, [f"{fmt(lo, '.3g')} to {fmt(hi, '.3g')}" for lo, hi in zip(session.alpha_min, session.alpha_max)])
    row("β", [fmt(v, ".3g") for v in s.beta])
    row("ν", [fmt(v, "+.3g") for v in s.nu])
    row("u_eq [N·m]", [fmt(v, "+.3g") for v in s.u_eq])
    row("u_D [N·m]", [fmt(v, "+.3g") for v in s.u_d])
    u_cells = []
    for ueq, ud, u in zip(s.u_eq, s.u_d, s.u_nm):
        if torque_saturated(ueq, ud, u):
            u_cells.append(Text(f"{fmt(u, '+.3g')} sat", style="bold yellow"))
        else:
            u_cells.append(Text(fmt(u, "+.3g"), style="bold"))
    row("u total [N·m]", u_cells)
    row("cmd body rate [deg/s]", [fmt_deg(v, "+.1f") for v in s.commanded_rates_rads])
    if s.extra:
        # the controller's own diagnostics (any law, e.g. PID's integrator) in place of the sliding-mode rows it lacks
        empty = {"σ [rad/s]": s.sigma, "μ band [rad/s]": session.mu, "α": s.alpha, ALPHA_RANGE_LABEL: session.alpha_max,
                 "β": s.beta, "ν": s.nu, "u_eq [N·m]": s.u_eq, "u_D [N·m]": s.u_d}
        rows[:] = [r for r in rows if not (r[0] in empty and not any(_finite(v) for v in empty[r[0]]))]
        at = len(rows) - 1  # before the command row
        rows[at:at] = [(key, [fmt(v, "+.4g") for v in values]) for key, values in s.extra]
    # SIMPLE_HEAD without edge: header line + rule line + one line per row
    return PanelBlock(table, emit() + 2)


def _marked_cells(values, bounds, crossed, spec: str, mark: str) -> list[Text]:
    """One cell per axis: the value, with ``mark`` in bold red where ``crossed(value, bound)``."""
    return [Text(f"{fmt(v, spec)} {mark}", style="bold red") if crossed(v, b) else Text(fmt(v, spec)) for v, b in zip(values, bounds)]


ALPHA_RANGE_LABEL = "α_m to α_max"  # not "…": an ellipsis reads as a value cut short

_AXIS_ROW_LABELS = (
    "reference Θd [deg]", "angle Θ [deg]", "error e [deg]", "Euler rate [deg/s]", "σ [rad/s]",
    "μ band [rad/s]", "α", ALPHA_RANGE_LABEL, "β", "ν", "u_eq [N·m]", "u_D [N·m]", "u total [N·m]",
    "cmd body rate [deg/s]",
)


def render_axis_compact(snapshot: TelemetrySnapshot) -> PanelBlock:
    """Three lines (one per axis) of error, sigma and alpha: the fallback for tiny terminals."""
    s = snapshot.latest
    lines = []
    for i, axis in enumerate(AXES):
        if s is None:
            lines.append(Text(f"{axis:5} —", no_wrap=True, overflow="ellipsis"))
            continue
        t = Text(no_wrap=True, overflow="ellipsis")
        t.append(f"{axis:5} e {fmt_deg(s.error_rad[i])}°  σ ")
        out = sigma_outside_band(s.sigma[i], snapshot.session.mu[i])
        t.append(fmt(s.sigma[i], "+.4f") + (" >μ" if out else ""), style="bold red" if out else "")
        pinned = alpha_pinned(s.alpha[i], snapshot.session.alpha_max[i])
        t.append("  α ")
        t.append(fmt(s.alpha[i], ".3g") + (" MAX" if pinned else ""), style="bold red" if pinned else "")
        t.append(f"  u {fmt(s.u_nm[i], '+.3g')} N·m")
        lines.append(t)
    return PanelBlock(Group(*lines), 3)


def render_history(snapshot: TelemetrySnapshot, width: int, window_s: float = HISTORY_WINDOW_S) -> PanelBlock:
    """Sparklines of error, alpha and commanded body rate per axis over the last ``window_s``, and
    the chattering figure TV(u)/s [N m/s]. Each sparkline is followed by its peak |value|.

    Error and rate lines span min..max of the window; the alpha line starts at alpha_m, so an alpha
    resting at its threshold draws a flat bottom line and adaptation shows as bumps above it."""
    h = history_arrays(snapshot.history, window_s)
    tv = chattering_nm_per_s(h.t_s, h.u_nm)
    label_w, peak_w, tv_w = 5, 8, 13  # columns: axis label, peak |value|, chattering figure
    gaps = 2 * 4  # padding between the 5 columns
    spark_w = max(4, (width - label_w - tv_w - gaps - 3 * (1 + peak_w)) // 3)
    col_w = spark_w + 1 + peak_w
    table = Table(box=None, show_edge=False, pad_edge=False, padding=(0, 1), show_header=True,
                  header_style="bold")
    table.add_column(Text(f"{window_s:g} s"), no_wrap=True, width=label_w)
    table.add_column(Text("error [deg]"), no_wrap=True, overflow="ellipsis", width=col_w)
    table.add_column(Text("α (adaptive)"), no_wrap=True, overflow="ellipsis", width=col_w)
    table.add_column(Text("cmd rate [deg/s]"), no_wrap=True, overflow="ellipsis", width=col_w)
    table.add_column(Text("TV(u) [N·m/s]"), no_wrap=True, justify="right", width=tv_w)
    for i, axis in enumerate(AXES):
        cells = []
        alpha_floor = snapshot.session.alpha_min[i]
        for values, scale, lo in ((h.error_rad[:, i], RAD2DEG, None),
                                  (h.alpha[:, i], 1.0, alpha_floor if _finite(alpha_floor) else None),
                                  (h.commanded_rates_rads[:, i], RAD2DEG, None)):
            spark = sparkline(h.t_s, values * scale, spark_w, window_s, lo=lo)
            finite = values[np.isfinite(values)]
            peak = fmt(float(np.max(np.abs(finite))) * scale, ".3g") if finite.size else "—"
            cells.append(Text(f"{spark} {peak:>{peak_w}}", no_wrap=True))
        table.add_row(Text(axis), *cells, Text(fmt(float(tv[i]), ".3g")))
    return PanelBlock(table, 4)


def _key_value_panel(title: str, rows: Sequence[tuple[str, Text | str]], width: int) -> PanelBlock:
    """A bordered two-column panel ``width`` cells wide; a value too long for its line wraps (word-wise, a long
    path or URL folded), never cut, and the height counts those lines. Plain strings become ``Text`` (no markup
    parsing of URLs/paths)."""
    key_w = max((cell_len(key) for key, _ in rows), default=0)
    value_w = max(1, width - 4 - key_w - 1)  # borders and padding 4, the gap between the columns 1
    grid = Table.grid(padding=(0, 1))
    grid.add_column(style="bold", no_wrap=True, width=key_w)
    grid.add_column(overflow="fold", width=value_w)
    lines = 0
    for key, value in rows:
        text = value if isinstance(value, Text) else Text(value)
        text.overflow = "fold"
        lines += max(1, len(text.wrap(_WRAP_CONSOLE, value_w)))
        grid.add_row(Text(key), text)
    panel = Panel(grid, title=title, title_align="left", box=box.ROUNDED, padding=(0, 1), width=width)
    return PanelBlock(panel, lines + 2)


def _armed_text(link_mode: str, armed: bool) -> Text:
    return Text(f"{link_mode or '—'} / " + ("ARMED" if armed else "disarmed"),
                style="bold green" if armed else "yellow")


def _other_counters(link) -> str:
    """The rarer counters (telemetry.COUNTER_DEFINITIONS), named only when not zero: a clean flight keeps its line."""
    names = (("out_of_order", "out-of-order"), ("clock_outliers", "clock outliers"), ("foreign_attitude", "foreign"), ("blocked_setpoints", "blocked"),
             ("overruns", "overruns"), ("late", "late"), ("reader_errors", "reader errors"))
    return "".join(f"  {label} {getattr(link, name)}" for name, label in names if getattr(link, name))


def render_link(snapshot: TelemetrySnapshot, width: int) -> PanelBlock:
    """Link and vehicle: URL, autopilot, mode, armed, thrust semantics, rates, latency, counters, signing."""
    link = snapshot.link
    version = f" {link.firmware_version}" if link.firmware_version else ""
    return _key_value_panel("link / vehicle", [
        ("url", link.url or "—"),
        ("autopilot", f"{link.autopilot}{version}"),
        ("mode / armed", _armed_text(link.mode, link.armed)),
        ("thrust", link.thrust_semantics or "—"),
        ("ATTITUDE", f"{fmt(link.attitude_rate_achieved_hz, '.1f')} of "
                     f"{fmt(link.attitude_rate_requested_hz, '.0f')} Hz requested; last {fmt_ms(link.time_since_attitude_s)} ago"),
        ("latency", f"p50 {fmt_ms(link.latency_p50_s)}  p99 {fmt_ms(link.latency_p99_s)}"),
        ("cycles", Text(f"{link.cycles} cycles, {link.missed} missed",
                        style="bold red" if link.missed else "")),
        ("messages", Text(f"dropped {link.dropped}  duplicate {link.duplicate}  superseded {link.superseded}  invalid {link.invalid}  refused {link.refused_frames}"
                          + _other_counters(link), style="bold red" if link.reader_errors else ("yellow" if link.refused_frames else ""))),
        ("signing", "on" if link.signing else "off"),
    ], width)


def render_link_compact(snapshot: TelemetrySnapshot, width: int, max_lines: int) -> PanelBlock:
    """The link state as items on at most ``max_lines`` lines, for terminals too small for the link panel: the
    most important first (rate, cycles, latency, message counters); whatever does not fit is left out whole."""
    link = snapshot.link
    version = f" {link.firmware_version}" if link.firmware_version else ""
    items = [
        (0, Text(f"ATT {fmt(link.attitude_rate_achieved_hz, '.1f')}/{fmt(link.attitude_rate_requested_hz, '.0f')} Hz")),
        (4, Text(f"last {fmt_ms(link.time_since_attitude_s)} ago")),
        (2, Text(f"latency p50 {fmt_ms(link.latency_p50_s)} p99 {fmt_ms(link.latency_p99_s)}")),
        (1, Text(f"{link.cycles} cycles, {link.missed} missed", style="bold red" if link.missed else "")),
        (3, Text(f"dropped {link.dropped} duplicate {link.duplicate} superseded {link.superseded} invalid {link.invalid} "
                 f"refused {link.refused_frames}" + _other_counters(link),
                 style="bold red" if link.reader_errors else ("yellow" if link.refused_frames else ""))),
        (5, Text(f"signing {'on' if link.signing else 'off'}")),
        (6, Text(f"thrust {link.thrust_semantics or '—'}")),
        (7, Text(f"{link.autopilot}{version}")),
        (8, Text(link.url or "—")),
    ]
    lines = fit_items(items, width, max_lines)
    return PanelBlock(Group(*lines), len(lines))


def render_state(snapshot: TelemetrySnapshot, width: int) -> PanelBlock:
    """Phase, controller and gains, reference progress, failsafe, configured actions, log paths."""
    session, latest = snapshot.session, snapshot.latest
    fs = snapshot.active_failsafe
    return _key_value_panel("state", [
        ("phase", Text(snapshot.link.phase or "—", style="bold cyan")),
        ("controller", session.controller or "—"),
        ("gains", "  ".join(f"{k}={v}" for k, v in session.gain_summary.items()) or "—"),
        ("reference", reference_progress(session, latest).removeprefix("ref ") or "—"),
        ("thrust sent", fmt(latest.thrust_norm, ".3f") if latest is not None else "—"),
        ("failsafe", Text(fs.label, style="bold white on red") if fs is not None else Text("none", style="green")),
        ("on failsafe", session.on_failsafe or "—"),
        ("on exit", session.on_exit or "—"),
        ("logs", ", ".join(session.log_paths) or "—"),
    ], width)


def render_state_compact(snapshot: TelemetrySnapshot, width: int, max_lines: int) -> PanelBlock:
    """The session state as items on at most ``max_lines`` lines, for terminals too small for the state panel:
    phase, failsafe and the configured actions first, then the gains, then the log files."""
    session = snapshot.session
    fs = snapshot.active_failsafe
    failsafe = Text("failsafe ")
    failsafe.append(fs.label if fs is not None else "none", style="bold white on red" if fs is not None else "green")
    items = [
        (0, Text(f"phase {snapshot.link.phase or '—'}", style="bold")),
        (1, failsafe),
        (2, Text(f"on failsafe {session.on_failsafe or '—'}")),
        (3, Text(f"on exit {session.on_exit or '—'}")),
        (4, Text(f"{session.controller or '—'}: " + ("  ".join(f"{k}={v}" for k, v in session.gain_summary.items()) or "—"))),
        (5, Text("logs " + (", ".join(session.log_paths) or "—"))),
    ]
    lines = fit_items(items, width, max_lines)
    return PanelBlock(Group(*lines), len(lines))


FOOTER_KEY_HELP = (  # the longest that fits is shown
    KEY_HELP,
    "q stop (level hold, hand back, exit; = Ctrl-C)   p pause/resume view (control keeps running)",
    "q stop (hold, hand back; = Ctrl-C)   p pause/resume view (control runs on)",
    "q stop (= Ctrl-C)   p pause view",
    "q stop   p pause",
)


def render_footer(paused: bool = False, width: int = 200) -> PanelBlock:
    """The key help line (shown in every layout), worded as fully as ``width`` allows."""
    prefix = "PAUSED (control unaffected)  " if paused else ""
    room = width - cell_len(prefix)
    keys = next((k for k in FOOTER_KEY_HELP if cell_len(k) <= room), FOOTER_KEY_HELP[-1])
    text = Text(no_wrap=True, overflow="ellipsis", style="dim")
    if paused:
        text.append(prefix, style="bold reverse")
    text.append(keys)
    return PanelBlock(text, 1)


# --------------------------------------------------------------------------- layout


WIDE_MIN_WIDTH = 130
HEADLINE_TWO_LINES_MIN_HEIGHT = 12  # below it the headline keeps to one line (its least important items left out)


def build_view(snapshot: TelemetrySnapshot, width: int, height: int, paused: bool = False,
               window_s: float = HISTORY_WINDOW_S) -> RenderableType:
    """The whole dashboard for a ``width`` x ``height`` terminal, never taller than ``height``, no value cut.

    Priority (kept first, dropped last): headline, footer, failsafe banner, per-axis table (or a
    3-line compact form when the table does not fit), history, link, state (link and state fall back
    to compact forms: their items on the lines left, the least important items left out whole). From
    ``WIDE_MIN_WIDTH`` columns on, link and state sit beside the per-axis table.
    """
    width, height = max(20, int(width)), max(1, int(height))
    headline = render_headline(snapshot, paused, width, max_lines=2 if height >= HEADLINE_TWO_LINES_MIN_HEIGHT else 1)
    footer = render_footer(paused, width)
    banner = render_failsafe_banner(snapshot, width)
    top: list[PanelBlock] = [headline]
    budget = height - headline.height - footer.height
    if banner is not None and banner.height <= budget:
        top.append(banner)
        budget -= banner.height

    body: list[PanelBlock] = []
    axis = render_axis_table(snapshot)
    if width >= WIDE_MIN_WIDTH:
        gap = 2
        side_w = width - _WRAP_CONSOLE.measure(axis.renderable).maximum - gap
        link, state = render_link(snapshot, side_w), render_state(snapshot, side_w)
        side_h = link.height + state.height
        if max(axis.height, side_h) <= budget:
            grid = Table.grid(padding=(0, gap))
            grid.add_column(no_wrap=True)
            grid.add_column(width=side_w)
            grid.add_row(axis.renderable, Group(link.renderable, state.renderable))
            body.append(PanelBlock(grid, max(axis.height, side_h)))
            budget -= body[-1].height
            hist = render_history(snapshot, width, window_s)
            if hist.height <= budget:
                body.append(hist)
            return _stack(top + body + [footer], height)
    if axis.height <= budget:
        body.append(axis)
        budget -= axis.height
        # each optional panel in priority order, in full or else in its compact form on the lines left
        optional = [(lambda: render_history(snapshot, width, window_s), None),
                    (lambda: render_link(snapshot, width), lambda: render_link_compact(snapshot, width, budget)),
                    (lambda: render_state(snapshot, width), lambda: render_state_compact(snapshot, width, budget))]
        for make_full, make_compact in optional:
            for make in (make_full, make_compact):
                if make is None or budget <= 0:
                    continue
                block = make()
                if 0 < block.height <= budget:
                    body.append(block)
                    budget -= block.height
                    break
    else:
        compact = render_axis_compact(snapshot)
        if compact.height <= budget:
            body.append(compact)
    return _stack(top + body + [footer], height)


def _stack(blocks: list[PanelBlock], height: int) -> RenderableType:
    """Vertical stack; when even the essentials exceed ``height`` (tiny terminal) keep the first lines."""
    kept, used = [], 0
    for block in blocks:
        if used + block.height > height:
            break
        kept.append(block.renderable)
        used += block.height
    if not kept:
        kept.append(blocks[0].renderable)
    return Group(*kept)
