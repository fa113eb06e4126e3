"""Attitude controllers behind one small interface (``controller_interface.AttitudeController``).

Registry: ``CONTROLLERS`` maps a key to a class with class attributes ``name``, ``summary`` (one line),
``default_config`` (file in ``configs/controllers``) and ``gains_type`` (the gains dataclass, fields == YAML keys).
A law is built from a gains object and a model: ``AstsmController(gains, solo)``; the laws never read YAML.
:func:`from_config` (a preset name or path -> validated gains -> the law) and :func:`make_controller` (the same by
name) are the one place that does. Its config-loader import is local to :func:`from_config`, so importing
``mavastsm.control`` or any law loads no YAML machinery (tests/test_architecture.py holds that).

Laws from outside the package (docs/controllers.md, "Your own controller"): :func:`law_class` also takes a name an
installed distribution registers under the entry-point group ``mavastsm.controllers`` (:func:`installed_laws`), and
``MODULE:CLASS`` or ``FILE.py:CLASS``; such a law's ``default_config`` is a file beside its module (:func:`law_preset`).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from pathlib import Path
from typing import Any, Mapping

from ..errors import ConfigError
from .astsm import AstsmController
from .atsm import AtsmController
from .pid import PidController, PidFairController
from .smc import SmcController
from .stsm import StsmController
from .controller_interface import PROTOCOL_MEMBERS, AttitudeController, TrackingError, tracking_error

CONTROLLERS: dict[str, type] = {
    "astsm": AstsmController,
    "stsm": StsmController,
    "smc": SmcController,
    "atsm": AtsmController,
    "pid": PidController,
    "pid_fair": PidFairController,
}

#: What a ``--controller`` value may be, for the commands' --help.
LAW_HELP = ("a registered key (mavastsm list-controllers), a law an installed distribution registers, or your own "
            "MODULE:CLASS or FILE.py:CLASS with its preset beside it (docs/controllers.md)")

#: The entry-point group under which an installed distribution registers its laws (``pd = "my_laws:PdController"``).
ENTRY_POINT_GROUP = "mavastsm.controllers"


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
    law : a name :func:`law_class` resolves (``"astsm"``, an installed law's name, ``"my_laws:PdController"``) or
          the class itself (it needs ``gains_type`` and ``default_config``)
    path_or_name : packaged preset (``"astsm_paper"``) or YAML path; None = the law's own (:func:`law_preset`)
    model : the vehicle model (SoloRigidBody; its nominal inertia I0 is the controllers' model)
    overrides : key -> value, validated against the YAML spec (range, choices) like the file's values
    batch_shape : leading shape of inputs for batched simulation; () for one vehicle

    The file the gains came from is kept as ``controller.config_path``.

    Raises
    ------
    ConfigError : unknown name (message lists the keys), a law that does not import, no preset, or a bad config
                  (one line: file, key, value, rule)
    """
    from ..config_loading import build_dataclass, resolve_config  # only here: the laws themselves read no YAML

    cls = law_class(law)
    path = resolve_config(path_or_name or law_preset(cls), "controllers")
    ctrl = cls(build_dataclass(cls.gains_type, path, "gains", overrides), model, batch_shape=batch_shape)
    ctrl.config_path = path
    return ctrl


def make_controller(
    name: str,
    solo,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    batch_shape: tuple = (),
) -> AttitudeController:
    """Build a controller from its preset (:func:`from_config` by name).

    Parameters
    ----------
    name : registry key (see ``CONTROLLERS``) such as ``"astsm"``, an installed law, or ``MODULE:CLASS`` (:func:`law_class`)
    solo : SoloRigidBody; its nominal inertia I0 is the controllers' model
    config : packaged preset (``"astsm_paper"``) or YAML path; None = the law's own preset (:func:`law_preset`)
    overrides : key -> value, validated against the YAML spec (range, choices)
    batch_shape : leading shape of inputs for batched simulation; () for one vehicle

    Raises
    ------
    ConfigError : unknown name (message lists the keys) or a bad config
    """
    return from_config(name, config, solo, overrides, batch_shape)


def controller_for_flight(choice: Any, solo, preset: str | Path | None, overrides: Mapping[str, Any] | None = None,
                          user_overrides: Mapping[str, Any] | None = None) -> tuple[AttitudeController, str]:
    """(controller, name) for a flight: ``choice`` a ``--controller`` value (built with :func:`make_controller` from
    ``preset``, ``overrides`` then the user's own ``user_overrides``, which win), or a ready object checked for the
    protocol's members and flown as built. ConfigError (one line) otherwise."""
    if not isinstance(choice, str):
        if user_overrides:
            raise ConfigError("controller overrides given with a controller object; set them on the object")
        from .controller_interface import missing_members

        missing = missing_members(choice)
        if missing:
            raise ConfigError(f"controller {type(choice).__name__} lacks {', '.join(missing)} of the AttitudeController "
                              "protocol (docs/controllers.md; mavastsm.control.controller_interface.NoLimits gives the limit members)")
        return choice, choice.name
    merged = {**(overrides or {}), **(user_overrides or {})}
    return make_controller(choice, solo, preset, merged or None), choice


