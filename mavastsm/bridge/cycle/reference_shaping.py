"""Acceleration-limited reference shaping (pure): turns the paper's raw steps into a trajectory the
autopilot can realise.

Why: ArduCopter shapes every body-rate command with ATC_ACCEL_R/P/Y_MAX. A sliding surface
sigma = e_dot + lambda e (eq. 19) asks for e_dot = -lambda e, i.e. 4.36 * 45 deg/s on the yaw step,
which the yaw acceleration limit cannot deliver and cannot stop: the saturated loop overshoots.
Shaping the reference with the same limit (a fraction of it, leaving margin for feedback) gives a
feasible Theta_d(t) with consistent Theta_dot_d and Theta_ddot_d, which the controller's equivalent
control (eq. 24) feeds forward. Tracking metrics are still computed against the raw reference.

Per axis, the shaped reference r follows the raw target R with ArduPilot's ``sqrt_controller``
velocity demand and a bounded acceleration::

    v_des = sqrt_controller(wrap(R - r), p, a) + R_dot
    r_ddot = clip(k_v (v_des - r_dot), -a, a);   r_dot += r_ddot dt;   r += r_dot dt

With an ``envelope`` (hold_s, decel, max_tilt, fraction), roll and pitch ``v_des`` away from level are also
capped at ``fraction`` of ``safety.last_setpoint_rate_bound`` at the shaped angle: the reference stays
inside the envelope in which the bridge's last setpoint is survivable, leaving the rest for feedback
(otherwise the controller chases a trajectory whose commands the safety clip cuts, and winds up).
"""

from __future__ import annotations

from ...ap_math import sqrt_controller  # ArduPilot's, one copy (dt 0: our shaper leaves it unclamped)
from ...frames import wrap_angle_float as _wrap
from .safety import last_setpoint_rate_bound


class AccelLimitedShaper:
    """Three independent axes [roll, pitch, yaw]; yaw errors wrapped to (-pi, pi].

    Parameters
    ----------
    accel_max_radss : [rad/s^2] (3,) acceleration bound of the shaped reference
    p : [1/s] position gain of the sqrt controller, per axis or one for all
    k_v : [1/s] velocity-tracking gain
    """

    def __init__(self, accel_max_radss, p=4.0, k_v: float = 20.0, envelope=None) -> None:
        self.accel_max = tuple(float(a) for a in accel_max_radss)
        self.p = tuple(float(x) for x in p) if hasattr(p, "__len__") else (float(p),) * 3
        self.k_v = float(k_v)
        self.envelope = envelope  # (hold_s, (decel_roll, decel_pitch) [rad/s^2], max_tilt_rad, fraction) or None
        self.r = [0.0, 0.0, 0.0]
        self.v = [0.0, 0.0, 0.0]

    def reset(self, attitude_rad, rate_rads=(0.0, 0.0, 0.0)) -> None:
        """Start the shaped reference at the given attitude [rad] and Euler rate [rad/s]."""
        self.r = [float(x) for x in attitude_rad]
        self.v = [float(x) for x in rate_rads]

    def step(self, target_rad, target_rate_rads, dt_s: float):
        """Advance by dt; returns (Theta_d, Theta_dot_d, Theta_ddot_d) as 3-tuples [rad, rad/s, rad/s^2]."""
        out_r, out_v, out_a = [], [], []
        for i in range(3):
            err = float(target_rad[i]) - self.r[i]
            if i == 2:
                err = _wrap(err)
            a_max = self.accel_max[i]
            v_des = sqrt_controller(err, self.p[i], a_max) + float(target_rate_rads[i])
            if self.envelope is not None and i < 2 and v_des * self.r[i] > 0.0:  # moving away from level
                hold_s, decel, max_tilt, fraction = self.envelope
                cap = fraction * last_setpoint_rate_bound(self.r[i], hold_s, decel[i], max_tilt)
                v_des = max(-cap, min(cap, v_des))
            acc = min(max(self.k_v * (v_des - self.v[i]), -a_max), a_max)
            self.v[i] += acc * dt_s
            self.r[i] += self.v[i] * dt_s
            out_r.append(self.r[i] if i < 2 else _wrap(self.r[i]))
            out_v.append(self.v[i])
            out_a.append(acc)
        return tuple(out_r), tuple(out_v), tuple(out_a)
