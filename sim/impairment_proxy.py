"""UDP impairment relay placed between the bridge and the vehicle (``mavastsm proxy``).

One datagram in, zero or more datagrams out. The proxy binds a *listen* socket (the peer that
talks to it first is the "client", e.g. the bridge with ``udpout:``) and relays everything to a
fixed *target* (e.g. the sim in server mode) from a second, ephemeral socket; replies from the
target go back to the last client heard. Both directions can be impaired independently:

* ``to_target``   : client -> target datagrams (e.g. bridge -> vehicle: SET_ATTITUDE_TARGET)
* ``from_target`` : target -> client datagrams (e.g. vehicle -> bridge: ATTITUDE)

Faults, applied per datagram in this order: outage window -> loss (independent, or bursty with a
two-state Gilbert-Elliott chain) -> byte corruption -> reordering (hold one datagram and emit it
after the next one) -> duplication -> delay + jitter. Every decision draws from a per-direction
``random.Random`` seeded from ``seed``, so the same packet sequence gives the same faults.

Clocks. ``clock="wall"`` delays in real (monotonic) seconds. ``clock="vehicle"`` delays in
*vehicle* seconds: the proxy reads ``time_boot_ms`` from every MAVLink ATTITUDE (msg 30) that
passes in either direction, stamps each datagram with the vehicle time at its arrival, and
releases it when a later datagram *in the same direction* arrives at a vehicle time at least its
delay later. With a lockstep sim this is exact: the bridge's answer to ATTITUDE k is released
when the bridge answers ATTITUDE k+N (N = delay x rate), so the sim gets exactly one answer per
step, N steps late, however loaded the machine is (a 20 ms delay is 8 periods at 400 Hz). Until
the first ATTITUDE is seen, vehicle-clock delays are zero (so a connection handshake never
deadlocks), and ``max_hold_wall_s`` bounds how long anything is held in real time.

Lockstep fill (``lockstep_fill=True``, for lockstep sims only). A lockstep sim waits after each
ATTITUDE for a SET_ATTITUDE_TARGET (or a wall-clock timeout). When a fault means that answer will
not come at this step (the ATTITUDE was lost or held back on its way to the bridge, or the
bridge's answer was lost or held back and nothing older was released in its place), the proxy
sends the vehicle a copy of the last SET_ATTITUDE_TARGET it delivered, so the sim steps on at once
holding the previous command: what ArduCopter does when an update is missing. Without it every
such step costs a gate timeout of wall time, and the bridge's host-clock timeouts (stale ATTITUDE,
heartbeat link loss) would measure the gate, not the fault. The copy also refreshes the sim's
GUID_TIMEOUT timer, so outages are never filled (``outage`` drops without a copy).

The proxy only peeks at the MAVLink header (``0xFD``/``0xFE`` framing, message id) and at the first
four payload bytes of ATTITUDE: it does not need pymavlink and never re-encodes a frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import heapq
import itertools
import random
import selectors
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

DIRECTIONS = ("to_target", "from_target")
ATTITUDE_MSGID = 30
SET_ATTITUDE_TARGET_MSGID = 82
_MAX_DATAGRAM = 65535


@dataclass(frozen=True)
class ImpairmentSettings:
    """Faults for one direction. Probabilities are per datagram in [0, 1].

    Attributes
    ----------
    loss : [0..1] drop probability in the Gilbert-Elliott *good* state (= independent loss when
        ``burst_enter`` is 0).
    burst_enter : [0..1] probability per datagram of going good -> bad (0 disables bursts).
    burst_exit : [0..1] probability per datagram of going bad -> good (mean burst = 1/burst_exit datagrams).
    burst_loss : [0..1] drop probability in the *bad* state.
    delay_s : [s] fixed one-way delay (wall or vehicle seconds, see ``ImpairmentProxy.clock``).
    jitter_s : [s] extra delay drawn uniformly from [0, jitter_s] per datagram (may reorder).
    duplicate : [0..1] probability a datagram is sent twice.
    reorder : [0..1] probability a datagram is held back and sent after the next one.
    corrupt : [0..1] probability of flipping ``corrupt_bytes`` random bytes of a datagram.
    corrupt_bytes : number of bytes flipped (XOR with a random non-zero byte) when corrupting.
    outage : drop everything while True (switch it at runtime for a window of any length).
    outage_windows : ((start_s, end_s), ...) on the proxy clock (vehicle time, or wall seconds
        since start) during which everything is dropped.
    """

    loss: float = 0.0
    burst_enter: float = 0.0
    burst_exit: float = 1.0
    burst_loss: float = 1.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0
    corrupt_bytes: int = 1
    outage: bool = False
    outage_windows: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("loss", "burst_enter", "burst_exit", "burst_loss", "duplicate", "reorder", "corrupt"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise ValueError(f"ImpairmentSettings.{name} must be a probability in [0, 1], got {v!r}")
        for name in ("delay_s", "jitter_s"):
            v = getattr(self, name)
            if not (v >= 0.0 and v < 3600.0):
                raise ValueError(f"ImpairmentSettings.{name} must be in [0, 3600) s, got {v!r}")
        if self.corrupt_bytes < 1:
            raise ValueError(f"ImpairmentSettings.corrupt_bytes must be >= 1, got {self.corrupt_bytes!r}")
        for w in self.outage_windows:
            if len(w) != 2 or not w[0] <= w[1]:
                raise ValueError(f"ImpairmentSettings.outage_windows entries must be (start_s, end_s) with start <= end, got {w!r}")

    @classmethod
    def bursty(cls, mean_loss: float, mean_burst_len: float, **others) -> "ImpairmentSettings":
        """Gilbert-Elliott loss with everything lost in the bad state and nothing in the good one.

        Stationary loss = P(bad) = enter / (enter + exit) = ``mean_loss``; mean burst length
        = 1 / exit = ``mean_burst_len`` datagrams.
        """
        if not (0.0 <= mean_loss < 1.0) or mean_burst_len < 1.0:
            raise ValueError(f"bursty loss needs 0 <= mean_loss < 1 and mean_burst_len >= 1, got {mean_loss!r}, {mean_burst_len!r}")
        exit_p = 1.0 / mean_burst_len
        enter_p = exit_p * mean_loss / (1.0 - mean_loss)
        return cls(loss=0.0, burst_enter=enter_p, burst_exit=exit_p, burst_loss=1.0, **others)


def _new_counters() -> dict[str, int]:
    return dict.fromkeys(
        ("received", "forwarded", "lost_outage", "lost_random", "lost_burst", "corrupted",
         "reordered", "duplicated", "delayed", "injected", "no_peer", "send_errors", "tap_errors", "filled"), 0)


def mavlink_msgid(datagram: bytes) -> int | None:
    """Message id of the first MAVLink frame in ``datagram`` (v2 ``0xFD`` or v1 ``0xFE``), else None."""
    if len(datagram) >= 10 and datagram[0] == 0xFD:
        return datagram[7] | (datagram[8] << 8) | (datagram[9] << 16)
    if len(datagram) >= 6 and datagram[0] == 0xFE:
        return datagram[5]
    return None


def attitude_time_s(datagram: bytes) -> float | None:
    """[s, vehicle clock] ``time_boot_ms``/1000 of an ATTITUDE frame, else None (header peek only)."""
    msgid = mavlink_msgid(datagram)
    if msgid != ATTITUDE_MSGID:
        return None
    start = 10 if datagram[0] == 0xFD else 6
    length = datagram[1]
    if length < 4 or len(datagram) < start + 4:
        return None  # MAVLink 2 trims trailing zeros; a payload this short is not a usable stamp
    return struct.unpack_from("<I", datagram, start)[0] / 1000.0


def parse_host_port(text: str) -> tuple[str, int]:
    """``"127.0.0.1:14550"`` -> ``("127.0.0.1", 14550)``; raises ValueError with the text on failure."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"expected HOST:PORT (e.g. 127.0.0.1:14550), got {text!r}")
    return host, int(port)


