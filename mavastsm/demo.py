"""``mavastsm demo``: the whole idea in one command.

Starts the in-repo simulated Solo (``mavastsm_sim.VehicleServer``, a background thread speaking
ArduCopter MAVLink on a loopback UDP port) and the offboard bridge (``mavastsm.bridge.Bridge``,
connected with ``udpout:127.0.0.1:PORT`` exactly as it would connect to SITL), then:

1. the bridge requests GUIDED, arms, and climbs level to ``--takeoff-m`` (climb-rate thrust);
2. the controller flies the scenario's attitude reference (the paper's steps: roll -10 deg at 0.5 s,
   pitch +10 deg at 1 s, yaw +45 deg at 2 s), with the scenario's disturbance / inertia variation
   applied by the sim (disturbance times count from engagement);
3. the bridge hands back with LAND; the sim lands and disarms on touchdown (ArduCopter LAND);
4. a summary table: per-axis settling time, overshoot, steady error, chattering, alpha peak, cycle
   latency, log paths.

Clock: the sim and the bridge are one lockstep pair (``mavastsm.lockstep_pair``): the vehicle moves only while
the bridge waits for it (every ATTITUDE answered, every command, start-up wait and the hand-back on the vehicle's
clock), at most ``--speedup`` x real time (default 1: it looks like real time). A loaded machine therefore slows
the flight down and never changes it: the same scenario gives the same flight CSV, idle or loaded (measured: the
demo completes with four busy processes on two cores); the achieved speed-up is printed. The landing after the
hand-back is paced at N x real time.

Ctrl-C (or ``q`` in the dashboard) at any point: the bridge holds level, hands back with LAND, the demo
waits for touchdown and disarm, then stops everything. A second Ctrl-C stops at once.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import tempfile
import threading
import time
from pathlib import Path

from .errors import ConfigError
from .processes import stopping_on_signals

SCENARIOS = ("nominal", "disturbance", "variation")
CONTROL_RATE_HZ = 400.0
PHYSICS_RATE_HZ = 1000.0
#: [s] the bridge's stale-ATTITUDE timeout (host time) in lockstep runs: the sim waits for the bridge, so
#: a host stall cannot let the vehicle run away; widened from the packaged 0.1 s so a loaded machine
#: (threads descheduled for a few hundred ms) does not end the demo with STALE_ATTITUDE.
LOCKSTEP_STALE_TIMEOUT_S = 1.0


#: What each packaged scenario within the Solo's torque authority shows in the demo (ASTSM, bridge defaults; measured
#: 2026-12-03, --speedup 20), said before the flight starts so that a failsafe ending is the expected lesson, not a
#: surprise. A scenario beyond the authority is said as such instead (``authority_exceeded``).
SCENARIO_OUTCOMES = {
    "nominal": "the paper's steps, flown to the end",
    "variation": "the paper's steps with the inertia varied as in Table 3, flown to the end",
    "variation_stress": "Table 3 read literally as kg m^2 (roll inertia 55 x the Solo's, physically implausible): the "
                        "steps overshoot until the ENVELOPE_BREACH failsafe (level hold, LAND, exit 1)",
    "disturbance_roll": "0.5 N m on roll from 4 s (17 % of the roll authority), rejected; flown to the end",
    "disturbance_pitch": "0.5 N m on pitch from 4 s (17 % of the pitch authority), rejected; flown to the end",
    "disturbance_within_authority": "0.5 / 0.5 / 0.2 N m from 4 s, within the Solo's authority: roll and pitch rejected "
                                    "within a second, the heading turned back slowly (--set mapping.yaw_trim_gain_per_s=1 "
                                    "brings it back in about 4 s); flown to the end",
    "disturbance_yaw_within_authority": "0.2 N m on yaw from 4 s (87 % of the yaw authority at hover): the heading pushed about "
                                        "28 deg off and turned back slowly (--set mapping.yaw_trim_gain_per_s=1 brings it "
                                        "back in about 4 s); flown to the end",
    "disturbance_pulse_within_authority": "0.5 / 0.5 / 0.2 N m for 1 s from 4 s: roll and pitch back within 2 s, the "
                                          "heading within about 4 s; flown to the end",
}

BEYOND_AUTHORITY = "beyond the vehicle's authority"
BEYOND_AUTHORITY_OUTCOME = ("no controller can hold that axis; it ends in a failsafe (ENVELOPE_BREACH or COMMAND_SATURATION: "
                            "level hold, LAND, exit 1)")


def authority_exceeded(args: argparse.Namespace) -> list[str]:
    """The scenario's axes whose disturbance exceeds the simulated Solo's torque authority (``mapping.torque_authority_nm``
    of the bridge config: 2.9 / 2.9 / 0.23 N m), said before the flight (``scenarios.beyond_authority``)."""
    from .bridge.bridge_config import load_bridge_config
    from .scenarios import beyond_authority

    return beyond_authority(_validate(args), load_bridge_config().mapping.torque_authority_nm)


def configure(parser: argparse.ArgumentParser) -> None:
    from .control import LAW_HELP

    parser.add_argument("--scenario", default="nominal", metavar="NAME",
                        help="packaged scenario or YAML path (default nominal). Flown to the end: nominal, variation, "
                             "disturbance_roll, disturbance_pitch, disturbance_within_authority; ending in a failsafe "
                             "(said before it starts): variation_stress, and the scenarios beyond the Solo's yaw "
                             "authority: disturbance, disturbance_yaw, disturbance_from_start, disturbance_pulse")
    parser.add_argument("--controller", default="astsm", metavar="NAME",
                        help=f"attitude controller: {LAW_HELP}; default astsm")
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
    from .control import law_class, law_preset
    from .scenarios import load_scenario

    if not (math.isfinite(args.speedup) and 0.1 <= args.speedup <= 100.0):
        raise ConfigError(f"--speedup {args.speedup}: must be within [0.1, 100]")
    if not (math.isfinite(args.takeoff_m) and 0.5 <= args.takeoff_m <= 20.0):
        raise ConfigError(f"--takeoff-m {args.takeoff_m}: must be within [0.5, 20] m")
    law_preset(law_class(args.controller))
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


def wait_landed(server, timeout_s: float, print_fn, period_s: float = 1.0) -> bool:
    """Wait (wall clock, bounded by ``timeout_s``) for the sim's landing after the hand-back, saying every
    ``period_s`` of wall time how high the vehicle still is and for how long it has been descending (simulated
    time). True once ArduCopter's land detector has fired."""
    def state():
        with server.lock:
            c = server.copter
            # NED down [m] -> height above the take-off point [m]; on the ground the sim puts down at exactly 0.0,
            # whose negation printed as "-0.00 m" (max(0.0, -0.0) is 0.0; the ground plane is never passed)
            return c.mode_name, max(0.0, -float(c.position_ned_m[2])), c.time_s
    t0 = state()[2]
    deadline = time.monotonic() + timeout_s
    while True:
        if server.wait_until(lambda c: c.landed, timeout_s=max(0.0, min(period_s, deadline - time.monotonic()))):
            mode, _, t = state()
            print_fn(f"landing ({mode}): landed {t - t0:.1f} s after the hand-back")
            return True
        if time.monotonic() >= deadline or not server.running:
            return False
        mode, height_m, t = state()
        print_fn(f"landing ({mode}): {height_m:.2f} m above the take-off point, {t - t0:.1f} s after the hand-back")


