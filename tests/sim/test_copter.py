"""SimulatedCopter end to end (no MAVLink): hover, sign conventions, LAND, determinism, scenario wiring,
pure-torque mode against the offline plant, read-out contract."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from copter_flight_tools import airborne_copter, coast, degrees, fly, heading_change_deg, offline_plant_stepper  # noqa: E402

from mavastsm import frames  # noqa: E402
from mavastsm_sim.copter import SimulatedCopter  # noqa: E402


def test_hover_equilibrium_in_guided_nogps():
    c = airborne_copter(2.0)
    fly(c, 3.0, thrust=0.5)  # let the climb-to-hold transient die out (6 s after the climb stopped)
    log = []
    fly(c, 4.0, thrust=0.5, record=log)
    pos = np.array([p for _, _, p, _ in log])
    vel = np.array([v for _, _, _, v in log])
    eul = np.array([e for _, e, _, _ in log])
    assert -2.4 < pos[-1, 2] < -1.6  # about 2 m up (NED down negative)
    assert np.ptp(pos[:, 2]) < 0.01  # altitude held within 1 cm over 4 s
    assert np.max(np.abs(vel)) < 0.01
    assert np.max(np.abs(degrees(eul[:, :2]))) < 0.05
    hover = c.params.get("MOT_THST_HOVER")
    assert abs(c.autopilot.throttle_in - hover) < 0.03  # throttle near MOT_THST_HOVER 0.37
    out = c.motor_outputs_norm
    assert np.ptp(out) < 0.02 and 0.4 < out.mean() < 0.8  # four equal motors (yaw balanced by spin pairs)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rate_command_sign_conventions(axis):
    """Positive roll rate -> right side down (roll up); positive pitch -> nose up; positive yaw -> heading
    increases (clockwise from above); a negative command then turns it the other way."""
    c = airborne_copter(3.0)
    for sign in (1.0, -1.0):
        fly(c, 1.0)  # zero rates: hold (the yaw acceleration limit needs 0.4 s per 0.5 rad/s)
        e0 = c.euler_rad.copy()
        rates = [0.0, 0.0, 0.0]
        rates[axis] = sign * 0.5
        fly(c, 0.6, rates=tuple(rates))
        assert sign * c.body_rates_rads[axis] > 0.4  # measured body rate follows (0.5 rad/s, accel-limited start)
        e1 = c.euler_rad
        change = heading_change_deg(e0[2], e1[2]) if axis == 2 else np.degrees(e1[axis] - e0[axis])
        assert sign * change > 10.0  # ~0.5 rad/s * 0.6 s = 17 deg, minus ramp-up, reversal and tracking lag
        for i in [i for i in range(3) if i != axis]:
            assert abs(np.degrees(e1[i] - e0[i])) < 3.0


def test_rate_command_integrates_into_attitude_hold_without_drift():
    """ArduCopter integrates rates into an attitude target: after the command returns to zero the
    vehicle holds the reached angle instead of drifting."""
    c = airborne_copter(3.0)
    fly(c, 0.4, rates=(0.5, 0.0, 0.0))
    fly(c, 0.5, rates=(0.0, 0.0, 0.0))
    r1 = c.euler_rad[0]
    fly(c, 1.0, rates=(0.0, 0.0, 0.0))
    assert np.degrees(r1) > 8.0
    assert abs(np.degrees(c.euler_rad[0] - r1)) < 0.5


def test_land_mode_descends_lands_and_disarms():
    c = airborne_copter(2.0)
    assert c.set_mode(9) == (True, "mode LAND")
    log = []
    coast(c, 2.0, record=log)
    vz = np.array([v[2] for *_, v in log])
    assert 0.4 < vz[-1] < 0.6  # LAND_SPEED 50 cm/s
    coast(c, 6.0)
    assert c.landed and not c.armed
    assert c.position_ned_m[2] == 0.0
    assert c.system_status == 3
    assert any("Disarming motors" in text for _, text in c.statustext_queue)


def test_time_and_fractional_steps():
    c = SimulatedCopter()
    for _ in range(5):
        c.step(0.0004)  # 2 ms in 0.4 ms pieces: exactly 2 physics steps at 1 kHz
    assert c.time_s == pytest.approx(0.002)
    c.step(float("nan"))
    c.step(-1.0)
    assert c.time_s == pytest.approx(0.002)
    c.step(1.0)
    assert c.time_s == pytest.approx(1.002)


def test_deterministic_for_a_seed_with_noise():
    def run(seed):
        c = SimulatedCopter(seed=seed, noise=True)
        c.set_mode(20)
        c.arm()
        fly(c, 1.0, rates=(0.2, -0.1, 0.3), thrust=0.7)
        return c.position_ned_m, c.euler_rad

    a, b, other = run(7), run(7), run(8)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], other[0])


def test_sensor_noise_has_configured_size():
    c = SimulatedCopter(noise=True, seed=3)
    c.set_mode(20)
    c.arm()
    errs = []
    for _ in range(200):
        c.step(0.01)
        errs.append(c.body_rates_rads - c.true_body_rates_rads)
    std = np.std(np.array(errs), axis=0)
    expected = c.config.sensor_noise.gyro_noise_std
    assert np.all((0.7 * expected < std) & (std < 1.3 * expected))


def test_pure_torque_mode_with_scenario_inertia_matches_offline_plant():
    """Motors, drag, gyroscopic torque and gravity off: the attitude response to a torque input equals
    the offline paper-mode plant with the scenario's true (full 3x3) inertia."""
    c = SimulatedCopter(scenario="variation", motors=False, aero_drag=False, gyroscopic=False, gravity=False,
                        initial_position_ned_m=(0.0, 0.0, -100.0))
    inertia = c.inertia_kgm2
    assert abs(inertia[1, 2]) > 0.0  # products of inertia present
    plant_step = offline_plant_stepper(inertia)
    torque = np.array([0.01, -0.02, 0.015])
    c.set_external_torque(tuple(torque))
    e, w = np.zeros(3), np.zeros(3)
    for _ in range(1500):
        c.step(1e-3)
        e, w = plant_step(e, w, torque, 1e-3)
    assert np.max(np.abs(e)) > 0.3
    assert np.allclose(c.euler_rad, e, atol=1e-6)
    assert np.allclose(c.body_rates_rads, w, atol=1e-6)


