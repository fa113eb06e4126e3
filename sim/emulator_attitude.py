"""The emulated ArduCopter's attitude controller (``AC_AttitudeControl``, ``AC_AttitudeControl_Multi``).

Body-rate inputs shaped by ATC_ACCEL_R/P/Y_MAX and integrated into an attitude-target quaternion; quaternion inputs
shaped by ``input_shaping_angle`` (ATC_INPUT_TC); the angle P loop (``sqrt_controller``) plus rate feed-forward; the
rate PIDs (``sim/emulator_filters.py``), run *before* the angle loop in each loop as ArduCopter's fast loop does.
Split out of ``ArduCopterEmulator`` (issue 29); the module docstring of ``sim/autopilot_emulator.py`` says what is
modelled and what is simplified.
"""

from __future__ import annotations

import math

from .attitude_math import (
    q_conj,
    q_from_euler,
    q_from_rotation_vector,
    q_mul,
    q_normalize,
    q_rotate,
    q_to_euler,
    q_to_rotation_vector,
    shape_ang_vel,
    shape_angle,
    sqrt_controller,
)
from .emulator_filters import RatePid, param_or_default

CDEG = math.pi / 18000.0  # [rad] per centidegree


class AttitudeController:
    """Attitude target, its shaping inputs, the angle loop and the rate PIDs -> normalised roll/pitch/yaw.

    State: ``att_target`` (NED->target quaternion), ``ang_vel_target`` [rad/s] (target frame), ``rate_target``
    [rad/s] (body, what the rate PIDs chase in the next loop), ``rate_pids`` (roll, pitch, yaw).
    """

    def __init__(self):
        self.rate_pids = (RatePid(), RatePid(), RatePid())
        self.att_target = (1.0, 0.0, 0.0, 0.0)
        self.ang_vel_target = [0.0, 0.0, 0.0]
        self.rate_target = (0.0, 0.0, 0.0)

    def load_parameters(self, params) -> None:
        """Copy the ATC_* and ANGLE_MAX parameters of the table into plain attributes."""
        g = params.get
        self.accel_max = (g("ATC_ACCEL_R_MAX") * CDEG, g("ATC_ACCEL_P_MAX") * CDEG, g("ATC_ACCEL_Y_MAX") * CDEG)
        self.ang_p = (g("ATC_ANG_RLL_P"), g("ATC_ANG_PIT_P"), g("ATC_ANG_YAW_P"))
        # update_ang_vel_target_from_att_error: the angle P loop's sqrt_controller uses half the
        # acceleration limit, clamped to [40, 720] deg/s^2 (roll/pitch) and [10, 120] deg/s^2 (yaw)
        rp_lo, rp_hi, y_lo, y_hi = (math.radians(v) for v in (40.0, 720.0, 10.0, 120.0))
        self.angle_loop_accel = tuple(
            min(max(a / 2.0, lo), hi) if a > 0.0 else 0.0
            for a, lo, hi in zip(self.accel_max, (rp_lo, rp_lo, y_lo), (rp_hi, rp_hi, y_hi))
        )
        self.input_tc = g("ATC_INPUT_TC")
        self.rate_ff_enabled = g("ATC_RATE_FF_ENAB") != 0.0
        for pid, ax in zip(self.rate_pids, ("RLL", "PIT", "YAW")):
            pid.kp = g(f"ATC_RAT_{ax}_P")
            pid.ki = g(f"ATC_RAT_{ax}_I")
            pid.kd = g(f"ATC_RAT_{ax}_D")
            pid.kff = g(f"ATC_RAT_{ax}_FF")
            pid.imax = g(f"ATC_RAT_{ax}_IMAX")
        for pid, ax in zip(self.rate_pids, ("RLL", "PIT", "YAW")):
            pid.fltt = param_or_default(params, f"ATC_RAT_{ax}_FLTT")
            pid.flte = param_or_default(params, f"ATC_RAT_{ax}_FLTE")
            pid.fltd = param_or_default(params, f"ATC_RAT_{ax}_FLTD")
            pid.invalidate_filters()
        self.angle_max = g("ANGLE_MAX") * CDEG

    def reset_to(self, q_meas, level: bool) -> None:
        """Target at the measured attitude (``level``: level at its heading), no target rate, PIDs reset."""
        if level:
            _, _, yaw = q_to_euler(q_meas)
            self.att_target = q_from_euler(0.0, 0.0, yaw)
        else:
            self.att_target = tuple(q_meas)
        self.ang_vel_target = [0.0, 0.0, 0.0]
        for pid in self.rate_pids:
            pid.reset()

    def _advance_target(self, dt):
        """Rotate the attitude target by the target angular velocity over one loop period."""
        avt = self.ang_vel_target
        step = q_from_rotation_vector(avt[0] * dt, avt[1] * dt, avt[2] * dt)
        self.att_target = q_normalize(q_mul(self.att_target, step))

    def input_rate_bf(self, rates, dt):
        """``input_rate_bf_roll_pitch_yaw``: shape, then integrate into the attitude target."""
        avt = self.ang_vel_target
        if self.rate_ff_enabled:
            am = self.accel_max
            avt[0] = shape_ang_vel(avt[0], rates[0], am[0], dt)
            avt[1] = shape_ang_vel(avt[1], rates[1], am[1], dt)
            avt[2] = shape_ang_vel(avt[2], rates[2], am[2], dt)
        else:
            avt[0], avt[1], avt[2] = rates
        self._advance_target(dt)

    def input_quaternion(self, q_desired, rates_ff, dt):
        """``input_quaternion``: shape toward a desired attitude with rate feed-forward."""
        err = q_to_rotation_vector(q_mul(q_conj(self.att_target), q_desired))
        avt = self.ang_vel_target
        if self.rate_ff_enabled:
            am = self.accel_max
            for i in range(3):
                avt[i] = shape_angle(err[i], self.input_tc, am[i], avt[i], rates_ff[i], dt)
            self._advance_target(dt)
        else:
            self.att_target = q_normalize(tuple(q_desired))
            avt[0], avt[1], avt[2] = rates_ff

    def input_level(self, yaw_rad, dt):
        """Level at ``yaw_rad`` [rad], no rate feed-forward."""
        self.input_quaternion(q_from_euler(0.0, 0.0, yaw_rad), (0.0, 0.0, 0.0), dt)

    def input_lean(self, roll, pitch, yaw, dt):
        """Lean angles [rad] clamped to ANGLE_MAX, at ``yaw`` [rad]."""
        lim = self.angle_max
        self.input_quaternion(q_from_euler(min(max(roll, -lim), lim), min(max(pitch, -lim), lim), yaw),
                              (0.0, 0.0, 0.0), dt)

    def target_yaw(self) -> float:
        """[rad] ZYX yaw of the attitude target."""
        return q_to_euler(self.att_target)[2]

    def run(self, q_meas, gyro, limit, dt: float):
        """``rate_controller_run`` then ``attitude_controller_run_quat``: -> normalised roll/pitch/yaw.

        In that order, as ArduCopter's fast loop runs them (the rate controller first, on the newest gyro sample,
        for the least gyro-to-motor latency): the rate PIDs chase the body-rate target the attitude controller set
        one loop earlier, so the angle loop acts one loop period (2.5 ms at 400 Hz) later than if it fed the rate
        loop directly. ``gyro`` is the filtered gyro [rad/s], ``limit`` the mixer's saturation flags."""
        g = gyro
        tx, ty, tz = self.rate_target
        pid_r, pid_p, pid_y = self.rate_pids
        r0 = pid_r.update(tx, g[0], dt, limit.roll)
        r1 = pid_p.update(ty, g[1], dt, limit.pitch)
        r2 = pid_y.update(tz, g[2], dt, limit.yaw)
        q_err = q_mul(q_conj(q_meas), self.att_target)  # target relative to the body
        ex, ey, ez = q_to_rotation_vector(q_err)
        am, ap = self.angle_loop_accel, self.ang_p
        wx = sqrt_controller(ex, ap[0], am[0], dt)
        wy = sqrt_controller(ey, ap[1], am[1], dt)
        wz = sqrt_controller(ez, ap[2], am[2], dt)
        avt = self.ang_vel_target
        # feed-forward: target angular velocity (target frame) expressed in the current body frame
        fx, fy, fz = q_rotate(q_err, avt[0], avt[1], avt[2])
        self.rate_target = (wx + fx, wy + fy, wz + fz)  # for the rate controller's next run
        return (-1.0 if r0 < -1.0 else (1.0 if r0 > 1.0 else r0),
                -1.0 if r1 < -1.0 else (1.0 if r1 > 1.0 else r1),
                -1.0 if r2 < -1.0 else (1.0 if r2 > 1.0 else r2))
