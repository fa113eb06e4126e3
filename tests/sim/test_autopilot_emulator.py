"""ArduCopter 4.2+ emulation behind SET_ATTITUDE_TARGET (docs/design-decisions.md, MAV-3, MAV-5): guided gate, type_mask
validation, climb-rate vs collective-thrust semantics, GUID_TIMEOUT, ground handling, arming rules,
auto-disarm, and a parameter table whose entries really change behaviour."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from copter_flight_tools import ATTITUDE_THRUST, IDENTITY, RATES_THRUST, airborne_copter, coast, fly  # noqa: E402

from mavastsm import frames  # noqa: E402
from mavastsm_sim.arducopter_profile import load_profile  # noqa: E402
from mavastsm_sim.copter import SimulatedCopter  # noqa: E402
from mavastsm_sim.parameters import MAV_PARAM_TYPE_REAL32, ParameterTable  # noqa: E402


# ---------------------------------------------------------------- gate and mask validation
def test_attitude_target_ignored_outside_guided_modes():
    c = SimulatedCopter()
    for mode in (0, 2, 5, 9):
        c.set_mode(mode)
        assert c.handle_attitude_target(RATES_THRUST, IDENTITY, (0.1, 0, 0), 0.8) == (False, "not in guided mode")
    assert c.rejected_attitude_targets == 0


@pytest.mark.parametrize("mask,q,why", [
    (RATES_THRUST | 0x40, IDENTITY, "THROTTLE_IGNORE"),
    (0x81, IDENTITY, "mixed"),  # roll-rate ignore only
    (0x86, IDENTITY, "mixed"),
    (0x03, IDENTITY, "mixed"),  # attitude + yaw rate (dropped in 4.2)
    (0x07, (0.9, 0.0, 0.0, 0.0), "unit"),
    (0x07, (float("nan"), 0.0, 0.0, 0.0), "unit"),
])
def test_bad_masks_and_quaternions_are_rejected_and_the_vehicle_stops(mask, q, why):
    c = airborne_copter(3.0)
    fly(c, 0.5, rates=(0.5, 0.0, 0.0), thrust=0.7)  # rolling right and climbing
    assert np.degrees(c.euler_rad[0]) > 5.0 and c.velocity_ned_ms[2] < -0.5
    ok, reason = c.handle_attitude_target(mask, q, (0.5, 0.0, 0.0), 0.7)
    assert not ok and why in reason
    assert c.rejected_attitude_targets == 1
    coast(c, 2.0)  # nothing more is sent; the hold must stop the roll and the climb
    assert abs(np.degrees(c.euler_rad[0])) < 1.0
    assert abs(c.velocity_ned_ms[2]) < 0.1
    assert c.mode_number == 20 and c.armed


@pytest.mark.parametrize("mask", [0x80, 0x87, 0x07, 0x00])
def test_usable_masks_are_accepted(mask):
    c = SimulatedCopter()
    c.set_mode(4)
    assert c.handle_attitude_target(mask, IDENTITY, (0.0, 0.0, 0.0), 0.5) == (True, "ok")


def test_attitude_quaternion_target_is_tracked():
    c = airborne_copter(3.0)
    q = tuple(frames.quaternion_from_euler([math.radians(10.0), math.radians(-5.0), math.radians(30.0)]))
    fly(c, 3.0, mask=ATTITUDE_THRUST, q=q, thrust=0.5)
    assert np.allclose(np.degrees(c.euler_rad), [10.0, -5.0, 30.0], atol=0.5)
    target_q, _, _ = c.attitude_target
    assert np.allclose(np.abs(np.dot(target_q, q)), 1.0, atol=1e-6)


# ---------------------------------------------------------------- thrust semantics
def test_thrust_is_climb_rate_by_default():
    c = airborne_copter(2.0)
    fly(c, 3.0, thrust=1.0)
    assert c.velocity_ned_ms[2] == pytest.approx(-2.5, abs=0.05)  # WPNAV_SPEED_UP 250 cm/s
    fly(c, 3.0, thrust=0.0)
    assert c.velocity_ned_ms[2] == pytest.approx(1.5, abs=0.05)  # WPNAV_SPEED_DN 150 cm/s
    fly(c, 3.0, thrust=0.25)
    assert c.velocity_ned_ms[2] == pytest.approx(0.75, abs=0.05)  # halfway down the lower half


def test_wpnav_speed_up_parameter_changes_climb_rate():
    c = airborne_copter(2.0)
    assert c.params.set("WPNAV_SPEED_UP", 100.0) == (True, "ok")
    fly(c, 3.0, thrust=1.0)
    assert c.velocity_ned_ms[2] == pytest.approx(-1.0, abs=0.05)


def test_thrust_as_collective_with_guid_options_bit3():
    c = airborne_copter(5.0)
    assert c.params.set("GUID_OPTIONS", 8.0)[0]
    hover = c.params.get("MOT_THST_HOVER")
    v0 = c.velocity_ned_ms[2]
    fly(c, 0.5, thrust=0.8)  # well above hover: accelerates up
    up_accel = -(c.velocity_ned_ms[2] - v0) / 0.5
    assert up_accel > 5.0
    assert c.autopilot.throttle_in == pytest.approx(0.8)  # thrust passed through, not a climb rate
    v1 = c.velocity_ned_ms[2]
    fly(c, 0.5, thrust=0.5 * hover)  # below hover: accelerates down (a climb-rate reading would climb)
    down_accel = (c.velocity_ned_ms[2] - v1) / 0.5
    assert down_accel > 3.0  # ideal 0.5 g = 4.9 m/s^2, minus motor lag
    assert c.autopilot.throttle_in == pytest.approx(0.5 * hover)


def test_angle_boost_in_thrust_mode():
    c = airborne_copter(5.0)
    c.params.set("GUID_OPTIONS", 8.0)
    q = tuple(frames.quaternion_from_euler([math.radians(20.0), 0.0, 0.0]))
    fly(c, 1.0, mask=ATTITUDE_THRUST, q=q, thrust=0.37)
    cos_tilt = math.cos(c.euler_rad[0]) * math.cos(c.euler_rad[1])
    assert c.autopilot.throttle_out == pytest.approx(0.37 / cos_tilt, rel=1e-3)


# ---------------------------------------------------------------- GUID_TIMEOUT
def test_guid_timeout_levels_at_current_yaw_and_holds_altitude():
    c = airborne_copter(3.0)
    q = tuple(frames.quaternion_from_euler([math.radians(12.0), 0.0, math.radians(40.0)]))
    fly(c, 2.0, mask=ATTITUDE_THRUST, q=q, thrust=0.6)  # leaning and climbing at 0.5 m/s
    log = []
    coast(c, 2.9, record=log)  # silence, still inside the 3 s timeout
    assert np.degrees(c.euler_rad[0]) == pytest.approx(12.0, abs=0.5)
    assert c.velocity_ned_ms[2] == pytest.approx(-0.5, abs=0.05)
    coast(c, 3.0)
    assert abs(np.degrees(c.euler_rad[0])) < 0.5 and abs(np.degrees(c.euler_rad[1])) < 0.5
    assert np.degrees(c.euler_rad[2]) == pytest.approx(40.0, abs=1.0)
    assert abs(c.velocity_ned_ms[2]) < 0.05
    assert c.mode_number == 20 and c.armed and not c.landed
    assert c.statustext_queue == [(6, "Arming motors")]  # no STATUSTEXT for the timeout, like ArduCopter


def test_guid_timeout_parameter_and_thrust_mode_fallback_to_climb_control():
    c = airborne_copter(5.0)
    c.params.set("GUID_TIMEOUT", 1.0)
    c.params.set("GUID_OPTIONS", 8.0)
    fly(c, 0.3, thrust=0.45)  # collective above hover: climbing
    coast(c, 0.8)
    assert c.velocity_ned_ms[2] < -0.3  # still obeying the (stale) thrust before 1 s
    coast(c, 3.0)
    assert abs(c.velocity_ned_ms[2]) < 0.05  # fell back to zero climb rate, not to a fixed thrust


# ---------------------------------------------------------------- ground handling, arming, disarming
def test_rate_commands_on_the_ground_do_nothing_until_positive_climb():
    c = SimulatedCopter()
    c.set_mode(20)
    c.arm()
    fly(c, 2.0, rates=(1.0, 0.5, 1.0), thrust=0.5)  # rates with "hold altitude": no take-off
    assert c.landed and c.position_ned_m[2] == 0.0
    assert np.allclose(c.euler_rad[:2], 0.0)
    spin_arm = c.params.get("MOT_SPIN_ARM")
    assert np.allclose(c.motor_outputs_norm, spin_arm)  # ground idle
    fly(c, 1.0, rates=(0.0, 0.0, 0.0), thrust=0.6)  # positive climb demand: take-off
    assert not c.landed and c.position_ned_m[2] < -0.1


def test_collective_thrust_zero_stays_on_ground():
    c = SimulatedCopter()
    c.params.set("GUID_OPTIONS", 8.0)
    c.set_mode(4)
    c.arm()
    fly(c, 1.0, thrust=0.0)
    assert c.landed and np.allclose(c.motor_outputs_norm, c.params.get("MOT_SPIN_ARM"))
    fly(c, 1.0, thrust=0.6)
    assert not c.landed and c.position_ned_m[2] < -0.1


def test_auto_disarm_after_disarm_delay():
    c = SimulatedCopter()
    c.set_mode(20)
    assert c.arm() == (True, "armed")
    fly(c, 9.9, thrust=0.5)
    assert c.armed
    fly(c, 0.2, thrust=0.5)
    assert not c.armed
    assert any(text.startswith("Disarming motors") for _, text in c.statustext_queue)


@pytest.mark.parametrize("delay,armed_after_15s", [(0.0, True), (3.0, False)])
def test_disarm_delay_parameter(delay, armed_after_15s):
    c = SimulatedCopter()
    c.params.set("DISARM_DELAY", delay)
    c.set_mode(2)
    c.arm()
    coast(c, 2.9 if delay else 15.0)
    assert c.armed
    coast(c, 0.2)
    assert c.armed is armed_after_15s


def test_arming_refused_in_land():
    c = SimulatedCopter()
    assert c.set_mode(9)[0]
    assert c.arm() == (False, "Arm: Mode not armable")
    assert c.arm(force=True) == (False, "Arm: Mode not armable")
    assert (2, "Arm: Mode not armable") in c.statustext_queue
    assert not c.armed


def test_disarm_in_flight_needs_force():
    c = airborne_copter(2.0)
    ok, reason = c.disarm()
    assert not ok and "not landed" in reason and c.armed
    assert c.disarm(force=True) == (True, "disarmed")
    coast(c, 2.0)
    assert c.landed and c.position_ned_m[2] == 0.0  # fell and rests on the ground


def test_modes_numbers_and_unsupported_modes():
    c = SimulatedCopter()
    assert c.mode_number == 0 and c.set_mode(0) == (True, "already in mode")  # boots in STABILIZE
    for number, name in ((2, "ALT_HOLD"), (4, "GUIDED"), (5, "LOITER"), (9, "LAND"), (20, "GUIDED_NOGPS"), (0, "STABILIZE")):
        assert c.set_mode(number) == (True, f"mode {name}") and c.mode_name == name
    assert c.set_mode(0) == (True, "already in mode")
    ok, _ = c.set_mode(1)  # ACRO needs RC sticks: not emulated
    assert not ok and c.mode_number == 0
    assert not c.set_mode(8)[0]  # unused number
    assert not c.set_mode("x")[0]


def test_non_guided_modes_hold_level_and_altitude_in_flight():
    c = airborne_copter(3.0)
    fly(c, 0.5, rates=(0.0, 0.0, 0.0), thrust=0.8)  # climbing
    z = c.position_ned_m[2]
    for mode in (2, 5, 0):
        assert c.set_mode(mode)[0]
        coast(c, 3.0)
        assert abs(c.velocity_ned_ms[2]) < 0.05
        assert np.max(np.abs(np.degrees(c.euler_rad[:2]))) < 0.5
    assert -0.7 < c.position_ned_m[2] - z < 0.0  # stopped within a short distance above


def test_loiter_brakes_horizontal_motion():
    c = airborne_copter(3.0)
    q = tuple(frames.quaternion_from_euler([0.0, math.radians(-10.0), 0.0]))
    fly(c, 2.0, mask=ATTITUDE_THRUST, q=q)  # nose down: accelerating north
    assert c.velocity_ned_ms[0] > 2.0
    c.set_mode(5)
    coast(c, 8.0)
    assert np.linalg.norm(c.velocity_ned_ms[:2]) < 0.1


# ---------------------------------------------------------------- parameter table
def test_parameter_table_is_index_consistent_and_validates_sets():
    t = ParameterTable.from_vehicle_config()
    names = [t.by_index(i).name for i in range(t.count)]
    assert len(set(names)) == t.count and all(len(n) <= 16 for n in names)
    assert all(t.index_of(n) == i for i, n in enumerate(names))
    assert t.by_index(t.count) is None and t.by_index(-1) is None
    assert t.get("ATC_ACCEL_R_MAX") == 36000.0 and t.get("MOT_THST_HOVER") == pytest.approx(0.37)  # Solo_AC35
    assert t.get("GUID_TIMEOUT") == 3.0 and t.get("DISARM_DELAY") == 10.0 and t.get("SCHED_LOOP_RATE") == 400.0
    assert t.entry("GUID_TIMEOUT").param_type == MAV_PARAM_TYPE_REAL32
    assert not t.set("GUID_TIMEOUT", float("nan"))[0] and not t.set("GUID_TIMEOUT", float("inf"))[0]
    assert t.set("FORMAT_VERSION", 1.0)[0] is False
    assert t.set("NO_SUCH_PARAM", 1.0)[0] is False
    assert t.set("DISARM_DELAY", 4.6) == (True, "ok") and t.get("DISARM_DELAY") == 5.0  # INT8 rounds
    seen = []
    t.on_change(lambda n, v: seen.append((n, v)))
    t.set("SCHED_LOOP_RATE", 1000.0)
    assert seen == [("SCHED_LOOP_RATE", 1000.0)]


def test_sched_loop_rate_changes_autopilot_rate():
    c = SimulatedCopter()
    assert c.autopilot.loop_rate_hz == 400.0
    c.params.set("SCHED_LOOP_RATE", 1000.0)
    assert c.autopilot.loop_rate_hz == 1000.0
    c.set_mode(20)
    c.arm()
    fly(c, 2.0, thrust=0.75)
    assert c.position_ned_m[2] < -1.0


def _roll_step(params: dict, seconds: float):
    c = airborne_copter(3.0)
    for name, value in params.items():
        assert c.params.set(name, value)[0]
    q = tuple(frames.quaternion_from_euler([math.radians(10.0), 0.0, 0.0]))
    fly(c, seconds, mask=ATTITUDE_THRUST, q=q)
    target_roll = frames.euler_from_quaternion(c.attitude_target[0])[0]
    return np.degrees(c.euler_rad[0]), np.degrees(target_roll)


def test_accel_limit_parameter_slows_the_attitude_target():
    fast, _ = _roll_step({"ATC_ACCEL_R_MAX": 36000.0}, 0.2)
    slow, _ = _roll_step({"ATC_ACCEL_R_MAX": 4000.0}, 0.2)
    assert fast > slow + 2.0


def test_angle_p_parameter_tightens_tracking_of_the_target():
    actual_hi, target_hi = _roll_step({"ATC_ANG_RLL_P": 9.0}, 0.15)
    actual_lo, target_lo = _roll_step({"ATC_ANG_RLL_P": 2.0}, 0.15)
    assert target_hi == pytest.approx(target_lo, abs=1e-9)  # shaping does not depend on the P gain
    assert abs(target_hi - actual_hi) < 0.7 * abs(target_lo - actual_lo)


def test_land_detector_in_guided_then_auto_disarm():
    """Descending onto the ground in GUIDED_NOGPS: land_complete about 1 s after touchdown (throttle at its
    lower limit, no motion), ground idle, then DISARM_DELAY later the vehicle disarms itself."""
    c = airborne_copter(1.5)
    c.params.set("DISARM_DELAY", 4.0)
    touchdown = None
    landed_at = None
    for _ in range(400):
        fly(c, 0.02, thrust=0.2)  # -0.9 m/s climb demand, kept up after touchdown
        if touchdown is None and c.position_ned_m[2] == 0.0:
            touchdown = c.time_s
        if landed_at is None and c.landed:
            landed_at = c.time_s
            break
    assert touchdown is not None and landed_at is not None
    assert 0.9 <= landed_at - touchdown <= 3.0
    assert c.armed and c.system_status == 3
    fly(c, 3.8, thrust=0.2)
    assert c.armed and np.allclose(c.motor_outputs_norm, c.params.get("MOT_SPIN_ARM"))
    fly(c, 0.4, thrust=0.2)
    assert not c.armed


def test_without_position_estimate_guided_refuses_and_guided_nogps_works():
    """docs/design-decisions.md, MAV-2 and MAV-3: disarmed mode changes skip checks; arming in GUIDED without a position
    estimate fails a pre-arm check; armed, a switch to GUIDED fails; GUIDED_NOGPS needs no position."""
    c = SimulatedCopter(profile=load_profile(overrides={"position_estimate": False}))
    assert c.set_mode(4)[0]  # disarmed: accepted
    assert c.prearm_check() == (False, "PreArm: Need Position Estimate")
    assert c.arm() == (False, "PreArm: Need Position Estimate")
    assert (2, "PreArm: Need Position Estimate") in c.statustext_queue
    assert c.arm(force=True) == (True, "armed")  # 2989 skips the checks
    c.disarm(force=True)
    assert c.set_mode(20)[0] and c.arm() == (True, "armed")
    ok, reason = c.set_mode(4)
    assert not ok and reason == "Mode change to GUIDED failed: requires position" and c.mode_number == 20
    c.disarm(force=True)
    c.params.set("ARMING_CHECK", 0.0)
    c.set_mode(5)
    assert c.arm() == (True, "armed")  # checks disabled


def test_prearm_check_passes_on_a_healthy_vehicle():
    c = SimulatedCopter()
    for mode in (0, 2, 4, 5, 20):
        c.set_mode(mode)
        assert c.prearm_check() == (True, "")
    assert c.statustext_queue == []


def test_absurd_but_finite_commands_never_raise_and_keep_state_finite():
    c = airborne_copter(5.0)
    fly(c, 0.5, rates=(1e6, -1e6, 1e6), thrust=1e9)  # accepted (finite), shaped and saturated
    c.params.set("GUID_OPTIONS", 8.0)
    fly(c, 0.5, rates=(-50.0, 50.0, 0.0), thrust=-1e9)
    for bad in (float("inf"), float("nan")):
        assert not c.handle_attitude_target(RATES_THRUST, IDENTITY, (bad, 0.0, 0.0), 0.5)[0]
    assert c.handle_attitude_target(RATES_THRUST, IDENTITY, (0.0, 0.0, 0.0), float("nan"))[0]  # NaN thrust -> midpoint
    coast(c, 5.0)
    state = np.concatenate([c.position_ned_m, c.velocity_ned_ms, c.quaternion_wxyz, c.body_rates_rads,
                            c.motor_outputs_norm, c.attitude_target[0], c.attitude_target[1]])
    assert np.isfinite(state).all()
    assert np.all((c.motor_outputs_norm >= 0.0) & (c.motor_outputs_norm <= 1.0))


def test_the_bridge_configs_yaw_authority_is_what_the_mixer_gives_at_hover():
    """configs/bridge.yaml's yaw torque_authority_nm (issue 25, docs/bridge.md "The yaw authority") is the yaw torque
    the Solo's mixer makes while it keeps the hover thrust, not kappa x two motors at full thrust. Pushed beyond it
    (0.3 N m about yaw against a full opposite yaw-rate demand), the yaw output saturates and the net yaw
    acceleration gives the torque the motors make: tau = d - I_zz r_dot."""
    from mavastsm.bridge.bridge_config import load_bridge_config

    disturbance_nm = 0.3
    c = airborne_copter(altitude_m=10.0)
    c.set_external_torque((0.0, 0.0, disturbance_nm))
    rates = []
    for _ in range(200):  # 0.5 s at 400 Hz
        ok, reason = c.handle_attitude_target(RATES_THRUST, IDENTITY, (0.0, 0.0, -20.0), 0.5)
        assert ok, reason
        c.step(1.0 / 400.0)
        rates.append(float(c.true_body_rates_rads[2]))
    assert c.autopilot.motors.rpy_out[2] == pytest.approx(-1.0)  # the yaw output at its limit
    r_dot = (rates[-1] - rates[120]) / ((len(rates) - 1 - 120) / 400.0)
    made_nm = disturbance_nm - c.inertia_kgm2[2][2] * r_dot
    assert abs(c.velocity_ned_ms[2]) < 0.3  # the throttle held: no climb bought with yaw
    configured_nm = load_bridge_config().mapping.torque_authority_nm[2]
    assert made_nm == pytest.approx(configured_nm, rel=0.05), (made_nm, configured_nm)
