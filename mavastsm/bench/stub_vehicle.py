"""A minimal ArduCopter-like MAVLink peer that streams ATTITUDE at a fixed rate and times the replies.

Bench code acting as a vehicle (a pymavlink peer, like the tests' doubles): it is not the simulator
(``mavastsm_sim``) and has no physics. It exists so that our bridge, a naive pymavlink loop and
MAVSDK can be timed by the same outside observer on the same wire.

What it does
------------
- Binds a UDP socket on 127.0.0.1 (port 0 = ephemeral); the client talks first (any packet, e.g.
  its HEARTBEAT) and from then on the stub sends to the address it last heard from.
- Streams ATTITUDE (and, if asked, ATTITUDE_QUATERNION with the same content right after it) at
  ``rate_hz`` from its own thread.
  Sample k carries ``time_boot_ms = TIME_BOOT_OFFSET_MS + k*1000//rate_hz`` (vehicle time,
  unique per sample up to 1 kHz, the resolution of the field) and a roll angle from ``attitude``:
  ``roll_code_rad(k)`` or a tiny sine (see ``ATTITUDE_PATTERNS``).
- Sends HEARTBEAT at 1 Hz (QUADROTOR, ARDUPILOTMEGA, GUIDED custom_mode 4, armed by default).
- Timestamps every received datagram with the kernel's receive time (``SO_TIMESTAMPNS``, Linux), so
  the stub's own scheduling delays (it shares 2 cores with the client) do not inflate the latency;
  send times then come from the same clock (``time.time_ns()``, taken just before ``sendto``).
  Without kernel timestamps it falls back to ``time.perf_counter_ns()`` right after ``recvfrom``.
  SET_ATTITUDE_TARGET goes to a ``CyclePairing`` (``bench_latency``).
- ACKs what clients need to run: COMMAND_LONG/INT 511 SET_MESSAGE_INTERVAL, 512 REQUEST_MESSAGE,
  520 REQUEST_AUTOPILOT_CAPABILITIES (then AUTOPILOT_VERSION 4.5.0), 176 DO_SET_MODE, 400 arm/disarm,
  SET_MODE (ACK command 11), PARAM_REQUEST_READ/LIST/SET over a small parameter table
  (GUID_OPTIONS 0, GUID_TIMEOUT 3 s, ...), TIMESYNC. Other commands get ACK UNSUPPORTED.
  It does not honour the requested stream rate: the rate is the experiment's fixed input.

Measurement window: starts ``warmup_s`` after the first SET_ATTITUDE_TARGET, lasts ``duration_s``;
``cpu_probe()`` (e.g. the client process's CPU seconds) is sampled at both ends.
"""

from __future__ import annotations

import math
import select
import socket
import threading
import time
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # MAVLink 2 by construction (no mavutil, no MAVLINK20)

from ..mavlink_datagram import enable_kernel_timestamps, kernel_receive_ns
from .latency import CyclePairing, LatencyStats, PairingRule, roll_code_rad

#: [ms] first sample's time_boot_ms: far from any client's own uptime so ECHO pairing cannot collide.
TIME_BOOT_OFFSET_MS = 100_000_000
GUIDED = 4
#: "roll_code": roll = roll_code_rad(seq) (decodable by the P-law baselines); "small_sine": roll =
#: SMALL_SINE_AMPLITUDE_RAD sin(2 pi SMALL_SINE_HZ t) with the matching roll rate plus an alternating
#: +-RATE_DITHER_RADS: a near-level vehicle that keeps a feedback controller such as ASTSM inside its sliding
#: band (no adaptive-gain wind-up against a plant that never responds), while consecutive samples always
#: differ, so consecutive commands differ too (ARRIVAL pairing treats a bit-identical command as a keep-alive).
ATTITUDE_PATTERNS = ("roll_code", "small_sine")
SMALL_SINE_AMPLITUDE_RAD = 1e-4
SMALL_SINE_HZ = 0.5
RATE_DITHER_RADS = 1e-4