def fly_demo(args: argparse.Namespace, stop_event: threading.Event | None = None, print_fn=print) -> DemoResult:
    """Run the demo (see module docstring). ``stop_event`` set from anywhere = Ctrl-C."""
    from mavastsm_sim.sim_clock import ClockSpec

    from .lockstep_pair import LockstepPair
    from .telemetry import TelemetryBuffer

    scenario = _validate(args)
    stop_event = stop_event or threading.Event()
    log_dir = _log_dir(args)
    # always lockstep with turns (a loaded machine slows the flight down, never changes it), paced at --speedup
    pair = LockstepPair(scenario, sim=dict(physics_rate_hz=PHYSICS_RATE_HZ, lockstep_paced=True, speedup=args.speedup,
                                           sched_loop_rate_hz=CONTROL_RATE_HZ / 0.8))
    server = pair.server
    telemetry = TelemetryBuffer()
    dashboard = None
    wall0 = time.monotonic()
    sim0 = 0.0
    landed = disarmed = False
    summary = None
    try:
        pair.start()
        if not args.no_dashboard:
            from .dashboard.live_view import DashboardRunner

            dashboard = DashboardRunner(telemetry, on_quit=stop_event.set)
            dashboard.start()
        # process-wide settings: the command line's, not the library's (runtime_tuning)
        bridge = pair.start_bridge(telemetry, process_tuning=True, controller=args.controller, reference=scenario.reference,
                                   rate_hz=CONTROL_RATE_HZ, duration_s=scenario.duration_s, mode="GUIDED", arm=True,
                                   takeoff_alt_m=args.takeoff_m, on_exit="LAND", on_failsafe="LAND", log_dir=log_dir,
                                   overrides={"timing.stale_timeout_s": LOCKSTEP_STALE_TIMEOUT_S},
                                   print_fn=print_fn if args.no_dashboard else None)
        while bridge.wait(0.02) is None:
            pair.tuning.tick(bridge.state == "engaged")
            if stop_event.is_set():
                bridge.request_stop()
        summary = bridge.summary
        if dashboard is not None:  # the bridge is done: its last status would only repeat while the vehicle lands
            dashboard.stop()
            dashboard = None
        with server.lock:  # nobody answers ATTITUDE any more: pace the landing instead of waiting on the gate
            server.clock = ClockSpec("realtime", args.speedup)
        landed = wait_landed(server, 60.0 / min(args.speedup, 1.0), print_fn)
        disarmed = server.wait_until(lambda c: not c.armed, timeout_s=10.0 + 15.0 / args.speedup)
    finally:
        sim_t = server.sim_time_s if server.running else 0.0
        wall = time.monotonic() - wall0
        pair.stop(bridge_timeout_s=10.0)
        if dashboard is not None:
            dashboard.stop()
    return DemoResult(scenario=scenario.name, controller=args.controller, summary=summary, landed=landed,
                      disarmed=disarmed, sim_time_s=sim_t - sim0, wall_time_s=wall, interrupted=stop_event.is_set(),
                      log_dir=str(log_dir))


