"""``mavastsm connect URL``: parse options, build a Bridge, show the dashboard, handle signals.

Composition only: everything that flies lives in ``bridge_api`` / ``offboard_session``.
Exit codes: 0 normal end or operator stop (Ctrl-C, SIGTERM, q); 1 a failsafe ended the run;
2 bad options, bad config, no link, or the autopilot refused (one-line error).
"""

from __future__ import annotations

import argparse
import math
import sys

from ..config_loading import parse_overrides
from ..option_types import positive_number
from ..processes import stopping_on_signals

EPILOG = """\
Examples:
  mavastsm connect udpin:0.0.0.0:14550                       # wait for the pilot to select GUIDED and arm
  mavastsm connect udpout:127.0.0.1:5760 --mode GUIDED_NOGPS --arm --takeoff 2 --on-exit LAND
  mavastsm connect /dev/ttyACM0 --baud 921600 --controller stsm --reference hold --duration 30
  mavastsm connect tcp:127.0.0.1:5760 --set mapping.rate_time_constant_s=0.04 --set mu=0.03

Frames and units: body rates FRD [rad/s]; thrust 0..1 (ArduCopter: climb rate, 0.5 = hold, unless
GUID_OPTIONS bit 3; PX4: normalised collective). The bridge never arms or changes mode unless told.
"""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("url", metavar="URL", help="pymavlink connection: udpin:HOST:PORT (udp:), udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT, or a serial device")
    link = parser.add_argument_group("link")
    link.add_argument("--baud", "--baudrate", dest="baud", type=int, default=115200, help="serial baud rate [bit/s] (--baudrate as MAVProxy spells it); default 115200")
    link.add_argument("--target-system", type=int, default=None, metavar="N", help="autopilot sysid to control when several are heard [-]; default: the first autopilot heard")
    link.add_argument("--source-system", type=int, default=None, metavar="N", help="our sysid [-]; default: the vehicle's (compid is link.source_component, 191)")
    link.add_argument("--signing-key", metavar="FILE", default=None, help="MAVLink 2 signing key file (32 raw bytes, 64 hex chars, or a passphrase hashed with SHA-256)")
    from ..control import LAW_HELP

    ctl = parser.add_argument_group("control")
    ctl.add_argument("--controller", default="astsm", metavar="NAME", help=f"attitude controller: {LAW_HELP}; default astsm")
    ctl.add_argument("--controller-config", default=None, metavar="NAME|FILE", help="controller preset or YAML; default: astsm_mavlink for astsm (E2 with mu 0.06, alpha_m 5 for the loop through the autopilot), else the controller's own (your own law's: its default_config beside its module)")
    ctl.add_argument("--config", default=None, metavar="FILE", help="bridge YAML (limits, timing, mapping, thrust); default: packaged configs/bridge.yaml")
    ctl.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override: SECTION.KEY for the bridge config (mapping.method=integrate), other keys for the controller (mu=0.03); repeatable")
    ctl.add_argument("--reference", default="paper_steps", metavar="NAME|FILE", help="reference profile (paper_steps, hold, roll_sine, yaw_ramp, or YAML); yaw relative to the heading at engagement")
    ctl.add_argument("--vehicle", default=None, metavar="NAME|FILE", help="vehicle description: model inertia and the loop through its autopilot (configs/vehicle: solo, arducopter_sitl_quad, px4_sih_quadx, or a YAML such as --save-vehicle writes); default: px4_sih_quadx on PX4; on ArduPilot the description whose autopilot_tuning the vehicle reports, else arducopter_sitl_quad with the yaw tau_z its heading loop asks for (docs/bridge.md, 'Vehicle descriptions')")
    ctl.add_argument("--save-vehicle", default=None, metavar="FILE", help="at the end of a flight no failsafe ended, write the vehicle description it flew (loop numbers, and the autopilot tuning they were chosen at) to FILE; fly it again with --vehicle FILE")
    ctl.add_argument("--rate-hz", "--rate", dest="rate", type=positive_number("Hz"), default=None, metavar="HZ", help="ATTITUDE rate to request [Hz]; default timing.attitude_rate_hz (400)")
    ctl.add_argument("--duration-s", "--duration", dest="duration", type=positive_number("s"), default=None, metavar="S", help="engaged time on the vehicle clock [s]; default: the reference's duration")
    ctl.add_argument("--realtime-priority", type=int, default=None, metavar="N", help="run the control (reader) thread SCHED_FIFO at priority N (1-99, Linux; needs CAP_SYS_NICE or ulimit -r N) [-]; default timing.realtime_priority (0 = normal scheduling)")
    ctl.add_argument("--forever", action="store_true", help="run until stopped (Ctrl-C, SIGTERM, q), ignoring the reference duration")
    eng = parser.add_argument_group("engagement (nothing here happens unless asked)")
    eng.add_argument("--mode", type=_mode_name, choices=["GUIDED", "GUIDED_NOGPS", "OFFBOARD"], default=None, help="request this mode (pre-streaming setpoints first); default: wait for the pilot to select it")
    eng.add_argument("--arm", action="store_true", help="arm after the mode is set (needs --mode)")
    eng.add_argument("--takeoff-m", "--takeoff", dest="takeoff", type=positive_number("m"), default=None, metavar="ALT_M", help="bounded climb to ALT_M [m] at level attitude before the profile (needs --arm, climb-rate thrust)")
    eng.add_argument("--on-exit", type=_mode_name, choices=["ALT_HOLD", "LOITER", "LAND", "none"], default="none", help="mode to hand back to at the end/stop; none = stop sending, the autopilot's own timeout takes over (default)")
    eng.add_argument("--on-failsafe", type=_mode_name, choices=["ALT_HOLD", "LOITER", "LAND", "none"], default="none", help="mode to hand back to after a failsafe (after the level hold); default none")
    eng.add_argument("--reengage", action="store_true", help="resume (controller reset) when the pilot returns to the guided mode")
    eng.add_argument("--engage-timeout", type=positive_number("s"), default=120.0, metavar="S", help="without --mode: give up if the pilot has not selected the guided mode and armed within S [s]; default 120")
    out = parser.add_argument_group("output")
    out.add_argument("--log", default=None, metavar="DIR", help="write <DIR>/mavastsm-<time>.csv (one row per cycle) and .tlog (all traffic)")
    out.add_argument("--no-dashboard", action="store_true", help="plain status lines instead of the live dashboard")
    out.add_argument("--dashboard-hz", type=positive_number("Hz"), default=10.0, metavar="HZ", help="dashboard refresh rate [Hz]; default 10")