def test_scenario_disturbance_torque_reaches_the_plant():
    c = SimulatedCopter(scenario="disturbance_roll", motors=False, aero_drag=False, gyroscopic=False, gravity=False,
                        initial_position_ned_m=(0.0, 0.0, -100.0))
    events = c.scenario.disturbances
    t_on = min(ev.start_s for ev in events)
    d = np.sum([ev.torque_nm for ev in events], axis=0)
    c.step(t_on - 0.1)
    assert np.allclose(c.body_rates_rads, 0.0)
    c.step(0.2)  # 0.1 s with the torque on
    expected = np.linalg.solve(c.inertia_kgm2, d) * 0.1
    assert np.allclose(c.body_rates_rads, expected, rtol=0.02, atol=1e-3)


def test_readout_contract_types_and_shapes():
    c = SimulatedCopter()
    c.step(0.01)
    assert isinstance(c.time_s, float)
    assert c.quaternion_wxyz.shape == (4,) and c.euler_rad.shape == (3,) and c.body_rates_rads.shape == (3,)
    assert c.position_ned_m.shape == (3,) and c.velocity_ned_ms.shape == (3,)
    q, rates, thrust = c.attitude_target
    assert q.shape == (4,) and rates.shape == (3,) and isinstance(thrust, float)
    assert c.motor_outputs_norm.shape == (4,)
    assert isinstance(c.battery_voltage_v, float) and 13.0 < c.battery_voltage_v <= 16.8
    assert isinstance(c.battery_remaining_pct, int) and 99 <= c.battery_remaining_pct <= 100  # AP truncates
    assert (c.mode_number, c.armed, c.landed, c.system_status) == (0, False, True, 3)
    assert np.allclose(c.euler_rad, frames.euler_from_quaternion(c.quaternion_wxyz))


def test_battery_drains_faster_in_flight():
    c = airborne_copter(2.0)
    assert c.battery_consumed_mah > 10.0  # ~5 s at ~15 A = ~20 mAh
    v_hover = c.battery_voltage_v
    assert c.config.battery.voltage_empty < v_hover < c.config.battery.voltage_full
    assert c.system_status == 4


