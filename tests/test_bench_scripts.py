"""``mavastsm bench`` runs scripts from the repository's ``benchmarks/`` folder: in a source checkout it must find
them (a stale path once made ``bench --quick`` report ``.../mavastsm/benchmarks/sim_realtime_factor.py not found``)."""

from __future__ import annotations

from pathlib import Path

from mavastsm import bench

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_bench_finds_the_simulator_benchmark_script_of_the_source_checkout():
    assert bench.SOURCE_BENCHMARKS_DIR == REPO_ROOT / "benchmarks"
    assert bench.SIM_RTF_SCRIPT.is_file(), bench.SIM_RTF_SCRIPT


def test_every_benchmark_script_the_bench_names_exists():
    named = [value for value in vars(bench).values() if isinstance(value, Path) and value.suffix == ".py"]
    assert named, "the bench names no benchmark script"
    assert all(path.is_file() for path in named), [str(p) for p in named if not p.is_file()]


def _benchmark_module(name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"bench_{name}", REPO_ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_cycle_profile_puts_each_sample_in_the_stage_of_its_innermost_project_frame():
    """benchmarks/cycle_profile.py (issue 30's breakdown): py-spy's raw lines -> stage counts; the innermost frame a
    rule names decides, a library frame below it does not, and the thread prefix is not a frame."""
    cp = _benchmark_module("cycle_profile")
    reader = ("thread (7): mavlink-reader;Thread.run (threading.py:982);MavlinkLink._reader_loop "
              "(mavastsm/bridge/link/mavlink_link.py:546);MavlinkLink._deliver (mavastsm/bridge/link/mavlink_link.py:608);"
              "OffboardSession.on_attitude (mavastsm/bridge/session/offboard_session.py:192)")
    raw = [
        reader + ";ControlCycle.step (mavastsm/bridge/cycle/control_cycle.py:305);AstsmController.update "
                 "(mavastsm/control/astsm.py:195);clip (numpy/core/fromnumeric.py:2169) 5",
        reader + ";SessionOutput.send_cycle (mavastsm/bridge/session/session_output.py:125);MavlinkLink.send_setpoint "
                 "(mavastsm/bridge/link/mavlink_link.py:724);MavlinkLink._send (mavastsm/bridge/link/mavlink_link.py:680);"
                 "MAVLink.send (pymavlink/dialects/v20/ardupilotmega.py:100) 3",
        reader + ";SessionOutput.record (mavastsm/bridge/session/session_output.py:137);FlightLog.append "
                 "(mavastsm/bridge/record/flight_log.py:200);format_row (mavastsm/bridge/record/flight_log.py:86) 2",
        "thread (7): mavlink-reader;Thread.run (threading.py:982);MavlinkLink._reader_loop "
        "(mavastsm/bridge/link/mavlink_link.py:526);mavfile.select (pymavlink/mavutil.py:343) 4",
        "thread (9): other;Thread.run (threading.py:982);wait (threading.py:320) 1",
        "not a sample line",
    ]
    lines = __import__("collections").Counter()
    counts, total = cp.stage_shares(raw, lines)
    assert total == 15
    assert counts == {"law (ASTSM)": 5, "encode, sign and send": 3, "flight log and .tlog": 2, "receive and decode": 4,
                      cp.OTHER: 1}
    assert lines["AstsmController.update (mavastsm/control/astsm.py:195)"] == 5
    assert lines[cp.OTHER] == 1


def test_the_codec_benchmark_times_frames_the_bridge_accepts():
    """benchmarks/codec_cost.py: every timed parse is of a frame the bridge's parser accepts (a signed frame parsed
    twice would be a replay, refused on a cheaper path), and each row is a positive time."""
    cc = _benchmark_module("codec_cost")
    rows = dict(cc.measure(calls=20))
    assert len(rows) == 6 and all(us > 0 for us in rows.values()), rows
    assert any(name.startswith("parse") and name.endswith("(signed)") for name in rows), rows
