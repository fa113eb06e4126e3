"""Which frames of the target identity the bridge acts on: one source, one clock (pure; no pymavlink).

On a link without signing anyone can send an ATTITUDE or HEARTBEAT with the vehicle's system and component id,
and two vehicles left with the same id do. So the link does not take every frame of the identity as the vehicle's:

* **Source.** A frame's source is where it came from: the UDP address, the MAVLink 2 signing link id, the system
  and component id (:class:`Source`). The *bound* source is the one the first HEARTBEAT of the target came from;
  only its HEARTBEATs are handed on (another source's are counted, ``other_source_heartbeats``). When the bound
  source has sent nothing for SOURCE_SILENT_S, or nothing since another one's first of two HEARTBEATs, that one
  becomes the bound source (a vehicle back on a new address, as a rebooted SITL's udpclient is).
* **Clock.** The vehicle's ``time_boot_ms`` from the bound source is a stream (:class:`ClockStream`). A frame fits it
  when it is at most ``tolerance`` ahead of what the host clock allows since the stream's least-delayed frame, and at
  most ``tolerance`` behind the stream's newest frame; tolerance = CLOCK_TOLERANCE_MS + 2 x the stream's period
  (100 ms at 400 Hz). A frame that does not fit (or comes from another source) is an *outlier*: held as evidence of
  a second clock, counted (``clock_outliers``) and never handed on.
* **A new clock** of the bound source is adopted when CONFIRM_FRAMES (3) consistent outliers of it arrived, *no* frame
  of the old clock arrived since the first of them (the old stream has stopped), and the new clock's source sent a
  HEARTBEAT of the identity within HEARTBEAT_RECENT_S (1.5 s). It is a vehicle restart (the session's
  VEHICLE_RESTARTED) when the clock went back or the source changed; a clock that jumped ahead on the same source is
  adopted quietly. At 100 Hz the three frames take 20 ms, at 10 Hz 200 ms: inside the 0.5 s failsafe promise.
* **Two vehicles** (an identity conflict): a second clock with CONFIRM_FRAMES consistent frames over at least
  CONFLICT_SPAN_S (0.5 s) with the HEARTBEAT corroboration above while the old clock (or the bound source) goes on
  after its first frame, or a second source heartbeating twice within CONFLICT_HEARTBEAT_S while the bound one
  goes on after the first of them. Only the bound source's clock is ever handed on, so the two are never mixed.

A single forged frame, or a few without a HEARTBEAT from their source, or a few over less than 0.5 s while the
vehicle's own stream goes on, are outliers and nothing else (docs/security.md, docs/bridge.md "Reordering,
vehicle restarts and re-engagement").
"""

from __future__ import annotations

from dataclasses import dataclass

CLOCK_TOLERANCE_MS = 100.0  # a frame ahead of the host clock, or behind the stream's newest, by more: an outlier
CLOCK_DRIFT = 0.01  # the anchor's allowance for a vehicle clock slower than the host's (1 %, a lockstep sim)
CONFIRM_FRAMES = 3  # consistent frames of one new clock before it is adopted (a restart) or is a second vehicle
CANDIDATE_FORGET_S = 1.0  # a second clock with no frame for this long is forgotten
HEARTBEAT_RECENT_S = 1.5  # a HEARTBEAT from a source this recent corroborates it (autopilots send one every 1 s)
SOURCE_SILENT_S = 1.5  # the bound source silent this long: another source's HEARTBEAT takes its place
CONFLICT_SPAN_S = 0.5  # a second clock going on this long beside the vehicle's is a second vehicle
CONFLICT_HEARTBEAT_S = 3.0  # two HEARTBEATs of a second source within this: a second vehicle
IDENTITY_LISTEN_S = 2.2  # before engaging, listen this long after the first HEARTBEAT: two HEARTBEAT periods and a margin
MAX_CANDIDATES = 4  # second clocks followed at once (a new one replaces the oldest)
MAX_PERIOD_MS = 500.0  # the period estimate's ceiling (2 Hz)


