"""Render ``docs/testing.md`` from the JSON the SITL suite writes at the end of a run.

Usage (from the repo root)::

    python -m pytest tests/sitl            # writes out/sitl/results.json
    python tests/sitl/render_testing_doc.py out/sitl/results.json docs/testing.md

Every number in the generated page comes from the results file: each SITL test records the fault
it injected, the reaction it expects and what it measured (reaction times, worst attitude
deviation, counters). Nothing here is typed by hand except the page's fixed prose.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HEADER = """# Loopback SITL test suite (`tests/sitl`)

The suite runs the real bridge (`mavastsm.bridge.Bridge`, and `mavastsm connect` as a subprocess)
against the real simulated Solo (`mavastsm_sim.VehicleServer`, and `mavastsm sim` as a subprocess)
over UDP on 127.0.0.1 ephemeral ports, mostly in **lockstep** (the sim steps only when the bridge
has answered each ATTITUDE, or after a bounded wall-clock wait), with the in-repo impairment proxy
(`mavastsm proxy`, `sim/impairment_proxy.py`) placed between them to inject faults. Randomness is
seeded. Run it with:

```
python -m pytest tests/sitl -q                    # writes out/sitl/results.json
python tests/sitl/render_testing_doc.py out/sitl/results.json docs/testing.md
```

The same relay is a command for manual experiments (real-time clock; `--help` lists every option
with units):

```
mavastsm sim --listen 127.0.0.1:14560 &
mavastsm proxy --listen 127.0.0.1:14570 --target 127.0.0.1:14560 --loss 0.2 --delay-ms 20 --jitter-ms 5 --seed 1 &
mavastsm connect udpout:127.0.0.1:14570 --mode GUIDED --arm --takeoff 1
```

Python: `ImpairmentProxy(target, listen=("127.0.0.1", 0), to_target=ImpairmentSettings(...),
from_target=..., seed=0, clock="wall"|"vehicle", lockstep_fill=False, tap=None)`, `.start()`,
`.configure(direction="both", **changes)` at runtime, `.counters(direction)`, `.inject(direction, bytes)`,
`.stop()` (context manager); bursty loss with `ImpairmentSettings.bursty(mean_loss, mean_burst_len)`.

Angles in degrees, times in seconds of **vehicle (sim) time** unless marked "wall". Delays injected
by the proxy are on the vehicle clock (`clock="vehicle"`: each datagram is stamped with the latest
ATTITUDE time seen and released by a later datagram in the same direction once the vehicle clock has
advanced by the delay), so a 20 ms delay is exactly 8 control periods at 400 Hz however loaded the
machine is.
"""


METHOD_NOTES = """## How faults are injected and measured

- **Where**: every in-process run puts the impairment proxy between bridge and sim; its tap records
  every ATTITUDE the sim sent and every SET_ATTITUDE_TARGET the bridge sent *before* any fault. Tracking
  metrics are computed from the sim's own attitude against the bridge's reference, and every recorded
  setpoint is checked against the packaged limits (finite; |p|,|q| <= 3.5 rad/s, |r| <= 2 rad/s;
  thrust in [0, 0.8]; type_mask 0x80, 0x07 (unit quaternion) or 0x87; target system 1).
- **Lockstep fill**: a lost or held-back ATTITUDE / SET_ATTITUDE_TARGET is replaced by a copy of the
  last command delivered (the autopilot keeps its last target), so the lockstep gate never waits out its
  timeout and the bridge's host-clock timers see the fault, not the gate. Outages are not filled.
- **Host-clock detectors**: in-process, sim, proxy and bridge share one GIL, so stale ATTITUDE is
  0.5 s (packaged 0.1 s) and loop-overrun detection is off; the subprocess runs (lockstep) use the same
  two settings. A real-time 400 Hz sim on this loaded 2-core machine (load average 6-7) delivered
  ATTITUDE in 50 ms bursts at 198-240 Hz and the bridge rightly tripped STALE_ATTITUDE, so real time
  is used only where a 4 Hz stream makes lockstep meaningless (the MAVProxy test).
- **Faults switched mid-flight**: link faults start at the first controlled cycle and last to the end
  of the 5 s paper-steps run (roll -10 deg at 0.5 s, pitch +10 deg at 1.0 s, yaw +45 deg at 2.0 s).
- "settle" = last exit from the 5 % band after the axis's step (inf = still outside at the end);
  "worst after settling" = largest roll/pitch error from 2.5 s on.
