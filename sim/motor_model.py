"""Motor + propeller model: first-order speed lag, thrust and reaction torque from speed.

Physics of one motor ``i`` (plain floats, called at the physics rate)::

    Omega_cmd_i = Omega_max * c_i                      c_i in [0, 1]: ESC command (fraction of full range)
    dOmega_i/dt = (Omega_cmd_i - Omega_i) / tau_m      integrated exactly over a step (zero-order hold)
    T_i         = k_t * Omega_i^2                      [N] along body -z
    Q_i         = s_i * kappa * T_i                    [N m] reaction torque about body +z (yaw)
    h_z        += -s_i * I_r * Omega_i                 rotor angular momentum along body +z (down)

with ``s_i = +1`` for a propeller spinning counter-clockwise seen from above (its reaction torque
turns the body clockwise = positive NED yaw) and ``-1`` for clockwise. Thrust is quadratic in the
ESC command at steady state; ArduPilot's MOT_THST_EXPO linearisation (in the autopilot emulator)
approximates that, as on a real vehicle.
"""

from __future__ import annotations

import math

from .vehicle_config import PropulsionConfig


class MotorBank:
    """Four (or N) identical motors at body positions ``positions_frd_m`` with spin signs ``spin_ccw``.

    Parameters
    ----------
    propulsion : motor/prop constants
    positions_frd_m : sequence of (x, y) [m] motor positions in body FRD
    spin_ccw : sequence of +1 (counter-clockwise from above) / -1 (clockwise)
    enabled : False turns the propulsion off (zero force and torque: pure-torque test mode)
    """

    def __init__(self, propulsion: PropulsionConfig, positions_frd_m, spin_ccw, enabled: bool = True):
        self.config = propulsion
        self.positions = [(float(px), float(py)) for px, py in positions_frd_m]
        self.spin = [float(s) for s in spin_ccw]
        self.count = len(self.positions)
        self.enabled = enabled
        self.k_t = propulsion.thrust_coefficient
        self.kappa = propulsion.yaw_torque_per_thrust
        self.omega_max = propulsion.max_motor_speed
        self.rotor_inertia = propulsion.rotor_inertia
        self.speed_rads = [0.0] * self.count
        # per motor: x, y [m], spin * kappa [m], spin * I_r [kg m^2]
        self._geometry = tuple((px, py, s * self.kappa, s * self.rotor_inertia)
                               for (px, py), s in zip(self.positions, self.spin))
        self._lag_dt = -1.0
        self._lag_alpha = 0.0

    def reset(self) -> None:
        """Stop every motor."""
        self.speed_rads = [0.0] * self.count

    def lag_alpha(self, dt_s: float) -> float:
        """Exact discrete gain 1 - exp(-dt/tau) of the first-order lag (cached per dt)."""
        if dt_s != self._lag_dt:
            self._lag_dt = dt_s
            self._lag_alpha = 1.0 - math.exp(-dt_s / self.config.motor_time_constant)
        return self._lag_alpha

    def step(self, esc_commands, dt_s: float):
        """Advance motor speeds by ``dt_s`` toward ``esc_commands`` (each clipped to [0, 1]).

        Returns
        -------
        (thrust_n, torque_x, torque_y, torque_z, rotor_momentum_z)
            total thrust [N] (along body -z), body torques [N m, FRD] from thrust offsets and
            reaction, and the rotor angular momentum along body +z [kg m^2/s].
        """
        if not self.enabled:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        a = self._lag_alpha if dt_s == self._lag_dt else self.lag_alpha(dt_s)
        wmax, k_t = self.omega_max, self.k_t
        speeds = self.speed_rads
        thrust = tx = ty = tz = hz = 0.0
        i = 0
        for (px, py, kappa_s, ir_s), c, w in zip(self._geometry, esc_commands, speeds):
            c = 0.0 if c < 0.0 else (1.0 if c > 1.0 else c)
            w += (wmax * c - w) * a
            speeds[i] = w
            i += 1
            ti = k_t * w * w
            thrust += ti
            # r x F with F = (0, 0, -T): (-y T, x T, 0)
            tx -= py * ti
            ty += px * ti
            tz += kappa_s * ti
            hz -= ir_s * w
        return thrust, tx, ty, tz, hz
