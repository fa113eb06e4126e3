"""The Solo's physics for genuine ArduCopter SITL over ArduPilot's JSON SITL protocol (``--model JSON:127.0.0.1``).

ArduCopter (libraries/SITL/SIM_JSON.cpp of ArduPilot) sends one binary servo packet per physics frame to UDP
port 9002 and waits (lockstep) for a JSON reply before it runs its next frame. This server answers each
packet with exactly one physics step of ``1/frame_rate`` seconds of :class:`~.solo_plant.SoloPlant` (the
same rigid body, motors, drag, gyroscopic torque, disturbances and ground contact as ``mavastsm sim``).

Servo packet (little-endian)::

    uint16 magic        18458 with 16 channels, 29569 with 32 (SERVO_32_ENABLE = 1)
    uint16 frame_rate   [Hz] physics rate ArduPilot wants (SIM_RATE_HZ): one step is 1/frame_rate
    uint32 frame_count  +1 per frame; back to 0 when ArduPilot restarts; repeated when it re-sends
    uint16 pwm[16|32]   [us] servo outputs; quad X motors 1..4 on servos 1..4

Reply: one line of JSON, preceded and followed by "\\n" (ArduPilot's parser is a plain ``strstr``/``sscanf``, so the
keys must be followed directly by ``":`` and no value may be NaN or infinite)::

    {"timestamp": t [s], "imu": {"gyro": [p, q, r] [rad/s, body FRD],
                                 "accel_body": [ax, ay, az] [m/s^2, body FRD, specific force: (0, 0, -g) at rest]},
     "position": [n, e, d] [m, NED from the start point], "velocity": [vn, ve, vd] [m/s, NED],
     "quaternion": [w, x, y, z] (NED -> FRD, ArduPilot's Quaternion q1..q4)}

Motor order (ArduPilot FRAME_CLASS 1 QUAD, FRAME_TYPE 1 X; ``mixer.QUAD_X_LAYOUT``): servo 1 front right (CCW
seen from above), 2 back left (CCW), 3 front left (CW), 4 back right (CW). PWM maps to the ESC command
``(pwm - 1000 us) / 1000 us`` clipped to [0, 1] (MOT_PWM_MIN/MAX 1000/2000 in configs/arducopter/solo.parm), the
same normalised command the in-repo autopilot emulation gives the motors.

Every packet is either stepped or rejected under a named reason (:class:`JsonPhysicsCounters`), and the server
keeps answering the valid ones. frame_count rules, as ArduPilot's own example backends apply them: a
repeat of the last frame_count is a duplicate (not stepped; the last reply is sent again, since ArduPilot
re-sends a frame whose reply it did not get); a frame_count going back to 0 is an ArduPilot restart (the
vehicle is put back at rest at the start point and the clock at 0); any other step backwards is out of order
(dropped); a forward gap is accepted and counted (ArduPilot never skips, so a gap means lost packets), but a
jump of more than ``MAX_FRAME_JUMP_S`` seconds of frames is dropped so that one corrupt packet cannot make
every later genuine frame look old.

Pure parts (packet decoding, frame_count rules, PWM mapping, the reply) are functions and a class without I/O,
:class:`JsonPhysics`; :class:`JsonPhysicsServer` only owns the UDP socket and its thread.
"""

from __future__ import annotations

import json
import logging
import math
import random
import socket
import struct
import threading
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path

from .attitude_math import q_rotate_inverse
from .solo_plant import SoloPlant, noisy_attitude_and_rates
from .vehicle_config import load_vehicle_config

LOG = logging.getLogger("mavastsm_sim.json_physics")

JSON_SITL_PORT = 9002
MAGIC_16 = 18458
MAGIC_32 = 29569
HEADER = struct.Struct("<HHI")
PACKET_16 = struct.Struct("<HHI16H")
PACKET_32 = struct.Struct("<HHI32H")
MOTOR_COUNT = 4  # quad X: servos 1..4
PWM_MIN_US = 1000.0  # MOT_PWM_MIN of configs/arducopter/solo.parm
PWM_MAX_US = 2000.0  # MOT_PWM_MAX
PWM_VALID_US = (800, 2200)  # a motor PWM outside this (other than 0 = "no output yet") is corrupt
FRAME_RATE_VALID_HZ = (10, 20000)
MAX_FRAME_JUMP_S = 10.0  # [s] longest forward frame_count jump accepted, in frames at the packet's rate
DISTURBANCE_STARTS = ("liftoff", "boot", "held")
REPLY_LIMIT = 1.0e6  # |value| bound of every reply number: ArduPilot parses them into 32-bit floats


