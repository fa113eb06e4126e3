"""ArduCopter 4.2+: body-rate setpoints (type_mask 0x80) in GUIDED / GUIDED_NOGPS; thrust per GUID_OPTIONS bit 3.

What the preflight reads here: GUID_OPTIONS (bit 3 = thrust is a collective, else a climb rate with 0.5 = hold;
written with ``thrust.set_guid_options``), ATC_ACCEL_R/P/Y_MAX (the slew limit ArduCopter puts on every body-rate
command, docs/bridge.md M3) and ATC_ANG_RLL/PIT/YAW_P (its hidden attitude target's gains, mirrored by
``autopilot_target_model`` when ``mapping.compensate_autopilot_target``). The setpoint timeout is GUID_TIMEOUT.
LOITER needs a position estimate (GPS): refused -> ALT_HOLD, which needs only the barometer.
"""

from __future__ import annotations

import math

from pymavlink import mavutil  # its ArduPilot mode tables (mode_mapping_byname): the library's copy, not ours

from ...errors import ConfigError, OffboardRejected
from .profile import CLIMB_RATE, COLLECTIVE, AutopilotProfile

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
GUID_OPTIONS_THRUST_AS_THRUST = 8
ACCEL_LIMIT_PARAMS = ("ATC_ACCEL_R_MAX", "ATC_ACCEL_P_MAX", "ATC_ACCEL_Y_MAX")  # [cdeg/s^2], 0 = unlimited
ANGLE_P_PARAMS = ("ATC_ANG_RLL_P", "ATC_ANG_PIT_P", "ATC_ANG_YAW_P")  # [1/s]


def ardupilot_profile(thrust_semantics: str, climb_hold_norm: float = 0.5, hover_collective_norm: float = 0.35) -> AutopilotProfile:
    """The profile for a thrust field of ``thrust_semantics`` (CLIMB_RATE: 0.5 holds altitude; COLLECTIVE)."""
    hover = climb_hold_norm if thrust_semantics == CLIMB_RATE else hover_collective_norm
    return AutopilotProfile(
        "ArduPilot", thrust_semantics, hover, ("GUIDED", "GUIDED_NOGPS"),
        handback=(("ALT_HOLD", ("ALT_HOLD", "LAND")), ("LOITER", ("LOITER", "ALT_HOLD", "LAND")), ("LAND", ("LAND",))),
        prestream_required=False, hidden_attitude_target=True,
        setpoint_timeout_param="GUID_TIMEOUT", setpoint_timeout_range_s=(0.1, 5.0), setpoint_timeout_default_s=3.0,
        rate_cap_reason="ArduCopter before 4.6 caps a message interval at what its main loop allows (SCHED_LOOP_RATE)",
        tuning_prefix="ATC_",  # ATC_ACCEL_*_MAX / ATC_ANG_*_P tell the Solo_AC35 tuning from SITL's stock quad
        # a tuning no description matches flies the loop numbers measured at ArduCopter's default tuning (the stock
        # quad's), not the Solo's: measured on three retunes, docs/bridge.md "Vehicle descriptions"
        default_vehicle="arducopter_sitl_quad",
        heading_loop_params=("ATC_ANG_YAW_P", "ATC_RAT_YAW_P"),  # [1/s] x [output per rad/s]
    )


def body_rate_support(version: tuple[int, int, int]) -> str | None:
    """None if ArduCopter accepts rates-only SET_ATTITUDE_TARGET (4.2+, AP PR#18833), else the refusal reason."""
    if version[:2] < (4, 2):
        return (
            f"ArduCopter {version[0]}.{version[1]}.{version[2]} ignores body-rate-only SET_ATTITUDE_TARGET "
            "(type_mask 0x80 arrived in 4.2, AP PR#18833); upgrade to 4.2 or later"
        )
    return None


