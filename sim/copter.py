"""``SimulatedCopter``: physics + ArduCopter emulation of a 3DR Solo, with no MAVLink, sockets or clock.

This is the contract the MAVLink layer (``sim/mavlink_vehicle.py``) drives: it calls ``step(dt)``
to advance simulated time, forwards commands (``set_mode``, ``arm``, ``disarm``,
``handle_attitude_target``) and reads the SI read-outs (NED/FRD) to fill telemetry.

Inside one ``step``, physics runs at ``physics_rate_hz`` (default 1 kHz, RK4 on the 6-DoF rigid
body, exact first-order motor lag) and the autopilot emulation at the SCHED_LOOP_RATE parameter
(default 400 Hz), each at its own tick times on one integer step counter, so results depend only
on the sequence of ``step`` calls (deterministic for a given seed).

Backward-compatible additions to the shared contract (keyword-only constructor options and
extra attributes): ``motors``, ``aero_drag``, ``gyroscopic``, ``gravity``, ``initial_position_ned_m``,
``disturbances``, ``set_external_torque``, ``restart_disturbance_clock``, ``land_complete``,
``in_ground_contact``, ``rejected_attitude_targets``, ``mode_name``, ``profile``,
``prearm_check``, ``true_quaternion_wxyz``, ``true_body_rates_rads``, ``motor_speeds_rads``,
``battery_current_a``, ``battery_consumed_mah``, ``time_boot_ms``, ``attitude_sample()`` (plain-float
Euler angles and body rates for the per-ATTITUDE path).
"""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np

from mavastsm.errors import ConfigError

from .arducopter_profile import ArduCopterProfile, load_profile
from .attitude_math import q_to_euler
from .autopilot_emulator import MODE_NAMES, ArduCopterEmulator, Measurement
from .disturbances import DisturbanceModel
from .parameters import ParameterTable, apply_parameter_set
from .solo_plant import SoloPlant, load_scenario_arg, noisy_attitude_and_rates
from .vehicle_config import load_vehicle_config

# MAV_STATE
MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
# MAV_SEVERITY
MAV_SEVERITY_WARNING = 4


_load_scenario = load_scenario_arg  # kept for importers of the old name


