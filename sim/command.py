"""``mavastsm sim`` / ``python -m sim``: run the MAVLink-speaking simulated 3DR Solo until stopped.

A composition root only: parse options, build a :class:`VehicleServer`, run it, stop cleanly on Ctrl-C or
SIGTERM (exit 0). Bad options give a one-line error and exit status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import logging
import math
import sys
import threading

from mavastsm.config_loading import parse_overrides
from mavastsm.errors import ConfigError
from mavastsm.option_types import positive_number
from mavastsm.processes import stopping_on_signals

from .arducopter_profile import DEFAULT_PROFILE, PROFILES_FOLDER, ArduCopterProfile, load_profile, packaged_profiles
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


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``sim`` options (units in every help text)."""
    parser.epilog = ("Behaves on the wire like the ArduCopter its --profile describes (sysid 1, compid 1, MAVLink 2). "
                     "Streams are off until requested, like ArduCopter. Examples: 'mavastsm sim' then 'mavastsm connect "
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
    vehicle.add_argument("--home", type=_home, default=None, metavar="LAT_DEG,LON_DEG,ALT_M",
                         help="home position reported in GPS messages (default ArduPilot SITL's CMAC) [deg, deg, m AMSL]")
    profile = parser.add_argument_group(
        "autopilot profile: which ArduCopter the sim emulates, every wire and emulator habit in one file "
        "(docs/sim.md, 'Sim profiles')")
    listed = "; ".join(f"{name}: {summary}" for name, summary in packaged_profiles().items())
    profile.add_argument("--profile", metavar="NAME|FILE", default=None,
                         help=f"a packaged profile or a profile YAML (it may 'extends:' a packaged one); default "
                              f"{DEFAULT_PROFILE}. Packaged ({PROFILES_FOLDER}): {listed}".replace("%", "%%"))
    habits = ", ".join(f.name for f in dataclasses.fields(ArduCopterProfile) if f.name != "name")
    profile.add_argument("--set", metavar="KEY=VALUE", action="append", default=None,
                         help=f"change one habit of the profile (repeatable), checked like the file's value: {habits}; "
                              "units, ranges and meaning: 'mavastsm check-config sim_profiles/"
                              f"{DEFAULT_PROFILE}'. E.g. --set sched_loop_rate_hz=500 (400 Hz streams), "
                              "--set position_estimate=false (no GPS: use GUIDED_NOGPS)")
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
        from .genuine_pair import run_pair

        if args.profile is not None or args.set:
            raise ConfigError("--profile and --set shape the in-repo sim's imitation of ArduCopter; --autopilot "
                              f"{args.autopilot} runs the genuine firmware")

        return run_pair(args)
    from .mavlink_vehicle import DEFAULT_HOME
    from .vehicle_server import VehicleServer

    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    logging.getLogger("mavastsm_sim").setLevel(logging.DEBUG if args.verbose else logging.INFO)
    if args.out:
        targets = list(args.out)
    else:
        targets = [] if args.listen else [parse_udp_endpoint(DEFAULT_OUT, "--out")]
    profile = load_profile(args.profile, parse_overrides(args.set))
    try:
        server = VehicleServer(vehicle_config=args.vehicle_config, scenario=args.scenario, seed=args.seed,
                               physics_rate_hz=args.physics_rate_hz, noise=args.noise,
                               clock="lockstep" if args.lockstep else "realtime", speedup=args.speedup,
                               lockstep_timeout_s=args.lockstep_timeout_ms / 1000.0,
                               listen=args.listen, target=targets, signing_key=args.signing_key,
                               signing_state=args.signing_state, home=args.home or DEFAULT_HOME, verbose=args.verbose,
                               profile=profile)
    except OSError as exc:
        raise ConfigError(f"cannot open the UDP socket: {exc}") from None
    stop = threading.Event()
    with stopping_on_signals(stop.set):  # before the banner: a supervisor may signal as soon as it reads it
        _announce_and_run(server, targets, profile, stop, args)
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


def _run_until_stopped(server, stop: threading.Event, args) -> None:
    """Wait until ``stop`` (a signal, the caller), the server's end, or ``--duration-s`` of simulated time."""
    while not stop.is_set() and server.running:
        wait_s = 0.05
        if args.duration_s is not None:
            remaining_s = args.duration_s - server.sim_time_s
            if remaining_s <= 0:
                return
            wait_s = min(wait_s, max(remaining_s / args.speedup, 0.002))
        stop.wait(wait_s)


def _announce_and_run(server, targets, profile, stop: threading.Event, args) -> None:
    """Say what runs where, start the server and run it until ``stop``, its end or ``--duration-s``; stop it."""
    host, port = server.address
    outs = ", ".join(f"{h}:{p}" for h, p in targets) or "nobody until a peer talks"
    print(f"mavastsm sim: ArduCopter {profile.firmware.text}-like Solo (profile {profile.name}, {profile.parameter_set} "
          "parameters" + (f", armable after {profile.prearm_delay_s:g} s" if profile.prearm_delay_s > 0 else "")
          + f") sysid {server.vehicle.sysid} compid {server.vehicle.compid} on "
          f"udp {host}:{port}, sending to {outs}; clock {server.clock.mode} x{server.clock.speedup:g}"
          + (", signing required" if server.vehicle.signing.enabled else ""), flush=True)
    # Everything alive now (pymavlink's dialect, NumPy, the vehicle) lives until exit: move it to the
    # permanent generation so a full collection no longer scans it (measured in real time: 22 ms, which
    # sent 8 ATTITUDEs late in one burst; the loop itself makes next to no cyclic garbage).
    gc.freeze()
    server.start()
    try:
        _run_until_stopped(server, stop, args)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