def run(args: argparse.Namespace) -> int:
    from .console_output import report_console

    console = report_console()
    stop_event = threading.Event()
    presses = {"n": 0}

    def on_signal():
        presses["n"] += 1
        if presses["n"] > 1:
            raise KeyboardInterrupt  # second Ctrl-C: stop now (the finally blocks still stop the sim)
        console.print("[bold]stopping: level hold, hand back with LAND, wait for touchdown (Ctrl-C again to abort)[/]")
        stop_event.set()

    name = Path(str(args.scenario)).stem
    beyond = authority_exceeded(args)
    with stopping_on_signals(on_signal):
        if beyond:
            console.print(f"scenario {name}: {BEYOND_AUTHORITY} ({'; '.join(beyond)}): {BEYOND_AUTHORITY_OUTCOME}", highlight=False)
        elif name in SCENARIO_OUTCOMES:
            console.print(f"scenario {name}: {SCENARIO_OUTCOMES[name]}", highlight=False)
        result = fly_demo(args, stop_event, print_fn=lambda text: console.print(text, highlight=False))
    from .state_types import FailsafeReason

    console.print(summary_table(result))
    for line in summary_lines(result):
        console.print(line, highlight=False)
    if beyond and result.summary.failsafe in (FailsafeReason.ENVELOPE_BREACH, FailsafeReason.COMMAND_SATURATION):
        console.print(f"{result.summary.failsafe.name}: the disturbance is {BEYOND_AUTHORITY} ({'; '.join(beyond)})", highlight=False)

    clean_end = result.summary.failsafe in (None, FailsafeReason.OPERATOR_STOP)
    return 0 if (result.landed and result.disarmed and clean_end) else 1
