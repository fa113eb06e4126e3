"""Benchmark: how much does drawing the dashboard delay a 400 Hz loop in the same process?

    python tests/dashboard/bench_render_isolation.py [--seconds 6] [--repeats 2]

A sender process emits one UDP datagram every 2.5 ms carrying its ``time.perf_counter()`` (a
system-wide monotonic clock on Linux). The receiving loop (a thread standing in for the bridge's
reader + control step) takes each datagram, does a little numpy work, and records
arrival-to-done latency measured from the sender's stamp, so a wait for the interpreter lock
*before* the loop wakes up is included (the bridge's own ``latency_s`` starts after wake-up).
A full 120x40 dashboard of a 4000-sample buffer is drawn at 10 Hz under each condition:

* ``off``: no dashboard;
* ``thread``: drawn by a thread in the loop's process (switch interval left at 5 ms);
* ``thread+si``: the same with the switch interval lowered to 0.5 ms (the runner's thread mode);
* ``process``: drawn by the child process (the default), this process only forwards samples.

Conditions run interleaved ``--repeats`` times. Prints p50/p99/max latency per condition. A
benchmark, not a test: numbers on a shared machine are noisy; compare within one run.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import make_buffer  # noqa: E402  (the tests' hand-made telemetry)

from mavastsm.bridge.bridge_config import load_bridge_config  # noqa: E402
from mavastsm.dashboard.live_view import DashboardRunner  # noqa: E402
from mavastsm.runtime_tuning import ProcessTuning  # noqa: E402

SENDER = """
import socket, sys, time
port, n = int(sys.argv[1]), int(sys.argv[2])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
t0 = time.perf_counter()
for k in range(1, n + 1):
    d = t0 + k / 400.0 - time.perf_counter()
    if d > 0:
        time.sleep(d)
    s.sendto(repr(time.perf_counter()).encode(), ("127.0.0.1", port))
"""


def run_condition(condition: str, seconds: float) -> np.ndarray:
    """Latencies [s] of one condition (first 0.5 s dropped as warm-up)."""
    n = int(seconds * 400)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    runner = tuning = None
    sink = open(os.devnull, "w")
    sink_b = open(os.devnull, "wb")
    try:
        if condition.startswith("thread"):
            console = Console(file=sink, force_terminal=True, width=120, height=40)
            runner = DashboardRunner(make_buffer(n=4000), plain=False, keys=False, console=console, isolation="thread")
            if condition == "thread+si":  # the switch interval as the command line sets it (mavastsm.runtime_tuning)
                tuning = ProcessTuning(load_bridge_config().timing).apply()
        elif condition == "process":
            runner = DashboardRunner(make_buffer(n=4000), plain=False, keys=False, isolation="process",
                                     process_output=sink_b, process_size=(120, 40))
        if runner is not None:
            runner.start()
        sender = subprocess.Popen([sys.executable, "-c", SENDER, str(rx.getsockname()[1]), str(n)])
        lat = []
        try:
            import time

            for _ in range(n):
                data = rx.recv(64)
                np.sin(np.arange(30.0)).sum()  # a little control work
                lat.append(time.perf_counter() - float(data))
        finally:
            sender.wait()
        return np.array(lat[200:])
    finally:
        if runner is not None:
            runner.stop()
        if tuning is not None:
            tuning.restore()
        rx.close()
        sink.close()
        sink_b.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    conditions = ["off", "thread", "thread+si", "process"]
    results: dict[str, list[np.ndarray]] = {c: [] for c in conditions}
    for _ in range(args.repeats):
        for c in conditions:
            results[c].append(run_condition(c, args.seconds))
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; latency sender stamp -> loop done [ms]")
    print(f"{'condition':10} {'p50':>7} {'p99':>7} {'max':>7}")
    for c in conditions:
        lat = np.concatenate(results[c]) * 1e3
        print(f"{c:10} {np.percentile(lat, 50):7.3f} {np.percentile(lat, 99):7.3f} {lat.max():7.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
