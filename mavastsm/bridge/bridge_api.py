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

from ..errors import ConfigError, LinkError, OffboardRejected
from ..signing import signing_key_option
from ..references import reference_from_option
from ..solo_model import load_solo
from ..telemetry import SessionInfo, TelemetryBuffer, extra_diagnostic_keys
from .bridge_config import BridgeConfig, load_bridge_config, split_overrides
from .cycle.control_cycle import ControlCycle
from .record.flight_log import FlightLog, open_flight_log
from .flight_plan import FlightPlan, alpha_max, alpha_within_ceiling, plan_flight, tuning_parameter_names
from .vehicle_description import save_flown_description
from .link.mavlink_link import MavlinkLink, parse_link_url
from .session.offboard_session import REENGAGE_AFTER, OffboardSession, SessionState
from .autopilots.preflight import LinkParameters, PreflightReport, format_preflight, hover_source, measure_attitude_rate, run_preflight
from .run_record import (BridgeSummary, flight_metadata, link_status, session_info, summarise, write_counters, write_flown_mapping,
                         write_flight_metadata)
from .supervision import AttitudeStreamKeeper, SessionNews, phase_text
from .vehicle_actions import VehicleActions

HANDBACK_ACTIONS = ("ALT_HOLD", "LOITER", "LAND", "none")
DEFAULT_VEHICLE = "solo"  # configs/vehicle/solo.yaml until preflight knows the autopilot (AutopilotProfile.default_vehicle)
REQUESTABLE_MODES = ("GUIDED", "GUIDED_NOGPS", "OFFBOARD")

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
    save_vehicle : write the vehicle description the flight flew here at its end, unless a failsafe ended it
        (``vehicle_description``; None = no file)
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
    save_vehicle: str | Path | None = None
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
        if self.save_vehicle is not None and not Path(self.save_vehicle).expanduser().parent.is_dir():
            raise ConfigError(f"--save-vehicle {self.save_vehicle}: its folder does not exist")
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