class PacketRejected(ValueError):
    """A servo packet that is not stepped; ``reason`` names the JsonPhysicsCounters field counting it."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass
class JsonPhysicsCounters:
    """What the server did with every datagram (one ``rejected_*`` field per named reason)."""

    stepped: int = 0  # physics steps run (one per accepted servo packet)
    restarts: int = 0  # frame_count back to 0: ArduPilot restarted, physics reset
    frames_missed: int = 0  # frames skipped over by forward gaps (accepted packets after lost ones)
    replies_resent: int = 0  # last reply sent again for a duplicate frame
    rejected_wrong_size: int = 0
    rejected_bad_magic: int = 0
    rejected_size_magic_mismatch: int = 0  # 16-channel magic on a 32-channel packet or the other way round
    rejected_bad_frame_rate: int = 0
    rejected_pwm_out_of_range: int = 0
    rejected_duplicate_frame: int = 0
    rejected_out_of_order_frame: int = 0
    rejected_frame_count_jump: int = 0
    nonfinite_state: int = 0  # physics produced a non-finite number (replaced by 0 before sending; never seen)
    clipped_values: int = 0  # reply numbers beyond +-REPLY_LIMIT, clipped

    @property
    def rejected_total(self) -> int:
        return sum(v for k, v in asdict(self).items() if k.startswith("rejected_"))

    def as_dict(self) -> dict:
        return {**asdict(self), "rejected_total": self.rejected_total}

    def summary(self) -> str:
        """One line: the steps and every non-zero counter by name."""
        d = asdict(self)
        rest = ", ".join(f"{k} {v}" for k, v in d.items() if v and k != "stepped")
        return f"{self.stepped} steps" + (f"; {rest}" if rest else "")


@dataclass(frozen=True)
class ServoPacket:
    frame_rate_hz: int
    frame_count: int
    pwm_us: tuple


def decode_servo_packet(data: bytes) -> ServoPacket:
    """A validated servo packet, or PacketRejected naming why (size, magic, frame rate, motor PWM)."""
    if len(data) not in (PACKET_16.size, PACKET_32.size):
        raise PacketRejected("rejected_wrong_size", f"{len(data)} bytes, expected {PACKET_16.size} or {PACKET_32.size}")
    magic = HEADER.unpack_from(data)[0]
    if magic not in (MAGIC_16, MAGIC_32):
        raise PacketRejected("rejected_bad_magic", f"magic {magic}, expected {MAGIC_16} or {MAGIC_32}")
    layout = PACKET_16 if magic == MAGIC_16 else PACKET_32
    if len(data) != layout.size:
        raise PacketRejected("rejected_size_magic_mismatch", f"magic {magic} with {len(data)} bytes")
    fields = layout.unpack(data)
    rate, count, pwm = fields[1], fields[2], fields[3:]
    if not FRAME_RATE_VALID_HZ[0] <= rate <= FRAME_RATE_VALID_HZ[1]:
        raise PacketRejected("rejected_bad_frame_rate", f"frame_rate {rate} Hz outside {FRAME_RATE_VALID_HZ}")
    for i, v in enumerate(pwm[:MOTOR_COUNT]):
        if v != 0 and not PWM_VALID_US[0] <= v <= PWM_VALID_US[1]:
            raise PacketRejected("rejected_pwm_out_of_range", f"servo {i + 1} pwm {v} us outside {PWM_VALID_US}")
    return ServoPacket(rate, count, pwm)


def pwm_to_esc_norm(pwm_us) -> list[float]:
    """Motor PWM [us] (ArduPilot servo order) -> ESC commands [0, 1]: (pwm - MOT_PWM_MIN) / (MAX - MIN), clipped;
    0 us (no output) is 0."""
    span = PWM_MAX_US - PWM_MIN_US
    out = []
    for v in pwm_us[:MOTOR_COUNT]:
        c = (v - PWM_MIN_US) / span
        out.append(0.0 if c < 0.0 else (1.0 if c > 1.0 else c))
    return out


class FrameSequencer:
    """ArduPilot's frame_count rules (module docstring): ``classify(count, rate)`` -> "step" | "restart" | the
    ``rejected_*`` reason; ``gap`` is the number of frames skipped by the last accepted forward jump."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.gap = 0

    def classify(self, frame_count: int, frame_rate_hz: int) -> str:
        self.gap = 0
        last = self.last
        if last is None:
            self.last = frame_count
            return "step"
        if frame_count == last:
            return "rejected_duplicate_frame"
        if frame_count < last:
            if frame_count == 0:
                self.last = 0
                return "restart"
            return "rejected_out_of_order_frame"
        if frame_count - last > MAX_FRAME_JUMP_S * frame_rate_hz:
            return "rejected_frame_count_jump"
        self.gap = frame_count - last - 1
        self.last = frame_count
        return "step"


