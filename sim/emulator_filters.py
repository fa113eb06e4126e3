"""The emulated ArduCopter's filters and rate PIDs (``AC_PID``, ``LowPassFilter2p``), and the defaults of the
filter, spool and jerk parameters a parameter table may not carry.

Split out of ``sim/autopilot_emulator.py`` (issue 29), which re-exports these names; what they model and why is
in that module's docstring and docs/sim.md, "Closed-loop parity".
"""

from __future__ import annotations

import math

from .attitude_math import lowpass_alpha

# ArduCopter 4.x defaults of parameters the emulation models but the parameter table may not carry (a table entry
# of the same name wins): the motors' spool time (AP_MotorsMulticopter, 0.5 s), the vertical jerk limit
# (AC_PosControl, 5 m/s^3), the gyro filter (AP_InertialSensor DEFAULT_GYRO_FILTER) and the rate PIDs' target,
# error and derivative filters (AC_AttitudeControl_Multi's AC_PID defaults: FLTT 20 Hz on every axis, FLTE only on yaw,
# FLTD only on roll and pitch)
FILTER_DEFAULTS = {"MOT_SPOOL_TIME": 0.5, "PSC_JERK_Z": 5.0,
                   "INS_GYRO_FILTER": 20.0,
                   "ATC_RAT_RLL_FLTT": 20.0, "ATC_RAT_PIT_FLTT": 20.0, "ATC_RAT_YAW_FLTT": 20.0,
                   "ATC_RAT_RLL_FLTE": 0.0, "ATC_RAT_PIT_FLTE": 0.0, "ATC_RAT_YAW_FLTD": 0.0}


def param_or_default(params, name: str) -> float:
    """A filter [Hz], spool time [s] or jerk limit [m/s^3] parameter from the table ``params``, else ArduCopter's
    default (FILTER_DEFAULTS)."""
    return params.get(name) if name in params else FILTER_DEFAULTS[name]


class RatePid:
    """AC_PID subset: target filter FLTT, error filter FLTE, P, I (IMAX, anti-windup on motor limits), D (FLTD
    low-pass of the filtered error's derivative), FF on the filtered target (``AC_PID::update_all``)."""

    __slots__ = ("kp", "ki", "kd", "kff", "imax", "fltt", "flte", "fltd", "integrator", "target", "err", "deriv",
                 "_started", "_alpha_dt", "_alpha_t", "_alpha_e", "_alpha_d")

    def __init__(self):
        self.kp = self.ki = self.kd = self.kff = self.imax = self.fltt = self.flte = self.fltd = 0.0
        self._alpha_dt = -1.0
        self.reset()

    def reset(self):
        self.integrator = 0.0
        self.target = 0.0
        self.err = 0.0
        self.deriv = 0.0
        self._started = False

    def invalidate_filters(self):
        """Recompute the filter gains on the next update (after a parameter change)."""
        self._alpha_dt = -1.0

    def update(self, target, measured, dt, limit):
        """Normalised output for a rate target/measurement [rad/s]; ``limit`` stops integrator growth."""
        if not self._started:
            self._started = True
            self.target = target
            self.err = target - measured
            self.deriv = 0.0
        else:
            if dt != self._alpha_dt:
                self._alpha_dt = dt
                self._alpha_t = lowpass_alpha(self.fltt, dt)
                self._alpha_e = lowpass_alpha(self.flte, dt)
                self._alpha_d = lowpass_alpha(self.fltd, dt)
            self.target += (target - self.target) * self._alpha_t
            prev = self.err
            err = prev + ((self.target - measured) - prev) * self._alpha_e
            self.err = err
            self.deriv += ((err - prev) / dt - self.deriv) * self._alpha_d
        err = self.err
        if self.ki > 0.0:
            delta = err * self.ki * dt
            integ = self.integrator
            if not limit or (integ > 0.0) != (delta > 0.0):
                integ += delta
                imax = self.imax
                self.integrator = imax if integ > imax else (-imax if integ < -imax else integ)
        else:
            self.integrator = 0.0
        return self.kp * err + self.integrator + self.kd * self.deriv + self.kff * self.target


class GyroFilter:
    """The inertial sensor's gyro low-pass (INS_GYRO_FILTER): a second-order Butterworth biquad per axis, as
    ArduPilot's LowPassFilter2p (bilinear transform, direct form II), run once per loop at the loop's rate.

    ArduCopter's rate loop and its ATTITUDE rates both see the gyro through this filter (about 11 ms of group delay
    at 20 Hz), while its attitude comes from the EKF's unfiltered delta angles; without it a loop closed through
    the autopilot looks faster than on the firmware. ``cutoff_hz`` 0 passes the gyro through."""

    __slots__ = ("cutoff_hz", "_dt", "_coef", "_d1", "_d2", "out", "_started")

    def __init__(self, cutoff_hz: float = 0.0):
        self.cutoff_hz = float(cutoff_hz)
        self._dt = -1.0
        self._coef = None
        self.reset()

    def reset(self):
        self._d1 = [0.0, 0.0, 0.0]
        self._d2 = [0.0, 0.0, 0.0]
        self.out = (0.0, 0.0, 0.0)
        self._started = False

    def set_cutoff(self, cutoff_hz: float) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self._dt = -1.0  # coefficients recomputed on the next sample

    def _coefficients(self, dt):
        fc = self.cutoff_hz
        if fc <= 0.0 or fc >= 0.5 / dt:
            return None
        ohm = math.tan(math.pi * fc * dt)
        c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
        b0 = ohm * ohm / c
        return (b0, 2.0 * b0, b0, 2.0 * (ohm * ohm - 1.0) / c, (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c)

    def apply(self, gyro, dt):
        """Filtered (p, q, r) [rad/s] after one more sample taken ``dt`` [s] after the last."""
        if dt != self._dt:
            self._dt = dt
            self._coef = self._coefficients(dt)
        coef = self._coef
        if coef is None:
            self.out = (gyro[0], gyro[1], gyro[2])
            return self.out
        b0, b1, b2, a1, a2 = coef
        d1, d2 = self._d1, self._d2
        if not self._started:  # start at rest on the first sample, as LowPassFilter2p::reset(sample)
            self._started = True
            for i in range(3):
                d1[i] = d2[i] = gyro[i] / (b0 + b1 + b2)
        out = [0.0, 0.0, 0.0]
        for i in range(3):
            d0 = gyro[i] - d1[i] * a1 - d2[i] * a2
            out[i] = d0 * b0 + d1[i] * b1 + d2[i] * b2
            d2[i] = d1[i]
            d1[i] = d0
        self.out = (out[0], out[1], out[2])
        return self.out
