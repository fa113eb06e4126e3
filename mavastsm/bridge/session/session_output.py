"""Where the offboard session's decisions leave it: setpoints through the final gate to the link, and the run's record
of each sample (the first ones kept in memory for the summary's metrics; every one as a flight-log row and in the
telemetry the dashboard reads) with every cycle's latency. Called by ``OffboardSession`` under its lock (the reader
thread's cycles, the supervisor's holds); the summary and the dashboard's status read ``samples`` and ``latencies_s``
(run_record.py)."""

from __future__ import annotations

import array
import collections
import math
from typing import Callable

import numpy as np

from ...frames import euler_rates_from_body_rates_floats
from ...telemetry import ControlSample, TelemetryBuffer
from ..record.flight_log import IDENTIFYING_PHASE, PHASE_OF_STATE, FlightLog
from ..link.messages import AttitudeSample, HeartbeatInfo
from ..cycle.safety import AdmittedSetpoint, OutputGate
from .session_counters import SessionCounters
from ..link.messages import TYPE_MASK_ATTITUDE, Setpoint

LIVE_LATENCY_WINDOW = 4096  # cycles behind the live p50/p99 (about 10 s at 400 Hz); the end summary uses every cycle


class LatencyRecord:
    """Every cycle's latency [s] (ATTITUDE received -> SET_ATTITUDE_TARGET sent) in bounded memory.

    A whole run's p50/p99/max come from a histogram of 1 us bins up to HISTOGRAM_MAX_S (order statistics exact
    to 1 us, 0.8 MB however long the flight); a slower cycle is kept as measured (at most SLOW_KEPT of them).
    The last ``live_n`` values are also kept as measured, for the live view. (An array of every value grew
    by 8 bytes a cycle: about 9 MB an hour at 320 Hz.)
    """

    RESOLUTION_S = 1e-6
    HISTOGRAM_MAX_S = 0.1
    SLOW_KEPT = 100_000

    def __init__(self, live_n: int) -> None:
        self._bins = np.zeros(int(round(self.HISTOGRAM_MAX_S / self.RESOLUTION_S)), dtype=np.int64)
        self._slow = array.array("d")
        self._live: collections.deque = collections.deque(maxlen=live_n)
        self.count = 0

    def append(self, latency_s: float) -> None:
        self.count += 1
        self._live.append(latency_s)
        i = int(latency_s / self.RESOLUTION_S)
        if 0 <= i < len(self._bins):
            self._bins[i] += 1
        elif len(self._slow) < self.SLOW_KEPT:
            self._slow.append(latency_s)

    def extend(self, values) -> None:
        for v in values:
            self.append(float(v))

    def percentiles(self, last_n: int | None = None) -> tuple[float, float, float]:
        """(p50, p99, max) [s] over every cycle (to 1 us), or over the last ``last_n`` (at most ``live_n``) as measured.

        Called every second by the supervisor (``last_n``) while the reader thread appends: the window is copied
        first (in C, under the GIL) and sorted by NumPy, because ``sorted()`` over the whole run held the GIL for
        milliseconds once a second and made the reader miss samples.
        """
        if not self.count:
            return float("nan"), float("nan"), float("nan")
        if last_n:
            xs = np.sort(np.fromiter(list(self._live)[-last_n:], dtype=np.float64))
            n = len(xs)
            return float(xs[int(0.5 * (n - 1))]), float(xs[min(n - 1, int(math.ceil(0.99 * (n - 1))))]), float(xs[-1])
        cum = np.cumsum(self._bins)
        in_bins = int(cum[-1])
        slow = np.sort(np.frombuffer(self._slow, dtype=np.float64)) if self._slow else np.empty(0)
        n = in_bins + len(slow)

        def order_statistic(k: int) -> float:
            if k < in_bins:
                return float(np.searchsorted(cum, k, side="right")) * self.RESOLUTION_S
            return float(slow[min(k - in_bins, len(slow) - 1)])

        return order_statistic(int(0.5 * (n - 1))), order_statistic(min(n - 1, int(math.ceil(0.99 * (n - 1))))), order_statistic(n - 1)


