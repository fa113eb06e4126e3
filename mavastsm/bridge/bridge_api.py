"""The Python API of the offboard attitude bridge: ``Bridge(BridgeOptions)``.

    from mavastsm.bridge import Bridge, BridgeOptions
    summary = Bridge(BridgeOptions("udpout:127.0.0.1:14550", mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=2.0)).run()

or, non-blocking (dashboards, tests)::

    bridge = Bridge(options, telemetry)
    bridge.start()            # connect + preflight + mode/arm requests; raises LinkError/OffboardRejected/ConfigError
    ...                       # telemetry fills; bridge.state, bridge.session
    summary = bridge.stop()   # level hold, hand-back (options.on_exit), logs flushed

The bridge never arms or changes mode unless the options say so (``mode``, ``arm``, ``on_exit``,
``on_failsafe``). Without ``mode`` it waits for the pilot to select a guided mode and arm.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from ..config_loading import per_axis, resolve_config
from ..errors import ConfigError, Interrupted, LinkError, OffboardRejected
from ..solo_model import load_offboard_loop, load_solo, packaged_vehicle_tunings
from ..state_types import FailsafeReason
from ..telemetry import COUNTER_DEFINITIONS, ControlSample, LinkStatus, SessionInfo, TelemetryBuffer, extra_diagnostic_keys
from .bridge_config import BridgeConfig, load_bridge_config, split_overrides
from .control_cycle import ControlCycle, command_clip_mode, command_torque_limit_nm
from .flight_log import FlightLog, add_metadata, metadata_path, write_metadata
from ..signing import REFUSED_FRAME_CLASSES, load_signing_key
from .mavlink_link import MAV_CMD_NAV_TAKEOFF, MSG_ID_ATTITUDE, MSG_ID_GLOBAL_POSITION_INT, MSG_ID_LOCAL_POSITION_NED, MavlinkLink, parse_link_url
from .offboard_session import LIVE_LATENCY_WINDOW, REENGAGE_AFTER, OffboardSession, SessionState
from .preflight import (HoverMeasurement, PreflightReport, format_preflight, measure_hover_collective, read_parameter, run_preflight,
                        wait_for_first_attitude)
from .autopilot_profile import CLIMB_RATE, COLLECTIVE, arming_fix
from .setpoint_mapping import adaptive_gain_ceiling, switching_delay_s, yaw_from_reference
from .tracking_metrics import AxisMetrics, format_metrics_table, run_metrics

HANDBACK_ACTIONS = ("ALT_HOLD", "LOITER", "LAND", "none")
DEFAULT_VEHICLE = "solo"  # configs/vehicle/solo.yaml until preflight knows the autopilot (AutopilotProfile.default_vehicle)
REQUESTABLE_MODES = ("GUIDED", "GUIDED_NOGPS", "OFFBOARD")
REST_VZ_MS = 0.1  # [m/s] before the autopilot's own takeoff: |vz| estimate at most this ...
REST_HOLD_S = 2.0  # [s] ... for this long: the vertical estimate is at rest (_wait_vertical_estimate_at_rest)
# [s] else the takeoff is refused. SIH's estimate wanders +-0.4 m/s on the ground for minutes, with a 2 s window at
# rest now and then (first after 11.2-11.5 s in 3 boots of 2026-12-04); once (CI) none came in 60 s.
REST_TIMEOUT_S = 120.0
SECOND_SOURCE_WAIT_S = 1.5  # [s] start-up: at most this long for the verdict on a second address sending the target's id

# The bridge runs one cycle per ATTITUDE (<= 400 Hz, 320 Hz on ArduCopter's 80 % cap), so ASTSM gets its
# the MAVLink preset (E2 with mu = 0.06 rad/s above the ripple the autopilot's rate loop leaves in sigma, alpha_m = 5) unless told otherwise.


@dataclass
class BridgeOptions:
    """Everything ``mavastsm connect`` can be told. Units in the names; angles never here.

    Attributes
    ----------
    url : pymavlink connection string (udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:5760, /dev/ttyACM0 ...)
    controller : registry name (``mavastsm list-controllers``) or a ready AttitudeController object
    controller_config : controller preset or YAML path (None = astsm_mavlink for astsm, else the controller's default)
    bridge_config : bridge YAML (None = packaged configs/bridge.yaml)
    overrides : ``{"section.key": value}`` for the bridge config, other keys go to the controller
    reference : packaged reference name / YAML path, or a ReferenceProfile object
    vehicle_config : vehicle YAML (None = packaged Solo) for the nominal inertia I0
    rate_hz : [Hz] ATTITUDE rate to request (None = timing.attitude_rate_hz)
    duration_s : [s] engaged time on the vehicle clock (None = the reference's duration; math.inf = until stopped)
    mode : None (wait for the pilot) or GUIDED / GUIDED_NOGPS / OFFBOARD to request
    arm : send the arm command after the mode is set
    takeoff_alt_m : [m] bounded climb (level attitude, climb-rate thrust) to this height before the profile
    on_exit, on_failsafe : hand-back mode: ALT_HOLD, LOITER, LAND or "none" (leave it to the autopilot's timeout)
    reengage : resume (controller reset) when the pilot returns to the guided mode
    log_dir : folder for <stamp>.csv and <stamp>.tlog (None = no files)
    signing_key : 32-byte key, or a key file path (format: mavastsm.signing)
    target_system : autopilot sysid to control (None = first autopilot heard)
    source_system : our sysid (None = the vehicle's)
    baud : [bit/s] for serial URLs
    engage_timeout_s : [s] wall time to wait for the pilot (guided + armed) before giving up
    print_fn : where the preflight summary and status go (None = nowhere)
    on_engage : called on the reader thread at each engagement with its sample's vehicle time [s], before the first
        setpoint answers it (in lockstep the vehicle waits there: ``mavastsm.lockstep_pair`` starts the scenario's
        disturbances at that instant); an exception from it is a CONTROLLER_FAULT
    lockstep_turns : ``mavastsm.lockstep_turns.LockstepTurns`` shared with an in-process lockstep sim on UDP
        (``mavastsm.lockstep_pair`` sets it): every wait of the bridge then runs on the vehicle's clock
    """

    url: str
    controller: Any = "astsm"
    controller_config: str | None = None
    bridge_config: str | Path | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)
    reference: Any = "paper_steps"
    vehicle_config: str | Path | None = None
    rate_hz: float | None = None
    duration_s: float | None = None
    mode: str | None = None
    arm: bool = False
    takeoff_alt_m: float | None = None
    on_exit: str = "none"
    on_failsafe: str = "none"
    reengage: bool = False
    log_dir: str | Path | None = None
    signing_key: bytes | str | Path | None = None
    target_system: int | None = None
    source_system: int | None = None
    baud: int = 115200
    engage_timeout_s: float = 120.0
    print_fn: Callable[[str], None] | None = None
    on_engage: Callable[[float], None] | None = None
    lockstep_turns: Any = None

    def validate(self) -> None:
        """ConfigError (one line) for contradictory or out-of-range options."""
        if self.mode is not None and self.mode not in REQUESTABLE_MODES:
            raise ConfigError(f"--mode {self.mode}: must be one of {', '.join(REQUESTABLE_MODES)}")
        for name in ("on_exit", "on_failsafe"):
            if getattr(self, name) not in HANDBACK_ACTIONS:
                raise ConfigError(f"--{name.replace('_', '-')} {getattr(self, name)}: must be one of {', '.join(HANDBACK_ACTIONS)}")
        if self.takeoff_alt_m is not None and not (0.3 <= self.takeoff_alt_m <= 50.0):
            raise ConfigError(f"--takeoff-m {self.takeoff_alt_m}: must be within [0.3, 50] m")
        if self.takeoff_alt_m is not None and not self.arm:
            raise ConfigError("--takeoff-m needs --arm (the bridge only climbs a vehicle it armed itself)")
        if self.arm and self.mode is None:
            raise ConfigError("--arm needs --mode (arming happens in the guided mode the bridge requested)")
        if self.duration_s is not None and not (self.duration_s > 0):
            raise ConfigError(f"--duration-s {self.duration_s}: must be > 0 s")
        if self.rate_hz is not None and not (10.0 <= self.rate_hz <= 1000.0):
            raise ConfigError(f"--rate-hz {self.rate_hz}: must be within [10, 1000] Hz")
        parse_link_url(self.url, self.baud)


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
    samples_capped: bool = False  # timing.samples_in_memory reached: samples and metrics cover the first ones only

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
            f"cycles {self.cycles}, missed {self.missed}, dropped {self.dropped}, duplicate {self.duplicate}, "
            f"superseded {self.superseded} (queued back to back: the newest of each burst was used), out-of-order {self.out_of_order}, clock outliers {self.clock_outliers}, invalid {self.invalid}, foreign {self.foreign_attitude}, "
            f"blocked {self.blocked_setpoints}, overruns {self.overruns}, reader errors {self.reader_errors}; engagements {self.engagements}, vehicle sessions {self.vehicle_sessions}"
            + (f", recovered from {', '.join(r.label for r in self.recovered_failsafes)}" if self.recovered_failsafes else ""),
            (f"ATTITUDE achieved {self.attitude_rate_achieved_hz:.1f} Hz" if math.isfinite(self.attitude_rate_achieved_hz) and self.attitude_rate_achieved_hz > 0
             else "ATTITUDE achieved: not measured (under one second of samples)") + f"; {lat}",
            format_metrics_table(self.axes),
        ]
        refused = sum(n for _, n in self.refused_frames)
        lines.insert(2, f"refused frames: {refused}" + (f" ({', '.join(f'{name} {n}' for name, n in self.refused_frames)})" if refused else ""))
        if self.samples_capped:
            lines.append(f"metrics over the first {len(self.samples)} cycles kept in memory (timing.samples_in_memory); the CSV has every cycle")
        if self.log_paths:
            lines.append("logs: " + ", ".join(self.log_paths))
        return "\n".join(lines)


class Bridge:
    """The offboard attitude bridge. See module docstring.

    Parameters
    ----------
    options : BridgeOptions
    telemetry : TelemetryBuffer the dashboard reads (one is created when None)
    """

    def __init__(self, options: BridgeOptions, telemetry: TelemetryBuffer | None = None) -> None:
        options.validate()
        self.options = options
        self.telemetry = telemetry if telemetry is not None else TelemetryBuffer()
        bridge_over, ctrl_over = split_overrides(options.overrides)
        if options.rate_hz is not None:
            bridge_over["timing"]["attitude_rate_hz"] = float(options.rate_hz)
        self.config: BridgeConfig = load_bridge_config(options.bridge_config, bridge_over)
        self._user_mapping_keys = set(bridge_over["mapping"])  # the user's --set wins over the vehicle description
        self._controller_overrides = ctrl_over
        self.vehicle = options.vehicle_config or DEFAULT_VEHICLE
        self.solo = load_solo(self.vehicle)
        self.controller, self.controller_name = self._build_controller()
        self._controller_vehicle = self.vehicle  # the vehicle whose I0 the controller was built with
        self.reference, self.reference_name = self._load_reference()
        if options.duration_s is not None:
            self.duration_s = float(options.duration_s)
        else:
            d = getattr(self.reference, "duration_s", None)
            self.duration_s = float(d) if d and math.isfinite(d) else math.inf
        self.link: MavlinkLink | None = None
        self.session: OffboardSession | None = None
        self.preflight: PreflightReport | None = None
        self.summary: BridgeSummary | None = None
        self.handback = "not yet"
        self.handback_confirmed = False
        self.handback_failed = False  # every mode of the hand-back action was refused
        self._stop = threading.Event()
        self._started = threading.Event()  # start() returned: from here the supervisor owns the end of the run
        self._abandon = threading.Event()  # start() failed: the supervisor ends without finishing (start-up does)
        self._thread: threading.Thread | None = None
        self._log: FlightLog | None = None
        self._log_paths: tuple[str, ...] = ()
        self._last_status = 0.0
        self._last_reassert = 0.0
        self._events_said = 0
        self._late_said = 0  # session.late_mode_heartbeats already said
        self._conflict_said = False  # the link's clock conflict (two vehicles, one id) said and acted on
        self._hover_said_at = 0  # the engagement whose hover collective was last said
        self._mode_before = ""  # the vehicle's mode at preflight
        self._armed_by_bridge = False  # the bridge's own arm request was ACKed (a failed start hands back)
        self._mode_changed = False  # the bridge requested a mode (start-up failure puts it back)
        self._alpha_note = ""  # how the adaptive gain was bounded, for the preflight summary
        self._finish_error = ""  # why _finish failed, if it did

    # ------------------------------------------------------------------ construction helpers
    def _build_controller(self, extra: Mapping[str, Any] | None = None):
        c = self.options.controller
        if not isinstance(c, str):
            if self._controller_overrides:
                raise ConfigError("controller overrides given with a controller object; set them on the object")
            from ..control.controller_interface import missing_members

            missing = missing_members(c)
            if missing:
                raise ConfigError(f"controller {type(c).__name__} lacks {', '.join(missing)} of the AttitudeController "
                                  "protocol (docs/controllers.md; mavastsm.control.controller_interface.NoLimits gives the limit members)")
            return c, c.name
        from ..control import make_controller

        overrides = {**(extra or {}), **self._controller_overrides}  # the user's --set wins
        preset = self.options.controller_config or getattr(self.config.presets, c, None)  # bridge.yaml presets
        return make_controller(c, self.solo, preset, overrides or None), c

    def _load_reference(self):
        r = self.options.reference
        if not isinstance(r, (str, Path)):
            return r, getattr(r, "name", "custom")
        from ..references import load_reference

        return load_reference(r), str(r)

    def _adaptive_gain(self):
        """The controller's adaptive gain (protocol member ``adaptive_gain()``), or None when its gain does not adapt."""
        return self.controller.adaptive_gain()

    def _alpha_max(self) -> tuple[float, float, float] | None:
        """Per-axis adaptive-gain clamp of the controller, or None when its gain does not adapt."""
        a = self._adaptive_gain()
        return None if a is None else per_axis(a.alpha_max)

    def _choose_vehicle(self, profile) -> BridgeConfig:
        """Vehicle description: the one given (--vehicle); else, where the profile allows it (ArduPilot), the packaged
        description whose ``autopilot_tuning`` the vehicle reports (``_recognise_vehicle``); else the profile's
        ``default_vehicle`` (PX4: px4_sih_quadx, PX4's stock SIH vehicle; ArduPilot: the Solo). Its ``offboard_loop``
        (rate time constant, loop delay, shaping) replaces bridge.yaml's mapping values except where the user's --set
        named them. Returns the config."""
        why = ""
        if self.options.vehicle_config is None:
            chosen, why = self._recognise_vehicle(profile)
            if chosen != self.vehicle:
                self.vehicle = chosen
                self.solo = load_solo(self.vehicle)
        loop = {k: v for k, v in load_offboard_loop(self.vehicle).items() if k not in self._user_mapping_keys}
        if loop:
            self.config = dataclasses.replace(self.config, mapping=dataclasses.replace(self.config.mapping, **loop))
        m = self.config.mapping
        self.preflight.notes.append(f"vehicle description: {self.vehicle}{' (' + why + ')' if why else ''}: I0 "
                                    f"{', '.join(f'{i:.3g}' for i in self.solo.inertia_diag)} kg m^2"
                                    + (f"; rate loop tau {', '.join(f'{t:g}' for t in m.rate_time_constant_s)} s, "
                                       f"delay {', '.join(f'{t:g}' for t in m.loop_delay_s)} s, "
                                       f"shaping {', '.join(f'{f:g}' for f in m.shaping_accel_fraction)} of the accel limits" if loop else "")
                                    + ("; pass --vehicle FILE for yours" if self.options.vehicle_config is None else ""))
        return self.config

    def _recognise_vehicle(self, profile) -> tuple[str, str]:
        """(description name, why): the first packaged description (by name) all of whose ``autopilot_tuning``
        parameters the vehicle reports (read now; equal at float32), else the profile's ``default_vehicle``. The loop
        numbers of a description (rate time constant, delay, shaping) were measured with that tuning, which is what
        decides them; an unrecognised tuning flies the default's numbers, and says so."""
        if not profile.vehicle_by_tuning:
            return profile.default_vehicle, ""
        for name, tuning in packaged_vehicle_tunings().items():
            for param, want in tuning.items():
                got = read_parameter(self.link, self.config, self.preflight, param)  # ATC_*: read by the preflight already
                if got is None or not math.isclose(got, want, rel_tol=1e-6, abs_tol=1e-6):
                    break
            else:
                return name, "recognised by its " + ", ".join(f"{p} {v:g}" for p, v in tuning.items())
        return profile.default_vehicle, "no packaged description matches its tuning; the default's loop numbers"

    def _alpha_ceiling(self) -> tuple[float, float, float] | None:
        """Per-axis ``adaptive_gain_ceiling`` for the controller's mu and mapping.loop_delay_s (in the gain's
        units), or None when its gain does not adapt."""
        a = self._adaptive_gain()
        if a is None or a.mu is None:
            return None  # no adaptive gain, or no adaptation band to bound it by
        delay = switching_delay_s(self.config.mapping)  # loop delay, plus the rate loop's lag on integrated axes (M9)
        return tuple(adaptive_gain_ceiling(u, d) * k for u, d, k in zip(per_axis(a.mu), delay, per_axis(a.units_per_accel)))  # type: ignore[return-value]

    def _alpha_within_ceiling(self) -> bool:
        """True when the controller's alpha clamp is at or below the loop-delay ceiling on every axis: alpha at
        its clamp is then the designed maximum gain, not a runaway (no ADAPTIVE_GAIN_PINNED)."""
        ceiling = self._alpha_ceiling()
        return ceiling is not None and all(a <= c * (1.0 + 1e-6) for a, c in zip(self._alpha_max(), ceiling))

    def _delay_bounded_alpha(self) -> dict:
        """Overrides that keep an adaptive gain below ``adaptive_gain_ceiling`` on each axis (mapping.loop_delay_s):
        alpha_max = min(preset, ceiling), alpha_min = min(preset, alpha_max / 2). {} when the controller's gain does
        not adapt or the bound is off; the user's own --set of these keys wins."""
        m = self.config.mapping
        ceiling = self._alpha_ceiling()
        if not m.bound_adaptive_gain or ceiling is None:
            return {}
        a = self._adaptive_gain()
        lo, hi = per_axis(a.alpha_min), per_axis(a.alpha_max)
        new_hi = [min(h, c) for h, c in zip(hi, ceiling)]
        new_lo = [min(l_, 0.5 * h) for l_, h in zip(lo, new_hi)]
        self._alpha_note = ("adaptive gain bounded by the loop delay (mapping.loop_delay_s, + tau on integrated axes: "
                            f"{', '.join(f'{d:.3g}' for d in switching_delay_s(m))} s): alpha {', '.join(f'{a:.3g}..{b:.3g}' for a, b in zip(new_lo, new_hi))}")
        return self.controller.limit_overrides(adaptive_gain_range=(tuple(new_lo), tuple(new_hi)))

    def _yaw_integral_by_autopilot(self, profile, cfg: BridgeConfig) -> dict:
        """M7: with the yaw command on the reference (M6) ArduCopter's attitude target integrates the yaw command,
        so a law's own yaw integral would be a second integrator in series (a slow yaw oscillation on genuine
        ArduCopter). ``mapping.yaw_integral: autopilot`` turns the law's attitude-error integral off on yaw (the
        protocol's ``limit_overrides(integral_off=...)``; ASTSM: epsilon 0 on yaw). {} otherwise, or when the law
        has no such integral; the user's own --set wins."""
        m = cfg.mapping
        if m.yaw_integral != "autopilot" or not yaw_from_reference(m.method, m.yaw_command_base, profile):
            return {}
        extra = self.controller.limit_overrides(integral_off=(False, False, True))
        if extra:
            self.preflight.notes.append("yaw integral left to the autopilot's attitude target (mapping.yaw_integral): epsilon 0 on yaw"
                                        if set(extra) == {"epsilon"} else f"yaw integral left to the autopilot's attitude target: {extra}")
        return extra

    def _say(self, text: str) -> None:
        if self.options.print_fn is not None:
            self.options.print_fn(text)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Connect, preflight, request mode/arm/takeoff if told, then run the supervisor in a thread.

        Each line is one named step, in the order they run; a step that fails raises and everything is closed
        again (``_abort_start``). Raises LinkError, OffboardRejected or ConfigError.
        """
        with self._turn():  # lockstep turns: the vehicle waits while start-up runs
            self._start()

    def _start(self) -> None:
        key = self._signing_key()
        tlog_path = self._open_flight_log()
        self._create_link(key, tlog_path)
        try:
            self._open_link()
            try:
                profile = self._run_preflight()
            except (OffboardRejected, ConfigError, LinkError):
                self._check_one_vehicle()  # two vehicles on the id explain a failed preflight better than its step
                raise
            self._check_one_vehicle()
            self._choose_vehicle(profile)
            self._adopt_granted_rate()
            self._check_takeoff_semantics(profile)
            hold_altitude = self._request_vertical_state(profile)
            self._check_mode(profile)
            accel, adaptive, authority = self._command_limits()
            self._fit_controller_to_vehicle(profile, authority)
            cycle = self._build_cycle(profile, accel, authority, hold_altitude)
            self._build_session(cycle)
            self._negotiate_rate(profile)
            self._announce(cycle, adaptive, authority)
            self._publish_start()
            self._request_altitude_for_takeoff()
            self._start_supervisor()
            self._engage()
        except BaseException:
            self._abort_start()
            raise
        self._started.set()

    def _check_one_vehicle(self) -> None:
        """Start-up ends here (one line, exit 2) when two vehicles already claim the target's id (vehicle_clock):
        checked after preflight and again right before each mode request and arming attempt (a second vehicle whose
        stream began during start-up is named only once its clock has run RIVAL_SPAN_MS); while a second address is
        being heard, its verdict is awaited (at most SECOND_SOURCE_WAIT_S)."""
        deadline = time.monotonic() + SECOND_SOURCE_WAIT_S
        while self.link.clock.second_source_heard(time.monotonic_ns()) and time.monotonic() < deadline:
            if self._sleep(0.05):
                raise Interrupted("interrupted (waiting to tell whether a second vehicle shares the id)")
        conflict = self.link.clock.conflict
        if conflict is not None:
            raise LinkError(conflict.text(self.link.target_system))

    def _turn(self):
        """The calling thread acts on the vehicle (lockstep turns: the vehicle waits while it runs), else nothing."""
        turns = self.options.lockstep_turns
        return turns.participant() if turns is not None else contextlib.nullcontext()

    def _sleep(self, seconds: float, interruptible: bool = True) -> bool:
        """Wait ``seconds`` [s], on the vehicle's clock with lockstep turns (else the host's); True when an operator
        stop ended it (``interruptible``)."""
        stop = self._stop if interruptible else threading.Event()
        turns = self.options.lockstep_turns
        if turns is not None:
            return turns.sleep(seconds, stop)
        if interruptible:
            return stop.wait(seconds)
        time.sleep(seconds)
        return False

    # ------------------------------------------------------------------ start-up steps (in the order start() runs them)
    def _signing_key(self) -> bytes | None:
        """The MAVLink2 signing key from the options (bytes, or a file/passphrase for ``load_signing_key``), checked
        to be 32 bytes; None to fly unsigned."""
        key = self.options.signing_key
        if key is not None and not isinstance(key, (bytes, bytearray)):
            key = load_signing_key(key)
        if key is not None and len(key) != 32:
            raise ConfigError(f"signing key must be 32 bytes, got {len(key)}")
        return key

    def _open_flight_log(self) -> Path | None:
        """Open the flight CSV (with a column per diagnostics key of the controller) in ``--log`` DIR, named by the
        start time; returns the tlog path beside it (None without ``--log``: the CSV is then a no-op log)."""
        o = self.options
        stamp = time.strftime("%Y%m%d-%H%M%S")
        tlog_path = None
        if o.log_dir is not None:
            d = Path(o.log_dir)
            try:
                d.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ConfigError(f"--log {d}: cannot create ({exc.strerror})") from None
            tlog_path = d / f"mavastsm-{stamp}.tlog"
            self._log = FlightLog(d / f"mavastsm-{stamp}.csv", extra_diagnostic_keys(self.controller.diagnostics()))
            self._log_paths = (str(self._log.path), str(tlog_path), str(metadata_path(self._log.path)))
        else:
            self._log = FlightLog(None)
        return tlog_path

    def _create_link(self, key: bytes | None, tlog_path: Path | None) -> None:
        """The MAVLink link object for the URL (not yet connected)."""
        o, cfg = self.options, self.config
        url, baud = parse_link_url(o.url, o.baud)
        self.link = MavlinkLink(
            url, baud=baud, source_system=o.source_system, source_component=cfg.link.source_component,
            heartbeat_type=cfg.link.heartbeat_type, target_system=o.target_system, signing_key=key, tlog_path=tlog_path,
            realtime_priority=cfg.timing.realtime_priority, turns=o.lockstep_turns,
        )

    def _open_link(self) -> None:
        """Connect and wait (``link.heartbeat_wait_s``) for the autopilot's HEARTBEAT, saying progress."""
        self.link.open(self.config.link.heartbeat_wait_s, stop=self._stop, progress=self._say)

    def _run_preflight(self):
        """The preflight checks (``run_preflight``): identify the autopilot and its profile, read its parameters,
        request the ATTITUDE rate. Keeps the report and the mode the vehicle was in; returns the profile."""
        self.preflight, profile = run_preflight(self.link, self.config)
        self._mode_before = self.preflight.mode
        return profile

    def _adopt_granted_rate(self) -> None:
        """The loop's nominal period is the ATTITUDE rate the vehicle granted, when that differs from the one asked."""
        cfg = self.config
        if self.preflight.attitude_rate_granted_hz != cfg.timing.attitude_rate_hz:
            # the loop's nominal period is what the vehicle granted (missed cycles, overruns, re-assertion)
            self.config = dataclasses.replace(cfg, timing=dataclasses.replace(
                cfg.timing, attitude_rate_hz=self.preflight.attitude_rate_granted_hz))

    def _check_takeoff_semantics(self, profile) -> None:
        """``--takeoff-m`` needs climb-rate thrust or the autopilot's own takeoff: ConfigError otherwise."""
        if self.options.takeoff_alt_m is not None and profile.thrust_semantics != CLIMB_RATE and not profile.autopilot_takeoff:
            raise ConfigError("--takeoff-m needs climb-rate thrust semantics (ArduCopter default, GUID_OPTIONS bit 3 clear)")

    def _request_vertical_state(self, profile) -> bool:
        """With collective thrust and ``thrust.altitude_hold``, ask for LOCAL_POSITION_NED (the height the thrust
        holds); returns whether the altitude is held."""
        cfg = self.config
        hold_altitude = profile.thrust_semantics == COLLECTIVE and cfg.thrust.altitude_hold
        if hold_altitude:
            try:
                self.link.set_message_interval(MSG_ID_LOCAL_POSITION_NED, 50.0, cfg.link.command_ack_timeout_s, cfg.link.command_retries)
            except OffboardRejected as exc:
                raise OffboardRejected("LOCAL_POSITION_NED for thrust.altitude_hold", exc.result,
                                       "the collective thrust needs it; set thrust.altitude_hold=false to fly without") from None
        return hold_altitude

    def _check_mode(self, profile) -> None:
        """``--mode`` must be one of the profile's guided modes: ConfigError otherwise."""
        o = self.options
        if o.mode is not None and o.mode not in profile.guided_modes:
            raise ConfigError(f"--mode {o.mode}: {profile.name} takes setpoints only in {', '.join(profile.guided_modes)}")

    def _command_limits(self) -> tuple[float | None, bool, Any]:
        """(accel limit [rad/s^2] or None, whether the controller's gain adapts, command torque limit [N m] per axis)."""
        cfg = self.config
        # ATC_ACCEL (the autopilot's rate-target slew limit): reference shaping and the hidden-target model
        accel = self.preflight.accel_limit_radss or cfg.mapping.accel_limit_radss
        adaptive = self._alpha_max() is not None  # ASTSM: its switching gain adapts (configs/bridge.yaml, command_accel_clip)
        authority = command_torque_limit_nm(cfg.mapping, self.solo.inertia_diag, accel, adaptive)
        return accel, adaptive, authority

    def _fit_controller_to_vehicle(self, profile, authority) -> None:
        """A controller named by the options is built again with what the preflight found: the chosen vehicle's I0,
        its adaptive gain bounded by the loop delay, the yaw integral left to the autopilot (M7) and the torque
        limit the vehicle can realise (through the protocol's ``limit_overrides``). A controller object is flown as
        built."""
        o, cfg = self.options, self.config
        extra = self._delay_bounded_alpha() if isinstance(o.controller, str) else {}
        if isinstance(o.controller, str):
            extra.update(self._yaw_integral_by_autopilot(profile, cfg))
        if cfg.mapping.limit_controller_torque and isinstance(o.controller, str):
            # the controller's anti-windup must know what the vehicle can realise (protocol: limit_overrides)
            extra.update(self.controller.limit_overrides(torque_limit_nm=tuple(authority)))
        if isinstance(o.controller, str) and (extra or self.vehicle != self._controller_vehicle):
            self.controller, _ = self._build_controller(extra)  # with the I0 of the vehicle chosen at preflight
            self._controller_vehicle = self.vehicle
        if self._alpha_note:
            self.preflight.notes.append(self._alpha_note)

    def _build_cycle(self, profile, accel, authority, hold_altitude: bool) -> ControlCycle:
        """The control cycle: controller, reference, mapping to the autopilot's setpoint, the autopilot-target model."""
        cfg = self.config
        return ControlCycle(self.controller, self.reference, self.solo.inertia_diag, profile, cfg, self._alpha_max(), accel,
                            self.preflight.angle_p, self.link.attitude_target, torque_authority_nm=authority,
                            setpoint_timeout_s=self.preflight.setpoint_timeout_s, pinned_failsafe=not self._alpha_within_ceiling(),
                            vertical_state=self._vertical_state if hold_altitude else None)

    def _build_session(self, cycle: ControlCycle) -> None:
        """The offboard session that runs the cycle on every ATTITUDE, wired to the link."""
        o = self.options
        self.session = OffboardSession(self.link, cycle, self.config, self.telemetry, self._log, o.reengage, self.duration_s)
        self.link.on_attitude = self.session.on_attitude
        self.session.altitude_fn = self._altitude_m
        self.session.on_engage = o.on_engage
        self.session.hover_source = self._hover_source(cycle.profile)

    def _hover_source(self, profile):
        """Where the autopilot's own hold gives the hover collective (PX4, ``thrust.hover_from_vehicle`` and
        ``thrust.hover_measure_s`` > 0, ATTITUDE_TARGET requested): vehicle time [ms] -> the measurement over the last
        ``hover_measure_s`` before the guided mode (``measure_hover_collective``) or why there is none; else None."""
        tc, rep = self.config.thrust, self.preflight
        if not (profile.hover_from_target_thrust and tc.hover_from_vehicle and tc.hover_measure_s > 0):
            return None
        if not rep.attitude_target_requested:
            rep.notes.append("hover collective not measured from the vehicle's hold: ATTITUDE_TARGET not requested "
                             "(timing.attitude_target_rate_hz = 0) or refused")
            return None
        link, guided = self.link, profile.guided_modes
        return lambda now_ms: measure_hover_collective(link.recent_attitude_targets(), guided, tc.hover_measure_s, now_ms,
                                                       rep.hover_parameter_norm)

    def _negotiate_rate(self, profile) -> None:
        """Measure the ATTITUDE rate the vehicle really sends; below 80 % of the accepted rate the loop runs at it."""
        self._measure_rate()
        cfg = self.config
        achieved = self.session.achieved_rate_hz
        if achieved < 0.8 * cfg.timing.attitude_rate_hz:
            self.preflight.notes.append(f"ATTITUDE accepted at {cfg.timing.attitude_rate_hz:g} Hz but sent at {achieved:.0f} Hz: "
                                        f"{profile.rate_cap_reason or 'the vehicle sends slower than it accepted'}; the loop runs at that rate")
            cfg = self.config = dataclasses.replace(cfg, timing=dataclasses.replace(cfg.timing, attitude_rate_hz=round(achieved, 1)))
            self.session.set_nominal_rate(cfg)

    def _announce(self, cycle: ControlCycle, adaptive: bool, authority) -> None:
        """Say the preflight summary: checks, rate, controller, reference, mapping and command limits."""
        cfg = self.config
        self._say(format_preflight(self.preflight, self.session.achieved_rate_hz, self.controller_name, self.reference_name,
                                   f"{cfg.mapping.method} (tau {', '.join(f'{t:g}' for t in cfg.mapping.rate_time_constant_s)} s"
                                   f"{', roll/pitch integrated (M9)' if cycle.mapping.integrated[0] else ''}"
                                   f"{', yaw on the reference rate (M6)' if cycle.yaw_from_reference else ''}), "
                                   f"command torque limit {', '.join(f'{t:.3g}' for t in authority)} N m ({command_clip_mode(cfg.mapping, adaptive)})",
                                   f"reader thread {self.link.reader_scheduling}"))

    def _publish_start(self) -> None:
        """The session's description and the link status to the telemetry (dashboard), the log's metadata sidecar."""
        self.telemetry.set_session(self._session_info())
        self._publish_link_status()
        self._write_log_metadata()

    def _request_altitude_for_takeoff(self) -> None:
        """With ``--takeoff-m``, ask for GLOBAL_POSITION_INT (``timing.altitude_rate_hz``): the climb needs the altitude."""
        cfg = self.config
        if self.options.takeoff_alt_m is not None:
            try:
                self.link.set_message_interval(MSG_ID_GLOBAL_POSITION_INT, cfg.timing.altitude_rate_hz, cfg.link.command_ack_timeout_s, cfg.link.command_retries)
            except OffboardRejected as exc:
                raise OffboardRejected("altitude for --takeoff", exc.result, "GLOBAL_POSITION_INT not available") from None

    def _start_supervisor(self) -> None:
        """The supervisor thread (failsafes, status, duration, re-assertion) from here until the end."""
        joined = threading.Event()
        self._thread = threading.Thread(target=self._supervise_in_turn, args=(joined,), name="bridge-supervisor", daemon=True)
        self._thread.start()
        joined.wait(5.0)  # lockstep turns: it takes its turns from this sample on, not from whenever it is scheduled

    def _abort_start(self) -> None:
        """start() failed: end the supervisor first (it leaves the ending to this thread, so it never closes the link
        under the hand-back), put back the mode we changed (never leave a disarmed vehicle in the guided mode the
        bridge asked for), hand back an armed vehicle, and close everything, leaving no thread behind."""
        self._stop.set()
        self._abandon.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._restore_mode_after_failed_start()
        self._hand_back_after_failed_start()
        self._restore_setpoint_timeout()
        if self.session is not None:
            self.session.finish()
        self._shutdown()

    def _restore_mode_after_failed_start(self) -> None:
        link, before = self.link, self._mode_before
        if link is None or not self._mode_changed or not before:
            return
        hb = link.last_heartbeat
        if hb is None or hb.armed or hb.mode == before:
            return  # armed: somebody flies it, leave the mode alone
        try:
            link.set_mode(before, self.config.link.command_ack_timeout_s, 1)
            self._say(f"start-up failed: mode set back to {before}")
        except (OffboardRejected, ConfigError, LinkError) as exc:
            self._say(f"start-up failed: could not set the mode back to {before} ({exc})")

    def _hand_back_after_failed_start(self) -> None:
        """start() failed after the bridge armed the vehicle (PX4's own takeoff stalled, timed out or was stopped, or
        the guided mode was refused after it): the run ends, so the vehicle gets the hand-back the operator asked for
        (``--on-failsafe``, else ``--on-exit``), never stays armed in a mode the bridge chose without a word. A PX4
        takeoff that stalled on the ground left it armed in TAKEOFF, with its land detector saying airborne."""
        link, o, s = self.link, self.options, self.session
        if link is None or s is None or not self._armed_by_bridge or self.handback != "not yet":
            return  # not armed by us, or a failsafe during start-up already handed back
        hb = link.last_heartbeat
        if hb is None or not hb.armed:
            return
        action = o.on_failsafe if o.on_failsafe != "none" else o.on_exit
        if action == "none":
            self._say(f"start-up failed with the vehicle armed in {hb.mode} (armed by the bridge): no hand-back asked "
                      f"(--on-failsafe and --on-exit none); the autopilot has it")
            return
        text, _ = self._request_handback(action)
        self._say(f"start-up failed with the vehicle armed: hand-back {text}")

    def _arm_when_ready(self) -> None:
        """Arm, waiting for the vehicle's pre-arm checks: retry every ``link.arm_retry_s`` with the vehicle's
        reason and the elapsed time shown, give up after ``link.arm_timeout_s`` with the reason and its fix.
        An operator stop (Ctrl-C, SIGTERM) ends the wait at once."""
        lc, link = self.config.link, self.link
        start = time.monotonic()
        reason = ""
        while True:
            self._check_one_vehicle()  # a second vehicle on the id may be named only now (its clock takes 0.5 s)
            try:
                link.arm(lc.command_ack_timeout_s, 1)
                self._armed_by_bridge = True
                if reason:
                    self._say(f"armed after {time.monotonic() - start:.0f} s of pre-arm checks")
                return
            except OffboardRejected as exc:
                detail = exc.detail
                if not detail and exc.result is not None and not self._sleep(lc.arm_reason_wait_s):
                    detail = "; ".join(link.texts_since(time.monotonic() - lc.arm_reason_wait_s - 0.05)[-2:])  # text after the ACK
                reason = detail or reason or f"MAV_RESULT {exc.result}"
                elapsed = time.monotonic() - start
                if elapsed >= lc.arm_timeout_s:
                    fix = arming_fix(reason) or "fix the reason the vehicle gives"
                    raise OffboardRejected("arm", exc.result, f"{reason}; pre-arm checks not passed within "
                                           f"link.arm_timeout_s = {lc.arm_timeout_s:g} s; {fix}") from None
                self._say(f"waiting for pre-arm checks: {reason} … {elapsed:.0f} s")
            if self._sleep(lc.arm_retry_s):
                raise Interrupted(f"while waiting for pre-arm checks ({reason or 'no reason yet'}, {time.monotonic() - start:.0f} s)")

    def _wait_vertical_estimate_at_rest(self) -> None:
        """Before the autopilot's own takeoff, wait until its vertical velocity estimate (LOCAL_POSITION_NED vz) has
        stayed within REST_VZ_MS for REST_HOLD_S: the vehicle stands still, so a larger one is an estimator still
        converging. PX4's estimator on SIH reports 0.1-0.3 m/s for seconds after it first allows arming, and a
        takeoff started then ended on the ground in 5 of 12 runs (its height estimate drifted up while the climb
        ramped; docs/bridge.md, "What the genuine firmware does differently"). Bounded by REST_TIMEOUT_S, with progress."""
        if self._vertical_state() is None:  # not streamed for the altitude hold (thrust.altitude_hold false): ask
            lc = self.config.link
            try:
                self.link.set_message_interval(MSG_ID_LOCAL_POSITION_NED, 50.0, lc.command_ack_timeout_s, lc.command_retries)
            except OffboardRejected as exc:
                self._say(f"vertical estimate not checked before the takeoff: LOCAL_POSITION_NED refused ({exc})")
                return
        start = time.monotonic()
        rest_since = None
        last_said = 0.0
        while True:
            vert = self._vertical_state()
            now = time.monotonic()
            vz = vert[1] if vert is not None else float("nan")
            rest_since = (rest_since or now) if abs(vz) <= REST_VZ_MS else None
            if rest_since is not None and now - rest_since >= REST_HOLD_S:
                if now - start > REST_HOLD_S + 0.5:
                    self._say(f"vertical estimate at rest after {now - start:.0f} s (|vz| <= {REST_VZ_MS:g} m/s for {REST_HOLD_S:g} s)")
                return
            if now - start > REST_TIMEOUT_S:
                raise OffboardRejected("takeoff", None, f"the vehicle's vertical velocity estimate was not at rest within {REST_TIMEOUT_S:g} s "
                                       f"(vz {vz:+.2f} m/s, LOCAL_POSITION_NED); the vehicle must stand still on the ground before its takeoff",
                                       failed="estimator not at rest")
            if now - start >= 1.0 and now - last_said >= 1.0:
                last_said = now
                self._say(f"waiting for the vertical estimate to come to rest: vz {vz:+.2f} m/s … {now - start:.0f} s")
            if self._sleep(0.05):
                raise Interrupted("while waiting for the vertical estimate to come to rest")

    def _vertical_state(self) -> tuple[float, float] | None:
        """(z [m, NED down], vz [m/s, down]) from the latest LOCAL_POSITION_NED, None before the first."""
        pos = self.link.local_position()
        return (pos.position_ned_m[2], pos.velocity_ned_ms[2]) if pos is not None else None

    def _autopilot_takeoff(self, alt_m: float) -> None:
        """The autopilot's own takeoff (PX4): MAV_CMD_NAV_TAKEOFF to home + ``alt_m`` AMSL, then wait (with progress,
        bounded by thrust.takeoff_timeout_s) until it holds within 10 % of the altitude in its hold mode."""
        link, lc, tc = self.link, self.config.link, self.config.thrust
        deadline = time.monotonic() + 5.0
        while link.global_position() is None:
            if time.monotonic() > deadline or self._sleep(0.05):
                raise OffboardRejected("takeoff", None, "no GLOBAL_POSITION_INT from the vehicle", failed="no altitude")
        home_amsl_m = link.global_position().home_amsl_m
        nan = float("nan")
        link.command_long(MAV_CMD_NAV_TAKEOFF, (0.0, 0.0, 0.0, nan, nan, nan, home_amsl_m + alt_m),
                          f"COMMAND_LONG NAV_TAKEOFF to {alt_m:g} m", lc.command_ack_timeout_s, lc.command_retries)
        start = time.monotonic()
        last_said = 0.0
        still_since = None  # PX4 hands over to its hold below the altitude and creeps up: settled = |vz| < 0.2 m/s for 1 s
        while True:
            alt, hb, vert = self._altitude_m(), link.last_heartbeat, self._vertical_state()
            now = time.monotonic()
            elapsed = now - start
            holding = hb is not None and hb.mode != "TAKEOFF" and math.isfinite(alt) and alt >= 0.5 * alt_m
            still_since = (still_since or now) if holding and vert is not None and abs(vert[1]) < 0.2 else None
            if holding and (alt >= 0.9 * alt_m or (still_since is not None and now - still_since >= 1.0)):
                self._say(f"takeoff: holding {alt:.2f} m in {hb.mode} after {elapsed:.0f} s; switching to the guided mode")
                return
            if elapsed > tc.takeoff_timeout_s:
                raise OffboardRejected("takeoff", None, f"at {alt:.2f} of {alt_m:g} m after {tc.takeoff_timeout_s:g} s "
                                       f"(thrust.takeoff_timeout_s); vehicle text: {'; '.join(link.texts_since(start)[-2:]) or 'none'}",
                                       failed="did not reach a hold at the altitude")
            if elapsed - last_said >= 1.0:
                last_said = elapsed
                self._say(f"taking off ({hb.mode if hb else '?'}): {alt:.2f} / {alt_m:g} m … {elapsed:.0f} s")
            if self._sleep(0.05):
                raise OffboardRejected("takeoff", None, f"during the takeoff at {alt:.2f} m (hand-back above)", failed="operator stop")

    def _let_hold_show_hover(self) -> None:
        """After the autopilot's own takeoff, where the hover collective is measured from its hold (PX4): let the hold
        fly ``thrust.hover_measure_s`` of vehicle time before the guided mode, so the measurement sees the hold alone
        (the takeoff hands over to the hold still climbing, and the pre-stream ran during the takeoff)."""
        s = self.session
        if s.hover_source is None:
            return
        self._say(f"measuring the hover collective in {self.link.last_heartbeat.mode if self.link.last_heartbeat else 'its hold'} "
                  f"for {self.config.thrust.hover_measure_s:g} s")
        if self._sleep(self.config.thrust.hover_measure_s):
            raise OffboardRejected("takeoff", None, "while measuring the hover collective (hand-back above)", failed="operator stop")

    def _altitude_m(self) -> float:
        """[m] above home from the latest GLOBAL_POSITION_INT (relative_alt mm), NaN before the first."""
        pos = self.link.global_position()
        return pos.relative_alt_m if pos is not None else float("nan")

    def _measure_rate(self) -> None:
        """Wait (wall time bounded) until the achieved ATTITUDE rate is known from time_boot_ms."""
        s = self.session
        grace_s = 4 * self.config.timing.rate_measure_s + self.config.timing.rate_measure_slack_s
        wait_for_first_attitude(self.link, s.cycle.profile, lambda: s.last_ms is not None, self.config, grace_s, self._stop, self._say,
                                self._sleep)
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline and not math.isfinite(s.achieved_rate_hz):
            win = s.rate_window()
            if win is not None:
                first, n, last = win
                span = (last - first) / 1000.0
                if span >= self.config.timing.rate_measure_s or (n >= 10 and span > 0):
                    s.record_achieved_rate(n / span)
                    break
            self._sleep(0.02)

    def _engage(self) -> None:
        """Mode/arm/takeoff requests (only those the options ask for), on the caller's thread.

        Control engages when the vehicle is in a guided mode *and* armed (HEARTBEAT), whoever put it
        there; with ``takeoff_alt_m`` the bounded climb starts right after our own arm was ACKed.
        """
        o, cfg, s, link = self.options, self.config, self.session, self.link
        lc = cfg.link
        s.set_state("prestream" if (s.cycle.profile.prestream_required or o.mode is not None) and cfg.timing.prestream_s > 0 else "waiting")
        link.on_heartbeat = s.on_heartbeat
        if o.mode is not None:
            profile = s.cycle.profile
            if o.takeoff_alt_m is not None and profile.autopilot_takeoff:
                # PX4: arm in its current mode and take off with its own takeoff; OFFBOARD once it holds at altitude
                if not (link.last_heartbeat and link.last_heartbeat.armed):
                    self._wait_vertical_estimate_at_rest()
                    self._arm_when_ready()
                self._autopilot_takeoff(o.takeoff_alt_m)
                self._let_hold_show_hover()
            if s.state == SessionState.PRESTREAM:
                self._wait_prestream(cfg.timing.prestream_s)
            if self._stop.is_set():
                raise Interrupted("during the pre-stream, before any mode change")
            hb = link.last_heartbeat
            if hb is None or hb.mode != o.mode:
                self._check_one_vehicle()
                self._mode_changed = True
                link.set_mode(o.mode, lc.command_ack_timeout_s, lc.command_retries)
                s.mode_request_acked()
            armed_by_us = False
            if o.arm and not (link.last_heartbeat and link.last_heartbeat.armed):
                self._arm_when_ready()
                armed_by_us = True
            if o.takeoff_alt_m is not None and not profile.autopilot_takeoff:
                s.start_takeoff(o.takeoff_alt_m)
                return
            if armed_by_us or link.last_heartbeat.armed:  # mode ACKed and armed: engage on the ACK, not the next HEARTBEAT
                s.set_state("engage_pending")
                return
            if not s.cycle.profile.prestream_required:
                s.set_state("waiting")
        else:
            self._say(f"{self.phase_text()} (the bridge never changes mode or arms unless told: --mode, --arm)")
        hb = link.last_heartbeat
        if hb is not None:
            s.on_heartbeat(hb)

    def _wait_prestream(self, duration_s: float) -> None:
        """Block until setpoints have streamed for ``duration_s`` of vehicle time since the first one was sent (PX4
        needs >= 1 s on its clock); at most ``duration_s`` + 5 s of host time."""
        s = self.session
        deadline = time.monotonic() + duration_s + 5.0
        while time.monotonic() < deadline and not self._stop.is_set():
            first, last = s.first_prestream_ms, s.last_ms
            if first is not None and last is not None and (last - first) / 1000.0 >= duration_s:
                return
            self._sleep(0.01)

    def _write_log_metadata(self) -> None:
        """The CSV's sidecar (flight_log.write_metadata): what is about to fly, once preflight knows the vehicle."""
        if self._log.path is None:
            return
        from .. import __version__

        rep, cfg = self.preflight, self.config
        try:
            write_metadata(self._log.path, {
                "mavastsm_version": __version__, "url": self.options.url, "autopilot": rep.autopilot,
                "firmware_version": rep.firmware_version, "thrust_semantics": rep.thrust_semantics,
                "attitude_rate_granted_hz": rep.attitude_rate_granted_hz, "vehicle": self.vehicle,
                "controller": self.controller_name, "controller_config": str(getattr(self.controller, "config_path", "")),
                "gains": self._exact_gains(), "reference": self.reference_name, "bridge_config": cfg.source,
                "overrides": {k: v for k, v in (self.options.overrides or {}).items()}, "notes": list(rep.notes),
                "mapping": self.session.cycle.mapping_record() if self.session is not None else None,
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            }, self._log.diagnostic_keys)
        except OSError as exc:
            self._say(f"note: cannot write the log's metadata sidecar ({exc})")

    def _write_log_counters(self) -> None:
        """The run's counters in the CSV's sidecar, by the names and definitions of telemetry.COUNTER_DEFINITIONS."""
        if self._log is None or self._log.path is None or not metadata_path(self._log.path).exists():
            return
        sm = self.summary
        values = {name: getattr(sm, name) for name in COUNTER_DEFINITIONS if name != "refused_frames"}
        values["refused_frames"] = sum(n for _, n in sm.refused_frames)
        try:
            add_metadata(self._log.path, {"counters": {name: {"value": values[name], "definition": d} for name, d in COUNTER_DEFINITIONS.items()}})
        except OSError as exc:
            self._say(f"note: cannot write the run's counters to the log's sidecar ({exc})")

    def _exact_gains(self) -> dict[str, str]:
        """The controller's gains as ``str`` gives them (every digit: the sidecar records what flew)."""
        g = getattr(self.controller, "gains", None)
        return {k: str(v) for k, v in vars(g).items()} if g is not None else {}

    def _session_info(self) -> SessionInfo:
        g = getattr(self.controller, "gains", None)
        gains = {k: gain_display_text(v) for k, v in vars(g).items()} if g is not None else {}
        a = self._adaptive_gain()
        nan3 = (float("nan"),) * 3
        return SessionInfo(
            controller=self.controller_name, gain_summary=gains, mu=per_axis(a.mu) if a and a.mu is not None else nan3,
            alpha_min=per_axis(a.alpha_min) if a else nan3, alpha_max=per_axis(a.alpha_max) if a else nan3,
            reference_name=self.reference_name,
            reference_start_vehicle_time_s=(self.session.cycle.engage_ms / 1000.0) if self.session and self.session.cycle.engage_ms is not None else float("nan"),
            reference_duration_s=self.duration_s, on_failsafe=self.options.on_failsafe, on_exit=self.options.on_exit,
            log_paths=self._log_paths,
        )

    def phase_text(self) -> str:
        """What the bridge is doing now, in words, for the dashboard and the status line."""
        s, o = self.session, self.options
        if s is None:
            return "connecting"
        state = s.state
        if state in (SessionState.WAITING, SessionState.PRESTREAM) and o.mode is None:
            modes = "/".join(s.cycle.profile.guided_modes)
            return f"waiting for the pilot or ground station to select {modes} and arm"
        if state == SessionState.PRESTREAM:
            return f"pre-streaming setpoints before requesting {o.mode}"
        if state == SessionState.WAITING:
            return f"waiting for {o.mode} and armed"
        if state == SessionState.ENGAGE_PENDING:
            return "engaging"
        if state == SessionState.TAKEOFF:
            return f"takeoff to {o.takeoff_alt_m:g} m (level, bounded climb)"
        if state == SessionState.ENGAGED:
            return f"flying {self.reference_name}"
        if state == SessionState.HOLDING:
            return f"level hold ({s.active_reason.label if s.active_reason else 'stop'})"
        if state == SessionState.HANDBACK:
            action = o.on_failsafe if s.failsafe is not None else o.on_exit
            return f"handing back ({action})" if action != "none" else "stopping (no hand-back: the autopilot's timeout takes over)"
        if state == SessionState.PAUSED:
            return "paused after a failsafe: waiting for a guided mode and armed (--reengage)"
        return str(state)

    def _publish_link_status(self) -> None:
        link, s, rep = self.link, self.session, self.preflight
        hb = link.last_heartbeat
        p50, p99, _ = s.latency_percentiles(LIVE_LATENCY_WINDOW) if s else (float("nan"),) * 3
        self.telemetry.set_link(LinkStatus(
            url=link.url, autopilot=rep.autopilot if rep else "unknown", firmware_version=rep.firmware_version if rep else "",
            mode=hb.mode if hb else "", armed=hb.armed if hb else False, thrust_semantics=rep.thrust_semantics if rep else "",
            attitude_rate_requested_hz=self.config.timing.attitude_rate_hz,
            attitude_rate_achieved_hz=s.achieved_rate_hz if s else float("nan"),
            latency_p50_s=p50, latency_p99_s=p99, cycles=s.cycles if s else 0, missed=s.missed if s else 0,
            dropped=s.dropped if s else 0, duplicate=s.duplicate if s else 0,
            superseded=link.stats.superseded, invalid=s.invalid if s else 0,
            time_since_attitude_s=((time.monotonic_ns() - s.last_fresh_ns) * 1e-9) if s and s.last_fresh_ns else float("nan"),
            signing=link.signing, refused_frames=link.stats.bad_data, phase=self.phase_text(),
            out_of_order=link.stats.out_of_order, clock_outliers=link.clock.outliers, foreign_attitude=link.stats.foreign_attitude,
            blocked_setpoints=s.blocked if s else 0, overruns=s.overruns if s else 0, reader_errors=link.stats.reader_errors,
        ))

    def _supervise_in_turn(self, joined: threading.Event) -> None:
        with self._turn():  # its hand-back acts on the vehicle
            joined.set()
            self._supervise()

    def _supervise(self) -> None:
        """Supervisor thread: session ticks, hand-back, status, log flushing, interval re-assertion."""
        cfg, s = self.config, self.session
        period = 1.0 / cfg.timing.hold_send_hz
        last_flush = time.monotonic()
        engaged_once = False
        start = time.monotonic()
        while True:
            if self._abandon.is_set():
                return  # start-up failed: _abort_start hands back and closes, on its own thread
            try:
                if self._stop.is_set() and self._started.is_set():  # during start-up, start-up ends the run
                    s.request_stop()
                s.tick()
                conflict = self.link.clock.conflict
                if conflict is not None and not self._conflict_said:
                    self._conflict_said = True
                    text = conflict.text(self.link.target_system)
                    self._say(f"bridge: {text}")
                    s.identity_conflict(text)
                now = time.monotonic()
                if s.state in (SessionState.ENGAGED, SessionState.HOLDING):
                    engaged_once = True
                if not engaged_once and s.state in (SessionState.WAITING, SessionState.PRESTREAM) and now - start > self.options.engage_timeout_s:
                    s.request_stop(end_reason=f"not engaged: no guided mode + armed within {self.options.engage_timeout_s:g} s")
                new_events, new_late = s.session_events[self._events_said:], s.late_mode_heartbeats[self._late_said:]
                self._events_said += len(new_events)  # the reader thread may append meanwhile: counted, said next tick
                self._late_said += len(new_late)
                for why in new_events:
                    self._say(f"new vehicle session: {why}")
                for mode in new_late:
                    self._say(f"HEARTBEAT still showing {mode} after the vehicle ACKed {self.options.mode}: taken as sent "
                              f"before the switch (the next one decides)")
                self._say_hover()
                if s.handback_due.is_set() and s.state == SessionState.HANDBACK:
                    s.handback_due.clear()
                    self._hand_back()
                if now - last_flush >= cfg.timing.log_flush_s:
                    self._log.flush()
                    self.link.flush()
                    last_flush = now
                if now - self._last_status >= 1.0:
                    self._last_status = now
                    self._publish_link_status()
                    if s.cycle.engage_ms is not None:
                        self.telemetry.set_session(self._session_info())
                    self._reassert_interval(now)
                    self._request_stream_while_idle()
                if s.done.is_set() or s.state == SessionState.DONE:
                    break
            except Exception as exc:  # the supervisor must keep supervising
                self._say(f"supervisor error: {exc!r}")
            self._sleep(period, interruptible=False)
        try:
            self._finish()
        except Exception as exc:  # never leave wait() without an answer: the error becomes the run's end
            self._finish_error = f"{type(exc).__name__}: {exc}"
            self._say(f"bridge: could not finish cleanly ({self._finish_error})")
            try:
                self._shutdown()
            except Exception as exc2:  # noqa: BLE001 - reported, and wait() still answers
                self._say(f"bridge: shutdown after that also failed ({type(exc2).__name__}: {exc2})")

    def _say_hover(self) -> None:
        """Once per engagement, where the hover collective flown comes from (PX4: measured from its hold, or why not)."""
        s = self.session
        if s.hover_source is None or s.engagements <= self._hover_said_at:
            return
        self._hover_said_at = s.engagements
        with s.lock:
            m, hover = s.hover_measurement, s.cycle.profile.hover_thrust_norm
        if isinstance(m, HoverMeasurement):
            text = m.text(s.cycle.profile.name, s.cycle.profile.hover_thrust_param)
        else:
            text = f"hover collective {hover:.3f} from {self.preflight.hover_source.split(';')[0]}: not measured from the hold ({m})"
        self.preflight.hover_collective_norm = hover
        self._say(text)

    def _reassert_interval(self, now: float) -> None:
        s, t = self.session, self.config.timing
        if not math.isfinite(s.achieved_rate_hz) or s.achieved_rate_hz >= 0.5 * t.attitude_rate_hz:
            return
        if now - self._last_reassert < t.interval_reassert_s:
            return
        self._last_reassert = now
        try:
            self.link.set_message_interval_nowait(MSG_ID_ATTITUDE, t.attitude_rate_hz)
            self._say(f"ATTITUDE at {s.achieved_rate_hz:.0f} Hz < half of {t.attitude_rate_hz:g} Hz: SET_MESSAGE_INTERVAL re-sent")
        except LinkError as exc:  # the link is going; its loss is the supervisor's to report
            self._say(f"ATTITUDE interval not re-sent ({exc})")

    def _request_stream_while_idle(self) -> None:
        """Waiting to engage, or paused (reengage), with the autopilot's HEARTBEAT heard but no ATTITUDE for 1 s: a
        restarted autopilot streams nothing until asked (ArduCopter 4.7's MAVn_EXTRA1 defaults to 0), so ask again
        for ATTITUDE at the configured rate (1 Hz, no ACK wait); its new clock is then confirmed (vehicle_clock)."""
        s, cfg = self.session, self.config
        if s.state not in (SessionState.WAITING, SessionState.PAUSED) or self.link.seconds_since_heartbeat() > cfg.link.link_loss_timeout_s:
            return
        if s.last_fresh_ns is not None and (time.monotonic_ns() - s.last_fresh_ns) * 1e-9 < 1.0:
            return
        try:
            self.link.set_message_interval_nowait(MSG_ID_ATTITUDE, cfg.timing.attitude_rate_hz)
        except LinkError as exc:  # the vehicle is not reachable yet: asked again in 1 s
            self._say(f"ATTITUDE interval not re-sent while {s.state.value} ({exc})")

    def _hand_back(self) -> None:
        s, o, lc = self.session, self.options, self.config.link
        action = o.on_failsafe if s.failsafe is not None else o.on_exit
        if action == "none":
            self.handback = "none (autopilot's own timeout takes over)"
        else:
            self.handback, mode = self._request_handback(action)
            if mode is None:
                self.handback_failed = True
            else:
                self.handback_confirmed = self.link.wait_heartbeat_mode(mode, lc.handback_confirm_s)
        self._say(f"hand-back: {self.handback}")
        if o.reengage and s.failsafe in REENGAGE_AFTER and not self._stop.is_set():
            self._say(f"{s.failsafe.label}: waiting for the vehicle to come back in a guided mode and armed (--reengage)")
            s.pause_after_handback()
            return
        s.finish()

    def _request_handback(self, action: str) -> tuple[str, str | None]:
        """Walk the profile's modes for hand-back ``action`` until one is accepted: (what happened, as said in the
        summary, e.g. "ALTCTL refused (…); LOITER accepted" or "FAILED: …"; the accepted mode, None if all refused)."""
        lc = self.config.link
        refused = []
        for mode in self.session.cycle.profile.handback_modes(action):
            try:
                self.link.set_mode(mode, lc.command_ack_timeout_s, lc.command_retries)
            except (OffboardRejected, ConfigError, LinkError) as exc:
                refused.append(f"{mode} refused ({exc})")
                continue
            return "; ".join(refused + [f"{mode} accepted"]), mode
        return "FAILED: " + "; ".join(refused), None

    def _restore_setpoint_timeout(self) -> None:
        """Put back the setpoint timeout preflight changed (after the hand-back; never raises)."""
        rep = self.preflight
        if rep is None or rep.setpoint_timeout_restore is None or self.link is None:
            return
        name, value = rep.setpoint_timeout_restore
        rep.setpoint_timeout_restore = None
        try:
            ok = self.link.param_set(name, value, self.config.link.param_timeout_s, self.config.link.command_retries)
        except LinkError:  # the link turns socket errors into LinkError
            ok = False
        self._say(f"{name} restored to {value:g} s" if ok else f"{name} could not be restored to {value:g} s (no echo)")

    def _finish(self) -> None:
        s, link = self.session, self.link
        self._restore_setpoint_timeout()
        if self.handback == "not yet":
            self.handback = "not performed (pilot in control, or never engaged)"
        p50, p99, pmax = s.latency_percentiles()
        engage_t = (s.cycle.engage_ms / 1000.0) if s.cycle.engage_ms is not None else float("nan")
        with s.lock:
            samples = tuple(s.samples)
        engaged = tuple(x for x in samples if x.vehicle_time_s >= engage_t) if math.isfinite(engage_t) else ()
        rep = self.preflight
        self.summary = BridgeSummary(
            url=link.url, autopilot=rep.autopilot, firmware_version=rep.firmware_version, thrust_semantics=rep.thrust_semantics,
            controller=self.controller_name, reference=self.reference_name, end_reason=s.end_reason or "stopped",
            failsafe=s.failsafe, handback=self.handback, engagements=s.engagements, cycles=s.cycles, missed=s.missed,
            dropped=s.dropped, duplicate=s.duplicate, superseded=link.stats.superseded, invalid=s.invalid,
            foreign_attitude=link.stats.foreign_attitude, blocked_setpoints=s.blocked, overruns=s.overruns,
            latency_p50_s=p50, latency_p99_s=p99, latency_max_s=pmax, attitude_rate_achieved_hz=s.achieved_rate_hz,
            engage_time_s=engage_t, axes=run_metrics(engaged, engage_t, s.cycle.reference), samples=samples, log_paths=self._log_paths,
            handback_confirmed=self.handback_confirmed, handback_failed=self.handback_failed, out_of_order=link.stats.out_of_order,
            clock_outliers=link.clock.outliers,
            vehicle_restarts=s.vehicle_restarts, vehicle_sessions=s.vehicle_sessions, recovered_failsafes=tuple(s.recovered_failsafes),
            refused_frames=tuple((name, link.stats.refused[name]) for name in REFUSED_FRAME_CLASSES if link.stats.refused[name]),
            samples_capped=len(samples) >= s.max_samples_kept, reader_errors=link.stats.reader_errors,
        )
        self._write_log_counters()
        self._publish_link_status()
        self._shutdown()

    def _shutdown(self) -> None:
        if self.link is not None:
            self.link.on_attitude = None
            self.link.on_heartbeat = None
            self.link.close()
        if self._log is not None:
            self._log.close()

    # ------------------------------------------------------------------ public control
    def request_stop(self) -> None:
        """Ask for a clean stop (thread- and signal-safe): level hold, hand-back (on_exit), logs flushed."""
        self._stop.set()

    def wait(self, timeout_s: float | None = None) -> BridgeSummary | None:
        """Block until the run ends (duration, stop, failsafe, mode change); the summary, or None on timeout."""
        if self._thread is None:
            return self.summary
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            return None
        if self.summary is None:  # the supervisor ended without one: say so once, never let a caller poll forever
            raise LinkError(f"{self.options.url}: the bridge ended without a summary ({self._finish_error or 'supervisor stopped'})")
        return self.summary

    def stop(self, timeout_s: float = 10.0) -> BridgeSummary | None:
        """request_stop() + wait()."""
        self.request_stop()
        return self.wait(timeout_s)

    def run(self) -> BridgeSummary:
        """start() and block until the run ends; returns the summary."""
        self.start()
        while True:
            summary = self.wait(0.2)
            if summary is not None:
                return summary

    @property
    def state(self) -> str:
        return self.session.state if self.session is not None else "connecting"

    def __enter__(self) -> "Bridge":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
