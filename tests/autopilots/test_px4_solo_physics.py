"""Genuine PX4, tuned as a Solo (configs/px4/solo.params), flying our Solo physics over PX4's simulator interface
(sim/px4_hil.py), with the README's PX4 command on top (``pytest -m px4``; MAVASTSM_PX4, see conftest).

SIH, PX4's built-in simulator, is the stock-vehicle check (test_px4.py); its IMU noise (hard-coded, 15-70 times a
Solo's) and its 0.025 kg m^2 vehicle keep the bounds out of reach there. Here the firmware flies the paper's Solo
with a Solo's sensors, so the bridge is held to every bound of the ArduCopter issue. The SIGKILL and hand-back
checks run on this vehicle too (test_px4.py's module fixture boots both).
"""

from __future__ import annotations

import math
import signal
import time

import pytest
from bridge_process import assert_no_traceback, sim_pair_in_private_namespace
from control_quality import assert_control_quality_bounds, control_quality, estimator_error_deg, identification_phase
from mavastsm_sim.genuine_observer import observe_cold

from mavastsm.readme_commands import readme_argv

pytestmark = [pytest.mark.px4, pytest.mark.timeout(400)]

README_PX4 = readme_argv("px4")  # the README's command (mavastsm.readme_commands)


def test_readme_px4_command_from_a_cold_start_meets_every_bound_on_the_solo(cold_px4_solo, record, tmp_path):
    """Started within 5 s of PX4: exit 0, LAND accepted, and every control-quality bound (control_quality.py) from
    ATTITUDE and from the true attitude the simulator kept (at PX4's time_boot_ms, which lockstep makes its time).
    The Solo's PX4 tuning (MC_ROLLRATE_P 0.135) is not px4_sih_quadx's, so the loop is identified in flight first."""
    v = cold_px4_solo
    b = v.bridge(README_PX4 + ["--no-dashboard", "--log", str(tmp_path)])
    started_after_s = time.monotonic() - v.sitl.started_monotonic
    assert started_after_s < 5.0, started_after_s
    _assert_every_bound(v, b, tmp_path, record, "PX4 1.15 + Solo physics (simulator_mavlink): README command from a cold start",
                        identified=True, bridge_started_after_px4_s=round(started_after_s, 1))


def _assert_every_bound(v, b, log_dir, record, label: str, identified: bool, **extra) -> str:
    """Observe the cold vehicle, wait for the bridge ``b`` (logging into ``log_dir``), then: exit 0, LAND accepted, no
    lockstep fault, the identification phase flown (``identified``, control_quality.identification_phase) or not, and
    every bound from ATTITUDE and from the simulator's true attitude. Returns its output."""
    server = v.sitl.companions[0]
    observe_cold(v)
    rc = b.wait(300.0)
    out = b.output
    assert rc == 0, f"lockstep: {server.counters.summary()}\n{out[-3000:]}"
    assert_no_traceback(out)
    assert "end: duration complete; hand-back: LAND accepted" in out, out[-2000:]
    assert server.error is None, repr(server.error)
    csv = sorted(log_dir.glob("*.csv"))[-1]
    if identified:
        extra.update(identification_phase(csv, out))
    else:
        assert "loop identified in flight" not in out, out[-3000:]
    measured = control_quality(csv)
    true = control_quality(csv, truth=server.physics.true_attitude_at)
    record(f"{label}, control quality (astsm)", lockstep=server.counters.summary(), sim_time_s=round(server.physics.time_s, 1),
           **extra, **measured)
    est = estimator_error_deg(csv, server.physics.true_attitude_at)
    record(f"{label}: the same flight against the true attitude", estimator_error_deg=est, **true)
    assert server.counters.actuator_timeouts == 0, server.counters.summary()
    assert_control_quality_bounds(measured)
    # against the truth: every bound, the steady error allowing EKF2's own error in that window (its heading is
    # 0.3-0.55 deg off the truth on this rig, docs/sim.md); no other bound is relaxed
    assert_control_quality_bounds(true, est)
    return out


