"""The flight plan: what the preflight's findings decide before the first setpoint.

Pure (it reads no link and builds no controller): from the bridge config, the autopilot profile, the preflight
report and the controller as built from its preset, ``plan_flight`` decides

* the vehicle description: the one given (``--vehicle``), else the packaged one whose ``autopilot_tuning`` the
  vehicle reports (ArduPilot), else the profile's ``default_vehicle``; its ``offboard_loop`` replaces bridge.yaml's
  mapping values except those the user's ``--set`` named;
* the config the loop flies: that mapping, at the ATTITUDE rate the vehicle granted;
* the command limits: the autopilot's angular-acceleration limit and the torque it lets the law realise;
* what a named controller is rebuilt with: the vehicle's I0, its adaptive gain bounded by the loop delay
  (eq. 34, ``adaptive_gain_ceiling``), the yaw integral left to the autopilot's attitude target (M7), the torque
  limit (protocol member ``limit_overrides``). A controller object is flown as built.

``Bridge`` asks for the plan once, after the preflight, and flies it; every line the plan wants said is in
``notes``, in the order the preflight summary prints them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

from ..config_loading import per_axis
from ..errors import ConfigError
from ..solo_model import SoloRigidBody, load_autopilot_tuning, load_offboard_loop, load_solo, packaged_vehicle_tunings
from .autopilots.profile import CLIMB_RATE, COLLECTIVE, AutopilotProfile
from .bridge_config import BridgeConfig
from .cycle.control_cycle import command_torque_limit_nm
from .cycle.loop_identification import excitation_text
from .cycle.setpoint_mapping import adaptive_gain_ceiling, switching_delay_s, yaw_from_reference

UNRECOGNISED = "no packaged description matches its tuning"  # recognise_vehicle's reason for the default
ParameterReader = Callable[[str], "float | None"]  # parameter name -> its value (autopilot units), None if unreadable


@dataclass(frozen=True)
class FlightPlan:
    """What the bridge flies, decided from the preflight (see module docstring)."""

    vehicle: str  # vehicle description name (configs/vehicle/NAME.yaml)
    solo: SoloRigidBody  # its rigid-body parameters (I0 [kg m^2] is what the law and the mapping use)
    config: BridgeConfig  # bridge config with the description's offboard loop and the granted ATTITUDE rate
    accel_limit_radss: tuple[float, float, float] | None  # the autopilot's rate-target slew limit per axis
    adaptive: bool  # the controller's switching gain adapts (ASTSM): command_accel_clip applies
    torque_authority_nm: tuple[float, float, float]  # command torque limit per axis [N m]
    controller_overrides: dict  # limit_overrides the named controller is rebuilt with ({} for an object)
    rebuild_controller: bool  # a named controller must be built again (overrides, or another vehicle's I0)
    notes: tuple[str, ...]  # lines for the preflight summary
    identify_in_flight: bool = False  # the first engagement flies the identification phase (loop_identification)
    hold_altitude: bool = False  # the bridge holds altitude itself (collective thrust and thrust.altitude_hold): it asks for LOCAL_POSITION_NED


def alpha_max(controller) -> tuple[float, float, float] | None:
    """Per-axis adaptive-gain clamp of the controller, or None when its gain does not adapt."""
    a = controller.adaptive_gain()
    return None if a is None else per_axis(a.alpha_max)


def alpha_ceiling(controller, mapping) -> tuple[float, float, float] | None:
    """Per-axis ``adaptive_gain_ceiling`` for the controller's mu and the switching delay (``switching_delay_s``:
    mapping.loop_delay_s, + tau on integrated axes), in the gain's units; None when its gain does not adapt or has
    no adaptation band to bound it by."""
    a = controller.adaptive_gain()
    if a is None or a.mu is None:
        return None
    delay = switching_delay_s(mapping)
    return tuple(adaptive_gain_ceiling(u, d) * k for u, d, k in zip(per_axis(a.mu), delay, per_axis(a.units_per_accel)))  # type: ignore[return-value]


def alpha_within_ceiling(controller, mapping) -> bool:
    """True when the controller's alpha clamp is at or below the loop-delay ceiling on every axis: alpha at its
    clamp is then the designed maximum gain, not a runaway (no ADAPTIVE_GAIN_PINNED)."""
    ceiling = alpha_ceiling(controller, mapping)
    return ceiling is not None and all(a <= c * (1.0 + 1e-6) for a, c in zip(alpha_max(controller), ceiling))


def tuning_mismatches(tuning: dict[str, float], read_parameter: ParameterReader) -> list[str]:
    """"NAME want -> got" for each ``autopilot_tuning`` parameter the vehicle does not report at its value (equal at
    float32); [] when every one matches."""
    changed = []
    for name, want in tuning.items():
        got = read_parameter(name)
        if not _reported_at(got, want):
            changed.append(f"{name} {want:g} -> {'unreadable' if got is None else f'{got:g}'}")
    return changed


def _reported_at(got: float | None, want: float) -> bool:
    """The vehicle answered with ``want`` (equal at float32, as PARAM_VALUE carries it)."""
    return got is not None and math.isclose(got, want, rel_tol=1e-6, abs_tol=1e-6)


class Recognition(NamedTuple):
    """What ``recognise_vehicle`` found."""

    vehicle: str  # description name (configs/vehicle/NAME.yaml)
    why: str  # the reason, for the preflight summary ("" where the profile recognises nothing by tuning)
    stand_in: bool  # the profile's default_vehicle stands in for a tuning no packaged description matches


def recognise_vehicle(profile: AutopilotProfile, read_parameter: ParameterReader) -> Recognition:
    """The first packaged description (by name) all of whose ``autopilot_tuning`` parameters the vehicle reports
    (``tuning_mismatches`` empty), else the profile's ``default_vehicle``. The loop numbers of a description (rate
    time constant, delay, shaping) were measured with that tuning, which is what decides them; an unrecognised
    tuning flies the default's numbers, and says so."""
    if not profile.tuning_prefix:
        return Recognition(profile.default_vehicle, "", False)
    for name, tuning in packaged_tunings(profile).items():
        if all(_reported_at(read_parameter(p), want) for p, want in tuning.items()):  # stops at the first that differs
            return Recognition(name, "recognised by its " + ", ".join(f"{p} {v:g}" for p, v in tuning.items()), False)
    return Recognition(profile.default_vehicle, f"{UNRECOGNISED}; {profile.default_vehicle}'s loop numbers", True)


