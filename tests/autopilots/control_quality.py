"""The control-quality bounds of the ArduCopter and PX4 issues (item 4 / item 3) and how one flight is measured."""

from __future__ import annotations

from mavastsm_sim.genuine_observer import against_truth

SETTLING_5PCT_MAX_S = {"roll": 1.5, "pitch": 1.5, "yaw": 2.5}
OVERSHOOT_MAX_PCT = 10.0
STEADY_ERROR_MAX_DEG = 0.5
HOLD_PP_MAX_DEG = 0.3  # error peak to peak over the last second: no limit cycle after settling
CMD_AT_LIMIT_MAX_PCT = 1.0  # of the settled cycles
ALPHA_BACK_MAX_S = 2.0  # alpha within 2 alpha_m after each step


def control_quality(csv, truth=None) -> dict:
    """Every bound's metric per axis of one flight CSV, against the raw paper steps. ``truth(t)``: the true attitude
    quaternion [w, x, y, z] at vehicle time t [s] (the simulator's), or None where unknown; given, the metrics are
    those of the true attitude instead of the autopilot's estimate (rows without a true attitude left out)."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.record.flight_log import read_flight_log
    from mavastsm.bridge.record.tracking_metrics import flight_metrics
    from mavastsm.references import load_reference

    samples = read_flight_log(csv)
    if truth is not None:
        samples = against_truth(samples, truth)
    axes, holds = flight_metrics(samples, load_reference("paper_steps"),
                                 load_bridge_config(None, {"limits": {}}).limits.max_rate_cmd_rads)
    return {m.axis: {"t5_s": round(m.settling_time_5pct_s, 3), "os_pct": round(m.overshoot_pct, 2),
                     "steady_deg": round(m.steady_error_deg, 3), "pp_deg": round(h.hold_pp_deg, 3),
                     "at_limit_pct": round(h.cmd_at_limit_pct, 2), "alpha_back_s": round(h.alpha_recovery_s, 3)}
            for m, h in zip(axes, holds)}


def assert_control_quality_bounds(measured: dict, estimator_error_deg: dict | None = None) -> None:
    """Every bound on every axis. ``estimator_error_deg`` (per axis, for metrics against the true attitude): the steady
    bound then allows the estimator's own error over the same window, which no controller fed by the estimate can
    remove (the PX4 issue: "the same bounds hold against the true attitude, or the estimator error explains it")."""
    for axis, m in measured.items():
        assert m["t5_s"] <= SETTLING_5PCT_MAX_S[axis], (axis, measured)
        assert m["os_pct"] < OVERSHOOT_MAX_PCT, (axis, measured)
        allowed = STEADY_ERROR_MAX_DEG + (estimator_error_deg or {}).get(axis, 0.0)
        assert m["steady_deg"] < allowed, (axis, allowed, measured)
        assert m["pp_deg"] < HOLD_PP_MAX_DEG, (axis, measured)
        assert m["at_limit_pct"] < CMD_AT_LIMIT_MAX_PCT, (axis, measured)
        assert m["alpha_back_s"] <= ALPHA_BACK_MAX_S, (axis, measured)


def estimator_error_deg(csv, truth, window_s: float = 0.5) -> dict:
    """Per axis, the mean |estimate - truth| [deg] over the last ``window_s`` of the flight's engaged samples (the
    window of the steady error): how far the autopilot's ATTITUDE was from the simulator's true attitude."""
    import math

    from mavastsm.bridge.record.flight_log import read_flight_log

    engaged = [s for s in read_flight_log(csv) if s.failsafe is None and math.isfinite(s.u_nm[0])]
    end = engaged[-1].vehicle_time_s
    tail = [s for s in engaged if s.vehicle_time_s >= end - window_s]
    pairs = list(zip(tail, against_truth(tail, truth)))
    return {axis: sum(abs(math.degrees(math.remainder(e.euler_rad[i] - t.euler_rad[i], 2.0 * math.pi))) for e, t in pairs) / len(pairs)
            for i, axis in enumerate(("roll", "pitch", "yaw"))}


def identification_phase(csv, out: str) -> dict:
    """The in-flight identification phase of an unrecognised vehicle's first flight (issue 27), on ArduCopter and PX4:
    said in the summary, at most 5 s of the flight, inside the envelope (the attitude within 10 deg of level: 5 deg
    doublets), and roll and pitch flown with the tau it found. Returns what it measured, for the record."""
    import json
    import math

    from mavastsm.bridge.record.flight_log import IDENTIFYING_PHASE, read_flight_rows

    line = next((ln.strip() for ln in out.splitlines() if ln.strip().startswith("loop identified in flight")), None)
    assert line is not None, out[-3000:]
    rows = [r for r in read_flight_rows(csv) if r.phase == IDENTIFYING_PHASE]
    span_s = rows[-1].sample.vehicle_time_s - rows[0].sample.vehicle_time_s
    tilt_deg = max(math.degrees(max(abs(r.sample.euler_rad[0]), abs(r.sample.euler_rad[1]))) for r in rows)
    assert span_s <= 5.0 and tilt_deg < 10.0, (span_s, tilt_deg)
    found = json.loads(csv.with_suffix(".json").read_text())["mapping"]["identified_in_flight"]["axes"]
    assert found["roll"]["applied"] and found["pitch"]["applied"], found
    return {"phase_s": round(span_s, 2), "phase_max_tilt_deg": round(tilt_deg, 1),
            "tau_identified_s": [round(found[a]["tau_eff_s"], 4) for a in ("roll", "pitch")]}


def band_entry(csv) -> dict:
    """Per axis, from its paper step: ``to_band_s``, the time until the estimate first enters its 5 % band [s] (inf
    when it never does): that the step was flown, and how fast; and ``at_limit_pct``, the share of the engaged cycles
    from that moment on whose body-rate command sat within 1 % of its limit (100 when the band is never reached).
    Where the estimate's own noise is as wide as the band (SIH), when it last leaves the band (the settling time) is
    the noise's, not the controller's, and ``control_quality``'s at-limit share, counted from the settling time, is
    100 % by definition whenever the noise is outside the band at the end of the run; counted from the first entry,
    it says whether the commands stayed off their limit once the step was flown."""
    import math

    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.bridge.record.flight_log import read_flight_log
    from mavastsm.bridge.record.tracking_metrics import at_limit_pct, engaged_samples, heading_at_engagement_rad, raw_errors
    from mavastsm.frames import AXES
    from mavastsm.references import load_reference

    samples = read_flight_log(csv)
    engaged = engaged_samples(samples)
    engage_t = engaged[0].vehicle_time_s
    ref = load_reference("paper_steps").relative_to((0.0, 0.0, heading_at_engagement_rad(engaged)))
    errors = raw_errors(samples, engage_t, ref)
    max_rate_rads = load_bridge_config(None, {"limits": {}}).limits.max_rate_cmd_rads
    out = {}
    for i, axis in enumerate(AXES):
        step = next(c for c in ref.components if c.axis == i and c.kind == "step")
        band = 0.05 * abs(step.angle_rad)
        to_band = next((t - step.start_s for t, e in errors if t >= step.start_s and abs(e[i]) <= band), math.inf)
        at_limit = at_limit_pct(engaged, engage_t, step.start_s + to_band, i, max_rate_rads[i])
        out[axis] = {"to_band_s": round(to_band, 3), "at_limit_pct": round(at_limit, 2)}
    return out


TAKEOFF_ARRIVAL_M = 0.2  # [m] the bridge's --takeoff: height at engagement and highest before it, off the target


def takeoff_heights_m(csv) -> dict:
    """The bridge's own --takeoff in a flight CSV: the altitude [m above home] at the first engaged row and the highest
    before it (the climb and the level hold), for the README's 2 m (docs/bridge.md, "Takeoff": genuine ArduCopter
    braking from full climb at the target once overshot it by 0.78-0.80 m)."""
    import math

    from mavastsm.bridge.record.flight_log import ENGAGED_PHASE, read_flight_rows

    rows = [r for r in read_flight_rows(csv) if math.isfinite(r.altitude_m)]
    first = next(i for i, r in enumerate(rows) if r.phase == ENGAGED_PHASE)
    return {"at_engagement_m": round(rows[first].altitude_m, 3), "highest_before_m": round(max(r.altitude_m for r in rows[:first + 1]), 3)}
