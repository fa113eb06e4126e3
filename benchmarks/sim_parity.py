"""Closed-loop parity: the same bridge command against our emulated ArduCopter + Solo and genuine ArduCopter + Solo.

    python benchmarks/sim_parity.py                                  # $MAVASTSM_ARDUCOPTER
    python benchmarks/sim_parity.py --keep-logs /tmp/parity          # keep both sides' flight CSVs
    python benchmarks/sim_parity.py --genuine-logs /tmp/parity       # re-fly only our sim against saved genuine CSVs
    python benchmarks/sim_parity.py --sim-logs /tmp/before --genuine-logs /tmp/parity   # compare two saved runs
    python benchmarks/sim_parity.py --json docs/results/sim_parity.json --markdown out.md

Flights (each the README's command, ``mavastsm connect URL --mode GUIDED_NOGPS --arm --takeoff 2 --on-exit LAND``
with ``--controller`` and ``--duration-s``, as a subprocess): the paper steps with astsm and with pid, and astsm
under the paper's 0.5 N m roll torque from 4 s of the profile (``disturbance_roll``, 7 s). Side (a) is
``mavastsm sim``'s vehicle (``VehicleServer``, real time, the vehicle YAML's ArduCopter parameters) in a private
network namespace, by default with sim profile ``arducopter-4.7-sitl-armable`` (every habit measured on genuine 4.7
SITL but its 25 s start-up: the 400 Hz ATTITUDE request denied, 333 Hz on loop ticks, as the genuine side sends it;
``--sim-profile arducopter-4.5-quick`` flies the sim's default, 4.5.7 and evenly spaced 320 Hz); side (b) is genuine ArduCopter 4.7 SITL with configs/arducopter/solo.parm on the same Solo
physics over the JSON SITL protocol (one boot for all flights). The torque is added to the physics for the
disturbance flight only and started at the bridge's engagement on both sides (``paper_on_genuine.DisturbanceAligner``).

Parity per flight and axis, from the flight CSVs (errors against the raw reference, ``tracking_metrics``):
5 % settling within +-15 % of genuine's, overshoot within +-3 points, RMS difference of the attitude traces
aligned on engagement time <= 0.5 deg (our sim's trace interpolated onto genuine's ATTITUDE times over the
common span), and the same verdict on a limit cycle (``limit_cycle``: a sustained oscillation in the last 1.5 s).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paper_on_genuine as pg  # noqa: E402  (sets up the repository paths)

from mavastsm.bridge.record.flight_log import read_flight_log  # noqa: E402
from mavastsm.scenarios import load_scenario  # noqa: E402
from mavastsm_sim.genuine_observer import boot_arducopter_solo_physics  # noqa: E402
from mavastsm_sim.genuine_sitl import NetNamespace, arducopter_paths, wait_for  # noqa: E402

FLIGHTS = (("astsm", "nominal"), ("pid", "nominal"), ("astsm", "disturbance_roll"))
SIM_PORT = 14560  # README_COMMANDS["sim"]: udpout:127.0.0.1:14560
PARITY_PROFILE = "arducopter-4.7-sitl-armable"  # configs/sim_profiles: genuine 4.7 SITL's habits, armable at once
GOAL = {"t5_rel": 0.15, "os_pts": 3.0, "rms_deg": 0.5}
LIMIT_CYCLE_WINDOW_S = 1.5
LIMIT_CYCLE_MIN_PP_DEG = 0.3  # [deg] smaller oscillations are not counted as a limit cycle
LIMIT_CYCLE_MIN_HZ = 2.0  # [Hz] slower wander is not a limit cycle


# ---------------------------------------------------------------------- pure parts
def limit_cycle(trace, axis: int, window_s: float = LIMIT_CYCLE_WINDOW_S) -> dict:
    """Is there a sustained oscillation on ``axis`` over the last ``window_s`` of an error trace
    [(t [s], (e_r, e_p, e_y) [rad])]? The error minus its straight-line trend must swing by at least
    LIMIT_CYCLE_MIN_PP_DEG with zero crossings at least as often as a LIMIT_CYCLE_MIN_HZ sine (2 per period).
    Returns {"cycle": bool, "pp_deg", "hz"} (hz from the crossings)."""
    if not trace:
        return {"cycle": False, "pp_deg": float("nan"), "hz": float("nan")}
    t_end = trace[-1][0]
    rows = [(t, e[axis]) for t, e in trace if t >= t_end - window_s]
    if len(rows) < 8:
        return {"cycle": False, "pp_deg": float("nan"), "hz": float("nan")}
    t = np.array([r[0] for r in rows])
    e = np.degrees(np.array([r[1] for r in rows]))
    resid = e - np.polyval(np.polyfit(t, e, 1), t)
    pp = float(resid.max() - resid.min())
    crossings = int(np.count_nonzero(np.signbit(resid[1:]) != np.signbit(resid[:-1])))
    hz = crossings / 2.0 / max(t[-1] - t[0], 1e-9)
    return {"cycle": bool(pp >= LIMIT_CYCLE_MIN_PP_DEG and hz >= LIMIT_CYCLE_MIN_HZ), "pp_deg": pp, "hz": hz}


def trace_rms_difference_deg(trace_a, trace_b, axis: int, reference=None) -> float:
    """RMS [deg] of the attitude difference on ``axis`` over the common span of two error traces aligned on
    engagement (t = 0), ``a`` interpolated onto ``b``'s sample times. Both are errors against the same raw reference;
    with ``reference`` given, each is turned back into an attitude (error + the raw reference at its own sample time)
    before ``a`` is interpolated, because interpolating an *error* across a step of the reference is wrong: one
    ``b`` sample between the two ``a`` samples that straddle the 45 deg yaw step read up to 27 deg of difference that
    neither flight had, and that single sample moved the yaw RMS from 0.12-0.30 to 0.69-1.19 deg, depending only on
    where the two logs' sample times fell (measured on 7 flights, 2026-12-02)."""
    if not trace_a or not trace_b:
        return float("nan")

    def attitude(trace):
        t = np.array([t for t, _ in trace])
        e = np.array([e[axis] for _, e in trace])
        if reference is not None:
            e = e + np.array([float(reference.at(x)[0][axis]) for x in t])
        return t, np.unwrap(e)

    ta, ea = attitude(trace_a)
    tb, eb = attitude(trace_b)
    keep = (tb >= max(ta[0], 0.0)) & (tb <= ta[-1])
    if not keep.any():
        return float("nan")
    d = np.interp(tb[keep], ta, ea) - eb[keep]
    return float(np.degrees(np.sqrt(np.mean(d * d))))