def packaged_tunings(profile: AutopilotProfile) -> dict[str, dict[str, float]]:
    """{description: autopilot_tuning} of the packaged descriptions this autopilot can be recognised by (every name
    with the profile's ``tuning_prefix``: ArduPilot's ATC_*, PX4's MC_*)."""
    return {name: tuning for name, tuning in packaged_vehicle_tunings().items() if _is_tuning_of(tuning, profile)}


def _is_tuning_of(tuning: dict[str, float], profile: AutopilotProfile) -> bool:
    return bool(profile.tuning_prefix) and all(n.startswith(profile.tuning_prefix) for n in tuning)


def tuning_parameter_names(profile: AutopilotProfile) -> list[str]:
    """The autopilot parameters that choose a vehicle's loop numbers: every packaged description's ``autopilot_tuning``
    for this autopilot and the heading loop's (what ``--save-vehicle`` records); [] where it recognises nothing."""
    if not profile.tuning_prefix:
        return []
    names = {n for tuning in packaged_tunings(profile).values() for n in tuning} | set(profile.heading_loop_params)
    return sorted(names)


def tuning_drift(vehicle_given: str, profile: AutopilotProfile, read_parameter: ParameterReader) -> str:
    """A note when a given description's ``autopilot_tuning`` is not what the vehicle reports ("" when it is, or when
    the description records none): its loop numbers were chosen at that tuning and may not apply."""
    tuning = load_autopilot_tuning(vehicle_given)
    tuning = tuning if _is_tuning_of(tuning, profile) else {}  # another autopilot's tuning says nothing here
    changed = tuning_mismatches(tuning, read_parameter)
    if not changed:
        return ""
    return (f"{vehicle_given} was chosen at another tuning ({', '.join(changed)}): its loop numbers may not apply; "
            "fly without --vehicle to derive them again")