# Issue 27 on PX4: rate and angle tunings no packaged description was measured at (px4_sih_quadx is recognised by PX4's
# default MC_* gains only), so px4_sih_quadx's loop numbers stand in and the loop is identified in flight first, as on
# the Solo's own tuning above. Each checked first with PX4 alone
# (its own attitude controller, the same steps, benchmarks/paper_on_genuine.fly_px4_alone, 2026-12-06): it flies both,
# roll 5 % settling 2.04 / 2.95 s, yaw 0.48 / 0.87 deg steady (stiffer / softer).
PX4_RETUNES = {
    "stiffer": {"MC_ROLLRATE_P": 0.2, "MC_ROLLRATE_I": 0.2, "MC_PITCHRATE_P": 0.2, "MC_PITCHRATE_I": 0.2,
                "MC_YAWRATE_P": 0.3, "MC_YAWRATE_I": 0.15, "MC_ROLL_P": 8.0, "MC_PITCH_P": 8.0, "MC_YAW_P": 4.0},
    "softer": {"MC_ROLLRATE_P": 0.1, "MC_ROLLRATE_I": 0.06, "MC_PITCHRATE_P": 0.1, "MC_PITCHRATE_I": 0.06,
               "MC_YAWRATE_P": 0.15, "MC_ROLL_P": 5.0, "MC_PITCH_P": 5.0, "MC_YAW_P": 2.0},
}


@pytest.mark.parametrize("retune", list(PX4_RETUNES))
def test_an_unrecognised_px4_tuning_meets_every_bound_on_its_first_flight(px4_build, record, tmp_path, retune):
    """Issue 27 on PX4: the Solo physics with PX4's rate and angle gains retuned, the README command with no extra
    option from a cold start: the loop identified in flight (as on ArduCopter), then every bound, from ATTITUDE and
    against the truth. Then the flight's --save-vehicle file (the tau found, the MC_* tuning it was found at), flown
    with --vehicle on a fresh boot of the same tuning, meets them again without the phase (a second flight on the PX4
    that has just landed is not a first flight: EKF2 was 0.38 deg off in pitch and 0.48 deg in heading there).

    Without the phase the softer tuning flew px4_sih_quadx's tau 0.05 s against a loop of 0.060 / 0.077 s: the 45 deg
    yaw step pulled pitch 0.40-0.44 deg off (ATTITUDE) and 0.45-0.52 deg (truth, EKF2 0.06-0.08 deg off), so the
    truth's pitch left its 0.5 deg band in 1 flight of 4 (CI failed on it). With the phase: 0.23-0.29 / 0.32-0.37 deg
    (4 flights, 2026-12-06)."""
    from mavastsm_sim.genuine_sitl import px4_solo_params_path
    from mavastsm_sim.genuine_observer import boot_px4_solo_physics

    params = tmp_path / "solo_retuned.params"
    params.write_text(px4_solo_params_path().read_text() + "".join(f"param set {k} {x:g}\n" for k, x in PX4_RETUNES[retune].items()))
    saved = tmp_path / "retuned.yaml"
    with boot_px4_solo_physics(px4_build, attitude_history_s=120.0, params=params) as v:
        first = v.bridge(README_PX4 + ["--no-dashboard", "--log", str(tmp_path / "first"), "--save-vehicle", str(saved)])
        out = _assert_every_bound(v, first, tmp_path / "first", record, f"PX4 + Solo physics, {retune} tuning: first flight",
                                  identified=True)
        assert "vehicle description: px4_sih_quadx (no packaged description matches its tuning" in out, out[-3000:]
        assert f"vehicle description saved: {saved}" in out, out[-3000:]
    with boot_px4_solo_physics(px4_build, attitude_history_s=120.0, params=params) as v:
        again = v.bridge(README_PX4 + ["--no-dashboard", "--log", str(tmp_path / "again"), "--vehicle", str(saved)])
        out = _assert_every_bound(v, again, tmp_path / "again", record, f"PX4 + Solo physics, {retune} tuning: --vehicle FILE",
                                  identified=False)
        assert f"vehicle description: {saved}" in out and "another tuning" not in out, out[:3000]