class SimulatedCopter:
    """A simulated Solo flying under emulated ArduCopter 4.2+ (see module docstring).

    Parameters
    ----------
    vehicle_config : vehicle YAML name or path (default: packaged ``solo``)
    scenario : ``mavastsm.scenarios.Scenario``, or its name/path: disturbance torques, true inertia
        (``true_inertia(I0)``, full 3x3) and payload mass are applied to the plant
    seed : seed of the sensor-noise generator
    physics_rate_hz : [Hz] physics integration rate
    noise : add white noise (vehicle YAML ``sensor_noise:``) to the attitude and rates the
        autopilot sees and the read-outs report
    motors : False = no propulsion; the body is driven only by ``set_external_torque`` and the
        scenario (pure-torque mode for plant comparisons)
    aero_drag, gyroscopic : include the paper's tau_a (eq. 9) and tau_p (eq. 8)
    gravity : False removes gravity (pure-attitude experiments far from the ground)
    initial_position_ned_m : [m] start position (default on the ground at the origin)
    profile : the ArduCopter emulated (``sim/arducopter_profile.py``; default: the default profile): its tuning
        (``parameter_set``), loop rate, take-off timing, density compensation and position estimate; the MAVLink
        face reads its wire habits from the same record (``copter.profile``)
    field_elevation_m : [m AMSL] the ground's altitude, where density compensation takes the air density ratio
        (the MAVLink server passes its home altitude)
    disturbances : extra DisturbanceModel (wind, gusts, code-defined torques); the scenario's
        torque events, and the optional ``wind:`` section of a scenario given by name/path, are
        added to it

    Raises
    ------
    mavastsm.errors.ConfigError
        bad vehicle or scenario file (one line naming file, key, value, rule).
    """

    def __init__(self, vehicle_config: str | Path | None = None, scenario=None, seed: int = 0,
                 physics_rate_hz: float = 1000.0, noise: bool = False, *, motors: bool = True,
                 aero_drag: bool = True, gyroscopic: bool = True, gravity: bool = True,
                 initial_position_ned_m=(0.0, 0.0, 0.0), disturbances: DisturbanceModel | None = None,
                 profile: ArduCopterProfile | None = None, field_elevation_m: float = 0.0):
        if not (math.isfinite(physics_rate_hz) and physics_rate_hz > 0.0):
            raise ValueError(f"physics_rate_hz must be a positive number, got {physics_rate_hz!r}")
        self.config = load_vehicle_config(vehicle_config)
        self.profile = profile if profile is not None else load_profile()
        self.params = ParameterTable.from_vehicle_config(self.config.path)
        apply_parameter_set(self.params, self.profile.parameter_set)
        ok, reason = self.params.set("SCHED_LOOP_RATE", self.profile.sched_loop_rate_hz)
        if not ok:
            raise ConfigError(f"profile {self.profile.name}: sched_loop_rate_hz refused: {reason}")
        # the physics (rigid body, motors, disturbances, ground), shared with sim/json_physics.py
        self.plant = SoloPlant(self.config, scenario, physics_rate_hz=physics_rate_hz, motors=motors,
                               aero_drag=aero_drag, gyroscopic=gyroscopic, gravity=gravity,
                               initial_position_ned_m=initial_position_ned_m, disturbances=disturbances)
        plant = self.plant
        self.scenario = plant.scenario
        self.inertia_kgm2 = plant.inertia_kgm2
        self.body = plant.body
        self.motors = plant.motors
        self.disturbances = plant.disturbances
        self.autopilot = ArduCopterEmulator(self.params, self.profile, field_elevation_m)
        self.physics_rate_hz = plant.physics_rate_hz
        self._h = plant.h
        self._step_count = 0
        self._target_steps = 0.0
        self._next_autopilot_step = 0
        self._ap_rate_hz = 0.0
        self._ap_base_step = 0
        self._ap_ticks = 0
        self._rng = random.Random(seed)
        self.noise = bool(noise)
        self._noisy = None  # (q, gyro) last noisy measurement when noise is on
        # battery
        bat = self.config.battery
        self._consumed_mah = 0.0
        self.battery_current_a = bat.idle_current
        rb = self.config.rigid_body
        self._hover_thrust = (rb.mass + plant.payload_kg) * rb.gravity
        self.statustext_queue: list[tuple[int, str]] = []

    # ------------------------------------------------------------------ time
    @property
    def time_s(self) -> float:
        """[s] simulated time since boot."""
        return self._step_count / self.physics_rate_hz

    @property
    def time_boot_ms(self) -> int:
        """[ms] simulated time since boot, exact (``int(time_s * 1000)`` can be 1 ms short by rounding)."""
        return int((self._step_count * 1000) // self.physics_rate_hz)

    def step(self, dt_s: float) -> None:
        """Advance physics and the autopilot by ``dt_s`` [s] (internally at ``physics_rate_hz``).

        Fractions of a physics step are carried over to the next call. Never raises on finite
        input; a non-finite or negative ``dt_s`` is ignored.
        """
        if not (dt_s > 0.0 and math.isfinite(dt_s)):
            return
        self._target_steps += dt_s * self.physics_rate_hz
        n = int(self._target_steps - self._step_count + 1e-9)
        for _ in range(n):
            self._physics_step()
        if self.autopilot.statustext:
            self.statustext_queue.extend(self.autopilot.statustext)
            self.autopilot.statustext.clear()

    def _measurement(self) -> Measurement:
        x = self._x
        q = (x[6], x[7], x[8], x[9])
        gyro = (x[10], x[11], x[12])
        if self.noise:
            q, gyro = noisy_attitude_and_rates(self._rng.gauss, q, gyro, self.config.sensor_noise)
            self._noisy = (q, gyro)
        return Measurement(q, gyro, (x[0], x[1], x[2]), (x[3], x[4], x[5]), self._accel)

    def _physics_step(self) -> None:
        k = self._step_count
        if k >= self._next_autopilot_step:
            self._autopilot_tick(k)
        self.plant.step(self.autopilot.esc_commands, k * self._h, self._h)
        self._step_count = k + 1

    # plant state, under the names the rest of this class (and the benchmarks) use
    @property
    def _x(self):
        return self.plant.x

    @property
    def _accel(self):
        return self.plant.accel_ned_ms2

    @property
    def _thrust_n(self) -> float:
        return self.plant.thrust_n

    @property
    def in_ground_contact(self) -> bool:
        return self.plant.in_ground_contact

    @property
    def external_torque_frd(self):
        return self.plant.external_torque_frd

    def _autopilot_tick(self, k: int) -> None:
        """Run the autopilot at physics step ``k`` and schedule its next tick.

        Ticks fall on the first physics step at or after each multiple of 1/SCHED_LOOP_RATE (at
        400 Hz with 1 kHz physics: alternately 2 and 3 ms apart, 400 per second on average); the
        controllers use the nominal loop period, as ArduCopter's fixed-rate scheduler does.
        """
        ap = self.autopilot
        rate = min(ap.loop_rate_hz, self.physics_rate_hz)  # cannot tick faster than the physics
        if rate != self._ap_rate_hz:  # (re)start the tick grid, e.g. after SCHED_LOOP_RATE changed
            self._ap_rate_hz = rate
            self._ap_base_step = k
            self._ap_ticks = 0
        h = self._h
        ap.update(self._measurement(), 1.0 / rate, self.in_ground_contact, now_s=k * h)
        self._ap_ticks += 1
        nxt = self._ap_base_step + math.ceil(self._ap_ticks * self.physics_rate_hz / rate - 1e-9)
        self._next_autopilot_step = max(nxt, k + 1)
        self._update_battery((self._next_autopilot_step - k) * h)

    def _update_battery(self, dt_s: float) -> None:
        """Current ~ (thrust / hover thrust)^1.5 (momentum theory); integrate the charge used [mAh]."""
        bat = self.config.battery
        ratio = self._thrust_n / self._hover_thrust
        motor_current = bat.hover_current * ratio * math.sqrt(ratio) if ratio > 0.0 else 0.0
        self.battery_current_a = bat.idle_current + motor_current
        self._consumed_mah += self.battery_current_a * dt_s / 3.6

    # ------------------------------------------------------------------ commands
    def _meas_now(self) -> Measurement:
        x = self._x
        return Measurement((x[6], x[7], x[8], x[9]), (x[10], x[11], x[12]), (x[0], x[1], x[2]),
                           (x[3], x[4], x[5]), self._accel)

    def _flush_text(self) -> None:
        if self.autopilot.statustext:
            self.statustext_queue.extend(self.autopilot.statustext)
            self.autopilot.statustext.clear()

    def set_mode(self, mode_number: int) -> tuple[bool, str]:
        """ArduCopter Mode::Number (0 STABILIZE, 2 ALT_HOLD, 4 GUIDED, 5 LOITER, 9 LAND, 20 GUIDED_NOGPS).
        Returns (accepted, reason)."""
        out = self.autopilot.set_mode(mode_number, self._meas_now())
        self._flush_text()
        return out

    def arm(self, force: bool = False) -> tuple[bool, str]:
        """Arm the motors (GCS arming). Refused in LAND/RTL/AUTO with "Arm: Mode not armable"."""
        out = self.autopilot.arm(self._meas_now(), force=force)
        self._flush_text()
        return out

    def prearm_check(self) -> tuple[bool, str]:
        """MAV_CMD_RUN_PREARM_CHECKS: (True, "") or (False, "PreArm: ..."); queues the failure text."""
        failure = self.autopilot.prearm_failure()
        if failure:
            self.statustext_queue.append((2, failure))
        return not failure, failure

    def disarm(self, force: bool = False) -> tuple[bool, str]:
        """Disarm; without ``force`` refused while not landed (ArduCopter's rule)."""
        out = self.autopilot.disarm(force=force, reason="forced" if force else "")
        self._flush_text()
        return out

    def handle_attitude_target(self, type_mask: int, q_wxyz, body_rates_rads, thrust: float) -> tuple[bool, str]:
        """SET_ATTITUDE_TARGET with ArduCopter 4.2+ semantics (docs/design-decisions.md, MAV-5).

        Outside GUIDED/GUIDED_NOGPS: (False, "not in guided mode"), nothing changes. Mask bit 64
        (THROTTLE_IGNORE), mixed rate-ignore bits, a non-unit quaternion (| |q|^2 - 1 | >= 1e-3) or
        non-finite rates: rejected, and the vehicle stops and holds (level, zero climb; position hold
        in GUIDED). Accepted targets refresh the GUID_TIMEOUT timer.
        """
        self.autopilot.time_s = self.time_s
        return self.autopilot.handle_attitude_target(type_mask, q_wxyz, body_rates_rads, thrust, self._meas_now)

    def set_external_torque(self, torque_frd_nm) -> None:
        """Constant extra torque [N m, body FRD] applied until changed (e.g. pure-torque tests)."""
        t = tuple(float(v) for v in torque_frd_nm)
        if len(t) != 3 or not all(math.isfinite(v) for v in t):
            raise ValueError(f"external torque must be 3 finite numbers, got {torque_frd_nm!r}")
        self.plant.external_torque_frd = t

    def restart_disturbance_clock(self) -> None:
        """Make the scenario's disturbance times count from now instead of from boot."""
        self.disturbances.restart_clock(self.time_s)

    # ------------------------------------------------------------------ read-outs
    @property
    def mode_number(self) -> int:
        return self.autopilot.mode_number

    @property
    def mode_name(self) -> str:
        return MODE_NAMES.get(self.autopilot.mode_number, str(self.autopilot.mode_number))

    @property
    def armed(self) -> bool:
        return self.autopilot.armed

    @property
    def landed(self) -> bool:
        """ArduCopter ``land_complete``."""
        return self.autopilot.land_complete

    land_complete = landed

    @property
    def system_status(self) -> int:
        """MAV_STATE: 3 STANDBY when landed, 4 ACTIVE flying, 5 CRITICAL when the battery is empty."""
        if self.battery_remaining_pct <= 0:
            return MAV_STATE_CRITICAL
        return MAV_STATE_STANDBY if self.autopilot.land_complete else MAV_STATE_ACTIVE

    @property
    def rejected_attitude_targets(self) -> int:
        """Count of SET_ATTITUDE_TARGET messages rejected by mask/quaternion validation."""
        return self.autopilot.rejected_targets

    @property
    def quaternion_wxyz(self) -> np.ndarray:
        """(4,) attitude NED->FRD (noisy when noise is on)."""
        if self.noise and self._noisy is not None:
            return np.array(self._noisy[0])
        return np.array(self._x[6:10])

    @property
    def euler_rad(self) -> np.ndarray:
        """(3,) [rad] ZYX roll, pitch, yaw (noisy when noise is on)."""
        if self.noise and self._noisy is not None:
            return np.array(q_to_euler(self._noisy[0]))
        x = self._x
        return np.array(q_to_euler((x[6], x[7], x[8], x[9])))

    def attitude_sample(self) -> tuple[float, float, float, float, float, float]:
        """(roll, pitch, yaw [rad], p, q, r [rad/s]) as plain floats for the per-ATTITUDE path of the MAVLink layer:
        the attitude of ``euler_rad`` and, as ArduCopter's ATTITUDE reports them (AHRS ``get_gyro``), the body rates
        through the autopilot's gyro filter (INS_GYRO_FILTER; ``body_rates_rads`` is the unfiltered gyro). Noisy
        when noise is on; no NumPy arrays."""
        if self.noise and self._noisy is not None:
            q = self._noisy[0]
        else:
            x = self._x
            q = (x[6], x[7], x[8], x[9])
        roll, pitch, yaw = q_to_euler(q)
        p, q_rate, r = self.autopilot.gyro_filter.out
        return roll, pitch, yaw, p, q_rate, r

    @property
    def body_rates_rads(self) -> np.ndarray:
        """(3,) [rad/s] body FRD p, q, r (noisy when noise is on)."""
        if self.noise and self._noisy is not None:
            return np.array(self._noisy[1])
        return np.array(self._x[10:13])

    @property
    def true_quaternion_wxyz(self) -> np.ndarray:
        """(4,) noise-free attitude."""
        return np.array(self._x[6:10])

    @property
    def true_body_rates_rads(self) -> np.ndarray:
        """(3,) [rad/s] noise-free body rates."""
        return np.array(self._x[10:13])

    @property
    def position_ned_m(self) -> np.ndarray:
        return np.array(self._x[0:3])

    @property
    def velocity_ned_ms(self) -> np.ndarray:
        return np.array(self._x[3:6])

    @property
    def attitude_target(self):
        """(q_wxyz (4,), body_rates_rads (3,), thrust) of the attitude controller, for ATTITUDE_TARGET."""
        ap = self.autopilot
        return np.array(ap.att_target), np.array(ap.ang_vel_target), float(ap.throttle_in)

    @property
    def motor_outputs_norm(self) -> np.ndarray:
        """(4,) ESC commands in [0, 1], ArduPilot motor order."""
        return np.array(self.autopilot.esc_commands)

    @property
    def motor_speeds_rads(self) -> np.ndarray:
        """(4,) [rad/s] propeller speeds."""
        return np.array(self.motors.speed_rads)

    @property
    def battery_consumed_mah(self) -> float:
        return self._consumed_mah

    @property
    def battery_remaining_pct(self) -> int:
        cap = self.config.battery.capacity
        return int(max(0.0, min(100.0, 100.0 * (1.0 - self._consumed_mah / cap))))

    @property
    def battery_voltage_v(self) -> float:
        bat = self.config.battery
        soc = max(0.0, 1.0 - self._consumed_mah / bat.capacity)
        open_circuit = bat.voltage_empty + (bat.voltage_full - bat.voltage_empty) * soc
        return open_circuit - self.battery_current_a * bat.internal_resistance