def yaw_tau_from_heading_loop(mapping, profile: AutopilotProfile, read_parameter: ParameterReader) -> tuple[float | None, str]:
    """(tau_z [s] or None, note) for a vehicle no description matches: the yaw tau_z that keeps the heading-trim
    path's gain, tau_z x yaw angle P x yaw rate P (the profile's ``heading_loop_params``), at ``mapping.yaw_loop_gain``
    (the gain measured good at ArduCopter's default tuning). Only where the yaw command trims the autopilot's
    attitude target (M6); None with the reason when a parameter is unreadable or the rule is off."""
    if not (profile.heading_loop_params and mapping.yaw_loop_gain > 0.0
            and yaw_from_reference(mapping.method, mapping.yaw_command_base, profile)):
        return None, ""
    values = [read_parameter(p) for p in profile.heading_loop_params]
    if any(v is None or not math.isfinite(v) or v <= 0.0 for v in values):
        read = ", ".join(f"{p} {'unreadable' if v is None else f'{v:g}'}" for p, v in zip(profile.heading_loop_params, values))
        return None, f"yaw tau_z not derived from the heading loop ({read}): the default description's is flown"
    loop = math.prod(values)  # type: ignore[arg-type]
    tau = min(max(mapping.yaw_loop_gain / loop, YAW_TAU_RANGE_S[0]), YAW_TAU_RANGE_S[1])
    return tau, (f"yaw tau_z {tau:.3g} s = mapping.yaw_loop_gain {mapping.yaw_loop_gain:g} / ("
                 + " x ".join(f"{p} {v:g}" for p, v in zip(profile.heading_loop_params, values)) + ")")


YAW_TAU_RANGE_S = (0.005, 0.2)  # [s] the derived tau_z is kept inside (0.2: PX4's slow yaw; 0.005: a trim still moves)


def _vehicle_note(vehicle: str, why: str, solo: SoloRigidBody, mapping, loop_replaced: bool, given: bool) -> str:
    return (f"vehicle description: {vehicle}{' (' + why + ')' if why else ''}: I0 "
            f"{', '.join(f'{i:.3g}' for i in solo.inertia_diag)} kg m^2"
            + (f"; rate loop tau {', '.join(f'{t:g}' for t in mapping.rate_time_constant_s)} s, "
               f"delay {', '.join(f'{t:g}' for t in mapping.loop_delay_s)} s, "
               f"shaping {', '.join(f'{f:g}' for f in mapping.shaping_accel_fraction)} of the accel limits" if loop_replaced else "")
            + ("" if given else "; pass --vehicle FILE for yours"))


def delay_bounded_alpha(controller, mapping) -> tuple[dict, str]:
    """(overrides, note) that keep an adaptive gain below ``adaptive_gain_ceiling`` on each axis: alpha_max =
    min(preset, ceiling), alpha_min = min(preset, alpha_max / 2). ({}, "") when the controller's gain does not adapt
    or ``mapping.bound_adaptive_gain`` is off; the user's own --set of these keys wins (applied after)."""
    ceiling = alpha_ceiling(controller, mapping)
    if not mapping.bound_adaptive_gain or ceiling is None:
        return {}, ""
    a = controller.adaptive_gain()
    lo, hi = per_axis(a.alpha_min), per_axis(a.alpha_max)
    new_hi = [min(h, c) for h, c in zip(hi, ceiling)]
    new_lo = [min(l_, 0.5 * h) for l_, h in zip(lo, new_hi)]
    note = ("adaptive gain bounded by the loop delay (mapping.loop_delay_s, + tau on integrated axes: "
            f"{', '.join(f'{d:.3g}' for d in switching_delay_s(mapping))} s): alpha {', '.join(f'{a:.3g}..{b:.3g}' for a, b in zip(new_lo, new_hi))}")
    return controller.limit_overrides(adaptive_gain_range=(tuple(new_lo), tuple(new_hi))), note


def yaw_integral_by_autopilot(controller, mapping, profile: AutopilotProfile) -> tuple[dict, str]:
    """M7: with the yaw command on the reference (M6) ArduCopter's attitude target integrates the yaw command, so a
    law's own yaw integral would be a second integrator in series (a slow yaw oscillation on genuine ArduCopter).
    ``mapping.yaw_integral: autopilot`` turns the law's attitude-error integral off on yaw (the protocol's
    ``limit_overrides(integral_off=...)``; ASTSM: epsilon 0 on yaw). ({}, "") otherwise, or when the law has no
    such integral."""
    if mapping.yaw_integral != "autopilot" or not yaw_from_reference(mapping.method, mapping.yaw_command_base, profile):
        return {}, ""
    extra = controller.limit_overrides(integral_off=(False, False, True))
    if not extra:
        return {}, ""
    return extra, ("yaw integral left to the autopilot's attitude target (mapping.yaw_integral): epsilon 0 on yaw"
                   if set(extra) == {"epsilon"} else f"yaw integral left to the autopilot's attitude target: {extra}")


