"""Benchmark: real-time factor of the MAVLink simulator in lockstep with 1 kHz physics.

A minimal pymavlink peer (a stand-in for the bridge, in a separate process by default) switches the vehicle
to GUIDED, arms, requests ATTITUDE at 400 Hz and answers every ATTITUDE with a SET_ATTITUDE_TARGET (rates +
climb-rate thrust: take off, then hover). The simulator advances only when answered, so

    real-time factor = simulated seconds (from time_boot_ms) / wall seconds of the same span.

It also reports the CPU time of the simulator process (``cpu_bound_real_time_factor`` = simulated seconds
per CPU second of the simulator process, start-up and handshake included), the CPU time of the simulation
thread alone per simulated second over the lockstep span (``sim_thread_cpu_ms_per_sim_s``: the issue-3
budget is about 40 ms) and the cost of ``SimulatedCopter.step`` alone at the same physics rate, to show how
time splits between physics and the MAVLink/UDP side (CPU figures: best of three runs). ``--peer-kind lean``
swaps ``mavutil.mavlink_connection``/``recv_match`` for a raw socket plus pymavlink's own pack/parse, so less
of each cycle's wall time is the peer's. ``--peer-law`` makes the peer also compute the package's law on every
ATTITUDE (``mavastsm.bench.clients.law_on_attitude``: tracking error and ASTSM, not flown): the ceiling of lockstep with
any bridge that flies that law. Prints numbers; asserts nothing (the target is >= 20x on one core).
On a shared, loaded machine the numbers are noisy: run it several times.

Usage: ``python benchmarks/sim_realtime_factor.py [--sim-s 20] [--attitude-hz 400] [--physics-rate-hz 1000]
[--peer process|thread] [--peer-kind mavutil|lean] [--peer-law] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import time

os.environ["MAVLINK20"] = "1"


def _answer_every_attitude(next_attitude, mav, sim_s: float, with_law: bool = False):
    """Answer each ATTITUDE (``next_attitude()``, None after a timeout) with a SET_ATTITUDE_TARGET through ``mav``
    (zero body rates, climb-rate thrust: take off, then hover) for ``sim_s`` simulated seconds; ``with_law``: compute
    the package's law on each ATTITUDE first (its torque is not flown). Returns (simulated s, wall s, ATTITUDEs
    answered), or None when the stream stopped."""
    law = None
    if with_law:
        from mavastsm.bench.clients import law_on_attitude

        law = law_on_attitude()
    first = None
    n = 0
    while True:
        att = next_attitude()
        if att is None:
            return None
        if first is None:
            first = (att.time_boot_ms, time.perf_counter())
        elapsed_sim_s = (att.time_boot_ms - first[0]) / 1000.0
        if law is not None:
            law(att)
        thrust = 0.75 if elapsed_sim_s < 2.0 else 0.5  # climb ~1.25 m/s for 2 s, then hold altitude
        mav.set_attitude_target_send(att.time_boot_ms, 1, 1, 0x80, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, thrust)
        n += 1
        if elapsed_sim_s >= sim_s:
            return elapsed_sim_s, time.perf_counter() - first[1], n


def _peer(port: int, sim_s: float, attitude_hz: float, result_queue, with_law: bool = False) -> None:
    """The lockstep controller stand-in: returns (sim_s, wall_s, n_attitude) through ``result_queue``."""
    from pymavlink import mavutil

    mavlink = mavutil.mavlink
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=191)
    try:
        conn.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        conn.recv_match(type="HEARTBEAT", blocking=True, timeout=10)

        def command(cmd, *p):
            p = list(p) + [0.0] * (7 - len(p))
            conn.mav.command_long_send(1, 1, cmd, 0, *p)
            conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5, condition=f"COMMAND_ACK.command=={cmd}")

        command(mavlink.MAV_CMD_DO_SET_MODE, 1, 4)
        command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 1e6 / attitude_hz)
        result_queue.put(_answer_every_attitude(lambda: conn.recv_match(type="ATTITUDE", blocking=True, timeout=5), conn.mav, sim_s,
                                                with_law))
    finally:
        conn.close()


class _LeanLink:
    """The least a pymavlink peer needs: one connected UDP socket and a ``MAVLink`` object (pack, parse).
    No ``mavutil`` bookkeeping per message, so the wall time of a cycle is mostly the simulator's."""

    def __init__(self, port: int) -> None:
        import socket

        from pymavlink import mavutil

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(0.25)  # blocking receive; the deadline is re-checked at least every 0.25 s
        self.mav = mavutil.mavlink.MAVLink(self, srcSystem=1, srcComponent=191)
        self.mav.robust_parsing = True
        self.pending: list = []

    def write(self, frame: bytes) -> None:  # MAVLink.send writes each packed frame here
        self.sock.send(frame)

    def recv_type(self, msg_type: str, timeout_s: float, accept=lambda m: True):
        """Next message of ``msg_type`` for which ``accept(msg)`` holds, or None after ``timeout_s`` [wall s]."""
        deadline = time.monotonic() + timeout_s
        while True:
            while self.pending:
                msg = self.pending.pop(0)
                if msg.get_type() == msg_type and accept(msg):
                    return msg
            if time.monotonic() >= deadline:
                return None
            try:
                data = self.sock.recv(65535)
            except OSError:  # timeout (or ICMP refusal): loop re-checks the deadline
                continue
            self.pending.extend(self.mav.parse_buffer(data) or [])

    def close(self) -> None:
        self.sock.close()