@dataclass(frozen=True, slots=True)
class Source:
    """Where a frame came from: UDP ``address`` ("host:port", "" on serial/TCP), MAVLink 2 signing ``link_id``
    (None unsigned), ``system`` and ``component`` id."""

    address: str
    link_id: int | None
    system: int
    component: int

    def __str__(self) -> str:
        where = self.address or "the link"
        link = f", link {self.link_id}" if self.link_id is not None else ""
        return f"{where} (system {self.system}, component {self.component}{link})"


class ClockStream:
    """One source's ``time_boot_ms`` as a stream: its newest frame, its least-delayed offset, its period.

    ``offset_ms`` = max over frames of (time_boot_ms - host receive time [ms]): the vehicle clock at host time 0 as
    the least-delayed frame tells it (network and scheduling delays only ever lower it). It decays by CLOCK_DRIFT
    of the elapsed host time so a vehicle clock running slower than the host's is followed.
    """

    def __init__(self, source: Source, t_ms: int, rx_ns: int) -> None:
        self.source = source
        self.first_ms = t_ms
        self.last_ms = t_ms
        self.last_rx_ns = rx_ns
        self.first_rx_ns = rx_ns
        self.offset_ms = t_ms - rx_ns / 1e6
        self.period_ms = 0.0
        self.frames = 1

    def tolerance_ms(self) -> float:
        return CLOCK_TOLERANCE_MS + 2.0 * self.period_ms

    def fits(self, t_ms: int, rx_ns: int) -> bool:
        """True when ``t_ms`` [ms] received at ``rx_ns`` [ns, host monotonic] continues this clock."""
        tol = self.tolerance_ms()
        anchor = self.offset_ms - CLOCK_DRIFT * max(0.0, (rx_ns - self.last_rx_ns) / 1e6)
        return t_ms - rx_ns / 1e6 <= anchor + tol and t_ms >= self.last_ms - tol

    def add(self, t_ms: int, rx_ns: int) -> None:
        """A frame that fits: the newest frame, the anchor and the period move on."""
        elapsed_ms = max(0.0, (rx_ns - self.last_rx_ns) / 1e6)
        self.offset_ms = max(t_ms - rx_ns / 1e6, self.offset_ms - CLOCK_DRIFT * elapsed_ms)
        step = t_ms - self.last_ms
        if 0 < step <= MAX_PERIOD_MS:
            self.period_ms = step if self.frames == 1 else 0.9 * self.period_ms + 0.1 * step
        self.last_ms = max(self.last_ms, t_ms)
        self.last_rx_ns = rx_ns
        self.frames += 1


@dataclass(frozen=True, slots=True)
class Judgement:
    """What to do with one ATTITUDE frame: hand it on or not; ``restart`` says why it starts a new vehicle session
    ("" when it does not); ``conflict`` is set (once) when this frame made two vehicles of one identity certain."""

    deliver: bool
    restart: str = ""
    conflict: str = ""


def conflict_text(a: Source, b: Source) -> str:
    """The one line that names two vehicles sharing an identity and the fix."""
    return (f"two vehicles claim system {a.system} component {a.component}: {a} and {b}; give each its own system id "
            "(ArduPilot SYSID_THISMAV, PX4 MAV_SYS_ID) and choose one with --target-system")