def thrust_semantics(requested: str, guid_options: float | None) -> str:
    """Pure rule: 'auto' -> GUID_OPTIONS bit 3; an explicit request must agree with GUID_OPTIONS.

    Raises ConfigError when GUID_OPTIONS is unknown and nothing explicit was asked, or when the explicit request
    contradicts it.
    """
    if guid_options is None:
        if requested == "auto":
            raise ConfigError(
                "GUID_OPTIONS could not be read, so the thrust meaning (climb rate or collective) is unknown; "
                "pass --set thrust.semantics=climb_rate or collective"
            )
        return requested
    actual = COLLECTIVE if int(guid_options) & GUID_OPTIONS_THRUST_AS_THRUST else CLIMB_RATE
    if requested not in ("auto", actual):
        raise ConfigError(
            f"thrust.semantics={requested} but GUID_OPTIONS={int(guid_options)} means {actual}; "
            "set thrust.set_guid_options=true to change it, or match the vehicle"
        )
    return actual


class ArduPilotAdapter:
    """ArduCopter (HEARTBEAT.autopilot MAV_AUTOPILOT_ARDUPILOTMEGA)."""

    name = "ArduPilot"
    mav_autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA

    def body_rate_refusal(self, version):
        if version is None:
            return "cannot confirm ArduCopter >= 4.2, which body-rate offboard control needs (no AUTOPILOT_VERSION)"
        return body_rate_support(version)

    def configure(self, params, cfg, rep) -> AutopilotProfile:
        tc = cfg.thrust
        guid_options = params.read_with_retries("GUID_OPTIONS")
        if tc.set_guid_options and tc.semantics != "auto":
            base = int(guid_options or 0)
            want = base | GUID_OPTIONS_THRUST_AS_THRUST if tc.semantics == COLLECTIVE else base & ~GUID_OPTIONS_THRUST_AS_THRUST
            if want != base or guid_options is None:
                if not params.write("GUID_OPTIONS", float(want)):
                    raise OffboardRejected(f"PARAM_SET GUID_OPTIONS={want}", None, "no matching PARAM_VALUE echo")
                rep.notes.append(f"GUID_OPTIONS set {int(guid_options or 0)} -> {want}")
                guid_options = float(want)
        rep.thrust_semantics = thrust_semantics(tc.semantics, guid_options)
        rep.thrust_detail = "GUID_OPTIONS=" + ("unknown" if guid_options is None else f"{guid_options:g}")
        rep.accel_limit_radss, rep.accel_limit_source = accel_limits(params, cfg.mapping.accel_limit_radss)
        if cfg.mapping.compensate_autopilot_target:
            rep.angle_p = angle_p(params)
        return ardupilot_profile(rep.thrust_semantics, tc.climb_hold_norm, tc.hover_collective_norm)

    def mode_command(self, mode: str, mav_type: int) -> tuple[float, ...]:
        mapping = mavutil.mode_mapping_byname(mav_type) or {}
        if mode not in mapping:
            raise ConfigError(f"mode {mode!r} unknown for this vehicle; known: {', '.join(mapping)}")
        return float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(mapping[mode])


def accel_limits(params, fallback_radss) -> tuple[tuple[float, float, float], str]:
    """ATC_ACCEL_R/P/Y_MAX [cdeg/s^2] -> [rad/s^2]; ``fallback_radss`` (the config) per axis where unreadable or 0
    (= unlimited). Returns (limits, where they came from)."""
    out, source = [], "vehicle ATC_ACCEL_*_MAX"
    for i, name in enumerate(ACCEL_LIMIT_PARAMS):
        v = params.read(name)
        if v is None or not math.isfinite(v) or v <= 0:
            out.append(fallback_radss[i])
            source = "config (vehicle value unreadable or unlimited)"
        else:
            out.append(math.radians(v / 100.0))
    return tuple(out), source  # type: ignore[return-value]


def angle_p(params) -> tuple[float, float, float] | None:
    """ATC_ANG_RLL_P / PIT_P / YAW_P [1/s]; None (no compensation) when any is unreadable."""
    out = []
    for name in ANGLE_P_PARAMS:
        v = params.read(name)
        if v is None or not math.isfinite(v) or v < 0:
            return None
        out.append(float(v))
    return tuple(out)  # type: ignore[return-value]


ADAPTER = ArduPilotAdapter()
