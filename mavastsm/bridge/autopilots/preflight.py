"""Preflight: who is on the other end, what it accepts, and whether ATTITUDE arrives fast enough.

1. Autopilot and version from HEARTBEAT + AUTOPILOT_VERSION (REQUEST_MESSAGE 148, falling back
   to REQUEST_AUTOPILOT_CAPABILITIES); the autopilot's adapter (``mavastsm.bridge.autopilots``, by HEARTBEAT.autopilot)
   refuses firmware that ignores rates-only targets (ArduCopter older than 4.2, docs/design-decisions.md, MAV-9).
2. The adapter reads its parameters (``LinkParameters``) and settles the thrust semantics: ArduCopter's
   GUID_OPTIONS bit 3 (written with ``thrust.set_guid_options``); PX4 always a normalised collective, hovering at
   the collective its own hold flies before OFFBOARD (``measure_hover_collective``, from ATTITUDE_TARGET.thrust),
   else at MPC_THR_HOVER (``thrust.hover_from_vehicle``). It returns the ``AutopilotProfile``.
   The setpoint timeout (GUID_TIMEOUT / COM_OF_LOSS_T) is read, and shortened with
   ``limits.set_setpoint_timeout`` (restored at the end): it bounds every roll/pitch command.
3. SET_MESSAGE_INTERVAL for ATTITUDE (and ATTITUDE_TARGET) with COMMAND_ACK checked; a denied rate is
   negotiated down to the fastest granted (``negotiate_attitude_rate``); the achieved rate is measured
   later from ``time_boot_ms`` and re-asserted when a ground station overrides it.
4. The first ATTITUDE (``wait_for_first_attitude``): PX4 answers from boot but sends no ATTITUDE until its
   estimator has an attitude (the profile's ``attitude_gate``); the bridge waits, saying for what and why.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

from ...errors import Interrupted, LinkError, OffboardRejected
from ..bridge_config import BridgeConfig
from ..link.messages import TargetInMode
from ..link.mavlink_link import MSG_ID_ATTITUDE, MSG_ID_ATTITUDE_TARGET, MSG_ID_AUTOPILOT_VERSION, MavlinkLink
from .profile import AutopilotProfile
from . import adapter_for, known_autopilots

MAV_RESULT_DENIED = 2
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520


@dataclass
class PreflightReport:
    """Everything preflight found, for the one-screen summary and the LinkStatus."""

    url: str
    system: int
    component: int
    autopilot: str
    firmware_version: str = "unknown"
    mode: str = ""
    armed: bool = False
    thrust_semantics: str = ""
    thrust_detail: str = ""  # the autopilot's own words for it (adapter): "GUID_OPTIONS=0", "PX4 normalised collective, ..."
    attitude_rate_requested_hz: float = float("nan")
    attitude_rate_granted_hz: float = float("nan")  # what SET_MESSAGE_INTERVAL was accepted at (the loop's nominal rate)
    attitude_target_requested: bool = False
    signing: bool = False
    accel_limit_radss: tuple[float, float, float] | None = None
    accel_limit_source: str = "config"
    angle_p: tuple[float, float, float] | None = None
    parameters: dict[str, float | None] = field(default_factory=dict)  # every parameter read, raw (autopilot units)
    hover_collective_norm: float | None = None  # PX4: the hover collective flown (MPC_THR_HOVER or the config)
    hover_parameter_norm: float | None = None  # PX4: MPC_THR_HOVER as read (None when unread or unreadable)
    hover_source: str = ""  # PX4: where the hover collective comes from, for the summary
    setpoint_timeout_param: str = ""  # the parameter that holds it (profile.setpoint_timeout_param)
    setpoint_timeout_s: float = float("nan")  # how long the vehicle obeys our last setpoint (GUID_TIMEOUT / COM_OF_LOSS_T)
    setpoint_timeout_restore: tuple[str, float] | None = None  # (parameter, value before we changed it)
    notes: list[str] = field(default_factory=list)


class LinkParameters:
    """The vehicle's parameters over the link, as an adapter reads and writes them (``VehicleParameters``): each
    name asked once per preflight, its value (autopilot units, None when unanswered) kept in ``rep.parameters``.
    One per preflight: the adapter's reads and the flight plan's share what was asked."""

    def __init__(self, link: MavlinkLink, cfg: BridgeConfig, rep: PreflightReport) -> None:
        self.link, self.lc, self.rep = link, cfg.link, rep
        self._attempts: dict[str, int] = {}  # how many requests each unanswered read was allowed

    def _read(self, name: str, retries: int) -> float | None:
        """An answered name is asked once per preflight; an unanswered one again only by a reader that retries more
        (a reply lost on a single attempt must not decide what a retrying reader sees)."""
        known = self.rep.parameters
        if known.get(name) is None and (name not in known or retries > self._attempts.get(name, 0)):
            known[name] = self.link.requests.param_read(name, self.lc.param_timeout_s, retries)
            self._attempts[name] = retries
        return known[name]

    def read(self, name: str) -> float | None:
        return self._read(name, 1)

    def read_with_retries(self, name: str) -> float | None:
        return self._read(name, self.lc.command_retries)

    def write(self, name: str, value: float) -> bool:
        if not self.link.requests.param_set(name, value, self.lc.param_timeout_s, self.lc.command_retries):
            return False
        self.rep.parameters[name] = float(value)
        return True


def run_preflight(link: MavlinkLink, cfg: BridgeConfig) -> tuple[PreflightReport, AutopilotProfile, LinkParameters]:
    """Identify the autopilot, settle thrust semantics and request the telemetry the loop needs. Returns the report,
    the autopilot's profile and the parameters as read so far (the flight plan reads on through them).

    Raises OffboardRejected (old ArduCopter, refused interval) or ConfigError (thrust semantics).
    """
    hb = link.last_heartbeat
    assert hb is not None
    lc = cfg.link
    rep = PreflightReport(link.url, hb.system, hb.component, str(hb.autopilot_id), mode=hb.mode, armed=hb.armed, signing=link.signing)
    if not link.requests.request_message(MSG_ID_AUTOPILOT_VERSION, lc.command_ack_timeout_s):
        try:
            link.requests.command_long(MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, (1.0,), "REQUEST_AUTOPILOT_CAPABILITIES", lc.command_ack_timeout_s, 1)
        except OffboardRejected:
            pass
    reported = link.autopilot_version()
    version = None
    if reported is not None:
        version = reported.version
        rep.firmware_version = reported.text
    adapter = adapter_for(hb.autopilot_id)
    if adapter is None:
        raise OffboardRejected("autopilot detection", None, f"no adapter for HEARTBEAT autopilot {hb.autopilot_id} "
                               f"(known: {known_autopilots()}; docs/bridge.md, 'Another autopilot')")
    rep.autopilot = adapter.name
    refusal = adapter.body_rate_refusal(version)
    if refusal:
        raise OffboardRejected("body-rate offboard control", None, refusal)
    rep.accel_limit_radss = tuple(cfg.mapping.accel_limit_radss)  # type: ignore[assignment]  # unless the adapter reads its own
    parameters = LinkParameters(link, cfg, rep)
    profile = adapter.configure(parameters, cfg, rep)
    _settle_setpoint_timeout(link, cfg, profile, rep)

    rep.attitude_rate_requested_hz = cfg.timing.attitude_rate_hz
    rep.attitude_rate_granted_hz, note = negotiate_attitude_rate(
        link, cfg.timing.attitude_rate_hz, cfg.timing.attitude_rate_min_hz, lc.command_ack_timeout_s, lc.command_retries)
    if note:
        rep.notes.append(note)
    if cfg.timing.attitude_target_rate_hz > 0:
        try:
            link.requests.set_message_interval(MSG_ID_ATTITUDE_TARGET, cfg.timing.attitude_target_rate_hz, lc.command_ack_timeout_s, 1)
            rep.attitude_target_requested = True
        except OffboardRejected as exc:
            rep.notes.append(f"ATTITUDE_TARGET not available ({exc})")
    return rep, profile, parameters


HOVER_MIN_COVERAGE = 0.5  # [-] of thrust.hover_measure_s the targets must span
HOVER_MIN_SAMPLES = 5
HOVER_MAX_STD_NORM = 0.05  # [-] a hold commands a steady collective; a climb or a landing's ramp scatters more
HOVER_PARAMETER_BAND = (0.5, 2.0)  # measured / MPC_THR_HOVER outside this: not a hover (a landed vehicle's idle)
HOVER_FRESH_S = 2.0  # [s] the newest target of the hold must be at most this older than the vehicle's clock now


@dataclass(frozen=True, slots=True)
class HoverMeasurement:
    """The hover collective measured from the autopilot's own hold (``measure_hover_collective``).

    hover_norm : [-] mean vertical component of the commanded collective (thrust x cos roll cos pitch of the target)
    samples : targets averaged; span_s : [s] vehicle time they cover; std_norm : [-] their standard deviation
    mode : the autopilot mode they were commanded in (its hold); parameter_norm : [-] MPC_THR_HOVER for comparison (or None)
    """

    hover_norm: float
    samples: int
    span_s: float
    std_norm: float
    mode: str
    parameter_norm: float | None = None

    def text(self, autopilot: str = "PX4", parameter: str = "MPC_THR_HOVER") -> str:
        """'hover collective 0.561 from PX4's hold (...)' for the operator."""
        was = f"; {parameter} {self.parameter_norm:.3f}" if self.parameter_norm is not None else ""
        return (f"hover collective {self.hover_norm:.3f} from {autopilot}'s hold (ATTITUDE_TARGET thrust, {self.samples} "
                f"targets over {self.span_s:.2f} s in {self.mode}, std {self.std_norm:.3f}{was})")