def parity_row(flight: tuple[str, str], sim: dict, genuine: dict, sim_trace, genuine_trace, reference=None) -> dict:
    """Per-axis comparison of one flight flown on both sides, with a verdict per goal."""
    out = {"controller": flight[0], "scenario": flight[1], "sim_end": sim.get("end", sim.get("error", "")),
           "genuine_end": genuine.get("end", genuine.get("error", ""))}
    for i, axis in enumerate(pg.AXES):
        s, g = sim.get(axis), genuine.get(axis)
        if not isinstance(s, dict) or not isinstance(g, dict):
            out[axis] = {"error": "missing"}
            continue
        t5s, t5g = s["t5_s"], g["t5_s"]
        t5_ok = (math.isfinite(t5s) and math.isfinite(t5g) and abs(t5s - t5g) <= GOAL["t5_rel"] * t5g) or \
                (math.isinf(t5s) and math.isinf(t5g))
        os_ok = abs(s["os_pct"] - g["os_pct"]) <= GOAL["os_pts"] if math.isfinite(s["os_pct"]) and math.isfinite(g["os_pct"]) else False
        rms = trace_rms_difference_deg(sim_trace, genuine_trace, i, reference)
        lc_s, lc_g = limit_cycle(sim_trace, i), limit_cycle(genuine_trace, i)
        out[axis] = {"t5_sim_s": t5s, "t5_genuine_s": t5g, "t5_ok": bool(t5_ok),
                     "os_sim_pct": s["os_pct"], "os_genuine_pct": g["os_pct"], "os_ok": bool(os_ok),
                     "rms_diff_deg": rms, "rms_ok": bool(rms <= GOAL["rms_deg"]),
                     "cycle_sim": lc_s, "cycle_genuine": lc_g, "cycle_ok": lc_s["cycle"] == lc_g["cycle"],
                     "steady_sim_deg": s["steady_deg"], "steady_genuine_deg": g["steady_deg"],
                     "dist_peak_sim_deg": s["dist_peak_deg"], "dist_peak_genuine_deg": g["dist_peak_deg"]}
    return out


