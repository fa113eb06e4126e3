"""``mavastsm demo``: the whole idea in one command.

Starts the in-repo simulated Solo (``mavastsm_sim.VehicleServer``, a background thread speaking
ArduCopter MAVLink on a loopback UDP port) and the offboard bridge (``mavastsm.bridge.Bridge``,
connected with ``udpout:127.0.0.1:PORT`` exactly as it would connect to SITL), then:

1. the bridge requests GUIDED, arms, and climbs level to ``--takeoff-m`` (climb-rate thrust);
2. the controller flies the scenario's attitude reference (the paper's steps: roll -10 deg at 0.5 s,
   pitch +10 deg at 1 s, yaw +45 deg at 2 s), with the scenario's disturbance / inertia variation
   applied by the sim (disturbance times count from engagement);
3. the bridge hands back with LAND; the sim lands and disarms on touchdown (ArduCopter LAND): its own
   phase, a line with the altitude once per simulated second until touchdown (the flight's status stops);
4. a summary table: per-axis settling time, overshoot, steady error, chattering, alpha peak, cycle
   latency, log paths.

Clock: the sim runs in lockstep with the bridge (every ATTITUDE waits for its SET_ATTITUDE_TARGET) and at
most ``--speedup`` x real time (default 1: it looks like real time). A loaded machine therefore slows the
flight down instead of ending it in STALE_ATTITUDE (measured: the demo completes with four busy processes
on two cores); the achieved speed-up is printed. The landing after the hand-back is paced at N x real time.

Ctrl-C (or ``q`` in the dashboard) at any point: the bridge holds level, hands back with LAND, the demo
waits for touchdown and disarm, then stops everything. A second Ctrl-C stops at once.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import signal
import tempfile
import threading
import time
from pathlib import Path

from .errors import ConfigError

SCENARIOS = ("nominal", "disturbance", "variation")
CONTROL_RATE_HZ = 400.0
PHYSICS_RATE_HZ = 1000.0
#: [s] longest wall wait of the lockstep sim for an answer: well under the bridge's stale-ATTITUDE timeout
#: (0.1 s host time), so the phases where the bridge does not answer every sample (connect, mode, arm)
#: never look like a dead link.
LOCKSTEP_TIMEOUT_S = 0.02
#: [s] the bridge's stale-ATTITUDE timeout (host time) in lockstep runs: the sim waits for the bridge, so
#: a host stall cannot let the vehicle run away; widened from the packaged 0.1 s so a loaded machine
#: (threads descheduled for a few hundred ms) does not end the demo with STALE_ATTITUDE.
LOCKSTEP_STALE_TIMEOUT_S = 1.0
#: [s] disturbance-clock origin while waiting for engagement (no scenario event starts before it)
DISTURBANCE_CLOCK_PARKED_S = 1e9
LANDING_REPORT_S = 1.0  # [s of simulated time] between two landing progress lines


#: What each packaged scenario shows in the demo (ASTSM, bridge defaults; measured 2026-12-01, --speedup 5),
#: said before the flight starts so that a failsafe ending is the expected lesson, not a surprise.
SCENARIO_OUTCOMES = {
    "nominal": "the paper's steps, flown to the end",
    "variation": "the paper's steps with the inertia varied as in Table 3, flown to the end",
    "variation_stress": "the steps with a larger inertia variation, flown to the end",
    "disturbance_roll": "0.5 N m on roll from 4 s (17 % of the roll authority), rejected; flown to the end",
    "disturbance_pitch": "0.5 N m on pitch from 4 s: the pitch command sits at the bound that keeps the last "
                         "setpoint survivable, so it ends in the COMMAND_SATURATION failsafe (level hold, LAND, exit 1)",
    "disturbance_yaw": "0.5 N m on yaw from 4 s, above the Solo's yaw authority (about 0.32 N m): no controller holds "
                       "the heading; it ends in the ENVELOPE_BREACH failsafe (level hold, LAND, exit 1)",
    "disturbance": "the paper's D-A, 0.5 N m on every axis from 4 s; the yaw part exceeds the Solo's authority, so "
                   "it ends in the ENVELOPE_BREACH failsafe (level hold, LAND, exit 1)",
    "disturbance_within_authority": "0.5 / 0.5 / 0.2 N m from 4 s: with the adaptive gain held under the loop-delay "
                                    "ceiling (docs/bridge.md, 'Adaptive gain and loop delay') the roll excursion "
                                    "reaches the envelope: ENVELOPE_BREACH failsafe (level hold, LAND, exit 1)",
    "disturbance_from_start": "0.5 N m on every axis from the start: the roll command saturates and the roll excursion "
                              "grows; whichever comes first, the COMMAND_SATURATION or the ENVELOPE_BREACH failsafe "
                              "(level hold, LAND, exit 1)",
    "disturbance_pulse": "a 0.5 N m pulse on every axis: ENVELOPE_BREACH failsafe (level hold, LAND, exit 1)",
}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", default="nominal", metavar="NAME",
                        help="packaged scenario or YAML path (default nominal). Flown to the end: nominal, variation, "
                             "variation_stress, disturbance_roll; ending in a failsafe (said before it starts): "
                             "disturbance, disturbance_pitch, disturbance_yaw, disturbance_within_authority, "
                             "disturbance_from_start, disturbance_pulse")
    parser.add_argument("--controller", default="astsm", metavar="NAME",
                        help="attitude controller (see 'mavastsm list-controllers'; default astsm)")
    parser.add_argument("--speedup", type=float, default=1.0, metavar="N",
                        help="simulated seconds per wall second, at most (the sim runs in lockstep with the bridge: "
                             "a loaded machine slows it down, never ends the flight) [-] (default 1)")
    parser.add_argument("--no-dashboard", action="store_true", help="plain status lines instead of the live dashboard")
    parser.add_argument("--log", metavar="DIR", type=Path, default=None,
                        help="folder for the flight CSV and the .tlog (default: a new folder under the system temp dir)")
    parser.add_argument("--takeoff-m", "--takeoff", dest="takeoff_m", type=float, default=2.0, metavar="ALT_M",
                        help="hover height reached before the steps [m] (default 2)")


def _validate(args: argparse.Namespace):
    """Load the scenario and check the options before anything starts (ConfigError -> one line, exit 2)."""
    from .control import CONTROLLERS
    from .scenarios import load_scenario

    if not (math.isfinite(args.speedup) and 0.1 <= args.speedup <= 100.0):
        raise ConfigError(f"--speedup {args.speedup}: must be within [0.1, 100]")
    if not (math.isfinite(args.takeoff_m) and 0.5 <= args.takeoff_m <= 20.0):
        raise ConfigError(f"--takeoff-m {args.takeoff_m}: must be within [0.5, 20] m")
    if args.controller not in CONTROLLERS:
        raise ConfigError(f"--controller {args.controller!r}: unknown; choose from {', '.join(sorted(CONTROLLERS))}")
    return load_scenario(args.scenario)


def _log_dir(args: argparse.Namespace) -> Path:
    if args.log is not None:
        return args.log
    return Path(tempfile.gettempdir()) / "mavastsm-demo" / time.strftime("%Y%m%d-%H%M%S")


def _chattering_nm_per_s(samples, axis: int) -> float:
    """[N m/s] total variation of the total control u (eq. 18) per second of vehicle time."""
    rows = [(s.vehicle_time_s, s.u_nm[axis]) for s in samples if s.failsafe is None and math.isfinite(s.u_nm[axis])]
    if len(rows) < 2 or rows[-1][0] <= rows[0][0]:
        return float("nan")
    tv = sum(abs(b[1] - a[1]) for a, b in zip(rows, rows[1:]))
    return tv / (rows[-1][0] - rows[0][0])


def _alpha_peak(samples, axis: int) -> float:
    vals = [s.alpha[axis] for s in samples if math.isfinite(s.alpha[axis])]
    return max(vals) if vals else float("nan")


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """What ``fly_demo`` returns (also printed as the summary)."""

    scenario: str
    controller: str
    summary: object  # BridgeSummary, or None if the bridge never started
    landed: bool
    disarmed: bool
    sim_time_s: float
    wall_time_s: float
    interrupted: bool
    log_dir: str


# one word per header line, units in brackets: the table fits 80 columns without cutting a header
SUMMARY_HEADERS = ("axis", "step\n[deg]", "settling\n5% [s]", "overshoot\n[%]", "steady\nerror\n[deg]", "max |e|\n[deg]",
                   "chattering\n[N·m/s]", "α peak\n[-]")


def summary_table(result: DemoResult):
    """Rich table of the run (pure: result in, renderable out)."""
    from rich import box
    from rich.table import Table
    from rich.text import Text

    s = result.summary
    reference = getattr(s, "reference", "") if s is not None else ""
    t = Table(title=f"mavastsm demo: {result.controller} on scenario '{result.scenario}'"
                    f"{f' (reference {reference})' if reference else ''} over MAVLink (simulated Solo)",
              box=box.HEAVY_HEAD, show_edge=False)  # no outer edge: 8 columns fit 80 with every header word whole
    for col in SUMMARY_HEADERS:  # Text: "[deg]" would otherwise be read as console markup and vanish
        t.add_column(Text(col), justify="left" if col == "axis" else "right")
    engaged = [x for x in s.samples if x.vehicle_time_s >= s.engage_time_s] if math.isfinite(s.engage_time_s) else []

    def f(v, nd=2):
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else (
            "never" if v == math.inf else f"{v:.{nd}f}")

    for i, m in enumerate(s.axes):
        t.add_row(m.axis, f(m.step_size_deg, 1), f(m.settling_time_5pct_s), f(m.overshoot_pct, 1),
                  f(m.steady_error_deg, 3), f(m.max_abs_error_deg), f(_chattering_nm_per_s(engaged, i), 1),
                  f(_alpha_peak(engaged, i), 3))
    return t


def summary_lines(result: DemoResult) -> list[str]:
    s = result.summary
    speed = result.sim_time_s / result.wall_time_s if result.wall_time_s > 0 else float("nan")
    lines = [
        f"cycle latency (ATTITUDE received -> SET_ATTITUDE_TARGET sent, in the bridge): p50 {s.latency_p50_s * 1e6:.0f} us, "
        f"p99 {s.latency_p99_s * 1e6:.0f} us, max {s.latency_max_s * 1e6:.0f} us",
        f"cycles {s.cycles}, missed {s.missed}, dropped {s.dropped}; ATTITUDE {s.attitude_rate_achieved_hz:.0f} Hz achieved",
        f"end: {s.end_reason}; failsafe: {s.failsafe.name if s.failsafe else 'none'}; hand-back: {s.handback}",
        f"landed: {'yes' if result.landed else 'NO'}; disarmed: {'yes' if result.disarmed else 'NO'}"
        + ("; interrupted by the operator" if result.interrupted else ""),
        f"run: {result.sim_time_s:.1f} s of simulated time (connect, takeoff, profile, landing) in "
        f"{result.wall_time_s:.1f} s of wall time ({speed:.1f}x real time)",
        "logs: " + (", ".join(s.log_paths) if s.log_paths else result.log_dir),
    ]
    return lines


def fly_demo(args: argparse.Namespace, stop_event: threading.Event | None = None, print_fn=print) -> DemoResult:
    """Run the demo (see module docstring). ``stop_event`` set from anywhere = Ctrl-C."""
    from mavastsm_sim.sim_clock import ClockSpec
    from mavastsm_sim.vehicle_server import VehicleServer

    from .bridge import Bridge, BridgeOptions
    from .runtime_tuning import ProcessTuning
    from .telemetry import TelemetryBuffer

    scenario = _validate(args)
    stop_event = stop_event or threading.Event()
    log_dir = _log_dir(args)
    # always lockstep (the sim waits for the bridge's answer to each ATTITUDE: a loaded machine slows the
    # flight down instead of ending it in STALE_ATTITUDE), paced at --speedup x real time
    server = VehicleServer(scenario=scenario, physics_rate_hz=PHYSICS_RATE_HZ, clock="lockstep", lockstep_paced=True, speedup=args.speedup,
                           lockstep_timeout_s=LOCKSTEP_TIMEOUT_S, listen=("127.0.0.1", 0),
                           sched_loop_rate_hz=CONTROL_RATE_HZ / 0.8)
    telemetry = TelemetryBuffer()
    # the scenario's disturbances count from the start of the reference profile, not from boot: hold
    # their clock far in the future until the bridge engages (set below), so takeoff is undisturbed
    server.copter.disturbances.restart_clock(DISTURBANCE_CLOCK_PARKED_S)
    server.start()
    try:
        bridge = Bridge(BridgeOptions(
            f"udpout:127.0.0.1:{server.port}", controller=args.controller, reference=scenario.reference,
            rate_hz=CONTROL_RATE_HZ, duration_s=scenario.duration_s, mode="GUIDED", arm=True,
            takeoff_alt_m=args.takeoff_m, on_exit="LAND", on_failsafe="LAND", log_dir=log_dir,
            overrides={"timing.stale_timeout_s": LOCKSTEP_STALE_TIMEOUT_S},
            print_fn=print_fn if args.no_dashboard else None), telemetry)
    except BaseException:
        server.stop()
        raise
    dashboard = None
    tuning = ProcessTuning(bridge.config.timing)
    wall0 = time.monotonic()
    sim0 = 0.0
    landed = disarmed = False
    try:
        if not args.no_dashboard:
            from .dashboard.live_view import DashboardRunner

            dashboard = DashboardRunner(telemetry, on_quit=stop_event.set)
            dashboard.start()
        tuning.apply()  # process-wide settings: the command line's, not the library's (runtime_tuning)
        bridge.start()
        aligned = False
        while bridge.wait(0.02) is None:
            tuning.tick(bridge.state == "engaged")
            if stop_event.is_set():
                bridge.request_stop()
            engage_ms = bridge.session.cycle.engage_ms if bridge.session is not None else None
            if not aligned and engage_ms is not None and bridge.state == "engaged":
                # the scenario's disturbance times count from the start of the reference profile
                server.call(lambda copter: copter.disturbances.restart_clock(engage_ms / 1000.0))
                aligned = True
        summary = bridge.summary
        with server.lock:  # nobody answers ATTITUDE any more: pace the landing instead of waiting on the gate
            server.clock = ClockSpec("realtime", args.speedup)
        if dashboard is not None:  # the flight's view ends with the flight: the landing reports itself
            dashboard.stop()
            dashboard = None
        landing_timeout_s = 60.0 / min(args.speedup, 1.0)
        landed = _wait_for_touchdown(server, landing_timeout_s, print_fn)
        disarmed = server.wait_until(lambda c: not c.armed, timeout_s=10.0 + 15.0 / args.speedup)
    finally:
        tuning.restore()
        if bridge.summary is None and bridge.session is not None:
            bridge.stop()
        sim_t = server.sim_time_s if server.running else 0.0
        wall = time.monotonic() - wall0
        server.stop()
        if dashboard is not None:
            dashboard.stop()
    return DemoResult(scenario=scenario.name, controller=args.controller, summary=summary, landed=landed,
                      disarmed=disarmed, sim_time_s=sim_t - sim0, wall_time_s=wall, interrupted=stop_event.is_set(),
                      log_dir=str(log_dir))


def _wait_for_touchdown(server, timeout_s: float, say) -> bool:
    """The landing after the hand-back as its own phase: wait (``timeout_s`` of wall time at most) for the sim's
    touchdown, saying the altitude [m above the take-off point, from the sim's NED z] every LANDING_REPORT_S of
    simulated time since the LAND hand-back. True once landed."""
    def altitude_m(copter) -> float:
        return -float(copter.position_ned_m[2])

    t0 = server.sim_time_s
    next_report = t0 + LANDING_REPORT_S
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        server.wait_until(lambda c: c.landed or server.sim_time_s >= next_report, timeout_s=min(remaining, 1.0))
        landed, alt = server.call(lambda c: (c.landed, altitude_m(c)))
        t = server.sim_time_s - t0
        if landed:
            say(f"landing (LAND): touched down after {t:.1f} s")
            return True
        if server.sim_time_s >= next_report:
            say(f"landing (LAND): altitude {alt:.2f} m, {t:.1f} s")
            next_report += LANDING_REPORT_S
    say(f"landing (LAND): not down after {timeout_s:g} s (wall)")
    return False


def run(args: argparse.Namespace) -> int:
    from .console_output import report_console

    console = report_console()
    stop_event = threading.Event()
    presses = {"n": 0}

    def on_signal(signum, _frame):
        presses["n"] += 1
        if presses["n"] > 1:
            raise KeyboardInterrupt  # second Ctrl-C: stop now (the finally blocks still stop the sim)
        console.print("[bold]stopping: level hold, hand back with LAND, wait for touchdown (Ctrl-C again to abort)[/]")
        stop_event.set()

    old_int = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    name = Path(str(args.scenario)).stem
    if name in SCENARIO_OUTCOMES:
        console.print(f"scenario {name}: {SCENARIO_OUTCOMES[name]}", highlight=False)
    try:
        result = fly_demo(args, stop_event, print_fn=lambda text: console.print(text, highlight=False))
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
    console.print(summary_table(result))
    for line in summary_lines(result):
        console.print(line, highlight=False)
    from .state_types import FailsafeReason

    clean_end = result.summary.failsafe in (None, FailsafeReason.OPERATOR_STOP)
    return 0 if (result.landed and result.disarmed and clean_end) else 1