class _Direction:
    """Mutable per-direction state: settings, RNG, Gilbert-Elliott state, reorder slot, counters."""

    def __init__(self, settings: ImpairmentSettings, seed: int) -> None:
        self.settings = settings
        self.rng = random.Random(seed)
        self.bad_state = False
        self.reorder_slot: tuple[bytes, float] | None = None  # (datagram, wall time held)
        self.counters = _new_counters()


class ImpairmentProxy:
    """Seeded, runtime-configurable UDP impairment relay running on one daemon thread.

    Parameters
    ----------
    target : (host, port) datagrams from the client are relayed to.
    listen : (host, port) to bind for the client side; port 0 picks an ephemeral port
        (read it back from ``listen_address`` after ``start``).
    to_target, from_target : initial ``ImpairmentSettings`` per direction (default: none).
    seed : base seed; direction i uses ``seed * 2 + i``.
    clock : ``"wall"`` (monotonic seconds) or ``"vehicle"`` (ATTITUDE.time_boot_ms, see module doc).
    max_hold_wall_s : [s] upper bound on how long any datagram is held in real time.
    tap : optional ``tap(direction, datagram, vehicle_time_s)`` called (on the relay thread) for every
        datagram received, before any impairment: lets tests see exactly what each side sent.
    lockstep_fill : when an ATTITUDE / SET_ATTITUDE_TARGET is lost or held back, send the target a
        copy of the last SET_ATTITUDE_TARGET delivered (see module docstring).
    wall_clock : injectable monotonic clock (tests).

    Use as a context manager, or call ``start()`` / ``stop()``. ``stop()`` joins the thread and
    closes both sockets; held datagrams are discarded.
    """

    def __init__(
        self,
        target: tuple[str, int],
        listen: tuple[str, int] = ("127.0.0.1", 0),
        *,
        to_target: ImpairmentSettings | None = None,
        from_target: ImpairmentSettings | None = None,
        seed: int = 0,
        clock: str = "wall",
        max_hold_wall_s: float = 2.0,
        tap: Callable[[str, bytes, float | None], None] | None = None,
        lockstep_fill: bool = False,
        wall_clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if clock not in ("wall", "vehicle"):
            raise ValueError(f"clock must be 'wall' or 'vehicle', got {clock!r}")
        self.target = target
        self.clock = clock
        self.max_hold_wall_s = max_hold_wall_s
        self.tap = tap
        self.lockstep_fill = lockstep_fill
        self._last_command: bytes | None = None
        self._commands_sent = 0  # SET_ATTITUDE_TARGET datagrams delivered to the target
        self._attitudes_sent = 0  # ATTITUDE datagrams delivered to the client
        self._wall = wall_clock
        self._lock = threading.Lock()
        self._dirs = {
            "to_target": _Direction(to_target or ImpairmentSettings(), seed * 2),
            "from_target": _Direction(from_target or ImpairmentSettings(), seed * 2 + 1),
        }
        self._client: tuple[str, int] | None = None
        self._vehicle_time_s: float | None = None
        self._start_wall = self._wall()
        # heap of (release_clock, release_wall_deadline, seq, direction, datagram)
        self._held: list[tuple[float, float, int, str, bytes]] = []
        self._seq = itertools.count()
        self._listen_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._target_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._listen_sock.bind(listen)
            self._target_sock.bind((listen[0], 0))
        except OSError:
            self._listen_sock.close()
            self._target_sock.close()
            raise
        self._wake_r, self._wake_w = socket.socketpair()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- public API
    @property
    def listen_address(self) -> tuple[str, int]:
        """(host, port) the client side should send to."""
        return self._listen_sock.getsockname()

    @property
    def target_side_address(self) -> tuple[str, int]:
        """(host, port) the target sees the proxy's datagrams coming from."""
        return self._target_sock.getsockname()

    @property
    def client_address(self) -> tuple[str, int] | None:
        """Last client heard on the listen socket (where ``from_target`` datagrams go)."""
        return self._client

    @property
    def vehicle_time_s(self) -> float | None:
        """[s] latest ATTITUDE.time_boot_ms seen in either direction (None before the first)."""
        return self._vehicle_time_s

    def settings(self, direction: str) -> ImpairmentSettings:
        return self._dirs[self._check(direction)].settings

    def configure(self, direction: str = "both", settings: ImpairmentSettings | None = None, **changes) -> None:
        """Replace (``settings=``) or change fields of (``**changes``) one or both directions, at runtime.

        Example: ``proxy.configure("from_target", loss=0.2)``; ``proxy.configure(outage=True)``.
        """
        names = DIRECTIONS if direction == "both" else (self._check(direction),)
        with self._lock:
            for name in names:
                d = self._dirs[name]
                new = settings if settings is not None else d.settings
                d.settings = dataclasses.replace(new, **changes) if changes else new
                if d.settings.reorder == 0.0 and d.reorder_slot is not None:
                    held, d.reorder_slot = d.reorder_slot, None
                    self._schedule(name, held[0])
        self._wake()

    def clear(self, direction: str = "both") -> None:
        """Remove every impairment (held datagrams still go out at their release time)."""
        self.configure(direction, settings=ImpairmentSettings())

    def counters(self, direction: str) -> dict[str, int]:
        """Copy of the counters of one direction (received, forwarded, lost_*, corrupted, ...)."""
        with self._lock:
            return dict(self._dirs[self._check(direction)].counters)

    def settle(self) -> None:
        """Return once the datagram being relayed right now, if any, is fully handled.

        The relay thread reads a datagram, shows it to ``tap`` and sends it on, all under one lock, so a
        caller that saw a datagram in ``tap`` and then calls this knows it has also left the proxy (or been
        dropped). Without it a starved relay thread can send it after the caller has changed the world
        (e.g. after a new vehicle has bound the target port)."""
        with self._lock:
            pass

    def inject(self, direction: str, datagram: bytes) -> bool:
        """Send raw bytes as if relayed in ``direction`` (no impairment). False if no peer is known yet."""
        with self._lock:
            self._dirs[self._check(direction)].counters["injected"] += 1
            return self._send(direction, datagram, count=False)

    def start(self) -> "ImpairmentProxy":
        if self._thread is not None:
            raise RuntimeError("ImpairmentProxy already started")
        self._start_wall = self._wall()
        self._thread = threading.Thread(target=self._run, name="impairment-proxy", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the relay thread and close the sockets (idempotent)."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():  # pragma: no cover - would be a bug in _run
                raise RuntimeError("impairment proxy thread did not stop")
        for s in (self._listen_sock, self._target_sock, self._wake_r, self._wake_w):
            s.close()

    def __enter__(self) -> "ImpairmentProxy":
        return self.start() if self._thread is None else self

    def __exit__(self, *exc) -> None:
        self.stop()

    # ---------------------------------------------------------------- internals
    @staticmethod
    def _check(direction: str) -> str:
        if direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS} or 'both', got {direction!r}")
        return direction

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass

    def _now(self) -> float:
        """Proxy clock: vehicle seconds (if known, in vehicle mode) or wall seconds since start."""
        if self.clock == "vehicle" and self._vehicle_time_s is not None:
            return self._vehicle_time_s
        return self._wall() - self._start_wall

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._listen_sock, selectors.EVENT_READ, "to_target")
        sel.register(self._target_sock, selectors.EVENT_READ, "from_target")
        sel.register(self._wake_r, selectors.EVENT_READ, None)
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(self._select_timeout()):
                    if key.data is None:
                        try:
                            self._wake_r.recv(4096)
                        except OSError:
                            pass
                        continue
                    self._receive(key.fileobj, key.data)
                with self._lock:
                    self._release_due()
        finally:
            sel.close()

    def _select_timeout(self) -> float:
        with self._lock:
            deadlines = [h[1] for h in self._held]
            deadlines += [d.reorder_slot[1] + self.max_hold_wall_s for d in self._dirs.values() if d.reorder_slot]
            if self.clock == "wall":
                deadlines += [h[0] + self._start_wall for h in self._held]
        if not deadlines:
            return 0.5
        return min(0.5, max(0.0, min(deadlines) - self._wall()))

    def _receive(self, sock: socket.socket, direction: str) -> None:
        try:
            datagram, addr = sock.recvfrom(_MAX_DATAGRAM)
        except (BlockingIOError, ConnectionRefusedError, OSError):
            return  # ICMP port-unreachable from a peer that went away shows up here on Linux
        with self._lock:
            if direction == "to_target":
                self._client = addr
            t = attitude_time_s(datagram)
            if t is not None:
                self._vehicle_time_s = t
            if self.tap is not None:
                try:
                    self.tap(direction, datagram, self._vehicle_time_s)
                except Exception:  # a broken observer must not stop the relay
                    self._dirs[direction].counters["tap_errors"] += 1
            before = (self._commands_sent, self._attitudes_sent)
            self._release_due(direction)
            outage = self._impair(direction, datagram)
            if self.lockstep_fill and not outage:
                self._fill_if_unanswered(direction, datagram, before)

    def _impair(self, direction: str, datagram: bytes) -> bool:
        """Apply the faults to one arriving datagram; True when it fell into an outage."""
        d = self._dirs[direction]
        s, rng, c = d.settings, d.rng, d.counters
        c["received"] += 1
        now = self._now()
        if s.outage or any(a <= now < b for a, b in s.outage_windows):
            c["lost_outage"] += 1
            return True
        if s.burst_enter > 0.0:
            if d.bad_state:
                d.bad_state = rng.random() >= s.burst_exit
            else:
                d.bad_state = rng.random() < s.burst_enter
            if d.bad_state and rng.random() < s.burst_loss:
                c["lost_burst"] += 1
                return False
        if s.loss > 0.0 and rng.random() < s.loss:
            c["lost_random"] += 1
            return False
        if s.corrupt > 0.0 and rng.random() < s.corrupt and datagram:
            buf = bytearray(datagram)
            for _ in range(s.corrupt_bytes):
                buf[rng.randrange(len(buf))] ^= rng.randrange(1, 256)
            datagram = bytes(buf)
            c["corrupted"] += 1
        if s.reorder > 0.0 and d.reorder_slot is None and rng.random() < s.reorder:
            d.reorder_slot = (datagram, self._wall())
            c["reordered"] += 1
            return False
        copies = 2 if s.duplicate > 0.0 and rng.random() < s.duplicate else 1
        if copies == 2:
            c["duplicated"] += 1
        for _ in range(copies):
            self._schedule(direction, datagram)
        if d.reorder_slot is not None:
            held, d.reorder_slot = d.reorder_slot, None
            self._schedule(direction, held[0])
        return False

    def _fill_if_unanswered(self, direction: str, datagram: bytes, before: tuple[int, int]) -> None:
        """Lockstep fill: the arrival of an ATTITUDE that did not reach the bridge, or of an answer
        when no answer reached the vehicle, is followed by a copy of the last command."""
        if self._last_command is None:
            return
        msgid = mavlink_msgid(datagram)
        if direction == "from_target":
            unanswered = msgid == ATTITUDE_MSGID and self._attitudes_sent == before[1]
        else:
            unanswered = msgid == SET_ATTITUDE_TARGET_MSGID and self._commands_sent == before[0]
        if unanswered and self._send("to_target", self._last_command, count=False):
            self._dirs[direction].counters["filled"] += 1

    def _schedule(self, direction: str, datagram: bytes) -> None:
        s, rng = self._dirs[direction].settings, self._dirs[direction].rng
        delay = s.delay_s + (rng.uniform(0.0, s.jitter_s) if s.jitter_s > 0.0 else 0.0)
        if self.clock == "vehicle" and self._vehicle_time_s is None:
            delay = 0.0  # no vehicle clock yet: never hold a handshake hostage
        if delay <= 0.0 and not any(h[3] == direction for h in self._held):
            self._send(direction, datagram)
            return
        self._dirs[direction].counters["delayed"] += 1
        wall = self._wall()
        heapq.heappush(self._held, (self._now() + delay, wall + self.max_hold_wall_s, next(self._seq), direction, datagram))

    def _release_due(self, trigger: str | None = None) -> None:
        """Send held datagrams that are due. In vehicle mode only an arrival in the same direction
        (``trigger``) releases by vehicle time; the wall-clock bound releases anything."""
        now, wall = self._now(), self._wall()
        vehicle = self.clock == "vehicle" and self._vehicle_time_s is not None

        def is_due(h) -> bool:
            if h[1] <= wall:
                return True
            if vehicle:
                return h[3] == trigger and h[0] <= now
            return h[0] <= now

        due = [h for h in self._held if is_due(h)]
        if due:
            self._held = [h for h in self._held if not is_due(h)]
            heapq.heapify(self._held)
            for h in sorted(due):
                self._send(h[3], h[4])
        for name, d in self._dirs.items():
            if d.reorder_slot is not None and wall - d.reorder_slot[1] >= self.max_hold_wall_s:
                held, d.reorder_slot = d.reorder_slot, None
                self._schedule(name, held[0])

    def _send(self, direction: str, datagram: bytes, count: bool = True) -> bool:
        c = self._dirs[direction].counters
        if direction == "to_target":
            sock, dest = self._target_sock, self.target
        else:
            sock, dest = self._listen_sock, self._client
        if dest is None:
            c["no_peer"] += 1
            return False
        try:
            sock.sendto(datagram, dest)
        except OSError:
            c["send_errors"] += 1
            return False
        if count:
            c["forwarded"] += 1
        msgid = mavlink_msgid(datagram)
        if direction == "to_target" and msgid == SET_ATTITUDE_TARGET_MSGID:
            self._commands_sent += 1
            if count:
                self._last_command = datagram
        elif direction == "from_target" and msgid == ATTITUDE_MSGID:
            self._attitudes_sent += 1
        return True


