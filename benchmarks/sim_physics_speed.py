"""Speed of the simulated Solo without MAVLink: microseconds per 1 kHz physics step and the real-time
factor of ``SimulatedCopter.step`` alone (hover and an aggressive rate manoeuvre), plus a breakdown.

Usage: ``python benchmarks/sim_physics_speed.py [--seconds 20] [--physics-rate-hz 1000] [--loop-rate-hz 400]``

Reports CPU time of this process (``time.process_time``) and wall time; on a shared machine the wall
numbers are noisy, the CPU numbers less so. This is a benchmark that prints numbers, not a test.
"""

from __future__ import annotations

import argparse
import json
import math
import time

from mavastsm_sim.copter import SimulatedCopter
from mavastsm_sim.rigid_body_dynamics import make_rk4_stepper


def _timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w0, time.process_time() - c0


def run(seconds: float, physics_rate_hz: float, loop_rate_hz: float, command_rate_hz: float = 400.0) -> dict:
    copter = SimulatedCopter(physics_rate_hz=physics_rate_hz)
    copter.params.set("SCHED_LOOP_RATE", loop_rate_hz)
    copter.set_mode(20)
    copter.arm()
    dt = 1.0 / command_rate_hz

    def fly(duration, rates_fn, thrust):
        n = int(round(duration / dt))
        for k in range(n):
            copter.handle_attitude_target(0x80, (1.0, 0.0, 0.0, 0.0), rates_fn(k * dt), thrust)
            copter.step(dt)

    fly(3.0, lambda t: (0.0, 0.0, 0.0), 0.75)  # take off (not timed)
    results = {}
    cases = {
        "hover": lambda t: (0.0, 0.0, 0.0),
        "manoeuvre": lambda t: (1.0 * math.sin(2.0 * t), 0.8 * math.cos(1.5 * t), 0.5),
    }
    steps = seconds * physics_rate_hz
    for name, rates_fn in cases.items():
        wall, cpu = _timed(lambda: fly(seconds, rates_fn, 0.5))
        results[name] = {
            "wall_us_per_step": round(wall / steps * 1e6, 2),
            "cpu_us_per_step": round(cpu / steps * 1e6, 2),
            "real_time_factor_wall": round(seconds / wall, 1),
            "real_time_factor_cpu": round(seconds / cpu, 1),
        }
    # breakdown: the rigid-body RK4 alone
    rk4 = make_rk4_stepper(copter.body)
    x = list(copter._x)
    u = (0.0, 0.0, -14.7, 0.01, -0.02, 0.003, 0.01, 0.0, 0.0, 0.0)
    n = 20000
    wall, cpu = _timed(lambda: [rk4(x, u, 1e-3) for _ in range(n)])
    results["rk4_only_cpu_us"] = round(cpu / n * 1e6, 2)
    results["config"] = {"physics_rate_hz": physics_rate_hz, "SCHED_LOOP_RATE": loop_rate_hz,
                         "command_rate_hz": command_rate_hz, "simulated_s_per_case": seconds}
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="benchmarks/sim_physics_speed.py", description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per case [s]")
    parser.add_argument("--physics-rate-hz", type=float, default=1000.0, help="physics rate [Hz]")
    parser.add_argument("--loop-rate-hz", type=float, default=400.0, help="emulated SCHED_LOOP_RATE [Hz]")
    parser.add_argument("--command-rate-hz", type=float, default=400.0, help="SET_ATTITUDE_TARGET calls per second")
    a = parser.parse_args()
    print(json.dumps(run(a.seconds, a.physics_rate_hz, a.loop_rate_hz, a.command_rate_hz), indent=2))
