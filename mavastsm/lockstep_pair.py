"""One lockstep pair: the simulated Solo and the offboard bridge flying it over loopback MAVLink.

The one harness the demo, the sweep's MAVLink level, the bench, the benchmarks and the SITL tests start a flight
with (none of them writes it again):

* the sim (``mavastsm_sim.VehicleServer``) on its own ephemeral loopback port, clock ``lockstep`` (after each
  ATTITUDE it waits for the bridge's answer, so a loaded machine slows the flight down instead of changing it);
* optionally the impairment proxy (``mavastsm_sim.impairment_proxy``) between them, on its own port;
* the scenario's disturbance clock parked (``DisturbanceModel.park``) until the bridge engages, and started at the
  engagement sample itself, from the bridge's reader thread (``BridgeOptions.on_engage``) while the sim still waits
  for the answer to that sample: the disturbance times count from the reference start, on the vehicle clock, however
  late the host schedules anyone;
* the bridge (``mavastsm.bridge.Bridge``) connected with ``udpout:127.0.0.1:PORT`` exactly as to SITL, optionally
  with the process settings ``mavastsm connect`` applies (``runtime_tuning.ProcessTuning``);
* without a proxy, the bridge and the sim take turns on the vehicle clock (``mavastsm.lockstep_turns``): the
  vehicle moves only while the bridge's reader has handled all it was sent and its start-up thread and supervisor
  wait for the vehicle, so each command, each pre-stream, rate, arming and takeoff wait, and the hand-back land on
  the same sample whatever the machine load, and a seeded flight is a function of its inputs. (Through the proxy, whose relay thread is not part of the turns, only the ATTITUDE /
  SET_ATTITUDE_TARGET lockstep holds.) The bridge must then be built from :meth:`bridge_options`: the sim waits
  for that bridge.

    with LockstepPair(scenario="disturbance_roll", seed=1) as pair:
        bridge = pair.start_bridge(mode="GUIDED", arm=True, takeoff_alt_m=0.5)
        summary = pair.wait(300.0)

``stop()`` (also on leaving the ``with``) stops the bridge, the proxy and the sim, in that order, even after a failure.
"""

from __future__ import annotations

from typing import Any, Callable

#: [s] longest wall wait of the lockstep sim for the bridge's answer to one ATTITUDE, unless told otherwise
LOCKSTEP_TIMEOUT_S = 0.05
#: Bridge overrides for a pair in one process (tests, sweep). Sim, proxy and bridge share one GIL and, in lockstep,
#: the sim waits for every answer, so host scheduling delays cannot hurt the plant; two host-clock detectors would
#: then only measure how busy the machine is: loop overrun (host latency > one period for 40 cycles) is off and the
#: stale-ATTITUDE timeout (host time) is 0.5 s. The SITL suite measures the stale reaction against the value
#: configured, and its subprocess tests run the packaged defaults in real time. ``prestream_s`` 0: ArduCopter needs
#: no setpoint stream before GUIDED (PX4 does).
IN_PROCESS_OVERRIDES = {"timing.overrun_cycles": 100000, "timing.stale_timeout_s": 0.5, "timing.prestream_s": 0.0}


