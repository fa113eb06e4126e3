"""Clocks for the simulated vehicle: real time, speed-up, and deterministic lockstep.

The simulator keeps its own time (integer microseconds since boot, so ``time_boot_ms`` never drifts);
these classes only decide *when, in wall-clock time,* the plant may advance to a given simulated time.

* ``realtime`` (speed-up 1) and ``--speedup N``: simulated time runs N times faster than the wall clock
  (:class:`RealTimePacer`). If the host falls behind by more than ``max_lag_s`` the pacer re-bases instead
  of bursting to catch up, and counts an overrun.
* ``lockstep``: after every ATTITUDE the plant waits until the controller has answered with a
  SET_ATTITUDE_TARGET, or until ``lockstep_timeout_s`` of wall time has passed (:class:`LockstepGate`).
  Between two gates it runs as fast as the CPU allows, so a closed loop sees exactly the same sequence of
  samples whatever the machine load. While nothing is streaming ATTITUDE (no controller yet: connecting,
  arming, changing mode) there is nothing to wait for, so the plant is paced like ``realtime`` at the
  configured speed-up; that keeps a human or a GCS handshake from racing through seconds of simulated time.
  ``VehicleServer`` also paces after three unanswered ATTITUDEs in a row (controller not engaged yet, or
  gone) until the next answer.

Pure timing logic; no sockets, no MAVLink. The wall clock is injectable for tests.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

from mavastsm.errors import ConfigError

CLOCK_MODES = ("realtime", "lockstep")


@dataclass(frozen=True)
class ClockSpec:
    """How simulated time relates to wall time.

    Parameters
    ----------
    mode : {"realtime", "lockstep"}
        ``realtime`` paces by the wall clock (times ``speedup``); ``lockstep`` waits for the controller.
    speedup : float
        Simulated seconds per wall second when paced [-]. In lockstep this applies only while no
        ATTITUDE stream is active.
    lockstep_timeout_s : float
        Longest wall-clock wait for a SET_ATTITUDE_TARGET after an ATTITUDE in lockstep [s].
    lockstep_paced : bool
        Lockstep that is also never faster than ``speedup`` x real time: the controller still gets every
        sample before the plant moves on (a loaded host slows simulated time down instead of letting the
        vehicle fly on without commands), and the flight looks like real time (``mavastsm demo``).
    """

    mode: str = "realtime"
    speedup: float = 1.0
    lockstep_timeout_s: float = 0.1
    lockstep_paced: bool = False

    def __post_init__(self) -> None:
        if self.mode not in CLOCK_MODES:
            raise ConfigError(f"clock: mode {self.mode!r} is not one of {', '.join(CLOCK_MODES)}")
        if not (math.isfinite(self.speedup) and 0.0 < self.speedup <= 1e6):
            raise ConfigError(f"clock: speedup {self.speedup!r} must be a finite number in (0, 1e6]")
        if not (math.isfinite(self.lockstep_timeout_s) and 0.0 < self.lockstep_timeout_s <= 60.0):
            raise ConfigError(
                f"clock: lockstep_timeout_s {self.lockstep_timeout_s!r} must be in (0, 60] seconds")


class RealTimePacer:
    """Map simulated time to wall-clock deadlines at a fixed speed-up.

    Parameters
    ----------
    speedup : float
        Simulated seconds per wall second [-].
    wall_clock : callable
        Monotonic wall clock [s]; injectable for tests.
    max_lag_s : float
        If the plant is later than this behind its schedule [wall s], re-base rather than burst.
    """

    def __init__(self, speedup: float = 1.0, wall_clock: Callable[[], float] = time.monotonic,
                 max_lag_s: float = 0.25) -> None:
        self.speedup = float(speedup)
        self._wall_clock = wall_clock
        self._max_lag_s = float(max_lag_s)
        self._sim0_s = 0.0
        self._wall0_s = wall_clock()
        self.overruns = 0
        self.last_lag_s = 0.0  # how far behind its schedule the last seconds_until() found the plant [wall s]

    def rebase(self, sim_s: float) -> None:
        """Declare that simulated time ``sim_s`` [s] corresponds to *now* on the wall clock."""
        self._sim0_s = float(sim_s)
        self._wall0_s = self._wall_clock()

    def sim_time_now_s(self) -> float:
        """Simulated time [s] that corresponds to the wall clock now."""
        return self._sim0_s + (self._wall_clock() - self._wall0_s) * self.speedup

    def seconds_until(self, sim_s: float) -> float:
        """Wall-clock seconds to wait before the plant may reach ``sim_s`` [s]; 0 when already due."""
        deadline = self._wall0_s + (sim_s - self._sim0_s) / self.speedup
        wait = deadline - self._wall_clock()
        self.last_lag_s = max(-wait, 0.0)
        if wait < -self._max_lag_s:
            self.overruns += 1
            self.rebase(sim_s)
            return 0.0
        return max(wait, 0.0)


class LockstepGate:
    """Wait for the controller's answer after each ATTITUDE (bounded by a wall-clock timeout).

    The gate compares a monotonically increasing count of SET_ATTITUDE_TARGET messages received:
    :meth:`close` records the count when ATTITUDE goes out; the gate is open again once the count has
    grown or the timeout has passed.

    Parameters
    ----------
    timeout_s : float
        Longest wall-clock wait per ATTITUDE [s].
    wall_clock : callable
        Monotonic wall clock [s]; injectable for tests.
    """

    def __init__(self, timeout_s: float = 0.1, wall_clock: Callable[[], float] = time.monotonic) -> None:
        self.timeout_s = float(timeout_s)
        self._wall_clock = wall_clock
        self._answers_at_close: int | None = None
        self._deadline_s = 0.0
        self.timeouts = 0
        self.answered = 0

    @property
    def is_closed(self) -> bool:
        """True while the plant must wait for the controller."""
        return self._answers_at_close is not None

    def close(self, answers_so_far: int) -> None:
        """ATTITUDE was just sent; wait for an answer beyond ``answers_so_far`` [count]."""
        self._answers_at_close = answers_so_far
        self._deadline_s = self._wall_clock() + self.timeout_s

    def poll(self, answers_now: int) -> float:
        """Open the gate if answered or timed out; return wall seconds still to wait (0 when open)."""
        if self._answers_at_close is None:
            return 0.0
        if answers_now > self._answers_at_close:
            self._answers_at_close = None
            self.answered += 1
            return 0.0
        remaining = self._deadline_s - self._wall_clock()
        if remaining <= 0.0:
            self._answers_at_close = None
            self.timeouts += 1
            return 0.0
        return remaining

    def open(self) -> None:
        """Release the gate without an answer (e.g. the ATTITUDE stream was stopped)."""
        self._answers_at_close = None
