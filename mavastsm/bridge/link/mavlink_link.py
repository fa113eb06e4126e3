"""The bridge's MAVLink link: with its request/reply half (``vehicle_requests``, reached as ``link.requests``:
commands and parameters, each awaiting its answer), the ONLY modules on the bridge side that import pymavlink.

One connection (any pymavlink URL: ``udpin:``/``udp:``, ``udpout:``, ``tcp:``, ``tcpin:``, a serial
device with ``baud``), MAVLink 2 from the first byte, our own identity (default: the vehicle's
sysid, compid 191) and 1 Hz HEARTBEAT, ONE reader thread that parses everything (no
``recv_match`` filtering), ONE locked sender, optional MAVLink 2 signing, and a ``.tlog`` of all
traffic in both directions (8-byte big-endian µs timestamp + packet, the MAVProxy format).

The reader thread calls ``on_attitude(AttitudeSample)`` for every ATTITUDE from the target
autopilot (system *and* component must match; ATTITUDE from other systems is counted and
ignored). When several ATTITUDE packets are already queued (a bursty scheduler), only the newest
is delivered (newest by vehicle time ``time_boot_ms``, not by arrival: a reordered older one is
counted in ``stats.out_of_order`` and discarded) and the superseded ones are counted in ``stats.superseded``.
"""

from __future__ import annotations

import collections
import dataclasses
import errno
import math
import os
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402  (constants and ids: MAVLink 2 whatever the import order)

from ... import signing  # noqa: E402
from ...mavlink_datagram import ANCILLARY_BYTES, arrival_monotonic_ns, enable_kernel_timestamps, parse_datagram  # noqa: E402
from ...errors import ConfigError, Interrupted, LinkError  # noqa: E402
from ...lockstep_turns import TurnCondition  # noqa: E402
from .messages import (  # noqa: E402
    AttitudeTarget,
    AutopilotVersion,
    GlobalPosition,
    LocalPosition,
    autopilot_version,
    global_position,
    local_position,
    AttitudeSample,
    HeartbeatInfo,
    StatusTextAssembler,
    TargetInMode,
    attitude_sample,
    attitude_target,
    heartbeat_info,
    is_vehicle_heartbeat,
    newest_attitude,
)
from .messages import Setpoint  # noqa: E402
from .vehicle_clock import VehicleClock  # noqa: E402
from .vehicle_requests import VehicleRequests  # noqa: E402


def _source_name(sender, msg) -> str:
    """Where a frame came from, for people: its UDP address when the link knows one, else its MAVLink 2 link id."""
    if sender is not None:
        return f"{sender[0]}:{sender[1]}"
    link_id = getattr(msg, "_link_id", None)
    return f"MAVLink link id {link_id}" if link_id is not None else "this link"


def use_mavlink2() -> None:
    """Make pymavlink's connections speak MAVLink 2 from their first byte; called before each connection.

    pymavlink keeps one process-wide dialect module (``mavutil.mavlink``), chosen from the ``MAVLINK20``
    environment variable when ``mavutil`` is imported and again by ``mavutil.set_dialect``; without it a
    connection sends MAVLink 1 until it hears a MAVLink 2 frame, and then sets the variable and switches itself.
    Signing, extensions and ids above 255 need MAVLink 2 from the start (docs/design-decisions.md, MAV-7, MAV-8),
    so the link selects it here, at connection time, the way pymavlink itself does: not as an import side effect.
    """
    if "MAVLINK20" not in os.environ or mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
        os.environ["MAVLINK20"] = "1"
        mavutil.set_dialect(mavutil.current_dialect)

HEARTBEAT_WAIT_SLICE_S = 0.1  # the heartbeat wait checks for an operator stop this often [s]
HEARTBEAT_TYPES = {"onboard_controller": mavlink.MAV_TYPE_ONBOARD_CONTROLLER, "gcs": mavlink.MAV_TYPE_GCS}
MSG_ID_ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
MSG_ID_ATTITUDE_TARGET = mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET
MSG_ID_GLOBAL_POSITION_INT = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
MSG_ID_AUTOPILOT_VERSION = mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
MSG_ID_LOCAL_POSITION_NED = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
ATTITUDE_TARGETS_KEPT = 512  # recent ATTITUDE_TARGETs kept with their mode: 10 s at the requested 50 Hz
MAV_CMD_NAV_TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF
MAV_CMD_DO_SET_MODE = mavlink.MAV_CMD_DO_SET_MODE


