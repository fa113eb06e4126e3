"""Sim profiles as data (issue 29): every habit of the emulated ArduCopter in one profile file, defined once.

``mavastsm sim --profile NAME|FILE [--set KEY=VALUE]``; the copter, its emulator and its MAVLink face read the one
``ArduCopterProfile`` they are built with. The behaviour of each habit is tested in test_wire_parity.py.
"""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from mavastsm.config_loading import packaged_config_dir, read_yaml
from mavastsm_sim.arducopter_profile import (DEFAULT_PROFILE, PROFILES_FOLDER, ArduCopterProfile, load_profile,
                                             packaged_profiles)

REPO = Path(__file__).resolve().parents[2]
HABITS = [f.name for f in dataclasses.fields(ArduCopterProfile) if f.name != "name"]
FOLDER = packaged_config_dir() / PROFILES_FOLDER


def test_the_default_profile_defines_every_habit_once_and_the_others_only_change_values():
    base = read_yaml(FOLDER / f"{DEFAULT_PROFILE}.yaml")
    assert "extends" not in base and sorted(base["habits"]) == sorted(HABITS)
    assert all({"value", "unit", "doc", "source"} <= set(spec) for spec in base["habits"].values())
    for path in FOLDER.glob("*.yaml"):
        if path.stem == DEFAULT_PROFILE:
            continue
        data = read_yaml(path)
        assert "extends" in data, f"{path.name} must extend another profile, so every habit stays defined once"
        assert all(set(spec) <= {"value", "source"} for spec in data["habits"].values()), path.name
        load_profile(path.stem)  # resolves and validates


def test_the_sim_reads_no_habit_through_hasattr_or_getattr():
    """The emulator and the MAVLink face read their profile; nothing pushes a habit in by probing for an attribute."""
    probed = []
    for path in (REPO / "sim").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("hasattr", "getattr"):
                names = {n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
                if names & {*HABITS, "set_field_elevation", "wire", "profile"}:
                    probed.append(f"{path.name}:{node.lineno}")
    assert not probed, probed


def test_the_copter_its_emulator_and_its_mavlink_face_share_one_profile():
    from mavastsm_sim.copter import SimulatedCopter
    from mavastsm_sim.mavlink_vehicle import MavlinkVehicle

    profile = load_profile("arducopter-4.7-sitl", {"sched_loop_rate_hz": 500.0, "parameter_set": "sitl-quad"})
    copter = SimulatedCopter(profile=profile, field_elevation_m=584.0)
    vehicle = MavlinkVehicle(copter, lambda datagram: None)
    assert copter.autopilot.profile is profile and vehicle.profile is profile
    assert copter.params.get("SCHED_LOOP_RATE") == 500.0 and copter.params.get("ATC_ANG_RLL_P") == 4.5
    assert round(copter.autopilot.compensation_gain, 3) == 1.058  # density compensation at SITL's 584 m
    assert vehicle.firmware.text == "4.7.0-dev" and vehicle.loop_tick_streams


def test_sim_help_lists_the_profiles_and_no_habit_flag():
    out = subprocess.run([sys.executable, "-m", "sim", "--help"], cwd=REPO, capture_output=True, text=True,
                         timeout=60).stdout
    text = " ".join(out.split())
    assert all(name in text for name in packaged_profiles()), text
    flags = [f"--{habit.replace('_', '-')}" for habit in HABITS] + ["--like-genuine-sitl", "--params",
                                                                   "--no-position-estimate", "--param-read-interval-ms",
                                                                   "--command-latency-ms"]
    assert not [flag for flag in flags if flag in out], out


def test_a_profile_file_of_ones_own_extends_a_packaged_one(tmp_path):
    mine = tmp_path / "my_bench.yaml"
    mine.write_text("description: 4.6 release, armable after 1 s\nextends: arducopter-4.7-sitl\nhabits:\n"
                    "  firmware_version: {value: \"4.6.2\"}\n  prearm_delay_s: {value: 1.0}\n", encoding="utf-8")
    run = subprocess.run([sys.executable, "-m", "sim", "--profile", str(mine), "--set", "parameter_set=sitl-quad",
                          "--listen", "127.0.0.1:0", "--lockstep", "--duration-s", "0.1"], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert "ArduCopter 4.6.2-like Solo (profile my_bench, sitl-quad parameters, armable after 1 s)" in run.stdout


@pytest.mark.parametrize("options, named", [
    (["--profile", "arducopter-9.9"], "arducopter-9.9"),
    (["--set", "prearm_delay=5"], "habits.prearm_delay"),
    (["--set", "sched_loop_rate_hz=5000"], "habits.sched_loop_rate_hz"),
    (["--set", "sched_loop_rate_hz=[500, 600]"], "habits.sched_loop_rate_hz"),
    (["--set", "stream_timing=bursty"], "habits.stream_timing"),
    (["--set", "parameter_set=px4"], "habits.parameter_set"),
    (["--set", "firmware_version=4.7"], "MAJOR.MINOR.PATCH"),
    (["--profile", "arducopter-4.7-sitl", "--autopilot", "arducopter"], "--profile"),
])
def test_an_unknown_profile_or_a_bad_habit_is_one_line_and_exit_2(capsys, options, named):
    from mavastsm.cli import main

    status = main(["sim", "--listen", "127.0.0.1:0", "--duration-s", "0.1", *options])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and named in err, err


def test_a_bad_key_in_a_profile_file_is_one_line_and_exit_2(tmp_path, capsys):
    from mavastsm.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("extends: arducopter-4.5-quick\nhabits:\n  takeoff_delay_s: {value: 2.0}\n", encoding="utf-8")
    status = main(["sim", "--listen", "127.0.0.1:0", "--profile", str(bad)])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "habits.takeoff_delay_s" in err, err
