"""Simulator vehicle constants loaded from ``configs/vehicle/<name>.yaml`` (sections ``rigid_body``,
``propulsion``, ``airframe``, ``battery``, ``sensor_noise``; see the YAML for units and sources).

Nothing physical is hard-coded in the simulator: every constant below comes from the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from mavastsm.config_loading import build_dataclass, resolve_config
from mavastsm.solo_model import DEFAULT_VEHICLE_CONFIG, SoloRigidBody


@dataclass(frozen=True)
class PropulsionConfig:
    """One motor + propeller, identical for all four. See ``propulsion:`` in the vehicle YAML.

    Attributes
    ----------
    max_thrust_per_motor : [N] thrust at ``max_motor_speed``; thrust = k_t * Omega^2
    max_motor_speed : [rad/s] propeller speed at full ESC command
    motor_time_constant : [s] first-order lag of the speed to its command
    yaw_torque_per_thrust : [m] reaction torque / thrust (kappa)
    rotor_inertia : [kg m^2] I_r of paper eq. 8
    """

    max_thrust_per_motor: float
    max_motor_speed: float
    motor_time_constant: float
    yaw_torque_per_thrust: float
    rotor_inertia: float

    @property
    def thrust_coefficient(self) -> float:
        """k_t [N/(rad/s)^2]."""
        return self.max_thrust_per_motor / self.max_motor_speed**2


@dataclass(frozen=True)
class AirframeConfig:
    """Aerodynamic drag and ground plane. See ``airframe:`` in the vehicle YAML.

    Attributes
    ----------
    aero_drag_torque_coefficient : [N m s^2/rad^2] (3,) k_a of paper eq. 9, body FRD axes
    linear_drag_coefficient : [N s/m] (3,) translational drag per NED axis
    ground_level_down : [m] NED down coordinate of the ground
    """

    aero_drag_torque_coefficient: tuple[float, float, float]
    linear_drag_coefficient: tuple[float, float, float]
    ground_level_down: float


@dataclass(frozen=True)
class BatteryConfig:
    """4S pack model. See ``battery:`` in the vehicle YAML. [mAh], [V], [ohm], [A]."""

    capacity: float
    voltage_full: float
    voltage_empty: float
    internal_resistance: float
    idle_current: float
    hover_current: float

    def validate(self) -> list[tuple[str, str]]:
        if self.voltage_empty >= self.voltage_full:
            return [("voltage_empty", "must be below voltage_full")]
        return []


@dataclass(frozen=True)
class SensorNoiseConfig:
    """White noise on the reported attitude [rad] and body rates [rad/s] (only when noise is enabled)."""

    attitude_noise_std: float
    gyro_noise_std: float


@dataclass(frozen=True)
class VehicleConfig:
    """Everything physical the simulator needs, plus the path it came from."""

    path: Path
    rigid_body: SoloRigidBody
    propulsion: PropulsionConfig
    airframe: AirframeConfig
    battery: BatteryConfig
    sensor_noise: SensorNoiseConfig


def load_vehicle_config(name_or_path: str | Path | None = None) -> VehicleConfig:
    """Load and validate a simulator vehicle file (default: the packaged Solo).

    Parsed files are cached per (path, modification time): YAML parsing costs ~0.1 s and tests
    build many vehicles. The result is immutable, so sharing it is safe.

    Raises
    ------
    mavastsm.errors.ConfigError
        one line naming file, key, value and rule.
    """
    path = resolve_config(name_or_path or DEFAULT_VEHICLE_CONFIG, "vehicle")
    return _load_cached(str(path), path.stat().st_mtime_ns)


@lru_cache(maxsize=16)
def _load_cached(path_str: str, mtime_ns: int) -> VehicleConfig:
    path = Path(path_str)
    return VehicleConfig(
        path=path,
        rigid_body=build_dataclass(SoloRigidBody, path, "rigid_body"),
        propulsion=build_dataclass(PropulsionConfig, path, "propulsion"),
        airframe=build_dataclass(AirframeConfig, path, "airframe"),
        battery=build_dataclass(BatteryConfig, path, "battery"),
        sensor_noise=build_dataclass(SensorNoiseConfig, path, "sensor_noise"),
    )
