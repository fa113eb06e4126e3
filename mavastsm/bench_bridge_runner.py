"""Run our bridge for the benchmark: against the stub vehicle (latency) or the simulator (lockstep speed).

Used by ``bench_clients`` (``bridge`` client process) and ``bench.measure_sim_lockstep``.
"""

from __future__ import annotations

import math
import os
import threading
import time


def run_bridge_until(url: str, stop: threading.Event, rate_hz: float, dashboard: bool = False) -> None:
    """Bridge with ASTSM holding the engage attitude (``hold`` reference) until ``stop`` is set.

    The stub is already armed in GUIDED, so the bridge engages as it would when a pilot hands over
    (no mode or arm request). ``dashboard``: the rich dashboard renders at 10 Hz into /dev/null in
    this process, so its CPU and GIL cost land on the control loop exactly as on a terminal.
    """
    from .bridge import Bridge, BridgeOptions
    from .telemetry import TelemetryBuffer

    telemetry = TelemetryBuffer()
    bridge = Bridge(BridgeOptions(url, controller="astsm", reference="hold", rate_hz=rate_hz,
                                  duration_s=math.inf, engage_timeout_s=60.0), telemetry)
    runner = None
    devnull = None
    if dashboard:
        from rich.console import Console

        from .dashboard.live_view import DashboardRunner

        devnull = open(os.devnull, "w")
        console = Console(file=devnull, force_terminal=True, width=140, height=45, color_system="truecolor")
        runner = DashboardRunner(telemetry, refresh_hz=10.0, plain=False, console=console)
        runner.start()
    try:
        bridge.start()
        while not stop.wait(0.5):
            if bridge.wait(0) is not None:  # the bridge ended by itself (failsafe): say why
                s = bridge.summary
                raise RuntimeError(f"bridge stopped early: {s.end_reason} (failsafe {s.failsafe})")
    finally:
        bridge.stop()
        if runner is not None:
            runner.stop()
        if devnull is not None:
            devnull.close()


def run_sim_lockstep(sim_seconds: float, control_hz: float = 400.0, physics_hz: float = 1000.0) -> tuple[float, float]:
    """Sim (lockstep clock, ``physics_hz``) + bridge (ASTSM, ``control_hz``) flying the paper steps.

    Returns (simulated seconds, wall seconds) measured while the bridge is engaged: the sim's
    real-time factor in lockstep with a real MAVLink controller. Sim and bridge share this process
    (sim thread + bridge threads), as in the integration tests.
    """
    from mavastsm_sim.vehicle_server import VehicleServer

    from .bridge import Bridge, BridgeOptions

    with VehicleServer(clock="lockstep", physics_rate_hz=physics_hz, listen=("127.0.0.1", 0),
                       sched_loop_rate_hz=max(400.0, control_hz / 0.8)) as server:
        bridge = Bridge(BridgeOptions(f"udpout:127.0.0.1:{server.port}", controller="astsm", reference="paper_steps",
                                      rate_hz=control_hz, duration_s=math.inf, mode="GUIDED", arm=True,
                                      takeoff_alt_m=2.0, on_exit="LAND"))
        bridge.start()
        try:
            deadline = time.monotonic() + 60.0 + sim_seconds * 5
            while bridge.state != "engaged" and time.monotonic() < deadline:
                time.sleep(0.01)
            if bridge.state != "engaged":
                raise RuntimeError(f"bridge never engaged (state {bridge.state})")
            sim0, wall0 = server.sim_time_s, time.monotonic()
            while server.sim_time_s - sim0 < sim_seconds and time.monotonic() < deadline:
                if bridge.wait(0.05) is not None:
                    break
            sim1, wall1 = server.sim_time_s, time.monotonic()
        finally:
            bridge.stop()
    return sim1 - sim0, wall1 - wall0
