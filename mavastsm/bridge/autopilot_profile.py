"""Everything the bridge knows about one autopilot family, in one place (pure data, no I/O).

The control cycle, the session, preflight and the hand-back ask an ``AutopilotProfile`` instead of
testing the autopilot's name. What differs between ArduCopter (4.2+) and PX4 (1.13+), and why:

================================  ================================  =====================================
question                          ArduCopter                        PX4
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
"""

from __future__ import annotations

from dataclasses import dataclass

CLIMB_RATE = "climb_rate"
COLLECTIVE = "collective"
PX4_OFFBOARD_CUSTOM_MODE = 6 << 16  # 393216: main mode OFFBOARD (6) in bits 16-23


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
    hover_thrust_param : the parameter that holds the hover collective [0..1], or "" when none is needed
    hover_from_target_thrust : the autopilot's ATTITUDE_TARGET.thrust is the collective its own controllers command
        (PX4: |thrust_body| of its attitude setpoint), so in its own hold mode it is the collective that hovers the
        vehicle as it is (payload included), measured before the guided mode (preflight.measure_hover_collective)
    default_vehicle : the configs/vehicle description flown when --vehicle is not given and none is recognised
    vehicle_by_tuning : recognise a packaged description by its ``autopilot_tuning`` (the parameters its loop
        numbers were measured with), read from the vehicle at preflight
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
    hover_thrust_param: str = ""
    hover_from_target_thrust: bool = False
    autopilot_takeoff: bool = False
    rate_cap_reason: str = ""  # why an accepted ATTITUDE rate may arrive slower
    default_vehicle: str = "solo"  # configs/vehicle description flown when --vehicle is not given
    vehicle_by_tuning: bool = False  # recognise a packaged vehicle description by its autopilot_tuning parameters
    attitude_gate: str = ""  # what the autopilot waits for before its first ATTITUDE ("" = sends it from boot)

    def handback_modes(self, action: str) -> tuple[str, ...]:
        """The modes to request, in order, for hand-back ``action`` (ALT_HOLD / LOITER / LAND)."""
        return dict(self.handback).get(action, (action,))


def ardupilot_profile(thrust_semantics: str, climb_hold_norm: float = 0.5, hover_collective_norm: float = 0.35) -> AutopilotProfile:
    """ArduCopter 4.2+: body-rate mask 0x80 in GUIDED / GUIDED_NOGPS; thrust per GUID_OPTIONS bit 3.

    LOITER needs a position estimate (GPS): refused -> ALT_HOLD, which needs only the barometer.
    """
    hover = climb_hold_norm if thrust_semantics == CLIMB_RATE else hover_collective_norm
    return AutopilotProfile(
        "ArduPilot", thrust_semantics, hover, ("GUIDED", "GUIDED_NOGPS"),
        handback=(("ALT_HOLD", ("ALT_HOLD", "LAND")), ("LOITER", ("LOITER", "ALT_HOLD", "LAND")), ("LAND", ("LAND",))),
        prestream_required=False, hidden_attitude_target=True,
        setpoint_timeout_param="GUID_TIMEOUT", setpoint_timeout_range_s=(0.1, 5.0),
        rate_cap_reason="ArduCopter before 4.6 caps a message interval at what its main loop allows (SCHED_LOOP_RATE)",
        vehicle_by_tuning=True,  # ATC_ACCEL_*_MAX / ATC_ANG_*_P tell the Solo_AC35 tuning from SITL's stock quad
    )


def px4_profile(hover_collective_norm: float = 0.5) -> AutopilotProfile:
    """PX4: OFFBOARD only; thrust is always a normalised collective (never a climb rate).

    ALTCTL/POSCTL are refused (MAV_RESULT 1) without a manual-control source (RC or MANUAL_CONTROL),
    which an offboard vehicle often lacks: ALT_HOLD falls back to LOITER (Hold), then LAND.
    """
    return AutopilotProfile(
        "PX4", COLLECTIVE, hover_collective_norm, ("OFFBOARD",),
        handback=(("ALT_HOLD", ("ALTCTL", "LOITER", "LAND")), ("LOITER", ("LOITER", "LAND")), ("LAND", ("LAND",))),
        prestream_required=True, hidden_attitude_target=False,
        setpoint_timeout_param="COM_OF_LOSS_T", setpoint_timeout_range_s=(0.0, 60.0),
        hover_thrust_param="MPC_THR_HOVER", hover_from_target_thrust=True, autopilot_takeoff=True,
        rate_cap_reason="PX4 streams ATTITUDE no faster than its attitude estimate updates",
        default_vehicle="px4_sih_quadx",  # PX4's stock SIH vehicle
        attitude_gate="PX4's estimator (EKF2) to have an attitude (about 33 s after boot on SITL)",
    )


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
