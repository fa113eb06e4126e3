"""The Solo physics server for ArduPilot's JSON SITL protocol (sim/json_physics.py), over real UDP sockets, with a
fake ArduPilot client: no ArduCopter needed (the genuine pair: tests/autopilots/test_arducopter_solo_physics.py).

What a wrong answer here would break on genuine ArduCopter: hover PWM must hold the vehicle (thrust and motor
mapping), a roll/pitch/yaw PWM pattern must turn it the way ArduPilot's quad-X mixer expects (motor order and
spin), the timestamp must advance by exactly 1/frame_rate (ArduPilot's lockstep clock), and no reply may carry a
non-finite number (ArduPilot parses them with sscanf into floats). Every wait is on a condition with a timeout.
"""

from __future__ import annotations

import json
import math
import socket
import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavastsm.config_loading import load_section
from mavastsm_sim.command import main as sim_main
from mavastsm_sim.genuine_sitl import solo_parm_path
from mavastsm_sim.json_physics import (MAGIC_16, MAGIC_32, MAX_FRAME_JUMP_S, JsonPhysics, JsonPhysicsCounters,
                                       JsonPhysicsServer, encode_reply)
from mavastsm_sim.mixer import QUAD_X_LAYOUT

RATE_HZ = 1200  # ArduCopter SITL's default SIM_RATE_HZ
TIMEOUT_S = 5.0


def _reject_constant(name):
    raise ValueError(f"non-finite JSON constant {name}")


def parse_reply(data: bytes) -> dict:
    """A reply as ArduPilot reads it: one JSON line between newlines; NaN/Infinity are errors."""
    text = data.decode("ascii")
    assert text.startswith("\n") and text.endswith("\n") and text.count("\n") == 2, text
    assert '": ' not in text, "ArduPilot's parser needs each key directly followed by '\":'"
    return json.loads(text, parse_constant=_reject_constant)


def servo_packet(frame_count: int, pwm_motors, rate_hz: int = RATE_HZ, channels: int = 16, magic: int | None = None) -> bytes:
    pwm = list(pwm_motors) + [0] * (channels - len(pwm_motors))
    return struct.pack(f"<HHI{channels}H", magic if magic is not None else (MAGIC_16 if channels == 16 else MAGIC_32),
                       rate_hz, frame_count, *pwm)


class FakeArduPilot:
    """ArduPilot's side of the protocol on a real UDP socket: send a servo packet, read the JSON reply."""

    def __init__(self, server_address) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(TIMEOUT_S)
        self.server = server_address
        self.frame = 0

    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.server)

    def reply(self) -> dict:
        data, _ = self.sock.recvfrom(4096)
        return parse_reply(data)

    def step(self, pwm_motors, rate_hz: int = RATE_HZ, channels: int = 16) -> dict:
        """One lockstep frame: the next frame_count, answered by one reply."""
        self.frame += 1
        self.send(servo_packet(self.frame, pwm_motors, rate_hz, channels))
        return self.reply()

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def pair():
    """(server, client) on loopback; the server's thread must not have failed."""
    server = JsonPhysicsServer(JsonPhysics(), port=0).start()
    client = FakeArduPilot(server.address)
    yield server, client
    client.close()
    server.stop()
    assert server.error is None, repr(server.error)


def hover_pwm_us(physics: JsonPhysics) -> float:
    """PWM at which each motor carries a quarter of the weight (motor_model: T = k_t (Omega_max c)^2)."""
    m = physics.plant.motors
    c = math.sqrt(physics.plant.weight_n / 4.0 / m.k_t) / m.omega_max
    return 1000.0 + 1000.0 * c


def airborne_at_hover(physics: JsonPhysics, altitude_m: float = 10.0) -> int:
    """Put the plant at rest in the air with the motors already at hover speed; returns the hover PWM [us]."""
    pwm = round(hover_pwm_us(physics))
    physics.plant.reset((0.0, 0.0, -altitude_m))
    m = physics.plant.motors
    m.speed_rads = [m.omega_max * (pwm - 1000) / 1000.0] * m.count
    return pwm


def roll_pitch_yaw(q):
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def test_resting_on_the_ground_reads_like_an_accelerometer_at_rest(pair):
    server, client = pair
    r = client.step([1000] * 4)
    assert set(r) == {"timestamp", "imu", "position", "velocity", "quaternion"}
    assert r["imu"]["accel_body"] == pytest.approx([0.0, 0.0, -9.81]) and r["imu"]["gyro"] == [0.0, 0.0, 0.0]
    assert r["quaternion"] == [1.0, 0.0, 0.0, 0.0] and r["position"] == [0.0, 0.0, 0.0]


def test_hover_pwm_keeps_the_vehicle_still(pair):
    server, client = pair
    pwm = airborne_at_hover(server.physics)
    for _ in range(2 * RATE_HZ):  # 2 s
        r = client.step([pwm] * 4)
    assert abs(r["position"][2] + 10.0) < 0.05 and max(abs(v) for v in r["velocity"]) < 0.05, r
    assert max(abs(v) for v in r["imu"]["gyro"]) < 1e-9 and max(abs(a) for a in roll_pitch_yaw(r["quaternion"])) < 1e-9
    assert r["imu"]["accel_body"][2] == pytest.approx(-9.81, abs=0.02)


