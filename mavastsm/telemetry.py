"""What the control loop publishes and the dashboard (or status lines, or tests) reads.

One writer (the bridge's control loop) and any number of readers. The writer never waits on a
reader: ``publish`` appends to a bounded deque under a lock held for a few hundred nanoseconds;
readers copy what they need in ``snapshot`` (everything) or ``samples_since`` (only what is new since
a cursor, for the dashboard's drawing process). All quantities SI (rad, rad/s, N m, s); the view
converts to degrees at the edge.
"""

from __future__ import annotations

import collections
import itertools
import threading
import time
from dataclasses import dataclass, field
from typing import Mapping

from .state_types import FailsafeReason

Vec3 = tuple[float, float, float]
NAN3: Vec3 = (float("nan"), float("nan"), float("nan"))


# controller diagnostics keys that have their own ControlSample field (key -> field); every other key goes to ``extra``
DIAGNOSTIC_FIELDS = {"sigma": "sigma", "alpha": "alpha", "beta": "beta", "nu": "nu", "u_eq": "u_eq", "u_d": "u_d", "u": "u_nm"}


def extra_diagnostic_keys(diagnostics) -> tuple[str, ...]:
    """The keys of a controller's ``diagnostics()`` that travel in ``ControlSample.extra`` (stable per controller)."""
    return tuple(k for k in diagnostics if k not in DIAGNOSTIC_FIELDS)


@dataclass(frozen=True, slots=True)
class ControlSample:
    """One control cycle. Axis order [roll, pitch, yaw]; NaN where a controller lacks the quantity.

    Attributes
    ----------
    vehicle_time_s : [s] vehicle clock (ATTITUDE.time_boot_ms / 1000)
    reference_rad, euler_rad : [rad] Theta_d and Theta (ZYX, NED -> FRD)
    euler_rate_rads : [rad/s] Theta_dot (Euler rates)
    error_rad : [rad] e = Theta - Theta_d (yaw wrapped)
    sigma : [rad/s] sliding variable sigma = e_dot + Lambda e (eq. 19)
    alpha, beta, nu : ASTSM internals (eqs. 25, 34, 35), in the controller's gain units
    u_eq, u_d, u_nm : [N m] equivalent, switching and total control (eq. 18)
    commanded_rates_rads : [rad/s, body FRD] body rates sent in SET_ATTITUDE_TARGET
    thrust_norm : [0..1] thrust field sent (climb-rate or collective, see LinkStatus.thrust_semantics)
    latency_s : [s] ATTITUDE received -> SET_ATTITUDE_TARGET sent
    failsafe : active reason, or None while the controller output is being sent
    extra : the controller's other per-axis diagnostics (any controller, e.g. PID's ``integrator``), as
        ``((key, (roll, pitch, yaw)), ...)`` in the order its ``diagnostics()`` gives them, in its own units
    identifying : a cycle of the in-flight identification phase (its excitation, not the profile: no metric counts it)
    """

    vehicle_time_s: float
    reference_rad: Vec3 = NAN3
    euler_rad: Vec3 = NAN3
    euler_rate_rads: Vec3 = NAN3
    error_rad: Vec3 = NAN3
    sigma: Vec3 = NAN3
    alpha: Vec3 = NAN3
    beta: Vec3 = NAN3
    nu: Vec3 = NAN3
    u_eq: Vec3 = NAN3
    u_d: Vec3 = NAN3
    u_nm: Vec3 = NAN3
    commanded_rates_rads: Vec3 = NAN3
    thrust_norm: float = float("nan")
    latency_s: float = float("nan")
    failsafe: FailsafeReason | None = None
    extra: tuple = ()
    identifying: bool = False


@dataclass(frozen=True, slots=True)
class LinkStatus:
    """Link and vehicle state, refreshed by the bridge about once a second."""

    url: str = ""
    autopilot: str = "unknown"  # "ArduPilot" | "PX4" | "unknown"
    firmware_version: str = ""
    mode: str = ""
    armed: bool = False
    thrust_semantics: str = ""  # "climb_rate" (ArduCopter default, 0.5 = hold) | "collective"
    attitude_rate_requested_hz: float = float("nan")
    attitude_rate_achieved_hz: float = float("nan")
    latency_p50_s: float = float("nan")  # over the last LIVE_LATENCY_WINDOW cycles (about 10 s at 400 Hz)
    latency_p99_s: float = float("nan")
    cycles: int = 0
    missed: int = 0
    # the same counters, names and definitions as BridgeSummary's:
    dropped: int = 0  # ATTITUDE older (time_boot_ms) than the last one used
    duplicate: int = 0  # same time_boot_ms as the last one used
    superseded: int = 0  # queued back to back: an older one of a burst, the newest was used
    invalid: int = 0  # NaN/inf/out-of-range samples dropped
    time_since_attitude_s: float = float("nan")
    signing: bool = False
    phase: str = ""  # what the bridge is doing, in words (Bridge.phase_text)
    refused_frames: int = 0  # frames the link refused (bad CRC, garbage, unsigned, bad signature, replayed)
    out_of_order: int = 0
    clock_outliers: int = 0
    foreign_attitude: int = 0
    blocked_setpoints: int = 0
    overruns: int = 0
    late: int = 0
    reader_errors: int = 0