@pytest.mark.parametrize("loop_hz,expected", [(400.0, 400), (1000.0, 1000), (300.0, 300), (2000.0, 1000)])
def test_autopilot_runs_at_sched_loop_rate(loop_hz, expected, monkeypatch):
    c = SimulatedCopter()
    c.params.set("SCHED_LOOP_RATE", loop_hz)
    ticks = []
    original = c.autopilot.update

    def counting(meas, dt, contact, now_s=None):
        ticks.append((now_s, dt))
        return original(meas, dt, contact, now_s=now_s)

    monkeypatch.setattr(c.autopilot, "update", counting)
    c.step(2.0)
    in_second = [t for t, _ in ticks if 1.0 <= t < 2.0]
    assert len(in_second) == expected
    assert all(dt == pytest.approx(1.0 / expected) for _, dt in ticks)  # capped at the physics rate


def test_wind_gust_from_scenario_yaml_pushes_the_vehicle(tmp_path):
    """A scenario file's optional ``wind:`` section (sim only) acts through the translational drag: a
    1-cos gust blowing toward north (+x NED) carries a hovering copter north."""
    path = tmp_path / "gusty.yaml"
    path.write_text(
        "description: test gust\n"
        "scenario:\n  reference: paper_steps\n  duration_s: 5.0\n"
        "wind:\n  gusts:\n    - {start_s: 6.0, duration_s: 2.0, peak_ned_ms: [8.0, 0.0, 0.0]}\n"
    )
    c = airborne_copter(3.0, scenario=str(path))
    assert c.disturbances.gusts
    assert c.time_s < 6.0
    x0 = c.position_ned_m[0]
    fly(c, 8.5 - c.time_s, thrust=0.5)  # GUIDED_NOGPS attitude hold: no position hold, the gust carries it
    assert c.position_ned_m[0] - x0 > 0.5
    assert c.velocity_ned_ms[0] > 0.2


def test_bad_wind_section_is_a_one_line_config_error(tmp_path):
    from mavastsm.errors import ConfigError

    path = tmp_path / "bad.yaml"
    path.write_text("scenario:\n  reference: paper_steps\nwind:\n  gusts:\n    - {start_s: 1.0, duration_s: -2.0, peak_ned_ms: [1, 0, 0]}\n")
    with pytest.raises(ConfigError, match=r"wind.gusts\[0\].duration_s"):
        SimulatedCopter(scenario=str(path))


def test_restart_disturbance_clock_shifts_scenario_torques():
    c = SimulatedCopter(scenario="disturbance_pulse", motors=False, aero_drag=False, gyroscopic=False, gravity=False,
                        initial_position_ned_m=(0.0, 0.0, -100.0))

    def momentum():  # |I omega| is conserved while no torque acts (the body tumbles, rates change)
        return np.linalg.norm(c.inertia_kgm2 @ c.body_rates_rads)

    c.step(10.0)  # the pulse (4-5 s after boot) has come and gone
    h0 = momentum()
    assert h0 > 0.3  # 0.5 N m on each axis for 1 s
    c.restart_disturbance_clock()  # now the same pulse comes again 4 s from now
    c.step(3.9)
    assert momentum() == pytest.approx(h0, rel=1e-6)
    c.step(0.3)
    assert abs(momentum() - h0) > 0.05


@pytest.mark.parametrize("edit,key", [
    (("max_motor_speed:\n    value: 1100.0", "max_motor_speed:\n    value: -5.0"), "propulsion.max_motor_speed"),
    (("ATC_ANG_RLL_P: {value: 4.5", "ATC_ANG_RLX_P: {value: 4.5"), "autopilot.ATC_ANG_RLX_P"),
    (("  gyro_noise_std:", "  gyro_noise_sd:"), "sensor_noise.gyro_noise_sd"),
])
def test_bad_vehicle_file_is_a_one_line_config_error(tmp_path, edit, key):
    from mavastsm.config_loading import resolve_config
    from mavastsm.errors import ConfigError

    text = resolve_config("solo", "vehicle").read_text()
    assert edit[0] in text
    bad = tmp_path / "bad_solo.yaml"
    bad.write_text(text.replace(edit[0], edit[1]))
    with pytest.raises(ConfigError) as info:
        SimulatedCopter(vehicle_config=bad)
    message = str(info.value)
    assert "\n" not in message and key in message and str(bad) in message


def test_time_boot_ms_is_exact():
    c = SimulatedCopter()
    for k in range(1, 3000):
        c.step(0.001)
        assert c.time_boot_ms == k
