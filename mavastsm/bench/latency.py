"""Pure bookkeeping for the latency benchmark: pair each SET_ATTITUDE_TARGET with the ATTITUDE it answers.

No sockets, no clocks: the stub vehicle (``bench_stub_vehicle``) feeds host timestamps in
[ns, ``time.perf_counter_ns``] and this module turns them into cycle latency statistics.

Definitions (measured from outside the client, as a vehicle would see it)
-------------------------------------------------------------------------
- *sample k*: the k-th ATTITUDE the stub sent (``seq`` = k), at host time ``sent_ns[k]``.
- *answer to k*: the first SET_ATTITUDE_TARGET attributed to sample k (rules below); its host
  receive time is ``answer_ns[k]``. Latency = ``answer_ns[k] - sent_ns[k]``.
- *missed cycle*: sample k whose answer had not arrived when sample k+1 was sent (late or never).
- *unanswered*: sample k never answered at all (a subset of missed).
- *extra*: a reply attributed to a sample that already had its answer (e.g. MAVSDK's 20 Hz
  keep-alive re-send of the last setpoint); never counted as an answer.

Pairing rules (``PairingRule``), chosen per client because clients differ in what they put on the wire
------------------------------------------------------------------------------------------------------
- ``ECHO``: the reply's ``time_boot_ms`` equals the ``time_boot_ms`` of the ATTITUDE it answers
  (our naive pymavlink loop does this). Exact.
- ``ROLL_CODE``: the stub's roll angle is a sawtooth that encodes ``seq mod CODE_PERIOD``
  (``roll_code_rad``); the baseline clients fly the P law ``rate = -BASELINE_KP * angle``
  (``baseline_rates_rads``), so the reply's roll rate decodes back to the sample it was computed
  from. Exact, and works for MAVSDK, which writes its own clock into ``time_boot_ms``.
- ``ARRIVAL``: the reply answers the newest sample sent before it arrived; a reply whose payload
  is bit-identical to the previous reply is a keep-alive repeat and is ignored. Approximate: when
  latency exceeds one period it under-reports latency (and then also shows missed cycles).

Every rule only ever attributes a reply to a sample already sent, so no latency can be negative.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

#: Samples per sawtooth period of the roll code (ROLL_CODE rule).
CODE_PERIOD = 1000
#: [rad] peak-to-peak amplitude of the roll sawtooth; roll stays within +-ROLL_CODE_SPAN_RAD/2 (+-2.9 deg).
ROLL_CODE_SPAN_RAD = 0.1
#: [1/s] gain of the baseline clients' P law on angle: body rate command = -BASELINE_KP * angle.
BASELINE_KP = 2.0
#: [0..1] thrust the baseline clients send (ArduCopter climb-rate semantics: 0.5 = hold altitude).
BASELINE_THRUST = 0.5


class PairingRule(str, enum.Enum):
    ECHO = "echo_time_boot_ms"
    ROLL_CODE = "roll_code"
    ARRIVAL = "arrival_order"


def roll_code_rad(seq: int) -> float:
    """[rad] roll angle the stub reports for sample ``seq`` (sawtooth encoding ``seq mod CODE_PERIOD``)."""
    return ROLL_CODE_SPAN_RAD * ((seq % CODE_PERIOD) / CODE_PERIOD - 0.5)


def decode_roll_code(roll_rad: float) -> int | None:
    """Inverse of ``roll_code_rad`` up to the period: ``seq mod CODE_PERIOD``, or None if not a code value."""
    if not math.isfinite(roll_rad):
        return None
    x = (roll_rad / ROLL_CODE_SPAN_RAD + 0.5) * CODE_PERIOD
    residue = round(x)
    if abs(x - residue) > 0.25 or not 0 <= residue < CODE_PERIOD:
        return None
    return residue


def baseline_rates_rads(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float]:
    """[rad/s, body FRD] the baseline clients' command: a P law on Euler angles toward level, heading 0."""
    return (-BASELINE_KP * roll_rad, -BASELINE_KP * pitch_rad, -BASELINE_KP * yaw_rad)


