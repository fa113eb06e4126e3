"""The MAVLink face of the simulated Solo: ArduCopter 4.2+ wire behaviour on top of ``SimulatedCopter``.

This is the only module in ``sim/`` that imports pymavlink. It turns datagrams into calls on the copter
(modes, arming, SET_ATTITUDE_TARGET, parameters) and the copter's state into telemetry, following
docs/design-decisions.md, MAV-1 to MAV-7 and the checklist MAV-12:

* identity sysid 1 / compid 1 (``SYSID_THISMAV``), HEARTBEAT at 1 Hz of simulated time with
  type/autopilot/base_mode/custom_mode/system_status as ArduCopter fills them, plus an extra one on every
  mode change and one to each newly heard peer;
* SET_MODE (ACK command 11) and MAV_CMD_DO_SET_MODE (ACK 176), by COMMAND_LONG and COMMAND_INT;
* MAV_CMD_COMPONENT_ARM_DISARM (400) with the force values 2989 (arm) and 21196 (disarm);
  MAV_CMD_RUN_PREARM_CHECKS (401);
* streams off by default (except HEARTBEAT, or what the ``SR0_*`` parameters pre-seed), REQUEST_DATA_STREAM
  groups, MAV_CMD_SET_MESSAGE_INTERVAL (0 = default, -1 = stop, FAILED + STATUSTEXT for unknown ids,
  interval never shorter than 1 / (0.8 * SCHED_LOOP_RATE)), GET_MESSAGE_INTERVAL, REQUEST_MESSAGE;
  the two request paths share one interval per message, so the last writer wins (as on ArduCopter);
* TIMESYNC replies (and a TIMESYNC request of our own every 10 s, as ArduPilot), AUTOPILOT_VERSION (the profile's
  ``firmware_version``; no FTP capability) via 520 (p1 = 1), 183 and REQUEST_MESSAGE;
* genuine ArduCopter's other wire habits as the copter's ``ArduCopterProfile`` says (sim/arducopter_profile.py,
  docs/sim.md "Sim profiles" and "Wire parity"): the >= 4.6
  DENIED message interval, loop-tick stream timing, PARAM_VALUE index 65535 and read pacing, statistics announced by
  PARAM_VALUE, a pre-arm delay with ArduCopter's reasons; HOME_POSITION and GPS_GLOBAL_ORIGIN on arming;
  PROTOCOL_VERSION (version 200, min 100, max 200) via 519 and REQUEST_MESSAGE 300, encoded by
  :class:`ProtocolVersionMessage` because PyPI pymavlink's dialects lack it;
* the PARAM protocol over ``copter.params``; MISSION_REQUEST_LIST answered with an empty MISSION_COUNT;
* MAVLink 2 signing (key from a file or SETUP_SIGNING): unsigned or badly signed frames are dropped and counted.

Every class of bad input is counted in :attr:`MavlinkVehicle.counters` (names in ``BAD_INPUT_COUNTERS``)
and logged at DEBUG on the ``mavastsm_sim`` logger; nothing inbound can raise out of :meth:`handle_datagram`.

Units: SI inside (rad, rad/s, m, m/s); MAVLink units at the edge (cdeg, mm, cm/s, mV, us) converted here.
Frames: NED world, FRD body, quaternion [w, x, y, z] rotating NED to FRD, as in ``mavastsm.frames``.
Time: ``time_boot_ms`` and every timestamp come from the simulated time passed in by the caller.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections import Counter, deque
from pathlib import Path
from typing import Any, Callable

from mavastsm import signing
from mavastsm.mavlink_datagram import discard_partial_frame, parse_datagram
from mavastsm.errors import ConfigError
# The MAVLink 2 dialect module itself: every MAVLink object here is built from it, so the vehicle speaks MAVLink 2
# from its first byte without touching pymavlink's process-wide MAVLINK20 switch (it opens no mavutil connection).
from pymavlink.dialects.v20 import ardupilotmega as mavlink

log = logging.getLogger("mavastsm_sim")

# --- identity and version (what ArduCopter on a quad X reports; 4.5.7 unless told otherwise) ----------------
AUTOPILOT_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1  # 1
FIRMWARE_GIT_HASH = b"6d617661"  # 8 ASCII chars, like ArduPilot's flight_custom_version
CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)  # deliberately no FTP (not implemented)

FORCE_ARM_MAGIC = 2989
FORCE_DISARM_MAGIC = 21196

# MAV_TYPE from FRAME_CLASS (AP_Motors get_frame_mav_type)
MAV_TYPE_BY_FRAME_CLASS = {1: mavlink.MAV_TYPE_QUADROTOR, 2: mavlink.MAV_TYPE_HEXAROTOR,
                           3: mavlink.MAV_TYPE_OCTOROTOR, 6: mavlink.MAV_TYPE_HELICOPTER,
                           7: mavlink.MAV_TYPE_TRICOPTER}
# Copter modes that set MAV_MODE_FLAG_GUIDED_ENABLED (the classic list; GUIDED_NOGPS has no position control)
GUIDED_FLAG_MODES = frozenset({3, 4, 5, 6, 7, 16, 17, 19, 21, 23})
BASE_MODE_ALWAYS = (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
                    | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)  # 81

# --- streams (ArduCopter GCS_MAVLink_Copter.cpp stream tables, the subset we emit) ----------------------
STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (mavlink.MAVLINK_MSG_ID_SYS_STATUS, mavlink.MAVLINK_MSG_ID_GPS_RAW_INT),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: (mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,),
    mavlink.MAV_DATA_STREAM_POSITION: (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                                       mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    mavlink.MAV_DATA_STREAM_EXTRA1: (mavlink.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA2: (mavlink.MAVLINK_MSG_ID_VFR_HUD,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS),
}
STREAM_RATE_PARAMS = {  # stream id -> the SR0_* parameter that seeds its default rate [Hz]
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: "SR0_EXT_STAT", mavlink.MAV_DATA_STREAM_RC_CHANNELS: "SR0_RC_CHAN",
    mavlink.MAV_DATA_STREAM_POSITION: "SR0_POSITION", mavlink.MAV_DATA_STREAM_EXTRA1: "SR0_EXTRA1",
    mavlink.MAV_DATA_STREAM_EXTRA2: "SR0_EXTRA2", mavlink.MAV_DATA_STREAM_EXTRA3: "SR0_EXTRA3",
}
GROUP_OF_MESSAGE = {mid: group for group, mids in STREAM_GROUPS.items() for mid in mids}
HEARTBEAT_INTERVAL_US = 1_000_000
MAX_INTERVAL_US = 60_000_000   # ArduPilot caps requested intervals at 60 s
MIN_REQUEST_INTERVAL_US = 1_000  # < 1000 us means 1 ms
LOOP_RATE_FRACTION = 0.8       # streams capped at 80 % of SCHED_LOOP_RATE
PARAMS_PER_SERVICE = 40        # PARAM_VALUE trickle per emit call
MAVLINK2_MIN_FRAME_BYTES = mavlink.HEADER_LEN_V2 + 2  # header + CRC of an empty, unsigned MAVLink 2 frame
TIMESYNC_REQUEST_INTERVAL_US = 10_000_000  # our own TIMESYNC request (tc1 = 0) every 10 s, as ArduPilot
PARAM_INDEX_UNKNOWN = 65535  # PARAM_VALUE.param_index of ArduPilot's replies to a read by name and of PARAM_SET echoes
STATS_FLUSH_INTERVAL_US = 30_000_000  # ArduPilot saves STAT_RUNTIME / STAT_FLTTIME (and announces them) every 30 s
PREARM_REPORT_INTERVAL_US = 30_000_000  # ArduPilot repeats failing pre-arm checks as "PreArm:" texts every 30 s
# Start-up of genuine ArduCopter 4.7 SITL, measured (docs/sim.md, "Wire parity"), as fractions of the pre-arm delay
# (25 s nominal there): "ArduPilot Ready" 2.45 s, EKF3 initialised 4.46 s, tilt and yaw aligned 5.8-5.9 s, EKF origin
# and home set 20.0 s; the gyros agree and the EKF uses GPS by the end of the delay.
BOOTED_FRACTION = 0.1
ORIGIN_SET_FRACTION = 0.8
STARTUP_TEXTS = (
    (BOOTED_FRACTION, ("ArduPilot Ready", "AHRS: DCM active")),
    (0.18, ("EKF3 IMU0 initialised", "EKF3 IMU1 initialised", "AHRS: EKF3 active")),
    (0.23, ("EKF3 IMU0 tilt alignment complete", "EKF3 IMU1 tilt alignment complete",
            "EKF3 IMU0 MAG0 initial yaw alignment complete", "EKF3 IMU1 MAG0 initial yaw alignment complete")),
    (ORIGIN_SET_FRACTION, ("EKF3 IMU0 origin set", "Field Elevation Set: {home_alt_m:.0f}m", "EKF3 IMU1 origin set")),
    (1.0, ("EKF3 IMU0 is using GPS", "EKF3 IMU1 is using GPS")),
)
POSITION_MODES = frozenset({3, 4, 5, 6, 7})  # AUTO, GUIDED, LOITER, RTL, CIRCLE: Mode::requires_GPS() (emulated set)

BAD_INPUT_COUNTERS = (
    "garbage_bytes",          # bytes before a MAVLink start marker (events)
    "crc_errors",             # frames with a wrong checksum
    "malformed_frames",       # bad length / incompat flags / undecodable payload
    "truncated_frames",       # a datagram ending inside a frame
    "unknown_message_ids",    # well-formed frames of ids this dialect does not know
    "wrong_target",           # addressed to another system or component
    "bad_field_values",       # NaN / inf / out-of-range fields (message dropped)
    "unsigned_rejected",      # unsigned frame while signing is required
    "bad_signature",          # signed with the wrong key (or a forged signature)
    "replayed",               # signed with our key, but a timestamp not newer than its stream's (replay)
    "unsupported_commands",   # COMMAND_LONG/INT ids we do not implement (ACK UNSUPPORTED)
    "unknown_params",         # PARAM_* for a name or index that does not exist
    "internal_errors",        # a handler raised (bug); the message is dropped, the vehicle keeps flying
)

# MAVLink FTP (refused: see MavlinkVehicle._on_file_transfer_protocol)
FTP_OP_TERMINATE_SESSION, FTP_OP_RESET_SESSIONS, FTP_OP_ACK, FTP_OP_NAK = 1, 2, 128, 129
FTP_ERR_FILE_NOT_FOUND = 10

EARTH_RADIUS_M = 6378137.0
DEFAULT_HOME = (-35.363261, 149.165230, 584.0)  # ArduPilot SITL default home (CMAC) [deg, deg, m AMSL]


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class ProtocolVersionMessage(mavlink.MAVLink_message):
    """PROTOCOL_VERSION (id 300, common.xml), which PyPI pymavlink's generated dialects lack.

    Written the way pymavlink's generator writes messages so ``MAVLink.send`` can pack (and sign) it.
    Wire order: version, min_version, max_version (uint16), spec_version_hash, library_version_hash
    (uint8[8]); CRC extra 217, computed from that field list like mavgen does.
    """

    id = 300
    msgname = "PROTOCOL_VERSION"
    fieldnames = ["version", "min_version", "max_version", "spec_version_hash", "library_version_hash"]
    ordered_fieldnames = fieldnames
    fieldtypes = ["uint16_t", "uint16_t", "uint16_t", "uint8_t", "uint8_t"]
    orders = [0, 1, 2, 3, 4]
    lengths = [1, 1, 1, 8, 8]
    array_lengths = [0, 0, 0, 8, 8]
    crc_extra = 217
    unpacker = struct.Struct("<HHH8s8s")
    instance_field = None
    instance_offset = -1

    def __init__(self, version: int, min_version: int, max_version: int, spec_version_hash: bytes,
                 library_version_hash: bytes) -> None:
        mavlink.MAVLink_message.__init__(self, self.id, self.msgname)
        self._fieldnames = self.fieldnames
        self._instance_field = None
        self._instance_offset = -1
        self.version, self.min_version, self.max_version = version, min_version, max_version
        self.spec_version_hash, self.library_version_hash = spec_version_hash, library_version_hash

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        payload = self.unpacker.pack(self.version, self.min_version, self.max_version, self.spec_version_hash,
                                     self.library_version_hash)
        return self._pack(mav, self.crc_extra, payload, force_mavlink1=False)  # id > 255: MAVLink 2 only


class _DatagramSink:
    """File-like adapter so ``MAVLink.send`` writes each packed frame as one datagram."""

    def __init__(self, send_datagram: Callable[[bytes], None]) -> None:
        self.write = send_datagram


class MavlinkVehicle:
    """ArduCopter-like MAVLink endpoint around a ``SimulatedCopter``.

    Parameters
    ----------
    copter : SimulatedCopter
        The plant and autopilot emulation (``sim/copter.py`` contract).
    send_datagram : callable(bytes)
        Sends one datagram to every peer.
    signing_key : bytes or None
        32-byte MAVLink 2 signing key; when set, unsigned or wrongly signed input is rejected.
    signing_state : path or None
        File that keeps our signing timestamp across runs (saved every 30 s and at the end; the next run starts
        60 s past it), as ArduPilot keeps it in its storage. None: the timestamp starts at the clock.
    home : (lat_deg, lon_deg, alt_m_amsl)
        Home / EKF origin used for GPS-like messages.
    unix_time_at_boot_s : float or None
        Wall-clock Unix time that simulated time 0 corresponds to (SYSTEM_TIME, GPS time);
        None uses the host time at construction.

    Notes
    -----
    Not thread-safe: call everything from one thread (``VehicleServer`` does, under its lock).
    """

    def __init__(self, copter: Any, send_datagram: Callable[[bytes], None], *, signing_key: bytes | None = None,
                 home: tuple[float, float, float] = DEFAULT_HOME, unix_time_at_boot_s: float | None = None,
                 signing_state: str | Path | None = None) -> None:
        self.copter = copter
        self.profile = copter.profile  # the habits of the ArduCopter emulated, one record for copter and wire
        self.firmware = self.profile.firmware
        # ArduCopter's whole-millisecond intervals, sent from loop ticks (the profile's stream_timing)
        auto_loop_ticks = self.profile.stream_timing == "auto" and self.firmware.denies_fast_message_intervals
        self.loop_tick_streams = self.profile.stream_timing == "loop-ticks" or auto_loop_ticks
        self.whole_ms_intervals = self.loop_tick_streams or self.firmware.denies_fast_message_intervals
        self.counters: Counter[str] = Counter()
        self.sysid = int(self._param("SYSID_THISMAV", 1.0))
        self.compid = AUTOPILOT_COMPONENT_ID
        self.mav = mavlink.MAVLink(_DatagramSink(send_datagram), srcSystem=self.sysid, srcComponent=self.compid)
        self.mav.robust_parsing = True
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = (float(v) for v in home)
        self._unix_at_boot_s = time.time() if unix_time_at_boot_s is None else float(unix_time_at_boot_s)
        self.signing_state = None if signing_state is None else Path(signing_state)
        self._signing_saved_at = -math.inf
        self.attitude_targets_received = 0
        self._held_targets: deque[tuple[int, int, list, tuple, float]] = deque()  # the profile's command_latency_s
        self._command_latency_us = int(round(self.profile.command_latency_s * 1e6))
        self._now_us = 0
        self._next_timesync_us = TIMESYNC_REQUEST_INTERVAL_US
        self._requested_us: dict[int, int | None] = {}   # msg id -> requested interval [us]; None = stopped
        self._next_due_us: dict[int, int] = {}
        self._last_sent_ms: dict[int, int] = {}  # loop-tick streams: ArduPilot's per-message last_sent_ms [ms]
        # parameter reads answered on a schedule (the profile's param_read_interval_s): (index, reported index)
        self._param_read_replies: deque[tuple[int, int]] = deque()
        self._param_read_last_us = -(10 ** 12)  # [us] slot of the last reply (long ago: the first goes at once)
        self._next_stats_flush_us = STATS_FLUSH_INTERVAL_US
        self._flight_time_us = 0
        self._flight_time_counted_to_us = 0
        self._next_prearm_report_us = PREARM_REPORT_INTERVAL_US
        self._startup_texts_sent = 0
        self._was_armed = bool(copter.armed)
        self._last_mode = int(copter.mode_number)
        self._param_queue: deque[int] = deque()
        self._statustext_id = 0
        self._pending_texts: list[tuple[int, str]] = []  # our own STATUSTEXTs, sent after the ACK like ArduPilot
        # stream-rate cap cache: the SCHED_LOOP_RATE value it was computed from, and the cap [us]
        self._cap_loop_rate_hz: float | None = None
        self._cap_interval_us = 0
        # plain-float read-out for ATTITUDE when the plant offers one (SimulatedCopter does), else NumPy
        self._attitude_sample: Callable[[], tuple] | None = getattr(copter, "attitude_sample", None)
        self._encoders: dict[int, Callable[[], Any]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: self._system_time,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._gps_raw_int,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._attitude_quaternion,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._local_position_ned,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._global_position_int,
            mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: self._servo_output_raw,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self._vfr_hud,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET: self._attitude_target,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self._battery_status,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
            mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: self._gps_global_origin,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._extended_sys_state,
            ProtocolVersionMessage.id: self._protocol_version,
        }
        self._handlers: dict[int, Callable[[Any], None]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: lambda m: None,
            mavlink.MAVLINK_MSG_ID_SET_MODE: self._on_set_mode,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self._on_param_request_read,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self._on_param_request_list,
            mavlink.MAVLINK_MSG_ID_PARAM_SET: self._on_param_set,
            mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: self._on_mission_request_list,
            mavlink.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: self._on_request_data_stream,
            mavlink.MAVLINK_MSG_ID_COMMAND_LONG: self._on_command,
            mavlink.MAVLINK_MSG_ID_COMMAND_INT: self._on_command,
            mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET: self._on_set_attitude_target,
            mavlink.MAVLINK_MSG_ID_TIMESYNC: self._on_timesync,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION_REQUEST: self._on_autopilot_version_request,
            mavlink.MAVLINK_MSG_ID_SETUP_SIGNING: self._on_setup_signing,
            mavlink.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self._on_file_transfer_protocol,
        }
        self._requested_us[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = HEARTBEAT_INTERVAL_US
        self._next_due_us[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = 0
        self._last_sent_ms[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = -HEARTBEAT_INTERVAL_US // 1000
        for mid in GROUP_OF_MESSAGE:
            self._set_interval(mid, self._default_interval_us(mid))
        if signing_key is not None:
            self.enable_signing(signing_key)

    # ------------------------------------------------------------------ public API
    @property
    def signing_enabled(self) -> bool:
        """True when inbound frames must carry a valid MAVLink 2 signature."""
        return self.mav.signing.secret_key is not None

    def enable_signing(self, key: bytes, initial_timestamp: int | None = None) -> None:
        """Require and produce MAVLink 2 signatures with ``key`` [32 bytes].

        Our timestamp starts as ArduPilot's does (GCS_Signing.cpp, load_signing_key): 60 s past the given
        ``initial_timestamp`` (SETUP_SIGNING) or past the one saved in ``signing_state`` by the last run, and never
        behind the clock. The 60 s lead refuses, as a stream more than 60 s old, every frame signed before the
        last save: a replay across a restart. Without a saved timestamp only the clock bounds it (docs/security.md)."""
        if len(key) != 32:
            raise ValueError(f"signing key must be 32 bytes, got {len(key)}")
        s = self.mav.signing
        s.secret_key = bytes(key)
        s.sign_outgoing = True
        s.allow_unsigned_callback = None  # like ArduPilot on a network link (not its channel 0): nothing unsigned gets in
        s.link_id = 0
        base = max(initial_timestamp or 0, self._saved_signing_timestamp() or 0)
        s.timestamp = max(s.timestamp, base + signing.RESTART_TIMESTAMP_LEAD if base else 0, signing.timestamp_now())
        signing.harden(self.mav)
        self.save_signing_timestamp(force=True)

    def _saved_signing_timestamp(self) -> int | None:
        path = self.signing_state
        if path is None or not path.exists():
            return None
        text = path.read_text(encoding="ascii", errors="replace").strip()
        if not text.isdigit():
            raise ConfigError(f"signing state {path}: {text[:40]!r} is not a signing timestamp (decimal, 10 us since 2015)")
        return int(text)

    def save_signing_timestamp(self, force: bool = False) -> None:
        """Write our signing timestamp to ``signing_state`` every TIMESTAMP_SAVE_PERIOD_S of wall time (now when
        ``force``), as ArduPilot does; nothing without signing or a state file. Never raises (counted)."""
        path = self.signing_state
        if path is None or self.mav.signing.secret_key is None:
            return
        now = time.monotonic()
        if not force and now - self._signing_saved_at < signing.TIMESTAMP_SAVE_PERIOD_S:
            return
        self._signing_saved_at = now
        try:
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(f"{self.mav.signing.timestamp}\n", encoding="ascii")
            tmp.replace(path)
        except OSError as exc:
            self.counters["signing_state_errors"] += 1
            log.warning("cannot save the signing timestamp to %s: %s", path, exc)

    def disable_signing(self) -> None:
        """Stop signing and accept unsigned frames again."""
        s = self.mav.signing
        s.secret_key = None
        s.sign_outgoing = False
        s.allow_unsigned_callback = None

    def bad_input_total(self) -> int:
        """Sum of all bad-input counters [count]."""
        return sum(self.counters[name] for name in BAD_INPUT_COUNTERS)

    def attitude_streaming(self) -> bool:
        """True while ATTITUDE is being streamed (the lockstep gate is active)."""
        return self._effective_interval_us(mavlink.MAVLINK_MSG_ID_ATTITUDE) is not None

    def effective_interval_us(self, msg_id: int) -> int | None:
        """Interval at which ``msg_id`` is emitted now [us], after the loop-rate cap; None when off."""
        return self._effective_interval_us(msg_id)

    def handle_datagram(self, data: bytes, now_us: int, on_first_valid: Callable[[], None] | None = None) -> int:
        """Parse one UDP datagram and act on every frame in it; never raises. Returns how many frames were valid
        MAVLink (known id, CRC right, and signed with our key when signing is on). ``on_first_valid`` runs
        before the first valid frame is acted on (the server admits the sender as a peer there, so that the
        answer to that frame reaches it); a datagram of junk never calls it.

        Parameters
        ----------
        data : bytes
            Datagram payload (zero or more MAVLink 1/2 frames).
        now_us : int
            Simulated time since boot [us] at which the datagram is processed.
        """
        self._now_us = now_us
        mav = self.mav
        msgs = []
        try:
            if self._is_single_v2_frame(data):
                msgs.append(self._decode_single_frame(data))
            else:
                msgs, left = parse_datagram(mav, data)
                if left > 0:
                    self._bad("truncated_frames", f"{left} bytes left in a datagram of {len(data)}")
        except Exception as exc:  # pymavlink should not raise with robust_parsing; never let it kill us
            msgs = []
            self._bad("malformed_frames", f"parser raised {exc!r}")
        left = mav.buf_len()  # after a parser exception (parse_datagram drops a cut frame itself)
        if left > 0:
            self._bad("truncated_frames", f"{left} bytes left in a datagram of {len(data)}")
            discard_partial_frame(mav)
        valid = 0
        for msg in msgs:
            try:
                if not valid and on_first_valid is not None and self._is_valid(msg):
                    on_first_valid()
                valid += self._dispatch(msg)
            except Exception as exc:  # a handler bug must not stop the vehicle
                self._bad("internal_errors", f"{msg.get_type()} handler raised {exc!r}")
                log.exception("handler for %s failed", msg.get_type())
        self._flush_side_effects()
        return valid

    def _is_single_v2_frame(self, data: bytes) -> bool:
        """True when ``data`` is exactly one MAVLink 2 frame (length from its header, incompat flags 0 or
        signed) and the parser holds no partial frame: the common case of one message per datagram."""
        n = len(data)
        return (n >= MAVLINK2_MIN_FRAME_BYTES and data[0] == mavlink.PROTOCOL_MARKER_V2 and self.mav.buf_len() == 0
                and data[2] in (0, mavlink.MAVLINK_IFLAG_SIGNED)
                and n == data[1] + MAVLINK2_MIN_FRAME_BYTES + (mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if data[2] else 0))

    def _decode_single_frame(self, data: bytes) -> Any:
        """What ``MAVLink.parse_char`` returns for a datagram that ``_is_single_v2_frame`` accepted, with the
        same bookkeeping, minus its byte-buffer handling: the frame goes straight to pymavlink's
        ``MAVLink.decode`` (header, CRC, signature and payload checks all stay pymavlink's). A frame it
        refuses becomes ``MAVLink_bad_data`` with pymavlink's reason, as the robust parser does."""
        mav = self.mav
        mav.total_bytes_received += len(data)
        frame = bytearray(data)
        try:
            msg = mav.decode(frame)
        except mavlink.MAVError as reason:
            msg = mavlink.MAVLink_bad_data(frame, reason.message)
            mav.total_receive_errors += 1
        mav.have_prefix_error = False
        mav.expected_length = mavlink.HEADER_LEN_V2 + 2
        mav.total_packets_received += 1
        if mav.callback is not None and mav.callback_args is not None and mav.callback_kwargs is not None:
            mav.callback(msg, *mav.callback_args, **mav.callback_kwargs)
        return msg

    def greet_new_peer(self) -> None:
        """Send a HEARTBEAT at once so a peer that just appeared learns our identity without waiting."""
        self._send_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)

    def next_due_us(self, now_us: int) -> int:
        """Earliest simulated time [us] > ``now_us`` at which something is due to be sent."""
        if self._param_queue or self._pending_texts or self.copter.statustext_queue:
            return now_us + 1
        # every entry in _next_due_us is a live stream (_set_interval drops stopped ones)
        due_us = min(self._next_timesync_us, *self._next_due_us.values())
        if self._param_read_replies:
            due_us = min(due_us, self._param_read_last_us + self._param_read_interval_us())
        if self._held_targets:
            due_us = min(due_us, self._held_targets[0][0])
        return max(due_us, now_us + 1)

    def emit_due(self, now_us: int) -> bool:
        """Send everything due at simulated time ``now_us`` [us]; True if an ATTITUDE went out."""
        self._now_us = now_us
        self.save_signing_timestamp()
        while self._held_targets and self._held_targets[0][0] <= now_us:
            self._apply_attitude_target(*self._held_targets.popleft()[1:])
        attitude_sent = False
        self._run_startup(now_us)
        self._flush_side_effects()
        if self.loop_tick_streams:
            attitude_sent = self._emit_on_loop_ticks(now_us)
        else:
            due_now = [(mid, due) for mid, due in self._next_due_us.items() if due <= now_us]
            for mid, due in due_now:
                interval = self._effective_interval_us(mid)
                if interval is None:
                    continue
                self._send_now(mid)
                if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
                    attitude_sent = True
                nxt = due + interval
                self._next_due_us[mid] = nxt if nxt > now_us else now_us + interval
        if self._param_queue:
            self._send_param_batch()
        if self._param_read_replies:
            self._send_due_param_read_reply(now_us)
        self._count_flight_time(now_us)
        if now_us >= self._next_stats_flush_us:
            self._next_stats_flush_us += STATS_FLUSH_INTERVAL_US
            self._flush_statistics()
        if now_us >= self._next_timesync_us:  # ArduPilot probes link latency with its own request every 10 s
            self._next_timesync_us += TIMESYNC_REQUEST_INTERVAL_US
            self.mav.timesync_send(0, now_us * 1000 + self.sysid)
        return attitude_sent

    def _emit_on_loop_ticks(self, now_us: int) -> bool:
        """ArduCopter's stream scheduler (GCS_MAVLINK::update_send) for every loop tick up to ``now_us``: on a tick,
        a message is due when ``millis - last_sent_ms >= interval_ms``; then ``last_sent_ms += interval_ms``, reset to
        ``millis`` when more than one interval behind. A stream faster than the tick grid therefore comes in runs
        of ticks with a skipped one (333 Hz from 400 Hz: 2, 3, 2, 3, 5 ms); time_boot_ms is the tick's millis.
        True if an ATTITUDE went out."""
        attitude_sent = False
        physics_now_us = now_us
        period_us = self._loop_period_us()
        while self._next_due_us:
            tick_us = min(self._next_due_us.values())
            if tick_us > physics_now_us:
                break
            self._now_us = tick_us
            tick_ms = tick_us // 1000
            for mid in [m for m, due in self._next_due_us.items() if due == tick_us]:
                interval = self._effective_interval_us(mid)
                if interval is None:
                    self._next_due_us.pop(mid, None)
                    continue
                interval_ms = interval // 1000
                last_ms = self._last_sent_ms.get(mid, tick_ms - interval_ms)
                while tick_ms - last_ms >= interval_ms:  # at most twice: ArduPilot's "pairs" when exactly one behind
                    self._send_now(mid)
                    attitude_sent = attitude_sent or mid == mavlink.MAVLINK_MSG_ID_ATTITUDE
                    last_ms += interval_ms
                    if tick_ms - last_ms > interval_ms:
                        last_ms = tick_ms
                self._last_sent_ms[mid] = last_ms
                self._next_due_us[mid] = self._first_tick_at_ms(last_ms + interval_ms, period_us)
        self._now_us = physics_now_us
        return attitude_sent

    @staticmethod
    def _first_tick_at_ms(ms: int, period_us: int) -> int:
        """[us] the first loop tick whose millis() reads at least ``ms``."""
        return -(-ms * 1000 // period_us) * period_us

    def _loop_period_us(self) -> int:
        """[us] ArduCopter's main-loop period, 1/SCHED_LOOP_RATE as whole microseconds (2500 at 400 Hz)."""
        loop_hz = self._param("SCHED_LOOP_RATE", 400.0)
        if not (math.isfinite(loop_hz) and loop_hz > 0):
            loop_hz = 400.0
        return max(int(1e6 // loop_hz), 1)

    # --- ArduCopter's start-up (the profile's prearm_delay_s)
    def _startup_fraction(self) -> float:
        delay_s = self.profile.prearm_delay_s
        return math.inf if delay_s <= 0 else self._now_us * 1e-6 / delay_s


    def startup_failures(self) -> list[str]:
        """Pre-arm reasons ArduCopter gives while it starts up (without the "PreArm: " / "Arm: " prefix); empty once
        ``prearm_delay_s`` has passed, with ARMING_CHECK 0, or without a pre-arm delay. As measured on 4.7 SITL:
        the gyros disagree and the AHRS waits for home until the EKF origin is set, then a mode that needs a position
        waits for the EKF to use GPS."""
        fraction = self._startup_fraction()
        if fraction >= 1.0 or self._param("ARMING_CHECK", 1.0) == 0.0:
            return []
        reasons = ["Gyros inconsistent"]
        if fraction < ORIGIN_SET_FRACTION:
            reasons.append("AHRS: waiting for home")
        elif int(self.copter.mode_number) in POSITION_MODES:
            reasons.append("Need Position Estimate")
        return reasons

    def _run_startup(self, now_us: int) -> None:
        """Start-up texts and events due by ``now_us`` (only with a pre-arm delay), and the 30 s "PreArm:" reminder."""
        if self.profile.prearm_delay_s <= 0:
            return
        fraction = self._startup_fraction()
        while self._startup_texts_sent < len(STARTUP_TEXTS) and fraction >= STARTUP_TEXTS[self._startup_texts_sent][0]:
            at_fraction, texts = STARTUP_TEXTS[self._startup_texts_sent]
            self._startup_texts_sent += 1
            if at_fraction >= ORIGIN_SET_FRACTION and not self.profile.position_estimate:
                continue  # no GPS: no origin, no home, the EKF never uses GPS
            for text in texts:
                self._pending_texts.append((mavlink.MAV_SEVERITY_INFO, text.format(home_alt_m=self.home_alt_m)))
            if at_fraction == ORIGIN_SET_FRACTION:
                self._flush_side_effects()
                self._send_home_and_origin()
        if fraction < 1.0 and now_us >= self._next_prearm_report_us:
            self._next_prearm_report_us += PREARM_REPORT_INTERVAL_US
            if not self.copter.armed:
                for reason in self.startup_failures():
                    self._pending_texts.append((mavlink.MAV_SEVERITY_CRITICAL, f"PreArm: {reason}"))

    def _send_home_and_origin(self) -> None:
        """HOME_POSITION and GPS_GLOBAL_ORIGIN, as ArduCopter sends them when the EKF origin is set and on arming."""
        if self.profile.position_estimate:
            self._send_now(mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)
            self._send_now(mavlink.MAVLINK_MSG_ID_HOME_POSITION)

    # --- parameters announced and answered on ArduCopter's schedule
    def _param_read_interval_us(self) -> int:
        return int(round(self.profile.param_read_interval_s * 1e6))

    def _send_due_param_read_reply(self, now_us: int) -> None:
        """One queued PARAM_REQUEST_READ reply per interval, on ArduPilot's deferred-message clock."""
        interval_us = self._param_read_interval_us()
        if now_us - self._param_read_last_us < interval_us:
            return
        index, reported_index = self._param_read_replies.popleft()
        self._send_param_value(index, reported_index)
        self._param_read_last_us += interval_us
        if now_us - self._param_read_last_us > interval_us:
            self._param_read_last_us = now_us

    def _count_flight_time(self, now_us: int) -> None:
        if self.copter.armed and not getattr(self.copter, "landed", True):
            self._flight_time_us += now_us - self._flight_time_counted_to_us
        self._flight_time_counted_to_us = now_us

    def _flush_statistics(self) -> None:
        """ArduPilot's statistics save every 30 s: STAT_RUNTIME [s] always changes, STAT_FLTTIME [s] once flown; with
        ``unsolicited_param_values`` each change is announced by PARAM_VALUE (index 65535) like any saved parameter."""
        values = {"STAT_RUNTIME": self._now_us // 1_000_000, "STAT_FLTTIME": self._flight_time_us // 1_000_000}
        for name, value in values.items():
            entry = self.copter.params.entry(name) if hasattr(self.copter.params, "entry") else None
            if entry is None or entry.value == float(value):
                continue
            entry.value = float(value)  # a statistic, not a setting: no change callbacks
            if self.profile.unsolicited_param_values:
                self._send_param_value(self.copter.params.index_of(name), PARAM_INDEX_UNKNOWN)
                self.counters["unsolicited_param_values"] += 1

    # ------------------------------------------------------------------ helpers
    def _param(self, name: str, default: float) -> float:
        try:
            value = self.copter.params.get(name)
        except (KeyError, AttributeError):
            return default
        return default if value is None else float(value)

    def _bad(self, counter: str, detail: str) -> None:
        self.counters[counter] += 1
        n = self.counters[counter]
        if log.isEnabledFor(logging.DEBUG) and (n <= 5 or n % 1000 == 0):
            log.debug("bad input #%d of class %s: %s", n, counter, detail)


    def _for_us(self, target_system: int, target_component: int | None = None) -> bool:
        ok = target_system in (0, self.sysid) and (target_component is None or target_component in (0, self.compid))
        if not ok:
            self._bad("wrong_target", f"for {target_system}/{target_component}, we are {self.sysid}/{self.compid}")
        return ok

    def _flush_side_effects(self) -> None:
        """Send queued STATUSTEXTs and the extra HEARTBEAT after a mode change."""
        queue = self.copter.statustext_queue
        while self._pending_texts:
            self.send_statustext(*self._pending_texts.pop(0))
        while queue:
            severity, text = queue.pop(0)
            self.send_statustext(int(severity), str(text))
        mode = int(self.copter.mode_number)
        if mode != self._last_mode:
            self._last_mode = mode
            self._send_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
        armed = bool(self.copter.armed)
        if armed != self._was_armed:
            self._was_armed = armed
            if armed:  # ArduCopter sets home where it arms and announces it with the EKF origin
                self._send_home_and_origin()

    def send_statustext(self, severity: int, text: str) -> None:
        """Send STATUSTEXT, chunked into 50-byte pieces with id/chunk_seq when longer (MAVLink 2)."""
        data = text.encode("ascii", errors="replace")
        if len(data) <= 50:
            self.mav.statustext_send(severity, data)
            return
        self._statustext_id = self._statustext_id % 65535 + 1
        for seq, start in enumerate(range(0, len(data), 50)):
            self.mav.statustext_send(severity, data[start:start + 50], id=self._statustext_id, chunk_seq=seq)

    # ------------------------------------------------------------------ stream intervals
    def _min_interval_us(self) -> int:
        """[us] the shortest interval a stream is capped to: 80 % of SCHED_LOOP_RATE; with whole-millisecond intervals
        ArduPilot's own rounding of it (cap_message_interval: 3 ms at 400 Hz, 2 ms at 500 Hz)."""
        loop_hz = self._param("SCHED_LOOP_RATE", 400.0)
        if loop_hz != self._cap_loop_rate_hz:  # recomputed only when the parameter changed (called per message)
            self._cap_loop_rate_hz = loop_hz
            hz = loop_hz if math.isfinite(loop_hz) and loop_hz > 0 else 400.0
            if self.whole_ms_intervals:
                self._cap_interval_us = max(int(self._loop_period_us() / (1000 * LOOP_RATE_FRACTION)), 1) * 1000
            else:
                self._cap_interval_us = int(math.ceil(1e6 / (LOOP_RATE_FRACTION * hz)))
        return self._cap_interval_us

    def _whole_ms(self, interval_us: int | None) -> int | None:
        """An interval as ArduPilot keeps it (whole milliseconds, at least 1) when the wire model says so [us]."""
        if interval_us is None or not self.whole_ms_intervals:
            return interval_us
        return max(interval_us // 1000, 1) * 1000

    def _effective_interval_us(self, msg_id: int) -> int | None:
        requested = self._requested_us.get(msg_id)
        if requested is None:
            return None
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return requested
        return max(requested, self._min_interval_us())

    def _default_interval_us(self, msg_id: int) -> int | None:
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return HEARTBEAT_INTERVAL_US
        group = GROUP_OF_MESSAGE.get(msg_id)
        if group is None:
            return None
        rate_hz = self._param(STREAM_RATE_PARAMS[group], 0.0)
        return self._whole_ms(int(1e6 / rate_hz)) if math.isfinite(rate_hz) and rate_hz > 0 else None

    def _set_interval(self, msg_id: int, interval_us: int | None) -> None:
        """Set the requested interval of one message [us] (None = off); keeps the phase if unchanged."""
        before = self._effective_interval_us(msg_id)
        self._requested_us[msg_id] = interval_us
        after = self._effective_interval_us(msg_id)
        if after is None:
            self._next_due_us.pop(msg_id, None)
        elif self.loop_tick_streams:
            if after != before or msg_id not in self._next_due_us:
                # ArduPilot files the message with last_sent_ms = now: the first copy one interval later
                self._last_sent_ms[msg_id] = self._now_us // 1000
                self._next_due_us[msg_id] = self._first_tick_at_ms(self._now_us // 1000 + after // 1000,
                                                                   self._loop_period_us())
        elif after != before or msg_id not in self._next_due_us:
            # first copy on the interval grid counted from boot, so the sampling phase (and a lockstep
            # run) does not depend on the wall-clock moment the request arrived. Strictly after now:
            # what is due now was emitted before inbound data is handled at this instant, so a copy
            # due "now" would go out one physics tick late, off the grid, and shift the whole run
            self._next_due_us[msg_id] = (self._now_us // after + 1) * after

    # ------------------------------------------------------------------ inbound dispatch
    @staticmethod
    def _is_valid(msg: Any) -> bool:
        return msg.get_msgId() not in (mavlink.MAVLINK_MSG_ID_BAD_DATA, mavlink.MAVLINK_MSG_ID_UNKNOWN)

    def _dispatch(self, msg: Any) -> int:
        """Act on one parsed frame; 1 when it was a valid message (handled or not), else 0 (counted as bad)."""
        mid = msg.get_msgId()
        if mid == mavlink.MAVLINK_MSG_ID_BAD_DATA:
            self._classify_bad_data(msg)
            return 0
        if mid == mavlink.MAVLINK_MSG_ID_UNKNOWN:
            self._bad("unknown_message_ids", f"msg id {getattr(msg, 'msgid', '?')}")
            return 0
        self.counters["messages_in"] += 1
        handler = self._handlers.get(mid)
        if handler is not None:
            handler(msg)
        return 1

    def _classify_bad_data(self, msg: Any) -> None:
        self._bad(signing.classify_bad_data(msg, self.mav), str(getattr(msg, "reason", "")))

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self.mav.command_ack_send(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    # --- modes and arming
    def _set_mode_common(self, base_mode: float, custom_mode: float) -> int:
        if not _finite(base_mode, custom_mode) or not (0 <= custom_mode < 2 ** 32) or not (0 <= base_mode < 256):
            self._bad("bad_field_values", f"set mode base={base_mode} custom={custom_mode}")
            return mavlink.MAV_RESULT_DENIED
        if not int(base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_DENIED
        ok, reason = self.copter.set_mode(int(custom_mode))
        if not ok:
            log.debug("mode change to %d refused: %s", int(custom_mode), reason)
        return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED

    def _on_set_mode(self, msg: Any) -> None:
        if not self._for_us(msg.target_system):
            return
        self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, self._set_mode_common(msg.base_mode, msg.custom_mode))

    def _arm_disarm(self, p1: float, p2: float) -> int:
        if not _finite(p1, p2):
            self._bad("bad_field_values", f"arm/disarm p1={p1} p2={p2}")
            return mavlink.MAV_RESULT_DENIED
        if p1 == 1.0:
            if self.copter.armed:
                return mavlink.MAV_RESULT_ACCEPTED
            starting_up = [] if p2 == FORCE_ARM_MAGIC else self.startup_failures()
            if starting_up:  # ArduCopter: MAV_RESULT_FAILED and every failing check as an "Arm:" text
                self._pending_texts.extend((mavlink.MAV_SEVERITY_CRITICAL, f"Arm: {r}") for r in starting_up)
                self.counters["arming_refused_starting_up"] += 1
                return mavlink.MAV_RESULT_FAILED
            ok, reason = self.copter.arm(force=(p2 == FORCE_ARM_MAGIC))
        elif p1 == 0.0:
            ok, reason = self.copter.disarm(force=(p2 == FORCE_DISARM_MAGIC))
        else:
            return mavlink.MAV_RESULT_UNSUPPORTED
        if not ok:
            log.debug("arm/disarm p1=%g refused: %s", p1, reason)
        return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED

    # --- commands
    def _on_command(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        self.counters["commands_in"] += 1
        cmd = msg.command
        p1, p2 = float(msg.param1), float(msg.param2)
        follow_up: Callable[[], None] | None = None
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            result = self._set_mode_common(p1, p2)
        elif cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._arm_disarm(p1, p2)
        elif cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._cmd_set_message_interval(p1, p2)
        elif cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            result, follow_up = self._cmd_get_message_interval(p1)
        elif cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            result, follow_up = self._cmd_request_message(p1)
        elif cmd == mavlink.MAV_CMD_RUN_PREARM_CHECKS and hasattr(self.copter, "prearm_check"):
            # ArduPilot: refused while armed; otherwise run the checks (failures go out as "PreArm:" texts)
            if self.copter.armed:
                result = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
            else:
                self._pending_texts.extend((mavlink.MAV_SEVERITY_CRITICAL, f"PreArm: {r}")
                                           for r in self.startup_failures())
                self.copter.prearm_check()
                result = mavlink.MAV_RESULT_ACCEPTED
        elif cmd == mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION:
            result = mavlink.MAV_RESULT_ACCEPTED
            follow_up = lambda: self._send_now(ProtocolVersionMessage.id)  # noqa: E731
        elif cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            ok = p1 == 1.0
            result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED
            if ok:
                follow_up = lambda: self._send_now(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)  # noqa: E731
        else:
            self._bad("unsupported_commands", f"command {cmd}")
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self._ack(msg, cmd, result)
        if follow_up is not None:
            follow_up()

    def _message_id_param(self, p1: float) -> int | None:
        if not math.isfinite(p1) or p1 < 0 or p1 > 2 ** 24 or p1 != int(p1):
            self._bad("bad_field_values", f"message id {p1}")
            return None
        return int(p1)

    def _unmapped(self, msg_id: int) -> bool:
        if msg_id in self._encoders:
            return False
        self._pending_texts.append((mavlink.MAV_SEVERITY_INFO, f"No ap_message for mavlink id ({msg_id})"))
        return True

    def _cmd_set_message_interval(self, p1: float, p2: float) -> int:
        msg_id = self._message_id_param(p1)
        if msg_id is None or not math.isfinite(p2):
            if msg_id is not None:
                self._bad("bad_field_values", f"interval {p2}")
            return mavlink.MAV_RESULT_DENIED
        if self._unmapped(msg_id):
            return mavlink.MAV_RESULT_FAILED
        if p2 < 0:
            interval: int | None = None if msg_id != mavlink.MAVLINK_MSG_ID_HEARTBEAT else HEARTBEAT_INTERVAL_US
        elif p2 == 0:
            interval = self._default_interval_us(msg_id)
        else:
            interval = self._whole_ms(int(min(max(p2, MIN_REQUEST_INTERVAL_US), MAX_INTERVAL_US)))
            if self.firmware.denies_fast_message_intervals and interval < self._loop_period_us():
                # ArduCopter >= 4.6: faster than one copy per loop is refused, with a text too long for one STATUSTEXT
                self._pending_texts.append((mavlink.MAV_SEVERITY_INFO, f"Requested rate for message ID {msg_id} too "
                                                                        "fast. Increase SCHED_LOOP_RATE"))
                self.counters["message_intervals_denied"] += 1
                return mavlink.MAV_RESULT_DENIED
        self._set_interval(msg_id, interval)
        return mavlink.MAV_RESULT_ACCEPTED

    def _cmd_get_message_interval(self, p1: float) -> tuple[int, Callable[[], None] | None]:
        msg_id = self._message_id_param(p1)
        if msg_id is None:
            return mavlink.MAV_RESULT_DENIED, None
        if self._unmapped(msg_id):
            return mavlink.MAV_RESULT_FAILED, None
        interval = self._effective_interval_us(msg_id)
        value = -1 if interval is None else interval
        return mavlink.MAV_RESULT_ACCEPTED, lambda: self.mav.message_interval_send(msg_id, value)

    def _cmd_request_message(self, p1: float) -> tuple[int, Callable[[], None] | None]:
        msg_id = self._message_id_param(p1)
        if msg_id is None:
            return mavlink.MAV_RESULT_DENIED, None
        if self._unmapped(msg_id):
            return mavlink.MAV_RESULT_FAILED, None
        return mavlink.MAV_RESULT_ACCEPTED, lambda: self._send_now(msg_id)

    def _on_request_data_stream(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        if msg.start_stop == 0:
            rate_hz = 0
        elif msg.req_message_rate > 0:
            rate_hz = msg.req_message_rate
        else:
            return
        groups = list(STREAM_GROUPS) if msg.req_stream_id == mavlink.MAV_DATA_STREAM_ALL else [msg.req_stream_id]
        for group in groups:
            for mid in STREAM_GROUPS.get(group, ()):
                self._set_interval(mid, self._whole_ms(int(1e6 / rate_hz)) if rate_hz > 0 else None)

    def _on_autopilot_version_request(self, msg: Any) -> None:
        if self._for_us(msg.target_system, msg.target_component):
            self._send_now(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)

    def _on_timesync(self, msg: Any) -> None:
        if msg.tc1 == 0:  # a request: answer at once with our receive time [ns]
            self.mav.timesync_send(self._now_us * 1000, msg.ts1)

    def _on_mission_request_list(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        mission_type = getattr(msg, "mission_type", 0)
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if mission_type in (mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_FENCE,
                            mavlink.MAV_MISSION_TYPE_RALLY):
            self.mav.mission_count_send(src[0], src[1], 0, mission_type)
        else:
            self.mav.mission_ack_send(src[0], src[1], mavlink.MAV_MISSION_UNSUPPORTED, mission_type)

    def _on_setup_signing(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        key = bytes(msg.secret_key)
        if not any(key) and msg.initial_timestamp == 0:
            self.disable_signing()
            self.counters["signing_disabled"] += 1
        else:
            self.enable_signing(key, int(msg.initial_timestamp))
            self.counters["signing_setups"] += 1

    def _on_file_transfer_protocol(self, msg: Any) -> None:
        """MAVLink FTP is not implemented (and not advertised): refuse every request at once.

        Session resets are ACKed; everything else gets NAK FileNotFound, so MAVProxy's ``param fetch``
        (which tries ``@PARAM/param.pck`` over FTP first) falls back to PARAM_REQUEST_LIST immediately
        instead of after its ~10 s FTP timeout.
        """
        if not self._for_us(msg.target_system, msg.target_component):
            return
        request = bytes(msg.payload)
        seq, session, opcode = request[0] | (request[1] << 8), request[2], request[3]
        if opcode in (FTP_OP_TERMINATE_SESSION, FTP_OP_RESET_SESSIONS):
            reply, size, data = FTP_OP_ACK, 0, 0
        else:
            reply, size, data = FTP_OP_NAK, 1, FTP_ERR_FILE_NOT_FOUND
        payload = [((seq + 1) & 0xFF), ((seq + 1) >> 8) & 0xFF, session, reply, size, opcode, 0, 0, 0, 0, 0, 0, data]
        payload += [0] * (251 - len(payload))
        self.counters["ftp_requests_refused"] += 1
        self.mav.file_transfer_protocol_send(0, msg.get_srcSystem(), msg.get_srcComponent(), payload)

    # --- SET_ATTITUDE_TARGET
    def _on_set_attitude_target(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        self.attitude_targets_received += 1
        q = [float(v) for v in msg.q]
        rates = (float(msg.body_roll_rate), float(msg.body_pitch_rate), float(msg.body_yaw_rate))
        thrust = float(msg.thrust)
        if not math.isfinite(sum(q) + sum(rates) + thrust):  # NaN/inf anywhere; float32 inputs cannot overflow
            self._bad("bad_field_values", f"SET_ATTITUDE_TARGET non-finite q={q} rates={rates} thrust={thrust}")
            return
        if self._command_latency_us > 0:  # acted on later (the profile's command_latency_s), in arrival order
            self._held_targets.append((self._now_us + self._command_latency_us, int(msg.type_mask), q, rates, thrust))
            return
        self._apply_attitude_target(int(msg.type_mask), q, rates, thrust)

    def _apply_attitude_target(self, type_mask: int, q: list, rates: tuple, thrust: float) -> None:
        accepted, reason = self.copter.handle_attitude_target(type_mask, q, rates, thrust)
        if not accepted:
            self.counters["attitude_targets_refused"] += 1
            n = self.counters["attitude_targets_refused"]
            if n <= 5 or n % 1000 == 0:
                log.debug("SET_ATTITUDE_TARGET mask=0x%02x refused (#%d): %s", type_mask, n, reason)

    # --- parameters
    def _index_of(self, name: str) -> int | None:
        index = self.copter.params.index_of(name)
        return None if index < 0 else index

    def _send_param_value(self, index: int, reported_index: int | None = None) -> None:
        """PARAM_VALUE of the entry at ``index``; ``reported_index`` goes in param_index (default: ``index``)."""
        entry = self.copter.params.by_index(index)
        self.counters["param_values_sent"] += 1
        self.mav.param_value_send(entry.name.encode("ascii"), float(entry.value), int(entry.param_type),
                                  self.copter.params.count, index if reported_index is None else reported_index)

    def _send_param_batch(self) -> None:
        for _ in range(min(PARAMS_PER_SERVICE, len(self._param_queue))):
            self._send_param_value(self._param_queue.popleft())

    def _on_param_request_list(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        self.send_statustext(mavlink.MAV_SEVERITY_INFO, f"ArduCopter V{self.firmware.text} (mavastsm sim)")
        self.send_statustext(mavlink.MAV_SEVERITY_INFO, "Frame: QUAD/X")
        self.counters["param_lists_requested"] += 1
        self._param_queue = deque(range(self.copter.params.count))

    @staticmethod
    def _param_name(raw: Any) -> str:
        if isinstance(raw, bytes):
            raw = raw.decode("ascii", errors="replace")
        return str(raw).rstrip("\x00")

    def _on_param_request_read(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        if msg.param_index >= 0:
            index: int | None = msg.param_index if msg.param_index < self.copter.params.count else None
            reported_index = index
        else:
            index = self._index_of(self._param_name(msg.param_id))
            reported_index = PARAM_INDEX_UNKNOWN if self.profile.param_index_65535 else index
        if index is None:
            self._bad("unknown_params", f"read {self._param_name(msg.param_id)!r} index {msg.param_index}")
            return
        if self.profile.param_read_interval_s > 0:
            self._param_read_replies.append((index, reported_index))
        else:
            self._send_param_value(index, reported_index)

    def _on_param_set(self, msg: Any) -> None:
        if not self._for_us(msg.target_system, msg.target_component):
            return
        name = self._param_name(msg.param_id)
        index = self._index_of(name)
        if index is None:
            self._bad("unknown_params", f"set {name!r}")
            return
        value = float(msg.param_value)
        if not math.isfinite(value):
            self._bad("bad_field_values", f"PARAM_SET {name}={value}")
            return
        ok, reason = self.copter.params.set(name, value)
        if not ok:
            self.counters["param_writes_denied"] += 1
            self._pending_texts.append((mavlink.MAV_SEVERITY_WARNING, f"Param write denied ({name})"))
            log.debug("PARAM_SET %s=%g denied: %s", name, value, reason)
        # echo: the new value is the ACK; on refusal the unchanged one (ArduPilot's announces it with index 65535)
        self._send_param_value(index, PARAM_INDEX_UNKNOWN if self.profile.param_index_65535 else index)

    # ------------------------------------------------------------------ outbound encoders
    def _send_now(self, msg_id: int) -> None:
        """Encode and send one message; a state that cannot be encoded (e.g. NaN after a blow-up) is counted
        in ``telemetry_encode_errors`` and skipped instead of stopping the vehicle."""
        try:
            msg = self._encoders[msg_id]()
            self.mav.send(msg)
        except Exception as exc:  # noqa: BLE001 - a telemetry value must never stop the loop
            self.counters["telemetry_encode_errors"] += 1
            n = self.counters["telemetry_encode_errors"]
            if n <= 5 or n % 1000 == 0:
                log.warning("cannot encode message id %d (#%d): %r", msg_id, n, exc)

    @property
    def _time_boot_ms(self) -> int:
        return (self._now_us // 1000) & 0xFFFFFFFF

    def base_mode(self) -> int:
        """HEARTBEAT base_mode: 81 disarmed, 89 disarmed GUIDED, 209 armed, 217 armed GUIDED."""
        c = self.copter
        mode = BASE_MODE_ALWAYS
        if int(c.mode_number) in GUIDED_FLAG_MODES:
            mode |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if c.armed:
            mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return mode

    def _heartbeat(self) -> Any:
        c = self.copter
        mav_type = MAV_TYPE_BY_FRAME_CLASS.get(int(self._param("FRAME_CLASS", 1.0)), mavlink.MAV_TYPE_QUADROTOR)
        booting = self._startup_fraction() < BOOTED_FRACTION  # before "ArduPilot Ready" (with a pre-arm delay)
        status = mavlink.MAV_STATE_BOOT if booting else int(c.system_status)
        return self.mav.heartbeat_encode(mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, self.base_mode(),
                                         int(c.mode_number), status, 3)

    def _sys_status(self) -> Any:
        c = self.copter
        s = mavlink
        present = (s.MAV_SYS_STATUS_SENSOR_3D_GYRO | s.MAV_SYS_STATUS_SENSOR_3D_ACCEL | s.MAV_SYS_STATUS_SENSOR_3D_MAG
                   | s.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | s.MAV_SYS_STATUS_SENSOR_GPS
                   | s.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL | s.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
                   | s.MAV_SYS_STATUS_SENSOR_YAW_POSITION | s.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
                   | s.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | s.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
                   | s.MAV_SYS_STATUS_AHRS | s.MAV_SYS_STATUS_SENSOR_BATTERY | s.MAV_SYS_STATUS_PREARM_CHECK)
        enabled = present if c.armed else present & ~s.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        errors = min(self.bad_input_total(), 65535)
        health = present | s.MAV_SYS_STATUS_GEOFENCE  # no fence configured, not breached (as ArduCopter)
        if self.startup_failures():  # the bit ground stations show as "ready to arm"
            health &= ~s.MAV_SYS_STATUS_PREARM_CHECK
        return self.mav.sys_status_encode(present, enabled, health, 250, int(c.battery_voltage_v * 1000), -1,
                                          int(c.battery_remaining_pct), 0, errors, 0, 0, 0, 0)

    def _system_time(self) -> Any:
        unix_us = int((self._unix_at_boot_s + self._now_us * 1e-6) * 1e6)
        return self.mav.system_time_encode(unix_us, self._time_boot_ms)

    def _lat_lon_e7(self) -> tuple[int, int]:
        n, e = float(self.copter.position_ned_m[0]), float(self.copter.position_ned_m[1])
        lat = self.home_lat_deg + math.degrees(n / EARTH_RADIUS_M)
        lon = self.home_lon_deg + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(self.home_lat_deg))))
        return int(round(lat * 1e7)), int(round(lon * 1e7))

    def _heading_deg(self) -> float:
        return math.degrees(float(self.copter.euler_rad[2])) % 360.0

    def _gps_raw_int(self) -> Any:
        c = self.copter
        lat, lon = self._lat_lon_e7()
        vn, ve = float(c.velocity_ned_ms[0]), float(c.velocity_ned_ms[1])
        alt_mm = int(round((self.home_alt_m - float(c.position_ned_m[2])) * 1000))
        cog = int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100)) % 36000
        return self.mav.gps_raw_int_encode(self._now_us, mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt_mm, 121, 200,
                                           min(int(round(math.hypot(vn, ve) * 100)), 65534), cog, 10)

    def _attitude(self) -> Any:
        if self._attitude_sample is not None:
            roll, pitch, yaw, p, q, r = self._attitude_sample()
        else:
            c = self.copter
            roll, pitch, yaw = c.euler_rad.tolist()
            p, q, r = c.body_rates_rads.tolist()
        return self.mav.attitude_encode((self._now_us // 1000) & 0xFFFFFFFF, roll, pitch, yaw, p, q, r)

    def _attitude_quaternion(self) -> Any:
        c = self.copter
        w, x, y, z = (float(v) for v in c.quaternion_wxyz)
        p, q, r = (float(v) for v in c.body_rates_rads)
        return self.mav.attitude_quaternion_encode(self._time_boot_ms, w, x, y, z, p, q, r)

    def _attitude_target(self) -> Any:
        q_target, rates, thrust = self.copter.attitude_target
        return self.mav.attitude_target_encode(self._time_boot_ms, 0, [float(v) for v in q_target],
                                               float(rates[0]), float(rates[1]), float(rates[2]), float(thrust))

    def _local_position_ned(self) -> Any:
        c = self.copter
        x, y, z = (float(v) for v in c.position_ned_m)
        vx, vy, vz = (float(v) for v in c.velocity_ned_ms)
        return self.mav.local_position_ned_encode(self._time_boot_ms, x, y, z, vx, vy, vz)

    def _global_position_int(self) -> Any:
        c = self.copter
        lat, lon = self._lat_lon_e7()
        down = float(c.position_ned_m[2])
        vn, ve, vd = (int(round(float(v) * 100)) for v in c.velocity_ned_ms)
        hdg = int(round(self._heading_deg() * 100)) % 36000
        return self.mav.global_position_int_encode(self._time_boot_ms, lat, lon,
                                                   int(round((self.home_alt_m - down) * 1000)),
                                                   int(round(-down * 1000)), vn, ve, vd, hdg)

    def _servo_output_raw(self) -> Any:
        pwm = [int(round(1000 + 1000 * min(max(float(u), 0.0), 1.0))) for u in self.copter.motor_outputs_norm]
        pwm = (pwm + [0] * 8)[:8]
        return self.mav.servo_output_raw_encode(self._now_us & 0xFFFFFFFF, 0, *pwm)

    def _vfr_hud(self) -> Any:
        c = self.copter
        vn, ve, vd = (float(v) for v in c.velocity_ned_ms)
        speed = math.hypot(vn, ve)
        outputs = [float(u) for u in c.motor_outputs_norm]
        throttle = int(round(100 * sum(outputs) / max(len(outputs), 1)))
        return self.mav.vfr_hud_encode(speed, speed, int(self._heading_deg()) % 360, min(max(throttle, 0), 100),
                                       self.home_alt_m - float(c.position_ned_m[2]), -vd)

    def _battery_status(self) -> Any:
        c = self.copter
        voltages = [min(int(c.battery_voltage_v * 1000), 65534)] + [65535] * 9
        return self.mav.battery_status_encode(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO,
                                              32767, voltages, -1, -1, -1, int(c.battery_remaining_pct))

    def _autopilot_version(self) -> Any:
        return self.mav.autopilot_version_encode(CAPABILITIES, self.firmware.flight_sw_version, 0, 0, 0,
                                                 list(FIRMWARE_GIT_HASH), [0] * 8,
                                                 [0] * 8, 0, 0, 0)

    def _protocol_version(self) -> Any:
        return ProtocolVersionMessage(200, 100, 200, b"\x00" * 8, FIRMWARE_GIT_HASH)

    def _home_position(self) -> Any:
        return self.mav.home_position_encode(int(round(self.home_lat_deg * 1e7)), int(round(self.home_lon_deg * 1e7)),
                                             int(round(self.home_alt_m * 1000)), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                             0.0, 0.0, 0.0, self._now_us)

    def _gps_global_origin(self) -> Any:
        lat_e7, lon_e7 = int(round(self.home_lat_deg * 1e7)), int(round(self.home_lon_deg * 1e7))
        return self.mav.gps_global_origin_encode(lat_e7, lon_e7, int(round(self.home_alt_m * 1000)), self._now_us)

    def _extended_sys_state(self) -> Any:
        landed = mavlink.MAV_LANDED_STATE_ON_GROUND if self.copter.landed else mavlink.MAV_LANDED_STATE_IN_AIR
        return self.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, landed)


class PrearmWatcher:
    """A ground station's view of a *genuine* autopilot's pre-arm state (``mavastsm sim --autopilot arducopter``),
    kept here because this is the sim's one pymavlink module.

    Feed it every datagram from the autopilot's spare MAVLink link (``handle_datagram``); send what
    ``requests()`` returns to the autopilot about once a second (a GCS HEARTBEAT and a 2 Hz SYS_STATUS interval
    request: ArduCopter streams nothing to a new link until asked). Read ``heard``, ``armable`` (SYS_STATUS health
    bit MAV_SYS_STATUS_PREARM_CHECK, as ground stations show it) and ``last_prearm_text`` (the newest "PreArm:"
    STATUSTEXT, which names the check that still fails). No I/O of its own.
    """

    GCS_SYSID = 254

    def __init__(self) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=self.GCS_SYSID, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self.mav.robust_parsing = True
        self._out = mavlink.MAVLink(None, srcSystem=self.GCS_SYSID, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self.heard = False
        self.armable = False
        self.target = (1, 1)
        self.last_prearm_text = ""

    def handle_datagram(self, data: bytes) -> None:
        msgs, _ = parse_datagram(self.mav, data)
        for m in msgs:
            kind = m.get_type()
            if kind == "HEARTBEAT" and m.get_srcComponent() == AUTOPILOT_COMPONENT_ID:
                self.heard = True
                self.target = (m.get_srcSystem(), m.get_srcComponent())
            elif kind == "SYS_STATUS":
                self.armable = bool(m.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK)
            elif kind == "STATUSTEXT":
                text = m.text if isinstance(m.text, str) else m.text.decode("ascii", "replace")
                if text.startswith("PreArm:"):
                    self.last_prearm_text = text.rstrip("\x00")

    def requests(self) -> list[bytes]:
        """Frames to send now: a GCS HEARTBEAT, and (once the autopilot is heard) SYS_STATUS at 2 Hz."""
        out = [self._out.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(self._out)]
        if self.heard:
            out.append(self._out.command_long_encode(*self.target, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                     mavlink.MAVLINK_MSG_ID_SYS_STATUS, 500000, 0, 0, 0, 0, 0)
                       .pack(self._out))
        return out
