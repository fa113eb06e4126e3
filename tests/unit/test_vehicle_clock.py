"""The vehicle's clock as a stream (mavastsm.bridge.link.vehicle_clock, issue 28): no single frame moves it, a restart
that the stream confirms does, and two clocks under one identity are named. Host time is injected."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from mavastsm.bridge.link.vehicle_clock import CONFIRM_FRAMES, CONFIRM_SPAN_MS, RIVAL_FRAMES, VehicleClock

MS = 1_000_000  # ns per ms
PERIOD_MS = 10  # a 100 Hz ATTITUDE stream


def stream(clock: VehicleClock, t0_ms: int, rx0_ms: int, n: int, source: str = "10.0.0.1:14555") -> list[bool]:
    """n frames of a steady stream; returns what offer said of each."""
    return [clock.offer(t0_ms + i * PERIOD_MS, (rx0_ms + i * PERIOD_MS) * MS, source) for i in range(n)]


def test_a_steady_stream_is_delivered_frame_by_frame():
    c = VehicleClock()
    assert all(stream(c, 50_000, 0, 200))
    assert (c.outliers, c.new_clocks, c.conflict) == (0, 0, None)


def test_a_link_gap_is_not_a_clock_jump():
    """After 2 s of silence the vehicle's clock is 2 s on: the wall clock allows it, delivered at once."""
    c = VehicleClock()
    stream(c, 50_000, 0, 100)
    assert all(stream(c, 52_000, 2_000, 10))
    assert c.outliers == 0


def test_reordered_and_duplicate_frames_pass_to_the_session_which_counts_them():
    c = VehicleClock()
    stream(c, 50_000, 0, 10)
    assert c.offer(50_090, 100 * MS)  # the last one again
    assert c.offer(50_050, 101 * MS)  # 40 ms behind: a reordered packet
    assert c.outliers == 0


def _forged_between(offsets_ms, spacing_ms: int):
    """The genuine 100 Hz stream for 2 s with a frame at (genuine time + offset) injected every ``spacing_ms`` from
    1 s on; returns (clock, forged frames delivered, genuine frames after the first not delivered)."""
    c = VehicleClock()
    forged_at = {100 + k * spacing_ms // PERIOD_MS: off for k, off in enumerate(offsets_ms)}
    delivered_forged = genuine_refused = 0
    for i in range(200):
        t, rx = 50_000 + i * PERIOD_MS, i * PERIOD_MS
        genuine_refused += not c.offer(t, rx * MS, "10.0.0.1:14555")
        if i in forged_at:
            delivered_forged += c.offer(t + forged_at[i], rx * MS + MS // 2, "10.0.0.9:40000")
    return c, delivered_forged, genuine_refused


def test_forged_frames_two_and_ten_seconds_either_way_are_outliers_and_the_stream_goes_on():
    """The issue's injections: one frame 2 s ahead, three frames 10 s ahead or 4 s back 100 ms apart, ..."""
    for offsets in ([2_000], [-2_000], [10_000] * 3, [-4_000] * 3, [-10_000] * 3, [2_000, -2_000, 10_000]):
        c, forged, refused = _forged_between(offsets, 100)
        assert forged == 0 and refused == 0, offsets
        assert c.outliers == len(offsets), offsets
        assert c.new_clocks == 0 and c.conflict is None


def test_a_restart_is_confirmed_by_a_few_consistent_frames_once_the_old_clock_stops():
    c = VehicleClock()
    stream(c, 50_000, 0, 100)
    said = stream(c, 1_200, 1_050, 20)  # rebooted: a new clock near 0, the old one silent
    first = max(CONFIRM_FRAMES, CONFIRM_SPAN_MS // PERIOD_MS)  # frames after the first: the count and the span
    assert said[:first] == [False] * first and all(said[first:]), said
    assert c.new_clocks == 1 and c.outliers == 0 and c.last_ms == 1_200 + 19 * PERIOD_MS
    assert c.confirmed == (1_200 + first * PERIOD_MS, first * PERIOD_MS)  # the confirming frame, wall ms after the first


def test_a_burst_of_consistent_forged_frames_inside_one_period_is_not_a_restart():
    """Five consistent frames 10 s back, all within 1 ms (the genuine stream could not have spoken): held, then
    refuted by the next genuine frame."""
    c = VehicleClock()
    stream(c, 50_000, 0, 100)
    assert not any(c.offer(40_000 + k, 995 * MS + k * 200_000, "forger") for k in range(5))
    assert c.offer(51_000, 1_000 * MS) and c.new_clocks == 0 and c.outliers == 5


def test_two_interleaved_clocks_are_named_with_both_sources():
    c = VehicleClock()
    stream(c, 80_000, 0, 50, "10.0.0.1:14555")
    for i in range(2 * RIVAL_FRAMES + 60):
        rx = (500 + i * PERIOD_MS) * MS
        assert c.offer(80_500 + i * PERIOD_MS, rx, "10.0.0.1:14555")
        c.offer(3_000 + i * PERIOD_MS, rx + MS // 2, "10.0.0.2:14555")  # a second vehicle, booted later
    assert c.conflict is not None
    text = c.conflict.text(1)
    assert "10.0.0.1:14555" in text and "10.0.0.2:14555" in text and "MAV_SYSID" in text and "SYSID_THISMAV" in text and "MAV_SYS_ID" in text
    assert c.last_ms >= 80_500  # it kept following the first


def test_sparse_forged_frames_never_add_up_to_a_second_vehicle():
    """One consistent forged frame every 1.5 s (past RIVAL_GAP_MS) for a minute: outliers, never a conflict."""
    c = VehicleClock()
    for i in range(6000):
        t, rx = 50_000 + i * PERIOD_MS, i * PERIOD_MS
        assert c.offer(t, rx * MS)
        if i % 150 == 75:
            assert not c.offer(t + 10_000, rx * MS + MS // 2, "10.0.0.9:40000")
    assert c.conflict is None and c.outliers == 40


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 299), st.integers(-60_000, 60_000)), max_size=6))
def test_a_few_forged_frames_never_starve_the_session_nor_restart_it(injections):
    """Whatever few frames are injected (any time, any offset) into a 100 Hz stream, what the session gets keeps its
    promises: no delivered frame more than 3 s behind the newest delivered (a restart), and fresh samples (newer
    than any delivered) at most 400 ms apart, inside the 0.5 s stale timeout."""
    from mavastsm.bridge.link.messages import VEHICLE_RESTART_BACKSTEP_MS

    c = VehicleClock()
    at = dict(injections)
    newest, last_fresh_rx, worst_gap = None, 0, 0
    for i in range(300):
        t, rx = 50_000 + i * PERIOD_MS, i * PERIOD_MS
        frames = [(t, rx * MS)] + ([(max(0, t + at[i]), rx * MS + MS // 2)] if i in at else [])
        for ms, rx_ns in frames:
            if not c.offer(ms, rx_ns, "forger" if rx_ns % MS else "vehicle"):
                continue
            assert newest is None or newest - ms <= VEHICLE_RESTART_BACKSTEP_MS, (ms, newest)
            if newest is None or ms > newest:
                worst_gap = max(worst_gap, rx_ns // MS - last_fresh_rx)
                newest, last_fresh_rx = ms, rx_ns // MS
    assert worst_gap <= 400, worst_gap
    assert c.conflict is None
