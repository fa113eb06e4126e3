"""CPU time per call of the live bridge's per-sample control path (batch_shape = ()).

Measures ``tracking_error`` and every registered controller's ``update`` (and ``diagnostics()``) with
``time.process_time`` over many calls, which counts this process's CPU time only and so is fairly robust
to other load on the machine (it is still affected by cache and frequency effects: treat as +-20 %).

Run: ``python benchmarks/controller_cpu_per_call.py [--calls N]``. Prints a table in microseconds.

``--period-ms P [P ...]`` instead times ``tracking_error`` + ASTSM's ``update`` one call at a time with a sleep of P ms
before each (as the bridge's reader thread sleeps between ATTITUDE samples; 0 = back to back), the median of each
call's own CPU time (``time.thread_time_ns``): why the bridge's CPU per cycle rises as the rate falls
(docs/benchmarks.md, "Why a cycle costs more at lower rates").
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mavastsm.control import CONTROLLERS, make_controller, tracking_error
from mavastsm.solo_model import load_solo


def cpu_us_per_call(fn, calls: int, repeats: int = 5) -> float:
    """Best of ``repeats`` runs of ``calls`` calls: CPU microseconds per call."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        for _ in range(calls):
            fn()
        best = min(best, (time.process_time() - t0) / calls)
    return best * 1e6


def median_cpu_us_after_sleep(fn, calls: int, period_s: float) -> float:
    """Median CPU microseconds of one call of ``fn`` made after sleeping ``period_s`` [s] (0: back to back)."""
    spent = []
    for _ in range(calls):
        if period_s > 0:
            time.sleep(period_s)
        t0 = time.thread_time_ns()
        fn()
        spent.append(time.thread_time_ns() - t0)
    return float(np.median(spent)) / 1e3


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20_000, help="calls per timed run (best of 5 runs)")
    parser.add_argument("--period-ms", type=float, nargs="+", default=None,
                        help="time tracking_error + astsm.update one call at a time after a sleep of each of these [ms]")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1)
    # inputs as the bridge has them: tuples of floats from the ATTITUDE message and the reference table
    euler = tuple(rng.uniform(-0.3, 0.3, 3).tolist())
    rates = tuple(rng.uniform(-1, 1, 3).tolist())
    ref, ref_rate, ref_acc = (tuple(rng.uniform(-0.3, 0.3, 3).tolist()) for _ in range(3))
    err = tracking_error(euler, rates, ref, ref_rate, ref_acc)
    if args.period_ms:
        ctrl = make_controller("astsm", load_solo())
        calls = min(args.calls, 1000)

        def cycle():
            ctrl.update(tracking_error(euler, rates, ref, ref_rate, ref_acc), 2.5e-3)

        print(f"{'sleep before each call':24s} {'median CPU us of tracking_error + astsm.update':>48s}")
        for period_ms in args.period_ms:
            print(f"{period_ms:21.1f} ms {median_cpu_us_after_sleep(cycle, calls, period_ms / 1e3):48.2f}")
        return 0
    te = cpu_us_per_call(lambda: tracking_error(euler, rates, ref, ref_rate, ref_acc), args.calls)
    print(f"{'call':32s} {'CPU us/call':>12s}")
    print(f"{'tracking_error':32s} {te:12.2f}")
    solo = load_solo()
    for name in CONTROLLERS:
        ctrl = make_controller(name, solo)
        up = cpu_us_per_call(lambda: ctrl.update(err, 2.5e-3), args.calls)
        dg = cpu_us_per_call(lambda: ctrl.diagnostics(), args.calls)
        print(f"{name + '.update':32s} {up:12.2f}")
        print(f"{name + '.diagnostics':32s} {dg:12.2f}")
        if name == "astsm":
            print(f"{'tracking_error + astsm.update':32s} {te + up:12.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