@dataclass(frozen=True)
class LatencyStats:
    """Cycle statistics over a measurement window. Latencies in microseconds [us]."""

    rule: str
    samples: int
    answered: int
    missed: int
    unanswered: int
    extra: int
    repeats: int
    undecodable: int
    p50_us: float
    p99_us: float
    max_us: float
    mean_us: float
    #: [us] largest gap between consecutive ATTITUDE sends (the stub's own timing, machine load).
    stub_max_send_gap_us: float


class CyclePairing:
    """Attribute replies to samples and compute ``LatencyStats`` (pure; fed by the stub thread).

    Parameters
    ----------
    rule : how a reply names the sample it answers (see module docstring).
    """

    def __init__(self, rule: PairingRule) -> None:
        self.rule = PairingRule(rule)
        self.sent_ns: list[int] = []
        self.answer_ns: list[int | None] = []
        self._seq_by_tbm: dict[int, int] = {}
        self._last_payload: tuple | None = None
        self.extra = 0
        self.repeats = 0
        self.undecodable = 0

    def on_sent(self, time_boot_ms: int, sent_ns: int) -> int:
        """Record sample number ``len(sent_ns)``; returns its seq."""
        seq = len(self.sent_ns)
        self.sent_ns.append(sent_ns)
        self.answer_ns.append(None)
        if self.rule is PairingRule.ECHO:
            self._seq_by_tbm[time_boot_ms] = seq
        return seq

    def _seq_for(self, time_boot_ms: int, roll_rate_rads: float, payload: tuple) -> int | None:
        last = len(self.sent_ns) - 1
        if last < 0:
            return None
        if self.rule is PairingRule.ECHO:
            return self._seq_by_tbm.get(time_boot_ms)
        if self.rule is PairingRule.ROLL_CODE:
            residue = decode_roll_code(-roll_rate_rads / BASELINE_KP)
            if residue is None:
                return None
            seq = last - ((last - residue) % CODE_PERIOD)
            return seq if seq >= 0 else None
        # ARRIVAL
        if payload == self._last_payload:
            self.repeats += 1
            return -1
        return last

    def on_reply(self, recv_ns: int, time_boot_ms: int, rates_rads: tuple[float, float, float], thrust: float) -> str:
        """Attribute one SET_ATTITUDE_TARGET; returns "answer", "extra", "repeat" or "undecodable"."""
        payload = (rates_rads[0], rates_rads[1], rates_rads[2], thrust)
        seq = self._seq_for(time_boot_ms, rates_rads[0], payload)
        self._last_payload = payload
        if seq == -1:
            return "repeat"
        if seq is None:
            self.undecodable += 1
            return "undecodable"
        if self.answer_ns[seq] is not None:
            self.extra += 1
            return "extra"
        self.answer_ns[seq] = recv_ns
        return "answer"

    def stats(self, first_seq: int = 0, last_seq: int | None = None) -> LatencyStats:
        """Statistics over samples ``first_seq..last_seq`` (inclusive; default all but the newest)."""
        if last_seq is None:
            last_seq = len(self.sent_ns) - 2  # the newest sample cannot be judged "missed" yet
        last_seq = min(last_seq, len(self.sent_ns) - 2)
        lat_ns: list[int] = []
        missed = unanswered = 0
        for k in range(first_seq, last_seq + 1):
            ans = self.answer_ns[k]
            if ans is None:
                missed += 1
                unanswered += 1
                continue
            lat_ns.append(ans - self.sent_ns[k])
            if ans > self.sent_ns[k + 1]:
                missed += 1
        n = max(0, last_seq - first_seq + 1)
        sends = np.asarray(self.sent_ns[first_seq : last_seq + 2], dtype=np.int64)
        gap_us = float(np.max(np.diff(sends)) / 1e3) if sends.size > 1 else float("nan")
        if lat_ns:
            lat_us = np.asarray(lat_ns, dtype=np.float64) / 1e3
            p50, p99 = (float(v) for v in np.percentile(lat_us, [50, 99]))
            mx, mean = float(lat_us.max()), float(lat_us.mean())
        else:
            p50 = p99 = mx = mean = float("nan")
        return LatencyStats(
            rule=self.rule.value, samples=n, answered=len(lat_ns), missed=missed, unanswered=unanswered,
            extra=self.extra, repeats=self.repeats, undecodable=self.undecodable,
            p50_us=p50, p99_us=p99, max_us=mx, mean_us=mean, stub_max_send_gap_us=gap_us,
        )
