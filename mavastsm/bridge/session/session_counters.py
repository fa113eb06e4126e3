"""Every count the offboard session keeps, in one record: written under the session's lock (the reader thread's
samples and cycles, the supervisor's failsafes), read by the run's summary, the log's sidecar and the dashboard's
link status (run_record.py), the supervisor's news (supervision.py) and the tests.

The names are the summary's (``BridgeSummary``) and, where the sidecar and the dashboard name one too, the ones
defined in ``telemetry.COUNTER_DEFINITIONS``. Streaks that decide a failsafe (consecutive invalid samples,
consecutive overruns) are not counts of the run and stay with the code that acts on them.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class SessionCounters:
    """The session's counts since it was built (never reset: a new vehicle session counts on)."""

    cycles: int = 0  # control cycles whose setpoint reached the send gate
    missed: int = 0  # ATTITUDE periods skipped while engaged (a gap over two periods, less the superseded samples)
    dropped: int = 0  # ATTITUDE older (time_boot_ms) than the last one used
    duplicate: int = 0  # ATTITUDE with the same time_boot_ms as the last one used
    invalid: int = 0  # ATTITUDE with NaN/inf/out-of-range values
    blocked_setpoints: int = 0  # setpoints not sent: outside the limits at the final gate, or the send failed
    overruns: int = 0  # cycles whose latency (from the sample's arrival) exceeded one nominal period
    superseded_waits: int = 0  # periods a sample waited in the reader while engaged before a newer one replaced it
    controller_faults: int = 0  # exceptions caught in the control cycle (each one is a CONTROLLER_FAULT)
    engagements: int = 0  # times the controller was engaged (reset) on a sample
    vehicle_restarts: int = 0  # time_boot_ms went back by more than the restart threshold, or a BOOT HEARTBEAT in a gap
    vehicle_sessions: int = 1  # 1 + restarts + HEARTBEAT reappearances after a link-loss gap

    @property
    def late(self) -> int:
        """The bridge's own deadline misses while engaged (telemetry.COUNTER_DEFINITIONS): every overrun (a cycle
        answered over a nominal period after its sample arrived) and every period a sample waited superseded."""
        return self.overruns + self.superseded_waits
