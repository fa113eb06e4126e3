"""PX4 1.13+: body-rate setpoints only in OFFBOARD, which it refuses without >= 1 s of setpoints streamed first;
thrust is always a normalised collective (never a climb rate).

The hover collective is MPC_THR_HOVER (``thrust.hover_from_vehicle``), and where its own hold flies one before
OFFBOARD, the collective measured from its ATTITUDE_TARGET.thrust (``preflight.measure_hover_collective``). The
setpoint timeout is COM_OF_LOSS_T. ALTCTL/POSCTL are refused (MAV_RESULT 1) without a manual-control source (RC or
MANUAL_CONTROL), which an offboard vehicle often lacks: the ALT_HOLD hand-back falls back to LOITER (Hold), then LAND.
"""

from __future__ import annotations

import math

from pymavlink import mavutil  # its PX4 mode table (px4_map): the library's copy, not ours

from ...errors import ConfigError
from .profile import CLIMB_RATE, COLLECTIVE, AutopilotProfile

MAV_AUTOPILOT_PX4 = 12
OFFBOARD_CUSTOM_MODE = 6 << 16  # 393216: main mode OFFBOARD (6) in bits 16-23
HOVER_THRUST_PARAM = "MPC_THR_HOVER"
HOVER_PARAMETER_RANGE_NORM = (0.05, 0.95)  # a value outside is not a hover collective (unset or misread)


def px4_profile(hover_collective_norm: float = 0.5) -> AutopilotProfile:
    """The profile at the hover collective ``hover_collective_norm`` [-]."""
    return AutopilotProfile(
        "PX4", COLLECTIVE, hover_collective_norm, ("OFFBOARD",),
        handback=(("ALT_HOLD", ("ALTCTL", "LOITER", "LAND")), ("LOITER", ("LOITER", "LAND")), ("LAND", ("LAND",))),
        prestream_required=True, hidden_attitude_target=False,
        setpoint_timeout_param="COM_OF_LOSS_T", setpoint_timeout_range_s=(0.0, 60.0), setpoint_timeout_default_s=1.0,
        hover_thrust_param=HOVER_THRUST_PARAM, hover_from_target_thrust=True, autopilot_takeoff=True,
        rate_cap_reason="PX4 streams ATTITUDE no faster than its attitude estimate updates",
        default_vehicle="px4_sih_quadx",  # PX4's stock SIH vehicle, recognised by its default MC_* rate and angle gains
        tuning_prefix="MC_",  # another tuning flies px4_sih_quadx's numbers as a stand-in: the loop is identified in flight
        attitude_gate="PX4's estimator (EKF2) to have an attitude (about 33 s after boot on SITL)",
    )


class Px4Adapter:
    """PX4 (HEARTBEAT.autopilot MAV_AUTOPILOT_PX4)."""

    name = "PX4"
    mav_autopilot = MAV_AUTOPILOT_PX4

    def body_rate_refusal(self, version):
        return None  # every PX4 the project flies (1.13+) takes body rates in OFFBOARD

    def configure(self, params, cfg, rep) -> AutopilotProfile:
        tc = cfg.thrust
        if tc.semantics == CLIMB_RATE:
            raise ConfigError("thrust.semantics=climb_rate: PX4 only accepts a normalised collective thrust")
        rep.thrust_semantics = COLLECTIVE
        hover = tc.hover_collective_norm
        rep.hover_source = "thrust.hover_collective_norm"
        if tc.hover_from_vehicle:
            read = params.read_with_retries(HOVER_THRUST_PARAM)
            lo, hi = HOVER_PARAMETER_RANGE_NORM
            if read is not None and math.isfinite(read) and lo <= read <= hi:
                hover = rep.hover_parameter_norm = float(read)
                rep.hover_source = HOVER_THRUST_PARAM
                rep.notes.append(f"hover collective {hover:.3f} from {HOVER_THRUST_PARAM}")
            else:
                rep.notes.append(f"{HOVER_THRUST_PARAM} unreadable: hover collective {hover:g} from thrust.hover_collective_norm")
            if tc.hover_measure_s > 0:
                rep.hover_source += (f"; measured from PX4's hold (ATTITUDE_TARGET thrust, last {tc.hover_measure_s:g} s "
                                     "before OFFBOARD) when it flies one")
        rep.hover_collective_norm = hover
        rep.thrust_detail = f"PX4 normalised collective, hover {hover:g} from {rep.hover_source}"
        return px4_profile(hover)

    def mode_command(self, mode: str, mav_type: int) -> tuple[float, ...]:
        if mode not in mavutil.px4_map:
            raise ConfigError(f"mode {mode!r} unknown for PX4; known: {', '.join(mavutil.px4_map)}")
        base, main, sub = mavutil.px4_map[mode]
        return float(base), float(main), float(sub)


ADAPTER = Px4Adapter()
