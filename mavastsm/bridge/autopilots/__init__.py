"""One adapter per autopilot, found by the MAV_AUTOPILOT its HEARTBEAT names (docs/bridge.md, "Another autopilot").

An adapter (protocol ``AutopilotAdapter`` in ``autopilots.profile``) owns every name, mode, parameter and habit of
its autopilot: whether its firmware takes body-rate setpoints, what its thrust field means, which parameters give
the angular-acceleration limit, the hover collective and the setpoint timeout, its mode table, and the
``AutopilotProfile`` the cycle, the session and the hand-back read. Nothing else in the bridge tests an autopilot's
name. What differs between the two packaged adapters, and why:

================================  ================================  =====================================
question                          ArduCopter (``ardupilot``)        PX4 (``px4``)
================================  ================================  =====================================
modes that obey body rates        GUIDED, GUIDED_NOGPS              OFFBOARD (custom_mode 393216)
setpoints before the mode         not needed (streamed anyway       required: OFFBOARD is refused
                                  when the bridge sets the mode)    without >= 1 s of setpoints
thrust field                      climb rate (0.5 = hold) unless    normalised collective, always
                                  GUID_OPTIONS bit 3                (hover measured from its own hold:
                                                                    ATTITUDE_TARGET.thrust; else
                                                                    MPC_THR_HOVER)
behind a body-rate command        an attitude target that           the rate controller directly
                                  integrates it (hidden target)
last setpoint after we stop       held until GUID_TIMEOUT           held until COM_OF_LOSS_T, then
                                  (default 3 s), then level         PX4's offboard-loss failsafe
hand-back, in order of trial      ALT_HOLD; LOITER -> ALT_HOLD;     ALTCTL needs RC or MANUAL_CONTROL,
                                  LAND                              so ALT_HOLD -> ALTCTL, LOITER, LAND
--takeoff                         the bridge's bounded climb-rate   PX4's own (NAV_TAKEOFF, then Hold),
                                  climb in the guided mode          then OFFBOARD
ATTITUDE faster than allowed      DENIED (4.6+) / capped (older)    accepted, capped at the estimator
ATTITUDE after boot               from the first seconds (its       none until EKF2 has an attitude (about
                                  DCM runs before the EKF)          33 s on SITL): the bridge waits
================================  ================================  =====================================

Adding one: a module with an ``ADAPTER`` object, plus one registry line, either here in ``PACKAGED`` (an adapter
the project ships) or, for your own, one entry point of your distribution in the group ``mavastsm.autopilots``
(``myautopilot = my_module:ADAPTER``). A packaged adapter is never replaced by an installed one.
"""

from __future__ import annotations

import importlib
from functools import lru_cache

from ...errors import ConfigError

ENTRY_POINT_GROUP = "mavastsm.autopilots"

#: the adapters shipped with mavastsm: name -> "module:object" (one line each)
PACKAGED = {
    "ardupilot": "mavastsm.bridge.autopilots.ardupilot:ADAPTER",
    "px4": "mavastsm.bridge.autopilots.px4:ADAPTER",
}


def _load(name: str, target: str):
    module, _, attr = target.partition(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"autopilot adapter {name!r}: loading {target} failed: {type(exc).__name__}: {exc}") from None


@lru_cache(maxsize=1)
def adapters() -> dict[int, object]:
    """MAV_AUTOPILOT -> adapter: the packaged ones, then those installed distributions register under
    :data:`ENTRY_POINT_GROUP` for an autopilot no packaged adapter answers."""
    from importlib.metadata import entry_points

    found: dict[int, object] = {}
    for name, target in PACKAGED.items():
        adapter = _load(name, target)
        found[int(adapter.mav_autopilot)] = adapter
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        if ep.name in PACKAGED:
            continue
        adapter = _load(ep.name, ep.value)
        found.setdefault(int(adapter.mav_autopilot), adapter)
    return found


def adapter_for(mav_autopilot: int):
    """The adapter for HEARTBEAT.autopilot ``mav_autopilot``, or None when none is registered."""
    return adapters().get(int(mav_autopilot))


def known_autopilots() -> str:
    """'ArduPilot (3), PX4 (12)' for an error message."""
    return ", ".join(f"{a.name} ({k})" for k, a in sorted(adapters().items()))
