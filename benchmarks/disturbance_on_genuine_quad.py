"""Torque pulses on genuine ArduCopter SITL's own physics: the README command through the bridge against ArduCopter alone.

    python benchmarks/disturbance_on_genuine_quad.py                       # stock quad, the bridge's defaults
    python benchmarks/disturbance_on_genuine_quad.py --set mapping.roll_pitch_command_base=measured
    python benchmarks/disturbance_on_genuine_quad.py --model hexa --pulses roll:12:1,yaw:3:1 --no-alone

Each flight takes off to 2 m and holds level (the bridge: the README command plus ``--reference hold``; ArduCopter
alone: attitude targets, sim/genuine_disturbance.fly_alone), then each pulse (``AXIS:RAD_S2:SECONDS``) is applied
through SIM_TWIST (sim/genuine_disturbance.py) 5 s apart. Printed per pulse: the peak excursion, the time back
within 0.5 deg after the pulse's end, and how the flight ended (a failsafe names itself). MAVASTSM_ARDUCOPTER
names the build. Genuine SITL runs in real time: about 1.5 min per flight."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

from mavastsm.readme_commands import readme_argv
from mavastsm_sim.genuine_disturbance import deviation, fly_alone, twist
from mavastsm_sim.genuine_observer import boot_arducopter
from mavastsm_sim.genuine_sitl import arducopter_paths

DEFAULT_PULSES = "roll:10:1,roll:20:1,pitch:20:1,yaw:4:1"
SETTLE_S, GAP_S = 4.0, 5.0


def parse_pulses(text: str) -> list[tuple[str, float, float]]:
    out = []
    for item in text.split(","):
        axis, accel, dur = item.split(":")
        out.append((axis, float(accel), float(dur)))
    return out


def fly_bridge(vehicle, pulses, sets=(), log_dir: Path | None = None) -> dict:
    """The README command + ``--reference hold`` for as long as the pulses need; the pulses applied once engaged."""
    duration = SETTLE_S + sum(d + GAP_S + 1.0 for _, _, d in pulses) + 5.0  # 1 s a pulse for setting it
    argv = [str(Path(sys.executable).with_name("mavastsm")), *readme_argv("arducopter"), "--no-dashboard", "--reference", "hold",
            "--duration", f"{duration:g}"]
    for s in sets:
        argv += ["--set", s]
    if log_dir is not None:
        argv += ["--log", str(log_dir)]
    proc = subprocess.Popen(vehicle.sitl.netns.command(argv), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            stdin=subprocess.DEVNULL, bufsize=1)
    lines: list[str] = []
    engaged = threading.Event()

    def read():
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if re.match(r"^t=\d", line):
                engaged.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    results = []
    try:
        if not engaged.wait(150.0):
            raise RuntimeError("bridge never engaged:\n" + "\n".join(lines[-30:]))
        time.sleep(SETTLE_S)
        for axis, accel, dur in pulses:
            if proc.poll() is not None or any(ln.startswith("end:") for ln in lines):
                break
            p = twist(vehicle.observer, axis, accel, dur)
            time.sleep(dur + GAP_S)
            results.append(deviation(vehicle.observer, p, after_s=GAP_S))
        rc = proc.wait(120.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        reader.join(5.0)
    out = "\n".join(lines)
    failsafes = sorted(set(re.findall(r"\| failsafe (?!none)(\S+)", out)))
    end = next((ln for ln in reversed(lines) if ln.startswith("end:")), lines[-1] if lines else "")
    vehicle.wait_disarmed(90.0)
    return {"pulses": results, "rc": rc, "failsafes": failsafes, "end": end}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="quad", help="ArduPilot SITL frame model (quad, hexa, octa, ...)")
    ap.add_argument("--pulses", default=DEFAULT_PULSES, help="AXIS:RAD_S2:SECONDS,... (default %(default)s)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="passed to the bridge")
    ap.add_argument("--defaults", action="append", default=[], metavar="PARM", help="extra ArduCopter defaults file")
    ap.add_argument("--no-alone", action="store_true", help="skip ArduCopter alone")
    ap.add_argument("--no-bridge", action="store_true", help="skip the bridge")
    ap.add_argument("--repeat", type=int, default=1, help="bridge flights per vehicle boot")
    ap.add_argument("--json", default=None, help="write the rows here")
    ap.add_argument("--log", default=None, help="bridge flight logs here")
    args = ap.parse_args(argv)
    pulses = parse_pulses(args.pulses)
    rows = []
    with boot_arducopter(arducopter_paths(), fast_prearm=True, model=args.model, extra_defaults=[Path(p) for p in args.defaults]) as v:
        if not args.no_alone:
            rows.append({"flight": "ArduCopter alone", "pulses": fly_alone(v, pulses, settle_s=SETTLE_S, gap_s=GAP_S)})
            print(json.dumps(rows[-1]), flush=True)
        for _ in range(0 if args.no_bridge else args.repeat):
            log_dir = Path(args.log) if args.log else None
            rows.append({"flight": "bridge " + " ".join(args.set), **fly_bridge(v, pulses, args.set, log_dir)})
            print(json.dumps(rows[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
