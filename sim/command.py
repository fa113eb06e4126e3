"""``mavastsm sim`` / ``python -m sim``: run the MAVLink-speaking simulated 3DR Solo until stopped.

A composition root only: parse options, build a :class:`VehicleServer`, run it, stop cleanly on Ctrl-C or
SIGTERM (exit 0). Bad options give a one-line error and exit status 2.
"""

from __future__ import annotations

import argparse
import gc
import logging
import math
import signal
import sys
import threading

from mavastsm.cli import positive_number
from mavastsm.errors import ConfigError

from .udp_transport import parse_udp_endpoint

DEFAULT_OUT = "udp:127.0.0.1:14550"


def _endpoint(what: str):
    def convert(text: str) -> tuple[str, int]:
        try:
            return parse_udp_endpoint(text, what)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix(f"{what}: ")) from None  # argparse names the option
    return convert


def _home(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        lat, lon, alt = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--home {text!r} must be LAT_DEG,LON_DEG,ALT_M") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180 and math.isfinite(alt)):
        raise argparse.ArgumentTypeError(f"--home {text!r}: latitude/longitude out of range")
    return lat, lon, alt


def _non_negative(unit: str, limit: float):
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and 0.0 <= value <= limit):
            raise argparse.ArgumentTypeError(f"{text!r} must be a number of {unit} within 0..{limit:g}")
        return value
    return convert


_non_negative_ms = _non_negative("ms", 10_000.0)
_non_negative_s = _non_negative("s", 3600.0)
WIRE_OPTIONS = (("like_genuine_sitl", False, "--like-genuine-sitl"), ("firmware_version", None, "--firmware-version"),
                ("stream_timing", None, "--stream-timing"), ("parameter_set", "solo", "--params"),
                ("param_index_65535", None, "--param-index-65535"),
                ("param_read_interval_ms", None, "--param-read-interval-ms"),
                ("unsolicited_param_values", None, "--unsolicited-param-values"),
                ("prearm_delay_s", None, "--prearm-delay-s"), ("takeoff_timing", None, "--takeoff-timing"),
                ("command_latency_ms", None, "--command-latency-ms"),
                ("density_compensation", None, "--density-compensation"))


