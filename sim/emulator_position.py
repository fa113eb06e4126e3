"""The emulated ArduCopter's position controller (``AC_PosControl``): vertical and horizontal hold.

Vertical: pos P -> vel P -> accel PID -> throttle about MOT_THST_HOVER, the velocity target shaped to PILOT_ACCEL_Z
(and, with the profile's ``takeoff_timing: arducopter``, jerk-limited by PSC_JERK_Z), the position target kept
within reach. Horizontal (LOITER, GUIDED's hold): pos P -> vel P -> lean angles. Split out of
``ArduCopterEmulator`` (issue 29); ``sim/autopilot_emulator.py``'s docstring says what is modelled and simplified.

``meas`` below is the loop's ``Measurement`` (``sim/autopilot_emulator.py``): position, velocity and acceleration NED.
"""

from __future__ import annotations

import math

from .attitude_math import inv_sqrt_controller, shape_ang_vel, sqrt_controller
from .emulator_filters import param_or_default

GRAVITY_MS2 = 9.80665  # [m/s^2] GRAVITY_MSS


class PositionController:
    """``AC_PosControl`` z (climb rate -> throttle) and xy (position hold -> lean), NED down positive.

    Parameters
    ----------
    motors : the ``MotorOutput`` it drives: its hover throttle, throttle input, spool state and limits
    jerk_limited : the velocity target is jerk-limited (``shape_vel_accel``; the profile's ArduCopter take-off)
    """

    def __init__(self, motors, jerk_limited: bool):
        self.motors = motors
        self.jerk_limited = jerk_limited
        self.pos_z_target = 0.0
        self.vel_z_target = 0.0
        self.accel_z_target = 0.0
        self.accz_integrator = 0.0
        self.hold_position_ne = (0.0, 0.0)

    def load_parameters(self, params) -> None:
        """Copy the PSC_*, WPNAV_SPEED_* and PILOT_ACCEL_Z parameters of the table into plain attributes."""
        g = params.get
        self.speed_up = g("WPNAV_SPEED_UP") * 0.01
        self.speed_dn = abs(g("WPNAV_SPEED_DN")) * 0.01
        self.accel_z_max = abs(g("PILOT_ACCEL_Z")) * 0.01
        self.posz_p = g("PSC_POSZ_P")
        self.jerk_z_max = param_or_default(params, "PSC_JERK_Z")
        # AC_PosControl's position error limits (AC_P_1D::set_limits from the climb/descent speed and vertical
        # acceleration limits, inv_sqrt_controller): 2.5 m up and 1.5 m down with ArduCopter's defaults
        self.z_error_limits_m = (inv_sqrt_controller(self.speed_up, self.posz_p, self.accel_z_max),
                                 inv_sqrt_controller(self.speed_dn, self.posz_p, self.accel_z_max))
        self.velz_p = g("PSC_VELZ_P")
        self.accz_p = g("PSC_ACCZ_P")
        self.accz_i = g("PSC_ACCZ_I")
        self.accz_imax = g("PSC_ACCZ_IMAX") * 0.001
        self.posxy_p = g("PSC_POSXY_P")
        self.velxy_p = g("PSC_VELXY_P")

    def init_z(self, meas) -> None:
        """Targets at the measured height and climb rate; the integrator at the throttle in use less hover (zero
        unless the motors run unlimited)."""
        motors = self.motors
        self.pos_z_target = meas.position_ned[2]
        self.vel_z_target = meas.velocity_ned[2]
        self.accel_z_target = 0.0
        self.accz_integrator = motors.throttle_in - motors.hover if motors.spool_unlimited else 0.0

    def hold_here(self, meas) -> None:
        """Hold the measured horizontal position."""
        self.hold_position_ne = (meas.position_ned[0], meas.position_ned[1])

    def _shape_vel_z(self, vd_des: float, dt: float) -> float:
        """Move the velocity target toward ``vd_des`` [m/s NED down]; -> its previous value."""
        prev = self.vel_z_target
        if self.jerk_limited:
            # AC_PosControl::input_vel_accel_U -> shape_vel_accel: the velocity error drives a jerk-limited
            # acceleration (PSC_JERK_Z) bounded by PILOT_ACCEL_Z, which the velocity target integrates
            a_max, jerk = self.accel_z_max, self.jerk_z_max
            acc = sqrt_controller(vd_des - prev, jerk / a_max, jerk, dt) if a_max > 0.0 else 0.0
            acc = -a_max if acc < -a_max else (a_max if acc > a_max else acc)
            step = jerk * dt
            delta = acc - self.accel_z_target
            self.accel_z_target += -step if delta < -step else (step if delta > step else delta)
            self.vel_z_target = prev + self.accel_z_target * dt
        else:
            self.vel_z_target = shape_ang_vel(prev, vd_des, self.accel_z_max, dt)
        return prev

    def update_z(self, climb_up_ms: float, meas, dt: float) -> float:
        """``set_pos_target_z_from_climb_rate`` + ``update_z_controller`` -> throttle in [0, 1]."""
        prev = self._shape_vel_z(-climb_up_ms, dt)
        acc_ff = (self.vel_z_target - prev) / dt  # shaped acceleration feed-forward (_accel_desired.z)
        self.pos_z_target += self.vel_z_target * dt
        # keep the position target within reach (AC_PosControl limits the leash)
        up, down = self.z_error_limits_m
        pz = meas.position_ned[2]
        pzt = self.pos_z_target
        self.pos_z_target = pzt = pz - up if pzt < pz - up else (pz + down if pzt > pz + down else pzt)
        vel_cmd = self.vel_z_target + self.posz_p * (pzt - pz)
        acc_cmd = acc_ff + self.velz_p * (vel_cmd - meas.velocity_ned[2])  # [m/s^2] NED down
        err_up_cms2 = -(acc_cmd - meas.accel_ned[2]) * 100.0
        motors = self.motors
        lim = motors.mixer.limit
        delta = err_up_cms2 * self.accz_i * dt * 0.001
        limited = lim.throttle_upper if delta > 0.0 else lim.throttle_lower or motors.throttle_in <= 0.0
        if not limited:
            i_new, imax = self.accz_integrator + delta, self.accz_imax
            self.accz_integrator = -imax if i_new < -imax else (imax if i_new > imax else i_new)
        thr = motors.hover + self.accz_p * err_up_cms2 * 0.001 + self.accz_integrator
        return 0.0 if thr < 0.0 else (1.0 if thr > 1.0 else thr)

    def hold_lean(self, meas, yaw: float):
        """Horizontal position hold (``AC_PosControl`` xy: pos P -> vel P) -> (roll, pitch) [rad]."""
        pn, pe = meas.position_ned[0], meas.position_ned[1]
        vn_cmd = self.posxy_p * (self.hold_position_ne[0] - pn)
        ve_cmd = self.posxy_p * (self.hold_position_ne[1] - pe)
        an = self.velxy_p * (vn_cmd - meas.velocity_ned[0])
        ae = self.velxy_p * (ve_cmd - meas.velocity_ned[1])
        cy, sy = math.cos(yaw), math.sin(yaw)
        a_fwd = cy * an + sy * ae
        a_right = -sy * an + cy * ae
        g = GRAVITY_MS2
        return math.atan2(a_right, g), -math.atan2(a_fwd, g)
