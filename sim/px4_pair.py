"""``mavastsm sim --autopilot px4``: genuine PX4 SITL flying the Solo physics (sim/px4_hil.py).

Composition only: the simulator server on tcp 127.0.0.1:4560, PX4 started as airframe 10016 ``none_iris`` with
configs/px4/solo.params (it connects to the server and runs in lockstep with it), and a clean stop on Ctrl-C /
SIGTERM (PX4's process group killed by PID). Both run in the caller's network namespace, so the bridge connects as
to PX4 SITL: ``mavastsm connect udpin:0.0.0.0:14540`` (for several pairs on one machine, start each under ``unshare -n``).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

from mavastsm.errors import ConfigError
from mavastsm.processes import stopping_on_signals

from .arducopter_pair import SIM_ONLY
from .genuine_sitl import PX4_ENV, HostNamespace, SitlUnavailable, px4_paths, start_px4_on_solo_physics
from .px4_hil import PX4_SIMULATOR_PORT, Px4HilPhysics

BRIDGE_URL = "udpin:0.0.0.0:14540"
README_COMMAND = f"mavastsm connect {BRIDGE_URL} --mode OFFBOARD --arm --takeoff 5 --on-exit LAND"


def run_px4_pair(args: argparse.Namespace) -> int:
    """Run PX4 + the Solo physics until Ctrl-C, SIGTERM, --duration-s of physics time, or PX4 exits."""
    for attr, default, option in SIM_ONLY:
        if getattr(args, attr, default) != default:
            raise ConfigError(f"{option} applies to the in-repo sim only, not to --autopilot px4 "
                              "(PX4 sets its own rates and links; the physics steps with its 250 Hz sensors)")
    try:
        build = px4_paths(args.px4)
    except SitlUnavailable as exc:
        text = f"{exc}" if args.px4 else f"{exc}; set {PX4_ENV} or pass --px4 PATH"
        print(f"mavastsm sim: error: {text}", file=sys.stderr)
        return 2
    physics = Px4HilPhysics(vehicle_config=args.vehicle_config, scenario=args.scenario, seed=args.seed, noise=args.noise)
    try:
        sitl = start_px4_on_solo_physics(*build, physics, speed=args.speedup, netns=HostNamespace())
    except OSError as exc:
        raise ConfigError(f"cannot open tcp 127.0.0.1:{PX4_SIMULATOR_PORT} for PX4's simulator interface: {exc}") from None
    server = sitl.companions[0]
    stop = threading.Event()
    with stopping_on_signals(stop.set):  # before the banner: a supervisor may signal as soon as it reads it
        print(f"mavastsm sim: genuine PX4 ({build[0]}) with configs/px4/solo.params flying the Solo physics (simulator "
              f"interface on tcp 127.0.0.1:{PX4_SIMULATOR_PORT}, lockstep x{args.speedup:g}"
              + (f", scenario {args.scenario}" if args.scenario else "") + (", sensor noise" if args.noise else ", exact sensors")
              + f"); MAVLink to udp 127.0.0.1:14540: connect with '{README_COMMAND}'", flush=True)
        try:
            rc = _supervise(args, sitl, server, stop)
        finally:
            sitl.stop()
    print(f"mavastsm sim: stopped at t={physics.time_s:.1f} s of physics time; lockstep: {server.counters.summary()}", flush=True)
    if server.error is not None:
        print(f"mavastsm sim: error: simulator loop failed: {server.error!r}", file=sys.stderr)
        return 1
    return rc


def _supervise(args, sitl, server, stop: threading.Event) -> int:
    """Say when PX4 connects (progress every 2 s until then), then wait for a stop condition; 1 if PX4 or the loop died."""
    t0 = time.monotonic()
    next_progress = 0.0
    physics = server.physics
    while not stop.is_set():
        if not sitl.alive():
            print(f"mavastsm sim: error: PX4 exited (status {sitl.proc.returncode}):\n{sitl.log_tail(20)}", file=sys.stderr)
            return 1
        if server.error is not None:
            return 1
        if args.duration_s is not None and physics.time_s >= args.duration_s:
            return 0
        now = time.monotonic()
        if next_progress is not None and now >= next_progress:
            if server.connected.is_set():
                print(f"mavastsm sim: PX4 connected after {now - t0:.0f} s and runs on our sensor clock; its estimator "
                      "has an attitude about 2 s of physics time later", flush=True)
                next_progress = None
            else:
                next_progress = now + 2.0
                print(f"mavastsm sim: waiting for PX4 to connect to tcp 127.0.0.1:{PX4_SIMULATOR_PORT}: {now - t0:.0f} s",
                      flush=True)
        stop.wait(0.2)
    return 0