def wire_from_args(args: argparse.Namespace):
    """The ``ArduCopterWire`` the options ask for: ``--like-genuine-sitl`` (or the sim's defaults), then each given
    option on top. ConfigError (one line) for a bad version."""
    from .mavlink_vehicle import ArduCopterWire

    base = ArduCopterWire.genuine_sitl() if getattr(args, "like_genuine_sitl", False) else ArduCopterWire()
    given = {
        "firmware_version": getattr(args, "firmware_version", None),
        "stream_timing": getattr(args, "stream_timing", None),
        "param_index_65535": getattr(args, "param_index_65535", None),
        "param_read_interval_s": None if getattr(args, "param_read_interval_ms", None) is None
        else args.param_read_interval_ms / 1000.0,
        "unsolicited_param_values": getattr(args, "unsolicited_param_values", None),
        "prearm_delay_s": getattr(args, "prearm_delay_s", None),
        "takeoff_timing": getattr(args, "takeoff_timing", None),
        "command_latency_s": None if getattr(args, "command_latency_ms", None) is None
        else args.command_latency_ms / 1000.0,
        "density_compensation": getattr(args, "density_compensation", None),
    }
    fields = {**base.__dict__, **{name: value for name, value in given.items() if value is not None}}
    return ArduCopterWire(**fields)


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``sim`` options (units in every help text)."""
    parser.epilog = ("Behaves on the wire like ArduCopter 4.2+ (sysid 1, compid 1, MAVLink 2). Streams are off "
                     "until requested, like ArduCopter. Examples: 'mavastsm sim' then 'mavastsm connect "
                     "udp:127.0.0.1:14550'; 'mavastsm sim --listen 127.0.0.1:14560' then 'mavproxy.py --master "
                     "udpout:127.0.0.1:14560'.")
    link = parser.add_argument_group("link")
    link.add_argument("--out", metavar="udp:HOST:PORT", action="append", type=_endpoint("--out"),
                      help=f"send to this address like SITL's udpclient (repeatable); default {DEFAULT_OUT} "
                           "when --listen is not given")
    link.add_argument("--listen", metavar="HOST:PORT", type=_endpoint("--listen"), default=None,
                      help="bind here and answer every peer heard in the last 10 s (server mode); "
                           "use port 0 for an ephemeral port (printed at start)")
    link.add_argument("--signing-key", metavar="FILE", default=None,
                      help="require MAVLink 2 signing with the key in FILE (32 raw bytes, 64 hex digits, or a "
                           "passphrase hashed with SHA-256 like MAVProxy's 'signing setup')")
    link.add_argument("--signing-state", metavar="FILE", default=None,
                      help="keep the signing timestamp in FILE across runs, as ArduPilot does (saved every 30 s; "
                           "the next run starts 60 s past it, so frames from before a restart cannot be replayed)")
    clock = parser.add_argument_group("clock")
    clock.add_argument("--speedup", type=positive_number("x real time"), default=1.0,
                       help="simulated seconds per wall second [-]; default 1 (real time)")
    clock.add_argument("--lockstep", action="store_true",
                       help="deterministic lockstep: after each ATTITUDE wait for the controller's "
                            "SET_ATTITUDE_TARGET (bounded by --lockstep-timeout-ms); paced by --speedup while "
                            "ATTITUDE is not streaming")
    clock.add_argument("--lockstep-timeout-ms", type=positive_number("ms"), default=100.0,
                       help="longest wall-clock wait for an answer in lockstep [ms]; default 100")
    clock.add_argument("--duration-s", "--duration", dest="duration_s", type=positive_number("s"), default=None,
                       help="stop after this much simulated time [s]; default: run until Ctrl-C/SIGTERM")
    vehicle = parser.add_argument_group("vehicle")
    vehicle.add_argument("--vehicle-config", metavar="NAME|PATH", default=None,
                         help="vehicle YAML (default: the packaged 3DR Solo, configs/vehicle/solo.yaml)")
    vehicle.add_argument("--scenario", metavar="NAME|PATH", default=None,
                         help="scenario YAML with disturbances / parameter variation (e.g. nominal, disturbance, "
                              "variation)")
    vehicle.add_argument("--seed", type=int, default=0, help="seed for sensor noise and gusts [-]; default 0")
    vehicle.add_argument("--noise", action="store_true", help="add seeded sensor noise to attitude and rates")
    vehicle.add_argument("--physics-rate-hz", type=positive_number("Hz"), default=1000.0,
                         help="physics integration rate; also the grid messages are sent on [Hz]; default 1000")
    vehicle.add_argument("--sched-loop-rate-hz", type=positive_number("Hz"), default=None,
                         help="set parameter SCHED_LOOP_RATE; message rates are capped at 80%% of it "
                              "(ArduCopter default 400 Hz -> 320 Hz) [Hz]")
    vehicle.add_argument("--no-position-estimate", action="store_true",
                         help="model a vehicle without GPS/EKF origin (indoors): arming in GUIDED fails with "
                              "'PreArm: Need Position Estimate'; use GUIDED_NOGPS (mode 20)")
    vehicle.add_argument("--home", type=_home, default=None, metavar="LAT_DEG,LON_DEG,ALT_M",
                         help="home position reported in GPS messages (default ArduPilot SITL's CMAC) [deg, deg, m AMSL]")
    wire = parser.add_argument_group(
        "wire parity with genuine ArduCopter (docs/sim.md; defaults: the sim's long-standing behaviour)")
    wire.add_argument("--like-genuine-sitl", action="store_true",
                      help="every habit measured on ArduCopter 4.7 SITL at once: --firmware-version 4.7.0-dev "
                           "--stream-timing loop-ticks --param-index-65535 --param-read-interval-ms 100 "
                           "--unsolicited-param-values --prearm-delay-s 25 --takeoff-timing arducopter "
                           "--command-latency-ms 3 --density-compensation (each can still be given to change it)")
    wire.add_argument("--firmware-version", metavar="VERSION", default=None,
                      help="ArduCopter version to claim, e.g. 4.5.7 (default, official release) or 4.7.0-dev: fills "
                           "AUTOPILOT_VERSION (release type 0xFF official, 0x00 dev) and decides SET_MESSAGE_INTERVAL "
                           "faster than the loop: >= 4.6 DENIED with a STATUSTEXT, older capped silently")
    wire.add_argument("--stream-timing", choices=("auto", "even", "loop-ticks"), default=None,
                      help="loop-ticks: ArduCopter's scheduler (whole-ms intervals sent from SCHED_LOOP_RATE ticks: 333 "
                           "Hz from 400 Hz comes as 2,3,2,3,5 ms gaps); even: exact intervals; auto (default): "
                           "loop-ticks for versions >= 4.6")
    wire.add_argument("--params", dest="parameter_set", choices=("solo", "sitl-quad"), default="solo",
                      help="parameter set: solo (Solo_AC35 gains, default) or sitl-quad (genuine SITL's default-quad "
                           "attitude controller: ATC_ACCEL_R/P/Y_MAX 110000/110000/27000 cdeg/s^2, ATC_ANG_*_P 4.5, ...)")
    wire.add_argument("--param-index-65535", action="store_const", const=True, default=None,
                      help="PARAM_VALUE answering a read by name or a PARAM_SET carries param_index 65535, as ArduPilot's")
    wire.add_argument("--param-read-interval-ms", type=_non_negative_ms, default=None, metavar="MS",
                      help="answer PARAM_REQUEST_READ one per MS [ms] (ArduCopter: 100); default 0: at once")
    wire.add_argument("--unsolicited-param-values", action="store_const", const=True, default=None,
                      help="announce STAT_RUNTIME / STAT_FLTTIME by PARAM_VALUE every 30 s, also in flight, as ArduPilot")
    wire.add_argument("--prearm-delay-s", type=_non_negative_s, default=None, metavar="S",
                      help="pre-arm checks fail for S simulated seconds after boot with ArduCopter's reasons ('Arm: Gyros "
                           "inconsistent', 'AHRS: waiting for home', 'Need Position Estimate'; genuine SITL: ~25) [s]; "
                           "default 0: armable at once")
    wire.add_argument("--takeoff-timing", choices=("instant", "arducopter"), default=None,
                      help="arducopter: motors stopped 2 s after arming (ARMING_DELAY_SEC), spooled up to MOT_SPIN_MIN "
                           "over MOT_SPOOL_TIME (0.5 s), climb controller started from zero throttle, jerk-limited climb: "
                           "lift-off ~3.5 s after the arm ACK, as genuine SITL; instant (default): lifts as soon as a "
                           "climb is asked for")
    wire.add_argument("--command-latency-ms", type=_non_negative("ms", 1000.0), default=None, metavar="MS",
                      help="act on a SET_ATTITUDE_TARGET MS [ms] of simulated time after it arrives, as genuine SITL's "
                           "bursty loop does (3 ms on the Solo physics); default 0: at the next autopilot loop")
    wire.add_argument("--density-compensation", action="store_const", const=True, default=None,
                      help="scale the motors' roll/pitch/yaw/throttle demands by 1/(air density ratio) at the home "
                           "altitude as ArduCopter does (x1.058 at 584 m); off by default (no hover-throttle learning)")
    parser.add_argument("--verbose", action="store_true",
                        help="log every class of bad input and a counter summary every 5 s")
    genuine = parser.add_argument_group("genuine autopilot")
    genuine.add_argument("--autopilot", choices=("sim", "arducopter", "px4"), default="sim",
                         help="sim: the in-repo ArduCopter emulation (default); arducopter: genuine ArduCopter SITL "
                              "(tuned by configs/arducopter/solo.parm) flying this Solo physics over ArduPilot's JSON "
                              "SITL protocol (udp 9002); connect with 'mavastsm connect udpin:0.0.0.0:14550'; px4: "
                              "genuine PX4 SITL (configs/px4/solo.params) flying it over PX4's simulator interface "
                              "(tcp 4560, lockstep, a Solo's sensors); connect with 'mavastsm connect udpin:0.0.0.0:14540'. "
                              "--scenario, --seed, --noise, --vehicle-config, --speedup and --duration-s apply")
    genuine.add_argument("--arducopter", metavar="PATH", default=None,
                         help="ArduCopter's SITL binary or its folder (default: $MAVASTSM_ARDUCOPTER)")
    genuine.add_argument("--px4", metavar="PATH", default=None,
                         help="PX4's build folder with bin/px4 and etc/ (default: $MAVASTSM_PX4)")


def run(args: argparse.Namespace) -> int:
    """Run the simulator until Ctrl-C, SIGTERM or --duration-s; 0 on a clean stop."""
    if getattr(args, "autopilot", "sim") in ("arducopter", "px4"):
        from .arducopter_pair import run_pair
        from .px4_pair import run_px4_pair

        for attr, default, option in WIRE_OPTIONS:
            if getattr(args, attr, default) != default:
                raise ConfigError(f"{option} shapes the in-repo sim's imitation of ArduCopter; --autopilot {args.autopilot} "
                                  "runs the genuine firmware")

        return run_pair(args) if args.autopilot == "arducopter" else run_px4_pair(args)
    from .mavlink_vehicle import DEFAULT_HOME
    from .vehicle_server import VehicleServer

    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    logging.getLogger("mavastsm_sim").setLevel(logging.DEBUG if args.verbose else logging.INFO)
    if args.out:
        targets = list(args.out)
    else:
        targets = [] if args.listen else [parse_udp_endpoint(DEFAULT_OUT, "--out")]
    try:
        server = VehicleServer(vehicle_config=args.vehicle_config, scenario=args.scenario, seed=args.seed,
                               physics_rate_hz=args.physics_rate_hz, noise=args.noise,
                               clock="lockstep" if args.lockstep else "realtime", speedup=args.speedup,
                               lockstep_timeout_s=args.lockstep_timeout_ms / 1000.0,
                               listen=args.listen, target=targets, sched_loop_rate_hz=args.sched_loop_rate_hz,
                               signing_key=args.signing_key, signing_state=args.signing_state, home=args.home or DEFAULT_HOME,
                               verbose=args.verbose,
                               copter_options={"position_estimate": False} if args.no_position_estimate else None,
                               wire=wire_from_args(args), parameter_set=args.parameter_set)
    except OSError as exc:
        raise ConfigError(f"cannot open the UDP socket: {exc}") from None
    stop = threading.Event()

    def on_signal(signum, frame):  # noqa: ARG001
        stop.set()

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, on_signal)
    host, port = server.address
    outs = ", ".join(f"{h}:{p}" for h, p in targets) or "nobody until a peer talks"
    wire = server.vehicle.wire
    print(f"mavastsm sim: ArduCopter {server.vehicle.firmware.text}-like Solo ({args.parameter_set} parameters"
          + (f", armable after {wire.prearm_delay_s:g} s" if wire.prearm_delay_s > 0 else "")
          + f") sysid {server.vehicle.sysid} compid {server.vehicle.compid} on "
          f"udp {host}:{port}, sending to {outs}; clock {server.clock.mode} x{server.clock.speedup:g}"
          + (", signing required" if server.vehicle.signing_enabled else ""), flush=True)
    # Everything alive now (pymavlink's dialect, NumPy, the vehicle) lives until exit: move it to the
    # permanent generation so a full collection no longer scans it (measured in real time: 22 ms, which
    # sent 8 ATTITUDEs late in one burst; the loop itself makes next to no cyclic garbage).
    gc.freeze()
    server.start()
    try:
        while not stop.is_set() and server.running:
            wait_s = 0.05
            if args.duration_s is not None:
                remaining_s = args.duration_s - server.sim_time_s
                if remaining_s <= 0:
                    break
                wait_s = min(wait_s, max(remaining_s / args.speedup, 0.002))
            stop.wait(wait_s)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    counters = server.counters
    print(f"mavastsm sim: stopped at t={server.sim_time_s:.1f} s simulated; bad input "
          f"{counters['bad_input_total']}; lockstep timeouts {counters['lockstep_timeouts']}; real time: "
          f"{counters['realtime_late_attitudes']} ATTITUDE sent > 1 ms late, {counters['realtime_overruns']} re-bases", flush=True)
    if server.error is not None:
        print(f"mavastsm sim: error: simulation loop failed: {server.error!r}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (``python -m sim``)."""
    parser = argparse.ArgumentParser(prog="python -m sim",
                                     description="MAVLink-speaking simulated 3DR Solo (stands in for ArduCopter)")
    configure(parser)
    args = parser.parse_args(argv)
    try:
        return run(args)
    except ConfigError as exc:
        print(f"python -m sim: error: {exc}", file=sys.stderr)
        return 2
