"""What the bridge asks of an autopilot, as data (``AutopilotProfile``) and as an adapter protocol (pure, no I/O).

The control cycle, the session, preflight and the hand-back ask an ``AutopilotProfile`` instead of testing the
autopilot's name; the profile is built by that autopilot's adapter (``mavastsm.bridge.autopilots``: one module per
autopilot, the table of what differs between ArduCopter and PX4 is in its docstring) from what its preflight read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

CLIMB_RATE = "climb_rate"
COLLECTIVE = "collective"


@dataclass(frozen=True, slots=True)
class AutopilotProfile:
    """What one autopilot accepts and does.

    Attributes
    ----------
    name : "ArduPilot" | "PX4"
    thrust_semantics : CLIMB_RATE (0.5 = hold altitude) or COLLECTIVE (normalised 0..1)
    hover_thrust_norm : thrust value that holds altitude level (0.5 climb-rate, or the hover collective)
    guided_modes : mode names in which SET_ATTITUDE_TARGET is obeyed
    handback : (action, modes to try in order) for each hand-back action (ALT_HOLD, LOITER, LAND)
    prestream_required : the guided mode is refused unless setpoints already stream
    hidden_attitude_target : body-rate commands are integrated into an attitude target that the
        autopilot's angle loop keeps chasing (ArduCopter); False = straight to the rate loop (PX4)
    setpoint_timeout_param : the parameter [s] for how long the last setpoint is obeyed once the stream stops
    setpoint_timeout_range_s : that parameter's documented range [s]
    setpoint_timeout_default_s : [s] its default, assumed when it cannot be read (the conservative value for the
        last-setpoint bound, ``safety.last_setpoint_safe_rates``)
    hover_thrust_param : the parameter that holds the hover collective [0..1], or "" when none is needed
    hover_from_target_thrust : the autopilot's ATTITUDE_TARGET.thrust is the collective its own controllers command
        (PX4: |thrust_body| of its attitude setpoint), so in its own hold mode it is the collective that hovers the
        vehicle as it is (payload included), measured before the guided mode (preflight.measure_hover_collective)
    default_vehicle : the configs/vehicle description flown when --vehicle is not given and none is recognised
    tuning_prefix : the prefix of the autopilot's attitude-tuning parameters (``ATC_``, ``MC_``): a packaged
        description whose ``autopilot_tuning`` (the parameters its loop numbers were measured with) are all named so
        is recognised by them, read from the vehicle at preflight; "" = recognise none
    heading_loop_params : the parameters whose product is the gain of the autopilot's heading loop behind its
        attitude target (yaw angle P x yaw rate P); on a vehicle no description matches, the yaw tau_z flown is
        ``mapping.yaw_loop_gain`` over it (``flight_plan.yaw_tau_from_heading_loop``); () = not used
    autopilot_takeoff : ``--takeoff`` is the autopilot's own (MAV_CMD_NAV_TAKEOFF, then its hold mode) before the
        guided mode; False = the bridge's bounded climb-rate climb in the guided mode (ArduCopter)
    attitude_gate : what the autopilot waits for before it sends any ATTITUDE although it answers (HEARTBEAT,
        parameters, commands): the bridge waits for it (``link.attitude_wait_s``) saying so; "" = ATTITUDE flows
        from boot, so none after the rate measurement is a broken link, reported at once
    """

    name: str
    thrust_semantics: str
    hover_thrust_norm: float
    guided_modes: tuple[str, ...]
    handback: tuple[tuple[str, tuple[str, ...]], ...]
    prestream_required: bool
    hidden_attitude_target: bool
    setpoint_timeout_param: str
    setpoint_timeout_range_s: tuple[float, float]
    setpoint_timeout_default_s: float = 1.0
    hover_thrust_param: str = ""
    hover_from_target_thrust: bool = False
    autopilot_takeoff: bool = False
    rate_cap_reason: str = ""  # why an accepted ATTITUDE rate may arrive slower
    default_vehicle: str = "solo"  # configs/vehicle description flown when --vehicle is not given
    tuning_prefix: str = ""  # names of the attitude tuning a packaged description is recognised by ("" = none)
    heading_loop_params: tuple[str, ...] = ()  # product = the heading loop's gain (yaw angle P x yaw rate P)
    attitude_gate: str = ""  # what the autopilot waits for before its first ATTITUDE ("" = sends it from boot)

    def handback_modes(self, action: str) -> tuple[str, ...]:
        """The modes to request, in order, for hand-back ``action`` (ALT_HOLD / LOITER / LAND)."""
        return dict(self.handback).get(action, (action,))


class VehicleParameters(Protocol):
    """The vehicle's parameters as an adapter reads and writes them during preflight (``preflight.LinkParameters``).

    Values are in the autopilot's units, as the vehicle reports them; every read is kept in the report's
    ``parameters`` (the sidecar), so a name is asked once."""

    def read(self, name: str) -> float | None:
        """One PARAM_REQUEST_READ; None when the vehicle does not answer (an optional parameter)."""

    def read_with_retries(self, name: str) -> float | None:
        """PARAM_REQUEST_READ retried ``link.command_retries`` times (a parameter the flight depends on)."""

    def write(self, name: str, value: float) -> bool:
        """PARAM_SET, True once the vehicle echoes the value."""


class AutopilotAdapter(Protocol):
    """Everything the bridge knows of one autopilot (``mavastsm.bridge.autopilots``; docs/bridge.md, "Another autopilot").

    Attributes: ``name`` as the summary, the sidecar and the errors say it ("ArduPilot"); ``mav_autopilot``, the
    HEARTBEAT.autopilot (MAV_AUTOPILOT) it answers for.
    """

    name: str
    mav_autopilot: int

    def body_rate_refusal(self, version: tuple[int, int, int] | None) -> str | None:
        """Why firmware ``version`` (AUTOPILOT_VERSION; None when it sent none) cannot fly body-rate setpoints, or
        None when it can."""

    def configure(self, params: VehicleParameters, cfg, rep) -> AutopilotProfile:
        """``cfg`` the BridgeConfig, ``rep`` the PreflightReport being filled. Read (and where the config asks, write) the parameters the flight depends on, fill the report's thrust
        semantics, ``thrust_detail``, the acceleration limits where it reads its own (``accel_limit_radss`` / ``_source``; preflight sets the config's before), ``angle_p``, hover
        collective and notes, and return the profile. Raises ConfigError or OffboardRejected, one line."""

    def mode_command(self, mode: str, mav_type: int) -> tuple[float, ...]:
        """MAV_CMD_DO_SET_MODE params 1.. for ``mode`` on a vehicle of HEARTBEAT.type ``mav_type``; ConfigError naming
        the known modes for an unknown one."""


# Known arming refusals -> what the operator can do (matched on the vehicle's own text, case-insensitive).
ARMING_FIXES = (
    ("need position estimate", "GUIDED needs a position estimate: use --mode GUIDED_NOGPS, or wait for GPS and the EKF"),
    ("inconsistent", "the IMUs are still settling after boot (about 25 s on SITL): wait, or raise link.arm_timeout_s"),
    ("ekf", "the estimator is not ready yet: wait, or raise link.arm_timeout_s"),
    ("gps", "no usable GPS fix yet: wait, or fly GUIDED_NOGPS"),
    ("system health", "PX4's estimator is not ready (about 35 s after boot on SITL): wait, or raise link.arm_timeout_s"),
    ("throttle", "throttle is not low: lower the RC throttle"),
    ("rc not", "no RC: calibrate the RC or set the vehicle's RC failsafe options"),
    ("safety", "the safety switch is on: press it"),
    ("mode not armable", "this mode cannot be armed in: select GUIDED / GUIDED_NOGPS / OFFBOARD first"),
)


def arming_fix(reason: str) -> str:
    """The operator's fix for an arming refusal, from the vehicle's own reason ('' when unknown)."""
    low = reason.lower()
    for key, fix in ARMING_FIXES:
        if key in low:
            return fix
    return ""
