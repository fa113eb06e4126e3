"""Attitude controllers behind one small interface (``controller_interface.AttitudeController``).

Registry: ``CONTROLLERS`` maps a key to a class with class attributes ``name``, ``summary`` (one line),
``default_config`` (file in ``configs/controllers``) and ``gains_type`` (the gains dataclass, fields == YAML keys).
A law is built from a gains object and a model: ``AstsmController(gains, solo)``; the laws never read YAML.
:func:`from_config` (a preset name or path -> validated gains -> the law) and :func:`make_controller` (the same by
registry key) are the one place that does. Its config-loader import is local to :func:`from_config`, so importing
``mavastsm.control`` or any law loads no YAML machinery (tests/test_architecture.py holds that).
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


def from_config(
    law: str | type,
    path_or_name: str | Path | None,
    model,
    overrides: Mapping[str, Any] | None = None,
    batch_shape: tuple = (),
) -> AttitudeController:
    """Build a law from a controller preset: read and validate its ``gains`` section, then ``law(gains, model)``.

    Parameters
    ----------
    law : registry key (``"astsm"``) or the class itself (it needs ``gains_type`` and ``default_config``)
    path_or_name : packaged preset (``"astsm_paper"``) or YAML path; None = the law's ``default_config``
    model : the vehicle model (SoloRigidBody; its nominal inertia I0 is the controllers' model)
    overrides : key -> value, validated against the YAML spec (range, choices) like the file's values
    batch_shape : leading shape of inputs for batched simulation; () for one vehicle

    The file the gains came from is kept as ``controller.config_path``.

    Raises
    ------
    ConfigError : unknown name (message lists the keys) or a bad config (one line: file, key, value, rule)
    """
    from ..config_loading import build_dataclass, resolve_config  # only here: the laws themselves read no YAML

    cls = _law_class(law)
    path = resolve_config(path_or_name or cls.default_config, "controllers")
    ctrl = cls(build_dataclass(cls.gains_type, path, "gains", overrides), model, batch_shape=batch_shape)
    ctrl.config_path = path
    return ctrl


def _law_class(law: str | type) -> type:
    if not isinstance(law, str):
        return law
    try:
        return CONTROLLERS[law]
    except KeyError:
        raise ConfigError(f"unknown controller '{law}'; registered: {', '.join(CONTROLLERS)}") from None


def make_controller(
    name: str,
    solo,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    batch_shape: tuple = (),
) -> AttitudeController:
    """Build a registered controller from its preset (:func:`from_config` by registry key).

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
    return from_config(name, config, solo, overrides, batch_shape)


__all__ = ["CONTROLLERS", "from_config", "make_controller", "AttitudeController", "TrackingError", "tracking_error"]
