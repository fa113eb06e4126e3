"""``mavastsm sim --autopilot arducopter|px4``: a genuine autopilot's SITL flying the Solo physics.

Composition only. One ``GenuinePair`` per autopilot says what differs:

- ArduCopter: the physics served over ArduPilot's JSON SITL protocol on udp 127.0.0.1:9002 (sim/json_physics.py),
  ArduCopter started with ``--model JSON:127.0.0.1`` and ``--defaults copter.parm,solo.parm``; progress read from its
  pre-arm state on its serial1 link (udp 127.0.0.1:14551).
- PX4: the physics served over PX4's simulator interface on tcp 127.0.0.1:4560 (sim/px4_hil.py, lockstep), PX4
  started as airframe 10016 ``none_iris`` with configs/px4/solo.params; progress until it connects.

Both run in the caller's network namespace, so the bridge connects as to SITL with the README's command
(mavastsm/readme_commands.py); for several pairs on one machine, start each under ``unshare -n``. Ctrl-C / SIGTERM
stop cleanly (the autopilot's process group killed by PID).
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

from mavastsm.errors import ConfigError
from mavastsm.processes import stopping_on_signals
from mavastsm.readme_commands import README_COMMANDS

from .genuine_sitl import (ARDUCOPTER_ENV, PX4_ENV, HostNamespace, SitlUnavailable, arducopter_paths, px4_paths,
                           start_arducopter_on_solo_physics, start_px4_on_solo_physics)
from .json_physics import JSON_SITL_PORT, JsonPhysics
from .px4_hil import PX4_SIMULATOR_PORT, Px4HilPhysics

# options of the in-repo sim that mean nothing for a genuine pair: (attribute, default, option)
SIM_ONLY = (("out", None, "--out"), ("listen", None, "--listen"), ("lockstep", False, "--lockstep"),
            ("signing_key", None, "--signing-key"), ("signing_state", None, "--signing-state"),
            ("home", None, "--home"), ("physics_rate_hz", 1000.0, "--physics-rate-hz"))
PROGRESS_EVERY_S = 2.0


class ArduCopterPrearm:
    """A progress line every 2 s until ArduCopter is armable, read from its serial1 link (udp 127.0.0.1:14551, where
    ArduCopter sends from an ephemeral port and reads replies) by a ``PrearmWatcher``; without that port, none."""

    WATCH_PORT = 14551  # ArduCopter's serial1 udpclient (sim/genuine_sitl.py start_arducopter)
    WHAT = "EKF attitude and origin, GPS lock, gyro and accelerometer consistency"

    def __init__(self, server) -> None:
        from .mavlink_vehicle import PrearmWatcher

        self.physics = server.physics
        self.t0 = time.monotonic()
        self.next_request = self.next_progress = 0.0
        self.peer = None
        self.sock = None
        try:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1", self.WATCH_PORT))
            self.sock.settimeout(0.2)
            self.watcher = PrearmWatcher()
        except OSError as exc:
            self.close()
            self.watcher = None
            print(f"mavastsm sim: no pre-arm progress (udp 127.0.0.1:{self.WATCH_PORT}: {exc})", flush=True)

    def step(self, stop: threading.Event) -> None:
        """Wait at most 0.2 s for ArduCopter's next datagram; say how far the pre-arm checks are, every 2 s."""
        if self.watcher is None:
            stop.wait(0.2)
            return
        try:
            data, self.peer = self.sock.recvfrom(4096)
            self.watcher.handle_datagram(data)
        except OSError:  # timeout: nothing this 0.2 s
            pass
        now = time.monotonic()
        if self.peer is not None and now >= self.next_request:
            self.next_request = now + 1.0
            for frame in self.watcher.requests():
                try:
                    self.sock.sendto(frame, self.peer)
                except OSError:
                    pass
        if self.next_progress is None or now < self.next_progress:
            return
        self.next_progress = now + PROGRESS_EVERY_S
        if self.watcher.armable:
            self.next_progress = None
            print(f"mavastsm sim: ArduCopter is armable after {now - self.t0:.0f} s (physics t={self.physics.time_s:.1f} "
                  f"s); fly with '{README_COMMANDS['arducopter']}'", flush=True)
        else:
            state = "pre-arm checks" if self.watcher.heard else "first HEARTBEAT"
            why = f"; {self.watcher.last_prearm_text}" if self.watcher.last_prearm_text else ""
            print(f"mavastsm sim: waiting for ArduCopter's {state} ({self.WHAT}; usually 20-25 s): {now - self.t0:.0f} s, "
                  f"physics t={self.physics.time_s:.1f} s{why}", flush=True)

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()


class Px4Connection:
    """A progress line every 2 s until PX4 connects to the simulator interface, then one saying it did."""

    def __init__(self, server) -> None:
        self.server = server
        self.t0 = time.monotonic()
        self.next_progress = 0.0

    def step(self, stop: threading.Event) -> None:
        now = time.monotonic()
        if self.next_progress is not None and now >= self.next_progress:
            if self.server.connected.is_set():
                print(f"mavastsm sim: PX4 connected after {now - self.t0:.0f} s and runs on our sensor clock; its "
                      "estimator has an attitude about 2 s of physics time later", flush=True)
                self.next_progress = None
            else:
                self.next_progress = now + PROGRESS_EVERY_S
                print(f"mavastsm sim: waiting for PX4 to connect to tcp 127.0.0.1:{PX4_SIMULATOR_PORT}: "
                      f"{now - self.t0:.0f} s", flush=True)
        stop.wait(0.2)

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class GenuinePair:
    """What one genuine autopilot's pair needs to be started, shown and stopped (the rest is ``run_pair``)."""

    name: str  # as the autopilot calls itself
    option: str  # the --autopilot value, the PATH option's name and the README command's key
    env: str  # the environment variable with its build's path
    paths: Callable  # (option value or None) -> build, SitlUnavailable naming the rule
    physics: type  # the physics class, built from --vehicle-config, --scenario, --seed, --noise
    start: Callable  # (build, physics, speedup) -> SitlInstance in the caller's namespace
    build_what: str  # what the PATH option must name
    port: str  # where the physics server listens for the autopilot
    interface: str  # how the physics reaches the autopilot, for the banner
    own_settings: str  # why the in-repo sim's own options mean nothing here
    tuning: str  # the parameter file the autopilot flies with
    ground_station: str  # where a ground station connects beside the bridge, for the banner ("" when nowhere)
    gcs_port: int  # where the autopilot's GCS link sends MAVLink
    progress: Callable  # (physics server) -> ArduCopterPrearm | Px4Connection
    counters: Callable  # (physics server) -> (name, summary) of what the end line counts