def _finite_vector(values, counters: JsonPhysicsCounters) -> list[float]:
    out = []
    for v in values:
        v = float(v)
        if not math.isfinite(v):
            counters.nonfinite_state += 1
            v = 0.0
        elif abs(v) > REPLY_LIMIT:
            counters.clipped_values += 1
            v = math.copysign(REPLY_LIMIT, v)
        out.append(v)
    return out


def specific_force_frd(q_wxyz, accel_ned_ms2, gravity_ms2: float):
    """What an accelerometer measures [m/s^2, body FRD]: R^T (a - g e_down), i.e. (0, 0, -g) level at rest."""
    an, ae, ad = accel_ned_ms2
    return q_rotate_inverse(q_wxyz, an, ae, ad - gravity_ms2)


def encode_reply(timestamp_s: float, gyro_frd_rads, accel_body_ms2, position_ned_m, velocity_ned_ms, q_wxyz,
                 counters: JsonPhysicsCounters) -> bytes:
    """The JSON line ArduPilot parses; every number finite and within +-REPLY_LIMIT (counted when forced)."""
    c = counters
    msg = {
        "timestamp": _finite_vector([timestamp_s], c)[0],
        "imu": {"gyro": _finite_vector(gyro_frd_rads, c), "accel_body": _finite_vector(accel_body_ms2, c)},
        "position": _finite_vector(position_ned_m, c),
        "velocity": _finite_vector(velocity_ned_ms, c),
        "quaternion": _finite_vector(q_wxyz, c),
    }
    return ("\n" + json.dumps(msg, separators=(",", ":"), allow_nan=False) + "\n").encode("ascii")


class JsonPhysics:
    """The Solo plant stepped by servo packets (no I/O): ``handle(datagram) -> reply bytes or None``.

    Parameters
    ----------
    vehicle_config, scenario, seed, noise : as ``mavastsm sim`` (noise: the vehicle YAML's ``sensor_noise``
        on the gyro and the attitude sent to ArduPilot)
    attitude_history_s : keep the last this many seconds of (physics time [s], true attitude quaternion) in
        ``attitude_history`` (0: none), so a caller can line ArduCopter's clock up with the physics clock from what
        ArduCopter reported (the benchmarks do, to start a scenario's torque at the bridge's engagement)
    disturbance_start : "liftoff" (default) starts the scenario's disturbance clock when the vehicle first leaves
        the ground, so its torque events fall in the flight and not in ArduCopter's ~25 s of pre-arm checks
        on the ground; "boot" counts from the first frame; "held" keeps it parked until the caller starts it
        (``plant.disturbances.restart_clock(t)``), which the benchmarks do at the bridge's engagement so that
        the scenario's times mean the same as in the offline runs and ``mavastsm sim``'s benchmarks
    """

    def __init__(self, vehicle_config: str | Path | None = None, scenario=None, seed: int = 0, noise: bool = False,
                 disturbance_start: str = "liftoff", attitude_history_s: float = 0.0) -> None:
        if disturbance_start not in DISTURBANCE_STARTS:
            raise ValueError(f"disturbance_start must be one of {DISTURBANCE_STARTS}, got {disturbance_start!r}")
        self.config = load_vehicle_config(vehicle_config)
        self.plant = SoloPlant(self.config, scenario)
        self.counters = JsonPhysicsCounters()
        self.sequencer = FrameSequencer()
        self.seed = seed
        self.noise = bool(noise)
        self.disturbance_start = disturbance_start
        self.attitude_history_s = float(attitude_history_s)
        self.attitude_history: deque | None = None
        self._reset_clock()
        self.last_reply: bytes | None = None

    def _reset_clock(self) -> None:
        self.steps = 0
        self._rate_hz = 0  # time is base + n / rate, exact per rate, re-based when ArduPilot changes the rate
        self._base_s = 0.0
        self._n_at_rate = 0
        self._rng = random.Random(self.seed)
        self._airborne_once = False
        self.attitude_history = None
        # parked far in the future until lift-off or the caller (restart_clock moves it), or from boot
        if self.disturbance_start == "boot":
            self.plant.disturbances.restart_clock(0.0)
        else:
            self.plant.disturbances.park()

    def handle(self, data: bytes) -> bytes | None:
        """Step once and return the reply, or count the rejection and return None (the last reply for a duplicate)."""
        c = self.counters
        try:
            pkt = decode_servo_packet(data)
        except PacketRejected as exc:
            setattr(c, exc.reason, getattr(c, exc.reason) + 1)
            return None
        verdict = self.sequencer.classify(pkt.frame_count, pkt.frame_rate_hz)
        if verdict.startswith("rejected_"):
            setattr(c, verdict, getattr(c, verdict) + 1)
            if verdict == "rejected_duplicate_frame" and self.last_reply is not None:
                c.replies_resent += 1
                return self.last_reply
            return None
        if verdict == "restart":
            c.restarts += 1
            self.plant.reset()
            self._reset_clock()
        c.frames_missed += self.sequencer.gap
        self.last_reply = self.step(pwm_to_esc_norm(pkt.pwm_us), pkt.frame_rate_hz)
        return self.last_reply

    @property
    def time_s(self) -> float:
        """[s] simulated time since the first frame (or ArduPilot's last restart)."""
        return self._base_s + (self._n_at_rate / self._rate_hz if self._rate_hz else 0.0)

    def step(self, esc_commands, frame_rate_hz: int) -> bytes:
        """One physics step of 1/``frame_rate_hz`` [s] with the ESC commands held; returns the reply for the new state."""
        if frame_rate_hz != self._rate_hz:
            self._base_s, self._rate_hz, self._n_at_rate = self.time_s, frame_rate_hz, 0
        h = 1.0 / frame_rate_hz
        plant = self.plant
        plant.step(esc_commands, self.time_s, h)
        self.steps += 1
        self.counters.stepped += 1
        self._n_at_rate += 1
        if not self._airborne_once and not plant.in_ground_contact:
            self._airborne_once = True
            if self.disturbance_start == "liftoff":
                plant.disturbances.restart_clock(self.time_s)
        x = plant.x
        q, gyro = (x[6], x[7], x[8], x[9]), (x[10], x[11], x[12])
        if self.attitude_history_s > 0.0:
            if self.attitude_history is None:
                self.attitude_history = deque(maxlen=max(int(self.attitude_history_s * frame_rate_hz), 1))
            self.attitude_history.append((self.time_s, q))
        accel = specific_force_frd(q, plant.accel_ned_ms2, plant.body.gravity_ms2)
        if self.noise:
            q, gyro = noisy_attitude_and_rates(self._rng.gauss, q, gyro, self.config.sensor_noise)
        return encode_reply(self.time_s, gyro, accel, x[0:3], x[3:6], q, self.counters)


