"""Comparison: every controller on the paper's scenarios, flown over MAVLink against the simulated Solo.

    python benchmarks/bridge_scenarios.py [--controllers astsm,stsm,smc,atsm,pid] [--scenarios nominal,disturbance,variation]
                                          [--markdown OUT.md]

Each run: in-process ``VehicleServer`` (lockstep, the scenario's disturbance/variation), ``Bridge``
(GUIDED_NOGPS, arm, 2 m takeoff, 1 s settle, the scenario's reference and duration), disturbance clock
restarted at engagement so "4.0 s" means 4.0 s after the profile starts, as in the offline runs.
Metrics (bridge record vs the raw reference): 5 % settling time, overshoot, steady error (final 0.5 s);
disturbance runs add the peak deviation after t_d and the recovery time to |e| < 0.5 deg (sustained).
Prints a markdown table; asserts nothing. Lockstep makes the plant side repeatable; the bridge side is
mostly so (run-to-run spread of the yaw numbers is about +-0.1 s, +-2 %).
"""

from __future__ import annotations

import argparse
import math
import sys
import threading

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.scenarios import load_scenario
from mavastsm_sim.vehicle_server import VehicleServer


def disturbance_metrics(summary, t_d: float, axis: int, band_deg: float = 0.5):
    """(peak |e| after t_d [deg], recovery time after t_d to |e| < band for good [s]) against the raw reference."""
    from mavastsm.bridge.tracking_metrics import raw_errors

    errs = raw_errors(summary.samples, summary.engage_time_s, _REF[0])
    after = [(t, e[axis]) for t, e in errs if t >= t_d]
    if not after:
        return float("nan"), float("nan")
    peak = max(abs(e) for _, e in after)
    outside = [t for t, e in after if abs(math.degrees(e)) > band_deg]
    rec = 0.0 if not outside else (math.inf if outside[-1] >= after[-1][0] - 1e-9 else outside[-1] - t_d)
    return math.degrees(peak), rec


_REF: list = [None]


def fly(controller: str, scenario: str):
    sc = load_scenario(scenario)
    duration = float(getattr(sc, "duration_s", 5.0))
    with VehicleServer(clock="lockstep", listen=("127.0.0.1", 0), scenario=scenario) as server:
        server.call(lambda copter: copter.disturbances.restart_clock(1e9))  # nothing during takeoff
        opts = BridgeOptions(f"udpout:127.0.0.1:{server.port}", controller=controller, reference=sc.reference,
                             duration_s=duration, mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=2.0, on_exit="LAND",
                             overrides={"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5})
        bridge = Bridge(opts)
        done = threading.Event()

        def align():
            # restart the scenario's disturbance clock at the engagement sample (vehicle clock)
            while not done.is_set():
                s = bridge.session
                if s is not None and s.cycle.engage_ms is not None:
                    t0 = s.cycle.engage_ms / 1000.0
                    server.call(lambda copter: copter.disturbances.restart_clock(t0))
                    return
                done.wait(0.001)

        th = threading.Thread(target=align, daemon=True)
        th.start()
        try:
            summary = bridge.run()
        finally:
            done.set()
            th.join(2.0)
        _REF[0] = bridge.session.cycle.reference
    t_d = None
    for d in getattr(sc, "disturbances", ()) or ():
        t_d = float(getattr(d, "start_s", 0.0))
        break
    return summary, t_d


def fmt(x, nd=2):
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else ("∞" if x == math.inf else f"{x:.{nd}f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controllers", default="astsm,stsm,smc,atsm,pid")
    ap.add_argument("--scenarios", default="nominal,disturbance,variation")
    ap.add_argument("--markdown", default=None)
    args = ap.parse_args()
    head = ("| controller | scenario | end | settle 5 % r/p/y [s] | overshoot r/p/y [%] | steady r/p/y [deg] | "
            "dist. peak r/p/y [deg] | recovery r/p/y [s] | latency p50/p99 [us] |")
    lines = [head, "|" + "---|" * 9]
    for sc in args.scenarios.split(","):
        for c in args.controllers.split(","):
            s, t_d = fly(c, sc)
            ax = s.axes
            if t_d is not None:
                dm = [disturbance_metrics(s, t_d, i) for i in range(3)]
                peak = "/".join(fmt(d[0]) for d in dm)
                rec = "/".join(fmt(d[1]) for d in dm)
            else:
                peak = rec = "—"
            end = s.failsafe.name if s.failsafe else "ok"
            line = (f"| {c} | {sc} | {end} | {'/'.join(fmt(a.settling_time_5pct_s) for a in ax)} | "
                    f"{'/'.join(fmt(a.overshoot_pct, 1) for a in ax)} | {'/'.join(fmt(a.steady_error_deg) for a in ax)} | "
                    f"{peak} | {rec} | {s.latency_p50_s * 1e6:.0f}/{s.latency_p99_s * 1e6:.0f} |")
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
