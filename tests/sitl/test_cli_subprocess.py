"""The real commands as separate processes: ``mavastsm sim`` + ``mavastsm connect``, and a bridge
killed with SIGKILL mid-flight (the vehicle's GUID_TIMEOUT fallback must level it; the bridge's logs
up to the last flush must be intact and parseable). Process groups are killed at teardown.
"""

from __future__ import annotations

import csv
import math
import os
import re
import signal
import time
from pathlib import Path

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402  (test code reads the tlog as a MAVLink peer would)

from mavastsm_sim.sim_clock import ClockSpec  # noqa: E402
from mavastsm_sim.vehicle_server import VehicleServer  # noqa: E402

pytestmark = pytest.mark.sitl

# conftest.mavastsm_argv cannot be imported (importlib mode); same definition:
import sys  # noqa: E402

MAVASTSM = [sys.executable, "-m", "mavastsm.cli"]
# Lockstep on a shared 2-core machine: the host-clock detectors are relaxed exactly as in-process
# (see mavastsm.lockstep_pair.IN_PROCESS_OVERRIDES). Real-time 400 Hz runs are not used here: with a load
# average of 6-7 on 2 cores a real-time sim delivered ATTITUDE in 50 ms bursts (198-240 Hz) and the
# bridge rightly tripped STALE_ATTITUDE, which would make the tests measure the machine.
LOCKSTEP_SETS = ["--set", "timing.stale_timeout_s=0.5", "--set", "timing.overrun_cycles=100000"]


def read_csv_log(path: Path) -> tuple[list[str], list[list[str]], str]:
    """Header, complete rows (as many fields as the header) and any partial trailing text."""
    text = path.read_text()
    lines = text.split("\n")
    tail = lines.pop()  # "" when the file ends with a newline
    reader = list(csv.reader(lines))
    header, rows = reader[0], reader[1:]
    return header, rows, tail


def _csv_has_rows(folder: Path) -> bool:
    """Whether the bridge's CSV in ``folder`` holds at least one complete data row yet."""
    files = list(folder.glob("*.csv"))
    return bool(files) and len(read_csv_log(files[0])[1]) > 0


def read_tlog(path: Path) -> list:
    conn = mavutil.mavlink_connection(str(path), robust_parsing=True)
    try:
        msgs = []
        while (m := conn.recv_match()) is not None:
            if m.get_type() != "BAD_DATA":
                msgs.append(m)
        return msgs
    finally:
        conn.close()


def test_real_sim_and_connect_commands_fly_the_paper_steps(spawn, tmp_path, sitl_record):
    sim = spawn(*MAVASTSM, "sim", "--listen", "127.0.0.1:0", "--lockstep", "--set", "sched_loop_rate_hz=500",
                "--scenario", "nominal")
    first = sim.stdout.readline()
    match = re.search(r"udp 127\.0\.0\.1:(\d+)", first)
    assert match, f"sim did not print its port: {first!r}"
    port = int(match.group(1))
    t0 = time.monotonic()
    bridge = spawn(*MAVASTSM, "connect", f"udpout:127.0.0.1:{port}", "--mode", "GUIDED", "--arm", "--takeoff", "0.5",
                   "--on-exit", "LAND", "--no-dashboard", "--log", str(tmp_path), *LOCKSTEP_SETS)
    out, err = bridge.communicate(timeout=120)
    wall_s = time.monotonic() - t0
    assert bridge.returncode == 0, f"connect exited {bridge.returncode}: {err[-2000:]}"
    assert "end: duration complete" in out and "hand-back: LAND accepted" in out, out[-2000:]
    sim.send_signal(signal.SIGTERM)
    sim_out, sim_err = sim.communicate(timeout=20)
    assert sim.returncode == 0, sim_err[-2000:]
    header, rows, tail = read_csv_log(next(tmp_path.glob("*.csv")))
    assert tail == "" and all(len(r) == len(header) for r in rows)
    msgs = read_tlog(next(tmp_path.glob("*.tlog")))
    setpoints = [m for m in msgs if m.get_type() == "SET_ATTITUDE_TARGET"]
    last_mode = [m.custom_mode for m in msgs if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1
                 and m.get_srcComponent() == 1][-1]  # the vehicle's, not the bridge's own (1/191)
    sitl_record("real `mavastsm sim` + `mavastsm connect` processes (lockstep)", "flies the steps, exits 0, LAND "
                "hand-back, CSV and tlog complete", category="check", wall_s=round(wall_s, 1), csv_rows=len(rows),
                tlog_messages=len(msgs), setpoints=len(setpoints), final_mode=last_mode)
    assert len(rows) >= 2000  # 5 s at 400 Hz
    assert len(setpoints) >= 2000 and last_mode == 9  # LAND


