"""Where the engaged cycle's time goes: the bridge against the bench's stub vehicle, sampled by py-spy.

    pip install -e ".[bench]"             # py-spy, a sampling profiler (a dev tool; the bridge never imports it)
    python benchmarks/cycle_profile.py    # 400 Hz, --log on, 20 s sampled from 1 s after engagement; about 30 s
    python benchmarks/cycle_profile.py --rate-hz 100 --markdown out.md
    python benchmarks/cycle_profile.py --top 15 --append docs/benchmarks.md   # after `mavastsm bench --quick --markdown`

The bridge runs as ``mavastsm bench`` runs it (``python -m mavastsm.bench.clients bridge``: ASTSM holding the
engage attitude against ``StubVehicle``, its own process, the flight log on as in the README's commands), and
py-spy samples that process from outside (``--nonblocking``: the process is never paused; ``--gil``: only the
thread holding the interpreter, i.e. Python work, not waits). Each sample's stack is put in one stage by the
first frame, from the innermost out, that one of ``STAGE_RULES`` names; the table gives each stage's share of
the samples and, from the process's CPU time over the same window divided by the ATTITUDE samples the stub sent,
its microseconds per cycle (CPU time over the sampled window / the ATTITUDE samples the stub sent in it). Asserts nothing; numbers move with the machine's load (the load average is printed).
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: (stage, file fragment, function names or None for any) in the order a sample's frames are tried, innermost
#: first: the first frame one of these names decides the sample's stage. Specific before general.
STAGE_RULES: tuple[tuple[str, str, tuple[str, ...] | None], ...] = (
    ("flight log and .tlog", "mavastsm/bridge/record/flight_log.py", None),
    ("flight log and .tlog", "mavastsm/bridge/link/mavlink_link.py", ("TlogWriter.write", "TlogWriter.flush")),
    ("telemetry (dashboard feed)", "mavastsm/telemetry.py", None),
    ("encode, sign and send", "mavastsm/bridge/link/mavlink_link.py", ("MavlinkLink.send_setpoint", "MavlinkLink._send")),
    ("output gate and latency record", "mavastsm/bridge/session/session_output.py", None),
    ("safety gates", "mavastsm/bridge/cycle/safety.py", None),
    ("law (ASTSM)", "mavastsm/control/", None),
    ("mapping (torque -> body rates, hidden target)", "mavastsm/bridge/cycle/setpoint_mapping.py", None),
    ("mapping (torque -> body rates, hidden target)", "mavastsm/bridge/cycle/autopilot_target_model.py", None),
    ("reference and shaping", "mavastsm/bridge/cycle/reference_shaping.py", None),
    ("reference and shaping", "mavastsm/references.py", None),
    ("cycle glue (ControlCycle)", "mavastsm/bridge/cycle/control_cycle.py", None),
    ("state stage (validation, dt, restarts)", "mavastsm/bridge/session/sample_stage.py", None),
    ("state stage (validation, dt, restarts)", "mavastsm/bridge/link/vehicle_clock.py", None),
    ("session state machine", "mavastsm/bridge/session/offboard_session.py", None),
    ("session state machine", "mavastsm/bridge/session/session_counters.py", None),
    ("receive and decode", "mavastsm/bridge/link/messages.py", None),
    ("receive and decode", "mavastsm/bridge/link/mavlink_link.py", None),  # the rest of the link: its reader side
    ("receive and decode", "mavastsm/mavlink_datagram.py", None),
    ("supervision, heartbeat and other threads", "mavastsm/", None),
)
OTHER = "outside the project (interpreter, library without a project caller)"


def parse_frame(frame: str) -> tuple[str, str]:
    """``"Func.name (path/file.py:123)"`` -> (``"Func.name"``, ``"path/file.py"``); a frame without a location keeps
    an empty path."""
    name, _, rest = frame.rpartition(" (")
    if not name:
        return frame, ""
    return name, rest.rstrip(")").rsplit(":", 1)[0]


def innermost_project_line(frames: list[str]) -> str:
    """The innermost frame in ``mavastsm/`` as ``"Func.name (file.py:line)"`` (where the project's own code, or the
    library call it made, spent the sample); "" when no project frame is on the stack."""
    for frame in reversed(frames):
        if "mavastsm/" in frame.replace(os.sep, "/"):
            return frame
    return ""


def stage_of(frames: list[str]) -> str:
    """The stage a sample's stack (outermost first, as py-spy's raw format lists it) belongs to (STAGE_RULES)."""
    parsed = [parse_frame(f) for f in frames]
    for name, path in reversed(parsed):
        for stage, fragment, names in STAGE_RULES:
            if fragment in path.replace(os.sep, "/") and (names is None or name in names):
                return stage
    return OTHER


def stage_shares(raw_lines, lines: collections.Counter | None = None) -> tuple[dict[str, int], int]:
    """py-spy ``--format raw`` lines (``frame;frame;... count``) -> ({stage: samples}, total samples); ``lines``, when
    given, also counts the samples of each innermost project frame (:func:`innermost_project_line`)."""
    counts: collections.Counter = collections.Counter()
    for line in raw_lines:
        stack, _, n = line.rstrip("\n").rpartition(" ")
        if not stack or not n.isdigit():
            continue
        frames = stack.split(";")
        if frames and frames[0].startswith(("thread (", "process ")):
            frames = frames[1:]
        counts[stage_of(frames)] += int(n)
        if lines is not None:
            lines[innermost_project_line(frames) or OTHER] += int(n)
    return dict(counts), sum(counts.values())


def process_cpu_s(pid: int) -> float:
    """utime + stime of ``pid`` [s] from /proc (all threads)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def profile(rate_hz: float, seconds: float, warmup_s: float, py_spy: str) -> dict:
    """One bridge process against a stub at ``rate_hz``, sampled for ``seconds`` once it has sent ``warmup_s`` worth of
    setpoints (engaged: its start-up is not the cycle)."""
    from mavastsm.bench import CLIENT_RULES
    from mavastsm.bench.stub_vehicle import StubVehicle

    stub = StubVehicle(rate_hz, CLIENT_RULES["bridge"], duration_s=seconds + 30.0, warmup_s=0.0, attitude="small_sine")
    raw = Path(tempfile.mkdtemp(prefix="mavastsm-cycle-profile-")) / "raw.txt"
    with tempfile.TemporaryDirectory(prefix="mavastsm-cycle-profile-log-") as log_dir:
        stub.start()
        proc = subprocess.Popen([sys.executable, "-m", "mavastsm.bench.clients", "bridge", "--port", str(stub.port),
                                 "--rate-hz", str(rate_hz), "--log-dir", log_dir],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            deadline = time.monotonic() + 60.0  # engaged: setpoints streaming for warmup_s (start-up is not the cycle)
            while stub.commands_seen.get("SET_ATTITUDE_TARGET", 0) < rate_hz * warmup_s:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise SystemExit("cycle_profile: the bridge did not engage against the stub within 60 s")
                time.sleep(0.1)
            cpu0, wall0 = process_cpu_s(proc.pid), time.monotonic()
            spy = subprocess.run([py_spy, "record", "--pid", str(proc.pid), "--duration", str(int(round(seconds))),
                                  "--rate", "997", "--format", "raw", "--output", str(raw), "--nonblocking", "--gil"],
                                 capture_output=True, text=True)
            cpu1, wall1 = process_cpu_s(proc.pid), time.monotonic()
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
            stub.stop()
    if spy.returncode != 0 or not raw.is_file():
        raise SystemExit(f"py-spy failed (exit {spy.returncode}): {spy.stderr.strip().splitlines()[-1:] or ''}")
    lines: collections.Counter = collections.Counter()
    counts, total = stage_shares(raw.read_text().splitlines(), lines)
    shutil.rmtree(raw.parent, ignore_errors=True)
    cycles = rate_hz * (wall1 - wall0)  # ATTITUDE samples the stub sent while py-spy sampled
    return {"rate_hz": rate_hz, "seconds": seconds, "samples": total, "stages": counts, "lines": lines,
            "cpu_per_cycle_us": (cpu1 - cpu0) / cycles * 1e6,
            "load_1m": round(os.getloadavg()[0], 2)}


def table(rep: dict, top: int = 0) -> str:
    cpu = rep["cpu_per_cycle_us"]
    lines = [f"Bridge at {rep['rate_hz']:.0f} Hz against the stub, --log on, {rep['seconds']:.0f} s sampled "
             f"({rep['samples']} samples holding the GIL); CPU {cpu:.0f} us per cycle, load {rep['load_1m']}.", "",
             "| stage | share of the Python samples | us per cycle (of the process's CPU) |", "|---|---|---|"]
    for stage, n in sorted(rep["stages"].items(), key=lambda kv: -kv[1]):
        share = n / rep["samples"] if rep["samples"] else 0.0
        lines.append(f"| {stage} | {100 * share:.1f} % | {share * cpu:.0f} |")
    if top:
        lines += ["", f"The {top} innermost project frames with the most samples (the project's line, or the library call "
                  "it made there):", "", "| frame | share | us per cycle |", "|---|---|---|"]
        for frame, n in rep["lines"].most_common(top):
            share = n / rep["samples"] if rep["samples"] else 0.0
            lines.append(f"| `{frame}` | {100 * share:.1f} % | {share * cpu:.0f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate-hz", type=float, default=400.0, help="ATTITUDE rate the stub streams [Hz] (default 400)")
    ap.add_argument("--seconds", type=float, default=20.0, help="sampled window [s] (default 20)")
    ap.add_argument("--warmup-s", type=float, default=1.0, help="engaged this long before sampling starts [s]")
    ap.add_argument("--top", type=int, default=0, metavar="N", help="also list the N hottest project lines")
    ap.add_argument("--markdown", default=None, metavar="FILE", help="also write the table there")
    ap.add_argument("--append", default=None, metavar="FILE",
                    help="append it to FILE as the section \"Where the cycle's time goes\" (docs/benchmarks.md)")
    args = ap.parse_args(argv)
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(py_spy).is_file():
        print("cycle_profile: py-spy not found: pip install -e \".[bench]\" (or pip install py-spy)", file=sys.stderr)
        return 2
    text = table(profile(args.rate_hz, args.seconds, args.warmup_s, py_spy), args.top)
    print(text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.append:
        with open(args.append, "a") as f:
            f.write("\n" + section(text) + "\n")
    return 0


def section(text: str) -> str:
    """The docs section around the table: how it was made, when, at which commit, on what machine."""
    import datetime
    import platform

    try:
        commit = subprocess.run(["git", "-C", str(Path(__file__).resolve().parents[1]), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True).stdout.strip() or "unknown"
    except OSError:
        commit = "unknown"
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (f"## Where the cycle's time goes\n\n`python benchmarks/cycle_profile.py` on {when} at commit {commit}, "
            f"{platform.machine()}, {os.cpu_count()} logical CPUs, Python {platform.python_version()}: py-spy samples "
            "the bridge process (the bench's bridge client, --log on) from outside, without pausing it, counting only "
            "the thread that holds the interpreter; each sample goes to the stage of its innermost project frame (the "
            "script's STAGE_RULES). Sampling costs the machine part of a core, so the shares are what to read; the "
            "bench's tables above are the figures to quote.\n\n" + text)


if __name__ == "__main__":
    sys.exit(main())
