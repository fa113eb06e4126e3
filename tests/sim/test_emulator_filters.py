"""What the ArduCopter emulation adds between the gyro and the motors to match genuine ArduCopter in closed loop
(docs/sim.md, "Closed-loop parity"): the IMU's gyro low-pass, the rate PIDs' target filter, and the fast loop's
order (rate controller before attitude controller)."""

from __future__ import annotations

import math

from mavastsm_sim.autopilot_emulator import FILTER_DEFAULTS, GyroFilter, RatePid
from mavastsm_sim.copter import SimulatedCopter


def _gain(f: GyroFilter, freq_hz: float, dt: float = 1.0 / 400.0) -> float:
    f.reset()
    n = 4000
    peak = 0.0
    for k in range(n):
        y = f.apply((math.sin(2.0 * math.pi * freq_hz * k * dt), 0.0, 0.0), dt)[0]
        if k > n // 2:
            peak = max(peak, abs(y))
    return peak


def test_gyro_filter_is_a_second_order_butterworth_at_its_cutoff():
    f = GyroFilter(20.0)
    assert abs(_gain(f, 1.0) - 1.0) < 1e-3
    assert abs(_gain(f, 20.0) - math.sqrt(0.5)) < 0.01  # -3 dB at the cutoff
    assert _gain(f, 80.0) < 0.08  # -40 dB/decade beyond it
    f.reset()
    assert f.apply((0.3, -0.2, 0.1), 0.0025) == (0.3, -0.2, 0.1) or all(
        abs(a - b) < 1e-12 for a, b in zip(f.apply((0.3, -0.2, 0.1), 0.0025), (0.3, -0.2, 0.1)))  # starts at rest
    assert GyroFilter(0.0).apply((1.0, 2.0, 3.0), 0.0025) == (1.0, 2.0, 3.0)  # 0 Hz = no filter


def test_rate_pid_target_filter_slows_a_target_step_like_a_first_order_lag():
    pid = RatePid()
    pid.kp, pid.fltt = 1.0, 20.0
    dt = 0.0025
    pid.update(0.0, 0.0, dt, False)
    out = [pid.update(1.0, 0.0, dt, False) for _ in range(4)]
    alpha = dt / (dt + 1.0 / (2.0 * math.pi * 20.0))
    assert abs(out[0] - alpha) < 1e-12 and abs(out[3] - (1.0 - (1.0 - alpha) ** 4)) < 1e-12


def test_filter_defaults_are_arducopters_and_the_table_wins():
    c = SimulatedCopter()
    ap = c.autopilot
    assert FILTER_DEFAULTS["INS_GYRO_FILTER"] == 20.0
    assert [p.fltt for p in ap.rate_pids] == [20.0, 20.0, 20.0]
    assert ap.rate_pids[2].flte == c.params.get("ATC_RAT_YAW_FLTE")  # the Solo's 3.15 Hz, from the table
    assert ap.rate_pids[0].fltd == c.params.get("ATC_RAT_RLL_FLTD")
    assert ap.gyro_filter.cutoff_hz == 20.0


def test_attitude_reports_the_filtered_gyro_as_arducopter_does():
    c = SimulatedCopter()
    c.set_mode(20)
    c.arm(force=True)
    for _ in range(400):  # climb a little, level
        c.handle_attitude_target(0x07, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.7)
        c.step(0.0025)
    roll_q = (math.cos(0.0873), math.sin(0.0873), 0.0, 0.0)  # 10 deg roll step
    for _ in range(40):
        c.handle_attitude_target(0x07, roll_q, (0.0, 0.0, 0.0), 0.5)
        c.step(0.0025)
    p_true = float(c.body_rates_rads[0])
    p_reported = c.attitude_sample()[3]
    assert p_reported == c.autopilot.gyro_filter.out[0]
    assert abs(p_true) > 0.1 and abs(p_reported - p_true) > 1e-3  # filtered, so it lags the true rate


def test_the_rate_loop_runs_on_the_previous_loops_rate_target():
    """ArduCopter's fast loop runs the rate controller before the attitude controller: a rate target set by the
    attitude controller in one loop reaches the rate PIDs in the next."""
    c = SimulatedCopter()
    c.set_mode(20)
    c.arm(force=True)
    for _ in range(400):
        c.handle_attitude_target(0x07, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.7)
        c.step(0.0025)
    ap = c.autopilot
    ap.att_target = (math.cos(0.0873), math.sin(0.0873), 0.0, 0.0)  # a 10 deg roll error from now on
    pid = ap.rate_pids[0]
    dt = 1.0 / ap.loop_rate_hz
    previous_target, filtered_before = ap.rate_target[0], pid.target
    ap._attitude_controller_run(c._meas_now(), dt)
    alpha = dt / (dt + 1.0 / (2.0 * math.pi * pid.fltt))
    assert abs(pid.target - (filtered_before + alpha * (previous_target - filtered_before))) < 1e-12
    assert ap.rate_target[0] > previous_target + 0.1  # the new target, for the next loop
