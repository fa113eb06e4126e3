"""The 3DR Solo rigid-body model of Hoang & Pham (2018): Table 1 constants and the nominal drift f(X).

Pure data and math; no I/O beyond reading the YAML through ``config_loading``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config_loading import build_dataclass, load_section, packaged_config_dir, per_axis, read_yaml, resolve_config
from .errors import ConfigError

DEFAULT_VEHICLE_CONFIG = "solo"
# what a vehicle description's ``offboard_loop`` may set (the bridge's mapping.* values of the same names)
OFFBOARD_LOOP_KEYS = ("rate_time_constant_s", "loop_delay_s", "shaping_accel_fraction", "roll_pitch_command_base", "yaw_trim_gain_per_s",
                      "yaw_trim_error_limit_rad", "yaw_trim_band_rad")
OFFBOARD_LOOP_SCALARS = ("yaw_trim_gain_per_s", "yaw_trim_error_limit_rad", "yaw_trim_band_rad")  # one value, not per axis
OFFBOARD_LOOP_CHOICES = {"roll_pitch_command_base": ("integrated", "measured")}


@dataclass(frozen=True)
class SoloRigidBody:
    """Table 1 of the paper, SI units. Field names equal the keys of ``configs/vehicle/solo.yaml``.

    Attributes
    ----------
    mass : [kg]
    arm_length : [m] motor to centre of mass, l
    gravity : [m/s^2]
    inertia_xx, inertia_zz : [kg m^2] principal moments (body FRD axes)
    inertia_yy_corrected : [kg m^2] 15.5e-3, the physically consistent reading of Table 1
    inertia_yy_paper_literal : [kg m^2] 1.55e-3, Table 1 as printed
    inertia_variant : 'corrected' | 'paper_literal'
    """

    mass: float
    arm_length: float
    gravity: float
    inertia_xx: float
    inertia_yy_corrected: float
    inertia_yy_paper_literal: float
    inertia_zz: float
    inertia_variant: str = "corrected"

    @property
    def inertia_yy(self) -> float:
        """[kg m^2] Iyy of the selected variant."""
        return self.inertia_yy_corrected if self.inertia_variant == "corrected" else self.inertia_yy_paper_literal

    @property
    def inertia_diag(self) -> np.ndarray:
        """[kg m^2] (3,) nominal principal moments I0 = diag(Ixx, Iyy, Izz) known to the controllers."""
        return np.array([self.inertia_xx, self.inertia_yy, self.inertia_zz])

    def validate(self) -> list[tuple[str, str]]:
        """Cross-field rules; the literal Iyy is allowed (it is a named variant) but reported."""
        if self.inertia_variant == "corrected" and self.inertia_zz > self.inertia_xx + self.inertia_yy_corrected:
            return [("inertia_zz", "principal moments must satisfy Izz <= Ixx + Iyy")]
        return []


def load_solo(path: str | Path | None = None, inertia_variant: str | None = None) -> SoloRigidBody:
    """Load the rigid-body section of a vehicle config (default: the packaged Solo).

    ``inertia_variant`` overrides the file's choice ('corrected' or 'paper_literal').
    """
    cfg = resolve_config(path or DEFAULT_VEHICLE_CONFIG, "vehicle")
    overrides = {"inertia_variant": inertia_variant} if inertia_variant else None
    return build_dataclass(SoloRigidBody, cfg, "rigid_body", overrides)


def load_offboard_loop(path: str | Path | None = None) -> dict:
    """The ``offboard_loop`` section of a vehicle config (the loop through its autopilot's rate controller, as
    the offboard bridge models it): ``{"rate_time_constant_s": (3,), "loop_delay_s": (3,)}`` [s] and the mapping choice
    ``roll_pitch_command_base`` (a string), or {} when the file has none. A scalar applies to all three axes."""
    cfg = resolve_config(path or DEFAULT_VEHICLE_CONFIG, "vehicle")
    if "offboard_loop" not in read_yaml(cfg):
        return {}
    loop = load_section(cfg, "offboard_loop")
    unknown = sorted(set(loop) - set(OFFBOARD_LOOP_KEYS))
    if unknown:
        raise ConfigError(f"{cfg}: unknown key(s) {', '.join('offboard_loop.' + k for k in unknown)}; expected {', '.join(OFFBOARD_LOOP_KEYS)}")
    out = {}
    for key, par in loop.items():
        if key in OFFBOARD_LOOP_CHOICES:
            if par.value not in OFFBOARD_LOOP_CHOICES[key]:
                raise ConfigError(f"{cfg}: offboard_loop.{key} = {par.value!r}; expected one of {', '.join(OFFBOARD_LOOP_CHOICES[key])}")
            out[key] = str(par.value)
        elif key in OFFBOARD_LOOP_SCALARS:
            out[key] = float(par.value)
        else:
            out[key] = per_axis(par.value)
    return out


def load_autopilot_tuning(path: str | Path) -> dict[str, float]:
    """The ``autopilot_tuning`` section of a vehicle description: the autopilot parameters (name -> value, in the
    autopilot's own units) its ``offboard_loop`` was measured with, by which the bridge recognises the vehicle at
    preflight. {} when the description has none."""
    cfg = resolve_config(path, "vehicle")
    if "autopilot_tuning" not in read_yaml(cfg):
        return {}
    return {name: float(par.value) for name, par in load_section(cfg, "autopilot_tuning").items()}


def packaged_vehicle_tunings() -> dict[str, dict[str, float]]:
    """{description name: autopilot_tuning} for every packaged vehicle description that has one (sorted by name)."""
    folder = packaged_config_dir() / "vehicle"
    out = {}
    for path in sorted(folder.glob("*.yaml")):
        tuning = load_autopilot_tuning(path)
        if tuning:
            out[path.stem] = tuning
    return out


def nominal_drift_torque(inertia_diag, body_rates_rads):
    """f(X) = -omega x (I omega) [N m] (paper eq. 17), for a diagonal I.

    Component-wise: [(Iyy - Izz) q r, (Izz - Ixx) p r, (Ixx - Iyy) p q].
    Broadcasts over leading axes of ``body_rates_rads`` (..., 3).

    Note: the paper writes f with X2 = Theta_dot standing in for omega; we always evaluate it
    with the body rates omega, which is what the rigid-body equation (6)-(7) actually contains.
    """
    i = np.asarray(inertia_diag, dtype=float)
    w = np.asarray(body_rates_rads, dtype=float)
    p, q, r = w[..., 0], w[..., 1], w[..., 2]
    return np.stack([(i[1] - i[2]) * q * r, (i[2] - i[0]) * p * r, (i[0] - i[1]) * p * q], axis=-1)
