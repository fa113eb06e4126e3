"""The vehicle's clock as a stream: which ATTITUDE frames belong to it (pure; no I/O, host time passed in).

On a link without signing anybody can send a frame with the vehicle's system id, and two vehicles left on the
same id send two clocks into one port. A frame's ``time_boot_ms`` alone must therefore never move the bridge's
idea of the vehicle's clock; only a *stream* may. The rule (issue 28; docs/bridge.md, "Reordering, vehicle
restarts and re-engagement", has it with its numbers):

* **In the family.** A frame continues the stream when it is newer than the last accepted one and not further
  ahead than the wall clock allows since that one: ``0 < t - t_last <= RATE_MAX (rx - rx_last) + AHEAD_SLACK_MS``
  (RATE_MAX covers simulators in lockstep faster than real time; the slack an autopilot's burst and jitter).
  It is delivered at once. ``rx_last`` is the host time of the stream's last frame *of any age*: a frame at or
  behind the newest (a duplicate, a reordered packet, the genuine vehicle behind a forged frame that got in)
  restarts the wall time the bound allows, so that a forger cannot let elapsed time widen it (before this, two
  forged frames 30 ms apart moved the stream 400 ms ahead of the vehicle and starved the session for 410 ms). Frames at or shortly behind the last one (up to REORDER_MS) are passed on too: the
  session drops and counts them as duplicates and reordered packets, as before.
* **Out of the family.** Anything else (further ahead, or more than REORDER_MS behind) is held, not delivered, and
  starts or continues a *rival* chain (frames consistent with each other by the same rule). A frame of the stream
  arriving after it refutes the chain so far: its frames are clock outliers (counted, dropped). A chain that
  grows by CONFIRM_FRAMES more frames over at least CONFIRM_SPAN_MS with no frame of the stream in between is a
  new clock: the stream moves to it and its newest frame is delivered (the session then sees a restart, when the
  clock went back by more than its restart threshold, or a gap). At an ATTITUDE rate of 20 Hz or more that takes
  100-150 ms, well inside the 0.5 s stale-attitude promise; a burst of forged frames inside one period of the
  genuine stream is not a silence of it.
* **Two clocks.** A rival chain that keeps going while the stream does too (RIVAL_FRAMES frames over at least
  RIVAL_SPAN_MS, none more than RIVAL_GAP_MS after the one before) is a second vehicle with the same identity (or a replayer that keeps at it): ``conflict`` names
  both, with the source of each (its UDP address where the link knows one).

* **Two addresses.** On a datagram link the link also knows where each frame came from: frames with the target's
  id from a second address while the first one still talks are never delivered; its ATTITUDE frames make a rival
  chain by the same rule (``second_source``): confirmed with the first address silent, the link moves to the new
  address (a restarted autopilot on a new port; its clock is then confirmed as above); as long as a rival chain
  with the first one talking, they name the second vehicle the same way, whatever that clock reads.

What it does not see: on a link without addresses (serial, TCP, a router merging both), two vehicles whose clocks
agree to within the slack look like one jittery stream (their frames then show as duplicates and reordered
packets in the session's counters).
"""

from __future__ import annotations

from dataclasses import dataclass

RATE_MAX = 10.0  # vehicle seconds per wall second a stream may advance (lockstep simulators run faster than real time)
AHEAD_SLACK_MS = 100  # [ms] ahead of the wall-clock bound that still continues the stream (bursts, scheduler jitter)
REORDER_MS = 250  # [ms] behind the last frame that is a reordered packet of the stream (passed on), not an outlier
CONFIRM_FRAMES = 2  # frames after the first of a rival chain, with the stream silent, that confirm a new clock ...
CONFIRM_SPAN_MS = 100  # [ms] ... over at least this much wall time (a burst of forged frames is not a silence)
RIVAL_FRAMES = 10  # frames of a rival chain, the stream going on, that make two clocks of one identity ...
RIVAL_SPAN_MS = 500  # [ms] ... over at least this much wall time
RIVAL_GAP_MS = 1000  # [ms] without a frame of the rival chain ends it (sparse forged frames never add up to a vehicle)


@dataclass(frozen=True)
class ClockConflict:
    """Two consistent clocks under one identity: the stream the bridge follows and the rival."""

    stream_source: str
    stream_ms: int
    rival_source: str
    rival_ms: int

    def text(self, system_id: int | None) -> str:
        who = f"system {system_id}" if system_id is not None else "the vehicle's system id"
        return (f"two vehicles claim {who}: {self.stream_source} (clock {self.stream_ms / 1000:.1f} s) and "
                f"{self.rival_source} (clock {self.rival_ms / 1000:.1f} s); give each vehicle its own id "
                f"(MAV_SYSID on ArduPilot 4.7, SYSID_THISMAV before it; MAV_SYS_ID on PX4)")


@dataclass
class _Chain:
    first_ms: int
    last_ms: int
    last_rx_ns: int
    first_rx_ns: int
    source: str
    frames: int = 1
    stream_silent: bool = True  # no frame of the stream since the chain began


def continues(last_ms: int, last_rx_ns: int, ms: int, rx_ns: int) -> bool:
    """True when a frame at ``ms`` [ms, vehicle clock] received at ``rx_ns`` [ns, host monotonic] continues a clock
    last seen at (``last_ms``, ``last_rx_ns``): newer, and not further ahead than the wall clock allows."""
    wall_ms = max(0, rx_ns - last_rx_ns) / 1e6
    return 0 < ms - last_ms <= RATE_MAX * wall_ms + AHEAD_SLACK_MS