def measure_hover_collective(targets: list[TargetInMode], guided_modes: tuple[str, ...], window_s: float, now_ms: int,
                             parameter_norm: float | None = None) -> HoverMeasurement | str:
    """The collective an autopilot's own controllers hover the vehicle with, from its ATTITUDE_TARGETs (pure).

    PX4 1.15 streams ATTITUDE_TARGET.thrust = |thrust_body| of its attitude setpoint (mavlink streams/
    ATTITUDE_TARGET.hpp): in its own hold (LOITER, POSCTL, ...) that is the collective its position controller,
    with its hover-thrust estimator, flies, so its vertical component (x R33 of the target quaternion =
    cos roll cos pitch) holds the vehicle as it is, payload included, whatever MPC_THR_HOVER says.

    Kept: targets received armed and outside ``guided_modes`` (in OFFBOARD PX4 repeats its last hold target with the
    old timestamp; those, and any target not newer than the one before, are dropped); averaged: those of the newest
    kept one's mode since PX4 entered it (the hold, not the takeoff's climb before it) within the last ``window_s`` [s]
    of vehicle time before the newest. ``now_ms`` [ms] is the vehicle's clock now.
    Returns the HoverMeasurement, or why there is none (a string): no hold, stale, too few, too short, scattered,
    outside [0.05, 0.95] or outside HOVER_PARAMETER_BAND x ``parameter_norm``.
    """
    kept: list[tuple[int, float]] = []
    modes: list[str] = []
    last_ms = None
    for t in targets:
        tb = t.target.time_boot_ms
        if last_ms is not None and tb <= last_ms:
            continue  # a repeated (stale) target
        last_ms = tb
        if not t.armed or t.mode in guided_modes or not math.isfinite(t.target.thrust_norm):
            continue
        w, x, y, z = t.target.q_wxyz
        n2 = w * w + x * x + y * y + z * z
        vertical = (w * w - x * x - y * y + z * z) / n2 if math.isfinite(n2) and n2 > 0.25 else 1.0
        kept.append((tb, t.target.thrust_norm * vertical))
        modes.append(t.mode)
    if not kept:
        return "no ATTITUDE_TARGET from a hold of its own (armed, not in the guided mode)"
    end_ms = kept[-1][0]
    if now_ms - end_ms > HOVER_FRESH_S * 1000.0:
        return f"its hold's last target is {(now_ms - end_ms) / 1000.0:.1f} s old"
    first = next(i for i, (tb, _) in enumerate(kept) if tb >= end_ms - window_s * 1000.0)
    while modes[first] != modes[-1]:  # the hold only: not the mode before it (PX4's takeoff still climbing)
        first += 1
    window, mode = kept[first:], modes[-1]
    span_s = (window[-1][0] - window[0][0]) / 1000.0
    if len(window) < HOVER_MIN_SAMPLES or span_s < HOVER_MIN_COVERAGE * window_s:
        return f"{len(window)} targets over {span_s:.2f} s of its hold (need {HOVER_MIN_SAMPLES} over {HOVER_MIN_COVERAGE * window_s:g} s)"
    values = [v for _, v in window]
    mean = sum(values) / len(values)
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / len(values))
    if not (math.isfinite(mean) and 0.05 <= mean <= 0.95):
        return f"mean collective {mean:.3f} of its hold is outside [0.05, 0.95]"
    if std > HOVER_MAX_STD_NORM:
        return f"its collective scatters (std {std:.3f} > {HOVER_MAX_STD_NORM:g}): not a steady hold"
    if parameter_norm is not None and not (HOVER_PARAMETER_BAND[0] * parameter_norm <= mean <= HOVER_PARAMETER_BAND[1] * parameter_norm):
        return (f"mean collective {mean:.3f} of its hold is outside {HOVER_PARAMETER_BAND[0]:g}-{HOVER_PARAMETER_BAND[1]:g} x "
                f"the hover parameter {parameter_norm:.3f} (a landed vehicle's idle is no hover)")
    return HoverMeasurement(mean, len(window), span_s, std, mode, parameter_norm)


