"""Attitude controllers behind one small interface (``controller_interface.AttitudeController``).

Registry: ``CONTROLLERS`` maps a key to a class with class attributes ``name``, ``summary`` (one line)
and ``default_config`` (file in ``configs/controllers``). Build one with :func:`make_controller`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from ..errors import ConfigError
from .astsm import AstsmController
from .atsm import AtsmController
from .pid import PidController, PidFairController
from .smc import SmcController
from .stsm import StsmController
from .controller_interface import AttitudeController, TrackingError, tracking_error

CONTROLLERS: dict[str, type] = {
    "astsm": AstsmController,
    "stsm": StsmController,
    "smc": SmcController,
    "atsm": AtsmController,
    "pid": PidController,
    "pid_fair": PidFairController,
}


def make_controller(
    name: str,
    solo,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    batch_shape: tuple = (),
) -> AttitudeController:
    """Build a registered controller.

    Parameters
    ----------
    name : registry key (see ``CONTROLLERS``), e.g. ``"astsm"``
    solo : SoloRigidBody; its nominal inertia I0 is the controllers' model
    config : packaged preset (``"astsm_paper"``) or YAML path; None = the class's ``default_config``
    overrides : key -> value, validated against the YAML spec (range, choices)
    batch_shape : leading shape of inputs for batched simulation; () for one vehicle

    Raises
    ------
    ConfigError : unknown name (message lists the keys) or a bad config
    """
    try:
        cls = CONTROLLERS[name]
    except KeyError:
        raise ConfigError(f"unknown controller '{name}'; registered: {', '.join(CONTROLLERS)}") from None
    return cls(solo, config=config, overrides=overrides, batch_shape=batch_shape)


__all__ = ["CONTROLLERS", "make_controller", "AttitudeController", "TrackingError", "tracking_error"]
