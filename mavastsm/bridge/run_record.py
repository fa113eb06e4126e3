"""The run's record outside the flight CSV: the summary a run ends with, the sidecar's metadata and counters, and the
session and link descriptions the dashboard reads (telemetry). Built from what the link, the session and the preflight
hold; nothing here talks to the vehicle."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..config_loading import per_axis
from ..signing import REFUSED_FRAME_CLASSES
from ..state_types import FailsafeReason
from ..telemetry import COUNTER_DEFINITIONS, ControlSample, LinkStatus, SessionInfo
from .record.flight_log import add_metadata, metadata_path, write_metadata
from .session.session_counters import SessionCounters
from .session.session_output import LIVE_LATENCY_WINDOW
from .record.tracking_metrics import AxisMetrics, format_metrics_table, run_metrics


def gain_display_text(value) -> str:
    """A gain for the dashboard: numbers to 4 significant digits, per-axis values as roll/pitch/yaw (no space, so a
    wrapped gain list breaks between gains); others as ``str``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, tuple, list)):
        return str(value)
    if isinstance(value, (tuple, list)):
        return "/".join(gain_display_text(v) for v in value)
    return f"{value:.4g}"


@dataclass(frozen=True)
class BridgeSummary:
    """What a run did. Latencies in s (ATTITUDE received -> SET_ATTITUDE_TARGET sent, host monotonic)."""

    url: str
    autopilot: str
    firmware_version: str
    thrust_semantics: str
    controller: str
    reference: str
    end_reason: str
    failsafe: FailsafeReason | None
    handback: str
    engagements: int
    cycles: int
    missed: int
    dropped: int
    duplicate: int
    superseded: int
    invalid: int
    foreign_attitude: int
    blocked_setpoints: int
    overruns: int
    latency_p50_s: float
    latency_p99_s: float
    latency_max_s: float
    attitude_rate_achieved_hz: float
    engage_time_s: float
    axes: tuple[AxisMetrics, ...]
    samples: tuple[ControlSample, ...] = ()
    log_paths: tuple[str, ...] = ()
    handback_confirmed: bool = False  # the autopilot's HEARTBEAT showed the hand-back mode (within link.handback_confirm_s of the ACK)
    handback_failed: bool = False  # every mode of the hand-back action was refused
    out_of_order: int = 0  # queued ATTITUDE older (time_boot_ms) than one pending in the reader: discarded
    clock_outliers: int = 0  # ATTITUDE out of the vehicle's clock, refuted by the stream: dropped (vehicle_clock)
    vehicle_restarts: int = 0  # autopilot clock restarts seen (time_boot_ms back by > 3 s)
    vehicle_sessions: int = 1  # 1 + restarts + HEARTBEAT reappearances after a link-loss gap
    recovered_failsafes: tuple[FailsafeReason, ...] = ()  # failsafes followed by a re-engagement (reengage)
    refused_frames: tuple[tuple[str, int], ...] = ()  # (class, count) per mavastsm.signing.REFUSED_FRAME_CLASSES, nonzero only
    reader_errors: int = 0  # exceptions counted in the link's threads (telemetry.COUNTER_DEFINITIONS)
    late: int = 0  # the bridge's own deadline misses while engaged (telemetry.COUNTER_DEFINITIONS)
    samples_capped: bool = False  # timing.samples_in_memory reached: samples and metrics cover the first ones only
    identified: str = ""  # what the in-flight identification phase found and flew ("" when no phase flew)

    @property
    def exit_code(self) -> int:
        """0 for a normal end or operator stop, 1 when a failsafe ended the run or the hand-back failed altogether."""
        return 0 if self.failsafe is None and not self.handback_failed else 1

    def format(self) -> str:
        if math.isfinite(self.latency_p50_s):
            lat = f"latency p50 {self.latency_p50_s * 1e6:.0f} us, p99 {self.latency_p99_s * 1e6:.0f} us, max {self.latency_max_s * 1e6:.0f} us"
        else:
            lat = "latency: none measured (no control cycle ran)"
        lines = [
            f"end: {self.end_reason}; hand-back: {self.handback}",
            *([self.identified] if self.identified else []),
            f"cycles {self.cycles}, late {self.late} (the bridge's own deadline misses), missed {self.missed} (the vehicle's gaps), dropped {self.dropped}, duplicate {self.duplicate}, "
            f"superseded {self.superseded} (queued back to back: the newest of each burst was used), out-of-order {self.out_of_order}, clock outliers {self.clock_outliers}, invalid {self.invalid}, foreign {self.foreign_attitude}, "
            f"blocked {self.blocked_setpoints}, overruns {self.overruns}, reader errors {self.reader_errors}; engagements {self.engagements}, vehicle sessions {self.vehicle_sessions}"
            + (f", recovered from {', '.join(r.label for r in self.recovered_failsafes)}" if self.recovered_failsafes else ""),
            (f"ATTITUDE achieved {self.attitude_rate_achieved_hz:.1f} Hz" if math.isfinite(self.attitude_rate_achieved_hz) and self.attitude_rate_achieved_hz > 0
             else "ATTITUDE achieved: not measured (under one second of samples)") + f"; {lat}",
            format_metrics_table(self.axes),
        ]
        refused = sum(n for _, n in self.refused_frames)
        lines.insert(2 + bool(self.identified), f"refused frames: {refused}" + (f" ({', '.join(f'{name} {n}' for name, n in self.refused_frames)})" if refused else ""))
        if self.samples_capped:
            lines.append(f"metrics over the first {len(self.samples)} cycles kept in memory (timing.samples_in_memory); the CSV has every cycle")
        if self.log_paths:
            lines.append("logs: " + ", ".join(self.log_paths))
        return "\n".join(lines)


