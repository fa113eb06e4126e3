"""ArduCopter quad-X motor mixer and thrust linearisation (AP_MotorsMatrix / AP_MotorsMulticopter).

Motor order and spin directions are ArduPilot's for FRAME_CLASS 1 (QUAD), FRAME_TYPE 1 (X), the Solo::

    motor 1: +45 deg  (front right)  CCW       motor 3: -45 deg  (front left)  CW
    motor 2: -135 deg (back left)    CCW       motor 4: +135 deg (back right)  CW

Angles are measured from the nose, positive toward the right wing (clockwise from above).
ArduPilot's factors: roll = cos(angle + 90 deg), pitch = cos(angle), yaw = +1 for CCW, -1 for CW,
each then normalised so the largest magnitude is 0.5. Sign conventions (body FRD):
positive roll demand raises the left motors and lowers the right ones, so the right side goes
down; positive pitch raises the front motors (nose up); positive yaw raises the CCW motors, whose
reaction torque turns the nose clockwise seen from above.

All inputs/outputs here are normalised: roll/pitch/yaw demands in [-1, 1], throttle and motor
thrusts in [0, 1] of full thrust. No physics here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# (angle from nose [deg], +1 CCW / -1 CW) for ArduPilot motors 1..4, QUAD/X (AP_MotorsMatrix::setup_quad_matrix).
QUAD_X_LAYOUT = ((45.0, 1.0), (-135.0, 1.0), (-45.0, -1.0), (135.0, -1.0))


def motor_positions_frd(arm_length_m: float, layout=QUAD_X_LAYOUT):
    """[(x, y)] motor positions [m] in body FRD for the ArduPilot layout."""
    return [(arm_length_m * math.cos(math.radians(a)), arm_length_m * math.sin(math.radians(a))) for a, _ in layout]


def motor_spin_ccw(layout=QUAD_X_LAYOUT):
    """+1 for counter-clockwise (seen from above) propellers, -1 for clockwise."""
    return [s for _, s in layout]


@dataclass
class MotorLimits:
    """AP_Motors ``limit`` flags of the last mix: integrators must not grow on a limited axis."""

    roll: bool = False
    pitch: bool = False
    yaw: bool = False
    throttle_lower: bool = False
    throttle_upper: bool = False


class QuadXMixer:
    """ArduCopter's ``output_armed_stabilizing`` for a quad X (roll/pitch take priority over yaw).

    Parameters
    ----------
    yaw_headroom : [-] MOT_YAW_HEADROOM / 1000: yaw authority always kept (default 0.2)
    layout : motor table (angle deg, spin)
    """

    def __init__(self, yaw_headroom: float = 0.2, layout=QUAD_X_LAYOUT):
        roll = [math.cos(math.radians(a + 90.0)) for a, _ in layout]
        pitch = [math.cos(math.radians(a)) for a, _ in layout]
        yaw = [s for _, s in layout]
        rp_max = max(max(abs(v) for v in roll), max(abs(v) for v in pitch))
        y_max = max(abs(v) for v in yaw)
        self.roll_factor = [0.5 * v / rp_max for v in roll]
        self.pitch_factor = [0.5 * v / rp_max for v in pitch]
        self.yaw_factor = [0.5 * v / y_max for v in yaw]
        self.count = len(layout)
        self._rp_factors = tuple(zip(self.roll_factor, self.pitch_factor))
        self._yaw_abs = tuple(abs(v) for v in self.yaw_factor)
        self.yaw_headroom = yaw_headroom
        self.limit = MotorLimits()

    def mix(self, roll: float, pitch: float, yaw: float, throttle: float, throttle_avg_max: float) -> list[float]:
        """Normalised demands -> motor thrusts in [0, 1] (fraction of full thrust).

        Parameters
        ----------
        roll, pitch, yaw : [-] normalised torque demands (ArduPilot rate-controller outputs)
        throttle : [-] collective thrust demand in [0, 1]
        throttle_avg_max : [-] highest average throttle the mixer may use to make room for attitude
            control (ArduCopter: mix of throttle and hover throttle, ATC_THR_MIX_*)

        Sets ``self.limit``. Follows AP_MotorsMatrix::output_armed_stabilizing (no battery compensation,
        no lost-motor boost).
        """
        lim = self.limit
        lim.roll = lim.pitch = lim.yaw = lim.throttle_lower = lim.throttle_upper = False
        if throttle <= 0.0:
            throttle = 0.0
            lim.throttle_lower = True
        elif throttle >= 1.0:
            throttle = 1.0
            lim.throttle_upper = True
        if throttle_avg_max < throttle:
            throttle_avg_max = throttle
        elif throttle_avg_max > 1.0:
            throttle_avg_max = 1.0
        out = [roll * rf + pitch * pf for rf, pf in self._rp_factors]
        rp_low, rp_high = min(out), max(out)
        if rp_high - rp_low > 1.0 or throttle_avg_max < -rp_low:
            lim.roll = lim.pitch = True
        best = 0.5 if throttle_avg_max > 0.5 else throttle_avg_max
        # largest yaw every motor can take from the best throttle (ArduPilot's yaw_allowed)
        yaw_allowed = 1.0
        for o, yf, yf_abs in zip(out, self.yaw_factor, self._yaw_abs):
            base = best + o
            room = (1.0 - base) if yaw * yf > 0.0 else base
            room = room / yf_abs if room > 0.0 else 0.0
            if room < yaw_allowed:
                yaw_allowed = room
        if yaw_allowed < self.yaw_headroom:
            yaw_allowed = self.yaw_headroom
        if yaw > yaw_allowed:
            yaw = yaw_allowed
            lim.yaw = True
        elif yaw < -yaw_allowed:
            yaw = -yaw_allowed
            lim.yaw = True
        out = [o + yaw * yf for o, yf in zip(out, self.yaw_factor)]
        rpy_low, rpy_high = min(out), max(out)
        best = 0.5 - 0.5 * (rpy_low + rpy_high)
        if best > throttle_avg_max:
            best = throttle_avg_max
        scale = 1.0
        if rpy_high - rpy_low > 1.0:
            scale = 1.0 / (rpy_high - rpy_low)
        if best + rpy_low < 0.0 and -best / rpy_low < scale:
            scale = -best / rpy_low
        rpy_high *= scale
        rpy_low *= scale
        best = -rpy_low
        thr_adj = throttle - best
        if scale < 1.0:
            lim.roll = lim.pitch = lim.yaw = True
            if thr_adj > 0.0:
                lim.throttle_upper = True
            thr_adj = 0.0
        elif thr_adj < 0.0:
            thr_adj = 0.0
        elif thr_adj > 1.0 - (best + rpy_high):
            thr_adj = 1.0 - (best + rpy_high)
            lim.throttle_upper = True
        base = best + thr_adj
        res = []
        for o in out:
            v = base + scale * o
            res.append(0.0 if v < 0.0 else (1.0 if v > 1.0 else v))
        return res


def thrust_to_actuator(thrust: float, expo: float, spin_min: float, spin_max: float) -> float:
    """Motor thrust fraction [0, 1] -> ESC command [0, 1] (AP_MotorsMulticopter::thrust_to_actuator).

    Inverts ArduPilot's assumed thrust curve thrust = (1 - e) a + e a^2 (MOT_THST_EXPO = e) and maps
    a in [0, 1] onto [MOT_SPIN_MIN, MOT_SPIN_MAX]. Battery voltage compensation is not modelled.
    """
    thrust = min(max(thrust, 0.0), 1.0)
    if abs(expo) < 1e-6:
        a = thrust
    else:
        a = ((expo - 1.0) + math.sqrt((1.0 - expo) ** 2 + 4.0 * expo * thrust)) / (2.0 * expo)
    return spin_min + (spin_max - spin_min) * a


def make_thrust_to_actuator(expo: float, spin_min: float, spin_max: float):
    """Vectorised, constant-bound :func:`thrust_to_actuator` for the loop: ``f(thrusts) -> [esc]``."""
    span = spin_max - spin_min
    if abs(expo) < 1e-6:
        return lambda thrusts: [spin_min + span * (0.0 if t < 0.0 else (1.0 if t > 1.0 else t)) for t in thrusts]
    c1, c2, c3, c4 = expo - 1.0, (1.0 - expo) ** 2, 4.0 * expo, span / (2.0 * expo)
    sqrt = math.sqrt
    return lambda thrusts: [spin_min + c4 * (c1 + sqrt(c2 + c3 * (0.0 if t < 0.0 else (1.0 if t > 1.0 else t))))
                            for t in thrusts]
