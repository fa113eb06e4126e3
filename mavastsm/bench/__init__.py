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
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .latency import PairingRule

CLIENT_LABELS = {
    "bridge": "mavastsm bridge (ASTSM, --log on)",
    "pymavlink": "naive pymavlink loop",
    "mavsdk-async": "MAVSDK asyncio stream",
    "mavsdk-callback": "MAVSDK native callback",
}
#: How each client's replies are paired with samples (see ``bench_latency``). The bridge writes its own
#: uptime into SET_ATTITUDE_TARGET.time_boot_ms and its ASTSM output cannot be decoded, so it is paired by
#: arrival order: exact while latency < one period; a late answer is still counted as a missed cycle
#: (exact count), but its latency is then under-reported.
CLIENT_RULES = {
    "bridge": PairingRule.ARRIVAL,
    "pymavlink": PairingRule.ECHO,
    "mavsdk-async": PairingRule.ROLL_CODE,
    "mavsdk-callback": PairingRule.ROLL_CODE,
}
RATE_LADDER_HZ = (1000.0, 800.0, 600.0, 400.0, 200.0, 100.0)


@dataclass
class BenchConfig:
    """What to run and for how long. ``quick()`` takes 60-67 s on an idle 2-core machine (see --quick); ``full()`` is the real thing."""

    rates_hz: tuple[float, ...] = (100.0, 400.0, 1000.0)
    clients: tuple[str, ...] = ("bridge", "pymavlink", "mavsdk-async", "mavsdk-callback")
    #: rates at which the baselines (every client but the bridge) are measured; None = all of ``rates_hz``
    baseline_rates_hz: tuple[float, ...] | None = None
    window_s: float = 10.0
    warmup_s: float = 1.0
    sustained_window_s: float = 30.0
    sustained_ladder_hz: tuple[float, ...] = RATE_LADDER_HZ
    sim_seconds: float = 20.0
    run_reproduce: bool = True
    offline_seconds: float = 7.0
    offline_batch: int = 64
    #: offline sweep: about this many ASTSM runs of ``sweep_seconds`` each, on every core (0 = not measured)
    sweep_runs: int = 1000
    sweep_seconds: float = 5.0
    #: MAVLink-level sweep: this many runs, one bridge + sim pair per core (0 = not measured)
    mavlink_sweep_runs: int = 8
    client_start_timeout_s: float = 30.0
    #: take the dashboard-off sustained rate from the latency runs of the bridge (same measurement,
    #: latency window) instead of a separate ladder: saves three runs in --quick
    sustained_off_from_latency: bool = False
    quick: bool = False
    extra_notes: list[str] = field(default_factory=list)

    @classmethod
    def full(cls) -> "BenchConfig":
        return cls()

    @classmethod
    def quick_config(cls) -> "BenchConfig":
        return cls(window_s=2.0, warmup_s=0.5, sustained_window_s=3.0, baseline_rates_hz=(400.0,), sustained_ladder_hz=(1000.0, 400.0, 100.0),
                   sim_seconds=3.0, offline_seconds=2.0, offline_batch=32, sweep_runs=256, sweep_seconds=2.0, mavlink_sweep_runs=4,
                   sustained_off_from_latency=True, quick=True)


# ---------------------------------------------------------------------------------------------
# Process helpers


def process_cpu_seconds(pid: int) -> float:
    """[s] user+system CPU of process ``pid`` (all threads) from /proc (Linux; NaN elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _end_process(proc: subprocess.Popen) -> None:
    """SIGTERM the client's own process group, then SIGKILL after 5 s; reap it."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(timeout=5)


def _client_error(stderr_text: str, rc: int | None) -> str:
    for line in reversed(stderr_text.splitlines()):
        if line.startswith("BENCH-CLIENT-ERROR"):
            return line[len("BENCH-CLIENT-ERROR "):]
    tail = " | ".join(stderr_text.strip().splitlines()[-3:])
    return f"client exited with code {rc}: {tail}" if rc not in (None, 0) else tail