def _lean_peer(port: int, sim_s: float, attitude_hz: float, result_queue, with_law: bool = False) -> None:
    """Same exchange as :func:`_peer` over :class:`_LeanLink` (raw socket + pymavlink pack/parse)."""
    from pymavlink import mavutil

    mavlink = mavutil.mavlink
    link = _LeanLink(port)
    mav = link.mav
    try:
        mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        link.recv_type("HEARTBEAT", 10)
        for cmd, *p in ((mavlink.MAV_CMD_DO_SET_MODE, 1, 4), (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1),
                        (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 1e6 / attitude_hz)):
            mav.command_long_send(1, 1, cmd, 0, *(list(p) + [0.0] * (7 - len(p))))
            link.recv_type("COMMAND_ACK", 5, lambda m, cmd=cmd: m.command == cmd)
        result_queue.put(_answer_every_attitude(lambda: link.recv_type("ATTITUDE", 5), mav, sim_s, with_law))
    finally:
        link.close()


PEERS = {"mavutil": _peer, "lean": _lean_peer}


def _get_result(queue, peer_alive, timeout_s: float):
    """Wait for the peer's result, failing fast if the peer died."""
    import queue as queue_module

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            return queue.get(timeout=0.5)
        except queue_module.Empty:
            if not peer_alive():
                raise RuntimeError("the benchmark peer exited without a result") from None
    raise RuntimeError(f"no result from the benchmark peer within {timeout_s:.0f} s")


def measure_copter_step_cost(physics_rate_hz: float = 1000.0, sim_s: float = 5.0,
                             clock=time.perf_counter) -> float:
    """Cost of ``SimulatedCopter.step`` alone per simulated second, hovering in GUIDED [s/s] (wall time by
    default; pass ``clock=time.process_time`` for CPU time)."""
    from mavastsm_sim.copter import SimulatedCopter

    copter = SimulatedCopter(physics_rate_hz=physics_rate_hz)
    copter.set_mode(4)
    copter.arm()
    dt = 1.0 / 400.0
    for _ in range(int(1.0 / dt)):  # take off first (not timed)
        copter.handle_attitude_target(0x80, [1.0, 0, 0, 0], (0.0, 0.0, 0.0), 0.75)
        copter.step(dt)
    t0 = clock()
    for _ in range(int(sim_s / dt)):
        copter.handle_attitude_target(0x80, [1.0, 0, 0, 0], (0.0, 0.0, 0.0), 0.5)
        copter.step(dt)
    return (clock() - t0) / sim_s


