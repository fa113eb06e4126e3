"""A mirror of ArduCopter's hidden attitude target, so a body-rate command means a body rate (pure).

ArduCopter does not simply track the body rates we send. ``input_rate_bf_roll_pitch_yaw``
(AC_AttitudeControl) slews them with ATC_ACCEL_*_MAX into a target angular velocity omega_t and
*integrates* omega_t into an attitude target q_t; the rate loop is then asked for::

    omega_demand = sqrt_controller(rotvec(q^-1 q_t), ATC_ANG_*_P, a_ang) + omega_t      (1)

with a_ang = ATC_ACCEL_*_MAX / 2 clamped to [40, 720] deg/s^2 (roll, pitch) or [10, 120] deg/s^2
(yaw) (``update_ang_vel_target_from_att_error``). Whenever the vehicle lags our command, q_t runs
ahead of the real attitude and the angle term of (1) keeps turning the vehicle after we asked it to
stop: a hidden integrator inside our loop, which made the 45 deg yaw step limit-cycle.

This model keeps an estimate of (q_t, omega_t), re-synchronised from ATTITUDE_TARGET (which reports
exactly q_t and omega_t) and propagated with our own commands in between, and chooses the command
so that (1) equals the body rate we want::

    omega_cmd = omega_des - sqrt_controller(rotvec(q^-1 q_t), P, a_ang)                (2)

With M6 (``compensate_yaw=False``, the default through ``mapping.yaw_command_base = reference``) only
roll and pitch are compensated: the yaw command is built on the reference's yaw rate, so q_t's heading
follows the reference and ArduCopter's yaw angle loop is *wanted*, to hold the heading against a yaw
torque that the yaw command, clipped at ATC_ACCEL_Y_MAX, could not (docs/bridge.md, M6).

PX4 has no such hidden target for body-rate setpoints (they go to the rate controller), so the
model is used for ArduPilot only. Quaternions are [w, x, y, z], NED -> FRD; rates body FRD [rad/s].
"""

from __future__ import annotations

import math

from ...ap_math import sqrt_controller
from ...frames import q_conj, q_from_euler, q_from_rotation_vector, q_mul, q_normalize, q_to_rotation_vector  # noqa: F401 (q_from_euler: re-exported)

ANGLE_LOOP_ACCEL_BOUNDS_DEG = ((40.0, 720.0), (40.0, 720.0), (10.0, 120.0))


def angle_loop_accel(accel_max_radss) -> tuple[float, float, float]:
    """a_ang of eq. (1): half the shaping limit, clamped per axis like ArduCopter."""
    out = []
    for a, (lo, hi) in zip(accel_max_radss, ANGLE_LOOP_ACCEL_BOUNDS_DEG):
        out.append(min(max(a / 2.0, math.radians(lo)), math.radians(hi)) if a > 0 else 0.0)
    return tuple(out)  # type: ignore[return-value]


class AutopilotTargetModel:
    """Estimate of ArduCopter's (q_t, omega_t) and the compensation (2).

    Parameters
    ----------
    ang_p : [1/s] (3,) ATC_ANG_RLL_P, ATC_ANG_PIT_P, ATC_ANG_YAW_P
    accel_max_radss : [rad/s^2] (3,) ATC_ACCEL_R/P/Y_MAX
    compensate_yaw : cancel the yaw angle loop too (False with M6: the yaw command is left as it is)
    """

    def __init__(self, ang_p, accel_max_radss, compensate_yaw: bool = True) -> None:
        self.ang_p = tuple(float(p) for p in ang_p)
        self.compensate_yaw = compensate_yaw
        self.accel_max = tuple(float(a) for a in accel_max_radss)
        self.ang_accel = angle_loop_accel(self.accel_max)
        self.q_t: tuple[float, float, float, float] | None = None
        self.w_t = [0.0, 0.0, 0.0]
        self.last_sync_ms: int | None = None
        self.syncs = 0

    def reset(self, q_target, w_target=(0.0, 0.0, 0.0)) -> None:
        self.q_t = q_normalize(tuple(float(c) for c in q_target))
        self.w_t = [float(w) for w in w_target]

    def sync(self, time_boot_ms: int, q_target, w_target) -> None:
        """Adopt the autopilot's reported target (ATTITUDE_TARGET) if it is newer than the last one."""
        if self.last_sync_ms is not None and time_boot_ms <= self.last_sync_ms:
            return
        n = math.sqrt(sum(float(c) ** 2 for c in q_target))
        if not (abs(n - 1.0) < 1e-2) or not all(math.isfinite(float(w)) for w in w_target):
            return
        self.last_sync_ms = time_boot_ms
        self.reset(q_target, w_target)
        self.syncs += 1

    def compensate(self, q_meas, w_des) -> tuple[float, float, float]:
        """omega_cmd of eq. (2) for a wanted body rate ``w_des`` at measured attitude ``q_meas``."""
        if self.q_t is None:
            return tuple(w_des)  # type: ignore[return-value]
        e = q_to_rotation_vector(q_mul(q_conj(q_meas), self.q_t))
        p, a = self.ang_p, self.ang_accel
        yaw = w_des[2] - sqrt_controller(e[2], p[2], a[2]) if self.compensate_yaw else w_des[2]
        return (w_des[0] - sqrt_controller(e[0], p[0], a[0]), w_des[1] - sqrt_controller(e[1], p[1], a[1]), yaw)

    def advance(self, w_cmd, dt_s: float) -> None:
        """Propagate the model by one cycle of our (sent) command: slew omega_t, integrate q_t."""
        if self.q_t is None:
            return
        for i in range(3):
            d = self.accel_max[i] * dt_s
            self.w_t[i] = min(max(w_cmd[i], self.w_t[i] - d), self.w_t[i] + d) if self.accel_max[i] > 0 else w_cmd[i]
        self.q_t = q_normalize(q_mul(self.q_t, q_from_rotation_vector(*[w * dt_s for w in self.w_t])))
