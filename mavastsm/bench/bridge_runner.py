"""Run our bridge for the benchmark: against the stub vehicle (latency) or the simulator (lockstep speed).

Used by ``bench_clients`` (``bridge`` client process) and ``bench.measure_sim_lockstep``.
"""

from __future__ import annotations

import functools
import math
import os
import threading
import time


def run_bridge_until(url: str, stop: threading.Event, rate_hz: float, dashboard: bool = False,
                     log_dir: str | None = None) -> None:
    """Bridge with ASTSM holding the engage attitude (``hold`` reference) until ``stop`` is set.

    The stub is already armed in GUIDED, so the bridge engages as it would when a pilot hands over
    (no mode or arm request). ``dashboard``: the rich Live dashboard at 10 Hz, drawn as ``connect``
    draws it (its own child process, fed from this one), into /dev/null instead of a terminal; the
    CPU per cycle then counts this process only, not the drawing child. ``log_dir``: the flight's CSV and .tlog
    there, as the README's commands keep them (``--log``).
    """
    from ..bridge import Bridge, BridgeOptions
    from ..runtime_tuning import ProcessTuning
    from ..telemetry import TelemetryBuffer

    telemetry = TelemetryBuffer()
    bridge = Bridge(BridgeOptions(url, controller="astsm", reference="hold", rate_hz=rate_hz,
                                  duration_s=math.inf, engage_timeout_s=60.0, log_dir=log_dir), telemetry)
    runner = None
    devnull = None
    if dashboard:
        from ..dashboard.live_view import DashboardRunner

        devnull = open(os.devnull, "w")
        # as users get it: the Live view drawn by the dashboard's own child process (default isolation)
        runner = DashboardRunner(telemetry, refresh_hz=10.0, plain=False, keys=False, isolation="process",
                                 process_output=devnull, process_size=(140, 45))
        runner.start()
    tuning = ProcessTuning(bridge.config.timing)  # as `mavastsm connect` runs it (runtime_tuning)
    try:
        tuning.apply()
        bridge.start()
        while not stop.wait(0.5):
            tuning.tick(bridge.state == "engaged")
            if bridge.wait(0) is not None:  # the bridge ended by itself (failsafe): say why
                s = bridge.summary
                raise RuntimeError(f"bridge stopped early: {s.end_reason} (failsafe {s.failsafe})")
    finally:
        bridge.stop()
        tuning.restore()
        if runner is not None:
            runner.stop()
        if devnull is not None:
            devnull.close()


def _fly_and_time(bridge_options, sim_seconds: float, control_hz: float) -> tuple[float, float]:
    """Bridge arms, takes off to 2 m and flies the paper steps; (sim s, wall s) while engaged. ``bridge_options``:
    ``(**options) -> BridgeOptions`` for the vehicle (a lockstep pair's, or one with the sim process's URL).

    Simulated time is read from the ATTITUDE ``time_boot_ms`` the bridge receives.
    """
    from ..bridge import Bridge
    from ..runtime_tuning import ProcessTuning

    bridge = Bridge(bridge_options(controller="astsm", reference="paper_steps", rate_hz=control_hz,
                                   duration_s=math.inf, mode="GUIDED", arm=True, takeoff_alt_m=2.0, on_exit="LAND",
                                   overrides={"timing.stale_timeout_s": 1.0}))
    tuning = ProcessTuning(bridge.config.timing).apply()  # as `mavastsm connect` runs it
    bridge.start()
    try:
        deadline = time.monotonic() + 60.0 + sim_seconds * 5
        while bridge.state != "engaged" and time.monotonic() < deadline and bridge.wait(0.01) is None:
            pass
        if bridge.state != "engaged":
            raise RuntimeError(f"bridge never engaged (state {bridge.state})")
        ms0, wall0 = bridge.session.last_ms, time.monotonic()
        while (bridge.session.last_ms - ms0) / 1000.0 < sim_seconds and time.monotonic() < deadline:
            if bridge.wait(0.02) is not None:
                break
        ms1, wall1 = bridge.session.last_ms, time.monotonic()
    finally:
        bridge.stop()
        tuning.restore()
    return (ms1 - ms0) / 1000.0, wall1 - wall0


def run_sim_lockstep(sim_seconds: float, separate_process: bool, control_hz: float = 400.0,
                     physics_hz: float = 1000.0) -> tuple[float, float]:
    """Sim in lockstep (``physics_hz``) + bridge (ASTSM at ``control_hz``): (simulated s, wall s) while engaged.

    ``separate_process`` False: the sim is a ``VehicleServer`` thread in this process (as in ``mavastsm
    demo``); True: ``mavastsm sim --lockstep`` in its own process (as a user runs the two programs).
    Either way they talk MAVLink over loopback UDP, and the lockstep gate waits for every answer.
    """
    sched = max(400.0, control_hz / 0.8)
    if not separate_process:
        from ..lockstep_pair import LockstepPair

        with LockstepPair(sim=dict(physics_rate_hz=physics_hz, lockstep_timeout_s=0.02, sched_loop_rate_hz=sched)) as pair:
            return _fly_and_time(pair.bridge_options, sim_seconds, control_hz)
    import re
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "mavastsm.cli", "sim", "--listen", "127.0.0.1:0", "--lockstep",
           "--lockstep-timeout-ms", "20", "--physics-rate-hz", str(physics_hz), "--set", f"sched_loop_rate_hz={sched}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        first = proc.stdout.readline()  # the sim prints its address first (an empty line if it died)
        m = re.search(r"udp 127\.0\.0\.1:(\d+)", first)
        if not m:
            raise RuntimeError(f"sim did not start: {first.strip() or proc.stdout.read()[-300:]}")
        from ..bridge import BridgeOptions

        return _fly_and_time(functools.partial(BridgeOptions, f"udpout:127.0.0.1:{m.group(1)}"), sim_seconds, control_hz)
    finally:
        if proc.poll() is None:
            proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
