"""Comparison: every controller on the paper's scenarios, flown over MAVLink against the simulated Solo.

    python benchmarks/bridge_scenarios.py [--controllers astsm,stsm,smc,atsm,pid] [--scenarios nominal,disturbance,variation]
                                          [--per-axis astsm] [--set mapping.command_accel_clip=authority] [--controller-config astsm_400hz]
                                          [--markdown OUT.md]

Each run: one lockstep pair (``mavastsm.lockstep_pair``: the sim with the scenario's disturbance/variation, the
bridge flying GUIDED_NOGPS, arm, 2 m takeoff, 1 s settle, the scenario's reference and duration), disturbance clock
started at the engagement sample so "4.0 s" means 4.0 s after the profile starts, as in the offline runs.
Metrics (bridge record vs the raw reference): 5 % settling time, overshoot, steady error (final 0.5 s);
disturbance runs add the peak deviation after t_d and the recovery time to |e| < 0.5 deg (sustained).
D-B (disturbance_roll/pitch/yaw) for the --per-axis controllers; for every disturbance scenario a reference
table of ArduCopter's emulation alone (``fly_autopilot_alone``). Prints markdown tables; asserts nothing. Lockstep makes the plant side repeatable; the bridge side is
mostly so (run-to-run spread of the yaw numbers is about +-0.1 s, +-2 %).
"""

from __future__ import annotations

import argparse
import math
import sys

from mavastsm.lockstep_pair import LockstepPair
from mavastsm.scenarios import load_scenario


def disturbance_metrics(summary, t_d: float, axis: int, band_deg: float = 0.5):
    """(peak |e| after t_d [deg], recovery time after t_d to |e| < band for good [s]) against the raw reference."""
    from mavastsm.bridge.record.tracking_metrics import raw_errors

    errs = raw_errors(summary.samples, summary.engage_time_s, _REF[0])
    after = [(t, e[axis]) for t, e in errs if t >= t_d]
    if not after:
        return float("nan"), float("nan")
    peak = max(abs(e) for _, e in after)
    outside = [t for t, e in after if abs(math.degrees(e)) > band_deg]
    rec = 0.0 if not outside else (math.inf if outside[-1] >= after[-1][0] - 1e-9 else outside[-1] - t_d)
    return math.degrees(peak), rec


_REF: list = [None]
_EXTRA: dict = {}  # extra BridgeOptions overrides (--set)
_PRESET: list = [None]  # --controller-config


def fly(controller: str, scenario: str, overrides: dict | None = None):
    sc = load_scenario(scenario)
    duration = float(getattr(sc, "duration_s", 5.0))
    with LockstepPair(scenario, sim=dict(lockstep_timeout_s=0.1)) as pair:
        bridge = pair.start_bridge(controller=controller, reference=sc.reference, controller_config=_PRESET[0],
                                   duration_s=duration, mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=2.0, on_exit="LAND",
                                   overrides={"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000,
                                              "timing.stale_timeout_s": 0.5, **_EXTRA, **(overrides or {})})
        while (summary := pair.wait(0.2)) is None:
            pass
        _REF[0] = bridge.session.cycle.reference
    t_d = None
    for d in getattr(sc, "disturbances", ()) or ():
        t_d = float(getattr(d, "start_s", 0.0))
        break
    return summary, t_d


def fly_autopilot_alone(scenario: str, level: bool = False, dt_s: float = 0.0025):
    """ArduCopter's emulation alone under the scenario (no bridge): a peer sends 0x07 attitude setpoints of the
    scenario's reference (relative to the heading at the start), or a level hold with ``level=True``,
    in GUIDED_NOGPS after the same 2 m climb and settle; disturbance clock restarted at the profile start.

    Returns (peak [deg] per axis roll/pitch/yaw after t_d, recovery [s] to |e| < 0.5 deg for good (inf if
    never), breached (|roll| or |pitch| > 35 deg at any time), max |r| [rad/s] after t_d, steady error
    [deg] per axis roll/pitch/yaw = mean |e| over the last 0.5 s; yaw error wrapped to +-180 deg).
    """
    import numpy as np

    from mavastsm.frames import quaternion_from_euler
    from mavastsm_sim.copter import SimulatedCopter

    sc = load_scenario(scenario)
    t_d = next((float(d.start_s) for d in (getattr(sc, "disturbances", ()) or ())), math.inf)
    c = SimulatedCopter(scenario=scenario)
    c.disturbances.park()  # nothing during the climb
    c.set_mode(20)  # GUIDED_NOGPS
    c.arm(force=True)
    level_q = (1.0, 0.0, 0.0, 0.0)
    for thrust, seconds in ((0.7, 3.0), (0.5, 1.0)):  # climb ~2-3 m, settle
        for _ in range(int(round(seconds / dt_s))):
            c.handle_attitude_target(0x07, level_q, (0.0, 0.0, 0.0), thrust)
            c.step(dt_s)
    yaw0 = float(c.euler_rad[2])
    c.disturbances.restart_clock(c.time_s)
    n = int(round(float(sc.duration_s) / dt_s))
    ts = np.arange(n) * dt_s
    ref = np.zeros((n, 3)) if level else np.asarray(sc.reference.at(ts)[0], dtype=float)
    peak, last_out, breached, r_max = [0.0, 0.0, 0.0], [-1.0, -1.0, -1.0], False, 0.0
    tail, tail_n = [0.0, 0.0, 0.0], 0
    for k in range(n):
        r = (float(ref[k, 0]), float(ref[k, 1]), yaw0 + float(ref[k, 2]))
        c.handle_attitude_target(0x07, tuple(float(x) for x in quaternion_from_euler(np.array(r))), (0.0, 0.0, 0.0), 0.5)
        c.step(dt_s)
        e = c.euler_rad
        err = (e[0] - r[0], e[1] - r[1], math.remainder(e[2] - r[2], 2.0 * math.pi))
        breached = breached or max(abs(e[0]), abs(e[1])) > math.radians(35.0)
        if ts[k] >= t_d:
            for i in range(3):
                d = abs(math.degrees(err[i]))
                peak[i] = max(peak[i], d)
                if d > 0.5:
                    last_out[i] = ts[k]
            r_max = max(r_max, abs(float(c.true_body_rates_rads[2])))
        if ts[k] >= ts[-1] - 0.5:
            tail_n += 1
            for i in range(3):
                tail[i] += abs(math.degrees(err[i]))
    end = ts[-1]
    rec = [0.0 if lo < 0 else (math.inf if lo >= end - 0.05 else lo - t_d) for lo in last_out]
    return peak, rec, breached, r_max, [t / max(tail_n, 1) for t in tail]