STUB_PARAMS: dict[str, tuple[float, int]] = {  # name -> (value, MAV_PARAM_TYPE)
    "SYSID_THISMAV": (1.0, mavlink2.MAV_PARAM_TYPE_INT16),
    "FRAME_CLASS": (1.0, mavlink2.MAV_PARAM_TYPE_INT8),
    "FRAME_TYPE": (1.0, mavlink2.MAV_PARAM_TYPE_INT8),
    "GUID_OPTIONS": (0.0, mavlink2.MAV_PARAM_TYPE_INT32),
    "GUID_TIMEOUT": (3.0, mavlink2.MAV_PARAM_TYPE_REAL32),
    "DISARM_DELAY": (10.0, mavlink2.MAV_PARAM_TYPE_INT16),
    "SCHED_LOOP_RATE": (1000.0, mavlink2.MAV_PARAM_TYPE_INT16),
    "MOT_THST_HOVER": (0.35, mavlink2.MAV_PARAM_TYPE_REAL32),
    "WPNAV_SPEED_UP": (250.0, mavlink2.MAV_PARAM_TYPE_REAL32),
    "WPNAV_SPEED_DN": (150.0, mavlink2.MAV_PARAM_TYPE_REAL32),
}


@dataclass(frozen=True)
class StubRunResult:
    """What one stub run measured."""

    rate_hz: float
    stats: LatencyStats | None
    #: [s] client CPU (``cpu_probe`` delta) over the window divided by its samples, in microseconds
    cpu_per_cycle_us: float
    window_wall_s: float
    commands_seen: dict
    error: str = ""


