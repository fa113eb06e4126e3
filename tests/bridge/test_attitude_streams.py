"""The link's source and clock judgement (attitude_streams), driven with injected host times: which ATTITUDE frames of
the target identity are the vehicle's, when a new clock is a restart and when two vehicles share the identity."""

from __future__ import annotations

import pytest

from mavastsm.bridge.attitude_streams import (
    CONFIRM_FRAMES,
    CONFLICT_SPAN_S,
    SOURCE_SILENT_S,
    AttitudeStreams,
    Source,
)

VEHICLE = Source("127.0.0.1:5760", None, 1, 1)
FORGER = Source("127.0.0.1:40000", None, 1, 1)
SECOND = Source("127.0.0.1:5761", None, 1, 1)
MS = 1_000_000  # ns


class Flight:
    """A vehicle streaming ATTITUDE every ``period_ms`` of its clock, received ``host_per_frame_ms`` apart."""

    def __init__(self, period_ms: float = 10.0, boot_ms: int = 60_000) -> None:
        self.streams = AttitudeStreams()
        self.period_ms = period_ms
        self.t_ms = boot_ms
        self.rx_ns = 10_000 * MS
        self.delivered: list[int] = []
        self.outliers = 0
        self.restarts: list[str] = []
        self.conflicts: list[str] = []
        self.heartbeat(VEHICLE)

    def heartbeat(self, source: Source) -> bool:
        deliver, conflict = self.streams.heartbeat(source, self.rx_ns)
        if conflict:
            self.conflicts.append(conflict)
        return deliver

    def frame(self, source: Source, t_ms: int, delay_ms: float = 0.0) -> bool:
        verdict = self.streams.judge(source, t_ms, self.rx_ns + int(delay_ms * MS))
        if verdict.conflict:
            self.conflicts.append(verdict.conflict)
        if verdict.restart:
            self.restarts.append(verdict.restart)
        if verdict.deliver:
            self.delivered.append(t_ms)
        else:
            self.outliers += 1
        return verdict.deliver

    def fly(self, n: int, host_per_frame_ms: float | None = None, source: Source = VEHICLE) -> None:
        """``n`` frames of the vehicle's own stream (a HEARTBEAT every 100 frames)."""
        for k in range(n):
            self.t_ms += int(self.period_ms)
            self.rx_ns += int((self.period_ms if host_per_frame_ms is None else host_per_frame_ms) * MS)
            if k % 100 == 0:
                self.heartbeat(source)
            self.frame(source, self.t_ms)

    def wait(self, s: float) -> None:
        self.rx_ns += int(s * 1e9)


@pytest.mark.parametrize("offset_ms", [2_000, -2_000, 10_000, -10_000])
def test_one_forged_frame_ahead_or_behind_is_an_outlier_and_the_stream_goes_on(offset_ms):
    f = Flight()
    f.fly(50)
    assert not f.frame(FORGER, f.t_ms + offset_ms)  # from the attacker's own address
    assert not f.frame(VEHICLE, f.t_ms + offset_ms)  # and with the vehicle's address spoofed
    f.fly(50)
    assert f.outliers == 2 and len(f.delivered) == 100 and not f.restarts and not f.conflicts


@pytest.mark.parametrize("offset_ms", [2_000, -4_000, 10_000])
@pytest.mark.parametrize("source", [FORGER, VEHICLE], ids=["own address", "spoofed address"])
def test_three_consistent_forged_frames_100ms_apart_are_outliers_not_a_restart(offset_ms, source):
    """The issue's table: three frames 10 s ahead (or 4 s back), 100 ms apart, while the vehicle streams at 100 Hz."""
    f = Flight()
    f.fly(50)
    for _ in range(3):
        f.frame(source, f.t_ms + offset_ms)
        f.fly(10)
    f.fly(200)
    assert f.outliers == 3 and not f.restarts and not f.conflicts
    assert f.delivered == sorted(f.delivered) and len(f.delivered) == 50 + 30 + 200


def test_a_restart_on_the_same_source_is_confirmed_by_three_frames_and_the_heartbeat():
    f = Flight(period_ms=10.0)
    f.fly(300)
    f.wait(2.0)  # the reboot: nothing for 2 s
    f.heartbeat(VEHICLE)  # the rebooted autopilot's HEARTBEAT
    f.t_ms = 150
    first_rx = f.rx_ns + int(f.period_ms * MS)
    f.fly(CONFIRM_FRAMES - 1)
    assert not f.restarts and f.outliers == CONFIRM_FRAMES - 1
    f.fly(1)
    assert len(f.restarts) == 1 and "time_boot_ms" in f.restarts[0]
    assert (f.rx_ns - first_rx) / 1e9 <= 0.5 and f.delivered[-1] == 150 + CONFIRM_FRAMES * 10
    f.fly(20)
    assert len(f.restarts) == 1 and f.delivered[-1] == 150 + (CONFIRM_FRAMES + 20) * 10


def test_a_restart_at_10_hz_is_still_confirmed_within_half_a_second():
    f = Flight(period_ms=100.0)
    f.fly(30)
    f.wait(3.0)
    f.t_ms = 400
    f.heartbeat(VEHICLE)
    start = f.rx_ns
    f.fly(CONFIRM_FRAMES)
    assert len(f.restarts) == 1 and (f.rx_ns - start) / 1e9 <= 0.5