# ---------------------------------------------------------------------- flights
def set_torques(clock: pg.PlantClock, scenario_name: str) -> None:
    """Give the physics exactly this scenario's torque events (parked until the engagement)."""
    d = clock.disturbances
    d.torque_events = []
    for ev in getattr(load_scenario(scenario_name), "disturbances", ()) or ():
        d.add_torque_event(ev)
    clock.park()


class InRepoSim:
    """``mavastsm sim``'s vehicle (VehicleServer, real time) in a private network namespace on udp 127.0.0.1:14560."""

    def __init__(self, profile: str = PARITY_PROFILE) -> None:
        from mavastsm_sim.vehicle_server import VehicleServer

        self.netns = NetNamespace()
        try:
            self.server = self.netns.call(lambda: VehicleServer(clock="realtime", listen=("127.0.0.1", SIM_PORT),
                                                                profile=profile))
            self.server.start()
        except BaseException:
            self.netns.close()
            raise
        copter = self.server.copter
        self.clock = pg.PlantClock(lambda: copter.time_s, copter.disturbances, 0.0)
        self.clock.park()

    def wait_disarmed(self, timeout_s: float = 90.0) -> None:
        wait_for(lambda: not self.server.copter.armed, timeout_s, "our sim disarmed after the flight")

    def close(self) -> None:
        self.server.stop()
        self.netns.close()


def fly_side(side: str, flights, log_root: Path, path=None, on_row=print, profile: str = PARITY_PROFILE) -> dict:
    """Fly every flight on one side ("sim" or "genuine"); returns {(controller, scenario): row} with the CSV paths."""
    rows = {}
    if side == "sim":
        vehicle = InRepoSim(profile)
        netns, clock, wait_disarmed, url = vehicle.netns, vehicle.clock, vehicle.wait_disarmed, "sim"
    else:
        v = boot_arducopter_solo_physics(arducopter_paths(path), fast_prearm=True, disturbance_start="held",
                                         attitude_history_s=pg.ATTITUDE_HISTORY_S)
        vehicle = v
        try:
            clock = pg.genuine_plant_clock(v)
        except BaseException:
            v.close()
            raise
        netns, wait_disarmed, url = v.sitl.netns, (lambda: v.wait_disarmed(90.0)), "arducopter"
    try:
        for c, sc in flights:
            set_torques(clock, sc)
            d = log_root / side / f"{c}-{sc}"
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir(parents=True)
            row, _ = pg.fly_bridge(netns, clock, url, c, sc, d, wait_disarmed)
            row["side"] = side
            rows[(c, sc)] = row
            on_row(row)
    finally:
        vehicle.close()
    return rows


def rows_from_logs(side: str, flights, log_root: Path) -> dict:
    """Rows of a side flown earlier (--genuine-logs): metrics recomputed from the kept CSVs."""
    rows = {}
    for c, sc in flights:
        csvs = sorted((log_root / side / f"{c}-{sc}").glob("*.csv"))
        if not csvs:
            raise FileNotFoundError(f"no {side} CSV for {c} {sc} under {log_root}")
        s = load_scenario(sc)
        row = {"controller": c, "scenario": sc, "side": side, "csv": str(csvs[-1]), "end": "(saved log)"}
        row.update(pg.flight_metrics(read_flight_log(csvs[-1]), s.reference, pg.disturbance_onset_s(s)))
        rows[(c, sc)] = row
    return rows


def compare(flights, sim_rows: dict, genuine_rows: dict) -> list[dict]:
    out = []
    for f in flights:
        s, g = sim_rows[f], genuine_rows[f]
        ref = load_scenario(f[1]).reference
        ts = pg.error_trace(read_flight_log(s["csv"]), ref) if "csv" in s else []
        tg = pg.error_trace(read_flight_log(g["csv"]), ref) if "csv" in g else []
        out.append(parity_row(f, s, g, ts, tg, ref))
    return out


# ---------------------------------------------------------------------- table
def _ok(flag: bool) -> str:
    return "✓" if flag else "✗"