def hover_source(link: MavlinkLink, profile: AutopilotProfile, thrust_cfg, rep: PreflightReport):
    """Where the autopilot's own hold gives the hover collective (PX4, ``thrust.hover_from_vehicle`` and
    ``thrust.hover_measure_s`` > 0, ATTITUDE_TARGET requested): vehicle time [ms] -> the measurement over the last
    ``hover_measure_s`` before the guided mode (``measure_hover_collective``) or why there is none; else None (and a
    note says why, when ATTITUDE_TARGET is what is missing)."""
    tc = thrust_cfg
    if not (profile.hover_from_target_thrust and tc.hover_from_vehicle and tc.hover_measure_s > 0):
        return None
    if not rep.attitude_target_requested:
        rep.notes.append("hover collective not measured from the vehicle's hold: ATTITUDE_TARGET not requested "
                         "(timing.attitude_target_rate_hz = 0) or refused")
        return None
    guided = profile.guided_modes
    return lambda now_ms: measure_hover_collective(link.recent_attitude_targets(), guided, tc.hover_measure_s, now_ms,
                                                   rep.hover_parameter_norm)


def _settle_setpoint_timeout(link: MavlinkLink, cfg: BridgeConfig, profile: AutopilotProfile, rep: PreflightReport) -> None:
    """Read (and with ``limits.set_setpoint_timeout`` write) the vehicle's setpoint timeout.

    ``rep.setpoint_timeout_s`` is the value in force, which bounds every outbound roll/pitch command
    (safety.last_setpoint_safe_rates). Unreadable -> the autopilot's default is assumed (3 s ArduCopter,
    1 s PX4), which is the conservative choice for that bound.
    """
    lim, lc = cfg.limits, cfg.link
    name = profile.setpoint_timeout_param
    rep.setpoint_timeout_param = name
    current = link.requests.param_read(name, lc.param_timeout_s, lc.command_retries)
    lo, hi = profile.setpoint_timeout_range_s
    want = min(max(lim.setpoint_timeout_s, lo), hi)
    if lim.set_setpoint_timeout and current is not None and abs(current - want) > 1e-6:
        if link.requests.param_set(name, want, lc.param_timeout_s, lc.command_retries):
            rep.setpoint_timeout_restore = (name, float(current))
            rep.notes.append(f"{name} set {current:g} -> {want:g} s (limits.setpoint_timeout_s; restored at the end)")
            current = want
        else:
            rep.notes.append(f"{name} could not be set to {want:g} s; keeping {current:g} s")
    if current is None or not math.isfinite(current):
        current = profile.setpoint_timeout_default_s
        rep.notes.append(f"{name} unreadable: {current:g} s assumed for the last-setpoint bound")
    rep.setpoint_timeout_s = float(current)
    if current < 10.0 / cfg.timing.attitude_rate_hz:
        rep.notes.append(f"{name} {current:g} s is less than 10 control periods")
    if current > 1.0:
        rep.notes.append(f"{name} is {current:g} s: the last-setpoint bound leaves little roll/pitch rate "
                         f"(set limits.set_setpoint_timeout=true, or lower {name})")