def summarise(link, session, preflight, controller_name: str, reference_name: str, handback: str, handback_confirmed: bool,
              handback_failed: bool, log_paths: tuple[str, ...]) -> BridgeSummary:
    """The run's summary from the link's and the session's counters, the preflight report and the hand-back;
    metrics over the engaged samples kept in memory."""
    s, c, rep = session, session.counters, preflight
    p50, p99, pmax = s.output.latencies_s.percentiles()
    cyc = s.cycle
    unfinished = cyc.identifying  # the phase never handed over to the profile: no profile metric exists
    engage_t = (cyc.engage_ms / 1000.0) if cyc.engage_ms is not None and not unfinished else float("nan")
    identified = (cyc.identified.text() if cyc.identified is not None
                  else "loop identification phase not finished: the profile never started" if unfinished else "")
    with s.lock:
        samples = tuple(s.output.samples)
    engaged = tuple(x for x in samples if x.vehicle_time_s >= engage_t) if math.isfinite(engage_t) else ()
    return BridgeSummary(
        url=link.url, autopilot=rep.autopilot, firmware_version=rep.firmware_version, thrust_semantics=rep.thrust_semantics,
        controller=controller_name, reference=reference_name, end_reason=s.end_reason or "stopped",
        failsafe=s.failsafe, handback=handback, engagements=c.engagements, cycles=c.cycles, missed=c.missed,
        dropped=c.dropped, duplicate=c.duplicate, superseded=link.stats.superseded, invalid=c.invalid,
        foreign_attitude=link.stats.foreign_attitude, blocked_setpoints=c.blocked_setpoints, overruns=c.overruns,
        latency_p50_s=p50, latency_p99_s=p99, latency_max_s=pmax, attitude_rate_achieved_hz=s.sample_stage.achieved_rate_hz,
        engage_time_s=engage_t, axes=run_metrics(engaged, engage_t, s.cycle.reference), samples=samples, log_paths=log_paths,
        handback_confirmed=handback_confirmed, handback_failed=handback_failed, out_of_order=link.stats.out_of_order,
        clock_outliers=link.clock.outliers,
        vehicle_restarts=c.vehicle_restarts, vehicle_sessions=c.vehicle_sessions, recovered_failsafes=tuple(s.recovered_failsafes),
        refused_frames=tuple((name, link.stats.refused[name]) for name in REFUSED_FRAME_CLASSES if link.stats.refused[name]),
        samples_capped=len(samples) >= s.output.max_samples_kept, reader_errors=link.stats.reader_errors, late=c.late,
        identified=identified,
    )


def exact_gains(controller) -> dict[str, str]:
    """The controller's gains as ``str`` gives them (every digit: the sidecar records what flew)."""
    g = getattr(controller, "gains", None)
    return {k: str(v) for k, v in vars(g).items()} if g is not None else {}


def flight_metadata(url: str, overrides, preflight, vehicle: str, controller, controller_name: str, reference_name: str,
                    config, session) -> dict[str, Any]:
    """What is about to fly, for the sidecar: the link, the autopilot, the vehicle description, the controller with
    its exact gains, the reference, the bridge config and the user's overrides, the preflight notes, the mapping."""
    rep = preflight
    return {
        "url": url, "autopilot": rep.autopilot, "firmware_version": rep.firmware_version,
        "thrust_semantics": rep.thrust_semantics, "attitude_rate_granted_hz": rep.attitude_rate_granted_hz,
        "vehicle": vehicle, "controller": controller_name,
        "controller_config": str(getattr(controller, "config_path", "")), "gains": exact_gains(controller),
        "reference": reference_name, "bridge_config": config.source,
        "overrides": {k: v for k, v in (overrides or {}).items()}, "notes": list(rep.notes),
        "mapping": session.cycle.mapping_record() if session is not None else None,
    }


