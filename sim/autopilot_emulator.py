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

Where each lives (issue 29: one job per class; this module re-exports the parts' public names): the modes, arming,
take-off start, land detector and the loop's order in ``ArduCopterEmulator`` here; the GUIDED angle interface in
``sim/emulator_guided.py``; the attitude controller in ``sim/emulator_attitude.py``; the vertical and horizontal
position controller in ``sim/emulator_position.py``; spool, angle boost, density compensation and mixing in
``sim/emulator_motors.py``; the rate PID and the gyro filter in ``sim/emulator_filters.py``.

Simplifications (documented in docs/sim_physics.md): no spool-up ramp unless ``takeoff_timing`` asks for it, no
thrust-vector/heading split of the attitude error, no hover-throttle learning, no battery-voltage
compensation, land detector uses the throttle-at-lower-limit, |accel| < 1 m/s^2 and
|climb| < 1 m/s conditions for 1 s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from operator import attrgetter

from .arducopter_profile import ArduCopterProfile
from .emulator_attitude import CDEG, AttitudeController  # noqa: F401 (CDEG re-exported)
from .emulator_filters import FILTER_DEFAULTS, GyroFilter, RatePid, param_or_default  # noqa: F401 (re-exported)
from .emulator_guided import (  # noqa: F401 (the type_mask bits re-exported)
    GUID_OPTIONS_THRUST_AS_THRUST,
    MASK_ATTITUDE_IGNORE,
    MASK_PITCH_RATE_IGNORE,
    MASK_ROLL_RATE_IGNORE,
    MASK_THROTTLE_IGNORE,
    MASK_THRUST_BODY_SET,
    MASK_YAW_RATE_IGNORE,
    GuidedAngleTarget,
)
from .emulator_motors import (  # noqa: F401 (the ISA names re-exported)
    ISA_DENSITY_EXPONENT,
    ISA_LAPSE_KPM,
    ISA_T0_K,
    MotorOutput,
    density_compensation_gain,
    isa_density_ratio,
)
from .emulator_position import PositionController
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

LAND_DETECTOR_TRIGGER_S = 1.0  # AP:ArduCopter/land_detector.cpp LAND_DETECTOR_TRIGGER_SEC
LAND_DETECTOR_ACCEL_MAX = 1.0  # [m/s^2] LAND_DETECTOR_ACCEL_MAX
LOWER_LIMIT_THROTTLE = 0.05  # [-] stand-in for motors->limit.throttle_lower && is_throttle_mix_min()
ARMING_DELAY_S = 2.0  # [s] ArduCopter config.h ARMING_DELAY_SEC: motor interlock off this long after arming


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


def _part_attribute(part: str, name: str) -> property:
    """Attribute ``name`` of the emulator's part ``part``, read and written through the emulator."""

    def set_value(self, value):
        setattr(getattr(self, part), name, value)

    return property(attrgetter(f"{part}.{name}"), set_value, doc=f"``{part}.{name}``")


class ArduCopterEmulator:
    """ArduCopter 4.2+ flight modes, arming, land detector and the fast loop that runs its parts.

    The parts, one job each: ``gyro_filter`` (the inertial sensor's low-pass), ``guided`` (the GUIDED angle
    interface, ``sim/emulator_guided.py``), ``attitude`` (``AC_AttitudeControl``, ``sim/emulator_attitude.py``),
    ``position`` (``AC_PosControl``, ``sim/emulator_position.py``) and ``motors`` (``AP_MotorsMulticopter``,
    ``sim/emulator_motors.py``). This class is ArduCopter's ``Copter``: the mode and arming state machine, the
    take-off start, the land detector and auto-disarm, and the order the parts run in each loop.

    Parameters
    ----------
    params : the vehicle's parameter table; changes are picked up through its change callback
    profile : the habits of the ArduCopter emulated (take-off timing, density compensation, position estimate)
    field_elevation_m : [m AMSL] the ground's altitude (ArduCopter's "Field Elevation Set" at the EKF origin), where
        the density compensation takes the air density ratio
    """

    # the parts' state under the names the emulator's users read (and tests set)
    rate_pids = _part_attribute("attitude", "rate_pids")
    att_target = _part_attribute("attitude", "att_target")
    ang_vel_target = _part_attribute("attitude", "ang_vel_target")
    rate_target = _part_attribute("attitude", "rate_target")
    mixer = _part_attribute("motors", "mixer")
    throttle_in = _part_attribute("motors", "throttle_in")
    throttle_out = _part_attribute("motors", "throttle_out")
    motor_thrusts = _part_attribute("motors", "motor_thrusts")
    esc_commands = _part_attribute("motors", "esc_commands")
    rpy_out = _part_attribute("motors", "rpy_out")
    spool_unlimited = _part_attribute("motors", "spool_unlimited")
    compensation_gain = _part_attribute("motors", "compensation_gain")
    rejected_targets = _part_attribute("guided", "rejected_targets")
    last_reject_reason = _part_attribute("guided", "last_reject_reason")

    def __init__(self, params: ParameterTable, profile: ArduCopterProfile, field_elevation_m: float = 0.0):
        self.params = params
        self.profile = profile
        self.gyro_filter = GyroFilter()
        # AP_MotorsMulticopter::get_compensation_gain (see density_compensation_gain)
        self.motors = MotorOutput(density_compensation_gain(field_elevation_m) if profile.density_compensation
                                  else 1.0)
        self.attitude = AttitudeController()
        self.position = PositionController(self.motors, jerk_limited=profile.takeoff_timing == "arducopter")
        self.guided = GuidedAngleTarget()
        self.mode_number = STABILIZE
        self.armed = False
        self.auto_armed = False
        self.land_complete = True
        self.statustext: list[tuple[int, str]] = []
        self.time_s = 0.0
        self.arm_time_s = 0.0
        self._landed_timer = 0.0
        self._disarm_timer = 0.0
        params.on_change(lambda name, value: self.load_parameters())
        self.load_parameters()

    def load_parameters(self) -> None:
        """Copy the table into plain attributes of the emulator and its parts (called on every parameter change)."""
        params = self.params
        g = params.get
        self.loop_rate_hz = max(50.0, g("SCHED_LOOP_RATE"))
        self.attitude.load_parameters(params)
        self.gyro_filter.set_cutoff(param_or_default(params, "INS_GYRO_FILTER"))
        self.motors.load_parameters(params)
        self.position.load_parameters(params)
        self.guided.load_parameters(params)
        self.land_speed = abs(g("LAND_SPEED")) * 0.01
        self.disarm_delay_s = g("DISARM_DELAY")

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
        self.guided.clear()
        self.position.hold_here(meas)
        self.position.init_z(meas)

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
        self.motors.spin_up_ratio = 0.0
        self.attitude.reset_to(meas.q_wxyz, level=True)
        self.position.init_z(meas)
        self.position.hold_here(meas)
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
        self.motors.spool_unlimited = False
        self._text(6, "Disarming motors" + (f" ({reason})" if reason else ""))
        return True, "disarmed"

    def _stop(self, meas: Measurement, reason: str) -> tuple[bool, str]:
        """``mode_guided.init(true)``: drop the attitude target and hold (zero velocity, level)."""
        self.guided.stop(reason)
        self.position.hold_here(meas)
        self.position.init_z(meas)
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
        guided, position = self.guided, self.position
        target, reason = guided.parse(type_mask, q_wxyz, body_rates_rads, thrust, position.speed_up,
                                      position.speed_dn)
        if target is None:
            return self._stop(meas, reason)
        if guided.submode != "angle" or target[3] != guided.use_thrust:
            # angle_control_start (or switching climb/thrust interpretation) re-initialises z control
            if guided.submode != "angle":
                self.attitude.reset_to(meas.q_wxyz, level=True)
            position.init_z(meas)
        guided.accept(target, self.time_s)
        return True, "ok"

    def _attitude_controller_run(self, meas: Measurement, dt: float):
        """The attitude and rate controllers on this loop's attitude and filtered gyro -> normalised roll/pitch/yaw
        (``AttitudeController.run``)."""
        return self.attitude.run(meas.q_wxyz, self.gyro_filter.out, self.motors.mixer.limit, dt)

    # ------------------------------------------------------------------ main loop
    def update(self, meas: Measurement, dt: float, in_ground_contact: bool, now_s: float | None = None) -> list[float]:
        """One fast-loop iteration of ``dt`` [s] at time ``now_s`` (default: previous time + dt).

        Returns the ESC commands [0, 1] of the motors (ArduPilot order).
        """
        self.time_s = self.time_s + dt if now_s is None else now_s
        self.gyro_filter.apply(meas.gyro_frd, dt)  # the IMU filters whatever the flight state
        if not self.armed:
            self.motors.spool_unlimited = False
            self.land_complete = True
            self.auto_armed = False
            self._ground_idle(meas, stopped=True)
            return self.motors.esc_commands
        climb, thrust, takeoff_demand, attitude_input = self._mode_demand(meas)
        if takeoff_demand:
            self.auto_armed = True
        if not self._held_on_ground(meas, dt, takeoff_demand):
            self._fly(meas, dt, climb, thrust, attitude_input)
        self._update_land_and_disarm(meas, dt, in_ground_contact)
        return self.motors.esc_commands

    def _mode_demand(self, meas: Measurement):
        """The flight mode's demand this loop: (climb [m/s up], collective thrust or None, take-off demand, attitude
        input). Without RC input the non-guided modes hold level at zero climb (LOITER and GUIDED's hold also hold
        position); LAND descends at LAND_SPEED."""
        mode = self.mode_number
        guided = self.guided
        if mode in GUIDED_MODES and guided.submode == "angle":
            if guided.check_timeout(self.time_s, meas.q_wxyz):
                self.position.init_z(meas)  # a collective-thrust target timed out: the z controller takes over
            return guided.demand()
        if mode == LAND:
            return -self.land_speed, None, False, ("level",)
        if mode in (LOITER, GUIDED):
            return 0.0, None, False, ("hold",)
        return 0.0, None, False, ("level",)  # STABILIZE / ALT_HOLD with no RC input

    def _held_on_ground(self, meas: Measurement, dt: float, takeoff_demand: bool) -> bool:
        """True when the vehicle stays on the ground this loop (its ESC commands set): spooling up before a
        take-off (profile ``takeoff_timing: arducopter``), or landed with no take-off demand, or not auto-armed."""
        if self.profile.takeoff_timing == "arducopter" and self._spooling(meas, dt, takeoff_demand):
            return True
        if not self.auto_armed or (self.land_complete and not takeoff_demand):
            self._ground_idle(meas, stopped=False)
            return True
        return False

    def _fly(self, meas: Measurement, dt: float, climb: float, thrust, attitude_input) -> None:
        """Flying: the attitude input, the attitude and rate controllers, the throttle (collective ``thrust``, or
        the vertical controller's for ``climb``) and the motors."""
        motors = self.motors
        motors.spool_unlimited = True
        attitude = self.attitude
        kind = attitude_input[0]
        if kind == "rate":
            attitude.input_rate_bf(attitude_input[1], dt)
        elif kind == "quat":
            attitude.input_quaternion(attitude_input[1], attitude_input[2], dt)
        elif kind == "hold":
            target_yaw = attitude.target_yaw()
            roll, pitch = self.position.hold_lean(meas, target_yaw)
            attitude.input_lean(roll, pitch, target_yaw, dt)
        else:
            attitude.input_level(attitude.target_yaw(), dt)
        rpy = self._attitude_controller_run(meas, dt)
        if thrust is not None:
            throttle = 0.0 if thrust < 0.0 else (1.0 if thrust > 1.0 else thrust)
        else:
            throttle = self.position.update_z(climb, meas, dt)
        motors.output(rpy, throttle, meas.q_wxyz)

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
        motors = self.motors
        if self.time_s - self.arm_time_s <= ARMING_DELAY_S:
            self._ground_idle(meas, stopped=True)
            motors.spin_up_ratio = 0.0
            return True
        demand = self.auto_armed and takeoff_demand
        self._ground_idle(meas, stopped=False)
        ratio = motors.spool_step(demand, dt)
        if demand and ratio >= 1.0:
            self.land_complete = False  # set_land_complete(false); pos_control->D_init_controller() from zero throttle
            self._landed_timer = 0.0
            motors.spool_unlimited = True
            motors.throttle_in = 0.0
            self.position.init_z(meas)
        return True

    def _ground_idle(self, meas: Measurement, stopped: bool) -> None:
        """``make_safe_ground_handling``: ground idle (or stopped when disarmed), targets and I-terms reset."""
        self.motors.spool_unlimited = False
        self.attitude.reset_to(meas.q_wxyz, level=True)
        self.attitude.rate_target = (0.0, 0.0, 0.0)
        self.position.init_z(meas)
        self.position.accz_integrator = 0.0
        self.motors.idle(stopped)

    def _update_land_and_disarm(self, meas: Measurement, dt: float, in_contact: bool) -> None:
        """Land detector (``update_land_detector``) and ``auto_disarm_check`` / LAND-mode disarm."""
        self._update_land_detector(meas, dt)
        if not self.armed:
            return
        if self.mode_number == LAND and self.land_complete:
            self.disarm(force=True, reason="landed")
            return
        if self.land_complete and not self.motors.spool_unlimited and self.disarm_delay_s > 0.0:
            self._disarm_timer += dt
            if self._disarm_timer >= self.disarm_delay_s:
                self.disarm(force=True, reason="auto-disarm")
        else:
            self._disarm_timer = 0.0

    def _update_land_detector(self, meas: Measurement, dt: float) -> None:
        """``update_land_detector``: take-off when the motors run unlimited above half the hover throttle; landed
        after LAND_DETECTOR_TRIGGER_S of throttle at its lower limit, |accel| < LAND_DETECTOR_ACCEL_MAX and
        |climb| < 1 m/s."""
        motors = self.motors
        if self.land_complete:
            if motors.spool_unlimited and motors.throttle_out > 0.5 * motors.hover:
                self.land_complete = False  # take-off detected
                self._landed_timer = 0.0
            return
        a = meas.accel_ned
        accel_ok = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) < LAND_DETECTOR_ACCEL_MAX
        climb_ok = abs(meas.velocity_ned[2]) < 1.0
        lower = motors.throttle_in <= LOWER_LIMIT_THROTTLE or motors.mixer.limit.throttle_lower
        if lower and accel_ok and climb_ok:
            self._landed_timer += dt
            if self._landed_timer >= LAND_DETECTOR_TRIGGER_S:
                self.land_complete = True
        else:
            self._landed_timer = 0.0
