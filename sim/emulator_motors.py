"""The emulated ArduCopter's motor output (``AP_MotorsMulticopter``, ``AP_MotorsMatrix``): spool state, ground idle,
the spin-up before a take-off, angle boost, air-density compensation, the quad-X mixer (``sim/mixer.py``) and the
thrust curve to ESC commands.

Split out of ``ArduCopterEmulator`` (issue 29); ``sim/autopilot_emulator.py``'s docstring says what is modelled and
what is simplified (no battery-voltage compensation, no spool ramp unless the profile's take-off timing asks).
"""

from __future__ import annotations

from .emulator_filters import param_or_default
from .mixer import QuadXMixer, make_thrust_to_actuator

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


class MotorOutput:
    """Throttle and roll/pitch/yaw demands -> motor thrusts -> ESC commands [0, 1] (ArduPilot motor order).

    State: ``throttle_in`` (the attitude controller's throttle), ``throttle_out`` (after angle boost),
    ``rpy_out``, ``motor_thrusts``, ``esc_commands``, ``spool_unlimited`` (THROTTLE_UNLIMITED: flying),
    ``spin_up_ratio`` (``AP_MotorsMulticopter::_spin_up_ratio``: motors at MOT_SPIN_MIN times it).

    Parameters
    ----------
    compensation_gain : the air-density demand scale (``density_compensation_gain``, 1.0 when not modelled)
    """

    def __init__(self, compensation_gain: float = 1.0):
        self.mixer = QuadXMixer()
        self.compensation_gain = compensation_gain
        self.throttle_in = 0.0
        self.throttle_out = 0.0
        self.motor_thrusts = [0.0] * self.mixer.count
        self.esc_commands = [0.0] * self.mixer.count
        self.rpy_out = (0.0, 0.0, 0.0)
        self.spool_unlimited = False
        self.spin_up_ratio = 0.0

    def load_parameters(self, params) -> None:
        """Copy the MOT_* (and ATC_THR_MIX_MAX) parameters of the table into plain attributes."""
        g = params.get
        self.thr_mix_max = g("ATC_THR_MIX_MAX")  # AC_AttitudeControl_Multi's, applied here at mixing
        self.spool_time_s = max(param_or_default(params, "MOT_SPOOL_TIME"), 0.05)
        self.hover = min(max(g("MOT_THST_HOVER"), 0.125), 0.6875)
        self.expo = g("MOT_THST_EXPO")
        self.spin_arm = g("MOT_SPIN_ARM")
        self.spin_min = g("MOT_SPIN_MIN")
        self.spin_max = g("MOT_SPIN_MAX")
        self._thrust_to_esc = make_thrust_to_actuator(self.expo, self.spin_min, self.spin_max)
        self.mixer.yaw_headroom = g("MOT_YAW_HEADROOM") * 0.001

    def idle(self, stopped: bool) -> None:
        """No demand: motors at ground idle (MOT_SPIN_ARM), or stopped."""
        self.throttle_in = self.throttle_out = 0.0
        self.rpy_out = (0.0, 0.0, 0.0)
        self.motor_thrusts = [0.0] * self.mixer.count
        idle = 0.0 if stopped else self.spin_arm
        self.esc_commands = [idle] * self.mixer.count

    def spool_step(self, takeoff_demand: bool, dt: float) -> float:
        """``output_logic`` on the ground: the spin-up ratio one step of 1/MOT_SPOOL_TIME per second toward 1 (a
        take-off demand) or MOT_SPIN_ARM / MOT_SPIN_MIN (ground idle), the motors at MOT_SPIN_MIN times it.
        -> the new ratio."""
        step = dt / self.spool_time_s
        goal = 1.0 if takeoff_demand else (self.spin_arm / self.spin_min if self.spin_min > 0.0 else 0.0)
        ratio = self.spin_up_ratio
        self.spin_up_ratio = ratio = ratio + min(max(goal - ratio, -step), step)
        self.esc_commands = [self.spin_min * ratio] * self.mixer.count
        return ratio

    @staticmethod
    def boosted(throttle: float, q_wxyz) -> float:
        """``get_throttle_boosted``: divide by the tilt cosine (clamped), fade out when inverted."""
        w, x, y, z = q_wxyz
        cos_tilt = 1.0 - 2.0 * (x * x + y * y)
        inverted = 0.0 if cos_tilt < 0.0 else (1.0 if cos_tilt > 0.1 else 10.0 * cos_tilt)
        divisor = 0.1 if cos_tilt < 0.1 else (1.0 if cos_tilt > 1.0 else cos_tilt)
        return throttle * inverted / divisor

    def output(self, rpy, throttle_in: float, q_wxyz) -> list[float]:
        """Flying (``output_armed_stabilizing``): boost ``throttle_in`` [0, 1] for the tilt of ``q_wxyz``, mix it
        with the normalised roll/pitch/yaw ``rpy`` (room for attitude control per ATC_THR_MIX_MAX), scaled by the
        air-density gain. -> the ESC commands."""
        self.throttle_in = throttle_in
        out = self.boosted(throttle_in, q_wxyz)
        self.throttle_out = out = 0.0 if out < 0.0 else (1.0 if out > 1.0 else out)
        mix = self.thr_mix_max
        avg_max = out * (1.0 - mix) + self.hover * mix  # ATC_THR_MIX: room for attitude control
        if avg_max < out:
            avg_max = out
        self.rpy_out = rpy
        roll_out, pitch_out, yaw_out = rpy
        k = self.compensation_gain  # air density (AP_MotorsMatrix::output_armed_stabilizing)
        self.motor_thrusts = self.mixer.mix(roll_out * k, pitch_out * k, yaw_out * k, self.throttle_out * k,
                                            avg_max * k)
        self.esc_commands = self._thrust_to_esc(self.motor_thrusts)
        # (battery-voltage compensation of the thrust curve is not modelled)
        return self.esc_commands
