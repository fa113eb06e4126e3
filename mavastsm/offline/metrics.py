"""Per-axis performance metrics of one offline run (docs/design-decisions.md, CTL-13). Pure NumPy.

All angles are reported in degrees (``_deg``), times in seconds (``_s``), torques in N m.
For axis i with step time t_i and step size r_i (from the scenario's reference):

* settling_2pct_s / settling_5pct_s: last time in [t_i, t_w) with |e_i| > 0.02|r_i| (0.05|r_i|), minus t_i;
  inf when still outside the band at t_w. t_w = disturbance onset (or the run's end without one), so the
  step response is judged before the disturbance.
* overshoot_pct: max over [t_i, t_w) of sgn(r_i)(Theta_i - Theta_d,i)/|r_i|*100, floored at 0.
  overshoot_own_step_pct: the same over [t_i, next reference or disturbance event on any axis), i.e.
  without the cross-coupling that later steps on other axes cause.
* iae_deg_s, itae_deg_s2: integral of |e_i| and (t - t_i)|e_i| over [t_i, t_w).
* steady_error_deg: mean |e_i| over the final 0.5 s of the run.
* energy_nm2s: integral of u_i^2 over the run; peak_u_nm: max |u_i|.
* chattering on the steady window (the 1 s before the disturbance onset, or the last 1 s of the run):
  tv_steady_nm (total variation of u_i), hf_ratio (share of the power of u_i - mean above 20 Hz, Welch
  estimate with Hann windows), switching_rate_hz (sign changes of Delta u_i per second, |Delta u| < 1e-6 N m ignored); tv_total_nm over
  the whole run.
* disturbance (t >= t_d): dist_peak_deg (max |e_i|), dist_recovery_s (last time |e_i| >= 0.2 deg, minus
  t_d; inf if not recovered at the end), dist_iae_deg_s over [t_d, t_d + 2 s].
* adaptation (when the law has alpha): alpha_peak, alpha_return_s (largest, over events, of the time
  from the event until alpha last exceeded 1.1 alpha_m before the next event; inf when still above at the
  end), sliding_fraction (share of samples with |sigma| < mu).
"""

from __future__ import annotations

import numpy as np

from ..frames import AXES
from ..step_metrics import overshoot_pct, settling_time_s
from .simulator import RunResult

HF_CUTOFF_HZ = 20.0
RECOVERY_BAND_DEG = 0.2
STEADY_WINDOW_S = 1.0
FINAL_WINDOW_S = 0.5
DIST_IAE_WINDOW_S = 2.0