def test_frames_of_a_new_clock_without_a_heartbeat_from_their_source_are_never_the_vehicle():
    """The vehicle stops; someone else sends a steady ATTITUDE stream with its identity but no HEARTBEAT."""
    f = Flight()
    f.fly(100)
    f.wait(0.5)
    f.t_ms = 1_000
    for _ in range(100):
        f.t_ms += 10
        f.rx_ns += 10 * MS
        f.frame(FORGER, f.t_ms)
    assert f.outliers == 100 and not f.restarts and len(f.delivered) == 100


def test_a_vehicle_back_on_a_new_address_after_its_old_one_fell_silent_is_a_restart():
    """A rebooted SITL's udpclient sends from a new port."""
    f = Flight()
    f.fly(100)
    f.wait(SOURCE_SILENT_S + 0.1)
    assert f.heartbeat(SECOND)  # the old source silent: the new one is bound
    f.t_ms = 200
    f.fly(CONFIRM_FRAMES, source=SECOND)
    assert len(f.restarts) == 1 and str(SECOND) in f.restarts[0]
    assert f.delivered[-1] == 200 + CONFIRM_FRAMES * 10
    assert not f.heartbeat(VEHICLE)  # the old address is now the other one


def test_a_vehicle_rebooted_within_half_a_second_on_a_new_address_is_not_a_second_vehicle():
    """Genuine ArduCopter SITL rebooted: its new process heartbeats from a new port within 0.5 s of the old one's
    last frame, so the old source is not yet silent for SOURCE_SILENT_S at the new one's second HEARTBEAT. The old
    one said nothing since the new one's first HEARTBEAT: it is the vehicle back, not a second one."""
    f = Flight()
    f.fly(100)
    f.wait(0.3)
    assert not f.heartbeat(SECOND)
    f.wait(1.0)
    assert f.heartbeat(SECOND)  # bound now
    f.t_ms = 1_200
    f.fly(CONFIRM_FRAMES, source=SECOND)
    assert not f.conflicts and len(f.restarts) == 1 and str(SECOND) in f.restarts[0]


def test_a_second_vehicle_on_another_address_is_named_and_never_mixed_in():
    f = Flight()
    f.fly(100)
    other_ms = 5_000
    delivered_before = len(f.delivered)
    for k in range(120):  # both at 100 Hz, interleaved, each with its own HEARTBEAT once a second
        f.t_ms += 10
        other_ms += 10
        f.rx_ns += 5 * MS
        if k % 100 == 0:
            f.heartbeat(VEHICLE)
            assert not f.heartbeat(SECOND)  # the second one's HEARTBEAT (mode, armed) never reaches the session
        f.frame(VEHICLE, f.t_ms)
        f.rx_ns += 5 * MS
        f.frame(SECOND, other_ms)
    assert len(f.delivered) - delivered_before == 120  # every frame of the vehicle, none of the other
    assert len(f.conflicts) == 1, f.conflicts
    assert str(VEHICLE) in f.conflicts[0] and str(SECOND) in f.conflicts[0] and "SYSID_THISMAV" in f.conflicts[0]
    assert not f.restarts


def test_two_interleaved_clocks_from_one_address_are_named_after_half_a_second():
    f = Flight()
    f.fly(100)
    other_ms = 500_000
    named_at_s = None
    for k in range(100):
        f.t_ms += 10
        other_ms += 10
        f.rx_ns += 5 * MS
        f.frame(VEHICLE, f.t_ms)
        f.rx_ns += 5 * MS
        f.frame(VEHICLE, other_ms)
        if f.conflicts and named_at_s is None:
            named_at_s = k * 0.01
    assert named_at_s is not None and CONFLICT_SPAN_S <= named_at_s <= CONFLICT_SPAN_S + 0.05
    assert all(t < 500_000 for t in f.delivered)


def test_a_second_heartbeating_source_alone_is_a_conflict():
    f = Flight()
    f.fly(100)
    assert not f.heartbeat(SECOND) and not f.conflicts
    f.fly(100)
    assert not f.heartbeat(SECOND)
    assert len(f.conflicts) == 1


@pytest.mark.parametrize("host_per_frame_ms", [0.3, 2.5, 5.0], ids=["lockstep faster", "real time", "lockstep slower"])
def test_a_vehicle_clock_faster_or_slower_than_the_host_is_followed(host_per_frame_ms):
    f = Flight(period_ms=2.5)
    f.fly(4000, host_per_frame_ms=host_per_frame_ms)
    assert f.outliers == 0 and not f.restarts


def test_network_delay_spikes_do_not_make_on_time_frames_outliers():
    """A frame 300 ms late followed by on-time ones: the anchor is the least-delayed frame, not the last."""
    f = Flight()
    f.fly(100)
    f.t_ms += 10
    f.rx_ns += 310 * MS
    f.frame(VEHICLE, f.t_ms)  # arrived 300 ms late (the ones before it were lost)
    for _ in range(50):  # then on time again: 10 ms apart on both clocks, but 300 ms "ahead" of the late one
        f.t_ms += 10
        f.rx_ns += 4 * MS
        f.frame(VEHICLE, f.t_ms)
    f.fly(100)
    assert f.outliers == 0 and not f.restarts
