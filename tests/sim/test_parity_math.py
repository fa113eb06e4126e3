"""The pure parts of benchmarks/sim_parity.py and benchmarks/paper_on_genuine.py: limit-cycle verdict, trace
difference, and the two clock-offset estimates that put a scenario's torque at the bridge's engagement."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


def _load(name: str):
    sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location(f"{name}_for_tests", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def _trace(fn, t_end=5.0, rate=320.0):
    return [(t, (fn(t), 0.0, 0.0)) for t in np.arange(0.0, t_end, 1.0 / rate)]


def test_limit_cycle_needs_a_sustained_fast_swing():
    sp = _load("sim_parity")
    nine_hz = sp.limit_cycle(_trace(lambda t: math.radians(0.35) * math.sin(2 * math.pi * 9.0 * t)), 0)
    assert nine_hz["cycle"] and abs(nine_hz["hz"] - 9.0) < 0.5 and abs(nine_hz["pp_deg"] - 0.7) < 0.02
    assert not sp.limit_cycle(_trace(lambda t: math.radians(0.1) * math.sin(2 * math.pi * 9.0 * t)), 0)["cycle"]  # too small
    assert not sp.limit_cycle(_trace(lambda t: math.radians(2.0) * math.sin(2 * math.pi * 0.5 * t)), 0)["cycle"]  # too slow
    assert not sp.limit_cycle(_trace(lambda t: math.radians(3.0) * t), 0)["cycle"]  # a drift is not a cycle


def test_trace_difference_is_the_rms_over_the_common_span():
    sp = _load("sim_parity")
    a = _trace(lambda t: math.radians(1.0), rate=320.0)
    b = _trace(lambda t: 0.0, t_end=4.0, rate=333.0)
    assert abs(sp.trace_rms_difference_deg(a, b, 0) - 1.0) < 1e-9
    assert sp.trace_rms_difference_deg(a, a, 0) == 0.0


def test_clock_offsets_from_reception_and_from_the_attitude():
    pg = _load("paper_on_genuine")
    assert pg.clock_offset_s([(1.0, 1.013), (1.02, 1.031), (1.04, 1.055)]) == 1.031 - 1.02
    from mavastsm_sim.attitude_math import q_from_euler

    true_offset = 0.0237
    step = lambda t: math.radians(-10.0) * min(max((t - 30.5) / 0.2, 0.0), 1.0)  # noqa: E731
    physics = [(t, q_from_euler(step(t), 0.5 * step(t), 0.0)) for t in np.arange(29.0, 33.0, 1.0 / 1200.0)]
    vehicle = [(t, step(t + true_offset), 0.5 * step(t + true_offset)) for t in np.arange(30.0, 31.4, 1.0 / 333.0)]
    c = pg.attitude_clock_offset_s(vehicle, physics, prior_s=0.01)
    assert abs(c - true_offset) <= 0.0005


def test_held_disturbances_wait_for_the_caller_and_the_history_keeps_the_attitude():
    from mavastsm_sim.disturbances import PARKED_S
    from mavastsm_sim.json_physics import JsonPhysics

    p = JsonPhysics(scenario="disturbance_roll", disturbance_start="held", attitude_history_s=1.0)
    for _ in range(400):  # 1 s at full thrust: off the ground
        p.step([0.9] * 4, 400)
    assert not p.plant.in_ground_contact
    assert p.plant.disturbances.origin_s == PARKED_S and p.plant.disturbances.torque_nm(p.time_s) == (0.0, 0.0, 0.0)
    assert len(p.attitude_history) == 400 and p.attitude_history[-1][0] == p.time_s
    p.plant.disturbances.restart_clock(p.time_s - 4.0)  # the benchmarks' start at engagement
    assert p.plant.disturbances.torque_nm(p.time_s) == (0.5, 0.0, 0.0)


def test_trace_difference_of_one_attitude_sampled_at_other_times_across_a_step_is_zero():
    """The same flight logged at 320 and 333 Hz, its error taken against a reference with a 45 deg step at 2 s: the
    attitudes are identical, so the RMS is zero. Interpolating the *errors* across the step (what the comparison did
    before 2026-12-02) reads a spurious difference for the one sample that falls between the two straddling it."""
    sp = _load("sim_parity")
    from mavastsm.references import load_reference

    ref = load_reference("paper_steps")
    attitude = lambda t: math.radians(45.0) * (1.0 - math.exp(-max(t - 2.0, 0.0) / 0.3))  # noqa: E731
    err = lambda t: (0.0, 0.0, attitude(t) - float(ref.at(t)[0][2]))  # noqa: E731
    a = [(t, err(t)) for t in np.arange(0.0, 5.0, 1.0 / 320.0)]
    b = [(t, err(t)) for t in np.arange(0.0005, 4.9, 1.0 / 333.0)]
    assert sp.trace_rms_difference_deg(a, b, 2, ref) < 1e-3  # linear interpolation of a smooth curve only
    assert sp.trace_rms_difference_deg(a, b, 2) > 0.2  # the artefact the reference argument removes


def test_altitude_held_is_the_deviation_from_the_profile_start():
    pg = _load("paper_on_genuine")
    held = pg.altitude_held([(0.0, float("nan")), (0.1, 4.5), (0.2, 4.46), (0.3, 4.58), (0.4, 4.52)])
    assert held == {"start_m": 4.5, "min_dev_m": -0.04, "max_dev_m": 0.08, "end_dev_m": 0.02}
    assert all(math.isnan(v) for v in pg.altitude_held([(0.0, float("nan"))]).values())
    table = pg.altitude_table([{"scenario": "variation", "controller": "astsm", "altitude": held}, {"scenario": "variation", "controller": "x"}])
    assert table.splitlines()[-1] == "| variation | astsm | 4.50 | -0.04 / 0.08 / 0.02 |"


class _Landing:
    """A vehicle after LAND for ``wait_landed_on_solo_physics``: on the ground (physics) from the start; it disarms
    by itself after ``detector_s`` (None: never) or when a force-disarm COMMAND_LONG reaches it."""

    def __init__(self, detector_s):
        import time as _time
        from types import SimpleNamespace

        self.t0, self.detector_s, self.commands = _time.monotonic(), detector_s, []
        self.sitl = SimpleNamespace(companions=[SimpleNamespace(physics=SimpleNamespace(plant=SimpleNamespace(in_ground_contact=True)))])
        self.observer = SimpleNamespace(mode_now=self._mode, last_seen=lambda n=15: "observer: LAND")
        self.mav = SimpleNamespace(command_long_send=lambda *a: self.commands.append(a))

    def _mode(self):
        import time as _time

        by_itself = self.detector_s is not None and _time.monotonic() - self.t0 >= self.detector_s
        forced = any(a[2] == 400 and a[5] == 21196.0 for a in self.commands)
        return ("LAND", not (by_itself or forced))


def test_a_landing_that_arducopter_never_detects_is_disarmed_by_force_and_said():
    pg = _load("paper_on_genuine")
    normal = _Landing(detector_s=0.1)
    assert pg.wait_landed_on_solo_physics(normal, normal, (1, 1), timeout_s=3.0, ground_disarm_s=0.5) == "disarmed by ArduCopter's land detector"
    assert normal.commands == []
    stuck = _Landing(detector_s=None)
    said = pg.wait_landed_on_solo_physics(stuck, stuck, (1, 1), timeout_s=3.0, ground_disarm_s=0.3)
    assert said.startswith("ArduCopter's land detector did not fire in 0.3 s at rest on the ground: disarmed by force"), said
    assert [(a[0], a[1], a[2], a[4], a[5]) for a in stuck.commands] == [(1, 1, 400, 0.0, 21196.0)]


class _FakeDisturbances:
    """The two calls the aligner makes on a DisturbanceModel, recorded with the fake physics time."""

    def __init__(self, now):
        self.now, self.started_at, self.parked_at = now, None, []

    def restart_clock(self, t_s):
        self.started_at = t_s

    def park(self):
        self.parked_at.append(self.now())


def test_the_torque_stays_on_past_the_end_of_the_bridges_record(tmp_path):
    """The aligner starts the torque clock at the first engaged row of the bridge's CSV and switches the torque off
    only TORQUE_PAST_END_S after the profile's end (physics clock), so an offset error of tens of milliseconds never
    takes it away inside the record (CI 2026-12-04: a -2.5 deg swing in the last second of the within-authority
    flight)."""
    import inspect
    import time

    pg = _load("paper_on_genuine")
    search_s = inspect.signature(pg.attitude_clock_offset_s).parameters["search_s"].default
    assert pg.TORQUE_PAST_END_S > search_s + 0.02  # beyond any offset the attitude fit can return, plus one poll
    now = [100.0]
    dist = _FakeDisturbances(lambda: now[0])
    clock = pg.PlantClock(lambda: now[0], dist, offset_s=0.25)
    (tmp_path / "flight.csv").write_text("vehicle_time_s,roll_rad,pitch_rad,u_roll_nm,phase\n"
                                         "99.75,0,0,nan,takeoff\n99.9,0,0,0.01,engaged\n")
    duration = 2.0
    aligner = pg.DisturbanceAligner(clock, tmp_path, duration).start()
    try:
        deadline = time.monotonic() + 5.0
        while aligner.start_physics_s is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert aligner.start_physics_s == 99.9 + 0.25 == dist.started_at
        aligner.refined = True  # no attitude history: the offset stays as measured
        parked_at_start = len(dist.parked_at)  # start() parks the clock before the engagement
        for t in np.arange(100.2, aligner.start_physics_s + duration + pg.TORQUE_PAST_END_S - 0.01, 0.05):
            now[0] = float(t)
            time.sleep(0.03)  # the watcher polls every 20 ms
            assert len(dist.parked_at) == parked_at_start, (t, dist.parked_at)  # still on, at the profile's end too
        now[0] = aligner.start_physics_s + duration + pg.TORQUE_PAST_END_S + 0.01
        deadline = time.monotonic() + 5.0
        while len(dist.parked_at) == parked_at_start and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(dist.parked_at) == parked_at_start + 1
        assert aligner.record()["torque_off_after_profile_end_s"] >= pg.TORQUE_PAST_END_S
    finally:
        aligner.stop()