class StubVehicle:
    """Fixed-rate ATTITUDE source and latency observer (see module docstring).

    Parameters
    ----------
    rate_hz : ATTITUDE rate [Hz], 1..1000.
    rule : how replies are paired with samples (``PairingRule``).
    duration_s, warmup_s : measurement window length and delay after the first reply [s].
    cpu_probe : callable returning the client's CPU seconds, sampled at the window edges.
    armed : start armed (a vehicle already flying in GUIDED) or disarmed.
    """

    def __init__(self, rate_hz: float, rule: PairingRule, duration_s: float = 5.0, warmup_s: float = 1.0,
                 cpu_probe: Callable[[], float] | None = None, armed: bool = True,
                 send_quaternion: bool = False, attitude: str = "roll_code") -> None:
        if not 1.0 <= rate_hz <= 1000.0:
            raise ValueError(f"rate_hz must be in 1..1000 (time_boot_ms has 1 ms resolution), got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.pairing = CyclePairing(rule)
        self.duration_s = duration_s
        self.warmup_s = warmup_s
        self.cpu_probe = cpu_probe
        self.send_quaternion = send_quaternion
        if attitude not in ATTITUDE_PATTERNS:
            raise ValueError(f"attitude must be one of {ATTITUDE_PATTERNS}, got {attitude!r}")
        self.attitude = attitude
        self.custom_mode = GUIDED
        self.armed = armed
        self.params = {k: v for k, v in STUB_PARAMS.items()}
        self.commands_seen: dict[str, int] = {}
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.kernel_timestamps = False
        self.clock_ns = time.perf_counter_ns
        if enable_kernel_timestamps(self.sock):
            self.kernel_timestamps = True
            self.clock_ns = time.time_ns
        self.port: int = self.sock.getsockname()[1]
        self.peer: tuple[str, int] | None = None
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.mav.robust_parsing = True
        self.client_heard = threading.Event()
        self.done = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stub-vehicle", daemon=True)
        self._result: StubRunResult | None = None
        self._window: tuple[int, int] | None = None
        self._cpu0 = self._cpu1 = float("nan")
        self._t_window0 = self._t_window1 = 0

    # ---- lifecycle -------------------------------------------------------------------------
    def start(self) -> "StubVehicle":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self.sock.close()

    def __enter__(self) -> "StubVehicle":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def wait_result(self, timeout_s: float) -> StubRunResult:
        """Block until the window is complete (or ``timeout_s``); never raises for a silent client."""
        if not self.done.wait(timeout_s):
            answered = sum(a is not None for a in self.pairing.answer_ns)
            sent = len(self.pairing.sent_ns)
            if not self.client_heard.is_set():
                why = "no packet ever received from the client"
            elif self._window is None:
                why = f"the client never answered an ATTITUDE ({sent} sent)"
            else:
                first, last = self._window
                end = min(last, sent - 2)
                if end >= first:  # the window started: statistics over the part that ran
                    stats = self.pairing.stats(first, end)
                    why = f"window cut short after {end - first + 1} of {last - first + 1} samples"
                    return StubRunResult(self.rate_hz, stats, float("nan"), 0.0, dict(self.commands_seen), error=why)
                why = f"window not reached ({answered} answers to {sent} ATTITUDE samples)"
            return StubRunResult(self.rate_hz, None, float("nan"), 0.0, dict(self.commands_seen), error=why)
        assert self._result is not None
        return self._result

    # ---- wire ------------------------------------------------------------------------------
    def _send(self, msg) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(msg.pack(self.mav), self.peer)
            except OSError:
                pass

    def _send_heartbeat(self) -> None:
        base = 1 | 16 | 64 | 8 | (128 if self.armed else 0)
        self._send(self.mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             base, self.custom_mode, 4 if self.armed else 3, 3))

    def _send_attitude(self, seq_next: int) -> None:
        tbm = TIME_BOOT_OFFSET_MS + (seq_next * 1000) // int(self.rate_hz) if self.rate_hz.is_integer() \
            else TIME_BOOT_OFFSET_MS + int(seq_next * 1000 / self.rate_hz)
        if self.attitude == "roll_code":
            roll, p = roll_code_rad(seq_next), 0.0
        else:
            w = 2 * math.pi * SMALL_SINE_HZ
            roll = SMALL_SINE_AMPLITUDE_RAD * math.sin(w * seq_next / self.rate_hz)
            p = SMALL_SINE_AMPLITUDE_RAD * w * math.cos(w * seq_next / self.rate_hz) \
                + (RATE_DITHER_RADS if seq_next % 2 else -RATE_DITHER_RADS)
        att = self.mav.attitude_encode(tbm, roll, 0.0, 0.0, p, 0.0, 0.0).pack(self.mav)
        cr, sr = math.cos(roll / 2), math.sin(roll / 2)
        quat = self.mav.attitude_quaternion_encode(tbm, cr, sr, 0.0, 0.0, 0.0, 0.0, 0.0).pack(self.mav)
        t = self.clock_ns()
        try:
            self.sock.sendto(att, self.peer)
            if self.send_quaternion:
                self.sock.sendto(quat, self.peer)
        except OSError:
            return
        self.pairing.on_sent(tbm, t)

    def _ack(self, command: int, result: int, sysid: int, compid: int) -> None:
        self._send(self.mav.command_ack_encode(command, result, 0, 0, sysid, compid))

    def _send_param(self, name: str) -> None:
        names = list(self.params)
        value, ptype = self.params[name]
        self._send(self.mav.param_value_encode(name.encode(), value, ptype, len(names), names.index(name)))

    def _send_autopilot_version(self) -> None:
        caps = (mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
        version = (4 << 24) | (5 << 16) | (0 << 8) | 255
        self._send(self.mav.autopilot_version_encode(caps, version, 0, 0, 0, b"benchstu", b"\0" * 8, b"\0" * 8,
                                                     0, 0, 1, b"\0" * 18))

    def _handle(self, msg, recv_ns: int) -> None:
        mtype = msg.get_type()
        self.commands_seen[mtype] = self.commands_seen.get(mtype, 0) + 1
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype == "SET_ATTITUDE_TARGET":
            result = self.pairing.on_reply(recv_ns, msg.time_boot_ms,
                                           (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate), msg.thrust)
            if result == "answer" and self._first_answer_seq is None:
                self._first_answer_seq = len(self.pairing.sent_ns) - 1
        elif mtype in ("COMMAND_LONG", "COMMAND_INT"):
            cmd = msg.command
            self.commands_seen[f"cmd{cmd}"] = self.commands_seen.get(f"cmd{cmd}", 0) + 1
            if cmd == mavlink2.MAV_CMD_DO_SET_MODE:
                self.custom_mode = int(msg.param2)
                self._ack(cmd, mavlink2.MAV_RESULT_ACCEPTED, *src)
                self._send_heartbeat()
            elif cmd == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
                self.armed = msg.param1 == 1
                self._ack(cmd, mavlink2.MAV_RESULT_ACCEPTED, *src)
                self._send_heartbeat()
            elif cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES or (
                    cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION):
                self._ack(cmd, mavlink2.MAV_RESULT_ACCEPTED, *src)
                self._send_autopilot_version()
            elif cmd in (mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_CMD_REQUEST_MESSAGE,
                         mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL):
                self._ack(cmd, mavlink2.MAV_RESULT_ACCEPTED, *src)
            else:
                self._ack(cmd, mavlink2.MAV_RESULT_UNSUPPORTED, *src)
        elif mtype == "SET_MODE":
            self.custom_mode = int(msg.custom_mode)
            self._ack(mavlink2.MAVLINK_MSG_ID_SET_MODE, mavlink2.MAV_RESULT_ACCEPTED, *src)
            self._send_heartbeat()
        elif mtype == "PARAM_REQUEST_READ":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
            names = list(self.params)
            if msg.param_index >= 0 and msg.param_index < len(names):
                name = names[msg.param_index]
            if name in self.params:
                self._send_param(name)
        elif mtype == "PARAM_REQUEST_LIST":
            for name in self.params:
                self._send_param(name)
        elif mtype == "PARAM_SET":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
            if name in self.params and math.isfinite(msg.param_value):
                self.params[name] = (float(msg.param_value), self.params[name][1])
                self._send_param(name)
        elif mtype == "TIMESYNC" and msg.tc1 == 0:
            self._send(self.mav.timesync_encode(recv_ns, msg.ts1))
        elif mtype == "AUTOPILOT_VERSION_REQUEST":
            self._send_autopilot_version()

    # ---- the thread ------------------------------------------------------------------------
    def _drain(self) -> None:
        """Read and handle every datagram waiting on the socket (non-blocking)."""
        while True:
            try:
                data, anc, _flags, addr = self.sock.recvmsg(65536, 256)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            recv_ns = kernel_receive_ns(anc)
            if recv_ns is None:
                recv_ns = self.clock_ns()
            self.peer = addr
            self.client_heard.set()
            try:
                msgs = self.mav.parse_buffer(data) or []
            except mavlink2.MAVError:
                continue
            for msg in msgs:
                if msg.get_type() != "BAD_DATA":
                    self._handle(msg, recv_ns)

    def _run(self) -> None:
        period_ns = int(round(1e9 / self.rate_hz))
        self._first_answer_seq: int | None = None
        next_send = next_hb = 0
        grace_ns = max(200_000_000, 20 * period_ns)
        while not self._stop.is_set():
            self._drain()  # replies that arrived while we were descheduled are handled before the next send
            now = self.clock_ns()
            if self.peer is not None:
                if now >= next_hb:
                    self._send_heartbeat()
                    next_hb = now + 1_000_000_000
                if now >= next_send:
                    seq = len(self.pairing.sent_ns)
                    self._send_attitude(seq)
                    self._on_sample_sent(seq)
                    # never two samples closer than half a period: after a stall of the stub itself, a
                    # catch-up burst would make a newest-sample client (rightly) skip the older one, and
                    # that would be counted against the client
                    next_send = max(next_send + period_ns, now + period_ns // 2) if next_send else now + period_ns
                    continue
                end_seq = self._window[1] + 1 if self._window else -1
                if 0 < end_seq < len(self.pairing.sent_ns) and not self.done.is_set() and \
                        now - self.pairing.sent_ns[end_seq] > grace_ns:
                    self._finish()
            timeout = 0.05 if self.peer is None else max(0.0, (next_send - self.clock_ns()) / 1e9)
            select.select([self.sock], [], [], timeout)

    def _on_sample_sent(self, seq: int) -> None:
        if self._window is None and self._first_answer_seq is not None:
            first = self._first_answer_seq + int(round(self.warmup_s * self.rate_hz))
            last = first + max(1, int(round(self.duration_s * self.rate_hz))) - 1
            self._window = (first, last)
        if self._window is None:
            return
        if seq == self._window[0]:
            self._cpu0 = self.cpu_probe() if self.cpu_probe else float("nan")
            self._t_window0 = self.clock_ns()
        elif seq == self._window[1] + 1:
            self._cpu1 = self.cpu_probe() if self.cpu_probe else float("nan")
            self._t_window1 = self.clock_ns()

    def _finish(self) -> None:
        first, last = self._window  # type: ignore[misc]
        stats = self.pairing.stats(first, last)
        cycles = max(1, stats.samples)
        cpu_us = (self._cpu1 - self._cpu0) / cycles * 1e6
        self._result = StubRunResult(self.rate_hz, stats, cpu_us, (self._t_window1 - self._t_window0) / 1e9,
                                     dict(self.commands_seen))
        self.done.set()
