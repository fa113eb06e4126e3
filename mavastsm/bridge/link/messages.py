"""The link's typed messages, in and out (pure; duck-typed on message attributes, no pymavlink import).

In: raw MAVLink messages -> typed samples. Out: :class:`Setpoint`, one SET_ATTITUDE_TARGET payload, and its type masks.

ATTITUDE (msg 30) as ArduCopter/PX4 fill it: ``time_boot_ms`` = autopilot uptime [ms];
roll/pitch/yaw [rad] ZYX Euler NED -> FRD; rollspeed/pitchspeed/yawspeed = **body rates**
p, q, r [rad/s, FRD] (not Euler rates).
"""

from __future__ import annotations

from dataclasses import dataclass

MAV_AUTOPILOT_INVALID = 8
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_STATE_BOOT = 1  # HEARTBEAT system_status while booting (ArduCopter until it is ready)
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27})  # GCS, ONBOARD_CONTROLLER, GIMBAL, ADSB


# ATTITUDE_TARGET_TYPEMASK bits (common.xml). Unit-tested constants (docs/design-decisions.md, MAV-10).
BODY_ROLL_RATE_IGNORE = 1
BODY_PITCH_RATE_IGNORE = 2
BODY_YAW_RATE_IGNORE = 4
THROTTLE_IGNORE = 64
ATTITUDE_IGNORE = 128

TYPE_MASK_RATES = ATTITUDE_IGNORE  # 0x80: body rates + thrust, quaternion ignored (our control mode)
TYPE_MASK_ATTITUDE = BODY_ROLL_RATE_IGNORE | BODY_PITCH_RATE_IGNORE | BODY_YAW_RATE_IGNORE  # 0x07: attitude + thrust
TYPE_MASK_ZERO_RATES = ATTITUDE_IGNORE | TYPE_MASK_ATTITUDE  # 0x87: zero quaternion, zero rates
ALLOWED_TYPE_MASKS = frozenset({TYPE_MASK_RATES, TYPE_MASK_ATTITUDE, TYPE_MASK_ZERO_RATES})


@dataclass(frozen=True, slots=True)
class Setpoint:
    """One SET_ATTITUDE_TARGET payload (target ids added by the link).

    Attributes
    ----------
    type_mask : one of ALLOWED_TYPE_MASKS
    q_wxyz : quaternion NED -> FRD (zeros when ATTITUDE_IGNORE)
    body_rates_rads : [rad/s, body FRD] (zeros when the rate-ignore bits are set)
    thrust_norm : [0..1] climb-rate or collective per the profile
    """

    type_mask: int
    q_wxyz: tuple[float, float, float, float]
    body_rates_rads: tuple[float, float, float]
    thrust_norm: float