"""

# Hand-maintained (not generated): what the suite does not assert, and why. Keep it honest.
KNOWN_GAPS = [
    "Disturbance (0.5 N m step on all three axes at t = 4 s) is recorded, not asserted stable: over MAVLink "
    "every controller, the ArduCopter-style PID included, loses the vehicle within ~0.3 s and the envelope "
    "failsafe trips (max tilt 64-68 deg once the level hold is the autopilot's to fly). The yaw error "
    "runs to 180 deg first: 0.5 N m about yaw exceeds the simulated Solo's yaw authority at hover, "
    "yaw_torque_per_thrust x (weight - 4 x idle thrust) = 0.016 m x (14.7 - 0.6) N = 0.23 N m "
    "(configs/bridge.yaml torque_authority_nm), a motor limit the paper's torque-level model does not have. "
    "The suite asserts that the failsafe trips within 2 samples of the breach and that no controller "
    "setpoint follows it.",
    "Total outage: the bridge's level hold cannot reach the vehicle, which keeps flying the last body-rate "
    "command (ArduCopter integrates it into its attitude target) until GUID_TIMEOUT (3 s) levels it; the "
    "tilt reached in that window is the max_tilt_deg of the outage row. A shorter GUID_TIMEOUT bounds it.",
    "Re-engagement after a restarted vehicle on the ground: the bridge (with `reengage`) waits for GUIDED + "
    "armed and re-engages with reset gains (tested), but it does not take the landed vehicle off again, so "
    "after re-engagement only the control stream resuming is asserted, not tracking in flight.",
    "Vehicle restarts whose clock step back and HEARTBEAT gap are both under 3 s go unnoticed for up to 3 s "
    "(the new vehicle's samples are dropped as out of order until its clock passes the old one); unit-tested "
    "detection covers the longer cases.",
]


def _fmt(value) -> str:
    if isinstance(value, float):
        if value != value:
            return "n/a"
        return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
    if isinstance(value, dict):
        return ", ".join(f"{k} {_fmt(v)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def _table(rows: list[dict], columns: list[tuple[str, str]]) -> list[str]:
    out = ["| " + " | ".join(title for title, _ in columns) + " |", "|" + "---|" * len(columns)]
    for r in rows:
        out.append("| " + " | ".join(_fmt(r.get(key, "")).replace("|", "/") for _, key in columns) + " |")
    return out


def render(results: dict) -> str:
    lines = [HEADER]
    run = results.get("run", {})
    if run:
        lines.append(f"Generated from a run on {run.get('finished_utc', '?')}: {run.get('passed', 0)} passed, "
                     f"{run.get('failed', 0)} failed, wall time {_fmt(run.get('duration_wall_s', float('nan')))} s "
                     f"(python {run.get('python', '?')}, {run.get('cpus', '?')} CPUs, shared machine: timings are noisy).\n")
    entries = results.get("entries", [])
    scenarios = [e for e in entries if e.get("category") == "scenario"]
    faults = [e for e in entries if e.get("category") == "fault"]
    others = [e for e in entries if e.get("category") not in ("scenario", "fault")]
    if scenarios:
        lines.append("## Scenarios over MAVLink (lockstep, 400 Hz ATTITUDE)\n")
        lines.append("Asserted for ASTSM on the nominal run (issue 4): completes without failsafe; roll/pitch inside "
                     "a 5 % band within 1.5 s of their steps, 45 deg yaw within 2.5 s, overshoot < 10 %, steady error "
                     "< 0.5 deg on every axis. Every run, every controller: no setpoint outside the limits ever sent, and an "
                     "envelope breach trips the failsafe within 2 samples with no controller setpoint after it. "
                     "Settling/overshoot/steady error are computed from the sim's attitude; steady_deg and "
                     "max_err_deg are [roll, pitch, yaw].\n")
        keys: list[str] = []
        for e in scenarios:
            for k in e.get("measured", {}):
                if k not in keys:
                    keys.append(k)
        rows = [dict(name=e["name"], outcome=e.get("outcome", "?"), **e.get("measured", {})) for e in scenarios]
        lines += _table(rows, [("run", "name"), ("test", "outcome")] + [(k, k) for k in keys])
        lines.append("")
    for title, group in (("Faults", faults), ("Other checks", others)):
        if not group:
            continue
        lines.append(f"## {title}\n")
        rows = [dict(name=e["name"], expected=e.get("expected", ""), measured=e.get("measured", {}),
                     outcome=e.get("outcome", "?")) for e in group]
        lines += _table(rows, [("fault / check", "name"), ("expected reaction", "expected"),
                               ("measured", "measured"), ("test", "outcome")])
        lines.append("")
    lines.append(METHOD_NOTES)
    lines.append("## Not asserted / not covered (hand-maintained)\n")
    lines += [f"- {m}" for m in KNOWN_GAPS + list(results.get("missing", []))]
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    src = Path(argv[1]) if len(argv) > 1 else Path("out/sitl/results.json")
    dst = Path(argv[2]) if len(argv) > 2 else Path("docs/testing.md")
    try:
        results = json.loads(src.read_text())
    except (OSError, ValueError) as exc:
        print(f"render_testing_doc: cannot read {src}: {exc}", file=sys.stderr)
        return 2
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_text(render(results))
    print(f"wrote {dst} from {src} ({len(results.get('entries', []))} entries)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
