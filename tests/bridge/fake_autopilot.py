"""A small MAVLink autopilot test double for the bridge tests (a pymavlink peer; test code only).

Speaks just enough ArduCopter 4.2+ (docs/design-decisions.md, MAV-1 to MAV-6) or PX4 (MAV-13) for the bridge: HEARTBEAT,
AUTOPILOT_VERSION on REQUEST_MESSAGE, SET_MESSAGE_INTERVAL / DO_SET_MODE / ARM with COMMAND_ACK,
PARAM_REQUEST_READ / PARAM_SET, ATTITUDE from a kinematic plant (attitude integrates the commanded
body rates; a 0x07 target levels it), GLOBAL_POSITION_INT from a climb-rate altitude model.
PX4 mode: OFFBOARD (custom_mode 393216) is refused unless setpoints have streamed for >= 1 s.

PX4 mode also streams LOCAL_POSITION_NED (at rest, 50 Hz) and refuses NAV_TAKEOFF (UNSUPPORTED), so its own takeoff
fails after the bridge armed. Knobs for failsafe tests: ``pause_attitude``, ``nan_attitude``, ``force_roll_rad``, ``mute_heartbeat``,
``foreign_attitude`` (also send ATTITUDE from sysid 2 with a 60 deg roll), ``set_mode_external``.
PX4's own hold (``hold_thrust_norm``): armed outside OFFBOARD it sends ATTITUDE_TARGET with that thrust (level, new
timestamps) with every ATTITUDE, as PX4 1.15 streams its position controller's collective; in OFFBOARD it repeats the
last hold target with its old timestamp (PX4 publishes no attitude setpoint for body rates). ``px4_params`` answers
PARAM_REQUEST_READ for PX4 (MPC_THR_HOVER, ...).
Everything received is recorded (``setpoints``, ``commands``) with host monotonic times.
"""

from __future__ import annotations

import os
import threading
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402
from mavastsm.frames import wrap_angle_float  # noqa: E402
from mavastsm.solo_model import packaged_vehicle_tunings  # noqa: E402