def measure_mavlink_cycle_cost(cycles: int = 4000) -> float:
    """In-process CPU cost of the MAVLink side of one lockstep cycle, without sockets [s]: emit one ATTITUDE
    (encode + pack) and handle one SET_ATTITUDE_TARGET datagram (parse + dispatch into the copter)."""
    from pymavlink import mavutil

    from mavastsm_sim.copter import SimulatedCopter
    from mavastsm_sim.mavlink_vehicle import MavlinkVehicle

    sent: list[bytes] = []
    vehicle = MavlinkVehicle(SimulatedCopter(), sent.append)
    vehicle.handle_datagram(mavutil.mavlink.MAVLink(None, 1, 191).command_long_encode(
        1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 30, 2500, 0, 0, 0, 0, 0).pack(
        mavutil.mavlink.MAVLink(None, 1, 191)), 0)
    peer = mavutil.mavlink.MAVLink(None, 1, 191)
    answer = peer.set_attitude_target_encode(0, 1, 1, 0x80, [1.0, 0, 0, 0], 0.1, 0.0, 0.0, 0.5).pack(peer)
    t0 = time.process_time()
    for k in range(1, cycles + 1):
        vehicle.emit_due(k * 2500)
        vehicle.handle_datagram(answer, k * 2500)
    return (time.process_time() - t0) / cycles