def negotiate_attitude_rate(link: MavlinkLink, requested_hz: float, floor_hz: float, timeout_s: float,
                            retries: int) -> tuple[float, str]:
    """Ask for ATTITUDE at ``requested_hz``; when the vehicle DENIES it, settle on the fastest rate it grants.

    ArduCopter 4.6+ denies (MAV_RESULT_DENIED, plus a STATUSTEXT) an interval shorter than its main loop
    allows (SCHED_LOOP_RATE 400 -> anything faster than 3 ms); older ArduCopter and PX4 accept and send
    what they can (the achieved rate is measured from ``time_boot_ms`` afterwards). ArduCopter keeps
    intervals in whole milliseconds, so after a denial the next slower whole-millisecond intervals are
    tried, down to ``floor_hz``. Returns (granted rate [Hz], note for the preflight summary, "" when the
    request was granted as asked). OffboardRejected when nothing at or above ``floor_hz`` is granted.
    """
    try:
        link.requests.set_message_interval(MSG_ID_ATTITUDE, requested_hz, timeout_s, retries)
        return requested_hz, ""
    except OffboardRejected as exc:
        if exc.result != MAV_RESULT_DENIED:
            raise
        why = exc.detail or "no reason given"
    interval_ms = max(1, math.ceil(1000.0 / requested_hz - 1e-9))
    while 1000.0 / interval_ms >= floor_hz:
        try:
            link.requests.set_message_interval(MSG_ID_ATTITUDE, 1000.0 / interval_ms, timeout_s, retries)
        except OffboardRejected as exc:
            if exc.result != MAV_RESULT_DENIED:
                raise
            interval_ms += 1
            continue
        granted = 1000.0 / interval_ms
        return granted, (f"ATTITUDE at {requested_hz:g} Hz denied by the vehicle ({why}); using {granted:.1f} Hz "
                         f"({interval_ms} ms), the fastest it grants")
    raise OffboardRejected(f"SET_MESSAGE_INTERVAL ATTITUDE at {requested_hz:g} Hz", MAV_RESULT_DENIED,
                           f"{why}; nothing down to timing.attitude_rate_min_hz = {floor_hz:g} Hz was granted")


