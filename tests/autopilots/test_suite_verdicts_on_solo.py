"""The loopback suite keeps its meaning (issue 16, item 5): scenarios of the SITL suite that are about safety, flown
on genuine ArduCopter (solo.parm) + our Solo physics, must end with the verdict the suite asserts on our sim
(``pytest -m ardupilot``; MAVASTSM_ARDUCOPTER, see conftest). One ArduCopter boot for the module; each test flies the
README's bridge command, and leaves the vehicle landed and disarmed for the next.

The table of every scenario, the sim's verdict, genuine's and why they differ where they do is in docs/sim.md,
"Does the loopback suite keep its meaning on genuine ArduCopter?".
"""

from __future__ import annotations

import glob
import importlib.util
import math
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from bridge_process import README_ARDUCOPTER, assert_no_traceback
from mavastsm_sim.genuine_observer import boot_arducopter_solo_physics
from pymavlink import mavutil

from mavastsm.bridge.record.flight_log import read_flight_rows
from mavastsm.state_types import FailsafeReason
from mavastsm_sim.genuine_sitl import wait_for

pytestmark = [pytest.mark.ardupilot, pytest.mark.timeout(300)]

STEP_HELD_DEG = 8.0  # the paper steps hold roll -10 deg and pitch +10 deg: the bridge is visibly flying them


def _benchmark(name: str):
    """benchmarks/NAME.py as a module (the genuine-flight helpers of paper_on_genuine and sim_parity)."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / f"{name}.py"
    sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location(f"{name}_for_verdicts", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def solo(arducopter_build):
    """One boot for every test here; the physics keeps the scenario torque clock parked ("held") until a test starts
    it at the bridge's engagement, as benchmarks/paper_on_genuine.py does (no torque is set unless a test sets one)."""
    pg = _benchmark("paper_on_genuine")
    with boot_arducopter_solo_physics(arducopter_build, fast_prearm=True, disturbance_start="held",
                                      attitude_history_s=pg.ATTITUDE_HISTORY_S) as v:
        yield v


@pytest.fixture
def vehicle(solo):
    yield solo
    solo.after_test()


def _attitude_since(v, t0: float) -> list:
    with v.observer._lock:
        return [a for a in v.observer.track.attitude if a[0] >= t0]


def _steps_held(v, t0: float) -> bool:
    att = _attitude_since(v, t0)
    return bool(att) and abs(math.degrees(att[-1][1])) > STEP_HELD_DEG and abs(math.degrees(att[-1][2])) > STEP_HELD_DEG


def _tilt_deg(sample) -> float:
    _, roll, pitch, _ = sample
    return math.degrees(math.acos(max(-1.0, min(1.0, math.cos(roll) * math.cos(pitch)))))


def test_bridge_sigkilled_midflight_guid_timeout_levels_the_vehicle_as_on_the_sim(vehicle):
    """tests/sitl/test_cli_subprocess.py on our sim: the bridge killed while the paper's steps are held, the vehicle keeps
    the last command until GUID_TIMEOUT, then levels (tilt < 1 deg for good within GUID_TIMEOUT + 2 s) and holds its
    altitude in the guided mode. ArduCopter: ``ModeGuided::angle_control_run``'s timeout (level, zero climb)."""
    with tempfile.TemporaryDirectory(prefix="mavastsm-verdict-kill-") as logs:
        t0 = time.monotonic()
        b = vehicle.bridge(README_ARDUCOPTER + ["--no-dashboard", "--log", logs, "--duration-s", "60"])
        wait_for(lambda: _steps_held(vehicle, t0), 60.0, "bridge flying the paper steps", vehicle.sitl)
        time.sleep(0.5)
        tilt_at_kill = _tilt_deg(_attitude_since(vehicle, t0)[-1])
        b.proc.send_signal(signal.SIGKILL)
        t_kill = time.monotonic()
        b.wait(10.0)
        guid_timeout_s = _guid_timeout_left_by_the_bridge(logs)
        time.sleep(guid_timeout_s + 3.0)
        track = _attitude_since(vehicle, t_kill)
        last_tilted = max((t for t, *rpy in track if _tilt_deg((t, *rpy)) >= 1.0), default=t_kill)
        mode, armed = vehicle.observer.mode_now()
        alt_m = vehicle.observer.altitude_now()
    print(f"tilt at kill {tilt_at_kill:.1f} deg; levelled {last_tilted - t_kill:.2f} s after the kill "
          f"(GUID_TIMEOUT {guid_timeout_s:g} s); {mode}, armed {armed}, altitude {alt_m:.2f} m")
    assert tilt_at_kill > 5.0, "vehicle was level when the bridge died: the levelling check would be vacuous"
    assert _tilt_deg(track[-1]) < 1.0, "vehicle never levelled"
    assert guid_timeout_s - 0.1 <= last_tilted - t_kill <= guid_timeout_s + 2.0, (last_tilted - t_kill, guid_timeout_s)
    assert mode == "GUIDED_NOGPS" and armed and alt_m > 0.3, (mode, armed, alt_m)


