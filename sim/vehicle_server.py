"""Run the simulated Solo (copter + MAVLink + clock + UDP) in a background thread: the Python API.

Typical test use (ephemeral loopback port, deterministic lockstep)::

    from mavastsm_sim.vehicle_server import VehicleServer

    with VehicleServer(clock="lockstep", listen=("127.0.0.1", 0)) as server:
        url = f"udpout:127.0.0.1:{server.port}"       # a pymavlink peer talks first, then hears us
        ...
        server.wait_until(lambda copter: copter.armed, timeout_s=5.0)
        print(server.counters)

The default (no ``listen``, no ``target``) behaves like ArduPilot SITL's ``udpclient``: it sends to
``127.0.0.1:14550``, where ``mavastsm connect udp:127.0.0.1:14550`` or MAVProxy listen.

API
---
``VehicleServer(vehicle_config=None, scenario=None, seed=0, physics_rate_hz=1000.0, noise=False, *,
clock="realtime", speedup=1.0, lockstep_timeout_s=0.1, listen=None, target=None, sched_loop_rate_hz=None,
signing_key=None, home=DEFAULT_HOME, verbose=False, copter=None, copter_options=None, signing_state=None,
lockstep_paced=False, profile=None)``

* ``start()`` / ``stop()`` (idempotent; joins the thread, closes the socket); context manager.
* ``turns``: set it (before ``start``) to the ``LockstepTurns`` of an in-process bridge (``mavastsm.lockstep_pair``) and
  lockstep takes turns with that bridge: time starts when it first speaks and moves on only once it has handled
  everything sent and waits for the vehicle (``mavastsm/lockstep_turns.py``), never on the wall clock; paced at
  ``speedup`` with ``lockstep_paced``. Its closing (the bridge's link closed) ends the turns.
* ``port`` (bound local UDP port), ``address``, ``copter`` (the ``SimulatedCopter``), ``vehicle``
  (the ``MavlinkVehicle``), ``sim_time_s``, ``counters`` (dict snapshot: bad-input classes, lockstep
  answers/timeouts, datagrams), ``lock`` (hold it to read the copter consistently), ``wait_until(pred, timeout_s)``,
  ``call(fn)`` (run ``fn(copter)`` under the lock), ``error`` (exception that ended the loop, if any),
  ``loop_cpu_s`` (CPU time of the simulation thread [s], for benchmarks).

Clocks (see ``sim_clock.py``): ``realtime`` paces simulated time by the wall clock times ``speedup``;
``lockstep`` waits after each ATTITUDE for a SET_ATTITUDE_TARGET (at most ``lockstep_timeout_s`` of wall
time) and otherwise runs flat out; while ATTITUDE is not streaming, or after 3 ATTITUDEs in a row went
unanswered (no controller yet, or it died), it is paced like ``realtime`` until the next SET_ATTITUDE_TARGET.
Simulated time advances on a grid of physics ticks (1 / ``physics_rate_hz``) kept as integer microseconds,
so ``time_boot_ms`` never drifts; messages go out on the first tick at or after their due time.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from pathlib import Path
from typing import Any, Callable

from mavastsm.errors import ConfigError
from mavastsm.signing import load_signing_key

from .arducopter_profile import ArduCopterProfile, load_profile
from .mavlink_vehicle import DEFAULT_HOME, MavlinkVehicle
from .sim_clock import ClockSpec, LockstepGate, RealTimePacer
from .udp_transport import Address, UdpPeers
from .vehicle_link import BAD_INPUT_COUNTERS

log = logging.getLogger("mavastsm_sim")

DEFAULT_TARGET: Address = ("127.0.0.1", 14550)
MAX_CHUNK_US = 20_000          # never step more than 20 ms of simulated time without polling the socket
COUNTER_LOG_PERIOD_S = 5.0     # --verbose: summary of counters every 5 s of wall time
LATE_ATTITUDE_S = 0.001     # real time: an ATTITUDE whose step started more than this behind its wall-clock schedule counts as late
LOCKSTEP_LOST_AFTER = 3        # unanswered ATTITUDEs in a row before lockstep falls back to pacing


class VehicleServer:
    """Simulated ArduCopter-speaking Solo on a UDP socket, run in a background thread.

    Parameters
    ----------
    vehicle_config, scenario, seed, physics_rate_hz, noise
        Passed to ``SimulatedCopter`` (physics rate [Hz]; scenario name or path; seed for noise).
    clock : {"realtime", "lockstep"}
        Clock mode (see module docstring).
    speedup : float
        Simulated seconds per wall second when paced [-].
    lockstep_timeout_s : float
        Longest wall wait for the controller's answer to an ATTITUDE in lockstep [s].
    listen : (host, port) or None
        Bind here and answer whoever talks (server mode). Port 0 = ephemeral.
    target : (host, port), list of them, or None
        Always send here (client mode). Default when ``listen`` is None: 127.0.0.1:14550.
    sched_loop_rate_hz : float or None
        [Hz] replaces the profile's ``sched_loop_rate_hz`` (parameter SCHED_LOOP_RATE; stream-rate cap = 80 % of it);
        None keeps the profile's.
    signing_key : bytes, str, Path or None
        32-byte MAVLink 2 key, or a path to a key file (format: ``mavastsm.signing``).
    signing_state : str, Path or None
        File keeping the signing timestamp across runs, as ArduPilot does (``MavlinkVehicle``).
    home : (lat_deg, lon_deg, alt_m)
        Home position reported in GPS-like messages.
    verbose : bool
        Log bad input and a counter summary every 5 s (logger ``mavastsm_sim`` at DEBUG).
    copter : object or None
        Use this plant instead of constructing a ``SimulatedCopter`` (same interface, its own ``profile``); then
        ``profile`` and ``sched_loop_rate_hz`` must be None.
    copter_options : dict or None
        Extra keyword options for ``SimulatedCopter`` (e.g. ``initial_position_ned_m``, ``disturbances``; see
        ``sim/copter.py``).
    profile : ArduCopterProfile, profile name or file, or None
        The ArduCopter emulated: every wire and emulator habit (sim/arducopter_profile.py, docs/sim.md "Sim
        profiles"); None: the default profile. ``load_profile(name, {"prearm_delay_s": 30.0})`` changes one habit.
    """

    def __init__(self, vehicle_config: str | Path | None = None, scenario: Any = None, seed: int = 0,
                 physics_rate_hz: float = 1000.0, noise: bool = False, *, clock: str = "realtime",
                 speedup: float = 1.0, lockstep_timeout_s: float = 0.1, listen: Address | None = None,
                 target: Address | list[Address] | None = None, sched_loop_rate_hz: float | None = None,
                 signing_key: bytes | str | Path | None = None, home: tuple[float, float, float] = DEFAULT_HOME,
                 verbose: bool = False, copter: Any = None, copter_options: dict[str, Any] | None = None,
                 signing_state: str | Path | None = None, lockstep_paced: bool = False,
                 profile: ArduCopterProfile | str | Path | None = None) -> None:
        self.clock = ClockSpec(mode=clock, speedup=float(speedup), lockstep_timeout_s=float(lockstep_timeout_s),
                               lockstep_paced=bool(lockstep_paced))
        if not (math.isfinite(physics_rate_hz) and 10.0 <= physics_rate_hz <= 100_000.0):
            raise ConfigError(f"physics_rate_hz {physics_rate_hz!r} must be within 10..100000 Hz")
        self._tick_us = max(int(round(1e6 / physics_rate_hz)), 1)
        if copter is None:
            from .copter import SimulatedCopter  # imported here so the MAVLink layer can be used with any plant
            loop_rate = None if sched_loop_rate_hz is None else {"sched_loop_rate_hz": float(sched_loop_rate_hz)}
            if not isinstance(profile, ArduCopterProfile):
                profile = load_profile(profile, loop_rate)  # checked against the profile file's range
            elif loop_rate is not None:
                profile = dataclasses.replace(profile, **loop_rate)
            copter = SimulatedCopter(vehicle_config=vehicle_config, scenario=scenario, seed=seed,
                                     physics_rate_hz=physics_rate_hz, noise=noise, profile=profile,
                                     field_elevation_m=home[2], **(copter_options or {}))
        elif profile is not None or sched_loop_rate_hz is not None:
            raise ValueError("a copter passed in brings its own profile: give profile / sched_loop_rate_hz to it")
        self.copter = copter
        key = signing_key
        if isinstance(key, (str, Path)):
            key = load_signing_key(key)  # ConfigError naming the file and the rule
        if key is not None and len(key) != 32:
            raise ConfigError(f"signing key must be 32 bytes, got {len(key)}")
        if isinstance(target, tuple):
            targets = [target]
        elif target is None:
            targets = [] if listen is not None else [DEFAULT_TARGET]
        else:
            targets = list(target)
        self.verbose = verbose
        self.transport = UdpPeers(bind=listen or ("127.0.0.1", 0), targets=targets)
        try:
            self.vehicle = MavlinkVehicle(copter, self.transport.send, signing_key=key, home=home,
                                          signing_state=signing_state)
        except BaseException:
            self.transport.close()
            raise
        self.lock = threading.RLock()
        self._changed = threading.Condition(self.lock)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._now_us = 0
        self._pacer = RealTimePacer(self.clock.speedup)
        self._gate = LockstepGate(self.clock.lockstep_timeout_s)
        self._consecutive_timeouts = 0
        self._controller_lost = False
        self._answers_when_lost = 0
        self.controller_lost_events = 0
        # real time: ATTITUDEs whose physics step began > LATE_ATTITUDE_S behind schedule (the sim, not the peer, was late);
        # the step's own compute comes on top, so this is a lower bound on ATTITUDEs sent that late
        self.late_attitudes = 0
        self.turns = None  # LockstepTurns of an in-process bridge (module docstring)
        self.error: BaseException | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> "VehicleServer":
        """Start the simulation thread (returns self)."""
        if self._thread is None:
            self._pacer.rebase(0.0)
            self._thread = threading.Thread(target=self._run, name="mavastsm-sim", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread, join it and close the socket (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        with self.lock:
            self.vehicle.signing.save_timestamp(force=True)
        self.transport.close()

    def __enter__(self) -> "VehicleServer":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ------------------------------------------------------------------ read-outs
    @property
    def port(self) -> int:
        """Bound local UDP port."""
        return self.transport.port

    @property
    def address(self) -> Address:
        return self.transport.address

    @property
    def sim_time_s(self) -> float:
        """Simulated time since boot [s]."""
        return self._now_us * 1e-6

    @property
    def loop_cpu_s(self) -> float | None:
        """CPU time [s] used so far by the simulation thread alone (user + system), for benchmarks;
        None when the thread is not running or the platform has no per-thread CPU clock."""
        thread = self._thread
        if thread is None or not thread.is_alive() or not hasattr(time, "pthread_getcpuclockid"):
            return None
        try:
            return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
        except (OSError, TypeError):
            return None

    @property
    def counters(self) -> dict[str, int]:
        """Snapshot of all counters: bad-input classes (see ``BAD_INPUT_COUNTERS``), lockstep and transport."""
        with self.lock:
            out = {name: 0 for name in BAD_INPUT_COUNTERS}
            out.update(self.vehicle.counters)
            out["bad_input_total"] = self.vehicle.bad_input_total()
            out["lockstep_answered"] = self._gate.answered
            out["lockstep_timeouts"] = self._gate.timeouts
            out["lockstep_controller_lost"] = self.controller_lost_events
            out["realtime_overruns"] = self._pacer.overruns
            out["realtime_late_attitudes"] = self.late_attitudes
            out["datagrams_in"] = self.transport.datagrams_in
            out["datagrams_out"] = self.transport.datagrams_out
            out["send_errors"] = self.transport.send_errors
            out["peers"] = len(self.transport.peers())
            out["peers_refused"] = self.transport.peers_refused
            out["attitude_targets_received"] = self.vehicle.attitude_targets_received
        return out

    def call(self, fn: Callable[[Any], Any]) -> Any:
        """Run ``fn(copter)`` under the simulation lock and return its result."""
        with self.lock:
            return fn(self.copter)

    def wait_until(self, predicate: Callable[[Any], bool], timeout_s: float = 5.0) -> bool:
        """Wait (wall clock, bounded) until ``predicate(copter)`` holds; True if it did."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                if predicate(self.copter):
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not self.running:
                    return bool(predicate(self.copter))
                self._changed.wait(min(remaining, 0.05))

    # ------------------------------------------------------------------ the loop
    def _handle_inbound(self) -> int:
        """Handle every datagram waiting; returns how many there were."""
        pending = self.transport.receive_pending()
        for data, addr in pending:
            # a sender becomes a peer (gets our stream and a greeting) only with a valid, signed-if-required frame
            self.vehicle.handle_datagram(data, self._now_us, lambda addr=addr: self._admit(addr))
        return len(pending)

    def _admit(self, addr: Address) -> None:
        if self.transport.admit(addr):
            log.info("new peer %s:%d", *addr)
            self.vehicle.greet_new_peer()

    def _paced(self) -> bool:
        return (self.clock.mode == "realtime" or self.clock.lockstep_paced or not self.vehicle.attitude_streaming()
                or self._controller_lost)

    def _track_controller(self, timed_out: bool) -> None:
        """Lockstep: after LOCKSTEP_LOST_AFTER unanswered ATTITUDEs in a row the controller counts as gone and
        the plant is paced like real time (x speedup) until a SET_ATTITUDE_TARGET arrives again, so a dead
        bridge does not slow simulated time to one ATTITUDE per timeout (GUID_TIMEOUT would take minutes)."""
        answers = self.vehicle.attitude_targets_received
        if self._controller_lost:
            if answers != self._answers_when_lost:
                self._controller_lost = False
                self._consecutive_timeouts = 0
                log.info("lockstep: controller answering again at t=%.3f s", self.sim_time_s)
            return
        self._consecutive_timeouts = self._consecutive_timeouts + 1 if timed_out else 0
        if self._consecutive_timeouts >= LOCKSTEP_LOST_AFTER:
            self._controller_lost = True
            self._answers_when_lost = answers
            self.controller_lost_events += 1
            log.info("lockstep: no answer to %d ATTITUDEs in a row at t=%.3f s; pacing x%g until one comes",
                     LOCKSTEP_LOST_AFTER, self.sim_time_s, self.clock.speedup)

    def _take_turn(self, tick: int) -> None:
        """Lockstep with turns: move to the next due message once the bridge has handled all we sent and waits for the
        vehicle (time stands still until it first speaks); at most ``speedup`` x real time with ``lockstep_paced``."""
        if not self.transport.peers():
            if self.transport.wait_readable(0.05):
                with self.lock:
                    self._handle_inbound()
            return
        if not self.turns.settled(self.transport.datagrams_out):
            return
        with self.lock:
            sent = self.transport.datagrams_out
            if self._handle_inbound() and self.transport.datagrams_out != sent:
                return  # what came in was answered: the bridge's turn again, at this same time
            due_us = self.vehicle.next_due_us(self._now_us)
        target_us = min(due_us, self._now_us + MAX_CHUNK_US)
        target_us = max(-(-target_us // tick) * tick, self._now_us + tick)
        if self.clock.lockstep_paced:
            wait_s = self._pacer.seconds_until(target_us * 1e-6)
            if wait_s > 0:
                self._stop.wait(min(wait_s, 0.05))
                return
        with self.lock:
            self.copter.step((target_us - self._now_us) * 1e-6)
            self._now_us = target_us
            self.vehicle.emit_due(self._now_us)
            self._changed.notify_all()

    def _run(self) -> None:
        tick = self._tick_us
        was_paced = True
        next_log_s = time.monotonic() + COUNTER_LOG_PERIOD_S
        try:
            while not self._stop.is_set():
                if self.turns is not None and not self.turns.closed and self.clock.mode == "lockstep":
                    self._take_turn(tick)
                    continue
                # 1. lockstep: wait for the controller's answer to the last ATTITUDE (bounded)
                drained = False
                if self._gate.is_closed:
                    timeouts_before = self._gate.timeouts
                    remaining = self._gate.poll(self.vehicle.attitude_targets_received)
                    if remaining > 0:
                        if self.transport.wait_readable(min(remaining, 0.05)):
                            with self.lock:
                                self._handle_inbound()
                            drained = True
                            remaining = self._gate.poll(self.vehicle.attitude_targets_received)
                        if remaining > 0:
                            continue
                    self._track_controller(timed_out=self._gate.timeouts > timeouts_before)
                elif self._controller_lost:
                    self._track_controller(timed_out=False)
                if not drained:  # (just drained while waiting for the answer: skip a second empty read)
                    with self.lock:
                        self._handle_inbound()
                paced = self._paced()
                if paced and not was_paced:
                    self._pacer.rebase(self._now_us * 1e-6)
                was_paced = paced
                # 2. choose the next simulated time: next due message, at most MAX_CHUNK_US ahead, on the tick grid
                with self.lock:
                    due_us = self.vehicle.next_due_us(self._now_us)
                target_us = min(due_us, self._now_us + MAX_CHUNK_US)
                target_us = max(-(-target_us // tick) * tick, self._now_us + tick)
                # 3. pacing (realtime, or lockstep with no controller loop yet); inbound data cuts the wait short
                if paced:
                    wait_s = self._pacer.seconds_until(target_us * 1e-6)
                    if wait_s > 0 and self.transport.wait_readable(min(wait_s, 0.05)):
                        reached_us = (int(self._pacer.sim_time_now_s() * 1e6) // tick) * tick
                        if reached_us <= self._now_us:
                            continue  # handle the datagram at the current time
                        target_us = min(target_us, reached_us)
                    elif wait_s > 0.05:
                        continue
                # 4. advance the plant and emit what is due
                with self.lock:
                    self.copter.step((target_us - self._now_us) * 1e-6)
                    self._now_us = target_us
                    attitude_sent = self.vehicle.emit_due(self._now_us)
                    if attitude_sent and paced and self._pacer.last_lag_s > LATE_ATTITUDE_S:
                        # late, then caught up: the peer gets this ATTITUDE and the next close together
                        self.late_attitudes += 1
                    if attitude_sent and self.clock.mode == "lockstep" and not self._controller_lost:
                        self._gate.close(self.vehicle.attitude_targets_received)
                    self._changed.notify_all()
                if self.verbose and time.monotonic() >= next_log_s:
                    next_log_s = time.monotonic() + COUNTER_LOG_PERIOD_S
                    log.debug("sim t=%.1f s counters %s", self.sim_time_s, self.counters)
        except BaseException as exc:  # surface a crash to the owner instead of dying silently
            self.error = exc
            log.exception("simulation loop stopped by an exception")
        finally:
            with self._changed:
                self._changed.notify_all()
