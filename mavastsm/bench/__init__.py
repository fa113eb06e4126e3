"""``mavastsm bench``: bridge latency, sustained rate, CPU, sim speed, offline speed, and the baselines.

Everything is measured from outside where it can be:

- **Cycle latency** (ATTITUDE on the wire -> SET_ATTITUDE_TARGET back on the wire) is timed by
  ``StubVehicle`` (``bench_stub_vehicle``) in this process, while each client runs in its own
  process (``python -m mavastsm.bench.clients KIND``): our bridge, a naive pymavlink loop and
  MAVSDK (asyncio stream and native callback), on the same stub, at 100/400/1000 Hz.
  Pairing rules and the definition of a missed cycle: ``bench_latency``.
- **CPU per cycle**: utime+stime of the client process (``/proc/PID/stat``, all its threads, 10 ms
  tick resolution) over the measurement window, divided by the ATTITUDE samples in the window.
- **Sustained rate**: the highest ATTITUDE rate in a descending ladder (1000 Hz down) that the bridge
  answered for the whole window with no missed cycle, dashboard off and on (on = the rich dashboard
  rendered at 10 Hz to /dev/null in the bridge process). 1 kHz is the ceiling: ``time_boot_ms`` has
  1 ms resolution, so a faster ATTITUDE stream would carry duplicate timestamps.
- **Sim real-time factor**: simulated seconds / wall seconds with the sim in lockstep with the bridge
  (400 Hz control, 1 kHz physics): sim thread + bridge in one process (as ``mavastsm demo``), sim and
  bridge as two processes, and the sim alone against a minimal answering peer (helper B2's
  ``benchmarks/sim_realtime_factor.py``, source checkouts only).
- **Offline**: ``mavastsm reproduce`` wall time and the offline simulator's throughput.

Numbers from a loaded shared machine are noisy: the JSON records the load average before and after.
Performance targets (issue 30's: ratios to the naive pymavlink loop, no late cycle, sim and sweep speed) are
reported as met/missed with the measured number, never asserted. The bridge logs (``--log``) as the README's
commands have it.

Here: the command and the run of every measurement. ``measure.py`` measures, ``report.py`` compares and renders,
``clients.py`` / ``stub_vehicle.py`` / ``latency.py`` are the two sides of the wire and the pairing; the names the
benchmarks and tests use (``mavastsm.bench.measure_client``, ``CLIENT_LABELS``, ...) are re-exported below.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import time
from pathlib import Path
from typing import Callable

from .measure import (CLIENT_LABELS, CLIENT_RULES, SIM_RTF_SCRIPT, SOURCE_BENCHMARKS_DIR, BenchConfig,  # noqa: F401
                      library_versions, machine_description, measure_client, measure_offline, measure_sim_lockstep,
                      measure_sustained_rate, measure_sweep, sustained_from_rows)
from .report import compare, evaluate_targets, render_markdown, render_tables  # noqa: F401


def run_all_measurements(cfg: BenchConfig, progress: Callable[[str], None] = lambda s: None) -> dict:
    """Run every measurement in ``cfg`` and return the JSON-ready report (see module docstring)."""
    t0 = time.monotonic()
    report: dict = {
        "meta": {"date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                 "quick": cfg.quick, "machine": machine_description(), "versions": library_versions(),
                 "notes": list(cfg.extra_notes) + [
                     "latency = ATTITUDE sent by the stub -> SET_ATTITUDE_TARGET received by it (kernel receive "
                     "timestamps); each client runs in its own process",
                     "mavsdk 4.x from PyPI is the native MAVSDK binding (ctypes, in-process): no mavsdk_server/gRPC",
                     "the bridge is paired by arrival order (it writes its own clock into time_boot_ms): exact "
                     "below one period; the latency of a late (missed) answer is under-reported, the count is exact",
                 ]},
    }
    rows = []
    for rate in cfg.rates_hz:
        for kind in cfg.clients:
            if kind != "bridge" and cfg.baseline_rates_hz is not None and rate not in cfg.baseline_rates_hz:
                continue
            progress(f"latency: {CLIENT_LABELS[kind]} at {rate:.0f} Hz")
            rows.append(measure_client(kind, rate, cfg.window_s, cfg.warmup_s,
                                       start_timeout_s=cfg.client_start_timeout_s))
    report["latency"] = rows
    report["comparison"] = compare(rows)
    report["cpu_per_cycle_us"] = {f"{r['client']}@{r['rate_hz']:.0f}Hz": r["cpu_per_cycle_us"] for r in rows}
    phase_t = time.monotonic()
    phases = {"latency": round(phase_t - t0, 1)}
    if cfg.sustained_off_from_latency and "bridge" in cfg.clients:
        off = sustained_from_rows(rows)
    else:
        off = measure_sustained_rate(cfg.sustained_ladder_hz, cfg.sustained_window_s, False, progress)
    # the dashboard only adds work: rungs above the best dashboard-off rate cannot pass, so start there
    best_off = off["highest_rate_hz_without_miss"]
    on_ladder = tuple(r for r in cfg.sustained_ladder_hz if best_off is None or r <= best_off)
    if best_off is None:
        on_ladder = (min(cfg.sustained_ladder_hz),)
    report["sustained_rate"] = {
        "dashboard_off": off,
        "dashboard_on": measure_sustained_rate(on_ladder, cfg.sustained_window_s, True, progress),
    }
    phases["sustained_rate"] = round(time.monotonic() - phase_t, 1)
    phase_t = time.monotonic()
    progress(f"sim lockstep with the bridge: {cfg.sim_seconds:.0f} simulated s")
    report["sim_lockstep"] = measure_sim_lockstep(cfg.sim_seconds)
    phases["sim_lockstep"] = round(time.monotonic() - phase_t, 1)
    phase_t = time.monotonic()
    progress("offline: reproduce wall time and simulator throughput")
    report["offline"] = measure_offline(cfg)
    phases["offline"] = round(time.monotonic() - phase_t, 1)
    phase_t = time.monotonic()
    progress("sweep: offline simulated s per wall s, MAVLink-level runs per minute")
    report["sweep"] = measure_sweep(cfg)
    phases["sweep"] = round(time.monotonic() - phase_t, 1)
    report["meta"]["phase_wall_s"] = phases
    report["targets"] = evaluate_targets(report)
    report["meta"]["machine"]["load_average_1m_end"] = round(os.getloadavg()[0], 2)
    report["meta"]["bench_wall_s"] = round(time.monotonic() - t0, 1)
    return report


# ---------------------------------------------------------------------------------------------
# Presentation


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="short windows (2 s latency, 3 s sustained-rate with the dashboard, 3 sim s), baselines "
                             "at 400 Hz only, the dashboard-off sustained rate read off the latency runs: about 1 "
                             "to 2.5 minutes on an idle 2-core machine (measured 67 s with MAVSDK installed, 60 s "
                             "without it, its two clients then being skipped; 130-155 s with the floor rows, on a "
                             "day the machine ran everything 1.5-2x slower)")
    parser.add_argument("--json", metavar="OUT.json", type=Path, help="also write the full report as JSON here")
    parser.add_argument("--markdown", metavar="OUT.md", type=Path,
                        help="also write the report as a markdown page (docs/benchmarks.md is made this way)")
    parser.add_argument("--clients", default=None,
                        help="comma-separated subset of: " + ",".join(CLIENT_LABELS) + " (default all)")
    parser.add_argument("--rates-hz", default=None, help="comma-separated ATTITUDE rates [Hz] (default 100,400,1000)")


def run(args: argparse.Namespace) -> int:
    from ..console_output import report_console

    from ..errors import ConfigError

    cfg = BenchConfig.quick_config() if args.quick else BenchConfig.full()
    if args.clients:
        kinds = tuple(k.strip() for k in args.clients.split(",") if k.strip())
        bad = [k for k in kinds if k not in CLIENT_LABELS]
        if bad:
            raise ConfigError(f"--clients: unknown client {bad[0]!r}; choose from {', '.join(CLIENT_LABELS)}")
        cfg.clients = kinds
    if args.rates_hz:
        try:
            rates = tuple(float(x) for x in args.rates_hz.split(","))
        except ValueError:
            raise ConfigError(f"--rates-hz: {args.rates_hz!r} is not a comma-separated list of numbers") from None
        if any(not 1.0 <= r <= 1000.0 for r in rates):
            raise ConfigError(f"--rates-hz: {args.rates_hz!r}: each rate must be in 1..1000 Hz")
        cfg.rates_hz = rates
        cfg.baseline_rates_hz = None  # explicit rates: every client at every rate
    for opt in ("json", "markdown"):
        path = getattr(args, opt)
        if path is not None and not path.parent.exists():
            raise ConfigError(f"--{opt}: directory {path.parent} does not exist")
    console = report_console()
    err_console = report_console(stderr=True)
    with err_console.status("starting", spinner="dots") as status:
        report = run_all_measurements(cfg, progress=lambda msg: status.update(msg))
    for table in render_tables(report):
        console.print(table)
    m = report["meta"]
    console.print(f"{m['date_utc']} | {m['machine']['cpu']} x{m['machine']['logical_cpus']} | "
                  f"load {m['machine']['load_average_1m_start']} -> {m['machine']['load_average_1m_end']} | "
                  f"bench wall {m['bench_wall_s']} s{' (--quick)' if cfg.quick else ''}")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
        console.print(f"JSON written to {args.json}")
    if args.markdown is not None:
        command = "mavastsm bench" + (" --quick" if cfg.quick else "")
        args.markdown.write_text(render_markdown(report, command))
        console.print(f"markdown written to {args.markdown}")
    return 0
