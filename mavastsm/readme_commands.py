"""The README's commands that tests and benchmarks run, written here once, as a user types them.

``tests/test_readme_commands.py`` holds each line to README.md (it must be one of its command lines, character for
character), so a README edit that changes a command fails until this table follows it, and the code that flies
"the README's command" flies what the README says. ``readme_argv(name)`` gives the arguments after ``mavastsm``.
"""

from __future__ import annotations

import shlex

README_COMMANDS = {
    # "Against ArduPilot SITL" (genuine ArduCopter in CI: tests/autopilots, benchmarks/genuine_autopilots.py)
    "arducopter": "mavastsm connect udpin:0.0.0.0:14550 --mode GUIDED_NOGPS --arm --takeoff 2 --on-exit LAND",
    # "PX4" (genuine PX4 SITL with SIH)
    "px4": "mavastsm connect udpin:0.0.0.0:14540 --mode OFFBOARD --arm --takeoff 5 --on-exit LAND",
    # "Against the in-repo simulator", terminal 2
    "sim": "mavastsm connect udpout:127.0.0.1:14560 --mode GUIDED_NOGPS --arm --takeoff 2 --on-exit LAND --log logs/",
    # "Quick start": the whole test suite (the CI script runs it: tests/test_packaging.py)
    "test_suite": 'python3 -m venv .venv && . .venv/bin/activate && pip install ".[test]" && pytest',
}


def readme_argv(name: str) -> list[str]:
    """The arguments of the README's ``mavastsm`` command ``name`` (a key of README_COMMANDS), after ``mavastsm``."""
    argv = shlex.split(README_COMMANDS[name])
    if argv[0] != "mavastsm":
        raise ValueError(f"README command {name!r} is not a mavastsm command: {README_COMMANDS[name]}")
    return argv[1:]
