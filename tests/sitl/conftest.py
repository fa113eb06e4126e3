"""Harness of the loopback SITL suite: sim + bridge (+ impairment proxy) on ephemeral loopback ports.

Fixtures
--------
sitl_record
    ``record(name, expected, category="fault", **measured)``: what a test injected, the reaction it
    expects and what it measured. Collected for the whole session and written to
    ``out/sitl/results.json`` (override with ``MAVASTSM_SITL_RESULTS``); render it with
    ``python tests/sitl/render_testing_doc.py`` into ``docs/testing.md``.
leak_check (autouse)
    Fails a test that leaves behind a thread, a socket or a child process (checked after teardown
    of the test's own fixtures, waiting on the condition with a timeout, never sleeping blind).
spawn
    ``spawn(*argv) -> subprocess.Popen`` in its own session (process group); every process is killed
    with its group at teardown even when the test failed.
free_udp_port
    ``free_udp_port() -> int``: a loopback UDP port the kernel just handed out (only for
    subprocesses, which must be told a port on the command line).
"""

from __future__ import annotations

import json
import os
import platform
import socket
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import pytest

from mavastsm.processes import end_process_group

REPO = Path(__file__).resolve().parents[2]
RESULTS_PATH = Path(os.environ.get("MAVASTSM_SITL_RESULTS", REPO / "out" / "sitl" / "results.json"))

_ENTRIES: list[dict] = []
_SESSION = {"start": time.monotonic(), "passed": 0, "failed": 0}


# ---------------------------------------------------------------- result recording
@pytest.fixture
def sitl_record(request):
    """Record one measured reaction for docs/testing.md (see module docstring)."""

    def record(name: str, expected: str, category: str = "fault", **measured) -> None:
        entry = {"test": request.node.nodeid, "name": name, "category": category, "expected": expected,
                 "measured": {k: _jsonable(v) for k, v in measured.items()}, "outcome": "running"}
        _ENTRIES.append(entry)
        request.node.stash.setdefault(_ENTRY_KEY, []).append(entry)

    return record


_ENTRY_KEY = pytest.StashKey[list]()


def _jsonable(v):
    if isinstance(v, float):
        return round(v, 6) if v == v else None
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if hasattr(v, "item"):  # numpy scalar
        return _jsonable(v.item())
    return v


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.when == "call" or (report.when != "call" and report.failed):
        for entry in item.stash.get(_ENTRY_KEY, []):
            if report.failed:
                entry["outcome"] = "failed"
            elif report.when == "call":
                entry["outcome"] = "passed"
    return report


def pytest_runtest_logreport(report):
    if report.nodeid.startswith("tests/sitl") or "/sitl/" in report.nodeid:
        if report.when == "call" and report.passed:
            _SESSION["passed"] += 1
        elif report.failed:
            _SESSION["failed"] += 1


def pytest_sessionfinish(session, exitstatus):
    if not _ENTRIES:
        return
    RESULTS_PATH.parent.mkdir(parents=True, exist_ok=True)
    RESULTS_PATH.write_text(json.dumps({
        "run": {"finished_utc": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                "passed": _SESSION["passed"], "failed": _SESSION["failed"],
                "duration_wall_s": round(time.monotonic() - _SESSION["start"], 1),
                "python": platform.python_version(), "cpus": os.cpu_count()},
        "entries": _ENTRIES,
    }, indent=1))


# ---------------------------------------------------------------- leak checks
def _socket_fds() -> set[str]:
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:"):
            out.add(target)
    return out


def _child_pids() -> set[int]:
    me, kids = os.getpid(), set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == me and fields[0] != "Z":
            kids.add(int(entry))
    return kids


def _wait_for(predicate, timeout_s: float, poll_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)


@pytest.fixture(autouse=True)
def leak_check():
    threads_before = {t.ident for t in threading.enumerate()}
    sockets_before = _socket_fds()
    kids_before = _child_pids()
    yield

    def new_threads():
        return [t for t in threading.enumerate() if t.ident not in threads_before and t.is_alive()]

    _wait_for(lambda: not new_threads(), 5.0)
    _wait_for(lambda: not (_socket_fds() - sockets_before), 2.0)
    leaked_threads = [t.name for t in new_threads()]
    leaked_sockets = _socket_fds() - sockets_before
    leaked_kids = _child_pids() - kids_before
    assert not leaked_threads, f"threads left running: {leaked_threads}"
    assert not leaked_sockets, f"{len(leaked_sockets)} socket(s) left open"
    assert not leaked_kids, f"child processes left running: {sorted(leaked_kids)}"