class AttitudeStreams:
    """The bound source, the vehicle's clock and any second clocks (see the module docstring). The link's reader
    thread is the only caller; times are host monotonic [ns], passed in (tests inject them)."""

    def __init__(self) -> None:
        self.bound: Source | None = None
        self.clock: ClockStream | None = None
        self.candidates: list[ClockStream] = []
        self.conflict = ""  # the first identity conflict, named
        self._heartbeats: dict[Source, list[int]] = {}  # source -> host times [ns] of its last two HEARTBEATs
        self._bound_seen_ns = 0  # the bound source's last HEARTBEAT or fitting ATTITUDE

    # ------------------------------------------------------------------ HEARTBEAT
    def heartbeat(self, source: Source, rx_ns: int) -> tuple[bool, str]:
        """A vehicle HEARTBEAT of the target identity: (hand it on?, conflict text when this one made it certain)."""
        times = self._heartbeats.setdefault(source, [])
        times[:] = (times + [rx_ns])[-2:]
        if len(self._heartbeats) > 4 * MAX_CANDIDATES:  # bounded: keep the bound source and the most recent others
            oldest = min((s for s in self._heartbeats if s != self.bound and s != source), key=lambda s: self._heartbeats[s][-1])
            del self._heartbeats[oldest]
        if self.bound is None or source == self.bound:
            self.bound = source
            self._bound_seen_ns = rx_ns
            return True, ""
        silent_since_first = len(times) == 2 and self._bound_seen_ns < times[0]
        if (rx_ns - self._bound_seen_ns) * 1e-9 > SOURCE_SILENT_S or silent_since_first:
            # the vehicle is back on another address (a rebooted SITL's udpclient): its clock is judged by its frames
            self.bound = source
            self._bound_seen_ns = rx_ns
            return True, ""
        if len(times) == 2 and (times[1] - times[0]) * 1e-9 <= CONFLICT_HEARTBEAT_S:
            return False, self._name_conflict(self.bound, source)  # the bound source went on after this one began
        return False, ""

    def _heartbeat_recent(self, source: Source, rx_ns: int) -> bool:
        times = self._heartbeats.get(source)
        return bool(times) and (rx_ns - times[-1]) * 1e-9 <= HEARTBEAT_RECENT_S

    def _name_conflict(self, a: Source, b: Source) -> str:
        if self.conflict:
            return ""
        self.conflict = conflict_text(a, b)
        return self.conflict

    # ------------------------------------------------------------------ ATTITUDE
    def judge(self, source: Source, t_ms: int, rx_ns: int) -> Judgement:
        """One ATTITUDE of the target identity (valid fields; see the module docstring for the rule)."""
        clock = self.clock
        if clock is None:
            if self.bound is None or source == self.bound:
                self.bound = source
                self.clock = ClockStream(source, t_ms, rx_ns)
                self._bound_seen_ns = rx_ns
                return Judgement(True)
        elif source == clock.source and clock.fits(t_ms, rx_ns):
            clock.add(t_ms, rx_ns)
            self._bound_seen_ns = rx_ns
            return Judgement(True)
        return self._outlier(source, t_ms, rx_ns)

    def _outlier(self, source: Source, t_ms: int, rx_ns: int) -> Judgement:
        self.candidates = [c for c in self.candidates if (rx_ns - c.last_rx_ns) * 1e-9 <= CANDIDATE_FORGET_S]
        cand = next((c for c in self.candidates if c.source == source and c.fits(t_ms, rx_ns)), None)
        if cand is None:
            cand = ClockStream(source, t_ms, rx_ns)
            self.candidates = (self.candidates + [cand])[-MAX_CANDIDATES:]
        else:
            cand.add(t_ms, rx_ns)
        if cand.frames < CONFIRM_FRAMES or not self._heartbeat_recent(source, rx_ns):
            return Judgement(False)
        old = self.clock
        if source == self.bound and old is not None and old.last_rx_ns < cand.first_rx_ns:
            return self._adopt(cand, t_ms)
        going_on = old.source if old is not None and old.last_rx_ns >= cand.first_rx_ns else None
        if going_on is None and source != self.bound and self._bound_seen_ns >= cand.first_rx_ns:
            going_on = self.bound  # the bound source heartbeats on (its ATTITUDE not yet, or no longer, streaming)
        if going_on is not None and (cand.last_rx_ns - cand.first_rx_ns) * 1e-9 >= CONFLICT_SPAN_S:
            return Judgement(False, conflict=self._name_conflict(going_on, source))
        return Judgement(False)

    def _adopt(self, cand: ClockStream, t_ms: int) -> Judgement:
        """The old clock stopped and a corroborated new one of the bound source goes on: the vehicle's from now on."""
        old = self.clock
        self.candidates.remove(cand)
        self.clock = cand
        self._bound_seen_ns = cand.last_rx_ns
        if cand.source != old.source or t_ms < old.last_ms:
            moved = f" from {cand.source}" if cand.source != old.source else ""
            return Judgement(True, restart=f"vehicle restarted{moved} (time_boot_ms {old.last_ms} -> {cand.first_ms} ms, "
                                           f"confirmed by {cand.frames} consistent frames at {t_ms} ms)")
        return Judgement(True)
