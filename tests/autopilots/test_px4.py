"""The bridge against genuine PX4 SITL (``pytest -m px4``; MAVASTSM_PX4, see conftest): the README command from a cold
start on SIH, PX4's stock vehicle; the hand-back and SIGKILL checks on SIH and on PX4 flying our Solo physics (the
``px4`` fixture boots both; test_px4_solo_physics.py holds the README command on the Solo to every bound)."""

from __future__ import annotations

import math
import re
import signal
import time

import pytest
from bridge_process import assert_no_traceback
from control_quality import ALPHA_BACK_MAX_S, CMD_AT_LIMIT_MAX_PCT, SETTLING_5PCT_MAX_S, band_entry, control_quality
from mavastsm_sim.genuine_observer import observe_cold

from mavastsm.readme_commands import readme_argv
from mavastsm_sim.genuine_sitl import wait_for

pytestmark = [pytest.mark.px4, pytest.mark.timeout(600)]

README_PX4 = readme_argv("px4")  # the README's command (mavastsm.readme_commands)
ALTITUDE_DRIFT_M = 0.3


def test_readme_px4_command_from_a_cold_start_takes_off_holds_altitude_and_lands(cold_px4, record, tmp_path):
    """Started within 5 s of PX4, as a newcomer does: the bridge waits for PX4's estimator (no ATTITUDE for about
    33 s), saying so with the elapsed time, then PX4's own takeoff, then OFFBOARD on the ACK, the paper's steps on
    the collective thrust PX4 hovers with (MPC_THR_HOVER) and the bridge's altitude hold, LAND accepted; exit 0;
    altitude within 0.3 m during the steps.

    Control quality: every axis reaches its 5 % band after its step within the settling bound (1.5 s roll/pitch,
    2.5 s yaw), from then on the commands stay off their limit, and alpha comes back within 2 s. When it last leaves the band (the
    settling time), overshoot and peak to peak are recorded, not asserted: SIH's attitude estimate alone moves
    0.57-0.84 deg on roll within one second against its true attitude, wider than the 0.5 deg band
    (benchmarks/px4_estimator_floor.py; docs/bridge.md, "Why the PX4 bounds are out of reach on SIH"). Until
    2026-12-06 this test asserted the settling time < 5 s: roll's was 3.86-4.45 s of the 4.5 s after its step
    (6 flights, 2 with the machine loaded), and CI failed on it once; roll first entered its band 0.50-0.76 s
    after the step. The at-limit share was then still counted from that settling time, so a flight whose roll
    estimate was outside the band at the run's end (t5 inf) read 100 % at the limit however its commands flew (CI
    failed on it once: roll in its band 0.59 s after the step, t5 inf, "100 %")."""
    v = cold_px4
    b = v.bridge(README_PX4 + ["--no-dashboard", "--log", str(tmp_path)])
    started_after_s = time.monotonic() - v.sitl.started_monotonic
    assert started_after_s < 5.0, started_after_s
    observe_cold(v)
    waited = b.wait_line(r"^waiting for PX4's estimator \(EKF2\) to have an attitude .*: no ATTITUDE yet … \d+ s", 60.0)
    flows = b.wait_line(r"^ATTITUDE flows after \d+ s", 120.0)
    record("PX4: README command from a cold start", bridge_started_after_px4_s=round(started_after_s, 1), first_wait_line=waited,
           attitude_line=flows)
    line = b.wait_line(r"^t=\d", 180.0)
    t_engaged = time.monotonic()
    rc = b.wait(120.0)
    t_end = time.monotonic()
    out = b.output
    assert rc == 0, out[-3000:]
    assert_no_traceback(out)
    assert "hover collective 0.500 from MPC_THR_HOVER" in out and "COM_OF_LOSS_T set 1 -> 0.2 s" in out, out[:3000]
    assert re.search(r"takeoff: holding \d\.\d\d m in LOITER", out), out[:3000]
    assert "end: duration complete; hand-back: LAND accepted" in out and "COM_OF_LOSS_T restored to 1 s" in out, out[-2000:]
    track = [(t, a) for t, a in v.observer.track.altitude if t_engaged <= t <= t_end - 1.0]
    alts = [a for _, a in track]
    worst_t, worst_a = max(track, key=lambda ta: abs(ta[1] - alts[0])) if track else (t_engaged, float("nan"))
    record("PX4: README command, altitude during the steps", min_m=round(min(alts), 2), max_m=round(max(alts), 2), samples=len(alts),
           worst_m=round(worst_a, 2), worst_after_first_status_s=round(worst_t - t_engaged, 1), run_s=round(t_end - t_engaged, 1))
    assert alts and max(alts) - min(alts) <= 2 * ALTITUDE_DRIFT_M and max(abs(a - alts[0]) for a in alts) <= ALTITUDE_DRIFT_M, \
        (line, [round(a, 2) for a in alts[::5]])
    csv = sorted(tmp_path.glob("*.csv"))[-1]
    measured = control_quality(csv)
    entered = band_entry(csv)
    record("PX4: README command, control quality (astsm, defaults)", after_band_entry=entered, **measured)
    v.wait_disarmed(90.0)
    for axis, m in measured.items():
        assert entered[axis]["to_band_s"] <= SETTLING_5PCT_MAX_S[axis], (axis, entered, measured)
        assert entered[axis]["at_limit_pct"] < CMD_AT_LIMIT_MAX_PCT, (axis, entered, measured)
        assert m["alpha_back_s"] <= ALPHA_BACK_MAX_S, (axis, measured)