class VehicleClock:
    """The stream of one identity's ATTITUDE clock (module docstring). ``offer`` says what to do with each frame."""

    def __init__(self) -> None:
        self.last_ms: int | None = None
        self.last_rx_ns = 0
        self.source = "?"
        self._rival: _Chain | None = None
        self.outliers = 0  # frames held out of the family and refuted by the stream (dropped)
        self.new_clocks = 0  # rival chains confirmed (the stream silent): restarts and long gaps
        self.confirmed: tuple[int, float] | None = None  # the last new clock: (its confirming frame's ms, wall ms from its first frame)
        self.conflict: ClockConflict | None = None
        self._other: _Chain | None = None  # frames of the target's id from a second address (datagram links)

    def offer(self, ms: int, rx_ns: int, source: str = "?") -> bool:
        """One frame's vehicle time, host receive time and source; True = deliver it now, False = held or dropped."""
        if self.last_ms is None:
            self._follow(ms, rx_ns, source)
            return True
        if continues(self.last_ms, self.last_rx_ns, ms, rx_ns) or 0 <= self.last_ms - ms <= REORDER_MS:
            if ms > self.last_ms:
                self._follow(ms, rx_ns, source)
            else:  # a frame of the stream at or behind its newest: the wall time the ahead bound allows restarts here
                self.last_rx_ns = max(self.last_rx_ns, rx_ns)
            r = self._rival
            if r is not None and r.stream_silent:
                r.stream_silent = False
                self.outliers += r.frames  # refuted: the held frames were not the vehicle's clock
            return True
        return self._hold(ms, rx_ns, source)

    def _hold(self, ms: int, rx_ns: int, source: str) -> bool:
        r = self._rival
        if r is not None and (rx_ns - r.last_rx_ns) / 1e6 <= RIVAL_GAP_MS and continues(r.last_ms, r.last_rx_ns, ms, rx_ns):
            r.frames += 1
            r.last_ms, r.last_rx_ns = ms, rx_ns
            if not r.stream_silent:
                self.outliers += 1
        else:
            if r is not None and r.stream_silent:
                self.outliers += r.frames  # a chain that never confirmed, replaced by another
            r = self._rival = _Chain(ms, ms, rx_ns, rx_ns, source)
        if r.stream_silent and r.frames > CONFIRM_FRAMES and (r.last_rx_ns - r.first_rx_ns) / 1e6 >= CONFIRM_SPAN_MS:
            self._rival = None
            self._confirm(r, source)
            return True
        if (not r.stream_silent and r.frames >= RIVAL_FRAMES and (r.last_rx_ns - r.first_rx_ns) / 1e6 >= RIVAL_SPAN_MS
                and self.conflict is None):
            self.conflict = ClockConflict(self.source, self.last_ms, r.source, r.last_ms)
        return False

    def second_source(self, ms: int, rx_ns: int, source: str, stream_heard_ns: int) -> bool:
        """An ATTITUDE with the target's id from a second address while the first one still talks (datagram links:
        never delivered, never moves the stream). Its frames make a rival chain by the same rule; True (adopt the
        second address; the stream follows its clock) when the chain grew by CONFIRM_FRAMES over CONFIRM_SPAN_MS
        with the first address silent since it began
        (``stream_heard_ns`` [ns, host monotonic]: its last frame), a restarted autopilot on a new port; a chain
        as long as RIVAL_FRAMES over RIVAL_SPAN_MS with the first address talking is a second vehicle: ``conflict``."""
        o = self._other
        if (o is None or o.source != source or (rx_ns - o.last_rx_ns) / 1e6 > RIVAL_GAP_MS
                or not continues(o.last_ms, o.last_rx_ns, ms, rx_ns)):
            o = self._other = _Chain(ms, ms, rx_ns, rx_ns, source)
        else:
            o.frames += 1
            o.last_ms, o.last_rx_ns = ms, rx_ns
        o.stream_silent = o.stream_silent and stream_heard_ns < o.first_rx_ns
        if o.stream_silent and o.frames > CONFIRM_FRAMES and (o.last_rx_ns - o.first_rx_ns) / 1e6 >= CONFIRM_SPAN_MS:
            self._other = self._rival = None  # confirmed by the same rule as a new clock: the stream follows it now
            self._confirm(o, source)
            return True
        if self.conflict is None and o.frames >= RIVAL_FRAMES and (o.last_rx_ns - o.first_rx_ns) / 1e6 >= RIVAL_SPAN_MS:
            self.conflict = ClockConflict(self.source, self.last_ms or 0, source, o.last_ms)
        return False

    def second_source_heard(self, now_ns: int) -> bool:
        """True while a second address's ATTITUDE chain is alive (its last frame within RIVAL_GAP_MS of ``now_ns``)
        and not yet a conflict: whoever must decide before acting (start-up, before arming) waits for the verdict."""
        o = self._other
        return self.conflict is None and o is not None and (now_ns - o.last_rx_ns) / 1e6 <= RIVAL_GAP_MS

    def _confirm(self, chain: _Chain, source: str) -> None:
        """A rival chain is the vehicle's clock now: the stream follows its newest frame."""
        self.new_clocks += 1
        self.confirmed = (chain.last_ms, (chain.last_rx_ns - chain.first_rx_ns) / 1e6)
        self._follow(chain.last_ms, chain.last_rx_ns, source)

    def _follow(self, ms: int, rx_ns: int, source: str) -> None:
        self.last_ms, self.last_rx_ns, self.source = ms, rx_ns, source