def write_flight_metadata(log_path: Path | None, diagnostic_keys, what: dict[str, Any], say: Callable[[str], None]) -> None:
    """The CSV's sidecar (flight_log.write_metadata): what is about to fly (``what``: url, vehicle, controller, gains,
    mapping, notes, ...), stamped with the package version and the UTC start; a failure is said, never raised."""
    if log_path is None:
        return
    from .. import __version__

    try:
        write_metadata(log_path, {"mavastsm_version": __version__, **what,
                                  "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}, diagnostic_keys)
    except OSError as exc:
        say(f"note: cannot write the log's metadata sidecar ({exc})")


def write_counters(log_path: Path | None, summary: BridgeSummary, say: Callable[[str], None]) -> None:
    """The run's counters in the CSV's sidecar, by the names and definitions of telemetry.COUNTER_DEFINITIONS."""
    if log_path is None or not metadata_path(log_path).exists():
        return
    values = {name: getattr(summary, name) for name in COUNTER_DEFINITIONS if name != "refused_frames"}
    values["refused_frames"] = sum(n for _, n in summary.refused_frames)
    try:
        add_metadata(log_path, {"counters": {name: {"value": values[name], "definition": d} for name, d in COUNTER_DEFINITIONS.items()}})
    except OSError as exc:
        say(f"note: cannot write the run's counters to the log's sidecar ({exc})")


def write_flown_mapping(log_path: Path | None, session, say: Callable[[str], None]) -> None:
    """The mapping as it flew at the end (an in-flight identification may have changed its tau, and says what it
    found) in the CSV's sidecar, over the one written at the start."""
    if log_path is None or session is None or not metadata_path(log_path).exists():
        return
    try:
        add_metadata(log_path, {"mapping": session.cycle.mapping_record()})
    except OSError as exc:
        say(f"note: cannot write the flown mapping to the log's sidecar ({exc})")


def session_info(controller, controller_name: str, reference_name: str, session, duration_s: float, on_failsafe: str,
                 on_exit: str, log_paths: tuple[str, ...]) -> SessionInfo:
    """What the dashboard shows of the session: the controller's gains (4 digits), its adaptation band, the reference
    and when it started, the hand-back actions and the logs."""
    g = getattr(controller, "gains", None)
    gains = {k: gain_display_text(v) for k, v in vars(g).items()} if g is not None else {}
    a = controller.adaptive_gain()
    nan3 = (float("nan"),) * 3
    return SessionInfo(
        controller=controller_name, gain_summary=gains, mu=per_axis(a.mu) if a and a.mu is not None else nan3,
        alpha_min=per_axis(a.alpha_min) if a else nan3, alpha_max=per_axis(a.alpha_max) if a else nan3,
        reference_name=reference_name,
        reference_start_vehicle_time_s=(session.cycle.engage_ms / 1000.0) if session and session.cycle.engage_ms is not None else float("nan"),
        reference_duration_s=duration_s, on_failsafe=on_failsafe, on_exit=on_exit, log_paths=log_paths,
    )


def link_status(link, session, preflight, attitude_rate_requested_hz: float, phase: str) -> LinkStatus:
    """What the dashboard shows of the link: the autopilot, its mode, rates, latency and every counter."""
    s, rep = session, preflight
    c = s.counters if s else SessionCounters()  # before the session: every count 0
    hb = link.last_heartbeat
    p50, p99, _ = s.output.latencies_s.percentiles(LIVE_LATENCY_WINDOW) if s else (float("nan"),) * 3
    return LinkStatus(
        url=link.url, autopilot=rep.autopilot if rep else "unknown", firmware_version=rep.firmware_version if rep else "",
        mode=hb.mode if hb else "", armed=hb.armed if hb else False, thrust_semantics=rep.thrust_semantics if rep else "",
        attitude_rate_requested_hz=attitude_rate_requested_hz,
        attitude_rate_achieved_hz=s.sample_stage.achieved_rate_hz if s else float("nan"),
        latency_p50_s=p50, latency_p99_s=p99, cycles=c.cycles, missed=c.missed, dropped=c.dropped, duplicate=c.duplicate,
        superseded=link.stats.superseded, invalid=c.invalid,
        time_since_attitude_s=((time.monotonic_ns() - s.sample_stage.last_fresh_ns) * 1e-9) if s and s.sample_stage.last_fresh_ns
        else float("nan"),
        signing=link.signing, refused_frames=link.stats.bad_data, phase=phase,
        out_of_order=link.stats.out_of_order, clock_outliers=link.clock.outliers, foreign_attitude=link.stats.foreign_attitude,
        blocked_setpoints=c.blocked_setpoints, overruns=c.overruns, reader_errors=link.stats.reader_errors, late=c.late,
    )
