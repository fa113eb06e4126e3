"""Capture real dashboard frames from a bridge + simulated Solo run (for docs/dashboard.md).

    python tests/dashboard/make_screenshot.py --out out/dashboard --at 1.4 2.3 4.8

Starts the simulated Solo (real time, separate process) and the bridge (GUIDED_NOGPS, arm, 1 m
takeoff, paper_steps reference, ASTSM 400 Hz preset), and at each requested time into the
reference renders the dashboard view of the live telemetry snapshot with a fixed-size recording
console: ``frame-<t>s-<W>x<H>.txt`` (plain text) and ``.svg`` (colour). Not a test (no assertions).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

from rich.console import Console

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.dashboard.panels import build_view
from mavastsm.telemetry import TelemetryBuffer


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/dashboard"))
    parser.add_argument("--at", type=float, nargs="+", default=[1.4, 2.3, 4.8], help="[s] times into the reference")
    parser.add_argument("--size", default="120x40,80x24", help="comma-separated WxH list")
    parser.add_argument("--controller-config", default="astsm_400hz")
    parser.add_argument("--reference", default="paper_steps")
    args = parser.parse_args()
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.size.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)

    sim = subprocess.Popen([sys.executable, "-m", "mavastsm_sim", "--listen", "127.0.0.1:0", "--set", "sched_loop_rate_hz=1000"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        port = int(re.search(r"on udp 127\.0\.0\.1:(\d+)", sim.stdout.readline()).group(1))
        telemetry = TelemetryBuffer()
        bridge = Bridge(BridgeOptions(f"udpout:127.0.0.1:{port}", controller="astsm",
                                      controller_config=args.controller_config, reference=args.reference,
                                      rate_hz=400.0, mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=1.0,
                                      on_exit="LAND", on_failsafe="LAND", log_dir=args.out / "logs",
                                      print_fn=print), telemetry)
        bridge.start()
        gate = threading.Event()
        pending = sorted(args.at)
        while pending and bridge.wait(0.0) is None:
            snap = telemetry.snapshot()
            start = snap.session.reference_start_vehicle_time_s
            if snap.latest is not None and math.isfinite(start) and snap.latest.vehicle_time_s - start >= pending[0]:
                t = pending.pop(0)
                for width, height in sizes:
                    console = Console(width=width, height=height, record=True, file=open(os.devnull, "w"),
                                      force_terminal=True, color_system="truecolor", legacy_windows=False)
                    console.print(build_view(snap, width, height))
                    stem = args.out / f"frame-{t:.1f}s-{width}x{height}"
                    Path(f"{stem}.svg").write_text(console.export_svg(title="mavastsm connect", clear=False),
                                                        encoding="utf-8")
                    Path(f"{stem}.txt").write_text(console.export_text(), encoding="utf-8")
                    console.file.close()
                    print(f"saved {stem}.txt/.svg")
            gate.wait(0.01)
        summary = bridge.stop(15.0)
        if summary is not None:
            print(summary.format())
    finally:
        if sim.poll() is None:
            os.killpg(sim.pid, signal.SIGTERM)
            sim.wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