TLOG_MIN_RECORD_BYTES = 12  # pymavlink's tlog reader asks for 12 bytes after a MAVLink 2 frame


URL_FORMS = ("udpin:HOST:PORT, udpout:HOST:PORT, udp:HOST:PORT (= udpin), tcp:HOST:PORT, tcpin:HOST:PORT, a serial device "
             "(/dev/ttyACM0, COM3) with --baud, or MAVSDK's udp://[HOST]:PORT, udpin://, udpout://, tcp://HOST:PORT, "
             "serial:///dev/ttyACM0[:BAUD]")
_NET_SCHEMES = {"udpin": "udpin", "udp": "udpin", "udpout": "udpout", "udpbcast": "udpbcast", "tcp": "tcp", "tcpin": "tcpin"}


def parse_link_url(url: str, baud: int) -> tuple[str, int]:
    """The pymavlink connection string and baud rate for what a user typed as ``url``: pymavlink's own forms,
    or MAVSDK's (``udp://:14540`` listens on every interface, ``serial:///dev/ttyACM0:921600`` carries the baud).
    ConfigError naming the URL, the part that is wrong and the accepted forms."""
    text = url.strip()
    if text.startswith("serial://"):
        device, _, rate = text[len("serial://"):].partition(":")
        if not device:
            raise ConfigError(f"{url}: no serial device (accepted: {URL_FORMS})")
        if rate:
            if not rate.isdigit() or int(rate) <= 0:
                raise ConfigError(f"{url}: baud {rate!r} is not a positive integer (accepted: {URL_FORMS})")
            baud = int(rate)
        return device, baud
    scheme, sep, rest = text.partition("://")
    if sep:
        if scheme not in _NET_SCHEMES:
            raise ConfigError(f"{url}: unknown scheme {scheme!r} (accepted: {URL_FORMS})")
        host, _, port = rest.rpartition(":")
        host = host or "0.0.0.0"
        text = f"{_NET_SCHEMES[scheme]}:{host}:{port}"
    scheme, sep, rest = text.partition(":")
    if sep and scheme in _NET_SCHEMES:
        host, _, port = rest.rpartition(":")
        if not host:
            raise ConfigError(f"{url}: expected {scheme}:HOST:PORT (accepted: {URL_FORMS})")
        if not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ConfigError(f"{url}: port {port!r} is not an integer in 0..65535 (accepted: {URL_FORMS})")
        return text, baud
    if sep and not (text.startswith("/") or text[:3].upper() == "COM"):
        raise ConfigError(f"{url}: unknown scheme {scheme!r} (accepted: {URL_FORMS})")
    return text, baud  # a serial device path


UDP_MAX_DATAGRAM_BYTES = 65535
MAX_UDP_CLIENTS = 16  # udpin: most senders answered before the target autopilot is known
TARGET_ADDRESS_SILENT_S = 1.0  # [s] the target's address must be this quiet before its id is followed to another