# Every counter the link and the session keep: one name and one definition, the same in the summary
# (BridgeSummary), the dashboard (LinkStatus) and the CSV's sidecar ("counters", written when the run ends).
COUNTER_DEFINITIONS = {
    "cycles": "control cycles whose setpoint reached the send gate (ATTITUDE in, controller setpoint out)",
    "missed": "ATTITUDE periods skipped while engaged (a gap over two periods, less the superseded samples)",
    "dropped": "ATTITUDE older (time_boot_ms) than the last one used",
    "duplicate": "ATTITUDE with the same time_boot_ms as the last one used",
    "superseded": "ATTITUDE queued back to back in the reader: an older one of a burst (the newest was used)",
    "out_of_order": "queued ATTITUDE older (time_boot_ms) than one pending in the reader: discarded",
    "clock_outliers": "ATTITUDE whose time_boot_ms did not fit the vehicle's clock and that the stream refuted: dropped",
    "invalid": "ATTITUDE with NaN/inf/out-of-range values: dropped",
    "foreign_attitude": "ATTITUDE from another system or component than the target",
    "blocked_setpoints": "setpoints not sent: outside the limits at the final gate, or the send failed",
    "overruns": "cycles whose latency (ATTITUDE arrived -> setpoint written) exceeded one nominal period",
    "late": "the bridge's own deadline misses while engaged: an overrun, or each period a sample waited in the reader "
            "before a newer one replaced it (a vehicle's burst is not late; missed counts the vehicle's gaps)",
    "refused_frames": "frames the link refused (bad CRC, garbage, unsigned, bad signature, replayed)",
    "reader_errors": "exceptions in the link's reader, heartbeat or delivery threads (counted, the thread went on)",
}


@dataclass(frozen=True, slots=True)
class SessionInfo:
    """What is being run: set once at start (and on re-engagement)."""

    controller: str = ""
    gain_summary: Mapping[str, str] = field(default_factory=dict)
    mu: Vec3 = NAN3  # [rad/s] ASTSM sigma band (eq. 34)
    alpha_min: Vec3 = NAN3
    alpha_max: Vec3 = NAN3
    reference_name: str = ""
    reference_start_vehicle_time_s: float = float("nan")
    reference_duration_s: float = float("nan")
    on_failsafe: str = ""
    on_exit: str = ""
    log_paths: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class TelemetrySnapshot:
    """Everything a view needs, copied at one instant. Plain data: build views with pure functions."""

    history: tuple[ControlSample, ...]
    link: LinkStatus
    session: SessionInfo
    active_failsafe: FailsafeReason | None
    wall_time_s: float

    @property
    def latest(self) -> ControlSample | None:
        return self.history[-1] if self.history else None


class TelemetryBuffer:
    """Bounded buffer between the control loop (writer) and views (readers).

    Parameters
    ----------
    capacity : max samples kept (default 4000 = 10 s at 400 Hz); oldest dropped first.
    """

    def __init__(self, capacity: int = 4000) -> None:
        if capacity <= 0:
            raise ValueError(f"capacity must be > 0, got {capacity}")
        self._samples: collections.deque[ControlSample] = collections.deque(maxlen=capacity)
        self._published = 0  # total samples ever published (a cursor for incremental readers)
        self._lock = threading.Lock()
        self.link = LinkStatus()
        self.session = SessionInfo()
        self.active_failsafe: FailsafeReason | None = None

    def publish(self, sample: ControlSample) -> None:
        """Append one cycle (writer side; O(1), never blocks on readers for long)."""
        with self._lock:
            self._samples.append(sample)
            self._published += 1
        self.active_failsafe = sample.failsafe

    def set_link(self, status: LinkStatus) -> None:
        self.link = status

    def set_session(self, info: SessionInfo) -> None:
        self.session = info

    @property
    def capacity(self) -> int:
        return self._samples.maxlen or 0

    def samples_since(self, cursor: int) -> tuple[int, tuple[ControlSample, ...]]:
        """Samples published after ``cursor`` (oldest first, at most ``capacity``) and the new cursor.

        Start with cursor 0. Samples that fell out of the buffer before being read are skipped.
        """
        with self._lock:
            published = self._published
            n_new = min(published - cursor, len(self._samples))
            new = tuple(itertools.islice(reversed(self._samples), max(0, n_new)))
        return published, new[::-1]

    def snapshot(self, max_samples: int | None = None) -> TelemetrySnapshot:
        """Copy the newest ``max_samples`` samples (all when None) plus link and session state."""
        with self._lock:
            hist = tuple(self._samples)
        if max_samples is not None:
            hist = hist[-max_samples:] if max_samples > 0 else ()
        return TelemetrySnapshot(hist, self.link, self.session, self.active_failsafe, time.time())
