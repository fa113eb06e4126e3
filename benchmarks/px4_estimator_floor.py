"""How far PX4 SIH's attitude estimate (ATTITUDE, all an offboard controller sees) is from SIH's true attitude.

    python benchmarks/px4_estimator_floor.py --runs 2 [--json docs/results/px4_estimator_floor.json]

One PX4 SITL boot (SIH quadx, $MAVASTSM_PX4, private network namespace, as the tests do). A ground-station
observer on its own link records ATTITUDE (EKF2's estimate) and HIL_STATE_QUATERNION (SIH's ground truth) at
50 Hz each, both stamped with the vehicle's clock (time_boot_ms, time_usec). Each run flies the README's PX4
command (astsm, paper steps, --log) and prints, per axis:

* the peak to peak over the last second of the steps, of the estimate (what the control-quality bound is measured
  on) and of the truth;
* the same over the second before engagement, PX4's own controller holding the vehicle after its takeoff;
* the estimate's error (truth - estimate) over the steps: mean, standard deviation and peak to peak, and its
  peak to peak within the last second.

These are the floor under the bounds of the PX4 issue (0.3 deg peak to peak, 0.5 deg settling band): a controller
that holds the estimate still moves the real vehicle by the estimate's error, and every correction EKF2 makes to
its estimate is a step the controller must follow.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from genuine_autopilots import README_COMMANDS  # noqa: E402  (this folder)
from mavastsm.bridge.record.flight_log import read_flight_rows  # noqa: E402
from mavastsm.frames import AXES, euler_from_quaternion  # noqa: E402
from mavastsm_sim.genuine_observer import boot_px4  # noqa: E402
from mavastsm_sim.genuine_sitl import px4_paths  # noqa: E402

README_PX4 = README_COMMANDS["px4"]  # the README command, as the results tables fly it
MSG_ATTITUDE, MSG_HIL_STATE_QUATERNION = 30, 115
STREAM_HZ = 50.0


class Recorder:
    """Wraps the observer's reader: every ATTITUDE and HIL_STATE_QUATERNION as (vehicle time [s], roll, pitch, yaw [rad]).

    PX4 SIH sends HIL_STATE_QUATERNION with time_usec 0, so both are stamped on arrival (host monotonic, one link)
    and the truth's stamps are mapped to the vehicle's clock through ATTITUDE's (arrival, time_boot_ms) pairs."""

    def __init__(self, observer) -> None:
        self.estimate: list[tuple[float, float, float, float]] = []
        self.truth: list[tuple[float, float, float, float]] = []
        self.height: list[tuple[float, float, float]] = []  # (arrival, true height [m] AMSL, estimated height above home [m])
        self._relative_alt_m = float("nan")
        self._lock = threading.Lock()
        recv = observer.conn.recv_match

        def recv_match(*args, **kwargs):
            m = recv(*args, **kwargs)
            if m is not None and m.get_srcComponent() == 1:
                kind = m.get_type()
                if kind == "ATTITUDE":
                    with self._lock:
                        self.estimate.append((time.monotonic(), m.time_boot_ms / 1e3, m.roll, m.pitch, m.yaw))
                elif kind == "HIL_STATE_QUATERNION":
                    r, p, y = euler_from_quaternion(np.asarray(m.attitude_quaternion, dtype=float))
                    with self._lock:
                        self.truth.append((time.monotonic(), float(r), float(p), float(y)))
                        self.height.append((time.monotonic(), m.alt / 1e3, self._relative_alt_m))
                elif kind == "GLOBAL_POSITION_INT":
                    self._relative_alt_m = m.relative_alt / 1e3
            return m

        observer.conn.recv_match = recv_match

    def heights(self) -> np.ndarray:
        """(n, 3): vehicle time [s], true height above the ground SIH started on [m], EKF2's height above home [m]."""
        with self._lock:
            est, h = np.array(self.estimate), np.array(self.height)
        return np.column_stack((np.interp(h[:, 0], est[:, 0], est[:, 1]), h[:, 1] - h[0, 1], h[:, 2]))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(estimate, truth), each (n, 4): vehicle time [s], roll, pitch, yaw [rad]."""
        with self._lock:
            est, truth = np.array(self.estimate), np.array(self.truth)
        truth[:, 0] = np.interp(truth[:, 0], est[:, 0], est[:, 1])
        return est[:, 1:], truth


def window_pp_deg(track: np.ndarray, t0: float, t1: float) -> list[float]:
    m = (track[:, 0] >= t0) & (track[:, 0] <= t1)
    if m.sum() < 5:
        return [math.nan] * 3
    ang = np.column_stack((track[m, 1], track[m, 2], np.unwrap(track[m, 3])))
    return [round(float(x), 3) for x in np.degrees(np.ptp(ang, axis=0))]


def estimate_error_deg(est: np.ndarray, truth: np.ndarray, t0: float, t1: float) -> dict:
    """truth - estimate on the truth's samples in [t0, t1] (estimate interpolated at the truth's times), per axis."""
    m = (truth[:, 0] >= t0) & (truth[:, 0] <= t1)
    out = {}
    for i, axis in enumerate(AXES, start=1):
        e = np.unwrap(est[:, i])
        g = np.unwrap(truth[:, i])
        diff = np.degrees(g[m] - np.interp(truth[m, 0], est[:, 0], e))
        diff = (diff + 180.0) % 360.0 - 180.0
        out[axis] = {"mean": round(float(diff.mean()), 3), "std": round(float(diff.std()), 3), "pp": round(float(np.ptp(diff)), 3)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=2, help="flights [-] (default 2)")
    ap.add_argument("--path", default=None, help="PX4 build folder (default: $MAVASTSM_PX4)")
    ap.add_argument("--json", default=None, metavar="FILE", help="write the rows as JSON")
    args = ap.parse_args(argv)
    rows = []
    v = boot_px4(px4_paths(args.path))
    try:
        rec = Recorder(v.observer)
        v.observer.request_streams({MSG_ATTITUDE: STREAM_HZ, MSG_HIL_STATE_QUATERNION: STREAM_HZ})
        for run in range(args.runs):
            with tempfile.TemporaryDirectory(prefix="mavastsm-px4-floor-") as log_dir:
                argv_bridge = [str(Path(sys.executable).with_name("mavastsm")), *README_PX4, "--no-dashboard", "--log", log_dir]
                p = subprocess.run(v.sitl.netns.command(argv_bridge), capture_output=True, text=True, timeout=240)
                v.wait_disarmed(90.0)
                csvs = sorted(Path(log_dir).glob("*.csv"))
                engaged = [r.sample.vehicle_time_s for r in read_flight_rows(csvs[-1]) if r.phase == "engaged"] if csvs else []
            if p.returncode != 0 or not engaged:
                rows.append({"run": run, "error": (p.stdout + p.stderr)[-400:]})
                print(rows[-1], flush=True)
                continue
            est, truth = rec.arrays()
            t_on, t_off = engaged[0], engaged[-1]
            print(f"run {run}: engaged {t_on:.3f}-{t_off:.3f} s; estimate {est[0, 0]:.3f}-{est[-1, 0]:.3f} s ({len(est)}), "
                  f"truth {truth[0, 0]:.3f}-{truth[-1, 0]:.3f} s ({len(truth)})", flush=True)
            hh = rec.heights()
            during = (hh[:, 0] >= t_on) & (hh[:, 0] <= t_off)
            row = {"run": run,
                   "true_height_min_m": round(float(hh[during, 1].min()), 2),
                   "estimated_height_min_m": round(float(np.nanmin(hh[during, 2])), 2),
                   "estimate_pp_last_s_deg": window_pp_deg(est, t_off - 1.0, t_off),
                   "truth_pp_last_s_deg": window_pp_deg(truth, t_off - 1.0, t_off),
                   "px4_own_hold_estimate_pp_deg": window_pp_deg(est, t_on - 1.0, t_on),
                   "px4_own_hold_truth_pp_deg": window_pp_deg(truth, t_on - 1.0, t_on),
                   "estimate_error_steps_deg": estimate_error_deg(est, truth, t_on, t_off),
                   "estimate_error_last_s_deg": estimate_error_deg(est, truth, t_off - 1.0, t_off),
                   "estimate_error_own_hold_deg": estimate_error_deg(est, truth, t_on - 1.0, t_on)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        v.close()
    ok = [r for r in rows if "error" not in r]
    print("\nper axis roll / pitch / yaw [deg]")
    for r in ok:
        err = r["estimate_error_steps_deg"]
        last = r["estimate_error_last_s_deg"]
        print(f"run {r['run']}: last 1 s p-p estimate {r['estimate_pp_last_s_deg']} truth {r['truth_pp_last_s_deg']}; "
              f"PX4's own hold p-p estimate {r['px4_own_hold_estimate_pp_deg']} truth {r['px4_own_hold_truth_pp_deg']}; "
              f"estimate error over the steps mean {[err[a]['mean'] for a in AXES]} std {[err[a]['std'] for a in AXES]} "
              f"p-p {[err[a]['pp'] for a in AXES]}, its p-p in the last second {[last[a]['pp'] for a in AXES]}; "
              f"lowest true height {r['true_height_min_m']} m (estimated {r['estimated_height_min_m']} m)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