MAV_SEVERITY_WARNING = 4  # STATUSTEXT severities up to this are reasons; INFO (a log file's name) is not
ATTITUDE_WAIT_PROGRESS_S = 2.0  # how often the wait for the first ATTITUDE says where it is


def wait_for_first_attitude(link: MavlinkLink, profile: AutopilotProfile, has_attitude: Callable[[], bool], cfg: BridgeConfig,
                            grace_s: float, stop: threading.Event, say: Callable[[str], None],
                            sleep: Callable[[float], bool] | None = None) -> None:
    """Return once the first ATTITUDE has arrived (``has_attitude()``), after SET_MESSAGE_INTERVAL was accepted.
    ``sleep(s) -> stopped`` waits between looks (default ``stop.wait``; the bridge passes its own, which runs on the
    vehicle's clock in lockstep, so a lockstep sim advances while it waits).

    An autopilot that sends ATTITUDE from boot (``profile.attitude_gate`` empty: ArduCopter) and sends none within
    ``grace_s`` has a broken link: LinkError at once. One that answers but holds ATTITUDE back until its estimator
    has an attitude (PX4, about 33 s after boot) is waited for up to ``link.attitude_wait_s``, every
    ATTITUDE_WAIT_PROGRESS_S saying what for, the elapsed time and the autopilot's own reasons (the SYS_STATUS
    subsystems it reports unhealthy, its last two warnings by STATUSTEXT); then LinkError with them. A lost HEARTBEAT ends
    the wait with LinkError, an operator stop (``stop`` set: Ctrl-C, SIGTERM) with Interrupted, both at once.
    """
    lc = cfg.link
    gate = profile.attitude_gate
    start = time.monotonic()
    said = 0.0

    def reasons() -> str:
        warnings = [text for _, severity, text in list(link.stats.statustext) if severity <= MAV_SEVERITY_WARNING][-2:]
        failing = link.unhealthy_sensors()
        if failing is None and not warnings:
            return ""
        parts = [f"unhealthy {', '.join(failing)} (SYS_STATUS)"] if failing else ["no unhealthy subsystem (SYS_STATUS)"]
        return f"; {profile.name} reports {'; '.join(parts + [repr(t) for t in warnings])}"

    while not has_attitude():
        elapsed = time.monotonic() - start
        if not gate and elapsed >= grace_s:
            raise LinkError(f"{link.url}: autopilot answers but sends no ATTITUDE (SET_MESSAGE_INTERVAL was accepted)")
        if gate and elapsed >= lc.attitude_wait_s:
            raise LinkError(f"{link.url}: no ATTITUDE within link.attitude_wait_s = {lc.attitude_wait_s:g} s of waiting for "
                            f"{gate}{reasons()}; wait longer (--set link.attitude_wait_s=...) or check the estimator")
        if link.seconds_since_heartbeat() > lc.link_loss_timeout_s:
            raise LinkError(f"{link.url}: no HEARTBEAT for {link.seconds_since_heartbeat():.1f} s while waiting for the first ATTITUDE")
        if gate and elapsed - said >= ATTITUDE_WAIT_PROGRESS_S:
            said = elapsed
            say(f"waiting for {gate}: no ATTITUDE yet … {elapsed:.0f} s{reasons()}")
        if (sleep or stop.wait)(0.02):
            raise Interrupted(f"while waiting for {gate or 'the first ATTITUDE'} ({time.monotonic() - start:.0f} s)")
    if said:
        say(f"ATTITUDE flows after {time.monotonic() - start:.0f} s of waiting for {gate}")


