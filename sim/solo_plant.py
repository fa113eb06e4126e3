"""``SoloPlant``: the simulated Solo's physics alone (rigid body, motors, disturbances, ground), no autopilot.

Shared by the two ways the project flies its Solo physics, so the equations exist once:

- ``sim/copter.py`` (``SimulatedCopter``): the plant driven by the in-repo ArduCopter emulation;
- ``sim/json_physics.py``: the plant driven by genuine ArduCopter over its JSON SITL protocol.

One :meth:`SoloPlant.step` is one physics step of ``h`` seconds with the ESC commands held: first-order
motor lag (``motor_model.MotorBank``, ArduPilot quad-X geometry and spin from ``mixer.QUAD_X_LAYOUT``),
scenario torque events and wind (``disturbances.DisturbanceModel``), the RK4 rigid body with full inertia,
aerodynamic drag torque and propeller gyroscopic torque (``rigid_body_dynamics``), then ground contact.
Frames: world NED, body FRD; quaternion [w, x, y, z] rotating NED -> FRD. SI units throughout.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .attitude_math import q_from_euler, q_to_euler
from .disturbances import DisturbanceModel, load_wind
from .mixer import QUAD_X_LAYOUT, motor_positions_frd, motor_spin_ccw
from .motor_model import MotorBank
from .rigid_body_dynamics import RigidBodyParams, initial_state, make_rk4_stepper, resolve_ground_contact


def load_scenario_arg(scenario):
    """A ``mavastsm.scenarios.Scenario`` from a name/path; objects and None pass through."""
    if scenario is None or not isinstance(scenario, (str, Path)):
        return scenario
    from mavastsm.scenarios import load_scenario

    return load_scenario(scenario)


def noisy_attitude_and_rates(gauss, q_wxyz, gyro_frd_rads, sensor_noise):
    """(q, gyro) with white noise added: ``attitude_noise_std`` [rad] to roll, pitch and yaw, ``gyro_noise_std``
    [rad/s] to each body rate (vehicle YAML ``sensor_noise:``). ``gauss(mu, sigma)`` draws, in the order roll,
    pitch, yaw, p, q, r, so one seed gives one noise sequence whichever consumer uses it."""
    r, p, y = q_to_euler(q_wxyz)
    sa, sg = sensor_noise.attitude_noise_std, sensor_noise.gyro_noise_std
    q = q_from_euler(r + gauss(0.0, sa), p + gauss(0.0, sa), y + gauss(0.0, sa))
    g = gyro_frd_rads
    return q, (g[0] + gauss(0.0, sg), g[1] + gauss(0.0, sg), g[2] + gauss(0.0, sg))


class SoloPlant:
    """Rigid body + motors + disturbances + ground of the vehicle YAML, with the scenario's true inertia and payload.

    Parameters
    ----------
    config : loaded vehicle configuration (``vehicle_config.load_vehicle_config``)
    scenario : ``mavastsm.scenarios.Scenario`` or its name/path (torque events, true inertia ``true_inertia(I0)``
        as a full 3x3, payload mass; a name/path also brings the optional ``wind:`` section), or None
    physics_rate_hz : [Hz] rate of :meth:`step` (its ``h``)
    motors, aero_drag, gyroscopic, gravity, initial_position_ned_m, disturbances : as ``SimulatedCopter``

    Attributes
    ----------
    x : (13,) state list (rigid_body_dynamics layout: position NED, velocity NED, q_wxyz, rates FRD)
    accel_ned_ms2 : [m/s^2] kinematic acceleration dv/dt over the last step, NED (no gravity)
    in_ground_contact : resting on the ground plane
    thrust_n : [N] total propeller thrust of the last step
    external_torque_frd : [N m] constant extra body torque (pure-torque experiments)
    """

    def __init__(self, config, scenario=None, *, physics_rate_hz: float = 1000.0, motors: bool = True,
                 aero_drag: bool = True, gyroscopic: bool = True, gravity: bool = True,
                 initial_position_ned_m=(0.0, 0.0, 0.0), disturbances: DisturbanceModel | None = None):
        if not (math.isfinite(physics_rate_hz) and physics_rate_hz > 0.0):
            raise ValueError(f"physics_rate_hz must be a positive number, got {physics_rate_hz!r}")
        self.config = config
        self.scenario = load_scenario_arg(scenario)
        rb = config.rigid_body
        i0 = rb.inertia_diag
        inertia = self.scenario.true_inertia(i0) if self.scenario is not None else np.diag(i0)
        self.inertia_kgm2 = np.asarray(inertia, dtype=float)
        self.payload_kg = float(getattr(self.scenario, "payload_mass_kg", 0.0) or 0.0)
        af = config.airframe
        self.body = RigidBodyParams(
            mass_kg=rb.mass + self.payload_kg,
            gravity_ms2=rb.gravity if gravity else 0.0,
            inertia=tuple(tuple(float(v) for v in row) for row in self.inertia_kgm2),
            drag_torque_coeff=tuple(af.aero_drag_torque_coefficient) if aero_drag else (0.0, 0.0, 0.0),
            linear_drag_coeff=tuple(af.linear_drag_coefficient),
            gyroscopic=gyroscopic,
        )
        self._rk4 = make_rk4_stepper(self.body)
        self.motors = MotorBank(config.propulsion, motor_positions_frd(rb.arm_length, QUAD_X_LAYOUT),
                                motor_spin_ccw(QUAD_X_LAYOUT), enabled=motors)
        dist = disturbances or DisturbanceModel()
        if isinstance(scenario, (str, Path)):
            dist.add_wind(*load_wind(scenario))
        if self.scenario is not None:
            for ev in getattr(self.scenario, "disturbances", ()) or ():
                dist.add_torque_event(ev)
        self.disturbances = dist
        self.external_torque_frd = (0.0, 0.0, 0.0)
        self.physics_rate_hz = float(physics_rate_hz)
        self.h = 1.0 / self.physics_rate_hz
        self.ground_down_m = af.ground_level_down
        self.weight_n = self.body.mass_kg * self.body.gravity_ms2
        self.reset(initial_position_ned_m)

    def reset(self, position_ned_m=(0.0, 0.0, 0.0)) -> None:
        """At rest, level, facing north at ``position_ned_m`` [m] (on the ground if at or below it), motors stopped."""
        pos = tuple(float(v) for v in position_ned_m)
        self.x = initial_state(pos)
        self.in_ground_contact = pos[2] >= self.ground_down_m
        if self.in_ground_contact:
            self.x[2] = self.ground_down_m
        self.accel_ned_ms2 = (0.0, 0.0, 0.0)
        self.thrust_n = 0.0
        self.motors.reset()

    def step(self, esc_commands, t_s: float, h: float) -> None:
        """Advance by one physics step of ``h`` [s] from simulated time ``t_s`` [s] (where the disturbances are
        evaluated) with the ESC commands (ArduPilot motor order, each in [0, 1]) held over the step."""
        x = self.x
        thrust, tx, ty, tz, hz = self.motors.step(esc_commands, h)
        self.thrust_n = thrust
        ex, ey, ez = self.external_torque_frd
        dist = self.disturbances
        if dist.torque_events:
            dx, dy, dz = dist.torque_nm(t_s)
            ex += dx
            ey += dy
            ez += dz
        wn = we = wd = 0.0
        if dist.gusts or dist.steady_wind != (0.0, 0.0, 0.0):
            wn, we, wd = dist.wind_ned_ms(t_s)
        u = (0.0, 0.0, -thrust, tx + ex, ty + ey, tz + ez, hz, wn, we, wd)
        if self.in_ground_contact and thrust < self.weight_n and wd == 0.0:
            # Resting on the ground with less thrust than weight: integrating would only push the body
            # into the ground and resolve_ground_contact would put it back at rest (same state), so
            # skip the integration. Ground friction also keeps it from turning.
            self.accel_ned_ms2 = (0.0, 0.0, 0.0)
            return
        vn, ve, vd = x[3], x[4], x[5]
        x = self._rk4(x, u, h)
        if x[2] >= self.ground_down_m:
            x, self.in_ground_contact = resolve_ground_contact(x, self.ground_down_m)
        else:
            self.in_ground_contact = False
        self.accel_ned_ms2 = ((x[3] - vn) / h, (x[4] - ve) / h, (x[5] - vd) / h)
        self.x = x
