"""``mavastsm sim --autopilot arducopter``: genuine ArduCopter SITL flying the Solo physics (sim/json_physics.py).

Composition only: the physics server on udp 127.0.0.1:9002, ArduCopter started with ``--model JSON:127.0.0.1`` and
``--defaults copter.parm,solo.parm``, a pre-arm watcher on ArduCopter's serial1 link (udp 127.0.0.1:14551) for
the progress line, and a clean stop on Ctrl-C / SIGTERM (ArduCopter's process group killed by PID). Both run in
the caller's network namespace, so the bridge connects as to SITL: ``mavastsm connect udpin:0.0.0.0:14550``
(for several pairs on one machine, start each under ``unshare -n``).
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
import time

from mavastsm.errors import ConfigError
from mavastsm.processes import stopping_on_signals

from .genuine_sitl import ARDUCOPTER_ENV, HostNamespace, SitlUnavailable, arducopter_paths, start_arducopter_on_solo_physics
from .json_physics import JSON_SITL_PORT, JsonPhysics

BRIDGE_URL = "udpin:0.0.0.0:14550"
WATCH_PORT = 14551  # ArduCopter's serial1 udpclient (sim/genuine_sitl.py start_arducopter)
PREARM_WHAT = "EKF attitude and origin, GPS lock, gyro and accelerometer consistency"
# options of the in-repo sim that mean nothing for the genuine pair: (attribute, default, option)
SIM_ONLY = (("out", None, "--out"), ("listen", None, "--listen"), ("lockstep", False, "--lockstep"),
            ("signing_key", None, "--signing-key"), ("signing_state", None, "--signing-state"),
            ("home", None, "--home"), ("physics_rate_hz", 1000.0, "--physics-rate-hz"))


def _check_options(args: argparse.Namespace) -> None:
    for attr, default, option in SIM_ONLY:
        if getattr(args, attr, default) != default:
            raise ConfigError(f"{option} applies to the in-repo sim only, not to --autopilot arducopter "
                              "(ArduCopter sets its own rates, home and links; the physics step is 1/SIM_RATE_HZ)")


def run_pair(args: argparse.Namespace) -> int:
    """Run ArduCopter + the Solo physics until Ctrl-C, SIGTERM, --duration-s of physics time, or ArduCopter exits."""
    _check_options(args)
    try:
        build = arducopter_paths(args.arducopter)
    except SitlUnavailable as exc:
        text = (f"--arducopter {args.arducopter}: no executable arducopter there (the SITL binary or its folder)"
                if args.arducopter else f"{exc}; set {ARDUCOPTER_ENV} or pass --arducopter PATH")
        print(f"mavastsm sim: error: {text}", file=sys.stderr)
        return 2
    physics = JsonPhysics(vehicle_config=args.vehicle_config, scenario=args.scenario, seed=args.seed, noise=args.noise)
    try:
        sitl = start_arducopter_on_solo_physics(*build, physics, speedup=args.speedup, netns=HostNamespace())
    except OSError as exc:
        raise ConfigError(f"cannot open udp 127.0.0.1:{JSON_SITL_PORT} for the JSON physics: {exc}") from None
    stop = threading.Event()
    with stopping_on_signals(stop.set):  # before the banner: a supervisor may signal as soon as it reads it
        physics_server = sitl.companions[0]
        print(f"mavastsm sim: genuine ArduCopter ({build[0]}) with configs/arducopter/solo.parm flying the Solo physics "
              f"(JSON SITL on udp 127.0.0.1:{JSON_SITL_PORT}"
              + (f", scenario {args.scenario}" if args.scenario else "") + (", sensor noise" if args.noise else "")
              + f"); MAVLink to udp 127.0.0.1:14550: connect with 'mavastsm connect {BRIDGE_URL} --mode GUIDED_NOGPS "
              "--arm --takeoff 2 --on-exit LAND' (a ground station: tcp 127.0.0.1:5763)", flush=True)
        rc = 0
        watcher = sock = None
        try:
            try:
                from .mavlink_vehicle import PrearmWatcher

                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                sock.bind(("127.0.0.1", WATCH_PORT))
                sock.settimeout(0.2)
                watcher = PrearmWatcher()
            except OSError as exc:
                print(f"mavastsm sim: no pre-arm progress (udp 127.0.0.1:{WATCH_PORT}: {exc})", flush=True)
            rc = _supervise(args, sitl, physics_server, watcher, sock, stop)
        finally:
            if sock is not None:
                sock.close()
            sitl.stop()
    print(f"mavastsm sim: stopped at t={physics.time_s:.1f} s of physics time; JSON frames: "
          f"{physics.counters.summary()}", flush=True)
    if physics_server.error is not None:
        print(f"mavastsm sim: error: physics loop failed: {physics_server.error!r}", file=sys.stderr)
        return 1
    return rc


def _supervise(args, sitl, physics_server, watcher, sock, stop: threading.Event) -> int:
    """The wait loop: a progress line every 2 s until ArduCopter is armable, then wait for a stop condition.
    0, or 1 if ArduCopter or the physics loop died."""
    t0 = time.monotonic()
    next_request = next_progress = 0.0
    armable_reported = False
    peer = None  # ArduCopter's serial1 sends from an ephemeral port and reads replies there
    physics = physics_server.physics
    while not stop.is_set():
        if not sitl.alive():
            print(f"mavastsm sim: error: ArduCopter exited (status {sitl.proc.returncode}):\n{sitl.log_tail(20)}",
                  file=sys.stderr)
            return 1
        if physics_server.error is not None:
            return 1
        if args.duration_s is not None and physics.time_s >= args.duration_s:
            return 0
        if watcher is None:
            stop.wait(0.2)
            continue
        try:
            data, peer = sock.recvfrom(4096)
            watcher.handle_datagram(data)
        except OSError:  # timeout: nothing this 0.2 s
            pass
        now = time.monotonic()
        if peer is not None and now >= next_request:
            next_request = now + 1.0
            for frame in watcher.requests():
                try:
                    sock.sendto(frame, peer)
                except OSError:
                    pass
        if not armable_reported and now >= next_progress:
            next_progress = now + 2.0
            if watcher.armable:
                armable_reported = True
                print(f"mavastsm sim: ArduCopter is armable after {now - t0:.0f} s (physics t={physics.time_s:.1f} s); "
                      f"fly with 'mavastsm connect {BRIDGE_URL} ...'", flush=True)
            else:
                state = "pre-arm checks" if watcher.heard else "first HEARTBEAT"
                why = f"; {watcher.last_prearm_text}" if watcher.last_prearm_text else ""
                print(f"mavastsm sim: waiting for ArduCopter's {state} ({PREARM_WHAT}; usually 20-25 s): "
                      f"{now - t0:.0f} s, physics t={physics.time_s:.1f} s{why}", flush=True)
    return 0