ZERO_Q = (0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class AttitudeTarget:
    """The autopilot's own attitude target (ATTITUDE_TARGET), as the link hands it on.

    time_boot_ms : [ms] vehicle clock; q_wxyz : NED -> FRD quaternion; body_rates_rads : [rad/s, body FRD] (p, q, r);
    thrust_norm : [-] the message's ``thrust`` (PX4: the magnitude of the collective its own controllers command, 0..1;
    NaN when not given)
    """

    time_boot_ms: int
    q_wxyz: tuple[float, float, float, float]
    body_rates_rads: tuple[float, float, float]
    thrust_norm: float = float("nan")


def attitude_target(msg) -> AttitudeTarget:
    """ATTITUDE_TARGET -> AttitudeTarget."""
    return AttitudeTarget(int(msg.time_boot_ms), tuple(float(c) for c in msg.q),  # type: ignore[arg-type]
                          (float(msg.body_roll_rate), float(msg.body_pitch_rate), float(msg.body_yaw_rate)),
                          float(msg.thrust))


@dataclass(frozen=True, slots=True)
class TargetInMode:
    """One ATTITUDE_TARGET with the mode and arming of the autopilot's last HEARTBEAT when it arrived (so a
    measurement can keep the targets of one flight mode, e.g. PX4's hold before OFFBOARD)."""

    target: AttitudeTarget
    mode: str
    armed: bool


@dataclass(frozen=True, slots=True)
class AutopilotVersion:
    """AUTOPILOT_VERSION as the link hands it on.

    version : (major, minor, patch) from ``flight_sw_version`` (major<<24 | minor<<16 | patch<<8 | type);
    release_type : its low byte (255 = official release); capabilities : MAV_PROTOCOL_CAPABILITY bits
    """

    version: tuple[int, int, int]
    release_type: int
    capabilities: int

    @property
    def text(self) -> str:
        """'major.minor.patch'."""
        return "{}.{}.{}".format(*self.version)


def autopilot_version(msg) -> AutopilotVersion:
    """AUTOPILOT_VERSION -> AutopilotVersion."""
    raw = int(msg.flight_sw_version)
    return AutopilotVersion(decode_flight_sw_version(raw), raw & 0xFF, int(msg.capabilities))


@dataclass(frozen=True, slots=True)
class GlobalPosition:
    """GLOBAL_POSITION_INT altitudes as the link hands them on.

    time_boot_ms : [ms] vehicle clock; alt_amsl_m : [m] above mean sea level; relative_alt_m : [m] above home
    """

    time_boot_ms: int
    alt_amsl_m: float
    relative_alt_m: float

    @property
    def home_amsl_m(self) -> float:
        """[m] home altitude above mean sea level."""
        return self.alt_amsl_m - self.relative_alt_m


def global_position(msg) -> GlobalPosition:
    """GLOBAL_POSITION_INT (alt, relative_alt in mm) -> GlobalPosition in metres."""
    return GlobalPosition(int(msg.time_boot_ms), int(msg.alt) / 1000.0, int(msg.relative_alt) / 1000.0)


@dataclass(frozen=True, slots=True)
class LocalPosition:
    """LOCAL_POSITION_NED as the link hands it on.

    time_boot_ms : [ms] vehicle clock; position_ned_m : [m] (x, y, z) from the EKF origin, z down;
    velocity_ned_ms : [m/s] (vx, vy, vz), vz down
    """

    time_boot_ms: int
    position_ned_m: tuple[float, float, float]
    velocity_ned_ms: tuple[float, float, float]


def local_position(msg) -> LocalPosition:
    """LOCAL_POSITION_NED -> LocalPosition."""
    return LocalPosition(int(msg.time_boot_ms), (float(msg.x), float(msg.y), float(msg.z)),
                         (float(msg.vx), float(msg.vy), float(msg.vz)))


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """One ATTITUDE message.

    Attributes
    ----------
    time_boot_ms : [ms] vehicle clock
    euler_rad : [rad] (roll, pitch, yaw), ZYX NED -> FRD
    body_rates_rads : [rad/s, body FRD] (p, q, r)
    rx_ns : [ns] host monotonic time of its arrival: the kernel's receive time of its datagram on a UDP link (so
        the time it waited in the socket while the bridge was busy counts), else when the reader thread parsed it
    superseded : older samples of the same burst this one replaced (queued together in the reader; the
        vehicle sent them, so they count towards the achieved rate and are not missed cycles)
    burst_start_ns : [ns] arrival of the oldest sample of that burst (``rx_ns`` when none was superseded): how long
        the bridge left the burst's first sample unanswered (the session's ``late`` counter)
    autopilot_target : the autopilot's latest ATTITUDE_TARGET when the link delivered this sample (None before the first): the
        link hands it on with the sample, so the control cycle never calls back into the link for it
    """

    time_boot_ms: int
    euler_rad: tuple[float, float, float]
    body_rates_rads: tuple[float, float, float]
    rx_ns: int
    superseded: int = 0
    burst_start_ns: int = 0
    autopilot_target: AttitudeTarget | None = None


def attitude_sample(msg, rx_ns: int, autopilot_target: AttitudeTarget | None = None) -> AttitudeSample:
    """ATTITUDE (+ the latest ATTITUDE_TARGET) -> AttitudeSample (values copied as floats; validity checked by safety)."""
    return AttitudeSample(
        int(msg.time_boot_ms),
        (float(msg.roll), float(msg.pitch), float(msg.yaw)),
        (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed)),
        rx_ns,
        autopilot_target=autopilot_target,
    )


VEHICLE_RESTART_BACKSTEP_MS = 3_000  # time_boot_ms going back by more than this = the autopilot restarted