# ArduPilot motor (servo) order for quad X (sim/mixer.py QUAD_X_LAYOUT): 1 front right CCW, 2 back left CCW,
# 3 front left CW, 4 back right CW. +roll = right side down: left motors (2, 3) up, right ones (1, 4) down;
# +pitch = nose up: front (1, 3) up; +yaw = nose right: the CCW motors (1, 2) up, their reaction turns the body.
PATTERNS = {"roll": (-1, +1, +1, -1), "pitch": (+1, -1, +1, -1), "yaw": (+1, +1, -1, -1)}


@pytest.mark.parametrize("axis", ["roll", "pitch", "yaw"])
def test_torque_pwm_pattern_turns_the_vehicle_the_way_ardupilots_mixer_expects(pair, axis):
    server, client = pair
    pwm = airborne_at_hover(server.physics)
    pattern = PATTERNS[axis]
    for _ in range(RATE_HZ // 5):  # 0.2 s
        r = client.step([pwm + 40 * s for s in pattern])
    i = ("roll", "pitch", "yaw").index(axis)
    angles, rates = roll_pitch_yaw(r["quaternion"]), r["imu"]["gyro"]
    assert rates[i] > 0.05 and angles[i] > 0.002, (axis, rates, angles)
    others = [j for j in range(3) if j != i]
    assert all(abs(rates[j]) < 0.1 * rates[i] for j in others), (axis, rates)


def test_the_layout_the_patterns_assume_is_the_one_the_physics_uses():
    """Motor angles from the nose (+ toward the right wing) and spin: ArduPilot's AP_MotorsMatrix quad X."""
    assert QUAD_X_LAYOUT == ((45.0, 1.0), (-135.0, 1.0), (-45.0, -1.0), (135.0, -1.0))


def test_timestamps_advance_by_one_frame_period_also_when_the_rate_changes(pair):
    server, client = pair
    stamps = [client.step([1000] * 4)["timestamp"] for _ in range(1200)]
    assert stamps == pytest.approx([(k + 1) / RATE_HZ for k in range(1200)], abs=1e-12)
    more = [client.step([1000] * 4, rate_hz=400)["timestamp"] for _ in range(4)]
    assert more == pytest.approx([1.0 + (k + 1) / 400 for k in range(4)], abs=1e-12)


def test_32_channel_packets_are_served_like_16_channel_ones(pair):
    server, client = pair
    r = client.step([1000] * 4, channels=32)
    assert r["timestamp"] == pytest.approx(1 / RATE_HZ)


def test_duplicate_gets_the_same_reply_again_and_a_restart_resets_the_vehicle(pair):
    server, client = pair
    for _ in range(RATE_HZ):
        last = client.step([1900] * 4)
    assert last["position"][2] < -0.5  # climbing
    client.send(servo_packet(client.frame, [1900] * 4))  # ArduPilot re-sends a frame whose reply it lost
    assert client.reply() == last
    client.frame = -1  # ArduPilot restarted: frame_count 0 again
    r = client.step([1000] * 4)
    assert r["timestamp"] == pytest.approx(1 / RATE_HZ) and r["position"] == [0.0, 0.0, 0.0]
    c = server.counters
    assert (c.rejected_duplicate_frame, c.replies_resent, c.restarts, c.rejected_total) == (1, 1, 1, 1)


def test_encode_reply_never_sends_a_non_finite_number_and_counts_it():
    c = JsonPhysicsCounters()
    data = encode_reply(0.5, (math.nan, 0.0, math.inf), (0.0, 0.0, -1e300), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                        (1.0, 0.0, 0.0, 0.0), c)
    r = parse_reply(data)
    assert r["imu"]["gyro"] == [0.0, 0.0, 0.0] and r["imu"]["accel_body"] == [0.0, 0.0, -1e6]
    assert (c.nonfinite_state, c.clipped_values) == (2, 1)


def test_solo_parm_carries_the_solo_values_the_emulation_uses():
    """configs/arducopter/solo.parm (genuine ArduCopter) and solo.yaml's autopilot: section (our emulation) agree."""
    parm = {}
    for line in solo_parm_path().read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, value = line.split()
            parm[name] = float(value)
    yaml_values = {k.split(".", 1)[-1]: p.value for k, p in load_section(
        str(Path(solo_parm_path()).parents[1] / "vehicle" / "solo.yaml"), "autopilot").items()}
    assert {k: parm.get(k) for k in yaml_values} == yaml_values
    assert (parm["FRAME_CLASS"], parm["FRAME_TYPE"], parm["MOT_PWM_MIN"], parm["MOT_PWM_MAX"]) == (1, 1, 1000, 2000)


def test_missing_arducopter_is_a_one_line_error_with_exit_2(monkeypatch, capsys):
    monkeypatch.delenv("MAVASTSM_ARDUCOPTER", raising=False)
    assert sim_main(["--autopilot", "arducopter"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "MAVASTSM_ARDUCOPTER" in err and "--arducopter" in err, err
    assert sim_main(["--autopilot", "arducopter", "--arducopter", "/nonexistent/arducopter"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--arducopter /nonexistent/arducopter" in err, err


# ---------------------------------------------------------------------------------------------------- fuzz
# One event per datagram: a valid next frame, ArduPilot's own irregularities, or a corrupt packet, each with the
# counter it must land in (None: stepped).
BAD_KINDS = ("wrong_size", "bad_magic", "size_magic_mismatch", "bad_frame_rate", "pwm_out_of_range",
             "duplicate_frame", "out_of_order_frame", "frame_count_jump")
events = st.lists(st.one_of(
    st.tuples(st.just("valid"), st.lists(st.integers(1000, 2000), min_size=4, max_size=4), st.sampled_from([400, 1000, 1200])),
    st.tuples(st.just("restart"), st.just([1000] * 4), st.just(RATE_HZ)),
    st.tuples(st.sampled_from(BAD_KINDS), st.binary(min_size=0, max_size=120), st.integers(0, 2**16 - 1)),
), min_size=1, max_size=25)


def corrupt(kind: str, blob: bytes, n: int, last_frame: int) -> bytes:
    """A packet that must be rejected as ``kind`` (blob and n are hypothesis' random material)."""
    if kind == "wrong_size":
        return blob if len(blob) not in (40, 72) else blob + b"\x00"
    if kind == "bad_magic":
        magic = n if n not in (MAGIC_16, MAGIC_32) else n + 1
        return servo_packet(last_frame + 1, [1500] * 4, magic=magic)
    if kind == "size_magic_mismatch":
        return servo_packet(last_frame + 1, [1500] * 4, channels=32, magic=MAGIC_16)
    if kind == "bad_frame_rate":
        return servo_packet(last_frame + 1, [1500] * 4, rate_hz=n % 10)
    if kind == "pwm_out_of_range":
        bad = 2201 + n % 63000 if n % 2 else 1 + n % 799
        pwm = [1500] * 4
        pwm[n % 4] = bad
        return servo_packet(last_frame + 1, pwm)
    if kind == "duplicate_frame":
        return servo_packet(last_frame, [1500] * 4)
    if kind == "out_of_order_frame":
        return servo_packet(1 + n % (last_frame - 1), [1500] * 4)  # needs last_frame >= 2, never 0 (a restart)
    assert kind == "frame_count_jump"
    return servo_packet(last_frame + int(MAX_FRAME_JUMP_S * RATE_HZ) + 1 + n, [1500] * 4)


def all_finite(obj) -> bool:
    if isinstance(obj, dict):
        return all(all_finite(v) for v in obj.values())
    if isinstance(obj, list):
        return all(all_finite(v) for v in obj)
    return isinstance(obj, (int, float)) and math.isfinite(obj)


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(events)
def test_fuzz_every_bad_packet_is_counted_by_name_and_valid_ones_keep_being_answered(events):
    server = JsonPhysicsServer(JsonPhysics(), port=0).start()
    client = FakeArduPilot(server.address)
    try:
        last_reply = client.step([1000] * 4)  # frame 1: the server has seen ArduPilot
        expected = {f"rejected_{k}": 0 for k in BAD_KINDS}
        restarts, last_t, last_rate = 0, 1 / RATE_HZ, RATE_HZ
        for kind, material, n in events:
            if kind == "valid":
                r = client.step(material, rate_hz=n)
                assert all_finite(r), r
                assert r["timestamp"] == pytest.approx(last_t + 1 / n, abs=1e-9)
                last_t, last_reply, last_rate = r["timestamp"], r, n
                continue
            if kind == "restart":
                if client.frame == 0:  # a second frame 0 in a row is ArduPilot re-sending it: a duplicate, not a restart
                    continue
                client.frame = -1
                r = client.step(material)
                assert all_finite(r) and r["timestamp"] == pytest.approx(1 / RATE_HZ)
                last_t, last_reply, last_rate, restarts = r["timestamp"], r, RATE_HZ, restarts + 1
                continue
            if kind == "out_of_order_frame" and client.frame < 2:
                continue
            client.send(corrupt(kind, material, n, client.frame))
            expected[f"rejected_{kind}"] += 1
            if kind == "duplicate_frame" and last_reply is not None:
                assert client.reply() == last_reply  # answered again, not stepped
        # a final valid frame: answered, and (UDP on loopback keeps order) nothing else came back before it
        r = client.step([1000] * 4, rate_hz=last_rate)
        assert r["timestamp"] == pytest.approx(last_t + 1 / last_rate, abs=1e-9) and all_finite(r)
        counts = server.counters.as_dict()
        assert {k: counts[k] for k in expected} == expected, server.counters.summary()
        assert counts["restarts"] == restarts and counts["nonfinite_state"] == 0
        assert counts["rejected_total"] == sum(expected.values())
    finally:
        client.close()
        server.stop()
    assert server.error is None, repr(server.error)