# ---------------------------------------------------------------- subprocesses
def mavastsm_argv(*args: str) -> list[str]:
    """The real console entry point, run with this interpreter (same venv)."""
    return [sys.executable, "-m", "mavastsm.cli", *args]


@pytest.fixture
def spawn():
    procs: list[subprocess.Popen] = []

    def start(*argv: str, env_home: str | None = None, **kwargs) -> subprocess.Popen:
        kwargs.setdefault("stdout", subprocess.PIPE)
        kwargs.setdefault("stderr", subprocess.PIPE)
        kwargs.setdefault("text", True)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        if env_home is not None:  # e.g. MAVProxy must not read or write the user's ~/.mavproxy
            env["HOME"] = env_home
        proc = subprocess.Popen(list(argv), start_new_session=True, env=env, **kwargs)
        procs.append(proc)
        return proc

    try:
        yield start
    finally:
        for proc in procs:
            end_process_group(proc, grace_s=0)
            try:
                proc.communicate(timeout=10)
            except (subprocess.TimeoutExpired, ValueError):
                pass
            for stream in (proc.stdin, proc.stdout, proc.stderr):
                if stream:
                    try:
                        stream.close()
                    except OSError:
                        pass


@pytest.fixture
def free_udp_port():
    def pick() -> int:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]
        finally:
            s.close()

    return pick


# ---------------------------------------------------------------- in-process flights
os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402  (test code is a MAVLink peer)

from mavastsm_sim.impairment_proxy import ImpairmentProxy  # noqa: E402

# Limits the outbound gate must respect: the packaged configs/bridge.yaml values (read, not copied).
from mavastsm.bridge.bridge_config import load_bridge_config  # noqa: E402

BRIDGE_CONFIG = load_bridge_config(None, {})
ACCEPTED_TYPE_MASKS = {0x80, 0x87, 0x07}  # rates+thrust, zero rates (level-rate hold), level attitude + thrust

SIM_DEFAULTS = dict(sched_loop_rate_hz=500.0)  # lockstep, its timeout and the ephemeral port: the pair's
BRIDGE_DEFAULTS = dict(mode="GUIDED", arm=True, takeoff_alt_m=0.5, on_exit="none", on_failsafe="none")
# In-process runs: the host-clock detectors widened or off, and no pre-stream (mavastsm.lockstep_pair explains why)
from mavastsm.lockstep_pair import IN_PROCESS_OVERRIDES  # noqa: E402


def wrap_pi(a: float) -> float:
    from mavastsm.frames import wrap_angle_float  # the package's one wrap

    return wrap_angle_float(a)