def plan_flight(config: BridgeConfig, profile: AutopilotProfile, *, granted_rate_hz: float, report_accel_limit_radss,
                controller: Any, controller_named: bool, controller_vehicle: str, vehicle_given: str | None,
                user_mapping_keys: set[str], read_parameter: ParameterReader, mode: str | None = None,
                takeoff_alt_m: float | None = None) -> FlightPlan:
    """The flight plan for the preflight's findings (module docstring). ``controller`` is the law as built from its
    preset with ``controller_vehicle``'s I0; ``controller_named`` is False for a controller object (flown as built).
    Raises ConfigError for options the autopilot cannot fly (``--mode``, ``--takeoff-m``)."""
    if takeoff_alt_m is not None and profile.thrust_semantics != CLIMB_RATE and not profile.autopilot_takeoff:
        raise ConfigError("--takeoff-m needs climb-rate thrust semantics (ArduCopter default, GUID_OPTIONS bit 3 clear)")
    if mode is not None and mode not in profile.guided_modes:
        raise ConfigError(f"--mode {mode}: {profile.name} takes setpoints only in {', '.join(profile.guided_modes)}")
    vehicle, why, stand_in = (Recognition(vehicle_given, "", False) if vehicle_given is not None
                             else recognise_vehicle(profile, read_parameter))
    solo = load_solo(vehicle)
    loop = {k: v for k, v in load_offboard_loop(vehicle).items() if k not in user_mapping_keys}
    if loop:
        config = dataclasses.replace(config, mapping=dataclasses.replace(config.mapping, **loop))
    notes = [_vehicle_note(vehicle, why, solo, config.mapping, bool(loop), vehicle_given is not None)]
    drift = tuning_drift(vehicle_given, profile, read_parameter) if vehicle_given is not None else ""
    notes += [drift] if drift else []
    if stand_in and "rate_time_constant_s" not in user_mapping_keys:
        tau_z, note = yaw_tau_from_heading_loop(config.mapping, profile, read_parameter)
        if tau_z is not None:
            tau = (*config.mapping.rate_time_constant_s[:2], tau_z)
            config = dataclasses.replace(config, mapping=dataclasses.replace(config.mapping, rate_time_constant_s=tau))
        notes += [note] if note else []
    identify = identify_in_flight(config.mapping.identify_in_flight, stand_in, user_mapping_keys)
    if identify:
        notes.append(f"the loop is identified in flight before the profile (mapping.identify_in_flight="
                     f"{config.mapping.identify_in_flight}): {excitation_text()}, {IDENTIFICATION_TEXT}")
    if granted_rate_hz != config.timing.attitude_rate_hz:  # the loop's nominal period is what the vehicle granted
        config = dataclasses.replace(config, timing=dataclasses.replace(config.timing, attitude_rate_hz=granted_rate_hz))
    m = config.mapping
    accel = report_accel_limit_radss or m.accel_limit_radss  # ATC_ACCEL: reference shaping, the hidden-target model
    adaptive = alpha_max(controller) is not None  # ASTSM: its switching gain adapts (configs/bridge.yaml, command_accel_clip)
    authority = command_torque_limit_nm(m, solo.inertia_diag, accel, adaptive)
    overrides: dict = {}
    if controller_named:
        overrides, alpha_note = delay_bounded_alpha(controller, m)
        yaw_extra, yaw_note = yaw_integral_by_autopilot(controller, m, profile)
        overrides.update(yaw_extra)
        notes += [n for n in (yaw_note, alpha_note) if n]
        if m.limit_controller_torque:  # the law's anti-windup must know what the vehicle can realise
            overrides.update(controller.limit_overrides(torque_limit_nm=tuple(authority)))
    return FlightPlan(vehicle=vehicle, solo=solo, config=config, accel_limit_radss=accel, adaptive=adaptive,
                      torque_authority_nm=tuple(authority), controller_overrides=overrides,
                      rebuild_controller=controller_named and bool(overrides or vehicle != controller_vehicle),
                      notes=tuple(notes), identify_in_flight=identify,
                      hold_altitude=profile.thrust_semantics == COLLECTIVE and config.thrust.altitude_hold)


IDENTIFICATION_TEXT = ("every failsafe armed; the rate loop flown at tau_flown / k where the fit holds "
                       "(docs/bridge.md, 'Identifying the loop in flight')")


def identify_in_flight(mode: str, stand_in: bool, user_mapping_keys: set[str]) -> bool:
    """Whether the first engagement flies the identification phase: ``always``; ``auto`` when the profile's default
    stands in for a tuning no description matches and the user did not --set the rate loop's tau; never ``never``.
    (A given --vehicle is no stand-in.)"""
    return mode == "always" or (mode == "auto" and stand_in and "rate_time_constant_s" not in user_mapping_keys)