def welch_hf_ratio(x, dt_s, cutoff_hz=HF_CUTOFF_HZ, segment=256):
    """Share of the power of x (mean removed) above ``cutoff_hz`` (Welch, Hann, 50 % overlap); NaN if silent."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    if x.size < 8:
        return float("nan")
    seg = min(segment, x.size)
    step = seg // 2
    win = np.hanning(seg)
    starts = range(0, x.size - seg + 1, step)
    psd = sum(np.abs(np.fft.rfft(win * x[s : s + seg])) ** 2 for s in starts)
    f = np.fft.rfftfreq(seg, dt_s)
    total = float(np.sum(psd))
    if total <= 1e-30:
        return float("nan")
    return float(np.sum(psd[f > cutoff_hz]) / total)


SWITCH_DEADBAND_NM = 1e-6


def switching_rate_hz(u, duration_s, deadband_nm=SWITCH_DEADBAND_NM):
    """Sign changes of Delta u per second; increments smaller than ``deadband_nm`` (round-off) are ignored."""
    du = np.diff(u)
    d = np.sign(du[np.abs(du) > deadband_nm])
    if d.size < 2 or duration_s <= 0:
        return 0.0
    return float(np.count_nonzero(d[1:] != d[:-1]) / duration_s)


def _integral(y, dt):
    return float(np.sum(y) * dt)


def alpha_return_time_s(t_s, alpha, events, threshold):
    """max over events of (last time alpha > threshold before the next event) - event; 0 if never above."""
    worst = 0.0
    ev = sorted(events)
    for j, te in enumerate(ev):
        t_next = ev[j + 1] if j + 1 < len(ev) else np.inf
        m = (t_s >= te) & (t_s < t_next)
        tt, aa = t_s[m], alpha[m]
        above = np.nonzero(aa > threshold)[0]
        if above.size == 0:
            continue
        if above[-1] == tt.size - 1 and t_next == np.inf:
            return float("inf")
        worst = max(worst, float(tt[above[-1]] - te + (t_s[1] - t_s[0])))
    return worst


def compute_metrics(run: RunResult) -> dict[str, np.ndarray]:
    """Metrics of one run: name -> array (3,) per axis [roll, pitch, yaw] (see module docstring)."""
    t = run.t_s
    dt = run.dt_s
    e_deg = np.degrees(run.error_rad)
    u = run.u_nm
    scn = run.spec.scenario
    ref = scn.reference
    t_end = scn.duration_s
    t_d = scn.disturbance_start_s
    t_w = t_d if (t_d is not None and t_d > 0) else t_end
    out: dict[str, list] = {k: [] for k in (
        "step_time_s", "step_deg", "settling_2pct_s", "settling_5pct_s", "overshoot_pct", "overshoot_own_step_pct", "iae_deg_s", "itae_deg_s2",
        "steady_error_deg", "energy_nm2s", "peak_u_nm", "tv_total_nm", "tv_steady_nm", "hf_ratio", "switching_rate_hz",
        "dist_peak_deg", "dist_recovery_s", "dist_iae_deg_s", "alpha_peak", "alpha_return_s", "sliding_fraction",
    )}
    steady_lo = (t_d - STEADY_WINDOW_S) if (t_d is not None and t_d >= STEADY_WINDOW_S) else t_end - STEADY_WINDOW_S
    steady_hi = t_d if (t_d is not None and t_d >= STEADY_WINDOW_S) else t_end
    steady = (t >= steady_lo) & (t < steady_hi)
    final = t >= t_end - FINAL_WINDOW_S
    all_events = sorted({c.start_s for c in ref.components} | ({t_d} if t_d is not None else set()))
    for i in range(3):
        times = ref.event_times_s(i)
        t_i = times[0] if times else 0.0
        r_deg = float(np.degrees(ref.step_size_rad(i)))
        ei = e_deg[:, i]
        win = (t >= t_i) & (t < t_w)
        out["step_time_s"].append(t_i)
        out["step_deg"].append(r_deg)
        if r_deg != 0.0:
            out["settling_2pct_s"].append(settling_time_s(t, ei, 0.02 * abs(r_deg), t_i, t_w))
            out["settling_5pct_s"].append(settling_time_s(t, ei, 0.05 * abs(r_deg), t_i, t_w))
            out["overshoot_pct"].append(overshoot_pct(t, ei, r_deg, t_i, t_w))
            t_next = min([e for e in all_events if e > t_i] + [t_w])
            out["overshoot_own_step_pct"].append(overshoot_pct(t, ei, r_deg, t_i, t_next))
        else:
            out["settling_2pct_s"].append(np.nan)
            out["settling_5pct_s"].append(np.nan)
            out["overshoot_pct"].append(np.nan)
            out["overshoot_own_step_pct"].append(np.nan)
        out["iae_deg_s"].append(_integral(np.abs(ei[win]), dt))
        out["itae_deg_s2"].append(_integral((t[win] - t_i) * np.abs(ei[win]), dt))
        out["steady_error_deg"].append(float(np.mean(np.abs(ei[final]))))
        ui = u[:, i]
        out["energy_nm2s"].append(_integral(ui**2, dt))
        out["peak_u_nm"].append(float(np.max(np.abs(ui))))
        out["tv_total_nm"].append(float(np.sum(np.abs(np.diff(ui)))))
        out["tv_steady_nm"].append(float(np.sum(np.abs(np.diff(ui[steady])))))
        out["hf_ratio"].append(welch_hf_ratio(ui[steady], dt))
        out["switching_rate_hz"].append(switching_rate_hz(ui[steady], steady_hi - steady_lo))
        if t_d is not None:
            after = t >= t_d
            ea = np.abs(ei[after])
            out["dist_peak_deg"].append(float(np.max(ea)))
            bad = np.nonzero(~(ea < RECOVERY_BAND_DEG))[0]
            if bad.size == 0:
                rec = 0.0
            elif bad[-1] == ea.size - 1:
                rec = float("inf")
            else:
                rec = float(t[after][bad[-1] + 1] - t_d)
            out["dist_recovery_s"].append(rec)
            w2 = (t >= t_d) & (t < t_d + DIST_IAE_WINDOW_S)
            out["dist_iae_deg_s"].append(_integral(np.abs(ei[w2]), dt))
        else:
            for k in ("dist_peak_deg", "dist_recovery_s", "dist_iae_deg_s"):
                out[k].append(np.nan)
        a = run.alpha[:, i]
        if np.all(np.isfinite(a)):
            out["alpha_peak"].append(float(np.max(a)))
            out["alpha_return_s"].append(alpha_return_time_s(t, a, all_events, 1.1 * run.alpha_min[i]))
            out["sliding_fraction"].append(float(np.mean(np.abs(run.sigma[:, i]) < run.mu[i])))
        else:
            for k in ("alpha_peak", "alpha_return_s", "sliding_fraction"):
                out[k].append(np.nan)
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}


def pitch_coupling_deg(run: RunResult) -> float:
    """Claim C5: largest pitch excursion caused by the other axes' steps [deg].

    max(|e_theta| over [t_roll, t_pitch)) and max |e_theta(t) - e_theta(t_yaw)| over [t_yaw, t_yaw + 1 s]:
    the pitch error while only roll moves, and the change of pitch error the yaw step causes.
    """
    ref = run.spec.scenario.reference
    t = run.t_s
    e = np.degrees(run.error_rad[:, 1])
    t_roll = (ref.event_times_s(0) or [0.0])[0]
    t_pitch = (ref.event_times_s(1) or [run.spec.scenario.duration_s])[0]
    t_yaw = (ref.event_times_s(2) or [run.spec.scenario.duration_s])[0]
    w1 = (t >= t_roll) & (t < t_pitch)
    w2 = (t >= t_yaw) & (t < t_yaw + 1.0)
    a = float(np.max(np.abs(e[w1]))) if w1.any() else 0.0
    b = float(np.max(np.abs(e[w2] - e[w2][0]))) if w2.any() else 0.0
    return max(a, b)
