"""A flood of new source addresses must not stall the sim (hostile issue, defect 2): a sender becomes a peer only
with a valid frame, and the peer table is bounded, so neither greetings nor the fan-out grow with junk sources."""

from __future__ import annotations

import resource
import socket
import threading

import pytest
from mavlink_peer_tools import ATTITUDE_ID, mavlink

FLOOD_ADDRESSES = 2000


def flood(port: int, n: int, payload) -> None:
    """One datagram from each of ``n`` distinct source ports: the sockets stay open until all have sent, so the
    kernel cannot hand a closed one's port to the next."""
    socks = []
    try:
        for i in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            socks.append(s)
            s.sendto(payload(i), ("127.0.0.1", port))
    finally:
        for s in socks:
            s.close()


@pytest.fixture(autouse=True)
def enough_file_descriptors():
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = FLOOD_ADDRESSES + 256
    if soft < need:
        if hard != resource.RLIM_INFINITY and hard < need:
            pytest.fail(f"RLIMIT_NOFILE hard limit {hard} < {need}: cannot open one socket per flood address")
        resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def valid_heartbeat(i: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=100 + i % 100, srcComponent=190)
    return bytes(mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(mav))


@pytest.mark.parametrize("kind", ["junk", "valid"])
def test_a_flood_of_new_addresses_keeps_attitude_on_time(make_server, make_gcs, kind):
    """2000 addresses, one datagram each (1 junk byte, or a valid unsigned HEARTBEAT), while the GCS receives
    ATTITUDE at 100 Hz: the largest gap in ATTITUDE's time_boot_ms stays under 50 ms, the peer table at most its
    bound (16) with the GCS still in it. Before: every new address was a peer and got a greeting sent to all peers (gaps 2.1-6.8 s at 2000)."""
    server = make_server(clock="realtime")
    gcs = make_gcs(server.port)
    gcs.hello()
    assert gcs.set_interval(ATTITUDE_ID, 100.0).result == mavlink.MAV_RESULT_ACCEPTED
    payload = (lambda i: b"\x00") if kind == "junk" else valid_heartbeat
    attacker = threading.Thread(target=flood, args=(server.port, FLOOD_ADDRESSES, payload))
    times: list[int] = []
    first = gcs.recv("ATTITUDE", 2.0)
    assert first is not None
    times.append(first.time_boot_ms)
    attacker.start()
    try:
        while attacker.is_alive() or len(times) < 50:
            msg = gcs.recv("ATTITUDE", 2.0)
            assert msg is not None, "ATTITUDE stopped"
            times.append(msg.time_boot_ms)
    finally:
        attacker.join(60.0)
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert max(gaps) < 50, (max(gaps), len(times))
    assert server.wait_until(lambda c: server.counters["datagrams_in"] >= FLOOD_ADDRESSES, timeout_s=5.0)
    counters = server.counters
    if kind == "junk":
        assert counters["peers"] == 1 and counters["peers_refused"] == 0  # only the GCS
    else:
        assert server.wait_until(lambda c: server.counters["peers_refused"] == FLOOD_ADDRESSES - 15, timeout_s=5.0), {k: v for k, v in server.counters.items() if k.startswith(("peers", "datagrams", "messages"))}
        assert server.counters["peers"] == 16  # the GCS kept its slot
    assert gcs.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 0).result == mavlink.MAV_RESULT_ACCEPTED  # GCS still served
