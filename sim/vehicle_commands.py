"""Commands and one-shot requests to the simulated ArduCopter, each answered as ArduCopter 4.2+ does.

SET_MODE (ACK command 11) and MAV_CMD_DO_SET_MODE (ACK 176), by COMMAND_LONG and COMMAND_INT;
MAV_CMD_COMPONENT_ARM_DISARM (400) with the force values 2989 (arm) and 21196 (disarm); MAV_CMD_RUN_PREARM_CHECKS
(401); MAV_CMD_SET_MESSAGE_INTERVAL (0 = default, -1 = stop, FAILED + STATUSTEXT for unknown ids, the >= 4.6 DENIED),
GET_MESSAGE_INTERVAL, REQUEST_MESSAGE; PROTOCOL_VERSION (519) and AUTOPILOT_VERSION (520 with p1 = 1, and
AUTOPILOT_VERSION_REQUEST); MISSION_REQUEST_LIST answered with an empty MISSION_COUNT; MAVLink FTP refused.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .vehicle_link import VehicleLink
from .vehicle_startup import StartupSequence
from .vehicle_streams import HEARTBEAT_INTERVAL_US, StreamScheduler
from .vehicle_telemetry import ProtocolVersionMessage, TelemetryEncoder

log = logging.getLogger("mavastsm_sim")

FORCE_ARM_MAGIC = 2989
FORCE_DISARM_MAGIC = 21196
MAX_INTERVAL_US = 60_000_000   # ArduPilot caps requested intervals at 60 s
MIN_REQUEST_INTERVAL_US = 1_000  # < 1000 us means 1 ms

# MAVLink FTP (refused: see CommandHandler.on_file_transfer_protocol)
FTP_OP_TERMINATE_SESSION, FTP_OP_RESET_SESSIONS, FTP_OP_ACK, FTP_OP_NAK = 1, 2, 128, 129
FTP_ERR_FILE_NOT_FOUND = 10


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class CommandHandler:
    """COMMAND_LONG / COMMAND_INT, SET_MODE and the one-shot requests: act, ACK, send what was asked for.

    Parameters
    ----------
    link : VehicleLink
        The copter (modes, arming), sender, counters and the STATUSTEXT queue.
    telemetry : TelemetryEncoder
        Sends a requested message; knows which ids can be sent.
    streams : StreamScheduler
        The message intervals that SET/GET_MESSAGE_INTERVAL write and read.
    startup : StartupSequence
        The pre-arm reasons while the vehicle starts up.
    """

    def __init__(self, link: VehicleLink, telemetry: TelemetryEncoder, streams: StreamScheduler,
                 startup: StartupSequence) -> None:
        self.link = link
        self.copter: Any = link.copter
        self.mav = link.mav
        self.counters = link.counters
        self.telemetry = telemetry
        self.streams = streams
        self.startup = startup

    def _ack(self, msg: Any, command: int, result: int) -> None:
        self.mav.command_ack_send(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _set_mode_common(self, base_mode: float, custom_mode: float) -> int:
        if not _finite(base_mode, custom_mode) or not (0 <= custom_mode < 2 ** 32) or not (0 <= base_mode < 256):
            self.link.bad("bad_field_values", f"set mode base={base_mode} custom={custom_mode}")
            return mavlink.MAV_RESULT_DENIED
        if not int(base_mode) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_DENIED
        ok, reason = self.copter.set_mode(int(custom_mode))
        if not ok:
            log.debug("mode change to %d refused: %s", int(custom_mode), reason)
        return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED

    def on_set_mode(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system):
            return
        self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, self._set_mode_common(msg.base_mode, msg.custom_mode))

    def _arm_disarm(self, p1: float, p2: float) -> int:
        if not _finite(p1, p2):
            self.link.bad("bad_field_values", f"arm/disarm p1={p1} p2={p2}")
            return mavlink.MAV_RESULT_DENIED
        if p1 == 1.0:
            if self.copter.armed:
                return mavlink.MAV_RESULT_ACCEPTED
            starting_up = [] if p2 == FORCE_ARM_MAGIC else self.startup.failures()
            if starting_up:  # ArduCopter: MAV_RESULT_FAILED and every failing check as an "Arm:" text
                self.link.pending_texts.extend((mavlink.MAV_SEVERITY_CRITICAL, f"Arm: {r}") for r in starting_up)
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

    def on_command(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
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
                self.link.pending_texts.extend((mavlink.MAV_SEVERITY_CRITICAL, f"PreArm: {r}")
                                               for r in self.startup.failures())
                self.copter.prearm_check()
                result = mavlink.MAV_RESULT_ACCEPTED
        elif cmd == mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION:
            result = mavlink.MAV_RESULT_ACCEPTED
            follow_up = lambda: self.telemetry.send_now(ProtocolVersionMessage.id)  # noqa: E731
        elif cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            ok = p1 == 1.0
            result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_FAILED
            if ok:
                follow_up = lambda: self.telemetry.send_now(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)  # noqa: E731
        else:
            self.link.bad("unsupported_commands", f"command {cmd}")
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self._ack(msg, cmd, result)
        if follow_up is not None:
            follow_up()

    def _message_id_param(self, p1: float) -> int | None:
        if not math.isfinite(p1) or p1 < 0 or p1 > 2 ** 24 or p1 != int(p1):
            self.link.bad("bad_field_values", f"message id {p1}")
            return None
        return int(p1)

    def _unmapped(self, msg_id: int) -> bool:
        if self.telemetry.can_encode(msg_id):
            return False
        self.link.pending_texts.append((mavlink.MAV_SEVERITY_INFO, f"No ap_message for mavlink id ({msg_id})"))
        return True

    def _cmd_set_message_interval(self, p1: float, p2: float) -> int:
        msg_id = self._message_id_param(p1)
        if msg_id is None or not math.isfinite(p2):
            if msg_id is not None:
                self.link.bad("bad_field_values", f"interval {p2}")
            return mavlink.MAV_RESULT_DENIED
        if self._unmapped(msg_id):
            return mavlink.MAV_RESULT_FAILED
        if p2 < 0:
            interval: int | None = None if msg_id != mavlink.MAVLINK_MSG_ID_HEARTBEAT else HEARTBEAT_INTERVAL_US
        elif p2 == 0:
            interval = self.streams.default_interval_us(msg_id)
        else:
            interval = self.streams.whole_ms(int(min(max(p2, MIN_REQUEST_INTERVAL_US), MAX_INTERVAL_US)))
            if self.link.firmware.denies_fast_message_intervals and interval < self.streams.loop_period_us():
                # ArduCopter >= 4.6: faster than one copy per loop is refused, with a text too long for one STATUSTEXT
                self.link.pending_texts.append((mavlink.MAV_SEVERITY_INFO, f"Requested rate for message ID {msg_id} "
                                                                           "too fast. Increase SCHED_LOOP_RATE"))
                self.counters["message_intervals_denied"] += 1
                return mavlink.MAV_RESULT_DENIED
        self.streams.set_interval(msg_id, interval)
        return mavlink.MAV_RESULT_ACCEPTED

    def _cmd_get_message_interval(self, p1: float) -> tuple[int, Callable[[], None] | None]:
        msg_id = self._message_id_param(p1)
        if msg_id is None:
            return mavlink.MAV_RESULT_DENIED, None
        if self._unmapped(msg_id):
            return mavlink.MAV_RESULT_FAILED, None
        interval = self.streams.effective_interval_us(msg_id)
        value = -1 if interval is None else interval
        return mavlink.MAV_RESULT_ACCEPTED, lambda: self.mav.message_interval_send(msg_id, value)

    def _cmd_request_message(self, p1: float) -> tuple[int, Callable[[], None] | None]:
        msg_id = self._message_id_param(p1)
        if msg_id is None:
            return mavlink.MAV_RESULT_DENIED, None
        if self._unmapped(msg_id):
            return mavlink.MAV_RESULT_FAILED, None
        return mavlink.MAV_RESULT_ACCEPTED, lambda: self.telemetry.send_now(msg_id)

    def on_autopilot_version_request(self, msg: Any) -> None:
        if self.link.for_us(msg.target_system, msg.target_component):
            self.telemetry.send_now(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)

    def on_mission_request_list(self, msg: Any) -> None:
        if not self.link.for_us(msg.target_system, msg.target_component):
            return
        mission_type = getattr(msg, "mission_type", 0)
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if mission_type in (mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_FENCE,
                            mavlink.MAV_MISSION_TYPE_RALLY):
            self.mav.mission_count_send(src[0], src[1], 0, mission_type)
        else:
            self.mav.mission_ack_send(src[0], src[1], mavlink.MAV_MISSION_UNSUPPORTED, mission_type)

    def on_file_transfer_protocol(self, msg: Any) -> None:
        """MAVLink FTP is not implemented (and not advertised): refuse every request at once.

        Session resets are ACKed; everything else gets NAK FileNotFound, so MAVProxy's ``param fetch``
        (which tries ``@PARAM/param.pck`` over FTP first) falls back to PARAM_REQUEST_LIST immediately
        instead of after its ~10 s FTP timeout.
        """
        if not self.link.for_us(msg.target_system, msg.target_component):
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
