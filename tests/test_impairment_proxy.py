"""Unit tests of the UDP impairment relay with plain sockets on ephemeral loopback ports.

The proxy's fault decisions are seeded, so the counts below are reproducible; the assertions are
still statistical bounds derived from the configured probabilities (not recorded outputs), so a
wrong fault model fails them.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import time

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402  (test code is a MAVLink peer)

from mavastsm_sim.impairment_proxy import (  # noqa: E402
    ImpairmentProxy,
    ImpairmentSettings,
    attitude_time_s,
    mavlink_msgid,
    parse_host_port,
)

WAIT_S = 5.0


class Endpoint:
    """A plain UDP socket on 127.0.0.1 with a bounded blocking receive."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def recv(self, timeout_s: float = WAIT_S) -> bytes | None:
        self.sock.settimeout(timeout_s)
        try:
            return self.sock.recvfrom(65535)[0]
        except socket.timeout:
            return None

    def drain(self, quiet_s: float = 0.2) -> list[bytes]:
        """Everything that arrives until nothing came for ``quiet_s`` (end-of-stream detection)."""
        out = []
        while (d := self.recv(quiet_s)) is not None:
            out.append(d)
        return out

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def endpoints():
    client, target = Endpoint(), Endpoint()
    try:
        yield client, target
    finally:
        client.close()
        target.close()


def make_proxy(target: Endpoint, **kw) -> ImpairmentProxy:
    return ImpairmentProxy(target.address, ("127.0.0.1", 0), **kw).start()


