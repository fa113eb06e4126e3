"""Lockstep turns: the simulated vehicle's clock moves only while the bridge waits for the vehicle.

A lockstep sim waits for the bridge's answer to each ATTITUDE; that alone leaves the bridge's other threads free:
the start-up thread's mode and arm commands, its pre-stream, rate and arming waits, the supervisor's hand-back, all
ran on the host clock, so they reached the vehicle on whichever sample the host happened to schedule them at, and
a seeded flight differed from run to run (issue 29: the same ``demo --scenario disturbance_pulse`` once ended in
ENVELOPE_BREACH, once flew to the end spun 180 deg; the engaged flights differed by 1e-17 rad at engagement, which
the closed loop grew to the failsafe).

With turns, one process's bridge and sim take turns on the vehicle clock:

* every bridge thread that acts on the vehicle (the start-up thread, the supervisor) is a *participant*: it runs
  until it waits for the vehicle, on the link's condition (an ACK, a parameter, a HEARTBEAT) or on the vehicle's
  clock (:meth:`sleep`, the bridge's pre-stream, rate, arming and supervisor waits);
* the bridge's reader thread wakes a waiting participant when a message answers it, or when an ATTITUDE brings the
  vehicle time its sleep waits for, and then waits (:meth:`settle`) until every participant waits again before it
  answers that sample or reads the next message;
* the sim (``VehicleServer.turns``) advances only when the reader has handled every message it sent and every
  participant waits (:meth:`settled`).

So every action of the bridge lands on the vehicle at the sample it was decided on, whatever the machine load.
Pure threading; no MAVLink, no sim. Used through ``mavastsm.lockstep_pair``.
"""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

SLICE_S = 0.05  # [s] wall slice of every wait here: stops and closes are noticed within it
LIVENESS_S = 10.0  # [s] wall time a vehicle-clock sleep waits beyond its length for a vehicle that stopped streaming


class LockstepTurns:
    """Who may move: the bridge's participants, its reader thread, or the simulated vehicle (see module docstring)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._members: set[int] = set()
        self._busy: set[int] = set()  # participants running (not waiting for the vehicle)
        self._waiting_on: dict[int, object] = {}  # participant -> the condition it waits on
        self._sleepers: dict[int, float] = {}  # participant -> vehicle time [s] its sleep ends at
        self.vehicle_time_s: float | None = None  # [s] time_boot_ms of the latest ATTITUDE the reader handled
        self.handled = 0  # messages the bridge's reader has handled completely
        self.closed = False

    # ------------------------------------------------------------------ participants
    @contextmanager
    def participant(self):
        """The calling thread acts on the vehicle until the block ends (runs: the vehicle waits for it)."""
        me = threading.get_ident()
        with self._cond:
            self._members.add(me)
            self._busy.add(me)
        try:
            yield self
        finally:
            with self._cond:
                self._members.discard(me)
                self._busy.discard(me)
                self._waiting_on.pop(me, None)
                self._sleepers.pop(me, None)
                self._cond.notify_all()

    def is_participant(self) -> bool:
        return threading.get_ident() in self._members

    def sleep(self, seconds: float, stop: threading.Event) -> bool:
        """Wait ``seconds`` [s] of vehicle time, counted from the latest ATTITUDE (from boot before the first);
        wall time for a non-participant. True when ``stop`` was set."""
        me = threading.get_ident()
        with self._cond:
            if me not in self._members or self.closed:
                timed = True
            else:
                timed = False
                self._sleepers[me] = (self.vehicle_time_s or 0.0) + seconds
                self._busy.discard(me)
                self._cond.notify_all()
                deadline = time.monotonic() + seconds + LIVENESS_S
                while me not in self._busy and not stop.is_set() and not self.closed and time.monotonic() < deadline:
                    self._cond.wait(SLICE_S)
                self._sleepers.pop(me, None)
                self._busy.add(me)
        return stop.wait(seconds) if timed else stop.is_set()

    # ------------------------------------------------------------------ the link's condition (TurnCondition)
    def _idle_on(self, cond) -> None:
        me = threading.get_ident()
        with self._cond:
            self._waiting_on[me] = cond
            self._busy.discard(me)
            self._cond.notify_all()

    def _resume(self) -> None:
        me = threading.get_ident()
        with self._cond:
            self._waiting_on.pop(me, None)
            self._busy.add(me)

    def _wake_waiters_of(self, cond) -> None:
        with self._cond:
            for who, on in list(self._waiting_on.items()):
                if on is cond:
                    self._busy.add(who)
                    del self._waiting_on[who]

    # ------------------------------------------------------------------ the bridge's reader thread
    def vehicle_sample(self, time_s: float) -> None:
        """An ATTITUDE of ``time_s`` [s] arrived: wake the sleeps it ends (before the bridge answers it)."""
        with self._cond:
            self.vehicle_time_s = time_s
            due = [who for who, until in self._sleepers.items() if until <= time_s]
            for who in due:
                self._busy.add(who)
                del self._sleepers[who]
            if due:
                self._cond.notify_all()

    def settle(self, stopped) -> None:
        """Wait until every participant waits for the vehicle again (or ``stopped()``, or closed)."""
        with self._cond:
            while self._busy and not self.closed and not stopped():
                self._cond.wait(SLICE_S)

    def reader_handled(self, count: int) -> None:
        """Every message up to ``count`` [messages received] is handled (participants settled first)."""
        with self._cond:
            self.handled = count
            self._cond.notify_all()

    # ------------------------------------------------------------------ the sim
    def settled(self, sent: int, timeout_s: float = SLICE_S) -> bool:
        """True once the reader has handled ``sent`` [messages] and every participant waits (or closed); False
        after ``timeout_s`` [wall s] otherwise."""
        with self._cond:
            return self._cond.wait_for(lambda: self.closed or (self.handled >= sent and not self._busy), timeout_s)

    def close(self) -> None:
        """The bridge's link closed: no more turns (the sim falls back to its plain lockstep)."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()


class TurnCondition(threading.Condition):
    """The link's condition: a participant waiting on it lets the vehicle move; ``notify_all`` (the reader, on
    a message) makes its waiters run again before the reader goes on."""

    def __init__(self, turns: LockstepTurns | None) -> None:
        super().__init__()
        self.turns = turns

    def wait(self, timeout: float | None = None) -> bool:
        turns = self.turns
        if turns is None or not turns.is_participant():
            return super().wait(timeout)
        turns._idle_on(self)
        try:
            return super().wait(timeout)
        finally:
            turns._resume()

    def notify_all(self) -> None:
        if self.turns is not None:
            self.turns._wake_waiters_of(self)
        super().notify_all()
