"""The MAVLink face of the simulated Solo: ArduCopter 4.2+ wire behaviour on top of ``SimulatedCopter``.

It turns datagrams into calls on the copter (modes, arming, SET_ATTITUDE_TARGET, parameters) and the copter's state
into telemetry, following docs/design-decisions.md, MAV-1 to MAV-7 and the checklist MAV-12:

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
  ``vehicle_telemetry.ProtocolVersionMessage`` because PyPI pymavlink's dialects lack it;
* the PARAM protocol over ``copter.params``; MISSION_REQUEST_LIST answered with an empty MISSION_COUNT;
* MAVLink 2 signing (key from a file or SETUP_SIGNING): unsigned or badly signed frames are dropped and counted.

Every class of bad input is counted in :attr:`MavlinkVehicle.counters` (names in ``BAD_INPUT_COUNTERS``)
and logged at DEBUG on the ``mavastsm_sim`` logger; nothing inbound can raise out of :meth:`handle_datagram`.

:class:`MavlinkVehicle` owns one part per job and wires them together; they share a :class:`VehicleLink`
(identity, sender, counters, clock, queued STATUSTEXTs, ``vehicle_link.py``): inbound parsing (``vehicle_inbound.py``),
commands and one-shot requests (``vehicle_commands.py``), the PARAM protocol (``vehicle_params.py``), the message
streams (``vehicle_streams.py``), the encoders of outgoing messages (``vehicle_telemetry.py``), the start-up
(``vehicle_startup.py``), SET_ATTITUDE_TARGET (``vehicle_targets.py``) and signing (``vehicle_signing.py``).

Units: SI inside (rad, rad/s, m, m/s); MAVLink units at the edge (cdeg, mm, cm/s, mV, us) converted in
``vehicle_telemetry.py``.
Frames: NED world, FRD body, quaternion [w, x, y, z] rotating NED to FRD, as in ``mavastsm.frames``.
Time: ``time_boot_ms`` and every timestamp come from the simulated time passed in by the caller.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from mavastsm.mavlink_datagram import parse_datagram
# The MAVLink 2 dialect module itself: every MAVLink object here is built from it, so the vehicle speaks MAVLink 2
# from its first byte without touching pymavlink's process-wide MAVLINK20 switch (it opens no mavutil connection).
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .vehicle_commands import CommandHandler
from .vehicle_inbound import DatagramReader
from .vehicle_link import AUTOPILOT_COMPONENT_ID, VehicleLink
from .vehicle_params import ParameterService
from .vehicle_signing import SigningSession
from .vehicle_startup import StartupSequence
from .vehicle_streams import StreamScheduler
from .vehicle_targets import AttitudeTargetIntake
from .vehicle_telemetry import TelemetryEncoder

TIMESYNC_REQUEST_INTERVAL_US = 10_000_000  # our own TIMESYNC request (tc1 = 0) every 10 s, as ArduPilot
DEFAULT_HOME = (-35.363261, 149.165230, 584.0)  # ArduPilot SITL default home (CMAC) [deg, deg, m AMSL]


class MavlinkVehicle:
    """ArduCopter-like MAVLink endpoint around a ``SimulatedCopter``: owns the parts and runs them in order.

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
        self.link = link = VehicleLink(copter, send_datagram)
        self.copter, self.profile, self.firmware = copter, link.profile, link.firmware
        self.mav, self.counters, self.sysid, self.compid = link.mav, link.counters, link.sysid, link.compid
        lat_deg, lon_deg, alt_m = (float(v) for v in home)
        self.startup = StartupSequence(link, alt_m, self._announce_origin)
        self.telemetry = TelemetryEncoder(link, self.startup, (lat_deg, lon_deg, alt_m), unix_time_at_boot_s)
        self.streams = StreamScheduler(link, self.telemetry.send_now)
        self.params = ParameterService(link)
        self.commands = CommandHandler(link, self.telemetry, self.streams, self.startup)
        self.targets = AttitudeTargetIntake(link)
        self.signing = SigningSession(link, signing_state)
        self.inbound = DatagramReader(link, {
            mavlink.MAVLINK_MSG_ID_SET_MODE: self.commands.on_set_mode,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self.params.on_request_read,
            mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self.params.on_request_list,
            mavlink.MAVLINK_MSG_ID_PARAM_SET: self.params.on_set,
            mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: self.commands.on_mission_request_list,
            mavlink.MAVLINK_MSG_ID_REQUEST_DATA_STREAM: self.streams.on_request_data_stream,
            mavlink.MAVLINK_MSG_ID_COMMAND_LONG: self.commands.on_command,
            mavlink.MAVLINK_MSG_ID_COMMAND_INT: self.commands.on_command,
            mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET: self.targets.on_set_attitude_target,
            mavlink.MAVLINK_MSG_ID_TIMESYNC: self._on_timesync,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION_REQUEST: self.commands.on_autopilot_version_request,
            mavlink.MAVLINK_MSG_ID_SETUP_SIGNING: self.signing.on_setup_signing,
            mavlink.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: self.commands.on_file_transfer_protocol,
        })
        self._next_timesync_us = TIMESYNC_REQUEST_INTERVAL_US
        self._was_armed = bool(copter.armed)
        self._last_mode = int(copter.mode_number)
        if signing_key is not None:
            self.signing.enable(signing_key)

    # ------------------------------------------------------------------ public API
    @property
    def attitude_targets_received(self) -> int:
        """SET_ATTITUDE_TARGETs addressed to us so far [count] (``AttitudeTargetIntake.received``)."""
        return self.targets.received

    @property
    def loop_tick_streams(self) -> bool:
        """True when streams go out on ArduCopter's loop ticks (``StreamScheduler.loop_tick_streams``)."""
        return self.streams.loop_tick_streams

    def bad_input_total(self) -> int:
        """Sum of all bad-input counters [count]."""
        return self.link.bad_input_total()

    def attitude_streaming(self) -> bool:
        """True while ATTITUDE is being streamed (the lockstep gate is active)."""
        return self.streams.effective_interval_us(mavlink.MAVLINK_MSG_ID_ATTITUDE) is not None

    def effective_interval_us(self, msg_id: int) -> int | None:
        """Interval at which ``msg_id`` is emitted now [us], after the loop-rate cap; None when off."""
        return self.streams.effective_interval_us(msg_id)

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
        self.link.now_us = now_us
        valid = self.inbound.read(data, on_first_valid)
        self._flush_side_effects()
        return valid

    def greet_new_peer(self) -> None:
        """Send a HEARTBEAT at once so a peer that just appeared learns our identity without waiting."""
        self.telemetry.send_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)

    def next_due_us(self, now_us: int) -> int:
        """Earliest simulated time [us] > ``now_us`` at which something is due to be sent."""
        if self.params.listing() or self.link.pending_texts or self.copter.statustext_queue:
            return now_us + 1
        due_us = self.streams.earliest_due_us(self._next_timesync_us)
        due_us = self.targets.earliest_due_us(self.params.earliest_due_us(due_us))
        return max(due_us, now_us + 1)

    def emit_due(self, now_us: int) -> bool:
        """Send everything due at simulated time ``now_us`` [us]; True if an ATTITUDE went out."""
        self.link.now_us = now_us
        self.signing.save_timestamp()
        self.targets.apply_due(now_us)
        self.startup.run(now_us)
        self._flush_side_effects()
        attitude_sent = self.streams.emit_due(now_us)
        self.params.emit_due(now_us)
        if now_us >= self._next_timesync_us:  # ArduPilot probes link latency with its own request every 10 s
            self._next_timesync_us += TIMESYNC_REQUEST_INTERVAL_US
            self.mav.timesync_send(0, now_us * 1000 + self.sysid)
        return attitude_sent

    # ------------------------------------------------------------------ helpers
    def _on_timesync(self, msg: Any) -> None:
        if msg.tc1 == 0:  # a request: answer at once with our receive time [ns]
            self.mav.timesync_send(self.link.now_us * 1000, msg.ts1)

    def _announce_origin(self) -> None:
        """The EKF origin is set: what is queued goes out, then HOME_POSITION and GPS_GLOBAL_ORIGIN."""
        self._flush_side_effects()
        self.telemetry.send_home_and_origin()

    def _flush_side_effects(self) -> None:
        """Send queued STATUSTEXTs and the extra HEARTBEAT after a mode change."""
        queue = self.copter.statustext_queue
        while self.link.pending_texts:
            self.link.send_statustext(*self.link.pending_texts.pop(0))
        while queue:
            severity, text = queue.pop(0)
            self.link.send_statustext(int(severity), str(text))
        mode = int(self.copter.mode_number)
        if mode != self._last_mode:
            self._last_mode = mode
            self.telemetry.send_now(mavlink.MAVLINK_MSG_ID_HEARTBEAT)
        armed = bool(self.copter.armed)
        if armed != self._was_armed:
            self._was_armed = armed
            if armed:  # ArduCopter sets home where it arms and announces it with the EKF origin
                self.telemetry.send_home_and_origin()


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
