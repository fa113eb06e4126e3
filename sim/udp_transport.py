"""UDP transport of the simulated vehicle: one socket, fixed targets plus every peer heard recently.

Two ways to reach the vehicle, which can be combined:

* **client mode** (the default of ``mavastsm sim``), like ArduPilot SITL's ``udpclient``: the socket binds
  an ephemeral loopback port and sends to a fixed target such as ``127.0.0.1:14550``, where the bridge or
  MAVProxy listens (``udpin``/``udp:`` in pymavlink).
* **server mode** (``--listen``): the socket binds a known address and answers whoever talks to it, like
  pymavlink's ``udpin``. Several peers (bridge + MAVProxy) can talk at once; every datagram goes to every
  peer heard within ``peer_timeout_s`` (a peer that stays silent longer is forgotten). A sender becomes a
  peer only when the vehicle *admits* it (after a valid MAVLink frame from it, signed when signing is on),
  and at most ``max_peers`` are kept: while the table is full a new sender is refused (counted), so the
  established peers keep their stream until they fall silent, and neither junk nor valid frames from any
  number of source addresses grow the fan-out or the peer table.

Binds to loopback unless told otherwise. No MAVLink here: bytes in, bytes out.
"""

from __future__ import annotations

import select
import socket
import time
from typing import Callable

Address = tuple[str, int]

MAX_DATAGRAM_BYTES = 65535


def parse_udp_endpoint(text: str, what: str) -> Address:
    """Parse ``udp:HOST:PORT``, ``udpout:HOST:PORT`` or ``HOST:PORT`` into (host, port).

    Raises ValueError with a one-line message naming ``what`` on bad input.
    """
    body = text
    for prefix in ("udp:", "udpout:", "udpin:"):
        if body.startswith(prefix):
            body = body[len(prefix):]
            break
    host, sep, port_text = body.rpartition(":")
    if not sep or not host:
        raise ValueError(f"{what}: {text!r} is not HOST:PORT (e.g. udp:127.0.0.1:14550)")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"{what}: port {port_text!r} in {text!r} is not an integer") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{what}: port {port} in {text!r} is outside 0..65535")
    return host, port


class UdpPeers:
    """A UDP socket that sends each datagram to its fixed targets and to recently heard peers.

    Parameters
    ----------
    bind : (host, port)
        Local address; port 0 picks an ephemeral port (see :attr:`port`).
    targets : sequence of (host, port)
        Always sent to (client mode), whether heard from or not.
    peer_timeout_s : float
        A peer not heard for this long [wall s] stops receiving datagrams.
    max_peers : int
        Most admitted peers at once; while full, a new sender is refused (``peers_refused``) until one expires.
    wall_clock : callable
        Monotonic wall clock [s].
    """

    def __init__(self, bind: Address = ("127.0.0.1", 0), targets: tuple[Address, ...] | list[Address] = (),
                 peer_timeout_s: float = 10.0, wall_clock: Callable[[], float] = time.monotonic, max_peers: int = 16) -> None:
        self._wall_clock = wall_clock
        self._peer_timeout_s = float(peer_timeout_s)
        self._max_peers = int(max_peers)
        self.peers_refused = 0
        self._targets: list[Address] = [(socket.gethostbyname(h), int(p)) for h, p in targets]
        self._heard: dict[Address, float] = {}
        # send() runs for every datagram: the peer list is rebuilt only when a peer is added or dropped, and
        # the heard times are scanned only when the oldest could have gone stale (a lower bound on them)
        self._peer_list: list[Address] | None = None
        self._oldest_heard_bound_s = 0.0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            self.sock.bind(bind)
        except OSError:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        host, port = self.sock.getsockname()[:2]
        self._address: Address = (host, port)  # kept so .port still answers after close()
        self.send_errors = 0
        self.datagrams_in = 0
        self.datagrams_out = 0

    @property
    def port(self) -> int:
        """Bound local UDP port."""
        return self._address[1]

    @property
    def address(self) -> Address:
        """Bound local (host, port)."""
        return self._address

    def peers(self) -> list[Address]:
        """Addresses that currently receive our datagrams: fixed targets plus live heard peers."""
        return list(self._live_peers())

    def _live_peers(self) -> list[Address]:
        heard = self._heard
        if heard:
            now = self._wall_clock()
            if now - self._oldest_heard_bound_s > self._peer_timeout_s:  # someone may be stale: scan
                stale = [a for a, t in heard.items() if now - t > self._peer_timeout_s]
                for a in stale:
                    del heard[a]
                if stale:
                    self._peer_list = None
                self._oldest_heard_bound_s = min(heard.values(), default=now)
        out = self._peer_list
        if out is None:
            out = list(self._targets)
            out.extend(a for a in heard if a not in out)
            self._peer_list = out
        return out

    def send(self, data: bytes) -> None:
        """Send one datagram to every peer; errors are counted, never raised."""
        for addr in self._live_peers():
            try:
                self.sock.sendto(data, addr)
                self.datagrams_out += 1
            except OSError:
                self.send_errors += 1

    def receive_pending(self, max_datagrams: int = 256) -> list[tuple[bytes, Address]]:
        """Return the datagrams already waiting (never blocks). Senders are not peers until :meth:`admit`."""
        got: list[tuple[bytes, Address]] = []
        for _ in range(max_datagrams):
            try:
                data, addr = self.sock.recvfrom(MAX_DATAGRAM_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port-unreachable reported on some platforms
                self.send_errors += 1
                continue
            self.datagrams_in += 1
            got.append((data, (addr[0], addr[1])))
        return got

    def admit(self, addr: Address) -> bool:
        """``addr`` sent a valid frame: it is (still) a peer, heard now. True when it is a new peer; False also
        when the table is full (after stale peers are dropped) and ``addr`` is refused."""
        heard = self._heard
        new = addr not in heard
        if new and len(heard) >= self._max_peers:
            self._live_peers()  # drops the stale ones
            if len(heard) >= self._max_peers:
                self.peers_refused += 1
                return False
        now = self._wall_clock()
        if new:
            if not heard:
                self._oldest_heard_bound_s = now
            self._peer_list = None
        heard[addr] = now
        return new

    def wait_readable(self, timeout_s: float) -> bool:
        """Block up to ``timeout_s`` [wall s] until a datagram is waiting; True if one is."""
        try:
            ready, _, _ = select.select([self.sock], [], [], max(timeout_s, 0.0))
        except (OSError, ValueError):
            return False
        return bool(ready)

    def close(self) -> None:
        """Close the socket (idempotent)."""
        try:
            self.sock.close()
        except OSError:
            pass