def machine_description() -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gb = float("nan")
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                mem_gb = round(int(line.split()[1]) / 1024 / 1024, 1)
    except OSError:
        pass
    return {
        "cpu": cpu, "logical_cpus": os.cpu_count(), "memory_gb": mem_gb,
        "os": f"{platform.system()} {platform.release()}", "python": platform.python_version(),
        "load_average_1m_start": round(os.getloadavg()[0], 2),
    }


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("mavastsm", "pymavlink", "mavsdk", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


# ---------------------------------------------------------------------------------------------
# Measurements


def measure_client(kind: str, rate_hz: float, window_s: float, warmup_s: float, dashboard: bool = False,
                   start_timeout_s: float = 30.0) -> dict:
    """Run one client process against a fresh stub at ``rate_hz``; returns one JSON-ready row."""
    from .stub_vehicle import StubVehicle

    row = {"client": kind, "label": CLIENT_LABELS[kind] + (" + dashboard" if dashboard else ""),
           "rate_hz": rate_hz, "dashboard": dashboard, "window_s": window_s, "pairing": CLIENT_RULES[kind].value,
           "samples": 0, "answered": 0, "missed": None, "unanswered": None, "extra": None, "repeats": None,
           "p50_us": None, "p99_us": None, "max_us": None, "mean_us": None, "cpu_per_cycle_us": None,
           "stub_max_send_gap_us": None, "load_1m": round(os.getloadavg()[0], 2), "error": ""}
    stub = StubVehicle(rate_hz, CLIENT_RULES[kind], duration_s=window_s, warmup_s=warmup_s,
                       attitude="small_sine" if kind == "bridge" else "roll_code")
    cmd = [sys.executable, "-m", "mavastsm.bench.clients", kind, "--port", str(stub.port), "--rate-hz", str(rate_hz)]
    if dashboard:
        cmd.append("--dashboard")
    log_dir = tempfile.TemporaryDirectory(prefix="mavastsm-bench-log-") if kind == "bridge" else None
    if log_dir is not None:  # the bridge logs as the README's commands have it (--log): CSV and .tlog
        cmd += ["--log-dir", log_dir.name]
    stub.start()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        stub.cpu_probe = lambda: process_cpu_seconds(proc.pid)
        deadline = time.monotonic() + start_timeout_s + warmup_s + window_s + 5.0
        result = None
        while time.monotonic() < deadline:  # wait on the stub's event, but notice a client that died
            if stub.done.wait(0.2):
                break
            if proc.poll() is not None:
                break
        result = stub.wait_result(0.0 if not stub.done.is_set() else 1.0)
    finally:
        _end_process(proc)
        stub.stop()
        if log_dir is not None:
            log_dir.cleanup()
    stderr_text = proc.stderr.read() if proc.stderr else ""
    if proc.stderr:
        proc.stderr.close()
    if result.error:
        client_said = _client_error(stderr_text, proc.returncode).strip()
        row["error"] = f"{result.error}: {client_said}" if client_said else result.error
    if result.stats is None:
        return row
    s = result.stats
    row.update({"samples": s.samples, "answered": s.answered, "missed": s.missed, "unanswered": s.unanswered,
                "extra": s.extra, "repeats": s.repeats, "p50_us": _r(s.p50_us), "p99_us": _r(s.p99_us), "max_us": _r(s.max_us),
                "mean_us": _r(s.mean_us), "cpu_per_cycle_us": _r(result.cpu_per_cycle_us),
                "stub_max_send_gap_us": _r(s.stub_max_send_gap_us)})
    return row


def _r(x: float, nd: int = 1) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def measure_sustained_rate(ladder_hz: tuple[float, ...], window_s: float, dashboard: bool,
                           progress: Callable[[str], None]) -> dict:
    """Descend ``ladder_hz``; the first rate with a full window and zero missed cycles is the answer."""
    trials = []
    best = None
    for rate in ladder_hz:
        progress(f"sustained rate, dashboard {'on' if dashboard else 'off'}: {rate:.0f} Hz for {window_s:.0f} s")
        row = measure_client("bridge", rate, window_s, 1.0, dashboard=dashboard)
        trials.append({k: row[k] for k in ("rate_hz", "samples", "missed", "p50_us", "p99_us", "max_us",
                                           "cpu_per_cycle_us", "error")})
        if row["samples"] == 0:  # the client could not run at all: a lower rate will not help
            break
        if row["missed"] == 0 and not row["error"]:
            best = rate
            break  # a failed rung (missed cycles, or the bridge stopped itself) moves down the ladder
    ran = any(t["samples"] for t in trials)
    return {"highest_rate_hz_without_miss": best, "window_s": window_s, "ladder_hz": list(ladder_hz),
            "dashboard": dashboard, "trials": trials,
            "error": "" if ran else (trials[-1]["error"] if trials else "no trial ran")}


def sustained_from_rows(rows: list[dict]) -> dict:
    """The sustained-rate answer read off the bridge's latency runs (highest rate with no missed cycle)."""
    trials = sorted((r for r in rows if r["client"] == "bridge" and not r["dashboard"]), key=lambda r: -r["rate_hz"])
    best = next((r["rate_hz"] for r in trials if r["missed"] == 0 and r["samples"] > 0 and not r["error"]), None)
    ran = any(r["samples"] for r in trials)
    return {"highest_rate_hz_without_miss": best, "window_s": trials[0]["window_s"] if trials else None,
            "ladder_hz": [r["rate_hz"] for r in trials], "dashboard": False,
            "trials": [{k: r[k] for k in ("rate_hz", "samples", "missed", "p50_us", "p99_us", "max_us",
                                          "cpu_per_cycle_us", "error")} for r in trials],
            "error": "" if ran else next((r["error"] for r in trials if r["error"]), "no trial ran"),
            "from_latency_runs": True}


def measure_sim_lockstep(sim_seconds: float) -> dict:
    """Sim (lockstep, 1 kHz physics) + bridge (400 Hz) for ``sim_seconds`` of vehicle time: real-time factor.

    Two layouts: sim thread + bridge in one process (``real_time_factor``, as ``mavastsm demo``) and
    sim and bridge as two processes (``real_time_factor_two_processes``).
    """
    out = {"control_hz": 400.0, "physics_hz": 1000.0, "sim_s": None, "wall_s": None, "real_time_factor": None,
           "sim_s_two_processes": None, "wall_s_two_processes": None, "real_time_factor_two_processes": None,
           "error": ""}
    errors = []
    from .bridge_runner import run_sim_lockstep

    for separate, suffix in ((False, ""), (True, "_two_processes")):
        try:
            sim_s, wall_s = run_sim_lockstep(sim_seconds, separate_process=separate)
            out.update({f"sim_s{suffix}": _r(sim_s, 3), f"wall_s{suffix}": _r(wall_s, 3),
                        f"real_time_factor{suffix}": _r(sim_s / wall_s, 2)})
        except Exception as exc:  # report, do not crash the bench
            errors.append(f"{'two processes' if separate else 'one process'}: {type(exc).__name__}: {exc}")
    out.update(measure_sim_alone(sim_seconds))
    if out["minimal_peer_error"]:
        errors.append(f"minimal peer: {out['minimal_peer_error']}")
    out["error"] = "; ".join(errors)
    return out


def _source_benchmarks_dir() -> Path:
    """The repository's benchmarks/ folder (next to mavastsm/, not inside it; a source checkout only): beside the
    package when it runs from the checkout (editable install, python -m), else in the working directory (the package
    installed from the checkout, as CI installs it, and run from its root). The first candidate when neither exists."""
    candidates = (Path(__file__).resolve().parents[2] / "benchmarks", Path.cwd() / "benchmarks")
    return next((c for c in candidates if (c / "sim_realtime_factor.py").is_file()), candidates[0])


SOURCE_BENCHMARKS_DIR = _source_benchmarks_dir()
SIM_RTF_SCRIPT = SOURCE_BENCHMARKS_DIR / "sim_realtime_factor.py"


def measure_sim_alone(sim_seconds: float) -> dict:
    """The simulator's own benchmark (``benchmarks/sim_realtime_factor.py``, helper B2): lockstep against a
    minimal pymavlink peer process that answers every ATTITUDE, so the bridge's cycle cost is out of the
    loop. ``cpu_bound`` = simulated s per CPU s of the sim process (what one free core would give)."""
    out = {"real_time_factor_minimal_peer": None, "cpu_bound_real_time_factor_minimal_peer": None,
           "minimal_peer_error": ""}
    if not SIM_RTF_SCRIPT.is_file():
        out["minimal_peer_error"] = f"{SIM_RTF_SCRIPT} not found (only in a source checkout)"
        return out
    try:
        proc = subprocess.run([sys.executable, str(SIM_RTF_SCRIPT), "--sim-s", str(sim_seconds), "--json"],
                              capture_output=True, text=True, timeout=120 + 20 * sim_seconds)
        data = json.loads(proc.stdout.strip().splitlines()[-1])
        out["real_time_factor_minimal_peer"] = _r(data["real_time_factor"], 2)
        out["cpu_bound_real_time_factor_minimal_peer"] = _r(data["cpu_bound_real_time_factor"], 2)
    except Exception as exc:  # report, never crash the bench
        out["minimal_peer_error"] = f"{type(exc).__name__}: {exc}"
    return out


def measure_offline(cfg: BenchConfig) -> dict:
    """``mavastsm reproduce`` wall time, offline throughput single and batched (helper A's simulator)."""
    out = {"reproduce_wall_s": None, "single_sim_s_per_wall_s": None, "batched_sim_s_per_wall_s": None,
           "batch": cfg.offline_batch, "error": ""}
    try:
        from .offline import offline_throughput, reproduce_wall_time

        if cfg.run_reproduce:
            out["reproduce_wall_s"] = _r(reproduce_wall_time(), 2)
        single, batched = offline_throughput(cfg.offline_seconds, cfg.offline_batch)
        out["single_sim_s_per_wall_s"] = _r(single, 1)
        out["batched_sim_s_per_wall_s"] = _r(batched, 1)
    except Exception as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"
    return out


def measure_sweep(cfg: BenchConfig) -> dict:
    """``mavastsm sweep`` speed: offline sim s / wall s on every core, MAVLink-level runs per minute."""
    out = {"offline": None, "mavlink": None, "error": ""}
    try:
        from ..sweep.throughput import mavlink_sweep_rate, offline_sweep_throughput

        if cfg.sweep_runs > 0:
            out["offline"] = offline_sweep_throughput(cfg.sweep_runs, cfg.sweep_seconds)
        if cfg.mavlink_sweep_runs > 0:
            out["mavlink"] = mavlink_sweep_rate(cfg.mavlink_sweep_runs)
    except Exception as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"
    return out


def _sweep_rows(report: dict) -> list[list[str]]:
    """(measurement, value, detail) rows of the sweep speed, for the console and the markdown page."""
    sw = report["sweep"]
    off, mav = sw["offline"], sw["mavlink"]
    return [
        ["offline sweep (ASTSM + plant, T = 1 ms, simulation and metrics, every core)",
         "-" if off is None else f"{off['sim_s_per_wall_s']:.0f} sim s / wall s",
         sw["error"][:60] if off is None else f"{off['runs']} runs x {off['sim_s'] / max(off['runs'], 1):g} s in {off['wall_s']} s, {off['workers']} processes"
         + (f" (then {off['reports_s']} s for table, margins and map)" if off.get("reports_s") is not None else "")],
        ["MAVLink-level sweep (bridge + simulated Solo pairs in lockstep)",
         "-" if mav is None else f"{mav['runs_per_min']:.0f} runs / min",
         "" if mav is None else f"{mav['runs']} runs of 6 s in {mav['wall_s']} s, {mav['workers']} pairs at a time"],
    ]


def _find(rows: list[dict], client: str, rate: float) -> dict | None:
    for r in rows:
        if r["client"] == client and r["rate_hz"] == rate and not r.get("dashboard"):
            return r
    return None


def compare(rows: list[dict]) -> list[dict]:
    """Ratios theirs/ours of p50 and p99 per rate (> 1 means our bridge is faster)."""
    out = []
    for rate in sorted({r["rate_hz"] for r in rows}):
        ours = _find(rows, "bridge", rate)
        for other in ("pymavlink", "mavsdk-async", "mavsdk-callback"):
            theirs = _find(rows, other, rate)
            if theirs is None:
                continue
            item = {"rate_hz": rate, "versus": other, "p50_ratio": None, "p99_ratio": None}
            if ours and theirs and ours["p50_us"] and theirs["p50_us"]:
                item["p50_ratio"] = round(theirs["p50_us"] / ours["p50_us"], 2)
                item["p99_ratio"] = round(theirs["p99_us"] / ours["p99_us"], 2)
            out.append(item)
    return out


def evaluate_targets(report: dict) -> list[dict]:
    """Issue 30's targets (docs/benchmarks.md), each with the measured number and met / MISSED / not measured.

    Ratios are ours / the naive pymavlink loop's from the same run (< 1.25 is the goal); the bridge logs as the
    README's commands have it."""
    rows = report["latency"]
    b400, naive = _find(rows, "bridge", 400.0), _find(rows, "pymavlink", 400.0)
    rtf = report["sim_lockstep"]["real_time_factor"]

    def target(text, measured, unit, ok):
        status = "not measured" if measured is None else ("met" if ok(measured) else "MISSED")
        return {"target": text, "measured": measured, "unit": unit, "status": status}

    def ratio(key):
        if not (b400 and naive and b400.get(key) and naive.get(key)):
            return None
        return round(b400[key] / naive[key], 2)

    off_sweep = (report.get("sweep") or {}).get("offline")
    return [
        target("bridge CPU per cycle at 400 Hz <= 1.25 x the naive pymavlink loop's", ratio("cpu_per_cycle_us"), "x",
               lambda v: v <= 1.25),
        target("bridge p50 latency at 400 Hz <= 1.25 x the naive pymavlink loop's", ratio("p50_us"), "x",
               lambda v: v <= 1.25),
        target("bridge never late at 400 Hz: 0 missed cycles in the window (dashboard off)",
               None if not b400 or b400["missed"] is None else b400["missed"], "missed", lambda v: v == 0),
        target("sim >= 10x real time in lockstep with the bridge (400 Hz control, 1 kHz physics)", rtf, "x",
               lambda v: v >= 10.0),
        target("offline sweep >= 2000 simulated s per wall s (ASTSM + plant at 1 kHz, every core"
               + ("" if off_sweep is None else f", {off_sweep['runs']} runs x {off_sweep['sim_s'] / max(off_sweep['runs'], 1):g} s")
               + "; docs/sweep.md quotes 1024 x 5 s, the full bench's size)",
               None if off_sweep is None else off_sweep["sim_s_per_wall_s"], "sim s / wall s", lambda v: v >= 2000.0),
    ]


def run_all_measurements(cfg: BenchConfig, progress: Callable[[str], None] = lambda s: None) -> dict:
    """Run every measurement in ``cfg`` and return the JSON-ready report (see module docstring)."""
    t0 = time.monotonic()
    report: dict = {
        "meta": {"date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                 "quick": cfg.quick, "machine": machine_description(), "versions": _versions(),
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


def _fmt(v, nd=0) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def render_tables(report: dict):
    """Rich renderables for the report (pure: report in, renderables out)."""
    from rich.table import Table

    lat = Table(title="Cycle latency: ATTITUDE sent -> SET_ATTITUDE_TARGET received, timed by the stub vehicle")
    for col in ("client", "rate Hz", "p50 us", "p99 us", "max us", "missed/samples", "CPU us/cycle", "note"):
        lat.add_column(col, justify="right" if col not in ("client", "note") else "left")
    for r in report["latency"]:
        note = r["error"][:70] if r["error"] else ""
        lat.add_row(r["label"], _fmt(r["rate_hz"]), _fmt(r["p50_us"]), _fmt(r["p99_us"]), _fmt(r["max_us"]),
                    "-" if r["missed"] is None else f"{r['missed']}/{r['samples']}", _fmt(r["cpu_per_cycle_us"]), note)
    cmp_t = Table(title="Ratios theirs / ours (> 1: mavastsm bridge is faster)")
    for col in ("rate Hz", "versus", "p50 ratio", "p99 ratio"):
        cmp_t.add_column(col, justify="right")
    for c in report["comparison"]:
        cmp_t.add_row(_fmt(c["rate_hz"]), c["versus"], _fmt(c["p50_ratio"], 2), _fmt(c["p99_ratio"], 2))
    other = Table(title="Throughput")
    other.add_column("measurement")
    other.add_column("value", justify="right")
    other.add_column("note")
    for key, label in (("dashboard_off", "highest ATTITUDE rate, no missed cycle, dashboard off"),
                       ("dashboard_on", "highest ATTITUDE rate, no missed cycle, dashboard on")):
        s = report["sustained_rate"][key]
        val = "none of the ladder" if s["highest_rate_hz_without_miss"] is None else \
            f"{s['highest_rate_hz_without_miss']:.0f} Hz"
        if s["error"]:
            val = "-"
        other.add_row(label, val, (s["error"][:60] if s["error"] else f"{s['window_s']:.0f} s window"))
    sim = report["sim_lockstep"]
    for suffix, layout in (("", "sim thread + bridge, one process"), ("_two_processes", "sim and bridge processes")):
        rtf = sim[f"real_time_factor{suffix}"]
        other.add_row(f"sim real-time factor in lockstep with the bridge (400 Hz ctrl / 1 kHz physics), {layout}",
                      "-" if rtf is None else f"{rtf:.1f}x",
                      f"{sim[f'sim_s{suffix}']} sim s in {sim[f'wall_s{suffix}']} wall s" if rtf is not None
                      else sim["error"][:60])
    mp = sim.get("real_time_factor_minimal_peer")
    other.add_row("sim real-time factor in lockstep with a minimal pymavlink peer (sim alone; CPU-bound)",
                  "-" if mp is None else f"{mp:.1f}x ({sim['cpu_bound_real_time_factor_minimal_peer']:.1f}x)",
                  sim.get("minimal_peer_error", "")[:60])
    off = report["offline"]
    other.add_row("mavastsm reproduce wall time", "-" if off["reproduce_wall_s"] is None else f"{off['reproduce_wall_s']:.1f} s",
                  off["error"][:60])
    other.add_row("offline throughput, single run", "-" if off["single_sim_s_per_wall_s"] is None
                  else f"{off['single_sim_s_per_wall_s']:.1f} sim s / wall s", "")
    other.add_row(f"offline throughput, batch of {off['batch']}", "-" if off["batched_sim_s_per_wall_s"] is None
                  else f"{off['batched_sim_s_per_wall_s']:.1f} sim s / wall s", "")
    for row in _sweep_rows(report):
        other.add_row(*row)
    tg = Table(title="Targets")
    for col in ("target", "measured", "status"):
        tg.add_column(col)
    for t in report["targets"]:
        tg.add_row(t["target"], "-" if t["measured"] is None else f"{t['measured']} {t['unit']}", t["status"])
    return [lat, cmp_t, other, tg]


def _md_table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def render_markdown(report: dict, command: str) -> str:
    """A docs page from a report (pure). Every number comes from ``report``."""
    m = report["meta"]
    mach = m["machine"]
    lines = [
        "# Benchmarks",
        "",
        f"Generated by `{command}` on {m['date_utc']} (bench wall time {m['bench_wall_s']} s"
        + (", `--quick`: short windows" if m["quick"] else "") + "; by phase: "
        + ", ".join(f"{k} {v} s" for k, v in m.get("phase_wall_s", {}).items()) + ").",
        "",
        f"Machine: {mach['cpu']}, {mach['logical_cpus']} logical CPUs, {mach['memory_gb']} GB RAM, {mach['os']}, "
        f"Python {mach['python']}; 1-minute load average {mach['load_average_1m_start']} at the start and "
        f"{mach['load_average_1m_end']} at the end (the machine was shared with other jobs: expect noise, "
        "especially in p99 and max).",
        "",
        "Versions: " + ", ".join(f"{k} {v}" for k, v in m["versions"].items()) + ".",
        "",
        "## Cycle latency against the same stub vehicle",
        "",
        "ATTITUDE sent by the stub vehicle -> SET_ATTITUDE_TARGET received by it, timed outside the client "
        "with kernel receive timestamps; each client is its own process. Missed = an ATTITUDE whose answer had "
        "not arrived when the next one was sent. CPU = the client process's user+system time over the window "
        "per ATTITUDE (10 ms tick resolution).",
        "",
    ]
    rows = []
    for r in report["latency"]:
        rows.append([r["label"], _fmt(r["rate_hz"]), _fmt(r["p50_us"]), _fmt(r["p99_us"]), _fmt(r["max_us"]),
                     "-" if r["missed"] is None else f"{r['missed']} / {r['samples']}", _fmt(r["cpu_per_cycle_us"]),
                     r["pairing"], _fmt(r["load_1m"], 1), r["error"].replace("|", "/") or ""])
    lines.append(_md_table(["client", "rate Hz", "p50 us", "p99 us", "max us", "missed / samples", "CPU us/cycle",
                            "pairing", "load 1m", "error"], rows))
    lines += ["", "Ratios theirs / ours (> 1 means the mavastsm bridge answers faster):", ""]
    lines.append(_md_table(["rate Hz", "versus", "p50 ratio", "p99 ratio"],
                           [[_fmt(c["rate_hz"]), c["versus"], _fmt(c["p50_ratio"], 2), _fmt(c["p99_ratio"], 2)]
                            for c in report["comparison"]]))
    lines += ["", "## Sustained rate, simulator and offline speed", ""]
    rows = []
    for key, label in (("dashboard_off", "dashboard off"), ("dashboard_on", "dashboard on")):
        s = report["sustained_rate"][key]
        best = s["highest_rate_hz_without_miss"]
        tried = "; ".join(f"{t['rate_hz']:.0f} Hz: " + (f"{t['missed']} missed of {t['samples']}" if t["missed"] is not None
                                                           else "") + (f" ({t['error'][:90]})" if t["error"] else "")
                          for t in s["trials"])
        rows.append([f"highest ATTITUDE rate with no missed cycle over {s['window_s']:.0f} s, {label}",
                     "none of the ladder" if best is None else f"{best:.0f} Hz", tried])
    sim = report["sim_lockstep"]
    for suffix, layout in (("", "sim thread + bridge in one process (as `mavastsm demo`)"),
                           ("_two_processes", "sim and bridge as two processes")):
        rtf = sim[f"real_time_factor{suffix}"]
        rows.append([f"sim real-time factor, lockstep with the bridge, 400 Hz control / 1 kHz physics, {layout}",
                     "-" if rtf is None else f"{rtf:.1f}x",
                     f"{sim[f'sim_s{suffix}']} simulated s in {sim[f'wall_s{suffix}']} wall s" if rtf is not None
                     else sim["error"]])
    mp = sim.get("real_time_factor_minimal_peer")
    rows.append(["sim real-time factor, lockstep with a minimal pymavlink peer process (the sim alone, "
                 "`benchmarks/sim_realtime_factor.py`); in brackets: simulated s per CPU s of the sim process",
                 "-" if mp is None else f"{mp:.1f}x ({sim['cpu_bound_real_time_factor_minimal_peer']:.1f}x)",
                 sim.get("minimal_peer_error", "")])
    off = report["offline"]
    rows.append(["`mavastsm reproduce` wall time", _fmt(off["reproduce_wall_s"], 1) + (" s" if off["reproduce_wall_s"] else ""),
                 off["error"]])
    rows.append(["offline simulator, one run (ASTSM, nominal, T = 1 ms)",
                 _fmt(off["single_sim_s_per_wall_s"], 1) + " sim s / wall s", ""])
    rows.append([f"offline simulator, batch of {off['batch']} runs",
                 _fmt(off["batched_sim_s_per_wall_s"], 1) + " sim s / wall s", ""])
    rows += _sweep_rows(report)
    lines.append(_md_table(["measurement", "value", "detail"], rows))
    lines += ["", "## Targets", ""]
    lines.append(_md_table(["target", "measured", "status"],
                           [[t["target"], "-" if t["measured"] is None else f"{t['measured']} {t['unit']}",
                             t["status"]] for t in report["targets"]]))
    lines += ["", "## Reading the results", ""] + reading_notes(report) + ["", METHOD_NOTES]
    return "\n".join(lines)


def reading_notes(report: dict) -> list[str]:
    """Plain-language context computed from the report (no number here is typed in by hand)."""
    notes = []
    ours, naive = _find(report["latency"], "bridge", 400.0), _find(report["latency"], "pymavlink", 400.0)
    if ours and naive and ours["p50_us"] and naive["p50_us"]:
        notes.append(
            f"- At 400 Hz the naive pymavlink loop, which computes no control law at all, answers in p50 "
            f"{naive['p50_us']:.0f} us using {_fmt(naive['cpu_per_cycle_us'])} us of CPU per cycle on this machine; "
            f"the bridge answers in p50 {ours['p50_us']:.0f} us using {_fmt(ours['cpu_per_cycle_us'])} us per cycle. "
            "The difference is the bridge's Python control cycle (tracking error, ASTSM, torque-to-rate mapping, "
            "safety gate, telemetry, the flight log); docs/benchmarks.md, \"Where the cycle's time goes\", breaks it down.")
    for c in report["comparison"]:
        if c["versus"].startswith("mavsdk") and c["p50_ratio"] is not None:
            tail = c["p99_ratio"] is not None and c["p99_ratio"] > 2.0
            notes.append(f"- Versus {c['versus']} at {c['rate_hz']:.0f} Hz: p50 ratio {c['p50_ratio']:.2f}, p99 ratio "
                         f"{_fmt(c['p99_ratio'], 2)} (theirs / ours). MAVSDK 4 runs its MAVLink handling in C++ "
                         "in-process and calls Python only for the callback"
                         + ("; its tail was much longer than ours in this run." if tail else "."))
    sim = report["sim_lockstep"]
    cpu_bound = sim.get("cpu_bound_real_time_factor_minimal_peer")
    if cpu_bound:
        notes.append(f"- The simulator alone would run {cpu_bound:.1f}x real time on one free core (simulated s per CPU "
                     "s of the sim process); in lockstep each 2.5 ms control period also costs a UDP round trip and "
                     "the controller's cycle"
                     + (", so even the simulator's own CPU cost keeps it below 10x." if cpu_bound < 10.0 else "."))
    m = report["meta"]["machine"]
    notes.append(f"- Load average {m['load_average_1m_start']} -> {m['load_average_1m_end']} on {m['logical_cpus']} "
                 "CPUs: missed cycles and tails (p99, max) are strongly affected by other processes taking the CPUs; "
                 "compare clients within one run, and re-run on your machine.")
    return notes


METHOD_NOTES = """## How these numbers are measured

- **Stub vehicle** (`mavastsm/bench_stub_vehicle.py`): an ArduCopter-like MAVLink peer on a loopback UDP
  port (HEARTBEAT ArduPilot/GUIDED/armed, ACKs for SET_MESSAGE_INTERVAL, REQUEST_MESSAGE, AUTOPILOT_VERSION,
  DO_SET_MODE, SET_MODE, arming, PARAM read/list/set, TIMESYNC). It streams ATTITUDE at a fixed rate from its
  own thread and stamps every reply with the kernel's receive time (`SO_TIMESTAMPNS`), so its own scheduling
  delays do not count against the client. Each client runs in its own process.
- **Pairing** (`mavastsm/bench_latency.py`): the naive pymavlink loop echoes the ATTITUDE `time_boot_ms`
  (exact); the MAVSDK clients fly a P law on the stub's roll angle, which encodes the sample number (exact,
  and it recognises MAVSDK's 20 Hz keep-alive re-sends); our bridge writes its own clock into `time_boot_ms`
  and its ASTSM output cannot be decoded, so it is paired by arrival order (exact while latency is under one
  period; a late answer is still counted as missed, but its latency is then under-reported).
- **Clients**: *mavastsm bridge* = `mavastsm.bridge.Bridge` with ASTSM holding the engage attitude against a
  near-level stub (tiny sine plus a rate dither, inside the sliding band, so no adaptive-gain wind-up);
  *naive pymavlink loop* = `recv_match(type='ATTITUDE', blocking=True)` then `set_attitude_target_send`;
  *MAVSDK* = the PyPI `mavsdk` 4.x package, which is the native C++ binding (ctypes, in-process; there is no
  `mavsdk_server`/gRPC any more): the asyncio stream `telemetry.subscribe_attitude_euler()` driving
  `offboard.set_attitude_rate()`, and the native callback calling `Offboard.set_attitude_rate` directly.
- **Missed cycle**: an ATTITUDE whose answer had not arrived when the next ATTITUDE was sent.
- **CPU per cycle**: user + system time of the client process (all threads; `/proc/PID/stat`, 10 ms ticks)
  over the window divided by the ATTITUDE samples. With the dashboard on, the drawing child process is not
  included (the dashboard draws in its own process by default).
- **Sustained rate**: a ladder from 1000 Hz down; the first rate with zero missed cycles over the window.
  1 kHz is the ceiling of the ladder: `time_boot_ms` has 1 ms resolution. With the dashboard on, the ladder
  starts at the dashboard-off result (drawing only adds work; if no rung passed, only the lowest is tried).
  In `--quick` the dashboard-off answer is read off the latency runs.
- **Sim real-time factor**: the simulator in lockstep (every ATTITUDE waits for its SET_ATTITUDE_TARGET;
  1 kHz physics) with the bridge at 400 Hz flying the paper steps after a 2 m takeoff; simulated time from
  the `time_boot_ms` the bridge receives, over the engaged part. Measured with the sim as a thread of the
  bridge's process (as in `mavastsm demo`) and as a separate `mavastsm sim --lockstep` process. For
  comparison, the simulator's own benchmark (`benchmarks/sim_realtime_factor.py`) replaces the bridge by a
  minimal pymavlink peer process that answers every ATTITUDE at once: the sim alone.
- **Offline**: `mavastsm reproduce` run as a fresh process; throughput of the batched RK4 simulator with ASTSM
  on the nominal scenario (T = 1 ms), one run and a batch.
- The machine is shared and has 2 CPUs: a client, the stub and other people's jobs compete for them, which
  shows up mostly in p99, max and missed cycles. Re-run `mavastsm bench` on your own machine for your numbers.
"""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="short windows (2 s latency, 3 s sustained-rate with the dashboard, 3 sim s), baselines "
                             "at 400 Hz only, the dashboard-off sustained rate read off the latency runs: about 1 "
                             "to 1.5 minutes on an idle 2-core machine (measured 67 s with MAVSDK installed, 60 s "
                             "without it, its two clients then being skipped)")
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