def test_bridge_sigkilled_midflight_guid_timeout_levels_vehicle_and_logs_are_intact(spawn, tmp_path, sitl_record):
    """Lockstep while the bridge flies; killed once roll -10 / pitch +10 are held. Then nobody answers
    the lockstep gate any more, so the sim is switched to paced time (x4) to play out GUID_TIMEOUT."""
    server = VehicleServer(listen=("127.0.0.1", 0), clock="lockstep", speedup=4.0, lockstep_timeout_s=0.05,
                           sched_loop_rate_hz=500.0, seed=1)
    server.start()
    try:
        bridge = spawn(*MAVASTSM, "connect", f"udpout:127.0.0.1:{server.port}", "--mode", "GUIDED", "--arm",
                       "--takeoff", "0.5", "--duration", "60", "--no-dashboard", "--log", str(tmp_path), *LOCKSTEP_SETS)
        assert server.wait_until(lambda c: c.mode_name == "GUIDED" and c.armed and -c.position_ned_m[2] > 0.45, 60.0), \
            "bridge never took off"
        tilt_deg = lambda c: math.degrees(max(abs(c.euler_rad[0]), abs(c.euler_rad[1])))  # noqa: E731
        # kill once both steps are held (roll -10, pitch +10): the vehicle is visibly not level
        held = server.wait_until(lambda c: abs(c.euler_rad[0]) > math.radians(8) and abs(c.euler_rad[1]) > math.radians(8), 30.0)
        if held:
            t_held = server.sim_time_s
            server.wait_until(lambda c: c.time_s >= t_held + 0.5, 10.0)
            # and until a flush (every timing.log_flush_s of *wall* time) has put engaged rows in the CSV: lockstep
            # can fly the whole takeoff and both steps in under 0.5 s of wall time, and a kill before the first
            # flush would leave nothing to check the rows or the loss bound against
            deadline = time.monotonic() + 20.0
            while not _csv_has_rows(tmp_path) and time.monotonic() < deadline and bridge.poll() is None:
                server.wait_until(lambda c, t=server.sim_time_s: c.time_s >= t + 0.05, 1.0)
        tilt_at_kill = server.call(tilt_deg)
        if not held or bridge.poll() is not None:
            bridge.kill()
            out, err = bridge.communicate(timeout=10)
            pytest.fail(f"bridge did not fly the steps (exit {bridge.returncode}): {out[-1500:]} {err[-1500:]}")
        # the timeout in force: the bridge shortened it at preflight (limits.setpoint_timeout_s) and a SIGKILL leaves it so
        guid_timeout_s = server.call(lambda c: c.params.get("GUID_TIMEOUT"))
        os.killpg(bridge.pid, signal.SIGKILL)
        with server.lock:  # as mavastsm.demo does once the bridge has gone: pace instead of gating
            server.clock = ClockSpec("realtime", 4.0)
            t_kill_wall, t_kill = time.time(), server.sim_time_s
        bridge.wait(10)
        # sample (sim time, tilt) until GUID_TIMEOUT + 3 s of sim time have passed; "levelled" = the time
        # after which the tilt stays below 1 deg (a vehicle still turning at the last rate passes level)
        track = []
        deadline = time.monotonic() + 60.0
        while server.sim_time_s < t_kill + guid_timeout_s + 3.0 and time.monotonic() < deadline:
            track.append(server.call(lambda c: (c.time_s, tilt_deg(c))))
            server.wait_until(lambda c, t=track[-1][0]: c.time_s >= t + 0.01, 1.0)
        last_tilted = max((t for t, tilt in track if tilt >= 1.0), default=t_kill)
        assert track and track[-1][1] < 1.0, "vehicle never levelled"
        t_level = last_tilted
        max_tilt_after_kill = max(tilt for _, tilt in track)
        alt_m = server.call(lambda c: -c.position_ned_m[2])
        mode = server.call(lambda c: c.mode_name)
    finally:
        server.stop()
    header, rows, tail = read_csv_log(next(tmp_path.glob("*.csv")))
    complete = [r for r in rows if len(r) == len(header)]
    assert complete, "no complete CSV row after the engaged flight: no flush reached the file before the kill"
    partial = len(rows) - len(complete)
    times = [float(r[header.index("vehicle_time_s")]) for r in complete]
    for r in complete:  # every complete row parses: numbers or empty/text enums only where the header says so
        float(r[header.index("vehicle_time_s")])
    msgs = read_tlog(next(tmp_path.glob("*.tlog")))
    last_tlog_s = max(m._timestamp for m in msgs)
    last_cmd = [m for m in msgs if m.get_type() == "SET_ATTITUDE_TARGET"][-1]  # what the vehicle keeps flying
    # the CSV has no host clock: map its last row to host time through the tlog's stamp of that ATTITUDE
    # (in lockstep vehicle time runs faster than the wall clock, and the flush promise is in wall time)
    attitude_host_s = {m.time_boot_ms: m._timestamp for m in msgs
                       if m.get_type() == "ATTITUDE" and m.get_srcSystem() == 1 and m.get_srcComponent() == 1}
    csv_last_host_s = attitude_host_s.get(int(round(times[-1] * 1000)))
    sitl_record("bridge SIGKILLed mid-flight", f"vehicle keeps the last command until GUID_TIMEOUT ({guid_timeout_s:g} s), "
                "then levels and holds altitude in GUIDED; CSV and tlog intact up to the last flush (<= 1 s lost)",
                tilt_at_kill_deg=round(tilt_at_kill, 1), max_tilt_after_kill_deg=round(max_tilt_after_kill, 1),
                levelled_after_s=round(t_level - t_kill, 2), mode_after=mode,
                last_logged_command={"type_mask": last_cmd.type_mask, "rates_rads": [round(last_cmd.body_roll_rate, 3),
                                     round(last_cmd.body_pitch_rate, 3), round(last_cmd.body_yaw_rate, 3)]},
                altitude_after_m=round(alt_m, 2), csv_rows=len(complete), csv_partial_rows=partial + (1 if tail else 0),
                csv_lost_vehicle_s=round(t_kill - times[-1], 3),
                csv_lost_wall_s=round(t_kill_wall - csv_last_host_s, 3) if csv_last_host_s else None, tlog_messages=len(msgs),
                tlog_last_before_kill_s=round(t_kill_wall - last_tlog_s, 3))
    assert tilt_at_kill > 5.0, "vehicle was level when the bridge died: the levelling check would be vacuous"
    assert guid_timeout_s - 0.1 <= t_level - t_kill <= guid_timeout_s + 2.0
    assert mode == "GUIDED" and alt_m > 0.3
    assert partial <= 1 and len(complete) > 0  # how many rows depends on how much wall time the flight took
    assert times == sorted(times)
    assert csv_last_host_s is not None, "the CSV's last row matches no ATTITUDE in the tlog"
    assert t_kill_wall - csv_last_host_s <= 1.0, "CSV lost more than 1 s (wall) at the kill"
    assert t_kill_wall - last_tlog_s <= 1.0, "tlog lost more than 1 s (wall) at the kill"