class _DatagramReceiver:
    """``recv_msg`` for a pymavlink UDP connection that keeps datagram boundaries (pymavlink's does not).

    pymavlink parses UDP as one byte stream: a datagram that ends inside a frame (a truncated or forged
    header) makes the parser take the start of the *next* datagram, a genuine ATTITUDE or HEARTBEAT, as the
    rest of that frame. Here every frame of a datagram is parsed and whatever is left is dropped (counted
    as truncated_frames), so junk can cost only itself. Each message remembers its sender (``_mavastsm_from``)
    and pymavlink's own sender bookkeeping (udpin's ``clients``, to which every send goes) is not done: the
    link's reader tells it, frame by frame, which address is the target's (:meth:`second_address`) and who
    hears what we send (:meth:`note_sender`). Each message also remembers when its datagram arrived
    (``_mavastsm_rx_ns``, host monotonic [ns]): the kernel's receive time where the socket gives it (Linux), so the time
    a datagram waited while the reader was busy counts in the bridge's latency and ``late``.
    """

    def __init__(self, conn, stats: "LinkStats") -> None:
        self.conn = conn
        self.stats = stats
        self.kernel_timestamps = enable_kernel_timestamps(conn.port)
        self.queue: collections.deque = collections.deque()
        self.datagrams = 0  # received so far (lockstep turns: what the sim sent and the reader has taken in)
        self.target_addr = None  # the address the target's frames come from
        self.target_heard_at = 0.0  # [s, host monotonic] last frame from it

    def recv_msg(self):
        if self.queue:
            return self.queue.popleft()
        conn = self.conn
        try:
            if self.kernel_timestamps:
                data, ancdata, _flags, addr = conn.port.recvmsg(UDP_MAX_DATAGRAM_BYTES, ANCILLARY_BYTES)
                rx_ns = arrival_monotonic_ns(ancdata)
            else:
                data, addr = conn.port.recvfrom(UDP_MAX_DATAGRAM_BYTES)
                rx_ns = time.monotonic_ns()
        except (BlockingIOError, InterruptedError):
            return None
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return None
            raise
        self.datagrams += 1
        msgs, cut = parse_datagram(conn.mav, data)
        if cut:  # the datagram ended inside a frame: its rest was dropped, never joined to the next
            self.stats.bad_data += 1
            self.stats.refused["truncated_frames"] += 1
        for msg in msgs:
            msg._mavastsm_from = addr
            msg._mavastsm_rx_ns = rx_ns
            conn.post_message(msg)
        self.queue.extend(msgs)
        return self.queue.popleft() if self.queue else None

    def second_address(self, addr, msg, target_system: int | None) -> bool:
        """True for a frame with the target's system id from another address than the target's while that one is
        still heard (within TARGET_ADDRESS_SILENT_S); otherwise the frame's address becomes (or stays) the target's."""
        if target_system is None or msg.get_srcSystem() != target_system or msg.get_type() == "BAD_DATA":
            return False
        now = time.monotonic()
        if self.target_addr is not None and addr != self.target_addr and now - self.target_heard_at <= TARGET_ADDRESS_SILENT_S:
            return True
        self.target_addr, self.target_heard_at = addr, now
        return False

    def follow(self, addr) -> None:
        """The target restarted on ``addr`` (the link's vehicle clock confirmed it): its address from now on."""
        self.target_addr, self.target_heard_at = addr, time.monotonic()

    def note_sender(self, addr, msg, target_system: int | None) -> None:
        """udpin: who receives what we send. Once the target autopilot is known, only the address its frames
        come from (a sender of junk, or of valid frames from another system, never gets our setpoints);
        before, up to MAX_UDP_CLIENTS senders of valid frames, so the autopilot hears our HEARTBEAT."""
        conn = self.conn
        if target_system is not None and msg.get_srcSystem() == target_system:
            # the target's address (second_address keeps a second one out while the first still talks)
            if len(conn.clients) != 1 or addr not in conn.clients:
                conn.clients = {addr}
                conn.clients_last_alive = {addr: time.time()}
        elif target_system is None and addr not in conn.clients and len(conn.clients) < MAX_UDP_CLIENTS:
            conn.clients.add(addr)
            conn.clients_last_alive[addr] = time.time()


def _data_waiting(conn) -> bool:
    """More bytes wait on ``conn``'s descriptor now (False for a connection without one)."""
    fd = getattr(conn, "fd", None)
    if fd is None:
        return False
    try:
        return conn.select(0.0)
    except Exception:
        return False


def _make_realtime(thread: threading.Thread, prio: int) -> None:
    """SCHED_FIFO at ``prio`` for ``thread`` only (Linux: a thread id is a valid pid here)."""
    try:
        os.sched_setscheduler(thread.native_id, os.SCHED_FIFO, os.sched_param(prio))
    except AttributeError:
        raise ConfigError(f"timing.realtime_priority={prio}: SCHED_FIFO is not available on this platform (Linux only); set 0") from None
    except OSError as exc:
        raise ConfigError(f"timing.realtime_priority={prio}: SCHED_FIFO refused ({exc.strerror or exc}); "
                          f"run with CAP_SYS_NICE or an RLIMIT_RTPRIO >= {prio} (ulimit -r), or set 0") from None


def unhealthy_sensors(msg) -> list[str]:
    """SYS_STATUS -> the subsystems it reports present and enabled but not healthy, by their MAVLink names without
    the prefix (``AHRS``, ``SENSOR_3D_MAG``, ``PREARM_CHECK``); the bit in hex for one the dialect does not name."""
    failing = int(msg.onboard_control_sensors_present) & int(msg.onboard_control_sensors_enabled) & ~int(msg.onboard_control_sensors_health)
    names = mavlink.enums["MAV_SYS_STATUS_SENSOR"]
    return [names[bit].name.removeprefix("MAV_SYS_STATUS_") if bit in names else hex(bit)
            for bit in (1 << i for i in range(31)) if failing & bit]


