"""What ArduCopter 4.2+ does between a SET_ATTITUDE_TARGET and the motors (no MAVLink, no clock).

Runs at SCHED_LOOP_RATE (default 400 Hz) and reproduces, in simplified but faithful form
(docs/design-decisions.md, MAV-3 and MAV-5; ArduCopter sources named per class):

* modes STABILIZE 0, ALT_HOLD 2, GUIDED 4, LOITER 5, LAND 9, GUIDED_NOGPS 20 (``MODE_NAMES``);
  without RC input the non-guided flying modes hold level attitude at the current heading and zero
  climb (LOITER and GUIDED's hold also brake horizontal velocity and hold position), LAND descends
  at LAND_SPEED and disarms on touchdown;
* arming/disarming rules (LAND/RTL not armable; no non-forced disarm in flight) and auto-disarm
  after DISARM_DELAY while landed with no takeoff demand;
* GUIDED angle submode (``ModeGuided::angle_control_run``): type_mask validation, quaternion or
  body-rate targets, thrust as climb rate (0.5 = hold, linear to WPNAV_SPEED_UP/DN) or, with
  GUID_OPTIONS bit 3, as collective thrust with angle boost; GUID_TIMEOUT fallback to level at the
  current yaw with zero climb; ``make_safe_ground_handling`` until a positive climb/thrust demand;
* the attitude controller (``AC_AttitudeControl``): body-rate inputs shaped by ATC_ACCEL_R/P/Y_MAX
  and integrated into an attitude-target quaternion; quaternion inputs shaped by
  ``input_shaping_angle`` (ATC_INPUT_TC); angle P loop (``sqrt_controller``) plus rate feed-forward;
  rate PIDs (``AC_PID``: target filter FLTT, error filter FLTE, P, I with IMAX and motor-limit anti-windup, D
  with FLTD, FF), run *before* the attitude controller in each loop as ArduCopter's fast loop does, so they
  chase the previous loop's rate target; the gyro they see, and ATTITUDE reports, passes the inertial sensor's
  second-order low-pass (INS_GYRO_FILTER, 20 Hz). These three were found missing by flying the same bridge
  command against genuine ArduCopter on the same physics (docs/sim.md, "Closed-loop parity");
* the vertical position controller (``AC_PosControl`` z: pos P -> vel P -> accel PID ->
  throttle about MOT_THST_HOVER, angle boost) and the quad-X mixer (``sim/mixer.py``).

* when its profile says so (``takeoff_timing: arducopter``, issue 16 D9) ArduCopter's start of a take-off: motors stopped for
  ARMING_DELAY_SEC (2 s) after arming, the spool up to MOT_SPIN_MIN (MOT_SPOOL_TIME), then
  ``ModeGuided::angle_control_run`` clears land_complete and starts the vertical controller from zero throttle (its
  integrator at minus the hover throttle), whose velocity target is jerk-limited (PSC_JERK_Z). The default
  ("instant") spins up and lifts at once;
* when its profile says so (``density_compensation``) the motors' air-density compensation at the field elevation.

Which of these habits it has is read from the ``ArduCopterProfile`` it is built with (sim/arducopter_profile.py),
as is ``position_estimate``.

Simplifications (documented in docs/sim_physics.md): no spool-up ramp unless ``takeoff_timing`` asks for it, no
thrust-vector/heading split of the attitude error, no hover-throttle learning, no battery-voltage
compensation, land detector uses the throttle-at-lower-limit, |accel| < 1 m/s^2 and
|climb| < 1 m/s conditions for 1 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .arducopter_profile import ArduCopterProfile
from .attitude_math import (
    inv_sqrt_controller,
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
from .emulator_filters import FILTER_DEFAULTS, GyroFilter, RatePid, param_or_default  # noqa: F401 (re-exported)
from .mixer import QuadXMixer, make_thrust_to_actuator
from .parameters import ParameterTable

# ArduCopter Mode::Number (AP:ArduCopter/mode.h)
STABILIZE, ACRO, ALT_HOLD, AUTO, GUIDED, LOITER, RTL, CIRCLE, LAND = 0, 1, 2, 3, 4, 5, 6, 7, 9
GUIDED_NOGPS = 20
MODE_NAMES = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL", 7: "CIRCLE",
    9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE", 16: "POSHOLD", 17: "BRAKE",
    18: "THROW", 19: "AVOID_ADSB", 20: "GUIDED_NOGPS", 21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW",
    24: "ZIGZAG", 25: "SYSTEMID", 26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE",
}
SUPPORTED_MODES = (STABILIZE, ALT_HOLD, GUIDED, LOITER, LAND, GUIDED_NOGPS)
GUIDED_MODES = (GUIDED, GUIDED_NOGPS)
NOT_ARMABLE_MODES = (LAND, RTL, AUTO)  # Mode::allows_arming false for GCS arming (AUTO only with AUTO_OPTIONS)
POSITION_MODES = (GUIDED, LOITER, AUTO, RTL, CIRCLE)  # Mode::requires_GPS()

# SET_ATTITUDE_TARGET type_mask bits (ATTITUDE_TARGET_TYPEMASK)
MASK_ROLL_RATE_IGNORE = 1
MASK_PITCH_RATE_IGNORE = 2
MASK_YAW_RATE_IGNORE = 4
MASK_THRUST_BODY_SET = 32
MASK_THROTTLE_IGNORE = 64
MASK_ATTITUDE_IGNORE = 128
GUID_OPTIONS_THRUST_AS_THRUST = 8

LAND_DETECTOR_TRIGGER_S = 1.0  # AP:ArduCopter/land_detector.cpp LAND_DETECTOR_TRIGGER_SEC
LAND_DETECTOR_ACCEL_MAX = 1.0  # [m/s^2] LAND_DETECTOR_ACCEL_MAX
LOWER_LIMIT_THROTTLE = 0.05  # [-] stand-in for motors->limit.throttle_lower && is_throttle_mix_min()
CDEG = math.pi / 18000.0  # [rad] per centidegree
ARMING_DELAY_S = 2.0  # [s] ArduCopter config.h ARMING_DELAY_SEC: motor interlock off this long after arming
ISA_LAPSE_KPM = 0.0065  # [K/m] ISA troposphere temperature lapse rate
ISA_T0_K = 288.15  # [K] ISA sea-level temperature
ISA_DENSITY_EXPONENT = 4.25588  # [-] g M / (R L) - 1: density ratio = (T / T0) ** this in the ISA troposphere


def isa_density_ratio(altitude_amsl_m: float) -> float:
    """Air density relative to sea level in the ISA troposphere [-] (what AP_Baro's air density ratio follows)."""
    return (1.0 - ISA_LAPSE_KPM * altitude_amsl_m / ISA_T0_K) ** ISA_DENSITY_EXPONENT


def density_compensation_gain(field_elevation_m: float) -> float:
    """ArduCopter's motor demand scale 1 / (air density ratio) at the field elevation [m AMSL] [-].

    ArduCopter scales its roll, pitch, yaw and throttle demands by it before mixing
    (``AP_MotorsMulticopter::get_compensation_gain``, the ratio from the barometer, clamped to 0.5-1.25): 1.058 at
    ArduPilot SITL's home (584 m). Without it the emulated loop had about 6 % less gain than genuine ArduCopter's,
    which showed as a slower recovery from a sustained torque (docs/sim.md, "Closed-loop parity"). Battery
    compensation is off in the Solo's parameters (MOT_BAT_VOLT_MAX 0) and not modelled."""
    ratio = isa_density_ratio(float(field_elevation_m))
    return 1.0 / min(max(ratio, 0.5), 1.25) if 0.3 < ratio < 1.5 else 1.0


@dataclass
class Measurement:
    """What the autopilot's EKF would give it (SI, NED/FRD)."""

    q_wxyz: tuple
    gyro_frd: tuple
    position_ned: tuple
    velocity_ned: tuple
    accel_ned: tuple


class _LazyMeasurement:
    """Measurement built on first attribute access (SET_ATTITUDE_TARGET rarely needs one)."""

    __slots__ = ("_make", "_meas")

    def __init__(self, make):
        self._make = make
        self._meas = None

    def __getattr__(self, name):
        if self._meas is None:
            self._meas = self._make()
        return getattr(self._meas, name)


class ArduCopterEmulator:
    """ArduCopter 4.2+ flight modes, GUIDED attitude interface, attitude/rate/altitude control, mixer.

    Parameters
    ----------
    params : the vehicle's parameter table; changes are picked up through its change callback
    profile : the habits of the ArduCopter emulated (take-off timing, density compensation, position estimate)
    field_elevation_m : [m AMSL] the ground's altitude (ArduCopter's "Field Elevation Set" at the EKF origin), where
        the density compensation takes the air density ratio
    """

    def __init__(self, params: ParameterTable, profile: ArduCopterProfile, field_elevation_m: float = 0.0):
        self.params = params
        self.profile = profile
        self.mixer = QuadXMixer()
        self.rate_pids = (RatePid(), RatePid(), RatePid())
        self.gyro_filter = GyroFilter()
        self.mode_number = STABILIZE
        self.armed = False
        self.auto_armed = False
        self.land_complete = True
        self.statustext: list[tuple[int, str]] = []
        self.time_s = 0.0
        # GUIDED state
        self.guided_submode = "hold"  # "hold" (position/level hold) or "angle"
        self.guided_q = None  # target quaternion or None (= zero quaternion: rate input)
        self.guided_rates = (0.0, 0.0, 0.0)
        self.guided_climb_or_thrust = 0.0
        self.guided_use_thrust = False
        self.guided_update_time_s = 0.0
        self.guided_timed_out = False
        self.rejected_targets = 0
        self.last_reject_reason = ""
        # attitude controller state
        self.att_target = (1.0, 0.0, 0.0, 0.0)
        self.ang_vel_target = [0.0, 0.0, 0.0]
        self.rate_target = (0.0, 0.0, 0.0)
        # vertical controller state (NED down positive)
        self.pos_z_target = 0.0
        self.vel_z_target = 0.0
        self.accz_integrator = 0.0
        self.hold_position_ne = (0.0, 0.0)
        # outputs
        self.throttle_in = 0.0
        self.throttle_out = 0.0
        self.motor_thrusts = [0.0] * self.mixer.count
        self.esc_commands = [0.0] * self.mixer.count
        self.rpy_out = (0.0, 0.0, 0.0)
        self._landed_timer = 0.0
        self._disarm_timer = 0.0
        self.spool_unlimited = False
        self.arm_time_s = 0.0
        self.spin_up_ratio = 0.0  # AP_MotorsMulticopter::_spin_up_ratio: motors at MOT_SPIN_MIN times it
        # AP_MotorsMulticopter::get_compensation_gain (see density_compensation_gain)
        self.compensation_gain = density_compensation_gain(field_elevation_m) if profile.density_compensation else 1.0
        params.on_change(lambda name, value: self.load_parameters())
        self.load_parameters()

    # ------------------------------------------------------------------ parameters
    def load_parameters(self) -> None:
        """Copy the table into plain attributes (called on every parameter change)."""
        g = self.params.get
        self.loop_rate_hz = max(50.0, g("SCHED_LOOP_RATE"))
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
        self.thr_mix_max = g("ATC_THR_MIX_MAX")
        for pid, ax in zip(self.rate_pids, ("RLL", "PIT", "YAW")):
            pid.kp = g(f"ATC_RAT_{ax}_P")
            pid.ki = g(f"ATC_RAT_{ax}_I")
            pid.kd = g(f"ATC_RAT_{ax}_D")
            pid.kff = g(f"ATC_RAT_{ax}_FF")
            pid.imax = g(f"ATC_RAT_{ax}_IMAX")
        for pid, ax in zip(self.rate_pids, ("RLL", "PIT", "YAW")):
            pid.fltt = self._filter_param(f"ATC_RAT_{ax}_FLTT")
            pid.flte = self._filter_param(f"ATC_RAT_{ax}_FLTE")
            pid.fltd = self._filter_param(f"ATC_RAT_{ax}_FLTD")
            pid.invalidate_filters()
        self.gyro_filter.set_cutoff(self._filter_param("INS_GYRO_FILTER"))
        self.spool_time_s = max(self._filter_param("MOT_SPOOL_TIME"), 0.05)
        self.angle_max = g("ANGLE_MAX") * CDEG
        self.hover = min(max(g("MOT_THST_HOVER"), 0.125), 0.6875)
        self.expo = g("MOT_THST_EXPO")
        self.spin_arm = g("MOT_SPIN_ARM")
        self.spin_min = g("MOT_SPIN_MIN")
        self.spin_max = g("MOT_SPIN_MAX")
        self._thrust_to_esc = make_thrust_to_actuator(self.expo, self.spin_min, self.spin_max)
        self.mixer.yaw_headroom = g("MOT_YAW_HEADROOM") * 0.001
        self.speed_up = g("WPNAV_SPEED_UP") * 0.01
        self.speed_dn = abs(g("WPNAV_SPEED_DN")) * 0.01
        self.land_speed = abs(g("LAND_SPEED")) * 0.01
        self.accel_z_max = abs(g("PILOT_ACCEL_Z")) * 0.01
        self.posz_p = g("PSC_POSZ_P")
        self.jerk_z_max = self._filter_param("PSC_JERK_Z")
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
        self.guid_timeout_s = max(g("GUID_TIMEOUT"), 0.1)
        self.thrust_as_thrust = (int(g("GUID_OPTIONS")) & GUID_OPTIONS_THRUST_AS_THRUST) != 0
        self.disarm_delay_s = g("DISARM_DELAY")

    def _filter_param(self, name: str) -> float:
        """A filter [Hz], spool time [s] or jerk limit [m/s^3] parameter from the table, else ArduCopter's default
        (FILTER_DEFAULTS)."""
        return param_or_default(self.params, name)

    # ------------------------------------------------------------------ events
    def _text(self, severity: int, text: str) -> None:
        self.statustext.append((severity, text[:50]))

    def set_mode(self, mode_number: int, meas: Measurement) -> tuple[bool, str]:
        """Switch flight mode (ArduCopter ``Copter::set_mode``). Requesting the current mode succeeds."""
        try:
            mode_number = int(mode_number)
        except (TypeError, ValueError):
            return False, f"invalid mode {mode_number!r}"
        if mode_number == self.mode_number:
            return True, "already in mode"
        name = MODE_NAMES.get(mode_number)
        if name is None:
            return False, f"unknown mode number {mode_number}"
        if mode_number not in SUPPORTED_MODES:
            self._text(4, f"Mode change to {name} failed: unsupported in sim")
            return False, f"mode {name} is not emulated by the simulator"
        if self.armed and mode_number in POSITION_MODES and not self.profile.position_estimate:
            # checks are skipped while disarmed (the position requirement then bites at arming)
            self._text(4, f"Mode change to {name} failed: requires position")
            return False, f"Mode change to {name} failed: requires position"
        self.mode_number = mode_number
        self._enter_mode(meas)
        return True, f"mode {name}"

    def prearm_failure(self) -> str:
        """First failing pre-arm check as ArduCopter words it ("PreArm: ..."), or "" if all pass.

        The simulated EKF, GPS and RC are healthy; the only modelled failure is a missing position
        estimate (the profile's ``position_estimate`` false) in a mode that requires one. ARMING_CHECK = 0 skips it.
        """
        if self.params.get("ARMING_CHECK") == 0.0:
            return ""
        if self.mode_number in POSITION_MODES and not self.profile.position_estimate:
            return "PreArm: Need Position Estimate"
        return ""

    def _enter_mode(self, meas: Measurement) -> None:
        self.guided_submode = "hold"
        self.guided_q = None
        self.guided_rates = (0.0, 0.0, 0.0)
        self.guided_climb_or_thrust = 0.0
        self.guided_use_thrust = False
        self.guided_timed_out = False
        self.hold_position_ne = (meas.position_ned[0], meas.position_ned[1])
        self._init_z_controller(meas)

    def arm(self, meas: Measurement, force: bool = False) -> tuple[bool, str]:
        """GCS arming (AP_Arming_Copter::arm). Mode check applies even when forced, as in ArduCopter."""
        if self.armed:
            return True, "already armed"
        if self.mode_number in NOT_ARMABLE_MODES:
            self._text(2, "Arm: Mode not armable")
            return False, "Arm: Mode not armable"
        failure = "" if force else self.prearm_failure()
        if failure:
            self._text(2, failure)
            return False, failure
        self.armed = True
        self.auto_armed = False
        self.land_complete = True
        self._disarm_timer = 0.0
        self.arm_time_s = self.time_s
        self.spin_up_ratio = 0.0
        self._reset_attitude_to(meas.q_wxyz, level=True)
        self._init_z_controller(meas)
        self.hold_position_ne = (meas.position_ned[0], meas.position_ned[1])
        self._text(6, "Arming motors")
        return True, "armed"

    def disarm(self, force: bool = False, reason: str = "") -> tuple[bool, str]:
        """Disarm; a non-forced disarm is refused while not landed (AP_Arming_Copter::disarm)."""
        if not self.armed:
            return True, "already disarmed"
        if not force and not self.land_complete:
            return False, "Disarm: not landed"
        self.armed = False
        self.auto_armed = False
        self.spool_unlimited = False
        self._text(6, "Disarming motors" + (f" ({reason})" if reason else ""))
        return True, "disarmed"

    def _stop(self, meas: Measurement, reason: str) -> tuple[bool, str]:
        """``mode_guided.init(true)``: drop the attitude target and hold (zero velocity, level)."""
        self.rejected_targets += 1
        self.last_reject_reason = reason
        self.guided_submode = "hold"
        self.guided_q = None
        self.guided_rates = (0.0, 0.0, 0.0)
        self.guided_use_thrust = False
        self.hold_position_ne = (meas.position_ned[0], meas.position_ned[1])
        self._init_z_controller(meas)
        return False, reason

    def handle_attitude_target(self, type_mask: int, q_wxyz, body_rates_rads, thrust: float,
                               meas) -> tuple[bool, str]:
        """SET_ATTITUDE_TARGET in ArduCopter 4.2+ (GCS_MAVLink_Copter.cpp, docs/design-decisions.md, MAV-5).

        ``meas`` is the current Measurement or a zero-argument callable returning it (built only
        when a stop or an angle-mode start needs it).
        """
        if self.mode_number not in GUIDED_MODES:
            return False, "not in guided mode"
        if callable(meas):
            meas = _LazyMeasurement(meas)
        try:
            type_mask = int(type_mask)
            q0, q1, q2, q3 = q_wxyz
            q = (float(q0), float(q1), float(q2), float(q3))
            r0, r1, r2 = body_rates_rads
            rates = (float(r0), float(r1), float(r2))
            thrust = float(thrust)
        except (TypeError, ValueError):
            return self._stop(meas, "malformed attitude target")
        if type_mask & MASK_THROTTLE_IGNORE:
            return self._stop(meas, "THROTTLE_IGNORE set: stopped (guided hold)")
        if type_mask & MASK_ATTITUDE_IGNORE:
            q_target = None
        else:
            n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
            if not (abs(n2 - 1.0) < 1e-3):  # Quaternion::is_unit_length; NaN fails too
                return self._stop(meas, "quaternion not unit length: stopped (guided hold)")
            q_target = q
        rate_bits = type_mask & (MASK_ROLL_RATE_IGNORE | MASK_PITCH_RATE_IGNORE | MASK_YAW_RATE_IGNORE)
        if rate_bits == 7:
            rates = (0.0, 0.0, 0.0)
        elif rate_bits != 0:
            return self._stop(meas, "mixed body-rate ignore bits: stopped (guided hold)")
        elif not (math.isfinite(rates[0]) and math.isfinite(rates[1]) and math.isfinite(rates[2])):
            # ArduCopter does not check; the simulator refuses rather than fly NaN (counted).
            return self._stop(meas, "non-finite body rates: stopped (guided hold)")
        use_thrust = self.thrust_as_thrust
        if not math.isfinite(thrust):
            thrust = 0.0 if use_thrust else 0.5  # AP constrain_float() returns the midpoint for NaN
        if use_thrust:
            value = min(max(thrust, -1.0), 1.0)
        else:
            t = min(max(thrust, 0.0), 1.0)
            if t == 0.5:
                value = 0.0
            elif t > 0.5:
                value = (t - 0.5) * 2.0 * self.speed_up
            else:
                value = -(0.5 - t) * 2.0 * self.speed_dn
        if self.guided_submode != "angle" or use_thrust != self.guided_use_thrust:
            # angle_control_start (or switching climb/thrust interpretation) re-initialises z control
            if self.guided_submode != "angle":
                self._reset_attitude_to(meas.q_wxyz, level=True)
            self._init_z_controller(meas)
            self.guided_submode = "angle"
        self.guided_q = q_target
        self.guided_rates = rates
        self.guided_climb_or_thrust = value
        self.guided_use_thrust = use_thrust
        self.guided_update_time_s = self.time_s
        self.guided_timed_out = False
        return True, "ok"

    # ------------------------------------------------------------------ controllers
    def _reset_attitude_to(self, q_meas, level: bool) -> None:
        if level:
            _, _, yaw = q_to_euler(q_meas)
            self.att_target = q_from_euler(0.0, 0.0, yaw)
        else:
            self.att_target = tuple(q_meas)
        self.ang_vel_target = [0.0, 0.0, 0.0]
        for pid in self.rate_pids:
            pid.reset()

    def _init_z_controller(self, meas: Measurement) -> None:
        self.pos_z_target = meas.position_ned[2]
        self.vel_z_target = meas.velocity_ned[2]
        self.accel_z_target = 0.0
        self.accz_integrator = self.throttle_in - self.hover if self.spool_unlimited else 0.0

    def _advance_target(self, dt):
        """Rotate the attitude target by the target angular velocity over one loop period."""
        avt = self.ang_vel_target
        step = q_from_rotation_vector(avt[0] * dt, avt[1] * dt, avt[2] * dt)
        self.att_target = q_normalize(q_mul(self.att_target, step))

    def _input_rate_bf(self, rates, dt):
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

    def _input_quaternion(self, q_desired, rates_ff, dt):
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

    def _input_level(self, yaw_rad, dt):
        self._input_quaternion(q_from_euler(0.0, 0.0, yaw_rad), (0.0, 0.0, 0.0), dt)

    def _input_lean(self, roll, pitch, yaw, dt):
        lim = self.angle_max
        self._input_quaternion(q_from_euler(min(max(roll, -lim), lim), min(max(pitch, -lim), lim), yaw),
                               (0.0, 0.0, 0.0), dt)

    def _attitude_controller_run(self, meas: Measurement, dt: float):
        """``rate_controller_run`` then ``attitude_controller_run_quat``: -> normalised roll/pitch/yaw.

        In that order, as ArduCopter's fast loop runs them (the rate controller first, on the newest gyro sample,
        for the least gyro-to-motor latency): the rate PIDs chase the body-rate target the attitude controller set
        one loop earlier, so the angle loop acts one loop period (2.5 ms at 400 Hz) later than if it fed the rate
        loop directly."""
        lim = self.mixer.limit
        g = self.gyro_filter.out
        tx, ty, tz = self.rate_target
        pid_r, pid_p, pid_y = self.rate_pids
        r0 = pid_r.update(tx, g[0], dt, lim.roll)
        r1 = pid_p.update(ty, g[1], dt, lim.pitch)
        r2 = pid_y.update(tz, g[2], dt, lim.yaw)
        q_err = q_mul(q_conj(meas.q_wxyz), self.att_target)  # target relative to the body
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

    def _z_controller(self, climb_up_ms: float, meas: Measurement, dt: float) -> float:
        """``set_pos_target_z_from_climb_rate`` + ``update_z_controller`` -> throttle in [0, 1]."""
        vd_des = -climb_up_ms
        prev = self.vel_z_target
        if self.profile.takeoff_timing == "arducopter":
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
        lim = self.mixer.limit
        delta = err_up_cms2 * self.accz_i * dt * 0.001
        limited = lim.throttle_upper if delta > 0.0 else lim.throttle_lower or self.throttle_in <= 0.0
        if not limited:
            i_new, imax = self.accz_integrator + delta, self.accz_imax
            self.accz_integrator = -imax if i_new < -imax else (imax if i_new > imax else i_new)
        thr = self.hover + self.accz_p * err_up_cms2 * 0.001 + self.accz_integrator
        return 0.0 if thr < 0.0 else (1.0 if thr > 1.0 else thr)

    def _hold_lean(self, meas: Measurement, yaw: float):
        """Horizontal position hold (``AC_PosControl`` xy: pos P -> vel P) -> (roll, pitch) [rad]."""
        pn, pe = meas.position_ned[0], meas.position_ned[1]
        vn_cmd = self.posxy_p * (self.hold_position_ne[0] - pn)
        ve_cmd = self.posxy_p * (self.hold_position_ne[1] - pe)
        an = self.velxy_p * (vn_cmd - meas.velocity_ned[0])
        ae = self.velxy_p * (ve_cmd - meas.velocity_ned[1])
        cy, sy = math.cos(yaw), math.sin(yaw)
        a_fwd = cy * an + sy * ae
        a_right = -sy * an + cy * ae
        g = 9.80665
        return math.atan2(a_right, g), -math.atan2(a_fwd, g)

    def _boosted(self, throttle: float, meas: Measurement) -> float:
        """``get_throttle_boosted``: divide by the tilt cosine (clamped), fade out when inverted."""
        w, x, y, z = meas.q_wxyz
        cos_tilt = 1.0 - 2.0 * (x * x + y * y)
        inverted = 0.0 if cos_tilt < 0.0 else (1.0 if cos_tilt > 0.1 else 10.0 * cos_tilt)
        divisor = 0.1 if cos_tilt < 0.1 else (1.0 if cos_tilt > 1.0 else cos_tilt)
        return throttle * inverted / divisor

    # ------------------------------------------------------------------ main loop
    def update(self, meas: Measurement, dt: float, in_ground_contact: bool, now_s: float | None = None) -> list[float]:
        """One fast-loop iteration of ``dt`` [s] at time ``now_s`` (default: previous time + dt).

        Returns the ESC commands [0, 1] of the motors (ArduPilot order).
        """
        self.time_s = self.time_s + dt if now_s is None else now_s
        self.gyro_filter.apply(meas.gyro_frd, dt)  # the IMU filters whatever the flight state
        if not self.armed:
            self.spool_unlimited = False
            self.land_complete = True
            self.auto_armed = False
            self._ground_idle(meas, stopped=True)
            return self.esc_commands
        mode = self.mode_number
        climb = 0.0
        use_thrust = False
        thrust = 0.0
        takeoff_demand = False
        attitude_input = None  # callable applying the attitude input
        if mode in GUIDED_MODES and self.guided_submode == "angle":
            if self.time_s - self.guided_update_time_s > self.guid_timeout_s:
                if not self.guided_timed_out:
                    self.guided_timed_out = True
                    self.guided_q = q_from_euler(0.0, 0.0, q_to_euler(meas.q_wxyz)[2])
                    self.guided_rates = (0.0, 0.0, 0.0)
                    self.guided_climb_or_thrust = 0.0
                    if self.guided_use_thrust:
                        self._init_z_controller(meas)
                        self.guided_use_thrust = False
            use_thrust = self.guided_use_thrust
            if use_thrust:
                thrust = self.guided_climb_or_thrust
            else:
                climb = self.guided_climb_or_thrust
            takeoff_demand = (thrust if use_thrust else climb) > 0.0
            if self.guided_q is None:
                attitude_input = ("rate", self.guided_rates)
            else:
                attitude_input = ("quat", self.guided_q, self.guided_rates)
        elif mode == LAND:
            climb = -self.land_speed
            attitude_input = ("level",)
        elif mode in (LOITER, GUIDED):
            attitude_input = ("hold",)
        else:  # STABILIZE / ALT_HOLD with no RC input: level, zero climb
            attitude_input = ("level",)
        if takeoff_demand:
            self.auto_armed = True
        if self.profile.takeoff_timing == "arducopter" and self._spooling(meas, dt, takeoff_demand):
            self._update_land_and_disarm(meas, dt, in_ground_contact)
            return self.esc_commands
        if not self.auto_armed or (self.land_complete and not takeoff_demand):
            self._ground_idle(meas, stopped=False)
            self._update_land_and_disarm(meas, dt, in_ground_contact)
            return self.esc_commands
        self.spool_unlimited = True
        kind = attitude_input[0]
        if kind == "rate":
            self._input_rate_bf(attitude_input[1], dt)
        elif kind == "quat":
            self._input_quaternion(attitude_input[1], attitude_input[2], dt)
        elif kind == "hold":
            target_yaw = q_to_euler(self.att_target)[2]
            roll, pitch = self._hold_lean(meas, target_yaw)
            self._input_lean(roll, pitch, target_yaw, dt)
        else:
            self._input_level(q_to_euler(self.att_target)[2], dt)
        roll_out, pitch_out, yaw_out = self._attitude_controller_run(meas, dt)
        if use_thrust:
            self.throttle_in = 0.0 if thrust < 0.0 else (1.0 if thrust > 1.0 else thrust)
        else:
            self.throttle_in = self._z_controller(climb, meas, dt)
        out = self._boosted(self.throttle_in, meas)
        self.throttle_out = out = 0.0 if out < 0.0 else (1.0 if out > 1.0 else out)
        mix = self.thr_mix_max
        avg_max = out * (1.0 - mix) + self.hover * mix  # ATC_THR_MIX: room for attitude control
        if avg_max < out:
            avg_max = out
        self.rpy_out = (roll_out, pitch_out, yaw_out)
        k = self.compensation_gain  # air density (AP_MotorsMatrix::output_armed_stabilizing)
        self.motor_thrusts = self.mixer.mix(roll_out * k, pitch_out * k, yaw_out * k, self.throttle_out * k,
                                            avg_max * k)
        self.esc_commands = self._thrust_to_esc(self.motor_thrusts)
        # (battery-voltage compensation of the thrust curve is not modelled)
        self._update_land_and_disarm(meas, dt, in_ground_contact)
        return self.esc_commands

    def _spooling(self, meas: Measurement, dt: float, takeoff_demand: bool) -> bool:
        """ArduCopter's start of a take-off (``takeoff_timing`` "arducopter"); True while it holds the vehicle on the
        ground (this loop's ESC commands are set), False once the vehicle may fly (or is flying).

        ``Copter::motors_output``: the motor interlock stays off for ARMING_DELAY_SEC after arming (motors stopped).
        ``AP_MotorsMulticopter::output_logic``: then the spin-up ratio moves toward MOT_SPIN_ARM / MOT_SPIN_MIN (ground
        idle) or, with a take-off demand, toward 1, by 1/MOT_SPOOL_TIME per second, the motors at MOT_SPIN_MIN times
        the ratio; SPOOLING_UP then ends at once because the mode asks for zero throttle.
        ``ModeGuided::angle_control_run`` clears land_complete and initialises the vertical controller from zero
        throttle (``zero_throttle_and_relax_ac``), so its acceleration integrator starts at minus the hover throttle and winds up before the vehicle lifts.
        Measured on genuine 4.7 SITL on the Solo physics: motors at 0 until 2.0 s after the arm, 0 -> 0.15 over the
        next 0.5 s, then a smooth rise to 0.64 and lift-off 3.3 s after the arm."""
        if not self.land_complete:
            return False
        if self.time_s - self.arm_time_s <= ARMING_DELAY_S:
            self._ground_idle(meas, stopped=True)
            self.spin_up_ratio = 0.0
            return True
        step = dt / self.spool_time_s
        demand = self.auto_armed and takeoff_demand
        goal = 1.0 if demand else (self.spin_arm / self.spin_min if self.spin_min > 0.0 else 0.0)
        ratio = self.spin_up_ratio
        self.spin_up_ratio = ratio = ratio + min(max(goal - ratio, -step), step)
        self._ground_idle(meas, stopped=False)
        self.esc_commands = [self.spin_min * ratio] * self.mixer.count
        if demand and ratio >= 1.0:
            self.land_complete = False  # set_land_complete(false); pos_control->D_init_controller() from zero throttle
            self._landed_timer = 0.0
            self.spool_unlimited = True
            self.throttle_in = 0.0
            self._init_z_controller(meas)
        return True

    def _ground_idle(self, meas: Measurement, stopped: bool) -> None:
        """``make_safe_ground_handling``: ground idle (or stopped when disarmed), targets and I-terms reset."""
        self.spool_unlimited = False
        self._reset_attitude_to(meas.q_wxyz, level=True)
        self._init_z_controller(meas)
        self.accz_integrator = 0.0
        self.throttle_in = self.throttle_out = 0.0
        self.rpy_out = (0.0, 0.0, 0.0)
        self.rate_target = (0.0, 0.0, 0.0)
        self.motor_thrusts = [0.0] * self.mixer.count
        idle = 0.0 if stopped else self.spin_arm
        self.esc_commands = [idle] * self.mixer.count

    def _update_land_and_disarm(self, meas: Measurement, dt: float, in_contact: bool) -> None:
        """Land detector (``update_land_detector``) and ``auto_disarm_check`` / LAND-mode disarm."""
        if self.land_complete:
            if self.spool_unlimited and self.throttle_out > 0.5 * self.hover:
                self.land_complete = False  # take-off detected
                self._landed_timer = 0.0
        else:
            a = meas.accel_ned
            accel_ok = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) < LAND_DETECTOR_ACCEL_MAX
            climb_ok = abs(meas.velocity_ned[2]) < 1.0
            lower = self.throttle_in <= LOWER_LIMIT_THROTTLE or self.mixer.limit.throttle_lower
            if lower and accel_ok and climb_ok:
                self._landed_timer += dt
                if self._landed_timer >= LAND_DETECTOR_TRIGGER_S:
                    self.land_complete = True
            else:
                self._landed_timer = 0.0
        if not self.armed:
            return
        if self.mode_number == LAND and self.land_complete:
            self.disarm(force=True, reason="landed")
            return
        if self.land_complete and not self.spool_unlimited and self.disarm_delay_s > 0.0:
            self._disarm_timer += dt
            if self._disarm_timer >= self.disarm_delay_s:
                self.disarm(force=True, reason="auto-disarm")
        else:
            self._disarm_timer = 0.0