def table(rows: list[dict]) -> str:
    head = ("| controller | scenario | axis | t5% sim / genuine [s] | OS sim / genuine [%] | RMS trace diff. [deg] "
            "| limit cycle sim / genuine | steady sim / genuine [deg] | dist. peak sim / genuine [deg] |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        for axis in pg.AXES:
            a = r[axis]
            first = axis == "roll"
            lead = f"| {r['controller'] if first else ''} | {r['scenario'] if first else ''} | {axis} |"
            if "error" in a:
                lines.append(lead + " — |" * 6)
                continue

            def lc(x):
                return f"yes ({x['hz']:.1f} Hz, {x['pp_deg']:.2f}°)" if x["cycle"] else "no"

            lines.append(lead + f" {pg.fmt(a['t5_sim_s'])} / {pg.fmt(a['t5_genuine_s'])} {_ok(a['t5_ok'])} | "
                         f"{pg.fmt(a['os_sim_pct'], 1)} / {pg.fmt(a['os_genuine_pct'], 1)} {_ok(a['os_ok'])} | "
                         f"{pg.fmt(a['rms_diff_deg'])} {_ok(a['rms_ok'])} | {lc(a['cycle_sim'])} / {lc(a['cycle_genuine'])} "
                         f"{_ok(a['cycle_ok'])} | {pg.fmt(a['steady_sim_deg'])} / {pg.fmt(a['steady_genuine_deg'])} | "
                         f"{pg.fmt(a['dist_peak_sim_deg'], 1)} / {pg.fmt(a['dist_peak_genuine_deg'], 1)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--path", default=None, help="ArduCopter SITL binary/folder (default: $MAVASTSM_ARDUCOPTER)")
    ap.add_argument("--keep-logs", default=None, metavar="DIR", help="keep both sides' flight logs here (DIR/sim, DIR/genuine)")
    ap.add_argument("--genuine-logs", default=None, metavar="DIR", help="do not fly genuine ArduCopter: use DIR/genuine from a --keep-logs run")
    ap.add_argument("--sim-logs", default=None, metavar="DIR", help="do not fly our sim: use DIR/sim from a --keep-logs run")
    ap.add_argument("--sim-profile", default=PARITY_PROFILE, metavar="NAME|FILE",
                    help=f"our sim's habits, a sim profile (mavastsm sim --profile); default {PARITY_PROFILE}: every "
                         "habit measured on genuine 4.7 SITL but its pre-arm wait (4.7's version and loop-tick ATTITUDE "
                         "timing, ArduCopter's take-off, SITL's 3 ms command latency, density compensation); "
                         "arducopter-4.5-quick: the sim's default (4.5.7, evenly spaced ATTITUDE)")
    ap.add_argument("--only", choices=("sim", "genuine"), default=None, help="fly this side only (with --keep-logs; no table)")
    ap.add_argument("--json", default=None, metavar="FILE")
    ap.add_argument("--markdown", default=None, metavar="FILE")
    args = ap.parse_args(argv)
    tmp = None
    if args.keep_logs:
        root = Path(args.keep_logs)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="mavastsm-parity-")
        root = Path(tmp.name)
    prov = pg.provenance()
    try:
        show = (lambda r: print(json.dumps(pg.json_safe(r)), flush=True))
        sides = {}
        for side, saved in (("sim", args.sim_logs), ("genuine", args.genuine_logs)):
            if args.only not in (None, side):
                continue
            sides[side] = (rows_from_logs(side, FLIGHTS, Path(saved)) if saved
                           else fly_side(side, FLIGHTS, root, args.path, on_row=show, profile=args.sim_profile))
        if args.only:
            return 0
        sim_rows, genuine_rows = sides["sim"], sides["genuine"]
        rows = compare(FLIGHTS, sim_rows, genuine_rows)
    finally:
        if tmp is not None:
            tmp.cleanup()
    text = (f"Flown {prov['date_utc']} UTC at commit {prov['commit']}"
            + "".join(f" ({side} side from saved logs)" for side, saved in (("sim", args.sim_logs), ("genuine", args.genuine_logs)) if saved)
            + ".\n\n" + table(rows))
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps(pg.json_safe({"provenance": prov, "goal": GOAL, "rows": rows,
                                                             "sim": list(sim_rows.values()),
                                                             "genuine": list(genuine_rows.values())}), indent=1) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
