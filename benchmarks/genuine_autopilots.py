"""Fly the paper's steps with every controller on genuine ArduCopter or PX4 SITL and print the table.

    python benchmarks/genuine_autopilots.py --autopilot arducopter                 # $MAVASTSM_ARDUCOPTER
    python benchmarks/genuine_autopilots.py --autopilot px4 --controllers astsm,pid --runs 3
    python benchmarks/genuine_autopilots.py --autopilot sim                        # our Solo, same command
    python benchmarks/genuine_autopilots.py --autopilot arducopter --set mapping.method=integrate --json out.json

One SITL boot (private network namespace; pre-arm wait shortened with SIM_SPEEDUP on ArduCopter),
then for each controller and run the README's command as a subprocess, exactly as a user types it
(plus ``--controller``, ``--log`` and any ``--set``), the flight CSV read back, and every bound of the
control-quality goal computed: 5 % settling, overshoot, steady error, error peak-to-peak over the
last second, share of settled cycles with the rate command at its limit, alpha's recovery. A
ground-station observer on a second link records what the vehicle did (max tilt, min altitude).
The last column is the autopilot's own level hold just before engagement (peak to peak over 1 s, from the
flight's .tlog): the noise floor of that vehicle's attitude. ``--markdown FILE`` writes the table for docs/bridge.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mavastsm.bridge.bridge_config import load_bridge_config  # noqa: E402
from mavastsm.bridge.record.flight_log import read_flight_log  # noqa: E402
from mavastsm.bridge.record.tracking_metrics import flight_metrics  # noqa: E402
from mavastsm.readme_commands import readme_argv  # noqa: E402
from mavastsm.references import load_reference  # noqa: E402
from mavastsm.state_types import FailsafeReason  # noqa: E402
from mavastsm_sim.genuine_observer import OBSERVER_STREAMS, Observer, boot_arducopter, boot_arducopter_solo_physics, boot_px4  # noqa: E402
from mavastsm_sim.genuine_sitl import arducopter_paths, px4_paths, wait_for  # noqa: E402

# the README's command of each vehicle (mavastsm.readme_commands; a flight's own --log comes after it, and wins)
README_COMMANDS = {"arducopter": readme_argv("arducopter"), "arducopter-solo": readme_argv("arducopter"),
                   "sim": readme_argv("sim"), "px4": readme_argv("px4")}


def boot(autopilot: str, path: str | None):
    """Start the vehicle and its observer, as the tests do, and wait until it can be armed."""
    if autopilot == "arducopter":
        v = boot_arducopter(arducopter_paths(path), fast_prearm=True)
        return v.sitl, v.observer
    if autopilot == "arducopter-solo":  # genuine ArduCopter tuned as a Solo, on our Solo physics (JSON SITL)
        v = boot_arducopter_solo_physics(arducopter_paths(path), fast_prearm=True)
        return v.sitl, v.observer
    if autopilot == "px4":
        v = boot_px4(px4_paths(path))
        return v.sitl, v.observer
    sitl = start_inrepo_sim()  # our sim is armable at once
    try:
        ob = Observer(sitl)
        ob.wait_heartbeat(90.0)
        ob.request_streams(OBSERVER_STREAMS)
    except BaseException:
        sitl.stop()
        raise
    return sitl, ob


def start_inrepo_sim():
    """Our simulated Solo (``mavastsm sim``, real time) in a namespace of its own, like the genuine autopilots."""
    import subprocess as sp

    from mavastsm_sim.genuine_sitl import NetNamespace, SitlInstance

    netns = NetNamespace()
    tmp = tempfile.TemporaryDirectory(prefix="mavastsm-sim-")
    log_path = Path(tmp.name) / "sim.log"
    with open(log_path, "wb") as log:
        proc = sp.Popen(netns.command([str(Path(sys.executable).with_name("mavastsm")), "sim", "--listen", "127.0.0.1:14560"]),
                        stdout=log, stderr=sp.STDOUT, stdin=sp.DEVNULL, start_new_session=True)
    return SitlInstance("sim", netns, proc, "udpout:127.0.0.1:14560", "udpout:127.0.0.1:14560", Path(tmp.name), log_path, tmp)


def fly(sitl, ob, autopilot: str, controller: str, sets: list[str], log_dir: Path, timeout_s: float = 180.0) -> dict:
    """One flight with the README's command; returns the row of the table (and the bridge's exit code)."""
    argv = [str(Path(sys.executable).with_name("mavastsm")), *README_COMMANDS[autopilot], "--controller", controller,
            "--log", str(log_dir), "--no-dashboard", "--on-failsafe", "LAND"]
    for s in sets:  # KEY=VALUE for --set, or --OPTION=VALUE passed as it is (e.g. --vehicle=FILE)
        argv += s.split("=", 1) if s.startswith("--") else ["--set", s]
    t0 = time.monotonic()
    p = subprocess.run(sitl.netns.command(argv), capture_output=True, text=True, timeout=timeout_s)
    t1 = time.monotonic()
    row = {"controller": controller, "exit": p.returncode, "max_tilt_deg": ob.max_tilt_deg(t0, t1)}
    try:
        wait_for(lambda: ob.mode_now() is not None and not ob.mode_now()[1], 90.0, "disarmed after the flight", sitl)
    except TimeoutError as exc:
        row["error"] = f"{exc}; bridge said: {p.stdout[-300:]} {p.stderr[-300:]}"
        return row
    csvs = sorted(log_dir.glob("*.csv"))
    if not csvs:
        row["error"] = (p.stderr or p.stdout)[-400:]
        return row
    samples = read_flight_log(csvs[-1])
    cfg = load_bridge_config(None, {"limits": {}})
    metrics = flight_metrics(samples, load_reference("paper_steps"), cfg.limits.max_rate_cmd_rads)
    if metrics is None:
        row["error"] = "never engaged: " + (p.stdout[-400:] or p.stderr[-400:])
        return row
    axes, holds = metrics
    for m, h in zip(axes, holds):
        row[m.axis] = {"t5_s": m.settling_time_5pct_s, "os_pct": m.overshoot_pct, "steady_deg": m.steady_error_deg,
                       "pp_deg": h.hold_pp_deg, "at_limit_pct": h.cmd_at_limit_pct, "alpha_back_s": h.alpha_recovery_s}
    row["end"] = next((ln for ln in p.stdout.splitlines() if ln.startswith("end:")), "")
    tlogs = sorted(log_dir.glob("*.tlog"))
    if tlogs:
        row["own_hold_pp_deg"] = own_hold_pp_deg(tlogs[-1])
    return row


def own_hold_pp_deg(tlog: Path, window_s: float = 1.0) -> list[float] | None:
    """[roll, pitch, yaw] peak to peak [deg] of ATTITUDE over the last ``window_s`` before the bridge's first body-rate
    setpoint (type_mask 0x80), read from the flight's .tlog: the vehicle held level by the autopilot's own attitude
    controller (PX4's takeoff hold in LOITER, ArduCopter's level hold during the bridge's climb). The floor any
    offboard controller's hold is measured against. None when the log has no such window."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tlog))
    att, engaged_at = [], None
    while engaged_at is None:
        msg = log.recv_match(type=["ATTITUDE", "SET_ATTITUDE_TARGET"])
        if msg is None:
            break
        if msg.get_type() == "SET_ATTITUDE_TARGET":
            if msg.type_mask == 0x80:
                engaged_at = msg._timestamp
        else:
            att.append((msg._timestamp, msg.roll, msg.pitch, msg.yaw))
    if engaged_at is None:
        return None
    last = [a for a in att if engaged_at - window_s <= a[0] < engaged_at]
    if len(last) < 10:
        return None
    out = []
    for k in (1, 2, 3):
        vals = [a[k] for a in last]
        if k == 3:  # unwrap the heading
            vals = [vals[0] + math.remainder(v - vals[0], 2.0 * math.pi) for v in vals]
        out.append(math.degrees(max(vals) - min(vals)))
    return out


def fmt(x: float, nd: int = 2) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else ("∞" if x == math.inf else f"{x:.{nd}f}")


VEHICLE_NAMES = {"arducopter": "ArduCopter 4.7 SITL", "arducopter-solo": "ArduCopter 4.7 on Solo physics", "px4": "PX4 1.15 SIH",
                 "sim": "our sim (Solo)"}


def end_label(row: dict) -> str:
    """How the run ended, in a few words: 'complete', or the failsafe that ended it."""
    end = row.get("end", "")
    if "duration complete" in end:
        return "complete"
    text = end.removeprefix("end: ")
    named = next((r.name for r in FailsafeReason if text.startswith(r.value)), "")
    return named or (text.split(";")[0][:40] if text else "—")


def table(rows: list[dict], autopilot: str) -> str:
    """Markdown rows, one per controller and axis; metrics against the raw paper steps."""
    head = ("| vehicle | controller | run | axis | t5% [s] | OS [%] | steady [deg] | p-p last 1 s [deg] | cmd at limit [%] "
            "| α back [s] | max tilt [deg] | autopilot's own hold p-p [deg] |")
    lines = [head, "|" + "---|" * 12]
    name = VEHICLE_NAMES.get(autopilot, autopilot)
    for r in rows:
        if "error" in r:
            lines.append(f"| {name} | {r['controller']} | {r['error'][:60]} ||||||||")
            continue
        for axis in ("roll", "pitch", "yaw"):
            a = r[axis]
            first = axis == "roll"
            lines.append(f"| {name if first else ''} | {r['controller'] if first else ''} | {end_label(r) if first else ''} | {axis} | "
                         f"{fmt(a['t5_s'])} | {fmt(a['os_pct'], 1)} | {fmt(a['steady_deg'])} | {fmt(a['pp_deg'])} | "
                         f"{fmt(a['at_limit_pct'], 1)} | {fmt(a['alpha_back_s'])} | {fmt(r['max_tilt_deg'], 1) if first else ''} | "
                         f"{fmt((r.get('own_hold_pp_deg') or [math.nan] * 3)[('roll', 'pitch', 'yaw').index(axis)])} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--autopilot", choices=sorted(README_COMMANDS), required=True)
    ap.add_argument("--path", default=None, help="SITL binary/folder (default: $MAVASTSM_ARDUCOPTER / $MAVASTSM_PX4)")
    ap.add_argument("--controllers", default="astsm,stsm,smc,atsm,pid", help="comma-separated registry names")
    ap.add_argument("--runs", type=int, default=1, help="flights per controller [-]")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="passed to every flight's --set")
    ap.add_argument("--variant", action="append", default=[], metavar="LABEL=KEY=VALUE;KEY=VALUE",
                    help="fly every controller once more per variant with these extra --set items, or --OPTION=VALUE "
                         "connect options such as --vehicle=FILE (repeatable)")
    ap.add_argument("--json", default=None, metavar="FILE", help="write the rows as JSON")
    ap.add_argument("--markdown", default=None, metavar="FILE", help="write the table as Markdown")
    ap.add_argument("--render", default=None, metavar="FILE.json", help="only print (and --markdown) the table of a saved --json run")
    ap.add_argument("--keep-logs", default=None, metavar="DIR", help="keep every flight's CSV log under DIR (default: a temporary folder, removed)")
    args = ap.parse_args(argv)
    if args.render:
        text = table(json.loads(Path(args.render).read_text()), args.autopilot)
        print(text)
        if args.markdown:
            Path(args.markdown).write_text(text + "\n")
        return 0
    sitl, ob = boot(args.autopilot, args.path)
    rows = []
    try:
        with (contextlib.nullcontext(args.keep_logs) if args.keep_logs else tempfile.TemporaryDirectory(prefix="mavastsm-genuine-")) as tmp:
            variants = [("", [])] + [(v.split("=", 1)[0], v.split("=", 1)[1].split(";")) for v in args.variant]
            for label, extra in variants:
                for c in args.controllers.split(","):
                    for k in range(args.runs):
                        d = Path(tmp) / f"{label or 'default'}-{c}-{k}"
                        d.mkdir(parents=True, exist_ok=True)
                        row = fly(sitl, ob, args.autopilot, c, args.set + extra, d)
                        if label:
                            row["controller"] = f"{c} [{label}]"
                        rows.append(row)
                        print(json.dumps(row), flush=True)
    finally:
        ob.close()
        sitl.stop()
    text = table(rows, args.autopilot)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
