"""What ``mavastsm bench`` measures and how (the package docstring says what each figure means): the clients'
latency and CPU per cycle against the stub vehicle, the sustained rate, the sim's real-time factor, the offline
simulator and the sweep. Each function returns plain dicts for the report (``report.py``)."""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..processes import end_process_group
from .latency import PairingRule


CLIENT_LABELS = {
    "bridge": "mavastsm bridge (ASTSM, --log on)",
    "pymavlink": "naive pymavlink loop",
    "pymavlink-astsm": "naive pymavlink loop + the ASTSM law (the floor)",
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
    "pymavlink-astsm": PairingRule.ECHO,
    "mavsdk-async": PairingRule.ROLL_CODE,
    "mavsdk-callback": PairingRule.ROLL_CODE,
}
RATE_LADDER_HZ = (1000.0, 800.0, 600.0, 400.0, 200.0, 100.0)


@dataclass
class BenchConfig:
    """What to run and for how long. ``quick()`` takes 60-155 s on an idle 2-core machine (see --quick); ``full()`` is the real thing."""

    rates_hz: tuple[float, ...] = (100.0, 400.0, 1000.0)
    clients: tuple[str, ...] = ("bridge", "pymavlink", "pymavlink-astsm", "mavsdk-async", "mavsdk-callback")
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


def library_versions() -> dict:
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
        end_process_group(proc, grace_s=5.0)
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
    loop. ``cpu_bound`` = simulated s per CPU s of the sim process (what one free core would give). ``_law``: the same
    peer computing the package's law on each ATTITUDE (``--peer-law``), the ceiling of lockstep with a bridge flying it."""
    out = {"real_time_factor_minimal_peer": None, "cpu_bound_real_time_factor_minimal_peer": None,
           "real_time_factor_minimal_peer_law": None, "minimal_peer_error": ""}
    if not SIM_RTF_SCRIPT.is_file():
        out["minimal_peer_error"] = f"{SIM_RTF_SCRIPT} not found (only in a source checkout)"
        return out
    try:
        for extra, key in (([], "real_time_factor_minimal_peer"), (["--peer-law"], "real_time_factor_minimal_peer_law")):
            proc = subprocess.run([sys.executable, str(SIM_RTF_SCRIPT), "--sim-s", str(sim_seconds), "--json", *extra],
                                  capture_output=True, text=True, timeout=120 + 20 * sim_seconds)
            data = json.loads(proc.stdout.strip().splitlines()[-1])
            out[key] = _r(data["real_time_factor"], 2)
            if not extra:
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