class LockstepPair:
    """A lockstep sim (+ impairment proxy) on ephemeral loopback ports and the bridge flying it.

    Parameters
    ----------
    scenario : scenario name, YAML path or ``Scenario`` for the sim (its torques start at engagement), or None
    seed : the sim's seed (sensor noise) and the proxy's (impairment draws)
    sim : extra ``VehicleServer`` keyword arguments (``physics_rate_hz``, ``sched_loop_rate_hz``, ``noise``,
        ``lockstep_paced``, ``speedup``, ``lockstep_timeout_s`` ...)
    proxy : ``ImpairmentProxy`` keyword arguments (``to_target``, ``from_target``, ``tap``) to put one in the middle,
        or None for none
    on_engage : called with the engagement's vehicle time [s] right after the disturbance clock started (reader
        thread; e.g. the sweep turns the link's faults on there)
    """

    def __init__(self, scenario: Any = None, *, seed: int = 0, sim: dict | None = None, proxy: dict | None = None,
                 on_engage: Callable[[float], None] | None = None) -> None:
        from mavastsm_sim.vehicle_server import VehicleServer

        options = {"clock": "lockstep", "lockstep_timeout_s": LOCKSTEP_TIMEOUT_S, **(sim or {})}
        self.server = VehicleServer(scenario=scenario, seed=seed, listen=("127.0.0.1", 0), **options)
        self.server.copter.disturbances.park()
        self.turns = None
        if proxy is None and options["clock"] == "lockstep":  # the bridge and the sim take turns on the vehicle clock
            from .lockstep_turns import LockstepTurns

            self.turns = self.server.turns = LockstepTurns()
        self.seed = seed
        self._proxy_options = proxy
        self._on_engage = on_engage
        self.proxy = None
        self.bridge = None
        self.tuning = None
        self.engage_time_s: float | None = None  # [s] vehicle time of the first engagement

    # ------------------------------------------------------------------ start
    def start(self) -> "LockstepPair":
        """Start the sim (and the proxy) thread(s); the bridge comes with :meth:`start_bridge`."""
        self.server.start()
        if self._proxy_options is not None and self.proxy is None:
            from mavastsm_sim.impairment_proxy import ImpairmentProxy

            try:
                self.proxy = ImpairmentProxy(("127.0.0.1", self.server.port), clock="vehicle", seed=self.seed,
                                             lockstep_fill=self.server.clock.mode == "lockstep", **self._proxy_options)
                self.proxy.start()
            except BaseException:
                self.stop()
                raise
        return self

    @property
    def url(self) -> str:
        """The link URL the bridge connects with (the proxy's port when there is one, else the sim's)."""
        port = self.proxy.listen_address[1] if self.proxy is not None else self.server.port
        return f"udpout:127.0.0.1:{port}"

    def bridge_options(self, **options):
        """``BridgeOptions`` for this pair: its URL and its engagement hook, plus ``options``."""
        from .bridge import BridgeOptions

        return BridgeOptions(self.url, on_engage=self._engaged, lockstep_turns=self.turns, **options)

    def start_bridge(self, telemetry=None, process_tuning: bool = False, **options):
        """Build the bridge with :meth:`bridge_options` and start it (connect, preflight, mode/arm/takeoff as told);
        ``process_tuning``: apply the process settings ``mavastsm connect`` runs with (restored by :meth:`stop`).
        Raises what ``Bridge.start`` raises; the pair then still needs :meth:`stop`."""
        from .bridge import Bridge
        from .runtime_tuning import ProcessTuning

        self.bridge = Bridge(self.bridge_options(**options), telemetry)
        if process_tuning:
            self.tuning = ProcessTuning(self.bridge.config.timing).apply()
        self.bridge.start()
        return self.bridge

    def _engaged(self, vehicle_time_s: float) -> None:
        """The bridge's engagement sample (reader thread, the sim waiting for its answer): start the disturbances."""
        if self.engage_time_s is not None:
            return  # a re-engagement (--reengage) keeps the scenario's clock running
        self.engage_time_s = vehicle_time_s
        self.server.call(lambda copter: copter.disturbances.restart_clock(vehicle_time_s))
        if self._on_engage is not None:
            self._on_engage(vehicle_time_s)

    # ------------------------------------------------------------------ run and stop
    def wait(self, timeout_s: float | None = None):
        """The bridge's summary once its run ended, or None after ``timeout_s`` [s] of wall time."""
        return self.bridge.wait(timeout_s)

    def stop(self, bridge_timeout_s: float = 15.0) -> None:
        """Stop the bridge (level hold, hand-back as its options say), the proxy and the sim; idempotent."""
        try:
            if self.bridge is not None and self.bridge.summary is None and self.bridge.session is not None:
                self.bridge.stop(timeout_s=bridge_timeout_s)
        finally:
            if self.tuning is not None:
                self.tuning.restore()
                self.tuning = None
            if self.proxy is not None:
                self.proxy.stop()
            if self.turns is not None:
                self.turns.close()
            self.server.stop()

    def __enter__(self) -> "LockstepPair":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