def installed_laws() -> dict:
    """Name -> ``importlib.metadata.EntryPoint`` of the laws installed distributions register under
    :data:`ENTRY_POINT_GROUP`. A name equal to a packaged key is left out: a packaged law is never replaced."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name not in CONTROLLERS}


def law_class(law: str | type) -> type:
    """The class a ``--controller`` value names, checked for the class attributes and protocol members of a law.

    ``law`` is, in this order: a packaged key (``CONTROLLERS``); a name an installed distribution registers
    (:func:`installed_laws`); ``MODULE:CLASS`` (MODULE imported from ``sys.path``, else from the working directory,
    as ``python -m`` would); ``FILE.py:CLASS`` (the file imported as a module named after it, its folder put on
    ``sys.path`` as ``python FILE.py`` would). A class is returned as given.

    Raises ConfigError (one line) for an unknown name, a module or file that does not import, a missing class, or a
    class without ``gains_type``, ``default_config`` or a member of the AttitudeController protocol.
    """
    if not isinstance(law, str):
        return law
    if law in CONTROLLERS:
        return CONTROLLERS[law]
    installed = installed_laws()
    if law in installed:
        cls = _imported(law, installed[law].value, installed[law].load)
    elif ":" in law:
        cls = _import_law(law)
    else:
        raise ConfigError(f"unknown controller '{law}'; {_choices(installed)}")
    if not isinstance(cls, type):
        raise ConfigError(f"controller '{law}': {getattr(cls, '__name__', cls)} is not a class")
    missing = [m for m in ("gains_type", "default_config", *PROTOCOL_MEMBERS) if not hasattr(cls, m)]
    if missing:
        raise ConfigError(f"controller '{law}': {cls.__name__} lacks {', '.join(missing)} of a law "
                          "(docs/controllers.md; controller_interface.NoLimits gives the limit members)")
    return cls


def law_preset(cls: type) -> str | Path:
    """A law's own preset, its class attribute ``default_config``: for a law of this package the name of a preset in
    ``configs/controllers``; for any other law a file beside the module that defines the class (an absolute path is
    taken as it is), checked here.

    Raises ConfigError (one line) naming where the file was looked for."""
    if cls.__module__.partition(".")[0] == "mavastsm":
        return cls.default_config
    module_file = getattr(sys.modules.get(cls.__module__), "__file__", None) or "."
    path = Path(module_file).resolve().parent / cls.default_config
    if not path.is_file():
        raise ConfigError(f"controller {cls.__module__}:{cls.__name__}: its preset {path} (default_config) not found; "
                          "put the YAML beside the module")
    return path


def split_law_and_preset(item: str) -> tuple[str, str | None]:
    """``LAW[:PRESET]`` as ``simulate --controller`` and sweep files give it -> (law, preset or None). LAW is a
    packaged or installed name (``astsm:astsm_paper``), else ``MODULE:CLASS`` or ``FILE.py:CLASS``
    (``my_laws:PdController:pd_soft.yaml``)."""
    head, _, rest = item.partition(":")
    if not rest or head in CONTROLLERS or head in installed_laws():
        return head, rest or None
    class_name, _, preset = rest.partition(":")
    return f"{head}:{class_name}", preset or None


def _choices(installed) -> str:
    extra = f"; installed: {', '.join(installed)}" if installed else ""
    return f"registered: {', '.join(CONTROLLERS)}{extra}; or MODULE:CLASS, FILE.py:CLASS"


def _imported(law: str, where: str, load):
    """``load()``, any failure of the user's import as one ConfigError line naming the law and where it came from."""
    try:
        return load()
    except ConfigError:
        raise
    except Exception as exc:  # the user's module: whatever it raises on import is a start-up error
        raise ConfigError(f"controller '{law}': importing {where} failed: {type(exc).__name__}: {exc}") from None


def _import_law(law: str) -> type:
    module_part, _, class_name = law.rpartition(":")
    if module_part.endswith(".py"):
        module = _imported(law, module_part, lambda: _module_from_file(law, Path(module_part)))
    else:
        module = _imported(law, module_part, lambda: _module_from_path(law, module_part))
    try:
        return getattr(module, class_name)
    except AttributeError:
        laws = [n for n, v in vars(module).items() if isinstance(v, type) and hasattr(v, "gains_type") and v.__module__ == module.__name__]
        raise ConfigError(f"controller '{law}': {module_part} has no '{class_name}'"
                          f"{'; its laws: ' + ', '.join(laws) if laws else ''}") from None


def _module_from_path(law: str, name: str):
    """Import ``name`` from sys.path, else from the working directory (appended, so it shadows nothing installed)."""
    cwd = os.getcwd()
    for attempt in (1, 2):
        try:
            return importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if not (exc.name and (name + ".").startswith(exc.name + ".")):
                raise  # a module the law itself imports is missing: _imported names it
            if attempt == 2 or cwd in sys.path:
                raise ConfigError(f"controller '{law}': no module named '{exc.name}' on sys.path or in {cwd}; "
                                  f"{_choices(installed_laws())}") from None
        sys.path.append(cwd)


def _module_from_file(law: str, path: Path):
    path = path.resolve()
    if not path.is_file():
        raise ConfigError(f"controller '{law}': {path}: no such file")
    for module in list(sys.modules.values()):
        if getattr(module, "__file__", None) == str(path):
            return module
    name = path.stem if path.stem not in sys.modules else f"{path.stem}_{abs(hash(str(path)))}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    if str(path.parent) not in sys.path:
        sys.path.append(str(path.parent))  # the file's own imports of modules beside it, as ``python FILE.py``
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


__all__ = ["CONTROLLERS", "ENTRY_POINT_GROUP", "LAW_HELP", "from_config", "make_controller", "installed_laws", "law_class",
           "law_preset", "split_law_and_preset", "AttitudeController", "TrackingError", "tracking_error"]