class Flight:
    """One lockstep pair (``mavastsm.lockstep_pair``: sim + impairment proxy + bridge, all in this process on
    ephemeral loopback ports; the scenario's torques start at the engagement sample).

    The proxy always sits in the middle (with no faults unless configured), and its tap records
    the ground truth: every ATTITUDE the sim sent (``truth``: (t_s, roll, pitch, yaw) [s, rad]) and
    every SET_ATTITUDE_TARGET the bridge sent (``setpoints``: (vehicle t_s, msg)), before any fault.
    """

    def __init__(self, pair, bridge_options: dict) -> None:
        self.pair = pair
        self.options = bridge_options
        self.truth: list[tuple[float, float, float, float]] = []
        self.setpoints: list[tuple[float, object]] = []
        self.other_to_vehicle: list[tuple[float, object]] = []
        self.setpoint_wall_s: list[float] = []  # host monotonic time of each entry of ``setpoints``
        self.vehicle_heartbeats: list[tuple[float, int, int]] = []  # (vehicle t_s, custom_mode, base_mode)
        self.unparsed = {"to_target": 0, "from_target": 0}
        self._parsers = {"to_target": mavlink2.MAVLink(None), "from_target": mavlink2.MAVLink(None)}
        for p in self._parsers.values():
            p.robust_parsing = True
        self._lock = threading.Lock()

    @property
    def server(self):
        return self.pair.server

    @server.setter
    def server(self, restarted) -> None:  # a test's restarted vehicle on the same port: the pair stops it at teardown
        self.pair.server = restarted

    @property
    def proxy(self) -> ImpairmentProxy:
        return self.pair.proxy

    @property
    def bridge(self):
        return self.pair.bridge

    # tap runs on the proxy thread
    def tap(self, direction: str, datagram: bytes, vehicle_time_s) -> None:
        try:
            msgs = self._parsers[direction].parse_buffer(datagram) or []
        except Exception:
            msgs = []
        if not msgs:
            self.unparsed[direction] += 1
        t = vehicle_time_s if vehicle_time_s is not None else float("nan")
        with self._lock:
            for m in msgs:
                kind = m.get_type()
                if direction == "from_target" and kind == "ATTITUDE" and m.get_srcSystem() == 1:
                    self.truth.append((m.time_boot_ms / 1000.0, m.roll, m.pitch, m.yaw))
                elif direction == "from_target" and kind == "HEARTBEAT" and m.get_srcSystem() == 1:
                    self.vehicle_heartbeats.append((t, m.custom_mode, m.base_mode))
                elif direction == "to_target" and kind == "SET_ATTITUDE_TARGET":
                    self.setpoints.append((t, m))
                    self.setpoint_wall_s.append(time.monotonic())
                elif direction == "to_target" and kind != "BAD_DATA":
                    self.other_to_vehicle.append((t, m))

    def start_bridge(self):
        """The bridge, with the process settings `mavastsm connect` applies (runtime_tuning)."""
        return self.pair.start_bridge(process_tuning=True, **self.options)

    # ------------------------------------------------------------ waiting (conditions, bounded)
    def wait_for(self, predicate, timeout_s: float = 30.0, what: str = "condition") -> None:
        assert _wait_for(predicate, timeout_s, 0.005), f"timed out after {timeout_s} s waiting for {what}"

    @property
    def engage_time_s(self) -> float | None:
        s = self.bridge.session if self.bridge else None
        return None if s is None or s.cycle.engage_ms is None else s.cycle.engage_ms / 1000.0

    def wait_engaged(self, timeout_s: float = 60.0) -> float:
        if not _wait_for(lambda: self.engage_time_s is not None, timeout_s, 0.005):
            s = self.bridge.session if self.bridge else None
            vehicle = self.server.call(lambda c: (c.mode_name, c.armed, round(-c.position_ned_m[2], 2), round(c.time_s, 2)))
            pytest.fail(f"bridge did not engage within {timeout_s} s: state {self.bridge.state if self.bridge else None}, "
                        f"end {getattr(s, 'end_reason', None)!r}, failsafe {getattr(s, 'failsafe', None)}, altitude seen "
                        f"{getattr(s, 'altitude_m', None)}; vehicle (mode, armed, alt m, t s) {vehicle}; "
                        f"sim counters {self.server.counters}")
        return self.engage_time_s

    def wait_vehicle_time(self, t_s: float, timeout_s: float = 60.0) -> None:
        self.wait_for(lambda: self.server.sim_time_s >= t_s, timeout_s, f"vehicle time {t_s:.2f} s")

    def finish(self, timeout_s: float = 120.0):
        summary = self.bridge.wait(timeout_s)
        assert summary is not None, f"bridge still running after {timeout_s} s (state {self.bridge.state})"
        return summary

    # ------------------------------------------------------------ analysis of the recorded truth
    def truth_between(self, t0: float, t1: float = float("inf")):
        with self._lock:
            return [row for row in self.truth if t0 <= row[0] <= t1]

    def tracking_errors(self, reference, engage_s: float, t1: float = float("inf")):
        """(t from engagement, e_roll, e_pitch, e_yaw) [s, rad] of the *sim's* attitude vs the reference."""
        out = []
        for t, r, p, y in self.truth_between(engage_s, t1):
            ref = reference.at(t - engage_s)[0]
            out.append((t - engage_s, r - ref[0], p - ref[1], wrap_pi(y - ref[2])))
        return out

    def max_tilt_deg(self, t0: float, t1: float = float("inf")) -> float:
        import math

        rows = self.truth_between(t0, t1)
        return max((math.degrees(max(abs(r), abs(p))) for _, r, p, _ in rows), default=float("nan"))

    def axis_metrics(self, steady_window_s: float = 0.5, settled_after_s: float = 2.5) -> list[dict]:
        """Per axis [roll, pitch, yaw], from the sim's attitude over the engaged run (reference time):
        ``settle_s`` (last exit from the 5 % band after the axis's step, inf if never back in),
        ``overshoot_pct``, ``steady_deg`` (mean |e| over the last ``steady_window_s``), ``max_err_deg``
        and ``worst_after_deg`` (max |e| once every step should have settled, t >= ``settled_after_s``)."""
        import math

        reference = self.bridge.session.cycle.reference
        engage_s = self.engage_time_s
        errors = self.tracking_errors(reference, engage_s, engage_s + self.bridge.duration_s)
        assert errors, "no ATTITUDE recorded while engaged"
        out = []
        for axis in range(3):
            rows = [(t, e[axis]) for t, *e in errors]
            t_end = rows[-1][0]
            steady = [abs(e) for t, e in rows if t >= t_end - steady_window_s]
            m = {"steady_deg": math.degrees(sum(steady) / len(steady)),
                 "max_err_deg": math.degrees(max(abs(e) for _, e in rows)),
                 "worst_after_deg": math.degrees(max((abs(e) for t, e in rows if t >= settled_after_s), default=float("nan")))}
            times, size = reference.event_times_s(axis), reference.step_size_rad(axis)
            if times and size:
                from mavastsm.step_metrics import overshoot_pct, settling_time_s  # the package's one definition

                t, e = [t for t, _ in rows], [e for _, e in rows]
                m["settle_s"] = settling_time_s(t, e, 0.05 * abs(size), times[0])
                m["overshoot_pct"] = overshoot_pct(t, e, size, times[0])
            out.append(m)
        return out

    def setpoints_between(self, t0: float, t1: float = float("inf")):
        with self._lock:
            return [(t, m) for t, m in self.setpoints if t0 <= t <= t1]

    def setpoint_violations(self, limits=None) -> list[str]:
        """Every recorded SET_ATTITUDE_TARGET checked against the packaged limits; list of problems."""
        import math

        lim = limits or BRIDGE_CONFIG.limits
        problems = []
        with self._lock:
            sps = list(self.setpoints)
        for t, m in sps:
            rates = (m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate)
            fields = list(rates) + [m.thrust] + list(m.q)
            why = None
            if m.type_mask not in ACCEPTED_TYPE_MASKS:
                why = f"type_mask {m.type_mask:#x}"
            elif not all(math.isfinite(v) for v in fields):
                why = "non-finite field"
            elif any(abs(w) > mx + 1e-6 for w, mx in zip(rates, lim.max_rate_cmd_rads)):
                why = f"rates {rates} beyond {lim.max_rate_cmd_rads}"
            elif not (lim.thrust_min_norm - 1e-6 <= m.thrust <= lim.thrust_max_norm + 1e-6):
                why = f"thrust {m.thrust}"
            elif m.type_mask == 0x07 and abs(math.sqrt(sum(c * c for c in m.q)) - 1.0) > 1e-3:
                why = f"non-unit quaternion {m.q}"
            elif m.target_system != 1:
                why = f"target_system {m.target_system}"
            if why:
                problems.append(f"t={t:.3f}: {why}")
        return problems