class JsonPhysicsServer:
    """:class:`JsonPhysics` on a UDP socket (default 127.0.0.1:9002), answering each packet's sender, on a thread.

    ``open()`` binds (call it inside the network namespace ArduCopter runs in; the socket stays there), ``start()``
    runs the loop, ``stop()`` ends it. ``physics`` and its ``counters`` may be read from other threads.
    """

    def __init__(self, physics: JsonPhysics, host: str = "127.0.0.1", port: int = JSON_SITL_PORT) -> None:
        self.physics = physics
        self.host, self.port = host, port
        self.sock: socket.socket | None = None
        self.peer = None  # address of the last accepted packet's sender (ArduCopter)
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def counters(self) -> JsonPhysicsCounters:
        return self.physics.counters

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname() if self.sock is not None else (self.host, self.port)

    def open(self) -> "JsonPhysicsServer":
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind((self.host, self.port))
        except OSError:
            s.close()
            raise
        s.settimeout(0.1)
        self.sock = s
        return self

    def start(self) -> "JsonPhysicsServer":
        if self.sock is None:
            self.open()
        self._thread = threading.Thread(target=self._run, name="json-physics", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        sock, handle = self.sock, self.physics.handle
        try:
            while not self._stop.is_set():
                try:
                    data, addr = sock.recvfrom(2048)
                except socket.timeout:
                    continue
                except OSError:
                    if self._stop.is_set():
                        return
                    raise
                reply = handle(data)
                if reply is not None:
                    self.peer = addr
                    try:
                        sock.sendto(reply, addr)
                    except OSError as exc:  # e.g. the peer's port is gone; ArduCopter re-sends after 1 s
                        LOG.debug("reply to %s failed: %s", addr, exc)
        except BaseException as exc:  # reported by the owner (command or test), never silently lost
            self.error = exc
            LOG.error("JSON physics loop failed: %r", exc)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self.sock is not None:
            self.sock.close()

    def __enter__(self) -> "JsonPhysicsServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
