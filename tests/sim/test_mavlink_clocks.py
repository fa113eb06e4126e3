"""Clock logic with an injected wall clock: real-time pacing, speed-up, re-basing, lockstep gate."""

from __future__ import annotations

import pytest

from mavastsm.errors import ConfigError
from mavastsm_sim.sim_clock import ClockSpec, LockstepGate, RealTimePacer


class FakeWall:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_pacer_maps_simulated_time_to_wall_deadlines_with_speedup():
    wall = FakeWall()
    pacer = RealTimePacer(speedup=4.0, wall_clock=wall)
    pacer.rebase(0.0)
    assert pacer.seconds_until(2.0) == pytest.approx(0.5)
    wall.t += 0.5
    assert pacer.seconds_until(2.0) == 0.0
    assert pacer.sim_time_now_s() == pytest.approx(2.0)


def test_pacer_rebases_instead_of_bursting_when_far_behind():
    wall = FakeWall()
    pacer = RealTimePacer(speedup=1.0, wall_clock=wall, max_lag_s=0.25)
    pacer.rebase(0.0)
    wall.t += 0.2  # 0.2 s late for t=0: still catching up
    assert pacer.seconds_until(0.0) == 0.0 and pacer.overruns == 0
    wall.t += 1.0
    assert pacer.seconds_until(0.001) == 0.0 and pacer.overruns == 1
    assert pacer.seconds_until(0.011) == pytest.approx(0.010)  # schedule restarts from now


def test_pacer_reports_how_late_the_plant_is_for_the_late_attitude_count():
    wall = FakeWall()
    pacer = RealTimePacer(speedup=1.0, wall_clock=wall)
    pacer.rebase(0.0)
    assert pacer.seconds_until(0.0025) == pytest.approx(0.0025) and pacer.last_lag_s == 0.0
    wall.t += 0.0045  # the sim process was descheduled: 2 ms behind the 2.5 ms step
    assert pacer.seconds_until(0.0025) == 0.0 and pacer.last_lag_s == pytest.approx(0.002)


def test_lockstep_gate_opens_on_answer_or_timeout():
    wall = FakeWall()
    gate = LockstepGate(timeout_s=0.1, wall_clock=wall)
    gate.close(answers_so_far=5)
    assert gate.is_closed and gate.poll(5) == pytest.approx(0.1)
    assert gate.poll(6) == 0.0 and not gate.is_closed and gate.answered == 1
    gate.close(6)
    wall.t += 0.05
    assert gate.poll(6) == pytest.approx(0.05)
    wall.t += 0.06
    assert gate.poll(6) == 0.0 and gate.timeouts == 1 and not gate.is_closed


@pytest.mark.parametrize("kwargs", [dict(mode="fast"), dict(speedup=0.0), dict(speedup=float("nan")),
                                    dict(lockstep_timeout_s=-1.0)])
def test_bad_clock_settings_are_config_errors(kwargs):
    with pytest.raises(ConfigError):
        ClockSpec(**kwargs)