def options_from_args(args) -> "BridgeOptions":  # noqa: F821
    from .bridge_api import BridgeOptions

    return BridgeOptions(
        url=args.url, controller=args.controller, controller_config=args.controller_config, bridge_config=args.config,
        overrides=_overrides(args), reference=args.reference, vehicle_config=args.vehicle, rate_hz=args.rate,
        duration_s=math.inf if args.forever else args.duration, mode=args.mode, arm=args.arm, takeoff_alt_m=args.takeoff,
        on_exit=args.on_exit, on_failsafe=args.on_failsafe, reengage=args.reengage, log_dir=args.log, save_vehicle=args.save_vehicle,
        signing_key=args.signing_key, target_system=args.target_system, source_system=args.source_system, baud=args.baud,
        engage_timeout_s=args.engage_timeout, print_fn=lambda text: print(text, flush=True),
    )


def _mode_name(text: str) -> str:
    """Mode names as the autopilots spell them, whatever case was typed (``guided`` -> GUIDED); ``none`` stays."""
    return "none" if text.lower() == "none" else text.upper()


def _overrides(args) -> dict:
    """``--set`` items, plus the options that are shorthands for one bridge.yaml key."""
    over = parse_overrides(args.set)
    if args.realtime_priority is not None:
        over["timing.realtime_priority"] = args.realtime_priority
    return over


def run(args) -> int:
    from ..runtime_tuning import ProcessTuning
    from ..telemetry import TelemetryBuffer
    from .bridge_api import Bridge
    from .session.offboard_session import SessionState

    telemetry = TelemetryBuffer()
    bridge = Bridge(options_from_args(args), telemetry)  # ConfigError -> one line, exit 2 (cli.main)
    dashboard = None
    tuning = ProcessTuning(bridge.config.timing)  # process-wide settings: the command line's, not the library's
    with stopping_on_signals(bridge.request_stop):
        try:
            tuning.apply()
            bridge.start()
            try:
                from ..dashboard.live_view import DashboardRunner

                dashboard = DashboardRunner(telemetry, refresh_hz=args.dashboard_hz, on_quit=bridge.request_stop, plain=True if args.no_dashboard else None)
                dashboard.start()
            except Exception as exc:  # a broken view must never stop the flight
                print(f"mavastsm connect: dashboard unavailable ({exc}); continuing without it", file=sys.stderr)
                dashboard = None
            summary = None
            while summary is None:
                summary = bridge.wait(0.2)
                tuning.tick(bridge.state == SessionState.ENGAGED)
        finally:
            tuning.restore()
            if dashboard is not None:
                try:
                    dashboard.stop()
                except Exception as exc:  # the flight is over; a view that fails to close must not hide the summary
                    print(f"mavastsm connect: dashboard did not stop cleanly ({exc})", file=sys.stderr)
    print(summary.format(), flush=True)
    return summary.exit_code