def _guid_timeout_left_by_the_bridge(logs: str) -> float:
    """GUID_TIMEOUT [s] in force after a SIGKILL: the last PARAM_VALUE of it in the bridge's tlog (the bridge shortens
    it at preflight, limits.setpoint_timeout_s, and a killed bridge cannot restore it)."""
    tlogs = sorted(glob.glob(f"{logs}/*.tlog"))
    assert tlogs, f"no tlog in {logs}"
    m = mavutil.mavlink_connection(tlogs[-1])
    value = None
    while (msg := m.recv_match(type="PARAM_VALUE")) is not None:
        if msg.param_id == "GUID_TIMEOUT":
            value = msg.param_value
    assert value is not None, "the bridge never read or set GUID_TIMEOUT"
    return float(value)


def test_pilot_leaves_guided_bridge_stops_commanding_at_once_as_on_the_sim(vehicle):
    """tests/sitl/test_peer_faults.py on our sim: a ground station switches the vehicle out of the guided mode while the
    bridge flies; the bridge sends no setpoint after the first HEARTBEAT in the new mode, ends with MODE_CHANGED and
    does not switch back. ALT_HOLD here (the sim test uses LOITER; the Solo physics flight is GUIDED_NOGPS, and what is
    tested is the bridge's reaction to any non-guided mode)."""
    with tempfile.TemporaryDirectory(prefix="mavastsm-verdict-mode-") as logs:
        t0 = time.monotonic()
        b = vehicle.bridge(README_ARDUCOPTER + ["--no-dashboard", "--log", logs, "--duration-s", "60"])
        wait_for(lambda: _steps_held(vehicle, t0), 60.0, "bridge flying the paper steps", vehicle.sitl)
        vehicle.observer.set_mode("ALT_HOLD")
        wait_for(lambda: vehicle.observer.mode_now()[0] == "ALT_HOLD", 10.0, "ALT_HOLD", vehicle.sitl)
        rc = b.wait(30.0)
        out = b.output
        time.sleep(1.0)
        mode_at_end = vehicle.observer.mode_now()[0]
        after = _setpoints_after_mode_heartbeat(logs, "ALT_HOLD")
    assert_no_traceback(out)
    assert FailsafeReason.MODE_CHANGED.value in out, out[-2000:]
    assert rc == 1, out[-2000:]
    assert after == 0, f"{after} setpoints after the first ALT_HOLD HEARTBEAT"
    assert mode_at_end == "ALT_HOLD"


def _setpoints_after_mode_heartbeat(logs: str, mode: str) -> int:
    """SET_ATTITUDE_TARGET the bridge sent after the vehicle's first HEARTBEAT in ``mode`` (its tlog, in order)."""
    tlogs = sorted(glob.glob(f"{logs}/*.tlog"))
    assert tlogs, f"no tlog in {logs}"
    m = mavutil.mavlink_connection(tlogs[-1])
    seen, after = False, 0
    while (msg := m.recv_match(type=["HEARTBEAT", "SET_ATTITUDE_TARGET"])) is not None:
        if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1 and msg.get_srcComponent() == 1:
            seen = seen or mavutil.mode_string_v10(msg) == mode
        elif msg.get_type() == "SET_ATTITUDE_TARGET" and seen:
            after += 1
    assert seen, f"the tlog has no HEARTBEAT in {mode}"
    return after


def test_astsm_under_the_papers_roll_torque_completes_without_leaving_the_envelope_as_on_the_sim(vehicle):
    """tests/bridge/test_bridge_on_sim.py on our sim: 0.5 N m on roll from 4 s of the paper steps, bridge defaults: the
    run completes (no failsafe) and the roll peak stays inside the 35 deg envelope (sim 30.3 deg). Flown with
    benchmarks/paper_on_genuine.py's torque alignment (the torque starts at the bridge's engagement)."""
    pg = _benchmark("paper_on_genuine")
    sp = _benchmark("sim_parity")
    clock = pg.genuine_plant_clock(vehicle)
    sp.set_torques(clock, "disturbance_roll")
    try:
        with tempfile.TemporaryDirectory(prefix="mavastsm-verdict-torque-") as logs:
            row, _ = pg.fly_bridge(vehicle.sitl.netns, clock, "arducopter", "astsm", "disturbance_roll", Path(logs),
                                   lambda: vehicle.wait_disarmed(90.0))
    finally:
        clock.disturbances.torque_events = []
        clock.park()
    print(f"end {row['end']}; roll peak {row['roll']['dist_peak_deg']:.1f} deg, steady {row['roll']['steady_deg']:.2f} deg")
    assert row["exit"] == 0 and row["end"].startswith("duration complete"), row["end"]
    assert row["roll"]["dist_peak_deg"] < 35.0, row["roll"]



