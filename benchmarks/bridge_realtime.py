"""Benchmark: the bridge in real time (no lockstep) against the simulated Solo in a separate process.

    python benchmarks/bridge_realtime.py [--seconds 60] [--rate 400] [--sched-loop-rate-hz 500]
        [--realtime-priority N] [--sim-sched normal|batch|fifo] [--pin-cpus]

Starts ``mavastsm sim`` (real-time clock) on an ephemeral loopback port in its own process, runs
``Bridge`` in this process (GUIDED_NOGPS, arm, 2 m takeoff, then the roll sine reference held for
``--seconds`` on the vehicle clock), and prints cycles, missed cycles (gaps in time_boot_ms longer
than 1.5 achieved periods), dropped/superseded samples and the ATTITUDE-received ->
SET_ATTITUDE_TARGET-sent latency p50/p99/max measured by the bridge (host monotonic clock).
A benchmark prints numbers; it asserts nothing. The machine is shared, so numbers are noisy.
ArduCopter caps message rates at 80 % of SCHED_LOOP_RATE; the sim does too, so a 400 Hz request
on the default 400 Hz loop achieves 320 Hz; ``--sched-loop-rate-hz 500`` lets 400 Hz through.

Scheduling: ``--realtime-priority N`` runs the bridge's control thread SCHED_FIFO (as
``mavastsm connect --realtime-priority N``); ``--sim-sched fifo`` runs the sim SCHED_FIFO one priority
above it, as a flight controller on its own processor would never be held up by the companion computer.
Both need CAP_SYS_NICE or ``ulimit -r``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.runtime_tuning import run_tuned
from mavastsm.config_loading import parse_overrides


def _sim_scheduling(policy: str, bridge_priority: int):
    """preexec_fn for the sim's process: its Linux scheduling policy (None = inherit ours)."""
    if policy == "batch":
        return lambda: os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    if policy == "fifo":
        return lambda: os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(2, bridge_priority + 1)))
    return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="engaged time on the vehicle clock [s]")
    ap.add_argument("--rate", type=float, default=400.0, help="ATTITUDE rate requested [Hz]")
    ap.add_argument("--sched-loop-rate-hz", type=float, default=500.0, help="sim's SCHED_LOOP_RATE [Hz]")
    ap.add_argument("--reference", default="roll_sine")
    ap.add_argument("--json", default=None, help="also write the numbers here")
    ap.add_argument("--pin-cpus", action="store_true", help="run the bridge on CPU 0 and the sim on CPU 1 (Linux, taskset)")
    ap.add_argument("--sim-sched", choices=("normal", "batch", "fifo"), default="normal",
                    help="the sim's Linux scheduling policy: batch (SCHED_BATCH) stops its wake-ups from preempting the bridge "
                         "mid-cycle, as a flight controller on its own processor would not; fifo (SCHED_FIFO, priority "
                         "--realtime-priority + 1, at least 2) keeps the plant's own clock on time")
    ap.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                    help="the bridge's control thread SCHED_FIFO at N (1-99); 0 = normal scheduling")
    ap.add_argument("--log", default=None, metavar="DIR", help="write the bridge's CSV and .tlog here (as `mavastsm connect --log`)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="bridge.yaml override, e.g. timing.gil_switch_interval_s=0")
    args = ap.parse_args()

    pin = ["taskset", "-c", "1"] if args.pin_cpus else []
    if args.pin_cpus:
        os.sched_setaffinity(0, {0})  # the bridge on CPU 0, the sim on CPU 1
    sim = subprocess.Popen(
        pin + [sys.executable, "-m", "mavastsm.cli", "sim", "--listen", "127.0.0.1:0", "--set", f"sched_loop_rate_hz={args.sched_loop_rate_hz}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        preexec_fn=_sim_scheduling(args.sim_sched, args.realtime_priority),
    )
    try:
        port = None
        deadline = time.monotonic() + 20.0
        while port is None and time.monotonic() < deadline:
            line = sim.stdout.readline()
            m = re.search(r"127\.0\.0\.1:(\d+)", line or "")
            if m and int(m.group(1)) != 0:
                port = int(m.group(1))
        if port is None:
            print("sim did not report its port", file=sys.stderr)
            return 2
        opts = BridgeOptions(f"udpout:127.0.0.1:{port}", reference=args.reference, rate_hz=args.rate, duration_s=args.seconds,
                             mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=2.0, on_exit="LAND", print_fn=print, log_dir=args.log,
                             overrides={**parse_overrides(args.set), "timing.realtime_priority": args.realtime_priority})
        t0 = time.monotonic()
        s = run_tuned(Bridge(opts))  # as `mavastsm connect` runs it
        wall = time.monotonic() - t0
    finally:
        os.killpg(sim.pid, signal.SIGTERM)
        try:
            sim_out = sim.communicate(timeout=5)[0] or ""
        except subprocess.TimeoutExpired:
            os.killpg(sim.pid, signal.SIGKILL)
            sim_out = sim.communicate()[0] or ""
    late = re.search(r"(\d+) ATTITUDE sent > 1 ms late, (\d+) re-bases", sim_out)
    numbers = {
        "engaged_s": args.seconds, "wall_s": round(wall, 1), "rate_requested_hz": args.rate,
        "rate_achieved_hz": round(s.attitude_rate_achieved_hz, 1), "cycles": s.cycles, "missed": s.missed,
        "dropped": s.dropped, "superseded": s.superseded, "duplicate": s.duplicate, "overruns": s.overruns, "late": s.late,
        "latency_p50_us": round(s.latency_p50_s * 1e6, 1), "latency_p99_us": round(s.latency_p99_s * 1e6, 1),
        "latency_max_us": round(s.latency_max_s * 1e6, 1),
        # the sim's side of "missed": ATTITUDEs it sent late and then close to the next one (a burst the bridge
        # rightly answers with the newest sample only), counted over the whole run (takeoff included)
        "sim_late_attitudes": int(late.group(1)) if late else None, "sim_rebases": int(late.group(2)) if late else None,
        "end": s.end_reason, "failsafe": s.failsafe.name if s.failsafe else None,
        "realtime_priority": args.realtime_priority, "sim_sched": args.sim_sched, "pin_cpus": args.pin_cpus,
        "load_1m_at_end": os.getloadavg()[0],
    }
    print(s.format())
    print(json.dumps(numbers))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(numbers, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