def _thread_scheduling(thread: threading.Thread | None) -> str:
    """How ``thread`` is scheduled, in words."""
    try:
        if thread is not None and os.sched_getscheduler(thread.native_id) == os.SCHED_FIFO:
            return f"SCHED_FIFO priority {os.sched_getparam(thread.native_id).sched_priority}"
    except (AttributeError, OSError):
        pass
    return "normal (timing.realtime_priority 0)"


def _post_message_without_caches(msg) -> None:
    """Replaces ``mavfile.post_message`` on our connection. pymavlink's keeps the last message of every type,
    instance ("NAMED_VALUE_FLOAT[name]") and source system, and every PARAM_VALUE by name, none of which this
    link reads (it keeps its own ``latest`` per type): with hostile traffic 60 000 distinct names cost 79 MB.
    Only the two attributes other pymavlink code expects on a received message are set."""
    msg._posted = True
    msg._timestamp = time.time()


def read_tlog_flight(path: str | Path) -> tuple[list[tuple], list[tuple]]:
    """What ``mavastsm plot`` and ``identify`` read from a .tlog when the CSV is absent: the autopilot's ATTITUDE and
    the bridge's SET_ATTITUDE_TARGET, each as rows ``(record time [s, unix], ...)``: ``attitude`` (8 each) = (t, roll,
    pitch, yaw [rad], p, q, r [rad/s, body FRD], time_boot_ms [ms, vehicle]); ``setpoints`` (6 each) = (t, type_mask,
    p, q, r [rad/s], thrust [0..1]). The record time (the .tlog's own timestamp) is the clock both share.
    ConfigError (one line) for an unreadable file or one without ATTITUDE."""
    out: dict[str, list] = {"attitude": [], "setpoints": []}
    try:
        reader = mavutil.mavlink_connection(str(path), robust_parsing=True)
        try:
            while (msg := reader.recv_match(type=["ATTITUDE", "SET_ATTITUDE_TARGET"])) is not None:
                t = float(getattr(msg, "_timestamp", 0.0))
                if msg.get_type() == "ATTITUDE":
                    out["attitude"].append((t, msg.roll, msg.pitch, msg.yaw, msg.rollspeed, msg.pitchspeed, msg.yawspeed, msg.time_boot_ms))
                else:
                    out["setpoints"].append((t, int(msg.type_mask), msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate, msg.thrust))
        finally:
            reader.close()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not out["attitude"]:
        raise ConfigError(f"{path}: no ATTITUDE in this .tlog")
    return out["attitude"], out["setpoints"]