def attitude_frame(time_boot_ms: int, seq: int = 0) -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = seq % 256
    return mav.attitude_encode(time_boot_ms, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(mav)


def numbered(i: int) -> bytes:
    return b"pkt%06d" % i


def send_numbered(client: Endpoint, proxy: ImpairmentProxy, n: int, target: Endpoint, paced: bool = True) -> list[bytes]:
    """Send n numbered datagrams client->target one at a time (waiting for each to be processed)."""
    got = []
    for i in range(n):
        client.sock.sendto(numbered(i), proxy.listen_address)
        if paced:  # wait until the proxy has consumed it, so the socket buffers never overflow
            deadline = time.monotonic() + WAIT_S
            while proxy.counters("to_target")["received"] <= i and time.monotonic() < deadline:
                d = target.recv(0.001)
                if d is not None:
                    got.append(d)
    return got + target.drain()


def test_relays_both_directions_and_learns_the_client(endpoints):
    client, target = endpoints
    with make_proxy(target) as proxy:
        client.sock.sendto(b"hello", proxy.listen_address)
        assert target.recv() == b"hello"
        assert proxy.client_address == client.address
        target.sock.sendto(b"reply", proxy.target_side_address)
        assert client.recv() == b"reply"
        assert proxy.counters("to_target")["forwarded"] == 1
        assert proxy.counters("from_target")["forwarded"] == 1


def test_reply_before_any_client_is_counted_not_crashed(endpoints):
    client, target = endpoints
    with make_proxy(target) as proxy:
        target.sock.sendto(b"early", proxy.target_side_address)
        deadline = time.monotonic() + WAIT_S
        while proxy.counters("from_target")["no_peer"] == 0 and time.monotonic() < deadline:
            time.sleep(0.001)
        assert proxy.counters("from_target")["no_peer"] == 1


def test_independent_loss_rate_matches_probability(endpoints):
    client, target = endpoints
    n, p = 2000, 0.2
    with make_proxy(target, to_target=ImpairmentSettings(loss=p), seed=7) as proxy:
        got = send_numbered(client, proxy, n, target)
        c = proxy.counters("to_target")
    assert c["received"] == n
    assert c["lost_random"] + c["forwarded"] == n
    assert len(got) == c["forwarded"]
    sigma = math.sqrt(n * p * (1 - p))
    assert abs(c["lost_random"] - n * p) < 4 * sigma
    assert got == sorted(got)  # loss alone never reorders


def test_bursty_loss_has_the_configured_mean_rate_and_burst_length(endpoints):
    client, target = endpoints
    n = 4000
    settings = ImpairmentSettings.bursty(mean_loss=0.2, mean_burst_len=8.0)
    with make_proxy(target, to_target=settings, seed=3) as proxy:
        got = send_numbered(client, proxy, n, target)
        c = proxy.counters("to_target")
    arrived = {int(d[3:]) for d in got}
    lost = [i not in arrived for i in range(n)]
    bursts, run = [], 0
    for is_lost in lost:
        if is_lost:
            run += 1
        elif run:
            bursts.append(run)
            run = 0
    assert c["lost_burst"] == sum(lost)
    assert 0.13 < sum(lost) / n < 0.27
    mean_burst = sum(bursts) / len(bursts)
    assert 5.0 < mean_burst < 11.0  # geometric with mean 8; independent 20 % loss would give ~1.25


def test_duplication_sends_exact_copies(endpoints):
    client, target = endpoints
    n = 500
    with make_proxy(target, to_target=ImpairmentSettings(duplicate=0.3), seed=1) as proxy:
        got = send_numbered(client, proxy, n, target)
        c = proxy.counters("to_target")
    assert len(got) == n + c["duplicated"]
    assert 0.2 * n < c["duplicated"] < 0.4 * n
    assert sorted(set(got)) == [numbered(i) for i in range(n)]


def test_corruption_flips_the_configured_number_of_bytes(endpoints):
    client, target = endpoints
    n = 300
    with make_proxy(target, to_target=ImpairmentSettings(corrupt=0.5, corrupt_bytes=1), seed=2) as proxy:
        got = send_numbered(client, proxy, n, target)
        c = proxy.counters("to_target")
    assert len(got) == n
    damaged = 0
    for i, d in enumerate(got):
        diff = sum(a != b for a, b in zip(d, numbered(i)))
        assert diff <= 1
        damaged += diff
    assert damaged == c["corrupted"]
    assert 0.4 * n < damaged < 0.6 * n


def test_reordering_swaps_neighbours_and_loses_nothing(endpoints):
    client, target = endpoints
    n = 400
    with make_proxy(target, to_target=ImpairmentSettings(reorder=0.2), seed=5) as proxy:
        got = send_numbered(client, proxy, n, target)
        c = proxy.counters("to_target")
    order = [int(d[3:]) for d in got]
    assert sorted(order) == list(range(n))
    inversions = sum(1 for a, b in zip(order, order[1:]) if a > b)
    assert inversions == c["reordered"] > 0.1 * n


def test_outage_switched_at_runtime_drops_everything_then_recovers(endpoints):
    client, target = endpoints
    with make_proxy(target) as proxy:
        assert send_numbered(client, proxy, 10, target) == [numbered(i) for i in range(10)]
        proxy.configure(outage=True)
        client.sock.sendto(b"lost", proxy.listen_address)
        target.sock.sendto(b"lost too", proxy.target_side_address)
        deadline = time.monotonic() + WAIT_S
        while proxy.counters("from_target")["lost_outage"] == 0 and time.monotonic() < deadline:
            time.sleep(0.001)
        assert target.drain(0.05) == [] and client.drain(0.05) == []
        proxy.configure(outage=False)
        client.sock.sendto(b"back", proxy.listen_address)
        assert target.recv() == b"back"
        assert proxy.counters("to_target")["lost_outage"] == 1


def test_wall_clock_delay_holds_each_datagram_at_least_the_delay(endpoints):
    client, target = endpoints
    delay_s = 0.05
    with make_proxy(target, to_target=ImpairmentSettings(delay_s=delay_s)) as proxy:
        for i in range(5):
            sent = time.monotonic()
            client.sock.sendto(numbered(i), proxy.listen_address)
            assert target.recv() == numbered(i)
            assert time.monotonic() - sent >= delay_s  # lower bound only: upper bounds are load-dependent
        assert proxy.counters("to_target")["delayed"] == 5


def test_vehicle_clock_delay_releases_after_exactly_the_vehicle_time(endpoints):
    """Lockstep-style: an answer is held until an answer sent 20 ms of vehicle time later arrives."""
    client, target = endpoints
    with make_proxy(target, clock="vehicle", max_hold_wall_s=60.0) as proxy:
        proxy.configure("to_target", delay_s=0.020)
        target.sock.sendto(attitude_frame(1000), proxy.target_side_address)  # no client yet
        deadline = time.monotonic() + WAIT_S
        while proxy.vehicle_time_s is None and time.monotonic() < deadline:
            time.sleep(0.001)
        client.sock.sendto(b"answer 1000", proxy.listen_address)  # stamped with vehicle time 1.000 s
        released = []
        for k in range(1, 15):  # 400 Hz ATTITUDE: 2.5 ms steps, each answered by the client
            t_ms = 1000 + round(k * 2.5)
            target.sock.sendto(attitude_frame(t_ms, k), proxy.target_side_address)
            assert client.recv() is not None
            client.sock.sendto(b"answer %d" % t_ms, proxy.listen_address)
            got = target.recv(0.5 if t_ms >= 1020 else 0.02)
            if got is not None:
                released.append((t_ms, got))
        # the answer to 1000 goes out when the answer to 1020 arrives, one answer per step after that
        assert released[0] == (1020, b"answer 1000")
        assert [r[1] for r in released] == [b"answer %d" % (1000 + round(k * 2.5)) for k in range(0, len(released))]
        assert proxy.counters("to_target")["delayed"] == 15


def test_lockstep_fill_replaces_lost_control_packets_with_the_last_command(endpoints):
    client, target = endpoints
    cmd_mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
    command = cmd_mav.set_attitude_target_encode(0, 1, 1, 0x80, [0, 0, 0, 0], 0.1, 0.0, 0.0, 0.5).pack(cmd_mav)
    with make_proxy(target, lockstep_fill=True) as proxy:
        client.sock.sendto(command, proxy.listen_address)
        assert target.recv() == command
        proxy.configure(loss=1.0)
        target.sock.sendto(attitude_frame(5), proxy.target_side_address)  # lost ATTITUDE -> last command again
        assert target.recv() == command
        client.sock.sendto(command[:-1] + b"x", proxy.listen_address)  # lost command -> the previous one
        assert target.recv() == command
        client.sock.sendto(b"not mavlink", proxy.listen_address)  # other losses are not filled
        assert target.recv(0.1) is None
        assert proxy.counters("from_target")["filled"] == 1
        assert proxy.counters("to_target")["filled"] == 1


def test_outage_window_in_vehicle_time(endpoints):
    client, target = endpoints
    window = ImpairmentSettings(outage_windows=((1.010, 1.020),))
    with make_proxy(target, clock="vehicle", from_target=window) as proxy:
        client.sock.sendto(b"hi", proxy.listen_address)
        assert target.recv() == b"hi"
        arrived = []
        for t_ms in range(1000, 1030, 5):
            target.sock.sendto(attitude_frame(t_ms), proxy.target_side_address)
        for d in client.drain():
            arrived.append(round(attitude_time_s(d) * 1000))
        assert arrived == [1000, 1005, 1020, 1025]
        assert proxy.counters("from_target")["lost_outage"] == 2


def test_inject_sends_raw_bytes_to_the_chosen_side(endpoints):
    client, target = endpoints
    with make_proxy(target) as proxy:
        assert proxy.inject("from_target", b"x") is False  # no client known yet
        client.sock.sendto(b"hi", proxy.listen_address)
        assert target.recv() == b"hi"
        assert proxy.inject("from_target", b"\xfd\x00garbage")
        assert client.recv() == b"\xfd\x00garbage"
        assert proxy.inject("to_target", b"junk")
        assert target.recv() == b"junk"
        assert proxy.counters("to_target")["injected"] == 1


def test_tap_sees_every_datagram_before_impairment(endpoints):
    client, target = endpoints
    seen = []
    with make_proxy(target, to_target=ImpairmentSettings(loss=1.0), tap=lambda d, b, t: seen.append((d, b, t))) as proxy:
        client.sock.sendto(b"one", proxy.listen_address)
        deadline = time.monotonic() + WAIT_S
        while proxy.counters("to_target")["lost_random"] == 0 and time.monotonic() < deadline:
            time.sleep(0.001)
        assert seen == [("to_target", b"one", None)]
        assert proxy.counters("to_target")["lost_random"] == 1


def test_settle_returns_only_after_a_datagram_seen_by_the_tap_has_been_sent_on(endpoints):
    """The SITL restart tests rely on this barrier: a relay thread starved between tap and sendto must not
    deliver an old datagram after the caller moved on (it once leaked a hold setpoint to a restarted sim)."""
    import threading

    client, target = endpoints
    in_tap, release = threading.Event(), threading.Event()

    def stalled_tap(direction, datagram, vehicle_time_s):
        in_tap.set()
        release.wait(WAIT_S)  # the relay thread descheduled right after the tap

    with make_proxy(target, tap=stalled_tap) as proxy:
        client.sock.sendto(b"old", proxy.listen_address)
        assert in_tap.wait(WAIT_S)
        settled = threading.Event()
        waiter = threading.Thread(target=lambda: (proxy.settle(), settled.set()))
        waiter.start()
        assert not settled.wait(0.05), "settle() returned while the datagram was still inside the relay"
        assert target.recv(0.01) is None
        release.set()
        waiter.join(WAIT_S)
        assert settled.is_set()
        target.sock.settimeout(0.0)
        assert target.sock.recvfrom(65535)[0] == b"old"  # already delivered when settle() returned


def test_lockstep_fill_covers_an_answer_held_back_by_reordering(endpoints):
    client, target = endpoints
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
    first = mav.set_attitude_target_encode(0, 1, 1, 0x80, [0, 0, 0, 0], 0.1, 0.0, 0.0, 0.5).pack(mav)
    second = mav.set_attitude_target_encode(1, 1, 1, 0x80, [0, 0, 0, 0], 0.2, 0.0, 0.0, 0.5).pack(mav)
    third = mav.set_attitude_target_encode(2, 1, 1, 0x80, [0, 0, 0, 0], 0.3, 0.0, 0.0, 0.5).pack(mav)
    with make_proxy(target, lockstep_fill=True) as proxy:
        client.sock.sendto(first, proxy.listen_address)
        assert target.recv() == first
        proxy.configure("to_target", reorder=1.0)
        client.sock.sendto(second, proxy.listen_address)  # held back: the vehicle gets the last command now
        assert target.recv() == first
        proxy.configure("to_target", reorder=0.0)  # releases the held one
        assert target.recv() == second
        client.sock.sendto(third, proxy.listen_address)
        assert target.recv() == third
        assert proxy.counters("to_target")["filled"] == 1


def test_same_seed_same_faults(endpoints):
    client, target = endpoints
    results = []
    for _ in range(2):
        with make_proxy(target, to_target=ImpairmentSettings(loss=0.3, duplicate=0.2, reorder=0.1), seed=11) as proxy:
            results.append(send_numbered(client, proxy, 200, target))
    assert results[0] == results[1]


def test_stop_closes_sockets_and_thread(endpoints):
    _, target = endpoints
    proxy = make_proxy(target)
    port = proxy.listen_address[1]
    proxy.stop()
    assert proxy._thread is not None and not proxy._thread.is_alive()
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind(("127.0.0.1", port))  # the port is free again
    finally:
        probe.close()


def test_header_peek_reads_mavlink_ids_and_attitude_time():
    frame = attitude_frame(123456)
    assert mavlink_msgid(frame) == 30
    assert attitude_time_s(frame) == pytest.approx(123.456)
    assert mavlink_msgid(b"\x00\x01") is None
    assert attitude_time_s(frame[:11]) is None


@pytest.mark.parametrize("bad", [dict(loss=1.5), dict(duplicate=-0.1), dict(delay_s=-1.0), dict(delay_s=float("nan")),
                                 dict(corrupt_bytes=0), dict(outage_windows=((2.0, 1.0),))])
def test_invalid_settings_are_rejected_with_the_field_name(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        ImpairmentSettings(**bad)


def test_bursty_parameters():
    s = ImpairmentSettings.bursty(0.2, 5.0)
    assert s.burst_exit == pytest.approx(0.2)
    assert s.burst_enter / (s.burst_enter + s.burst_exit) == pytest.approx(0.2)


def test_parse_host_port():
    assert parse_host_port("127.0.0.1:14550") == ("127.0.0.1", 14550)
    for bad in ("14550", "host:", "host:99999", ":1"):
        with pytest.raises(ValueError, match="HOST:PORT"):
            parse_host_port(bad)


def test_cli_help_states_units():
    out = subprocess.run([sys.executable, "-m", "mavastsm.cli", "proxy", "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    for text in ("--delay-ms", "[ms]", "--loss", "[0..1]", "--outage-duration-s", "--seed"):
        assert text in out.stdout


def test_cli_bad_option_is_a_one_line_error(endpoints):
    _, target = endpoints
    host, port = target.address
    out = subprocess.run([sys.executable, "-m", "mavastsm.cli", "proxy", "--target", f"{host}:{port}", "--loss", "2"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "loss" in out.stderr


def test_cli_relays_and_exits_cleanly(endpoints):
    client, target = endpoints
    host, port = target.address
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    listen_port = probe.getsockname()[1]
    probe.close()  # a free port for the subprocess (tiny race accepted: loopback, test-only)
    proc = subprocess.Popen([sys.executable, "-m", "mavastsm.cli", "proxy", "--listen", f"127.0.0.1:{listen_port}",
                             "--target", f"{host}:{port}", "--duration-s", "30", "--stats-interval-s", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "listening on" in proc.stdout.readline()
        client.sock.sendto(b"through", ("127.0.0.1", listen_port))
        assert target.recv() == b"through"
        proc.terminate()
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0
        assert "forwarded=1" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("argv,needle", [
    (["--loss", "2"], "--loss 2: must be a probability in [0, 1]"),
    (["--duplicate", "-0.1"], "--duplicate -0.1: must be a probability"),
    (["--jitter-ms", "-5"], "--jitter-ms -5: must be within"),
])
def test_bad_impairment_options_name_the_option_not_an_internal_class(argv, needle, capsys):
    """The ux issue, item 10: `ImpairmentSettings.loss must be a probability` named a class the user never typed."""
    from mavastsm.cli import main

    assert main(["proxy", "--listen", "127.0.0.1:0", "--target", "127.0.0.1:9", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and "ImpairmentSettings" not in err[0], err