def fmt(x, nd=2):
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else ("∞" if x == math.inf else f"{x:.{nd}f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controllers", default="astsm,stsm,smc,atsm,pid")
    ap.add_argument("--scenarios", default="nominal,disturbance,variation")
    ap.add_argument("--per-axis", default="astsm", help="controllers also flown on disturbance_roll/pitch/yaw (D-B); '' = none")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra BridgeOptions override (e.g. mapping.command_accel_clip=autopilot)")
    ap.add_argument("--controller-config", default=None, help="controller preset for every run (default: the bridge's, astsm_mavlink for astsm)")
    ap.add_argument("--markdown", default=None)
    args = ap.parse_args()
    _PRESET[0] = args.controller_config
    from mavastsm.config_loading import parse_overrides

    _EXTRA.update(parse_overrides(args.set))  # values parsed as YAML, like `mavastsm connect --set`
    head = ("| controller | scenario | end | settle 5 % r/p/y [s] | overshoot r/p/y [%] | steady r/p/y [deg] | "
            "dist. peak r/p/y [deg] | recovery r/p/y [s] | latency p50/p99 [us] |")
    lines = [head, "|" + "---|" * 9]
    runs = [(c, sc) for sc in args.scenarios.split(",") for c in args.controllers.split(",")]
    runs += [(c, sc) for c in filter(None, args.per_axis.split(",")) for sc in ("disturbance_roll", "disturbance_pitch", "disturbance_yaw")]
    for c, sc in runs:
        s, t_d = fly(c, sc)
        ax = s.axes
        if t_d is not None:
            dm = [disturbance_metrics(s, t_d, i) for i in range(3)]
            peak = "/".join(fmt(d[0], 1) for d in dm)
            rec = "/".join(fmt(d[1]) for d in dm)
        else:
            peak = rec = "—"
        end = s.failsafe.name if s.failsafe else "ok"
        line = (f"| {c} | {sc} | {end} | {'/'.join(fmt(a.settling_time_5pct_s) for a in ax)} | "
                f"{'/'.join(fmt(a.overshoot_pct, 1) for a in ax)} | {'/'.join(fmt(a.steady_error_deg) for a in ax)} | "
                f"{peak} | {rec} | {s.latency_p50_s * 1e6:.0f}/{s.latency_p99_s * 1e6:.0f} |")
        print(line, flush=True)
        lines.append(line)
    dist = [sc for sc in dict.fromkeys([sc for _, sc in runs]) if sc.startswith("disturbance")]
    if dist:
        lines += ["", "ArduCopter's emulation alone (no bridge; 0x07 attitude setpoints from a peer), same scenarios:", "",
                  "| setpoints | scenario | \\|roll\\| or \\|pitch\\| > 35 deg | dist. peak r/p/y [deg] | recovery r/p/y [s] | steady r/p/y [deg] | max \\|r\\| [rad/s] |",
                  "|" + "---|" * 7]
        for sc in dist:
            for level in (False, True):
                peak, rec, breached, r_max, steady = fly_autopilot_alone(sc, level=level)
                line = (f"| {'level hold' if level else 'the reference'} | {sc} | {'yes' if breached else 'no'} | "
                        f"{'/'.join(fmt(p, 1) for p in peak)} | {'/'.join(fmt(r) for r in rec)} | "
                        f"{'/'.join(fmt(x) for x in steady)} | {r_max:.1f} |")
                print(line, flush=True)
                lines.append(line)
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        with open(args.markdown, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