mavlink = mavutil.mavlink
ACM_MODES = {"STABILIZE": 0, "ALT_HOLD": 2, "GUIDED": 4, "LOITER": 5, "LAND": 9, "GUIDED_NOGPS": 20}
PX4_MAIN = {"ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "OFFBOARD": 6, "STABILIZED": 7}


PX4_PRESTREAM_MS = 1000  # [ms] of the vehicle's clock PX4 wants setpoints streaming before OFFBOARD is accepted


class FakeAutopilot:
    def __init__(self, autopilot: str = "ArduPilot", sysid: int = 1, version=(4, 5, 1), rate_hz: float = 200.0,
                 guid_options: int = 0, signing_key: bytes | None = None, heartbeat_hz: float = 10.0,
                 max_interval_rate_hz: float | None = None, hold_thrust_norm: float | None = None,
                 px4_params: dict[str, float] | None = None, ardupilot_tuning: dict[str, float] | None = None,
                 lose_first_param_reply: frozenset[str] = frozenset()) -> None:
        self.autopilot = autopilot
        self.sysid = sysid
        self.version = version
        self.period_s = 1.0 / rate_hz
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=sysid, source_component=1)
        self.port = self.conn.port.getsockname()[1]
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True)
        self._foreign = mavlink.MAVLink(self.conn, srcSystem=2, srcComponent=1)
        self.params = {"GUID_OPTIONS": float(guid_options), "GUID_TIMEOUT": 3.0, "ATC_ACCEL_R_MAX": 36000.0,
                       "ATC_ACCEL_P_MAX": 36000.0, "ATC_ACCEL_Y_MAX": 7000.0}
        self.heartbeat_period_s = 1.0 / heartbeat_hz
        self.hold_thrust_norm = hold_thrust_norm
        self._hold_target_ms: int | None = None  # timestamp of the last hold target (repeated in OFFBOARD)
        # PX4 answers the names it has: its stock SIH tuning (recognised as px4_sih_quadx) and what the test adds
        self.px4_params = {**packaged_vehicle_tunings()["px4_sih_quadx"], **(px4_params or {})} if autopilot == "PX4" else {}
        self.params.update(self.px4_params)
        # ArduPilot answers its ATC_* tuning as ArduCopter does: the Solo's (its ATC_ACCEL above are the Solo's too),
        # recognised as the solo description, unless the test gives another
        if autopilot == "ArduPilot":
            self.params.update({**packaged_vehicle_tunings()["solo"], **(ardupilot_tuning or {})})
        self.lose_first_param_reply = set(lose_first_param_reply)  # names whose first PARAM_VALUE is lost on the way
        # ArduCopter >= 4.6: SET_MESSAGE_INTERVAL faster than this is DENIED, and the reason (a STATUSTEXT in
        # two chunks) is sent after the ACK, as its queued texts can be
        self.max_interval_rate_hz = max_interval_rate_hz
        self.reason_delay_s = 0.1
        self.mode = "STABILIZE" if autopilot == "ArduPilot" else "POSCTL"
        self.armed = False
        self.att = [0.0, 0.0, 0.0]
        self.rates = [0.0, 0.0, 0.0]
        self.alt_m = 0.0
        self.time_ms = 1000
        self.setpoints: list[tuple[float, int, tuple, tuple, float, str, bool]] = []  # (t, mask, q, rates, thrust, mode, signed)
        self.commands: list[tuple[float, int, tuple]] = []
        self.first_setpoint_ms: int | None = None  # the fake's vehicle clock (time_ms) when the first setpoint arrived
        self.offboard_requests_ms: list[int] = []  # its vehicle clock at each OFFBOARD request (PX4's rule is on its clock)
        self.unsigned_or_bad = 0
        self.pause_attitude = False
        self.nan_attitude = False
        self.force_roll_rad: float | None = None
        self.mute_heartbeat = False
        self.late_heartbeat_after_mode_ack = False  # a HEARTBEAT in the old mode after the ACK (built before the switch)
        self._heartbeats_held_until = 0.0
        self.foreign_attitude = False
        self._last_sp = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)

    # -------------------------------------------------------------- lifecycle
    def start(self) -> "FakeAutopilot":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=3.0)
        self.conn.close()

    @property
    def prestream_floor_ms(self) -> int:
        """Least pre-stream [ms, the fake's clock] between the first setpoint and an OFFBOARD request it accepts:
        PX4_PRESTREAM_MS less one ATTITUDE period (the bridge counts from the last ATTITUDE it had when it sent the
        first setpoint, which may be one period older than this clock when that setpoint arrives)."""
        return PX4_PRESTREAM_MS - round(self.period_s * 1000)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    @property
    def url(self) -> str:
        return f"udpout:127.0.0.1:{self.port}"

    def set_mode_external(self, name: str) -> None:
        """A pilot / GCS changes the mode."""
        with self._lock:
            self.mode = name
        self._heartbeat()

    def wait_for(self, predicate, timeout_s: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if predicate(self):
                    return True
            self._stop.wait(0.01)
        return False

    # -------------------------------------------------------------- wire
    def _custom_mode(self) -> int:
        if self.autopilot == "ArduPilot":
            return ACM_MODES[self.mode]
        return PX4_MAIN[self.mode] << 16

    def _heartbeat(self) -> None:
        if self.mute_heartbeat:
            return
        ap = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA if self.autopilot == "ArduPilot" else mavlink.MAV_AUTOPILOT_PX4
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, ap, base, self._custom_mode(), mavlink.MAV_STATE_ACTIVE)

    def _late_heartbeat(self, old_mode: str) -> None:
        """A HEARTBEAT built before the switch, delivered after the ACK; the next one shows the new mode."""
        with self._lock:
            new_mode, self.mode = self.mode, old_mode
            self._heartbeat()
            self.mode = new_mode

    def _ack(self, command: int, result: int) -> None:
        self.conn.mav.command_ack_send(command, result)

    def _send_chunked_text(self, text: str) -> None:
        """STATUSTEXT as ArduPilot sends a long one: 50-character chunks with one id."""
        chunks = [text[i:i + 50] for i in range(0, len(text), 50)]
        for seq, chunk in enumerate(chunks):
            self.conn.mav.statustext_send(mavlink.MAV_SEVERITY_WARNING, chunk.encode(), 7, seq)

    def _handle(self, m) -> None:
        t = m.get_type()
        now = time.monotonic()
        if t == "BAD_DATA":
            self.unsigned_or_bad += 1
            return
        if self.conn.mav.signing.secret_key is not None and not getattr(m, "_signed", False):
            self.unsigned_or_bad += 1  # pymavlink lets nothing unsigned through with a key and no callback
        if t == "SET_ATTITUDE_TARGET":
            if m.target_system not in (0, self.sysid):
                return
            if self.first_setpoint_ms is None:
                self.first_setpoint_ms = self.time_ms
            sp = (now, int(m.type_mask), tuple(m.q), (m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate), float(m.thrust), self.mode,
                  bool(getattr(m, "_signed", False)))
            self.setpoints.append(sp)
            if self.mode in ("GUIDED", "GUIDED_NOGPS", "OFFBOARD"):
                self._last_sp = sp
        elif t == "COMMAND_LONG":
            if m.target_system not in (0, self.sysid):
                return
            params = (m.param1, m.param2, m.param3)
            self.commands.append((now, int(m.command), params))
            if m.command == mavlink.MAV_CMD_REQUEST_MESSAGE and int(m.param1) == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                self._ack(m.command, 0)
                major, minor, patch = self.version
                self.conn.mav.autopilot_version_send(0, (major << 24) | (minor << 16) | (patch << 8) | 255, 0, 0, 0, b"\0" * 8, b"\0" * 8, b"\0" * 8, 0, 0, 0)
            elif m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                limit = self.max_interval_rate_hz
                if limit is not None and 0 < m.param2 < 1e6 / limit - 1e-3:
                    self._ack(m.command, mavlink.MAV_RESULT_DENIED)
                    threading.Timer(self.reason_delay_s, self._send_chunked_text, (
                        f"Requested rate for message ID {int(m.param1)} too fast. Increase SCHED_LOOP_RATE",)).start()
                else:
                    self._ack(m.command, 0)
            elif m.command == mavlink.MAV_CMD_DO_SET_MODE:
                if self.autopilot == "ArduPilot":
                    names = {v: k for k, v in ACM_MODES.items()}
                    name = names.get(int(m.param2))
                else:
                    names = {v: k for k, v in PX4_MAIN.items()}
                    name = names.get(int(m.param2))
                    if name == "AUTO":
                        name = {3: "LOITER", 6: "LAND"}.get(int(m.param3), "AUTO")
                        name = name if name in PX4_MAIN else "AUTO"
                    if name == "OFFBOARD":
                        self.offboard_requests_ms.append(self.time_ms)
                    if name == "OFFBOARD" and (self.first_setpoint_ms is None or self.time_ms - self.first_setpoint_ms < self.prestream_floor_ms
                                               or now - self.setpoints[-1][0] > 0.5):
                        self._ack(m.command, mavlink.MAV_RESULT_TEMPORARILY_REJECTED)
                        return
                if name is None:
                    self._ack(m.command, mavlink.MAV_RESULT_FAILED)
                    return
                old_mode, self.mode = self.mode, name
                self._ack(m.command, 0)
                if self.late_heartbeat_after_mode_ack:  # PX4 after an ACK: one built before the switch comes first
                    self._heartbeats_held_until = now + 0.2
                    threading.Timer(0.1, self._late_heartbeat, (old_mode,)).start()
                else:
                    self._heartbeat()
            elif m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                self.armed = m.param1 == 1.0
                self._ack(m.command, 0)
            else:
                self._ack(m.command, mavlink.MAV_RESULT_UNSUPPORTED)
        elif t == "PARAM_REQUEST_READ":
            name = m.param_id
            if name in self.lose_first_param_reply:
                self.lose_first_param_reply.discard(name)
            elif name in self.params and (self.autopilot == "ArduPilot" or name in self.px4_params):
                self.conn.mav.param_value_send(name.encode(), self.params[name], mavlink.MAV_PARAM_TYPE_REAL32, len(self.params), 0)
        elif t == "PARAM_SET":
            self.params[m.param_id] = float(m.param_value)
            self.conn.mav.param_value_send(m.param_id.encode(), float(m.param_value), mavlink.MAV_PARAM_TYPE_REAL32, len(self.params), 0)

    def _plant(self, dt: float) -> None:
        sp = self._last_sp
        guided = self.mode in ("GUIDED", "GUIDED_NOGPS", "OFFBOARD")
        if sp is None or not guided or not self.armed:
            self.rates = [0.0, 0.0, 0.0]
            return
        _, mask, q, rates, thrust, _, _ = sp
        if mask == 0x80:
            target = list(rates)
        else:  # attitude (level) target: P loop on roll and pitch
            target = [-5.0 * self.att[0], -5.0 * self.att[1], 0.0]
        for i in range(3):
            self.rates[i] += (target[i] - self.rates[i]) * min(1.0, dt / 0.02)
            self.att[i] += self.rates[i] * dt
        self.att[2] = wrap_angle_float(self.att[2])
        if self.autopilot == "ArduPilot" and self.params["GUID_OPTIONS"] == 0:
            self.alt_m = max(0.0, self.alt_m + (thrust - 0.5) * 2.0 * 2.5 * dt)

    def _run(self) -> None:
        next_att = time.monotonic()
        next_hb = 0.0
        while not self._stop.is_set():
            while True:
                try:
                    m = self.conn.recv_msg()
                except Exception:
                    self.unsigned_or_bad += 1
                    continue
                if m is None:
                    break
                with self._lock:
                    self._handle(m)
            now = time.monotonic()
            with self._lock:
                if now >= next_hb and now >= self._heartbeats_held_until:
                    self._heartbeat()
                    next_hb = now + self.heartbeat_period_s
                if now >= next_att:
                    next_att += self.period_s
                    if next_att < now:
                        next_att = now + self.period_s
                    self.time_ms += int(round(self.period_s * 1000))
                    self._plant(self.period_s)
                    if not self.pause_attitude:
                        roll = self.force_roll_rad if self.force_roll_rad is not None else self.att[0]
                        if self.nan_attitude:
                            roll = float("nan")
                        self.conn.mav.attitude_send(self.time_ms, roll, self.att[1], self.att[2], *self.rates)
                        if self.hold_thrust_norm is not None and self.armed:
                            if self.mode != "OFFBOARD":
                                self._hold_target_ms = self.time_ms
                            if self._hold_target_ms is not None:
                                self.conn.mav.attitude_target_send(self._hold_target_ms, 0x00, [1.0, 0.0, 0.0, 0.0],
                                                                   0.0, 0.0, 0.0, self.hold_thrust_norm)
                        if self.foreign_attitude:
                            self.conn.write(self._foreign.attitude_encode(self.time_ms, 1.05, 0.0, 0.0, 0.0, 0.0, 0.0).pack(self._foreign))
                    if self.time_ms % 100 == 0:
                        self.conn.mav.global_position_int_send(self.time_ms, 0, 0, 0, int(self.alt_m * 1000), 0, 0, 0, 0)
                    if self.autopilot == "PX4" and self.time_ms % 20 == 0:  # PX4 streams its local estimate; at rest here
                        self.conn.mav.local_position_ned_send(self.time_ms, 0.0, 0.0, -self.alt_m, 0.0, 0.0, 0.0)
            self.conn.select(max(0.0, min(next_att, next_hb) - time.monotonic()))