def test_px4_hand_back_falls_back_when_altctl_is_refused(px4_vehicle):
    """ALT_HOLD on PX4 is ALTCTL, refused without RC or MANUAL_CONTROL: the bridge falls back to LOITER and says so."""
    v = px4_vehicle
    b = v.bridge(["connect", "udpin:0.0.0.0:14540", "--mode", "OFFBOARD", "--arm", "--takeoff", "5", "--on-exit", "ALT_HOLD",
                  "--reference", "hold", "--duration", "2", "--no-dashboard"])
    rc = b.wait(180.0)
    out = b.output
    assert rc == 0, out[-3000:]
    assert_no_traceback(out)
    assert re.search(r"hand-back: ALTCTL refused \(.*MAV_RESULT 1.*\); LOITER accepted", out), out[-2000:]
    # the ACK comes before the HEARTBEAT that shows the new mode: the observer hears it up to a second later (CI
    # once read OFFBOARD at the bridge's exit)
    try:
        wait_for(lambda: v.observer.mode_now() == ("LOITER", True), 10.0, "PX4 in LOITER after the hand-back", v.sitl)
    except TimeoutError:
        pytest.fail(f"PX4 not in LOITER within 10 s of the hand-back: {v.observer.track.modes[-4:]}")


def test_ctrl_c_during_px4s_own_takeoff_hands_back_and_the_vehicle_disarms(px4_vehicle):
    """Ctrl-C while PX4 climbs in its own TAKEOFF (start-up not finished, the vehicle armed by the bridge): the
    README's --on-exit LAND is applied, said, and the vehicle lands and disarms; before, it was left armed in
    whatever PX4 flew (a takeoff stalled on the ground stayed armed in TAKEOFF)."""
    v = px4_vehicle
    b = v.bridge(README_PX4 + ["--no-dashboard"])
    b.wait_line(r"^taking off \(TAKEOFF\): ", 180.0)
    t_stop = time.monotonic()
    b.signal(signal.SIGINT)
    rc = b.wait(30.0)
    out = b.output
    assert rc != 0 and "takeoff" in out.splitlines()[-1], out[-2000:]
    assert_no_traceback(out)
    assert "start-up failed with the vehicle armed: hand-back LAND accepted" in out, out[-2000:]
    assert "COM_OF_LOSS_T restored to 1 s" in out, out[-2000:]
    v.wait_disarmed(90.0)  # on the ground: PX4's TAKEOFF or hold would have kept it armed in the air
    modes = [m for t, m, _ in v.observer.track.modes if t >= t_stop]
    assert "LAND" in modes, v.observer.track.modes[-4:]


def test_px4_sigkill_never_flips_the_vehicle(px4_vehicle, record):
    """SIGKILL half-way into the roll step: PX4 holds the last body-rate setpoint for COM_OF_LOSS_T (0.2 s, set by
    the bridge), then its offboard-loss failsafe; the bound on every command keeps that survivable. Measured: max
    tilt 15.4-16.1 deg (9.7-9.8 deg when the README took off to 2 m); PX4 then switched to POSCTL and, with no RC,
    descended at up to 0.72 m/s (from 5 m down to 2.4-3.0 m within 4 s): its failsafe's choice (COM_OBL_RC_ACT),
    reported in docs/bridge.md, not a fall. Without the identification phase (the Solo-tuned PX4 is a stand-in and
    would fly it): the kill must land in the paper's -10 deg roll step, not in the phase's 5 deg doublet."""
    v = px4_vehicle
    ob = v.observer
    b = v.bridge(README_PX4 + ["--no-dashboard", "--set", "mapping.identify_in_flight=never"])
    b.wait_line(r"^t=\d", 180.0)
    deadline = time.monotonic() + 30.0
    while not (ob.track.attitude and math.degrees(ob.track.attitude[-1][1]) < -4.0):
        assert time.monotonic() < deadline and b.proc.poll() is None, b.output[-2000:]
        time.sleep(0.005)
    t_kill = time.monotonic()
    b.kill()
    time.sleep(4.0)
    tilt, alt = ob.max_tilt_deg(t_kill), ob.min_altitude_m(t_kill)
    track = [(t, a) for t, a in ob.track.altitude if t >= t_kill]
    sink = max(((a0 - a1) / (t1 - t0) for (t0, a0), (t1, a1) in zip(track, track[1:]) if t1 > t0), default=float("nan"))
    modes = [m for t, m, _ in ob.track.modes if t >= t_kill - 0.5]
    record("PX4: SIGKILL of the bridge during the roll step", max_tilt_deg=round(tilt, 1), min_altitude_m=round(alt, 2),
           max_sink_ms=round(sink, 2), modes_after=modes)
    assert tilt <= 30.0, f"max tilt {tilt:.1f} deg after SIGKILL"
    # the bridge's last setpoint governs for COM_OF_LOSS_T (0.2 s) and PX4's switch: no height lost in that second
    alt_1s = ob.min_altitude_m(t_kill, t_kill + 1.0)
    assert alt_1s >= 0.3 and alt_1s >= track[0][1] - 0.5, f"altitude down to {alt_1s:.2f} m within 1 s of the SIGKILL"
    # then PX4's own offboard-loss failsafe flies it (COM_OBL_RC_ACT, POSCTL by default; without RC it descends
    # under control): out of OFFBOARD, never falling
    assert modes and modes[-1] != "OFFBOARD", modes
    assert sink <= 1.5, f"sinking at {sink:.2f} m/s after SIGKILL: a fall, not PX4's controlled descent"