def test_astsm_rides_out_the_within_authority_torques_with_smaller_peaks_than_arducopter_alone(vehicle):
    """Issue 25: ``disturbance_within_authority`` (0.5 / 0.5 / 0.2 N m from 4 s of the paper steps) flown by the README
    command with the bridge's defaults (the Solo's description: roll/pitch commands integrated, M9), then by ArduCopter alone (its own attitude
    controller, the same reference) in the same boot. With the earlier default (M2) this ended in ENVELOPE_BREACH
    (measured 2026-12-03: peaks 28.0 / 25.0 / 75.6 deg). Now the flight completes, every axis peaks at most 0.8 x
    ArduCopter alone's (measured at the 4 m take-off, 2026-12-06: 7.8-7.9 / 8.9-9.0 / 31.7-31.9 deg against
    24.1-26.3 / 14.6-14.8 / 64.6-86.9 deg) and roll and pitch are back inside 0.5 deg within 1.5 s of the onset
    (0.51-0.55 / 0.71-0.78 s; ArduCopter alone never). The take-off climbs past ArduCopter's EKF3 heading reset
    (benchmarks/paper_on_genuine.py TAKEOFF_M): at 1.5 m that reset came mid-profile in some boots. Yaw's recovery (the issue asks
    3 s) is not met by the defaults and not asserted: the heading trim M10 (opt-in) brings it back in 3.9-5.6 s,
    docs/bridge.md."""
    pg = _benchmark("paper_on_genuine")
    sp = _benchmark("sim_parity")
    clock = pg.genuine_plant_clock(vehicle)
    scenario = "disturbance_within_authority"
    sp.set_torques(clock, scenario)
    t_start = time.monotonic()
    try:
        with tempfile.TemporaryDirectory(prefix="mavastsm-verdict-m9-") as logs:
            row, samples = pg.fly_bridge(vehicle.sitl.netns, clock, "arducopter", "astsm", scenario, Path(logs),
                                         lambda: vehicle.wait_disarmed(90.0))
            trace = _flight_trace(row.get("csv"))
        sp.set_torques(clock, scenario)
        alone, _ = pg.fly_arducopter_alone(vehicle, clock, scenario)
    finally:
        clock.disturbances.torque_events = []
        clock.park()
    axes = ("roll", "pitch", "yaw")
    print(f"end {row['end']}; peaks {[row[a]['dist_peak_deg'] for a in axes]} deg, recovery "
          f"{[row[a]['recovery_s'] for a in axes]} s; ArduCopter alone {[alone[a]['dist_peak_deg'] for a in axes]} deg, "
          f"landing: {alone.get('landing')}")
    # what an intermittent CI failure needs to be explained (issue 25's note): how each flight's torque was aligned,
    # the bridge's counters, the physics' steps and the vehicle's speed-up
    print(f"bridge alignment {row.get('alignment')}; counters {row.get('counters')}; ArduCopter alone alignment "
          f"{alone.get('alignment')}; physics {vehicle.sitl.companions[0].counters.summary()}; "
          f"SIM_SPEEDUP {vehicle.observer.track.params.get('SIM_SPEEDUP')}")
    sc = pg.load_scenario(scenario)
    for i, a in enumerate(axes):  # what each axis did after the onset, half a second a line (pytest cuts long messages)
        print(pg.after_onset_windows(samples, sc.reference, pg.disturbance_onset_s(sc), i))
    with vehicle.observer._lock:  # what ArduCopter said meanwhile (an EKF yaw reset, a failsafe), host s after the start
        texts = [f"{t - t_start:+.1f} s {x}" for t, x in vehicle.observer.track.texts if t >= t_start]
    print(f"altitude {row.get('altitude')}\nArduCopter said: {texts}\nthe bridge's flight every 0.25 s:\n{trace}")
    assert row["exit"] == 0 and row["end"].startswith("duration complete"), row["end"]
    assert "error" not in alone, alone
    for a in axes:
        assert row[a]["dist_peak_deg"] <= 0.8 * alone[a]["dist_peak_deg"], (a, row[a], alone[a])
    for a in ("roll", "pitch"):
        assert row[a]["recovery_s"] <= 1.5, (a, row[a])


TRACE_COLUMNS = "t_s err_roll_deg err_pitch_deg err_yaw_deg p_cmd_rads q_cmd_rads r_cmd_rads alpha_roll alpha_pitch " \
                "u_roll_nm u_pitch_nm altitude_m latency_us"


def _flight_trace(csv_path, every_s: float = 0.25) -> str:
    """The engaged rows of a bridge flight log (read by ``flight_log.read_flight_rows``), one every ``every_s`` [s]
    of time since engagement, for a failure's captured output: what the vehicle, the law and the command did,
    without the CSV (CI keeps only the log)."""
    if not csv_path or not Path(csv_path).is_file():
        return "no flight log"
    rows = [r for r in read_flight_rows(csv_path) if r.phase == "engaged"]
    if not rows:
        return "no engaged rows"
    t0, next_t, lines = rows[0].sample.vehicle_time_s, 0.0, [TRACE_COLUMNS]
    for r in rows:
        c = r.sample
        if c.vehicle_time_s - t0 >= next_t:
            next_t += every_s
            cells = [*np.degrees(c.error_rad), *c.commanded_rates_rads, *c.alpha[:2], *c.u_nm[:2], r.altitude_m,
                     c.latency_s * 1e6]
            lines.append(f"{c.vehicle_time_s - t0:.2f} " + " ".join(f"{x:.4g}" for x in cells))
    return "\n".join(lines)