def is_vehicle_restart(last_ms: int, new_ms: int, backstep_ms: int = VEHICLE_RESTART_BACKSTEP_MS) -> bool:
    """True when ``new_ms`` [ms, vehicle clock] is more than ``backstep_ms`` before ``last_ms``: the autopilot's
    uptime clock restarted (a reboot, or a new simulator), not a merely reordered packet."""
    return last_ms - new_ms > backstep_ms


def newest_attitude(kept: AttitudeSample, new: AttitudeSample, backstep_ms: int = VEHICLE_RESTART_BACKSTEP_MS) -> AttitudeSample:
    """Of two queued ATTITUDE samples, the newer by vehicle time (``time_boot_ms``), not by arrival.

    A sample older than ``kept`` by at most ``backstep_ms`` is a reordered packet and loses; one older by
    more is from a restarted autopilot and wins (the session then treats it as a new vehicle session).
    """
    if new.time_boot_ms >= kept.time_boot_ms or is_vehicle_restart(kept.time_boot_ms, new.time_boot_ms, backstep_ms):
        return new
    return kept


STATUSTEXT_CHUNK_LEN = 50  # characters in one STATUSTEXT's text field


class StatusTextAssembler:
    """Reassembles MAVLink 2 STATUSTEXT chunks (``id`` != 0, ``chunk_seq`` 0, 1, ...) into whole texts.

    ArduPilot splits a text longer than 50 characters into chunks with one ``id``; the last chunk is the
    one shorter than 50 characters. A text with ``id`` 0 is whole. A new ``id`` (or a chunk out of
    sequence) ends the text in progress, so a lost last chunk never swallows later texts.
    ``add`` returns every text completed by this message, as (severity, text).
    """

    def __init__(self) -> None:
        self._id = 0
        self._severity = 0
        self._parts: list[str] = []

    def _flush(self) -> list[tuple[int, str]]:
        done = [(self._severity, "".join(self._parts))] if self._parts else []
        self._id, self._parts = 0, []
        return done

    def add(self, severity: int, text: str, text_id: int = 0, chunk_seq: int = 0) -> list[tuple[int, str]]:
        text = text.split("\0", 1)[0]
        if not text_id:
            return self._flush() + [(int(severity), text)]
        done: list[tuple[int, str]] = []
        if text_id != self._id or chunk_seq != len(self._parts):
            done = self._flush()
            if chunk_seq != 0:  # the start of this text was lost: keep what arrived
                self._parts = ["…"]
        self._id, self._severity = text_id, int(severity)
        self._parts.append(text)
        if len(text) < STATUSTEXT_CHUNK_LEN:
            done += self._flush()
        return done


@dataclass(frozen=True, slots=True)
class HeartbeatInfo:
    """The autopilot's HEARTBEAT, decoded."""

    system: int
    component: int
    autopilot_id: int  # HEARTBEAT.autopilot (MAV_AUTOPILOT): which adapter speaks to it (mavastsm.bridge.autopilots)
    mav_type: int
    base_mode: int
    custom_mode: int
    system_status: int
    mode: str
    rx_s: float

    @property
    def booting(self) -> bool:
        """system_status MAV_STATE_BOOT: ArduCopter (and our sim) until it is ready, after every boot."""
        return self.system_status == MAV_STATE_BOOT

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)


def heartbeat_info(msg, mode: str, rx_s: float) -> HeartbeatInfo:
    """HEARTBEAT -> HeartbeatInfo; ``mode`` is its mode by name (the link's pymavlink decodes it), ``rx_s`` [s, unix]
    when it arrived."""
    return HeartbeatInfo(msg.get_srcSystem(), msg.get_srcComponent(), int(msg.autopilot), int(msg.type),
                         int(msg.base_mode), int(msg.custom_mode), int(msg.system_status), mode, rx_s)


def is_vehicle_heartbeat(msg) -> bool:
    """An autopilot's heartbeat (not a GCS, companion, gimbal or ADS-B)."""
    return int(msg.autopilot) != MAV_AUTOPILOT_INVALID and int(msg.type) not in NON_VEHICLE_TYPES


def decode_flight_sw_version(flight_sw_version: int) -> tuple[int, int, int]:
    """AUTOPILOT_VERSION.flight_sw_version = major<<24 | minor<<16 | patch<<8 | type -> (major, minor, patch)."""
    v = int(flight_sw_version)
    return (v >> 24) & 0xFF, (v >> 16) & 0xFF, (v >> 8) & 0xFF