def measure_lockstep_real_time_factor(sim_s: float = 20.0, attitude_hz: float = 400.0,
                                      physics_rate_hz: float = 1000.0, peer: str = "process",
                                      sched_loop_rate_hz: float = 500.0, peer_kind: str = "mavutil",
                                      peer_law: bool = False) -> dict:
    """Run the simulator in lockstep against a minimal pymavlink peer; returns a dict of measurements.

    Keys: ``sim_s``, ``wall_s``, ``real_time_factor``, ``attitude_messages``, ``achieved_attitude_hz``,
    ``lockstep_timeouts``, ``copter_step_wall_s_per_sim_s``, ``physics_only_real_time_factor``, ``peer``,
    ``sim_thread_cpu_ms_per_sim_s`` (CPU of the simulation thread per simulated second, lockstep span only),
    ``copter_step_cpu_ms_per_sim_s`` and ``mavlink_cpu_us_per_cycle_no_sockets`` (best of three).
    ``sched_loop_rate_hz`` defaults to 500 Hz because ArduCopter's 400 Hz loop caps streams at 320 Hz.
    ``peer_kind``: "mavutil" (``mavutil.mavlink_connection`` + ``recv_match``, like a typical script) or
    "lean" (a raw socket + pymavlink's ``MAVLink`` pack/parse: less peer time in each cycle). ``peer_law``: the peer
    also computes the package's law on every ATTITUDE.
    """
    from mavastsm_sim.vehicle_server import VehicleServer

    with VehicleServer(clock="lockstep", physics_rate_hz=physics_rate_hz, listen=("127.0.0.1", 0),
                       sched_loop_rate_hz=sched_loop_rate_hz) as server:
        cpu0 = time.process_time()
        span = {}

        def lockstep_started(_copter) -> bool:  # (called by wait_until under the simulation lock)
            if not span and server.vehicle.attitude_targets_received > 0:
                span["thread_cpu_s"], span["sim_s"] = server.loop_cpu_s, server.sim_time_s
            return bool(span)

        if peer == "process":
            ctx = multiprocessing.get_context("spawn")
            queue = ctx.Queue()
            proc = ctx.Process(target=PEERS[peer_kind], args=(server.port, sim_s, attitude_hz, queue, peer_law),
                               daemon=True)
            proc.start()
            try:
                server.wait_until(lockstep_started, timeout_s=60.0)
                result = _get_result(queue, lambda: proc.is_alive(), sim_s * 10 + 60)
            finally:
                proc.join(10)
                if proc.is_alive():
                    proc.kill()
        else:
            import queue as queue_module
            import threading

            queue = queue_module.Queue()
            thread = threading.Thread(target=PEERS[peer_kind], args=(server.port, sim_s, attitude_hz, queue, peer_law),
                                      daemon=True)
            thread.start()
            server.wait_until(lockstep_started, timeout_s=60.0)
            result = _get_result(queue, thread.is_alive, sim_s * 10 + 60)
            thread.join(10)
        sim_cpu_s = time.process_time() - cpu0  # this process: the simulator (+ the peer when it is a thread)
        thread_cpu_end_s, sim_end_s = server.loop_cpu_s, server.sim_time_s
        counters = server.counters
        altitude_m = server.call(lambda c: -float(c.position_ned_m[2]))
    if result is None:
        raise RuntimeError("the peer stopped receiving ATTITUDE")
    sim_elapsed, wall_elapsed, n = result
    thread_ms_per_sim_s = None
    if span.get("thread_cpu_s") is not None and thread_cpu_end_s is not None and sim_end_s > span["sim_s"]:
        thread_ms_per_sim_s = (thread_cpu_end_s - span["thread_cpu_s"]) / (sim_end_s - span["sim_s"]) * 1e3
    step_cost = measure_copter_step_cost(physics_rate_hz)
    step_cpu = min(measure_copter_step_cost(physics_rate_hz, 3.0, time.process_time) for _ in range(3))
    cycle_cost = min(measure_mavlink_cycle_cost() for _ in range(3))
    return {
        "peer": peer, "peer_kind": peer_kind, "peer_law": peer_law, "physics_rate_hz": physics_rate_hz,
        "sched_loop_rate_hz": sched_loop_rate_hz,
        "attitude_hz_requested": attitude_hz,
        "sim_s": round(sim_elapsed, 3), "wall_s": round(wall_elapsed, 3),
        "real_time_factor": round(sim_elapsed / wall_elapsed, 2),
        "sim_process_cpu_s": round(sim_cpu_s, 3),
        "cpu_bound_real_time_factor": round(sim_elapsed / sim_cpu_s, 2),
        "sim_thread_cpu_ms_per_sim_s": None if thread_ms_per_sim_s is None else round(thread_ms_per_sim_s, 1),
        "attitude_messages": n, "achieved_attitude_hz": round((n - 1) / sim_elapsed, 1),
        "lockstep_timeouts": counters["lockstep_timeouts"], "final_altitude_m": round(altitude_m, 2),
        "copter_step_wall_s_per_sim_s": round(step_cost, 4),
        "copter_step_cpu_ms_per_sim_s": round(step_cpu * 1e3, 1),
        "mavlink_cpu_us_per_cycle_no_sockets": round(cycle_cost * 1e6, 1),
        "physics_only_real_time_factor": round(1.0 / step_cost, 1),
        "machine": f"{platform.machine()} {platform.python_implementation()} {platform.python_version()}, "
                   f"{os.cpu_count()} CPUs, load avg {os.getloadavg()[0]:.1f}",
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sim-s", type=float, default=20.0, help="simulated seconds to run [s]")
    parser.add_argument("--attitude-hz", type=float, default=400.0, help="ATTITUDE rate the peer answers [Hz]")
    parser.add_argument("--physics-rate-hz", type=float, default=1000.0, help="physics rate [Hz]")
    parser.add_argument("--sched-loop-rate-hz", type=float, default=500.0,
                        help="SCHED_LOOP_RATE [Hz]; streams are capped at 80 %% of it")
    parser.add_argument("--peer", choices=("process", "thread"), default="process",
                        help="run the peer in a separate process (like a real bridge) or a thread")
    parser.add_argument("--peer-kind", choices=tuple(PEERS), default="mavutil",
                        help="mavutil: mavlink_connection + recv_match; lean: raw socket + pymavlink pack/parse")
    parser.add_argument("--peer-law", action="store_true",
                        help="the peer also computes the package's law (tracking error + ASTSM) on every ATTITUDE")
    parser.add_argument("--json", action="store_true", help="print JSON only")
    args = parser.parse_args(argv)
    result = measure_lockstep_real_time_factor(args.sim_s, args.attitude_hz, args.physics_rate_hz, args.peer,
                                               args.sched_loop_rate_hz, args.peer_kind, args.peer_law)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:32s} {value}")
        verdict = "meets" if result["real_time_factor"] >= 20.0 else "MISSES"
        print(f"lockstep real-time factor {result['real_time_factor']}x {verdict} the >= 20x target")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
