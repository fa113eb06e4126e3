"""Bridge configuration: ``configs/bridge.yaml`` -> frozen dataclasses, one per section.

Field names equal YAML keys; units are in the YAML (and in the suffixes here). Overrides come as
``"section.key" -> raw value`` (from ``--set section.key=value``) and are validated against the
same spec as the file's value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..config_loading import build_dataclass, resolve_config
from ..errors import ConfigError

DEFAULT_BRIDGE_CONFIG = "bridge"


@dataclass(frozen=True)
class LinkConfig:
    heartbeat_wait_s: float
    link_loss_timeout_s: float
    command_ack_timeout_s: float
    command_retries: int
    param_timeout_s: float
    arm_timeout_s: float
    attitude_wait_s: float
    arm_retry_s: float
    arm_reason_wait_s: float
    handback_confirm_s: float
    source_component: int
    heartbeat_type: str


@dataclass(frozen=True)
class TimingConfig:
    attitude_rate_hz: float
    attitude_rate_min_hz: float
    attitude_target_rate_hz: float
    interval_reassert_s: float
    rate_measure_s: float
    dt_min_s: float
    dt_max_s: float
    stale_timeout_s: float
    failsafe_hold_s: float
    hold_send_hz: float
    prestream_s: float
    overrun_cycles: int
    invalid_samples: int
    alpha_pinned_s: float
    gc_freeze_s: float
    gil_switch_interval_s: float
    realtime_priority: int
    log_flush_s: float
    samples_in_memory: int
    altitude_rate_hz: float
    rate_measure_slack_s: float

    def validate(self) -> list[tuple[str, str]]:
        if self.dt_max_s <= self.dt_min_s:
            return [("dt_max_s", f"must be > dt_min_s ({self.dt_min_s})")]
        return []


@dataclass(frozen=True)
class MappingConfig:
    method: str
    rate_time_constant_s: tuple[float, float, float]
    loop_delay_s: tuple[float, float, float]
    bound_adaptive_gain: bool
    compensate_autopilot_target: bool
    yaw_command_base: str
    yaw_integral: str
    roll_pitch_command_base: str
    yaw_trim_gain_per_s: float
    yaw_trim_error_limit_rad: float
    yaw_trim_band_rad: float
    yaw_loop_gain: float
    accel_limit_radss: tuple[float, float, float]
    torque_authority_nm: tuple[float, float, float]
    command_accel_clip: str
    limit_controller_torque: bool
    reference_shaping: bool
    shaping_accel_fraction: tuple[float, float, float]
    shaping_p: tuple[float, float, float]
    shaping_envelope_fraction: float
    prefilter_wn_rads: float
    identify_in_flight: str


@dataclass(frozen=True)
class ThrustConfig:
    semantics: str
    set_guid_options: bool
    climb_hold_norm: float
    hover_collective_norm: float
    hover_from_vehicle: bool
    hover_measure_s: float
    tilt_compensation: bool
    max_tilt_compensation: float
    altitude_hold: bool
    altitude_kp: float
    altitude_ki: float
    altitude_kd: float
    altitude_max_delta_norm: float
    takeoff_climb_norm: float
    takeoff_settle_s: float
    takeoff_timeout_s: float
    takeoff_ramp_s: float
    takeoff_approach_m: float


@dataclass(frozen=True)
class LimitsConfig:
    max_reference_tilt_deg: float
    envelope_tilt_deg: float
    max_rate_cmd_rads: tuple[float, float, float]
    max_input_rate_rads: float
    thrust_min_norm: float
    thrust_max_norm: float
    set_setpoint_timeout: bool
    setpoint_timeout_s: float
    last_setpoint_tilt_deg: float
    last_setpoint_lag_s: float
    saturation_window_s: float
    saturation_fraction: float
    oscillation_max_hz: float
    oscillation_swing_rads: float
    saturation_hold_s: float

    def validate(self) -> list[tuple[str, str]]:
        if self.thrust_max_norm < self.thrust_min_norm:
            return [("thrust_max_norm", f"must be >= thrust_min_norm ({self.thrust_min_norm})")]
        return []

    @property
    def max_reference_tilt_rad(self) -> float:
        return math.radians(self.max_reference_tilt_deg)

    @property
    def envelope_tilt_rad(self) -> float:
        return math.radians(self.envelope_tilt_deg)

    @property
    def last_setpoint_tilt_rad(self) -> float:
        return math.radians(self.last_setpoint_tilt_deg)


@dataclass(frozen=True)
class PresetsConfig:
    """The controller presets the bridge flies by default, per registered law (``presets.<law>``)."""

    astsm: str

    def validate(self) -> list[tuple[str, str]]:
        try:
            resolve_config(self.astsm, "controllers")
        except ConfigError as exc:
            return [("astsm", str(exc))]
        return []


@dataclass(frozen=True)
class BridgeConfig:
    """All sections of ``bridge.yaml``; ``source`` is the file it came from."""

    link: LinkConfig
    timing: TimingConfig
    mapping: MappingConfig
    thrust: ThrustConfig
    limits: LimitsConfig
    presets: PresetsConfig
    source: str = ""


SECTIONS: dict[str, type] = {
    "link": LinkConfig,
    "timing": TimingConfig,
    "mapping": MappingConfig,
    "thrust": ThrustConfig,
    "limits": LimitsConfig,
    "presets": PresetsConfig,
}


def split_overrides(overrides: Mapping[str, Any] | None) -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """Split ``--set`` items into bridge-section overrides and the rest (controller gains).

    ``"mapping.method": "integrate"`` -> bridge section 'mapping'; ``"controller.mu": 0.03`` or
    ``"mu": 0.03`` -> controller overrides ``{"mu": 0.03}``.
    """
    bridge: dict[str, dict[str, Any]] = {name: {} for name in SECTIONS}
    controller: dict[str, Any] = {}
    for key, value in (overrides or {}).items():
        head, _, tail = key.partition(".")
        if tail and head in SECTIONS:
            bridge[head][tail] = value
        elif tail and head == "controller":
            controller[tail] = value
        else:
            controller[key] = value
    return bridge, controller


def load_bridge_config(path: str | Path | None = None, overrides: Mapping[str, Mapping[str, Any]] | None = None) -> BridgeConfig:
    """Load every section of a bridge config (default: the packaged ``configs/bridge.yaml``).

    Raises ConfigError (one line naming file, key, value and rule) on any problem.
    """
    cfg = resolve_config(path or DEFAULT_BRIDGE_CONFIG)
    overrides = overrides or {}
    unknown = set(overrides) - set(SECTIONS)
    if unknown:
        raise ConfigError(f"{cfg}: unknown section(s) {sorted(unknown)}; expected {', '.join(SECTIONS)}")
    parts = {name: build_dataclass(cls, cfg, name, overrides.get(name)) for name, cls in SECTIONS.items()}
    return BridgeConfig(**parts, source=str(cfg))
