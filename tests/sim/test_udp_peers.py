"""``UdpPeers``: who receives our datagrams. Fixed targets always; a heard peer until it has been silent for
longer than ``peer_timeout_s`` (wall clock injected); the cached peer list follows every change."""

from __future__ import annotations

import socket

import pytest

from mavastsm_sim.udp_transport import UdpPeers


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


@pytest.fixture
def transport_and_peers():
    clock = FakeClock()
    transport = UdpPeers(bind=("127.0.0.1", 0), targets=[("127.0.0.1", 9)], peer_timeout_s=10.0, wall_clock=clock)
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    try:
        yield transport, socks, clock
    finally:
        transport.close()
        for s in socks:
            s.close()


def _hear(transport: UdpPeers, sock: socket.socket, valid: bool = True) -> None:
    """``sock`` talks to the transport; returns once the transport has read it (bounded wait). ``valid``: the
    vehicle found a valid frame in it and admitted the sender."""
    sock.sendto(b"hello", transport.address)
    assert transport.wait_readable(5.0)
    got = transport.receive_pending()
    assert [addr for _, addr in got] == [sock.getsockname()]
    if valid:
        transport.admit(got[0][1])


def test_a_sender_is_a_peer_only_once_admitted(transport_and_peers) -> None:
    """Junk from an address (nothing the vehicle found valid) never makes it a peer: no fan-out, no table entry."""
    transport, (a, b), clock = transport_and_peers
    _hear(transport, a, valid=False)
    assert transport.peers() == [("127.0.0.1", 9)]
    _hear(transport, a)
    assert transport.peers() == [("127.0.0.1", 9), a.getsockname()]


def test_the_peer_table_is_bounded_and_a_full_table_refuses_new_senders_until_one_expires() -> None:
    """Established peers keep their stream whatever arrives from new addresses; a slot frees when a peer expires."""
    clock = FakeClock()
    transport = UdpPeers(bind=("127.0.0.1", 0), peer_timeout_s=10.0, wall_clock=clock, max_peers=3)
    try:
        for i in range(3):
            clock.now_s += 1.0
            assert transport.admit(("127.0.0.1", 1000 + i))
        assert not transport.admit(("127.0.0.1", 1003)) and not transport.admit(("127.0.0.1", 1004))
        assert transport.peers() == [("127.0.0.1", 1000), ("127.0.0.1", 1001), ("127.0.0.1", 1002)]
        assert transport.peers_refused == 2
        clock.now_s += 5.0
        assert not transport.admit(("127.0.0.1", 1001))  # heard again: not new
        clock.now_s += 4.5  # 1000 silent 10.5 s: expired, a slot is free
        assert transport.admit(("127.0.0.1", 1005))
        assert transport.peers() == [("127.0.0.1", 1001), ("127.0.0.1", 1002), ("127.0.0.1", 1005)]
    finally:
        transport.close()


def test_peers_expire_after_silence_and_come_back(transport_and_peers) -> None:
    transport, (a, b), clock = transport_and_peers
    target = ("127.0.0.1", 9)
    assert transport.peers() == [target]
    _hear(transport, a)
    assert transport.peers() == [target, a.getsockname()]
    clock.now_s += 6.0
    _hear(transport, b)
    assert transport.peers() == [target, a.getsockname(), b.getsockname()]
    clock.now_s += 4.0  # a silent for exactly 10 s: still a peer (stale means longer than the timeout)
    assert transport.peers() == [target, a.getsockname(), b.getsockname()]
    clock.now_s += 0.5  # a silent 10.5 s: dropped; b (4.5 s) stays
    assert transport.peers() == [target, b.getsockname()]
    _hear(transport, a)  # a talks again: back, after b
    assert transport.peers() == [target, b.getsockname(), a.getsockname()]
    clock.now_s += 5.6  # b silent 10.1 s
    assert transport.peers() == [target, a.getsockname()]
    clock.now_s += 20.0
    assert transport.peers() == [target]
    _hear(transport, b)
    assert transport.peers() == [target, b.getsockname()]


def test_send_reaches_every_live_peer_and_a_target_is_never_doubled(transport_and_peers) -> None:
    transport, (a, b), clock = transport_and_peers
    _hear(transport, a)
    _hear(transport, b)
    transport.send(b"frame")
    for s in (a, b):
        s.settimeout(5.0)
        assert s.recvfrom(100)[0] == b"frame"
    clock.now_s += 11.0
    transport.send(b"late")  # both silent > 10 s: only the fixed target gets it
    assert transport.peers() == [("127.0.0.1", 9)]
    listed = transport.peers()
    listed.append(("10.0.0.1", 1))  # the returned list is a copy
    assert transport.peers() == [("127.0.0.1", 9)]
