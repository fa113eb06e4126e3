"""Preflight: who is on the other end, what it accepts, and whether ATTITUDE arrives fast enough.

1. Autopilot and version from HEARTBEAT + AUTOPILOT_VERSION (REQUEST_MESSAGE 148, falling back
   to REQUEST_AUTOPILOT_CAPABILITIES). ArduCopter older than 4.2 ignores rates-only targets
   (mavlink-notes E1): refused with the reason.
2. Thrust semantics (E4): ArduCopter reads GUID_OPTIONS (bit 3 = thrust is thrust) and GUID_TIMEOUT;
   with ``thrust.set_guid_options`` the bit is written to match the requested semantics. PX4 is
   always a normalised collective.
3. SET_MESSAGE_INTERVAL for ATTITUDE (and ATTITUDE_TARGET) with COMMAND_ACK checked; the achieved
   rate is measured later from ``time_boot_ms`` deltas (E10) and re-asserted when a GCS overrides it (E9).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..errors import ConfigError, OffboardRejected
from .bridge_config import BridgeConfig
from .inbound_messages import ardupilot_body_rate_support, decode_flight_sw_version
from .mavlink_link import MSG_ID_ATTITUDE, MSG_ID_ATTITUDE_TARGET, MSG_ID_AUTOPILOT_VERSION, MavlinkLink
from .setpoint_mapping import CLIMB_RATE, COLLECTIVE, AutopilotProfile, ardupilot_profile, px4_profile

GUID_OPTIONS_THRUST_AS_THRUST = 8
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520


@dataclass
class PreflightReport:
    """Everything preflight found, for the one-screen summary and the LinkStatus."""

    url: str
    system: int
    component: int
    autopilot: str
    firmware_version: str = "unknown"
    mode: str = ""
    armed: bool = False
    thrust_semantics: str = ""
    guid_options: float | None = None
    guid_timeout_s: float | None = None
    attitude_rate_requested_hz: float = float("nan")
    attitude_target_requested: bool = False
    signing: bool = False
    accel_limit_radss: tuple[float, float, float] | None = None
    accel_limit_source: str = "config"
    angle_p: tuple[float, float, float] | None = None
    notes: list[str] = field(default_factory=list)


def choose_thrust_semantics(autopilot: str, requested: str, guid_options: float | None) -> str:
    """Pure rule: PX4 -> collective; ArduCopter 'auto' -> GUID_OPTIONS bit 3; explicit must agree with GUID_OPTIONS.

    Raises ConfigError when ArduCopter's GUID_OPTIONS is unknown and nothing explicit was asked, or
    when the explicit request contradicts it.
    """
    if autopilot == "PX4":
        if requested == CLIMB_RATE:
            raise ConfigError("thrust.semantics=climb_rate: PX4 only accepts a normalised collective thrust")
        return COLLECTIVE
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


def run_preflight(link: MavlinkLink, cfg: BridgeConfig) -> tuple[PreflightReport, AutopilotProfile]:
    """Identify the autopilot, settle thrust semantics and request the telemetry the loop needs.

    Raises OffboardRejected (old ArduCopter, refused interval) or ConfigError (thrust semantics).
    """
    hb = link.last_heartbeat
    assert hb is not None
    lc = cfg.link
    rep = PreflightReport(link.url, hb.system, hb.component, hb.autopilot, mode=hb.mode, armed=hb.armed, signing=link.signing)
    version_msg = link.request_message(MSG_ID_AUTOPILOT_VERSION, lc.command_ack_timeout_s)
    if version_msg is None:
        try:
            link.command_long(MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, (1.0,), "REQUEST_AUTOPILOT_CAPABILITIES", lc.command_ack_timeout_s, 1)
        except OffboardRejected:
            pass
        version_msg = link.latest.get("AUTOPILOT_VERSION")
    version = None
    if version_msg is not None:
        version = decode_flight_sw_version(version_msg.flight_sw_version)
        rep.firmware_version = "{}.{}.{}".format(*version)
    if hb.autopilot == "ArduPilot":
        if version is None:
            raise OffboardRejected("AUTOPILOT_VERSION", None, "cannot confirm ArduCopter >= 4.2, which body-rate offboard control needs")
        refusal = ardupilot_body_rate_support(version)
        if refusal:
            raise OffboardRejected("body-rate offboard control", None, refusal)
    elif hb.autopilot != "PX4":
        raise OffboardRejected("autopilot detection", None, f"autopilot type {hb.autopilot!r} is neither ArduPilot nor PX4")

    tc = cfg.thrust
    if hb.autopilot == "ArduPilot":
        rep.guid_options = link.param_read("GUID_OPTIONS", lc.param_timeout_s, lc.command_retries)
        rep.guid_timeout_s = link.param_read("GUID_TIMEOUT", lc.param_timeout_s, lc.command_retries)
        if tc.set_guid_options and tc.semantics != "auto":
            base = int(rep.guid_options or 0)
            want = base | GUID_OPTIONS_THRUST_AS_THRUST if tc.semantics == COLLECTIVE else base & ~GUID_OPTIONS_THRUST_AS_THRUST
            if want != base or rep.guid_options is None:
                if not link.param_set("GUID_OPTIONS", float(want), lc.param_timeout_s, lc.command_retries):
                    raise OffboardRejected(f"PARAM_SET GUID_OPTIONS={want}", None, "no matching PARAM_VALUE echo")
                rep.notes.append(f"GUID_OPTIONS set {int(rep.guid_options or 0)} -> {want}")
                rep.guid_options = float(want)
        rep.thrust_semantics = choose_thrust_semantics("ArduPilot", tc.semantics, rep.guid_options)
        rep.accel_limit_radss, rep.accel_limit_source = _ardupilot_accel_limits(link, cfg)
        if cfg.mapping.compensate_autopilot_target:
            rep.angle_p = _ardupilot_angle_p(link, cfg)
        profile = ardupilot_profile(rep.thrust_semantics, tc.climb_hold_norm, tc.hover_collective_norm)
        period = 1.0 / cfg.timing.attitude_rate_hz
        if rep.guid_timeout_s is not None and rep.guid_timeout_s < 10 * period:
            rep.notes.append(f"GUID_TIMEOUT {rep.guid_timeout_s:g} s is less than 10 control periods")
    else:
        rep.accel_limit_radss = tuple(cfg.mapping.accel_limit_radss)  # type: ignore[assignment]
        rep.thrust_semantics = choose_thrust_semantics("PX4", tc.semantics, None)
        profile = px4_profile(tc.hover_collective_norm)

    link.set_message_interval(MSG_ID_ATTITUDE, cfg.timing.attitude_rate_hz, lc.command_ack_timeout_s, lc.command_retries)
    rep.attitude_rate_requested_hz = cfg.timing.attitude_rate_hz
    if cfg.timing.attitude_target_rate_hz > 0:
        try:
            link.set_message_interval(MSG_ID_ATTITUDE_TARGET, cfg.timing.attitude_target_rate_hz, lc.command_ack_timeout_s, 1)
            rep.attitude_target_requested = True
        except OffboardRejected as exc:
            rep.notes.append(f"ATTITUDE_TARGET not available ({exc})")
    return rep, profile


def _ardupilot_accel_limits(link: MavlinkLink, cfg: BridgeConfig) -> tuple[tuple[float, float, float], str]:
    """ATC_ACCEL_R/P/Y_MAX [cdeg/s^2] -> [rad/s^2]; the config value per axis where unreadable or 0 (= unlimited)."""
    out, source = [], "vehicle ATC_ACCEL_*_MAX"
    for i, name in enumerate(("ATC_ACCEL_R_MAX", "ATC_ACCEL_P_MAX", "ATC_ACCEL_Y_MAX")):
        v = link.param_read(name, cfg.link.param_timeout_s, 1)
        if v is None or not math.isfinite(v) or v <= 0:
            out.append(cfg.mapping.accel_limit_radss[i])
            source = "config (vehicle value unreadable or unlimited)"
        else:
            out.append(math.radians(v / 100.0))
    return tuple(out), source  # type: ignore[return-value]


def _ardupilot_angle_p(link: MavlinkLink, cfg: BridgeConfig) -> tuple[float, float, float] | None:
    """ATC_ANG_RLL_P / PIT_P / YAW_P [1/s]; None (no compensation) when any is unreadable."""
    out = []
    for name in ("ATC_ANG_RLL_P", "ATC_ANG_PIT_P", "ATC_ANG_YAW_P"):
        v = link.param_read(name, cfg.link.param_timeout_s, 1)
        if v is None or not math.isfinite(v) or v < 0:
            return None
        out.append(float(v))
    return tuple(out)  # type: ignore[return-value]


def format_preflight(rep: PreflightReport, achieved_hz: float, controller: str, reference: str, mapping: str, scheduling: str = "") -> str:
    """The one-screen preflight summary (plain text); ``scheduling`` = how the control thread is scheduled."""

    def fmt(x, unit=""):
        return "unknown" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:g}{unit}"

    lines = [
        f"mavastsm connect: {rep.url}",
        f"  vehicle      : system {rep.system} component {rep.component}, {rep.autopilot} {rep.firmware_version}, mode {rep.mode}, {'ARMED' if rep.armed else 'disarmed'}",
        f"  thrust       : {rep.thrust_semantics}" + (f" (GUID_OPTIONS={fmt(rep.guid_options)}, GUID_TIMEOUT={fmt(rep.guid_timeout_s, ' s')})" if rep.autopilot == "ArduPilot" else " (PX4 normalised collective)"),
        f"  ATTITUDE     : requested {fmt(rep.attitude_rate_requested_hz, ' Hz')}, achieved {fmt(round(achieved_hz, 1) if math.isfinite(achieved_hz) else float('nan'), ' Hz')} (from time_boot_ms)",
        f"  controller   : {controller}, reference {reference}, mapping {mapping}",
        "  target model : " + (f"on (ATC_ANG_P {', '.join(f'{p:g}' for p in rep.angle_p)})" if rep.angle_p else "off"),
        "  accel limits : " + (", ".join(f"{a:.2f}" for a in rep.accel_limit_radss) + f" rad/s^2 ({rep.accel_limit_source})" if rep.accel_limit_radss else "none"),
        f"  signing      : {'on' if rep.signing else 'off'}",
    ]
    if scheduling:
        lines.append(f"  control loop : {scheduling}")
    lines += [f"  note         : {n}" for n in rep.notes]
    return "\n".join(lines)