def measure_attitude_rate(link: MavlinkLink, session, cfg: BridgeConfig, stop: threading.Event, say: Callable[[str], None],
                          sleep: Callable[[float], bool]) -> float:
    """[Hz] The ATTITUDE rate the vehicle really sends, from time_boot_ms of the samples the session received: after
    the first ATTITUDE (``wait_for_first_attitude``), over ``timing.rate_measure_s`` of vehicle time (or 10 samples),
    bounded in wall time; recorded in the session. NaN when not measured in time."""
    t = cfg.timing
    grace_s = 4 * t.rate_measure_s + t.rate_measure_slack_s
    wait_for_first_attitude(link, session.cycle.profile, lambda: session.last_ms is not None, cfg, grace_s, stop, say, sleep)
    deadline = time.monotonic() + grace_s
    stage = session.sample_stage
    while time.monotonic() < deadline and not math.isfinite(stage.achieved_rate_hz):
        win = stage.rate_window()
        if win is not None:
            first, n, last = win
            span = (last - first) / 1000.0
            if span >= t.rate_measure_s or (n >= 10 and span > 0):
                stage.record_achieved_rate(n / span)
                break
        sleep(0.02)
    return stage.achieved_rate_hz


def format_preflight(rep: PreflightReport, achieved_hz: float, controller: str, reference: str, mapping: str, scheduling: str = "") -> str:
    """The one-screen preflight summary (plain text); ``scheduling`` = how the control thread is scheduled."""

    def fmt(x, unit=""):
        return "unknown" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:g}{unit}"

    lines = [
        f"mavastsm connect: {rep.url}",
        f"  vehicle      : system {rep.system} component {rep.component}, {rep.autopilot} {rep.firmware_version}, mode {rep.mode}, {'ARMED' if rep.armed else 'disarmed'}",
        f"  thrust       : {rep.thrust_semantics} ({rep.thrust_detail}, {rep.setpoint_timeout_param}={fmt(rep.setpoint_timeout_s, ' s')})",
        f"  ATTITUDE     : requested {fmt(rep.attitude_rate_requested_hz, ' Hz')}, granted {fmt(round(rep.attitude_rate_granted_hz, 1), ' Hz')}, achieved {fmt(round(achieved_hz, 1) if math.isfinite(achieved_hz) else float('nan'), ' Hz')} (from time_boot_ms)",
        f"  controller   : {controller}, reference {reference}, mapping {mapping}",
        "  target model : " + (f"on (ATC_ANG_P {', '.join(f'{p:g}' for p in rep.angle_p)})" if rep.angle_p else "off"),
        "  accel limits : " + (", ".join(f"{a:.2f}" for a in rep.accel_limit_radss) + f" rad/s^2 ({rep.accel_limit_source})" if rep.accel_limit_radss else "none"),
        f"  last setpoint: obeyed {fmt(rep.setpoint_timeout_s, ' s')} after the stream stops; roll/pitch commands bounded so that it stays survivable",
        f"  signing      : {'on' if rep.signing else 'off'}",
    ]
    if scheduling:
        lines.append(f"  control loop : {scheduling}")
    lines += [f"  note         : {n}" for n in rep.notes]
    return "\n".join(lines)
