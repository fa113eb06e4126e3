"""Outbound telemetry of the simulated ArduCopter: the copter's state encoded as MAVLink messages and sent.

One encoder per message id the vehicle can send (streams, REQUEST_MESSAGE and the events that send one at once).
Units: SI inside (rad, rad/s, m, m/s); MAVLink units at the edge (cdeg, mm, cm/s, mV, us) converted here.
Frames: NED world, FRD body, quaternion [w, x, y, z] rotating NED to FRD, as in ``mavastsm.frames``.
Time: ``time_boot_ms`` and every timestamp come from the link's simulated time (``VehicleLink.now_us``).
"""

from __future__ import annotations

import logging
import math
import struct
import time
from typing import Any, Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .vehicle_link import VehicleLink
from .vehicle_startup import StartupSequence

log = logging.getLogger("mavastsm_sim")

# --- identity and version (what ArduCopter on a quad X reports; 4.5.7 unless told otherwise) ----------------
FIRMWARE_GIT_HASH = b"6d617661"  # 8 ASCII chars, like ArduPilot's flight_custom_version
CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)  # deliberately no FTP (not implemented)

# MAV_TYPE from FRAME_CLASS (AP_Motors get_frame_mav_type)
MAV_TYPE_BY_FRAME_CLASS = {1: mavlink.MAV_TYPE_QUADROTOR, 2: mavlink.MAV_TYPE_HEXAROTOR,
                           3: mavlink.MAV_TYPE_OCTOROTOR, 6: mavlink.MAV_TYPE_HELICOPTER,
                           7: mavlink.MAV_TYPE_TRICOPTER}
# Copter modes that set MAV_MODE_FLAG_GUIDED_ENABLED (the classic list; GUIDED_NOGPS has no position control)
GUIDED_FLAG_MODES = frozenset({3, 4, 5, 6, 7, 16, 17, 19, 21, 23})
BASE_MODE_ALWAYS = (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
                    | mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)  # 81
EARTH_RADIUS_M = 6378137.0


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


class TelemetryEncoder:
    """Encodes and sends the vehicle's messages, one encoder per message id.

    Parameters
    ----------
    link : VehicleLink
        Sender, clock and counters (``telemetry_encode_errors``).
    startup : StartupSequence
        Start-up state: HEARTBEAT system_status and the SYS_STATUS pre-arm health bit.
    home : (lat_deg, lon_deg, alt_m_amsl)
        Home / EKF origin used for GPS-like messages.
    unix_time_at_boot_s : float or None
        Wall-clock Unix time that simulated time 0 corresponds to (SYSTEM_TIME, GPS time);
        None uses the host time at construction.
    """

    def __init__(self, link: VehicleLink, startup: StartupSequence, home: tuple[float, float, float],
                 unix_time_at_boot_s: float | None) -> None:
        self.link = link
        self.copter: Any = link.copter
        self.mav = link.mav
        self.counters = link.counters
        self.startup = startup
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = home
        self._unix_at_boot_s = time.time() if unix_time_at_boot_s is None else float(unix_time_at_boot_s)
        # plain-float read-out for ATTITUDE when the plant offers one (SimulatedCopter does), else NumPy
        self._attitude_sample: Callable[[], tuple] | None = getattr(self.copter, "attitude_sample", None)
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

    def can_encode(self, msg_id: int) -> bool:
        """True when ``msg_id`` has an encoder here (ArduPilot: an ap_message for that MAVLink id)."""
        return msg_id in self._encoders

    def send_home_and_origin(self) -> None:
        """HOME_POSITION and GPS_GLOBAL_ORIGIN, as ArduCopter sends them when the EKF origin is set and on arming."""
        if self.link.profile.position_estimate:
            self.send_now(mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)
            self.send_now(mavlink.MAVLINK_MSG_ID_HOME_POSITION)

    def send_now(self, msg_id: int) -> None:
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
        return (self.link.now_us // 1000) & 0xFFFFFFFF

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
        mav_type = MAV_TYPE_BY_FRAME_CLASS.get(int(self.link.param("FRAME_CLASS", 1.0)), mavlink.MAV_TYPE_QUADROTOR)
        booting = self.startup.booting()  # before "ArduPilot Ready" (with a pre-arm delay)
        status = mavlink.MAV_STATE_BOOT if booting else int(c.system_status)
        return self.mav.heartbeat_encode(mav_type, self.link.profile.heartbeat_autopilot, self.base_mode(),
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
        errors = min(self.link.bad_input_total(), 65535)
        health = present | s.MAV_SYS_STATUS_GEOFENCE  # no fence configured, not breached (as ArduCopter)
        if self.startup.failures():  # the bit ground stations show as "ready to arm"
            health &= ~s.MAV_SYS_STATUS_PREARM_CHECK
        return self.mav.sys_status_encode(present, enabled, health, 250, int(c.battery_voltage_v * 1000), -1,
                                          int(c.battery_remaining_pct), 0, errors, 0, 0, 0, 0)

    def _system_time(self) -> Any:
        unix_us = int((self._unix_at_boot_s + self.link.now_us * 1e-6) * 1e6)
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
        return self.mav.gps_raw_int_encode(self.link.now_us, mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt_mm, 121, 200,
                                           min(int(round(math.hypot(vn, ve) * 100)), 65534), cog, 10)

    def _attitude(self) -> Any:
        if self._attitude_sample is not None:
            roll, pitch, yaw, p, q, r = self._attitude_sample()
        else:
            c = self.copter
            roll, pitch, yaw = c.euler_rad.tolist()
            p, q, r = c.body_rates_rads.tolist()
        return self.mav.attitude_encode((self.link.now_us // 1000) & 0xFFFFFFFF, roll, pitch, yaw, p, q, r)

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
        return self.mav.servo_output_raw_encode(self.link.now_us & 0xFFFFFFFF, 0, *pwm)

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
        return self.mav.autopilot_version_encode(CAPABILITIES, self.link.firmware.flight_sw_version, 0, 0, 0,
                                                 list(FIRMWARE_GIT_HASH), [0] * 8,
                                                 [0] * 8, 0, 0, 0)

    def _protocol_version(self) -> Any:
        return ProtocolVersionMessage(200, 100, 200, b"\x00" * 8, FIRMWARE_GIT_HASH)

    def _home_position(self) -> Any:
        return self.mav.home_position_encode(int(round(self.home_lat_deg * 1e7)), int(round(self.home_lon_deg * 1e7)),
                                             int(round(self.home_alt_m * 1000)), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                             0.0, 0.0, 0.0, self.link.now_us)

    def _gps_global_origin(self) -> Any:
        lat_e7, lon_e7 = int(round(self.home_lat_deg * 1e7)), int(round(self.home_lon_deg * 1e7))
        return self.mav.gps_global_origin_encode(lat_e7, lon_e7, int(round(self.home_alt_m * 1000)), self.link.now_us)

    def _extended_sys_state(self) -> Any:
        landed = mavlink.MAV_LANDED_STATE_ON_GROUND if self.copter.landed else mavlink.MAV_LANDED_STATE_IN_AIR
        return self.mav.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, landed)