def engaged_duration_s(option_s: float | None, reference) -> float:
    """[s] How long the bridge flies engaged: the option, else the reference's own duration, else until stopped."""
    if option_s is not None:
        return float(option_s)
    d = getattr(reference, "duration_s", None)
    return float(d) if d and math.isfinite(d) else math.inf


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
        self.reference, self.reference_name = reference_from_option(options.reference)
        self.duration_s = engaged_duration_s(options.duration_s, self.reference)
        self.link: MavlinkLink | None = None
        self.session: OffboardSession | None = None
        self.preflight: PreflightReport | None = None
        self._parameters: LinkParameters | None = None  # the preflight's reader: the plan and --save-vehicle read on through it
        self.summary: BridgeSummary | None = None
        self._saved_tuning: dict[str, float] = {}  # --save-vehicle: the autopilot parameters read at the plan
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
        self._mode_before = ""  # the vehicle's mode at preflight
        self._actions: VehicleActions | None = None  # arm, takeoff, mode and hand-back requests, once the link exists
        self._finish_error = ""  # why _finish failed, if it did

    # ------------------------------------------------------------------ construction helpers
    def _build_controller(self, extra: Mapping[str, Any] | None = None):
        """(controller, name): the options' controller, named ones from bridge.yaml's preset with ``extra`` overrides
        and the user's --set (which wins), built with the current vehicle's I0; an object as given."""
        from ..control import controller_for_flight

        c = self.options.controller
        preset = (self.options.controller_config or getattr(self.config.presets, c, None)) if isinstance(c, str) else None
        return controller_for_flight(c, self.solo, preset, extra, self._controller_overrides)

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
        key = signing_key_option(self.options.signing_key)
        self._log, tlog_path, self._log_paths = open_flight_log(self.options.log_dir, extra_diagnostic_keys(self.controller.diagnostics()))
        self._create_link(key, tlog_path)
        try:
            self.link.open(self.config.link.heartbeat_wait_s, stop=self._stop, progress=self._say)  # until its HEARTBEAT
            try:
                profile = self._run_preflight()
            except (OffboardRejected, ConfigError, LinkError):
                self._actions.check_one_vehicle()  # two vehicles on the id explain a failed preflight better than its step
                raise
            self._actions.check_one_vehicle()
            plan = self._fly_plan(profile)
            self._actions.request_vertical_state(plan.hold_altitude)
            cycle = self._build_cycle(profile, plan)
            self._build_session(cycle)
            self._negotiate_rate(profile)
            self._announce(cycle, plan)
            self._publish_start()
            self._actions.request_altitude_for_takeoff(self.options.takeoff_alt_m, self.config.timing.altitude_rate_hz)
            self._start_supervisor()
            self._engage()
        except BaseException:
            self._abort_start()
            raise
        self._started.set()

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
    def _create_link(self, key: bytes | None, tlog_path: Path | None) -> None:
        """The MAVLink link object for the URL (not yet connected)."""
        o, cfg = self.options, self.config
        url, baud = parse_link_url(o.url, o.baud)
        self.link = MavlinkLink(
            url, baud=baud, source_system=o.source_system, source_component=cfg.link.source_component,
            heartbeat_type=cfg.link.heartbeat_type, target_system=o.target_system, signing_key=key, tlog_path=tlog_path,
            realtime_priority=cfg.timing.realtime_priority, turns=o.lockstep_turns,
        )
        self._actions = VehicleActions(self.link, cfg.link, cfg.thrust, self._say, self._sleep)

    def _run_preflight(self):
        """The preflight checks (``run_preflight``): identify the autopilot and its profile, read its parameters,
        request the ATTITUDE rate. Keeps the report and the mode the vehicle was in; returns the profile."""
        self.preflight, profile, self._parameters = run_preflight(self.link, self.config)
        self._mode_before = self.preflight.mode
        return profile

    def _fly_plan(self, profile) -> FlightPlan:
        """Decide the flight plan from the preflight (``plan_flight``: vehicle description, config, command limits,
        controller overrides) and adopt it: a named controller is built again with what it says."""
        o = self.options
        rep = self.preflight
        plan = plan_flight(self.config, profile, granted_rate_hz=rep.attitude_rate_granted_hz,
                           report_accel_limit_radss=rep.accel_limit_radss, controller=self.controller,
                           controller_named=isinstance(o.controller, str), controller_vehicle=self.vehicle,
                           vehicle_given=o.vehicle_config, user_mapping_keys=self._user_mapping_keys,
                           read_parameter=self._parameters.read_with_retries,
                           mode=o.mode, takeoff_alt_m=o.takeoff_alt_m)
        self.vehicle, self.solo, self.config = plan.vehicle, plan.solo, plan.config
        rep.notes.extend(plan.notes)
        if o.save_vehicle is not None:  # the tuning the plan's numbers were chosen at, read now (the link's preflight turn)
            read = self._parameters.read_with_retries
            self._saved_tuning = {n: v for n in tuning_parameter_names(profile) if (v := read(n)) is not None}
        if plan.rebuild_controller:
            self.controller, _ = self._build_controller(plan.controller_overrides)  # with the I0 of the planned vehicle
        return plan

    def _build_cycle(self, profile, plan: FlightPlan) -> ControlCycle:
        """The control cycle: controller, reference, mapping to the autopilot's setpoint, the autopilot-target model."""
        cfg = self.config
        return ControlCycle(self.controller, self.reference, self.solo.inertia_diag, profile, cfg, alpha_max(self.controller),
                            plan.accel_limit_radss, self.preflight.angle_p,
                            torque_authority_nm=plan.torque_authority_nm, setpoint_timeout_s=self.preflight.setpoint_timeout_s,
                            pinned_failsafe=not alpha_within_ceiling(self.controller, cfg.mapping),
                            vertical_state=self._actions.vertical_state if plan.hold_altitude else None,
                            identify_in_flight=plan.identify_in_flight)

    def _build_session(self, cycle: ControlCycle) -> None:
        """The offboard session that runs the cycle on every ATTITUDE, wired to the link."""
        o = self.options
        self.session = OffboardSession(self.link, cycle, self.config, self.telemetry, self._log, o.reengage, self.duration_s)
        self.link.on_attitude = self.session.on_attitude
        self.session.altitude_fn = self._actions.altitude_m
        self.session.on_engage = o.on_engage
        self.session.hover_source = hover_source(self.link, cycle.profile, self.config.thrust, self.preflight)

    def _negotiate_rate(self, profile) -> None:
        """Measure the ATTITUDE rate the vehicle really sends; below 80 % of the accepted rate the loop runs at it."""
        achieved = measure_attitude_rate(self.link, self.session, self.config, self._stop, self._say, self._sleep)
        cfg = self.config
        if achieved < 0.8 * cfg.timing.attitude_rate_hz:
            self.preflight.notes.append(f"ATTITUDE accepted at {cfg.timing.attitude_rate_hz:g} Hz but sent at {achieved:.0f} Hz: "
                                        f"{profile.rate_cap_reason or 'the vehicle sends slower than it accepted'}; the loop runs at that rate")
            cfg = self.config = dataclasses.replace(cfg, timing=dataclasses.replace(cfg.timing, attitude_rate_hz=round(achieved, 1)))
            self.session.set_nominal_rate(cfg)

    def _announce(self, cycle: ControlCycle, plan: FlightPlan) -> None:
        """Say the preflight summary: checks, rate, controller, reference, mapping and command limits."""
        self._say(format_preflight(self.preflight, self.session.sample_stage.achieved_rate_hz, self.controller_name, self.reference_name,
                                   cycle.mapping_text(plan.adaptive), f"reader thread {self.link.reader_scheduling}"))

    def _publish_start(self) -> None:
        """The session's description and the link status to the telemetry (dashboard), the log's metadata sidecar."""
        self.telemetry.set_session(self._session_info())
        self._publish_link_status()
        self._write_log_metadata()

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
        if self._actions is not None:
            self._actions.restore_mode(self._mode_before)
            self._hand_back_after_failed_start()
            self._actions.restore_setpoint_timeout(self.preflight)
        if self.session is not None:
            self.session.finish()
        self._shutdown()

    def _hand_back_after_failed_start(self) -> None:
        """start() failed: an armed vehicle the bridge armed gets the hand-back asked for (--on-failsafe, else
        --on-exit; ``VehicleActions.hand_back_after_failed_start``), unless a failsafe during start-up already did."""
        o, s = self.options, self.session
        if s is None or self.handback != "not yet":
            return
        action = o.on_failsafe if o.on_failsafe != "none" else o.on_exit
        self._actions.hand_back_after_failed_start(action, s.cycle.profile.handback_modes(action) if action != "none" else ())

    def _engage(self) -> None:
        """Mode/arm/takeoff requests (only those the options ask for: ``VehicleActions.request_guided_flight``), on
        the caller's thread. Control engages when the vehicle is in a guided mode *and* armed (HEARTBEAT), whoever put
        it there; with ``takeoff_alt_m`` the bounded climb starts right after our own arm was ACKed."""
        o, cfg, s, link = self.options, self.config, self.session, self.link
        s.set_state("prestream" if (s.cycle.profile.prestream_required or o.mode is not None) and cfg.timing.prestream_s > 0 else "waiting")
        link.on_heartbeat = s.on_heartbeat
        if o.mode is not None:
            if self._actions.request_guided_flight(s, o.mode, o.arm, o.takeoff_alt_m, cfg.timing.prestream_s, self._stop):
                return
        else:
            self._say(f"{self.phase_text()} (the bridge never changes mode or arms unless told: --mode, --arm)")
        hb = link.last_heartbeat
        if hb is not None:
            s.on_heartbeat(hb)

    def _write_log_metadata(self) -> None:
        """The CSV's sidecar: what is about to fly, once preflight knows the vehicle."""
        write_flight_metadata(self._log.path, self._log.diagnostic_keys, flight_metadata(
            self.options.url, self.options.overrides, self.preflight, self.vehicle, self.controller, self.controller_name,
            self.reference_name, self.config, self.session), self._say)

    def _session_info(self) -> SessionInfo:
        o = self.options
        return session_info(self.controller, self.controller_name, self.reference_name, self.session, self.duration_s,
                            o.on_failsafe, o.on_exit, self._log_paths)

    def phase_text(self) -> str:
        """What the bridge is doing now, in words, for the dashboard and the status line."""
        o = self.options
        return phase_text(self.session, o.mode, o.takeoff_alt_m, self.reference_name, o.on_failsafe, o.on_exit)

    def _publish_link_status(self) -> None:
        self.telemetry.set_link(link_status(self.link, self.session, self.preflight, self.config.timing.attitude_rate_hz,
                                            self.phase_text()))

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
        news, stream = SessionNews(self._say, self.options.mode), AttitudeStreamKeeper(self._say)
        while True:
            if self._abandon.is_set():
                return  # start-up failed: _abort_start hands back and closes, on its own thread
            try:
                if self._stop.is_set() and self._started.is_set():  # during start-up, start-up ends the run
                    s.request_stop()
                s.tick()
                now = time.monotonic()
                if s.state in (SessionState.ENGAGED, SessionState.HOLDING):
                    engaged_once = True
                if not engaged_once and s.state in (SessionState.WAITING, SessionState.PRESTREAM) and now - start > self.options.engage_timeout_s:
                    s.request_stop(end_reason=f"not engaged: no guided mode + armed within {self.options.engage_timeout_s:g} s")
                news.tell(s, self.link, self.preflight)
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
                stream.keep(s, self.link, cfg, now)
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

    def _hand_back(self) -> None:
        s, o = self.session, self.options
        action = o.on_failsafe if s.failsafe is not None else o.on_exit
        modes = s.cycle.profile.handback_modes(action) if action != "none" else ()
        self.handback, confirmed, failed = self._actions.hand_back(action, modes)
        if failed:
            self.handback_failed = True  # stays said for the run, as does an earlier confirmation after a re-engagement
        elif action != "none":
            self.handback_confirmed = confirmed
        self._say(f"hand-back: {self.handback}")
        if o.reengage and s.failsafe in REENGAGE_AFTER and not self._stop.is_set():
            self._say(f"{s.failsafe.label}: waiting for the vehicle to come back in a guided mode and armed (--reengage)")
            s.pause_after_handback()
            return
        s.finish()

    def _finish(self) -> None:
        self._actions.restore_setpoint_timeout(self.preflight)
        if self.handback == "not yet":
            self.handback = "not performed (pilot in control, or never engaged)"
        self.summary = summarise(self.link, self.session, self.preflight, self.controller_name, self.reference_name,
                                 self.handback, self.handback_confirmed, self.handback_failed, self._log_paths)
        log_path = self._log.path if self._log is not None else None
        write_counters(log_path, self.summary, self._say)
        write_flown_mapping(log_path, self.session, self._say)
        if self.options.save_vehicle is not None:
            save_flown_description(self.options.save_vehicle, self.summary, self.vehicle, self.config.mapping,
                                   self.session.cycle.mapping.tau_s, self._saved_tuning, self._say)
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