ALTITUDE_BAND_M = 0.5  # [m] the engaged altitude stays within this of the hold it engaged at (issue 26)


def test_variation_payload_bridge_hovers_at_the_collective_px4_holds_with(px4_build, record, tmp_path):
    """The paper's ``variation`` (0.8 kg payload, Table 3's inertia) in the physics from boot: PX4's own takeoff holds
    the heavier vehicle at about 0.56, MPC_THR_HOVER says 0.364. The README command must complete the profile and
    keep the altitude within ALTITUDE_BAND_M of the engagement's (the bridge's hover measured from PX4's hold;
    at MPC_THR_HOVER plus the altitude hold's 0.15 the vehicle sank onto the ground within the profile)."""
    from mavastsm.bridge.record.flight_log import read_flight_rows
    from mavastsm_sim.genuine_observer import boot_px4_solo_physics

    with boot_px4_solo_physics(px4_build, ready=True, scenario="variation") as v:
        server = v.sitl.companions[0]
        b = v.bridge(README_PX4 + ["--duration-s", "5", "--no-dashboard", "--log", str(tmp_path)])
        rc = b.wait(300.0)
        out = b.output
        assert rc == 0, f"lockstep: {server.counters.summary()}\n{out[-3000:]}"
        assert_no_traceback(out)
        assert "end: duration complete; hand-back: LAND accepted" in out, out[-2000:]
        hover_line = next((ln.strip() for ln in out.splitlines() if "hover collective" in ln and "from PX4's hold" in ln), None)
        assert hover_line is not None, out[-3000:]  # the hover collective came from the vehicle's own hold
        rows = read_flight_rows(sorted(tmp_path.glob("*.csv"))[-1])
        engaged = [r for r in rows if r.phase == "engaged" and math.isfinite(r.altitude_m)]
        assert engaged, "no engaged row with an altitude"
        hold_m = engaged[0].altitude_m
        deviation = [r.altitude_m - hold_m for r in engaged]
        thrust = [r.sample.thrust_norm for r in engaged if math.isfinite(r.sample.thrust_norm)]
        record("PX4 1.15 + Solo physics, variation (0.8 kg payload): altitude held by the bridge (astsm)",
               hold_m=round(hold_m, 2), min_dev_m=round(min(deviation), 3), max_dev_m=round(max(deviation), 3),
               end_dev_m=round(deviation[-1], 3), thrust_mean=round(sum(thrust) / len(thrust), 3),
               hover=hover_line, lockstep=server.counters.summary())
        assert max(abs(d) for d in deviation) <= ALTITUDE_BAND_M, (min(deviation), max(deviation))
        assert server.error is None, repr(server.error)


def test_mavastsm_sim_autopilot_px4_starts_the_pair_and_stops_cleanly(px4_build):
    """``mavastsm sim --autopilot px4`` as a user types it (the tests above boot the same rig from Python and fly the
    README's PX4 command on it): the banner names the README's PX4 command, PX4 connects to the simulator interface
    and runs in lockstep, and SIGTERM stops the pair cleanly (exit 0, its end line with the lockstep counted)."""
    build = px4_build[0].parents[1]  # the build folder (bin/px4, etc/)
    with sim_pair_in_private_namespace(["sim", "--autopilot", "px4", "--px4", str(build)]) as (sim, _rig):
        sim.wait_line(r"^mavastsm sim: genuine PX4 .* connect with 'mavastsm connect udpin:0\.0\.0\.0:14540 ", 30.0)
        sim.wait_line(r"^mavastsm sim: PX4 connected after \d+ s", 120.0)
        sim.signal(signal.SIGTERM)
        assert sim.wait(30.0) == 0, sim.output[-3000:]
    assert_no_traceback(sim.output)
    last = sim.lines[-1]
    assert last.startswith("mavastsm sim: stopped at t=") and "lockstep:" in last, sim.output[-2000:]
    assert float(last.split("t=")[1].split()[0]) > 0.0, last  # the physics stepped with PX4