class SessionOutput:
    """The final gate to the link and the run's record (see module docstring).

    Parameters
    ----------
    link : object with ``send_setpoint(Setpoint)`` and ``stats.bad_data`` (logged with each row)
    gate : the cycle's output gate (``safety.OutputGate``): what the cycle admitted goes out as it is, any other
        setpoint only when it is inside the limits (``verify``)
    counters : the session's SessionCounters (blocked_setpoints counted here)
    telemetry : TelemetryBuffer (written every cycle, never waited on)
    flight_log : FlightLog
    samples_kept : how many samples to keep in memory (the first ones; the CSV keeps everything)
    """

    def __init__(self, link, gate: OutputGate, counters: SessionCounters, telemetry: TelemetryBuffer,
                 flight_log: FlightLog, samples_kept: int) -> None:
        self.link = link
        self.gate = gate
        self.counters = counters
        self.telemetry = telemetry
        self.flight_log = flight_log
        self.max_samples_kept = samples_kept
        self.samples: list[ControlSample] = []
        self.latencies_s = LatencyRecord(LIVE_LATENCY_WINDOW)

    def send(self, sp: Setpoint) -> bool:
        """Through the output gate to the link: a setpoint the cycle admitted as it is (checked once), any other only when
        ``gate.verify`` finds it finite, inside the limits and with an allowed mask."""
        if type(sp) is not AdmittedSetpoint and self.gate.verify(sp) is None:
            self.counters.blocked_setpoints += 1
            return False
        try:
            self.link.send_setpoint(sp)
        except Exception:  # a socket error must not kill the loop; link loss is detected by the supervisor
            self.counters.blocked_setpoints += 1
            return False
        return True

    def send_cycle(self, sp: Setpoint, rx_ns: int, clock_ns: Callable[[], int]) -> float:
        """A controller cycle's setpoint through the gate, the cycle counted; returns its latency [s] (ATTITUDE parsed
        -> SET_ATTITUDE_TARGET written, on ``clock_ns``), kept when the setpoint went out."""
        sent = self.send(sp)
        latency_s = (clock_ns() - rx_ns) * 1e-9
        self.counters.cycles += 1
        if sent:
            self.latencies_s.append(latency_s)
        return latency_s

    def record(self, sample: ControlSample, state: str, hb: HeartbeatInfo | None, altitude_fn: Callable[[], float]) -> None:
        """A sample of the session's (a cycle, a failsafe): kept (the first ones), logged and published."""
        if len(self.samples) < self.max_samples_kept:
            self.samples.append(sample)
        self.log(sample, state, hb, altitude_fn)
        self.telemetry.publish(sample)

    def log(self, sample: ControlSample, state: str, hb: HeartbeatInfo | None, altitude_fn: Callable[[], float]) -> None:
        """One flight-log row with the phase of ``state``, the last HEARTBEAT's mode and armed, and the altitude."""
        phase = IDENTIFYING_PHASE if sample.identifying else PHASE_OF_STATE.get(state, state)
        self.flight_log.append(sample, self.link.stats.bad_data, phase,
                               hb.mode if hb is not None else "", hb is not None and hb.armed, altitude_fn())

    def log_phase_row(self, state: str, s: AttitudeSample, sp: Setpoint | None, hb: HeartbeatInfo | None,
                      altitude_fn: Callable[[], float]) -> None:
        """A flight-log row for a sample outside the engaged phase (takeoff, level hold, hand-back): the attitude
        and, when one was sent, the setpoint's thrust and body rates (NaN when the setpoint commands an attitude).
        The log only: the summary's samples and the dashboard keep the controller's cycles."""
        commanded = (float("nan"),) * 3
        if sp is not None and not sp.type_mask & TYPE_MASK_ATTITUDE:  # the body-rate ignore bits
            commanded = sp.body_rates_rads
        self.log(ControlSample(s.time_boot_ms / 1000.0, euler_rad=s.euler_rad,
                               euler_rate_rads=euler_rates_from_body_rates_floats(s.euler_rad[0], s.euler_rad[1], *s.body_rates_rads),
                               commanded_rates_rads=commanded, thrust_norm=sp.thrust_norm if sp is not None else float("nan")),
                 state, hb, altitude_fn)