class TlogWriter:
    """Thread-safe .tlog writer (both directions), buffered; ``flush()`` from a timer.

    It records every frame that parsed (the reader thread never passes BAD_DATA), except a MAVLink 1 frame
    shorter than TLOG_MIN_RECORD_BYTES: after a MAVLink 2 frame, pymavlink's tlog reader
    (``mavutil.mavlink_connection(path)``, ``mavlogdump.py``) reads 12 bytes for the next frame, so a shorter
    record throws it out of sync for the rest of the file (one 11-byte frame cost 11 records in a test). Such
    frames (a MAVLink 1 payload under 4 bytes; no MAVLink 2 frame is that short) are counted in ``skipped``
    instead, so the file reads back to its last record.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        self._f = open(path, "wb", buffering=64 * 1024)
        self._lock = threading.Lock()
        self.skipped = 0

    def write(self, packet: bytes) -> None:
        if len(packet) < TLOG_MIN_RECORD_BYTES:
            self.skipped += 1
            return
        usec = int(time.time() * 1.0e6) & ~3
        with self._lock:
            if not self._f.closed:
                self._f.write(struct.pack(">Q", usec) + packet)

    def flush(self) -> None:
        with self._lock:
            if not self._f.closed:
                self._f.flush()

    def close(self) -> None:
        with self._lock:
            if not self._f.closed:
                self._f.flush()
                self._f.close()


@dataclass
class LinkStats:
    """Counters kept by the reader thread."""

    received: int = 0
    attitude: int = 0
    superseded: int = 0
    out_of_order: int = 0  # queued ATTITUDE older (vehicle time) than one already pending: discarded
    foreign_attitude: int = 0  # ATTITUDE from another system or component than the target (once the target is known)
    bad_data: int = 0
    # refused frames by class (mavastsm.signing.REFUSED_FRAME_CLASSES); their sum is bad_data
    refused: collections.Counter = field(default_factory=collections.Counter)
    sent_setpoints: int = 0
    reader_errors: int = 0
    # the vehicle's reassembled texts: (host monotonic s, severity, text), newest last
    statustext: collections.deque = field(default_factory=lambda: collections.deque(maxlen=50))


class MavlinkLink:
    """One MAVLink connection to one autopilot.

    Parameters
    ----------
    url : pymavlink connection string (udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:, /dev/ttyUSB0 ...)
    baud : serial baud rate [bit/s]
    source_system : our sysid; None = the vehicle's sysid once its HEARTBEAT is heard (1 before that)
    source_component : our compid (191 = ONBOARD_COMPUTER)
    heartbeat_type : "onboard_controller" (MAV_TYPE 18) or "gcs" (6); autopilot field INVALID (8)
    target_system : the autopilot's sysid to control; None = the first autopilot heard
    signing_key : 32-byte key -> MAVLink 2 signing of everything we send; unsigned input rejected
    tlog_path : write all traffic here
    realtime_priority : SCHED_FIFO priority (1-99) of the reader thread (which runs the control cycle); 0 = normal
    turns : ``mavastsm.lockstep_turns.LockstepTurns`` of an in-process lockstep sim (UDP), or None
    """

    def __init__(
        self,
        url: str,
        *,
        baud: int = 115200,
        source_system: int | None = None,
        source_component: int = 191,
        heartbeat_type: str = "onboard_controller",
        target_system: int | None = None,
        signing_key: bytes | None = None,
        tlog_path: str | Path | None = None,
        realtime_priority: int = 0,
        turns=None,
    ) -> None:
        self.url = url
        self.turns = turns
        self.baud = baud
        self._explicit_source_system = source_system
        self.source_component = source_component
        self.heartbeat_mav_type = HEARTBEAT_TYPES[heartbeat_type]
        self.target_system = target_system
        self.target_component = 1
        self.signing_key = signing_key
        self.tlog = TlogWriter(tlog_path) if tlog_path else None
        self.realtime_priority = realtime_priority
        self.stats = LinkStats()
        self.clock = VehicleClock()  # the target's ATTITUDE clock as a stream (reader thread only)
        self.on_attitude: Callable[[AttitudeSample], None] | None = None
        self.last_heartbeat: HeartbeatInfo | None = None
        self.last_heartbeat_monotonic = float("nan")
        self.heartbeat_count = 0
        self.on_heartbeat: Callable[[HeartbeatInfo], None] | None = None
        self.latest: dict[str, object] = {}  # type -> latest message from the target (non-ATTITUDE)
        # the target's recent ATTITUDE_TARGETs with the mode they arrived in (PX4's hover measurement, preflight)
        self._targets: collections.deque[TargetInMode] = collections.deque(maxlen=ATTITUDE_TARGETS_KEPT)
        self.autopilot_target: AttitudeTarget | None = None  # the latest, decoded once, handed on with each ATTITUDE sample
        self.on_text: Callable[[int, str], None] | None = None  # each reassembled vehicle text (reader thread)
        self._texts = StatusTextAssembler()
        self._conn = None
        self._send_lock = threading.Lock()
        self._cond = TurnCondition(turns)  # a plain Condition without turns
        self._stop = threading.Event()
        self.requests = VehicleRequests(self, self._cond, self._stop)  # commands and parameters, answers awaited
        self._threads: list[threading.Thread] = []
        self._reader: threading.Thread | None = None  # the thread that parses everything and runs on_attitude
        self._boot = time.monotonic()

    # ------------------------------------------------------------------ lifecycle
    def open(self, heartbeat_wait_s: float, stop: threading.Event | None = None,
             progress: Callable[[str], None] | None = None) -> HeartbeatInfo:
        """Connect, start the reader and heartbeat threads, and wait for the autopilot's HEARTBEAT.

        Raises LinkError naming the URL when the connection cannot be made or nothing answers, and
        ConfigError when the operating system refuses ``realtime_priority`` (before waiting).
        """
        src = self._explicit_source_system or self.target_system or 1
        use_mavlink2()
        try:
            self._conn = mavutil.mavlink_connection(
                self.url, baud=self.baud, source_system=src, source_component=self.source_component, autoreconnect=True,
                retries=1,  # one TCP connect attempt: pymavlink's retries print "Connection refused sleeping" and wait 1 s each
            )
        except Exception as exc:  # pymavlink raises assorted OSError/SerialException types
            raise LinkError(f"{self.url}: cannot open ({exc})") from None
        self._conn.post_message = _post_message_without_caches
        self._receiver = _DatagramReceiver(self._conn, self.stats) if isinstance(self._conn, mavutil.mavudp) else self._conn
        if self.signing_key is not None:
            self._conn.setup_signing(self.signing_key, sign_outgoing=True)
            signing.harden(self._conn.mav)
        self._reader = self._start_thread(self._reader_loop, "mavlink-reader")
        self._start_thread(self._heartbeat_loop, "mavlink-heartbeat")
        if self.realtime_priority > 0:
            try:
                _make_realtime(self._reader, self.realtime_priority)
            except ConfigError:
                self.close()
                raise
        who = f"system {self.target_system}" if self.target_system else "any autopilot"
        start = time.monotonic()
        deadline = start + heartbeat_wait_s
        next_note = start + 1.0
        while True:
            with self._cond:
                # short slices: an operator stop ends the wait within HEARTBEAT_WAIT_SLICE_S
                self._cond.wait_for(lambda: self.last_heartbeat is not None, HEARTBEAT_WAIT_SLICE_S)
                heard = self.last_heartbeat
            now = time.monotonic()
            if heard is not None:
                return heard
            if stop is not None and stop.is_set():
                self.close()
                raise Interrupted(f"while waiting for a HEARTBEAT from {who} on {self.url} ({now - start:.1f} s)")
            if now >= deadline:
                self.close()
                raise LinkError(f"{self.url}: no HEARTBEAT from {who} within {heartbeat_wait_s:g} s "
                                "(is the autopilot sending to this address? link.heartbeat_wait_s sets the wait)")
            if progress is not None and now >= next_note:
                progress(f"waiting for a HEARTBEAT from {who} on {self.url} … {now - start:.0f} s")
                next_note += 1.0

    def close(self) -> None:
        """Stop threads, close the connection and the tlog. Safe to call twice."""
        self._stop.set()
        if self.turns is not None:  # the vehicle no longer waits for us
            self.turns.close()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads.clear()
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:  # the socket or port is already gone: closed either way; counted, not hidden
                self.stats.reader_errors += 1
            self._conn = None
        if self.tlog is not None:
            self.tlog.close()

    @property
    def source_system(self) -> int:
        return self._conn.mav.srcSystem if self._conn is not None else (self._explicit_source_system or 1)

    @property
    def signing(self) -> bool:
        return self.signing_key is not None

    def _start_thread(self, target, name: str) -> threading.Thread:
        t = threading.Thread(target=target, name=name, daemon=True)
        t.start()
        self._threads.append(t)
        return t

    @property
    def reader_scheduling(self) -> str:
        """How the reader (control) thread is scheduled, for the preflight summary."""
        return _thread_scheduling(self._reader)

    def time_boot_ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF

    # ------------------------------------------------------------------ threads
    def _heartbeat_loop(self) -> None:
        while not self._stop.is_set():
            try:
                with self._send_lock:
                    self._send(self._conn.mav.heartbeat_encode(self.heartbeat_mav_type, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE))
            except Exception:
                self.stats.reader_errors += 1
            self._stop.wait(1.0)

    def _reader_loop(self) -> None:
        conn = self._conn
        pending: AttitudeSample | None = None
        turns = self.turns if isinstance(self._receiver, _DatagramReceiver) else None
        while not self._stop.is_set():
            if turns is not None and not self._receiver.queue:  # every datagram so far handled: the sim may move
                turns.settle(self._stop.is_set)
                turns.reader_handled(self._receiver.datagrams)
            try:
                msg = self._receiver.recv_msg()
            except Exception:  # signature failures, socket errors: count and continue
                self.stats.reader_errors += 1
                msg = None
                if self._stop.wait(0.01):
                    break
            if msg is None:
                if pending is not None:
                    self._deliver(pending)
                    pending = None
                    continue
                conn.select(0.05)
                continue
            rx_ns = getattr(msg, "_mavastsm_rx_ns", None) or time.monotonic_ns()  # a datagram's arrival, else now
            self.stats.received += 1
            if self.tlog is not None and msg.get_type() != "BAD_DATA":
                self.tlog.write(msg.get_msgbuf())
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                self.stats.bad_data += 1
                self.stats.refused[signing.classify_bad_data(msg, conn.mav)] += 1
                continue
            sender = getattr(msg, "_mavastsm_from", None)
            adopted = False  # this ATTITUDE confirmed a restarted autopilot on a new address (and its clock)
            if sender is not None and self._receiver.second_address(sender, msg, self.target_system):
                if mtype != "ATTITUDE" or not self._adopt_second_address(sender, msg, rx_ns):
                    continue
                adopted = True
            if sender is not None and conn.udp_server:
                self._receiver.note_sender(sender, msg, self.target_system)
            if mtype == "ATTITUDE":
                pending = self._on_attitude_frame(msg, rx_ns, sender, adopted, pending, turns)
                continue
            try:
                self._handle_other(msg, mtype)
            except Exception:
                self.stats.reader_errors += 1

    def _adopt_second_address(self, sender, msg, rx_ns: int) -> bool:
        """An ATTITUDE with the target's id from another address than the target's, which talked lately: a second
        vehicle (or a forger), never mixed with the first, named once it keeps at it (counted foreign, False); or the
        autopilot restarted on a new port, followed once its stream confirms it with the old address silent
        (vehicle_clock): the new address becomes the target's (True)."""
        if not self.clock.second_source(int(msg.time_boot_ms), rx_ns, _source_name(sender, msg),
                                        int(self._receiver.target_heard_at * 1e9)):
            self.stats.foreign_attitude += 1
            return False
        self._receiver.follow(sender)
        return True

    def _on_attitude_frame(self, msg, rx_ns: int, sender, adopted: bool, pending: AttitudeSample | None,
                           turns) -> AttitudeSample | None:
        """One ATTITUDE frame on the reader thread: the target's only, in the vehicle's clock, delivered now (alone
        in the socket, or with lockstep turns) or kept as the burst's newest; returns the sample still pending."""
        if not self._from_target(msg):
            if self.target_system is not None:  # before the first HEARTBEAT nobody is foreign yet (PX4 streams first)
                self.stats.foreign_attitude += 1
            return pending
        self.stats.attitude += 1
        sample = attitude_sample(msg, rx_ns, self.autopilot_target)  # ATTITUDE_TARGET is read on this thread too
        if not all(math.isfinite(v) for v in sample.euler_rad + sample.body_rates_rads):
            # never a replacement for (or replaced by) a pending sample: straight on to be validated and counted as
            # invalid by the session, after the valid one that arrived before it (the session's INVALID_INPUT counts
            # consecutive invalid samples in arrival order: a burst NaN, valid, NaN, valid, NaN delivered NaN-first
            # looked like three in a row)
            if pending is not None:
                self._deliver(pending)
            self._deliver(sample)
            return None
        if not adopted and not self.clock.offer(sample.time_boot_ms, rx_ns, _source_name(sender, msg)):
            return pending  # out of the vehicle's clock: held until confirmed, or an outlier (vehicle_clock)
        if turns is not None:  # the waits this sample ends run first: their commands precede its answer
            turns.vehicle_sample(sample.time_boot_ms / 1000.0)
            turns.settle(self._stop.is_set)
            self._deliver(sample)
            return pending
        if pending is not None:
            newest = newest_attitude(pending, sample)
            if newest is pending:
                self.stats.out_of_order += 1
            else:
                self.stats.superseded += 1
                newest = dataclasses.replace(newest, superseded=pending.superseded + 1,
                                             burst_start_ns=pending.burst_start_ns or pending.rx_ns)
            sample = newest
        if not (getattr(self._receiver, "queue", None) or _data_waiting(self._conn)):
            self._deliver(sample)
            return None
        return sample

    def _deliver(self, sample: AttitudeSample) -> None:
        cb = self.on_attitude
        if sample.autopilot_target is not self.autopilot_target:  # a burst's sample kept while a newer target came in
            sample = dataclasses.replace(sample, autopilot_target=self.autopilot_target)
        if cb is not None:
            try:
                cb(sample)
            except Exception:  # the control cycle must never kill the reader
                self.stats.reader_errors += 1

    def _from_target(self, msg) -> bool:
        return msg.get_srcSystem() == self.target_system and msg.get_srcComponent() == self.target_component

    def _handle_other(self, msg, mtype: str) -> None:
        if mtype == "HEARTBEAT":
            if not is_vehicle_heartbeat(msg):
                return
            if self.target_system is None:
                self.target_system = msg.get_srcSystem()
                self.target_component = msg.get_srcComponent()
                if self._explicit_source_system is None:
                    self._conn.mav.srcSystem = self.target_system
            if msg.get_srcSystem() != self.target_system:
                return
            if self.last_heartbeat is None:
                self.target_component = msg.get_srcComponent()
            elif msg.get_srcComponent() != self.target_component:
                return
            info = heartbeat_info(msg, mavutil.mode_string_v10(msg), time.time())
            with self._cond:
                self.last_heartbeat = info
                self.last_heartbeat_monotonic = time.monotonic()
                self.heartbeat_count += 1
                self._cond.notify_all()
            cb = self.on_heartbeat
            if cb is not None:
                cb(info)
            return
        if self.target_system is None or msg.get_srcSystem() != self.target_system:
            return
        if mtype == "COMMAND_ACK":
            if getattr(msg, "target_system", 0) not in (0, self.source_system):
                return
            self.requests.ack_received(int(msg.command), int(msg.result))
        elif mtype == "PARAM_VALUE":
            self.requests.param_value_received(str(msg.param_id), float(msg.param_value))
        elif mtype == "STATUSTEXT":
            now = time.monotonic()
            for severity, text in self._texts.add(int(msg.severity), str(msg.text), int(getattr(msg, "id", 0) or 0),
                                                   int(getattr(msg, "chunk_seq", 0) or 0)):
                with self._cond:
                    self.stats.statustext.append((now, severity, text))
                    self._cond.notify_all()
                cb = self.on_text
                if cb is not None:
                    cb(severity, text)
        with self._cond:
            self.latest[mtype] = msg
            if mtype == "ATTITUDE_TARGET":
                hb = self.last_heartbeat
                self.autopilot_target = attitude_target(msg)
                self._targets.append(TargetInMode(self.autopilot_target, hb.mode if hb else "", hb is not None and hb.armed))
            if mtype == "AUTOPILOT_VERSION":
                self._cond.notify_all()

    # ------------------------------------------------------------------ sending
    @property
    def mav(self):
        """The pymavlink encoder (this link's and its requests'); LinkError (one line) once the link is closed or
        lost, never AttributeError."""
        conn = self._conn
        if conn is None:
            raise LinkError(f"{self.url}: link closed")
        return conn.mav

    def _send(self, msg) -> None:
        """Caller holds ``_send_lock``. A socket error (the peer vanished: ECONNREFUSED on a udpout, a serial device
        unplugged) is a LinkError naming the URL, which every caller of the link already handles."""
        try:
            self.mav.send(msg)
        except OSError as exc:
            raise LinkError(f"{self.url}: send failed ({exc.strerror or exc})") from None
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf())

    def recent_attitude_targets(self) -> list[TargetInMode]:
        """The target's last ATTITUDE_TARGETs (at most ATTITUDE_TARGETS_KEPT, oldest first), each with the mode and
        arming of the HEARTBEAT before it."""
        with self._cond:
            return list(self._targets)

    def autopilot_version(self) -> AutopilotVersion | None:
        """The target's latest AUTOPILOT_VERSION as a typed value (None before the first)."""
        msg = self.latest.get("AUTOPILOT_VERSION")
        return autopilot_version(msg) if msg is not None else None

    def global_position(self) -> GlobalPosition | None:
        """The target's latest GLOBAL_POSITION_INT as a typed value in metres (None before the first)."""
        msg = self.latest.get("GLOBAL_POSITION_INT")
        return global_position(msg) if msg is not None else None

    def local_position(self) -> LocalPosition | None:
        """The target's latest LOCAL_POSITION_NED as a typed value (None before the first)."""
        msg = self.latest.get("LOCAL_POSITION_NED")
        return local_position(msg) if msg is not None else None

    def unhealthy_sensors(self) -> list[str] | None:
        """The target's latest SYS_STATUS as the subsystems it reports unhealthy; None before the first."""
        msg = self.latest.get("SYS_STATUS")
        return unhealthy_sensors(msg) if msg is not None else None

    def send_setpoint(self, sp: Setpoint) -> None:
        """SET_ATTITUDE_TARGET to the target autopilot (checked by the caller against the limits)."""
        msg = self.mav.set_attitude_target_encode(
            self.time_boot_ms(), self.target_system, self.target_component, sp.type_mask,
            sp.q_wxyz, sp.body_rates_rads[0], sp.body_rates_rads[1], sp.body_rates_rads[2], sp.thrust_norm,
        )
        with self._send_lock:
            self._send(msg)
            self.stats.sent_setpoints += 1

    def send_message(self, msg) -> None:
        with self._send_lock:
            self._send(msg)

    def flush(self) -> None:
        if self.tlog is not None:
            self.tlog.flush()

    def seconds_since_heartbeat(self) -> float:
        return time.monotonic() - self.last_heartbeat_monotonic
