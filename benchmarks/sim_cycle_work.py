"""Benchmark: load-independent work of one lockstep cycle of the simulator, in Python opcodes and calls.

Wall and CPU times on the shared 2-vCPU development VM vary by a factor of two from run to run, which hides
changes of 10-20 %. This script counts what CPython executes instead (``sys.settrace`` with opcode events),
which is the same on every run: one 400 Hz lockstep cycle at 1 kHz physics and SCHED_LOOP_RATE 500 = advance
the copter 2.5 ms (``SimulatedCopter.step``), emit what is due (ATTITUDE) and handle one SET_ATTITUDE_TARGET
datagram, in process, without sockets, hovering in GUIDED. Work done in C (pymavlink's struct packing, NumPy,
the CRC, system calls) is not counted, so compare opcode counts only between versions of the Python code, and
time with ``benchmarks/sim_realtime_factor.py``.

Usage: ``python benchmarks/sim_cycle_work.py [--cycles 200] [--package mavastsm_sim] [--json]``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys

os.environ["MAVLINK20"] = "1"

PARTS = ("copter_step", "emit_due", "handle_datagram")


def count_cycle_work(cycles: int = 200, package: str = "mavastsm_sim") -> dict:
    """Mean Python opcodes and calls per lockstep cycle, per part (see module docstring)."""
    from pymavlink import mavutil

    copter_cls = importlib.import_module(f"{package}.copter").SimulatedCopter
    vehicle_cls = importlib.import_module(f"{package}.mavlink_vehicle").MavlinkVehicle
    mavlink = mavutil.mavlink
    copter = copter_cls()
    copter.params.set("SCHED_LOOP_RATE", 500.0)
    sent: list[bytes] = []
    vehicle = vehicle_cls(copter, sent.append)
    peer = mavlink.MAVLink(None, 1, 191)
    for command in ((mavlink.MAV_CMD_DO_SET_MODE, 1, 4), (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1),
                    (mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, 2500)):
        cmd, *p = command
        vehicle.handle_datagram(peer.command_long_encode(1, 1, cmd, 0, *(list(p) + [0] * (7 - len(p)))).pack(peer), 0)
    climb = peer.set_attitude_target_encode(0, 1, 1, 0x80, [1.0, 0, 0, 0], 0.0, 0.0, 0.0, 0.75).pack(peer)
    hold = peer.set_attitude_target_encode(0, 1, 1, 0x80, [1.0, 0, 0, 0], 0.0, 0.0, 0.0, 0.5).pack(peer)
    now_us = 0
    for _ in range(400):  # take off (1 s), not counted
        now_us += 2500
        copter.step(0.0025)
        vehicle.emit_due(now_us)
        vehicle.handle_datagram(climb, now_us)

    totals = {part: {"opcodes": 0, "calls": 0} for part in PARTS}
    current = totals[PARTS[0]]

    def tracer(frame, event, arg):
        if event == "call":
            current["calls"] += 1
            frame.f_trace_opcodes = True
        elif event == "opcode":
            current["opcodes"] += 1
        return tracer

    for _ in range(cycles):
        now_us += 2500
        for part, run in zip(PARTS, (lambda: copter.step(0.0025), lambda: vehicle.emit_due(now_us),
                                     lambda: vehicle.handle_datagram(hold, now_us))):
            current = totals[part]
            sys.settrace(tracer)
            try:
                run()
            finally:
                sys.settrace(None)
        sent.clear()
    out = {f"{part}_{kind}_per_cycle": round(totals[part][kind] / cycles, 1) for part in PARTS
           for kind in ("opcodes", "calls")}
    out["total_opcodes_per_cycle"] = round(sum(t["opcodes"] for t in totals.values()) / cycles, 1)
    out["total_calls_per_cycle"] = round(sum(t["calls"] for t in totals.values()) / cycles, 1)
    out["cycles"] = cycles
    out["package"] = package
    out["python"] = sys.version.split()[0]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=200, help="cycles to count (after a 1 s take-off)")
    parser.add_argument("--package", default="mavastsm_sim", help="simulator package to import (A/B comparisons)")
    parser.add_argument("--json", action="store_true", help="print JSON only")
    args = parser.parse_args(argv)
    if args.cycles < 1:
        parser.error(f"--cycles {args.cycles} must be at least 1")
    result = count_cycle_work(args.cycles, args.package)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:36s} {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