@pytest.fixture
def flight_factory(request):
    """``make(controller=..., scenario=..., reference=..., sim=dict, bridge=dict, overrides=dict,
    to_target=ImpairmentSettings, from_target=ImpairmentSettings, start=True) -> Flight``.

    Everything it starts is stopped at teardown in reverse order, even when the test failed.
    """
    from mavastsm.lockstep_pair import LockstepPair

    made: list[Flight] = []

    def make(controller="astsm", scenario="nominal", reference="paper_steps", sim=None, bridge=None,
             overrides=None, to_target=None, from_target=None, seed=1, start=True) -> Flight:
        over = dict(IN_PROCESS_OVERRIDES, **(overrides or {}))
        options = dict(controller=controller, reference=reference, overrides=over, **dict(BRIDGE_DEFAULTS, **(bridge or {})))
        proxy = dict(to_target=to_target, from_target=from_target)
        pair = LockstepPair(scenario, seed=seed, sim=dict(SIM_DEFAULTS, **(sim or {})), proxy=proxy)
        flight = Flight(pair, options)
        proxy["tap"] = flight.tap
        pair.start()
        made.append(flight)
        if start:
            flight.start_bridge()
        return flight

    try:
        yield make
    finally:
        for flight in reversed(made):
            flight.pair.stop()
            assert flight.server.error is None, f"sim loop died: {flight.server.error!r}"
