"""TelemetryBuffer: bounded, snapshot copies, incremental reads with a cursor."""

from __future__ import annotations

import pytest

from mavastsm.state_types import FailsafeReason
from mavastsm.telemetry import ControlSample, TelemetryBuffer


def times(samples) -> list[float]:
    return [s.vehicle_time_s for s in samples]


def test_samples_since_returns_only_new_samples_and_skips_overwritten_ones():
    buf = TelemetryBuffer(capacity=5)
    cursor, new = buf.samples_since(0)
    assert (cursor, new) == (0, ())
    for k in range(3):
        buf.publish(ControlSample(float(k)))
    cursor, new = buf.samples_since(cursor)
    assert cursor == 3 and times(new) == [0.0, 1.0, 2.0]
    for k in range(3, 10):  # 7 more into a buffer of 5: samples 3 and 4 are gone before being read
        buf.publish(ControlSample(float(k)))
    cursor, new = buf.samples_since(cursor)
    assert cursor == 10 and times(new) == [5.0, 6.0, 7.0, 8.0, 9.0]
    assert buf.samples_since(cursor) == (10, ())


def test_snapshot_is_bounded_and_tracks_the_latest_failsafe():
    buf = TelemetryBuffer(capacity=3)
    for k in range(5):
        buf.publish(ControlSample(float(k), failsafe=FailsafeReason.LINK_LOST if k == 4 else None))
    snap = buf.snapshot()
    assert times(snap.history) == [2.0, 3.0, 4.0] and snap.latest.vehicle_time_s == 4.0
    assert snap.active_failsafe is FailsafeReason.LINK_LOST
    assert times(buf.snapshot(max_samples=1).history) == [4.0] and buf.snapshot(max_samples=0).history == ()


def test_capacity_must_be_positive():
    with pytest.raises(ValueError, match="capacity"):
        TelemetryBuffer(capacity=0)