# -------------------------------------------------------------------- command line
def configure(parser: argparse.ArgumentParser) -> None:
    """Options of ``mavastsm proxy`` (units in every help text)."""
    parser.formatter_class = argparse.ArgumentDefaultsHelpFormatter
    parser.description = (
        "UDP relay that injects faults between a MAVLink peer and a vehicle. Point the bridge at "
        "--listen (e.g. 'mavastsm connect udpout:127.0.0.1:14560') and the proxy relays to --target "
        "(e.g. the sim in server mode); replies go back to the last client heard. Faults apply to "
        "--direction; probabilities are per datagram in [0, 1]."
    )
    parser.add_argument("--listen", default="127.0.0.1:14560", help="HOST:PORT to bind for the client side (port 0 = ephemeral)")
    parser.add_argument("--target", required=True, help="HOST:PORT datagrams are relayed to (the vehicle or sim)")
    parser.add_argument("--direction", choices=("both", "to-target", "from-target"), default="both",
                        help="which direction the faults apply to")
    parser.add_argument("--loss", type=float, default=0.0, help="independent loss probability [0..1]")
    parser.add_argument("--burst-loss", type=float, default=0.0, metavar="P",
                        help="mean loss probability [0..1] of Gilbert-Elliott bursty loss (0 = off)")
    parser.add_argument("--burst-len", type=float, default=5.0, help="mean burst length [datagrams] with --burst-loss")
    parser.add_argument("--delay-ms", type=float, default=0.0, help="fixed one-way delay [ms]")
    parser.add_argument("--jitter-ms", type=float, default=0.0, help="extra uniform random delay in [0, jitter] [ms] (can reorder)")
    parser.add_argument("--duplicate", type=float, default=0.0, help="duplication probability [0..1]")
    parser.add_argument("--reorder", type=float, default=0.0, help="probability [0..1] a datagram is swapped with the next one")
    parser.add_argument("--corrupt", type=float, default=0.0, help="probability [0..1] of flipping bytes in a datagram")
    parser.add_argument("--corrupt-bytes", type=int, default=1, help="bytes flipped per corrupted datagram [count]")
    parser.add_argument("--outage-start-s", type=float, default=None, help="start of a total outage [s on the proxy clock]")
    parser.add_argument("--outage-duration-s", type=float, default=0.0, help="length of the total outage [s]")
    parser.add_argument("--clock", choices=("wall", "vehicle"), default="wall",
                        help="delays and outage times in wall seconds, or in vehicle seconds read from ATTITUDE.time_boot_ms")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fault random generators")
    parser.add_argument("--stats-interval-s", type=float, default=1.0, help="print counters every N seconds [s] (0 = only at exit)")
    parser.add_argument("--duration-s", type=float, default=0.0, help="stop after N seconds [s] (0 = until Ctrl-C)")