PAIRS = {pair.option: pair for pair in (
    GenuinePair(
        name="ArduCopter", option="arducopter", env=ARDUCOPTER_ENV, paths=arducopter_paths, physics=JsonPhysics,
        start=lambda build, physics, speedup: start_arducopter_on_solo_physics(*build, physics, speedup=speedup,
                                                                                netns=HostNamespace()),
        build_what="executable arducopter (the SITL binary or its folder)", port=f"udp 127.0.0.1:{JSON_SITL_PORT}",
        interface="ArduPilot's JSON SITL",
        own_settings="ArduCopter sets its own rates, home and links; the physics step is 1/SIM_RATE_HZ",
        tuning="configs/arducopter/solo.parm", ground_station="tcp 127.0.0.1:5763", gcs_port=14550,
        progress=ArduCopterPrearm, counters=lambda server: ("JSON frames", server.physics.counters.summary())),
    GenuinePair(
        name="PX4", option="px4", env=PX4_ENV, paths=px4_paths, physics=Px4HilPhysics,
        start=lambda build, physics, speedup: start_px4_on_solo_physics(*build, physics, speed=speedup,
                                                                         netns=HostNamespace()),
        build_what="bin/px4 (executable) and etc/ (PX4's build folder)", port=f"tcp 127.0.0.1:{PX4_SIMULATOR_PORT}",
        interface="PX4's lockstep simulator interface",
        own_settings="PX4 sets its own rates and links; the physics steps with its 250 Hz sensors",
        tuning="configs/px4/solo.params", ground_station="", gcs_port=14540,
        progress=Px4Connection, counters=lambda server: ("lockstep", server.counters.summary())),
)}


def run_pair(args: argparse.Namespace) -> int:
    """Run the genuine autopilot ``args.autopilot`` + the Solo physics until Ctrl-C, SIGTERM, --duration-s of physics
    time, or the autopilot exits. 0 on a clean stop, 1 if the autopilot or the physics loop died, 2 for a build
    that is not there (one line on stderr); ConfigError for an option that does not apply or a port in use."""
    pair = PAIRS[args.autopilot]
    for attr, default, option in SIM_ONLY:
        if getattr(args, attr, default) != default:
            raise ConfigError(f"{option} applies to the in-repo sim only, not to --autopilot {pair.option} "
                              f"({pair.own_settings})")
    given = getattr(args, pair.option, None)
    try:
        build = pair.paths(given)
    except SitlUnavailable as exc:
        text = f"--{pair.option} {given}: no {pair.build_what} there" if given else f"{exc}; set {pair.env} or pass --{pair.option} PATH"
        print(f"mavastsm sim: error: {text}", file=sys.stderr)
        return 2
    physics = pair.physics(vehicle_config=args.vehicle_config, scenario=args.scenario, seed=args.seed, noise=args.noise)
    try:
        sitl = pair.start(build, physics, args.speedup)
    except OSError as exc:
        raise ConfigError(f"cannot open {pair.port} for {pair.interface}: {exc}") from None
    server = sitl.companions[0]
    stop = threading.Event()
    with stopping_on_signals(stop.set):  # before the banner: a supervisor may signal as soon as it reads it
        print(f"mavastsm sim: genuine {pair.name} ({build[0]}) with {pair.tuning}"
              + (f" (a ground station: {pair.ground_station})" if pair.ground_station else "") + " flying the Solo physics "
              f"({pair.interface} on {pair.port}, speed-up x{args.speedup:g}" + (f", scenario {args.scenario}" if args.scenario else "")
              + (", sensor noise" if args.noise else ", exact sensors") + f"); MAVLink to udp 127.0.0.1:{pair.gcs_port}: "
              f"connect with '{README_COMMANDS[pair.option]}'", flush=True)
        progress = pair.progress(server)
        try:
            rc = _supervise(args, pair, sitl, server, progress, stop)
        finally:
            progress.close()
            sitl.stop()
    what, summary = pair.counters(server)
    print(f"mavastsm sim: stopped at t={physics.time_s:.1f} s of physics time; {what}: {summary}", flush=True)
    if server.error is not None:
        print(f"mavastsm sim: error: physics loop failed: {server.error!r}", file=sys.stderr)
        return 1
    return rc


def _supervise(args, pair: GenuinePair, sitl, server, progress, stop: threading.Event) -> int:
    """Progress until the autopilot can fly, then wait for a stop condition: 0, or 1 if the autopilot or the physics
    loop died."""
    while not stop.is_set():
        if not sitl.alive():
            print(f"mavastsm sim: error: {pair.name} exited (status {sitl.proc.returncode}):\n{sitl.log_tail(20)}",
                  file=sys.stderr)
            return 1
        if server.error is not None:
            return 1
        if args.duration_s is not None and server.physics.time_s >= args.duration_s:
            return 0
        progress.step(stop)
    return 0
