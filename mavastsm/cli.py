"""Command-line entry point ``mavastsm``: a composition root only (parse, load, build, run).

Each subcommand lives in the module that owns its job and exposes two functions:
``configure(parser: argparse.ArgumentParser) -> None`` and ``run(args) -> int``.
They are imported lazily so ``mavastsm --help`` stays fast and one broken optional part
cannot take the others down.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__
from .errors import ConfigError, Interrupted, LinkError, OffboardRejected

# name -> (module, one-line help). Order is the order shown in --help.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("mavastsm.demo", "start the simulated Solo and the bridge, fly the paper's steps, print a summary"),
    "connect": ("mavastsm.bridge.command", "run the offboard attitude bridge against a vehicle at URL"),
    "sim": ("mavastsm_sim.command", "run the MAVLink-speaking simulated 3DR Solo (stands in for ArduCopter)"),
    "simulate": ("mavastsm.offline.commands", "offline torque-level simulation of one or more controllers on a scenario"),
    "reproduce": ("mavastsm.offline.commands", "run every controller on every paper scenario; claims C1-C8 PASS/FAIL"),
    "sweep": ("mavastsm.sweep.command", "robustness maps: sweep disturbances, inertia, noise, loop and link over a grid, offline or over MAVLink"),
    "bench": ("mavastsm.bench", "measure bridge latency, throughput and sim speed against pymavlink and MAVSDK loops"),
    "proxy": ("mavastsm_sim.impairment_proxy", "UDP relay that injects loss, delay, jitter, duplication, reordering, corruption, outages"),
    "plot": ("mavastsm.flight_plot", "figures of one flight from its --log CSV (or .tlog): angles, errors, sigma/alpha, rates, thrust, failsafes"),
    "identify": ("mavastsm.identify", "identify the loop through the autopilot's rate controller from a --log flight: effectiveness, delay, tau"),
    "check-config": ("mavastsm.config_commands", "validate a config file and print its parameters with units"),
    "list-controllers": ("mavastsm.config_commands", "list the registered attitude controllers"),
}


def _one_line_error(command: str):
    """argparse's error for a subcommand: one line naming the command and the option, and where the help is
    (argparse's own prints the whole usage block first)."""
    def error(message: str):
        print(f"mavastsm {command}: error: {message} (see 'mavastsm {command} --help')", file=sys.stderr)
        sys.exit(2)

    return error


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with ``only`` (a subcommand name) only that subcommand's module is imported and
    configured, the others are listed with their one-line help (what ``mavastsm --help`` and one command need)."""
    parser = argparse.ArgumentParser(
        prog="mavastsm",
        description=(
            "Offboard attitude control over MAVLink with the Adaptive Super-Twisting Sliding Mode "
            "controller (Hoang & Pham 2018). Units: SI inside; angles on the command line in degrees "
            "where the option name says _deg."
        ),
        epilog="Run 'mavastsm COMMAND --help' for the options of one command.",
    )
    parser.add_argument("--version", action="version", version=f"mavastsm {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.error = _one_line_error(name)
        p.set_defaults(_module=module_name, _command=name)
        if only is not None and name != only:
            continue
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:  # a part not built yet must not hide the others
            if exc.name and (exc.name == module_name or module_name.startswith(exc.name + ".")):
                p.set_defaults(_missing=str(exc))
                continue
            raise
        configure = getattr(module, f"configure_{name.replace('-', '_')}", None) or module.configure
        configure(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv if not a.startswith("-")), "")  # the subcommand (top-level options take no value)
    parser = build_parser(only=chosen if chosen in SUBCOMMANDS else "")
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    if getattr(args, "_missing", None):
        print(f"mavastsm {args.command}: not available in this build ({args._missing})", file=sys.stderr)
        return 2
    module = importlib.import_module(args._module)
    run = getattr(module, f"run_{args._command.replace('-', '_')}", None) or module.run
    try:
        return int(run(args) or 0)
    except (ConfigError, LinkError, OffboardRejected) as exc:
        print(f"mavastsm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Interrupted as exc:
        print(f"mavastsm {args.command}: stopped: {exc}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