_OPTION_OF = {"loss": "--loss", "duplicate": "--duplicate", "reorder": "--reorder", "corrupt": "--corrupt", "burst_loss": "--burst-loss"}


def settings_from_args(args: argparse.Namespace) -> ImpairmentSettings:
    """Build the settings for the impaired direction(s) from parsed options (ValueError naming the option)."""
    for field_name, option in _OPTION_OF.items():
        v = getattr(args, field_name, None)
        if v is not None and not (0.0 <= v <= 1.0):
            raise ValueError(f"{option} {v:g}: must be a probability in [0, 1]")
    for option, v in (("--delay-ms", args.delay_ms), ("--jitter-ms", args.jitter_ms)):
        if not (0.0 <= v < 3_600_000.0):
            raise ValueError(f"{option} {v:g}: must be within [0, 3600000) ms")
    windows = ()
    if args.outage_start_s is not None:
        if args.outage_duration_s < 0:
            raise ValueError(f"--outage-duration-s must be >= 0, got {args.outage_duration_s}")
        windows = ((args.outage_start_s, args.outage_start_s + args.outage_duration_s),)
    common = dict(delay_s=args.delay_ms / 1000.0, jitter_s=args.jitter_ms / 1000.0, duplicate=args.duplicate,
                  reorder=args.reorder, corrupt=args.corrupt, corrupt_bytes=args.corrupt_bytes, outage_windows=windows)
    if args.burst_loss > 0.0:
        base = ImpairmentSettings.bursty(args.burst_loss, args.burst_len, **common)
        return dataclasses.replace(base, loss=args.loss)
    return ImpairmentSettings(loss=args.loss, **common)


def _format_counters(proxy: ImpairmentProxy) -> str:
    parts = []
    for name in DIRECTIONS:
        c = proxy.counters(name)
        shown = " ".join(f"{k}={v}" for k, v in c.items() if v or k in ("received", "forwarded"))
        parts.append(f"{name}: {shown}")
    return " | ".join(parts)


def run(args: argparse.Namespace) -> int:
    """Run the relay until Ctrl-C/SIGTERM or ``--duration-s``; print counters; exit 0 (2 on bad options)."""
    import signal

    try:
        listen, target = parse_host_port(args.listen), parse_host_port(args.target)
        impaired = settings_from_args(args)
    except ValueError as exc:
        print(f"mavastsm proxy: error: {exc}", file=sys.stderr)
        return 2
    kwargs = {}
    if args.direction in ("both", "to-target"):
        kwargs["to_target"] = impaired
    if args.direction in ("both", "from-target"):
        kwargs["from_target"] = impaired
    try:
        proxy = ImpairmentProxy(target, listen, seed=args.seed, clock=args.clock, **kwargs)
    except OSError as exc:
        print(f"mavastsm proxy: error: cannot bind {args.listen}: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    proxy.start()
    host, port = proxy.listen_address
    print(f"mavastsm proxy: listening on {host}:{port}, relaying to {target[0]}:{target[1]} "
          f"({args.direction}: {impaired})", flush=True)
    deadline = time.monotonic() + args.duration_s if args.duration_s > 0 else float("inf")
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            interval = args.stats_interval_s if args.stats_interval_s > 0 else 1.0
            stop.wait(min(interval, max(0.0, deadline - time.monotonic())))
            if args.stats_interval_s > 0:
                print(_format_counters(proxy), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        proxy.stop()
    print("final: " + _format_counters(proxy), flush=True)
    return 0
