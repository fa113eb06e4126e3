"""Checklist F3-F4 over the wire: SET_ATTITUDE_TARGET sign conventions, thrust semantics in both GUID_OPTIONS
settings, GUID_TIMEOUT fallback, type_mask rejection and auto-disarm. Lockstep; time from ``time_boot_ms``."""

from __future__ import annotations

import math

import pytest
from mavlink_peer_tools import ATTITUDE_ID, fly, guided_and_armed, mavlink, rates_command, wrap_pi

ATTITUDE_HZ = 50


def take_off(server, gcs, climb_s: float = 2.0) -> None:
    """GUIDED, arm, and climb at thrust 0.8 (climb-rate mode: +1.5 m/s) for ``climb_s`` of simulated time."""
    guided_and_armed(gcs)
    assert gcs.set_interval(ATTITUDE_ID, ATTITUDE_HZ).result == mavlink.MAV_RESULT_ACCEPTED
    fly(gcs, climb_s, rates_command(thrust=0.8))
    fly(gcs, 0.5, rates_command(thrust=0.5))
    altitude = server.call(lambda c: -c.position_ned_m[2])
    assert altitude > 1.5 and not server.call(lambda c: c.landed), altitude


@pytest.fixture
def airborne(server_and_gcs):
    server, gcs = server_and_gcs
    take_off(server, gcs)
    return server, gcs


@pytest.mark.parametrize("axis", [0, 1], ids=["roll", "pitch"])
def test_positive_roll_or_pitch_rate_increases_the_angle(airborne, axis):
    server, gcs = airborne
    rates = [0.0, 0.0, 0.0]
    rates[axis] = 0.5
    before = fly(gcs, 0.02, rates_command(thrust=0.5))[-1]
    after = fly(gcs, 0.4, rates_command(*rates, thrust=0.5))[-1]
    angle = ("roll", "pitch")[axis]
    delta = getattr(after, angle) - getattr(before, angle)
    assert 0.08 < delta < 0.3, f"{angle} changed by {math.degrees(delta):.1f} deg for +0.5 rad/s over 0.4 s"
    rate_field = ("rollspeed", "pitchspeed")[axis]
    assert getattr(after, rate_field) > 0.3  # ATTITUDE reports body rates, positive about +x / +y FRD


def test_positive_yaw_rate_turns_heading_clockwise(airborne):
    server, gcs = airborne
    before = fly(gcs, 0.02, rates_command(thrust=0.5))[-1]
    after = fly(gcs, 1.0, rates_command(r=0.5, thrust=0.5))[-1]
    delta = wrap_pi(after.yaw - before.yaw)
    assert 0.25 < delta < 0.6, f"heading changed by {math.degrees(delta):.1f} deg"
    assert after.yawspeed > 0.3


def test_thrust_is_climb_rate_by_default(airborne):
    server, gcs = airborne
    fly(gcs, 2.0, rates_command(thrust=0.5))  # let the vertical controller settle after the climb
    z0 = server.call(lambda c: c.position_ned_m[2])
    fly(gcs, 1.0, rates_command(thrust=0.5))
    z1, vz = server.call(lambda c: (c.position_ned_m[2], c.velocity_ned_ms[2]))
    assert abs(z1 - z0) < 0.1 and abs(vz) < 0.1, ("thrust 0.5 must hold altitude", z1 - z0, vz, server.counters)
    fly(gcs, 2.0, rates_command(thrust=1.0))
    climb = -server.call(lambda c: c.velocity_ned_ms[2])
    speed_up = server.call(lambda c: c.params.get("WPNAV_SPEED_UP")) / 100.0
    assert abs(climb - speed_up) < 0.3, f"thrust 1.0 climbs at {climb:.2f} m/s, WPNAV_SPEED_UP {speed_up} m/s"


def test_guid_options_bit3_makes_thrust_a_normalised_collective(airborne):
    server, gcs = airborne
    assert gcs.set_param("GUID_OPTIONS", 8).param_value == 8
    hover = server.call(lambda c: c.params.get("MOT_THST_HOVER"))
    fly(gcs, 1.5, rates_command(thrust=hover))
    vz_hover = server.call(lambda c: c.velocity_ned_ms[2])
    assert abs(vz_hover) < 0.5, f"thrust = MOT_THST_HOVER {hover} should roughly hover, vz {vz_hover:.2f} m/s"
    fly(gcs, 1.0, rates_command(thrust=min(hover + 0.2, 1.0)))
    vz_up = server.call(lambda c: c.velocity_ned_ms[2])
    assert vz_up < -0.5, f"collective above hover must climb, vz {vz_up:.2f} m/s"
    fly(gcs, 1.0, rates_command(thrust=0.5 if hover + 0.2 < 0.5 else hover + 0.1))
    # in climb-rate mode 0.5 would hold; as collective (> hover) it keeps climbing
    assert server.call(lambda c: c.velocity_ned_ms[2]) < -0.5


def test_guid_timeout_falls_back_to_level_hold_in_guided(make_server, make_gcs):
    server = make_server(lockstep_timeout_s=0.005, speedup=20.0)  # the silent phase is paced at 20x
    gcs = make_gcs(server.port)
    gcs.hello()
    take_off(server, gcs)
    tilted = fly(gcs, 0.3, rates_command(p=0.5, thrust=0.5))[-1]
    assert tilted.roll > 0.1
    fly(gcs, 0.05, rates_command(thrust=0.5))  # last command: zero rates, so the tilt is held
    timeout_s = server.call(lambda c: c.params.get("GUID_TIMEOUT"))
    silent = fly(gcs, timeout_s + 1.5, lambda att: None)
    t0 = silent[0].time_boot_ms
    still_tilted = [m.roll for m in silent if m.time_boot_ms - t0 < (timeout_s - 0.3) * 1000]
    levelled = [m.roll for m in silent if m.time_boot_ms - t0 > (timeout_s + 1.0) * 1000]
    assert min(still_tilted) > 0.08, "the last target is held until GUID_TIMEOUT"
    assert max(abs(r) for r in levelled) < math.radians(2.0), "after GUID_TIMEOUT the vehicle levels"
    assert server.call(lambda c: (c.mode_number, c.armed)) == (4, True)
    assert abs(server.call(lambda c: c.velocity_ned_ms[2])) < 0.3, "and holds altitude (zero climb)"


@pytest.mark.parametrize("mask,q", [(0x80 | 0x40, [1.0, 0, 0, 0]), (0x81, [1.0, 0, 0, 0]), (0x07, [0.9, 0, 0, 0])],
                         ids=["throttle_ignore", "mixed_rate_bits", "non_unit_quaternion"])
def test_rejected_mask_stops_and_holds_level(airborne, mask, q):
    server, gcs = airborne
    tilted = fly(gcs, 0.3, rates_command(p=0.5, thrust=0.5))[-1]
    assert tilted.roll > 0.1
    rejected_before = server.call(lambda c: c.rejected_attitude_targets)
    out = fly(gcs, 1.5, lambda att: (mask, q, (0.5, 0.0, 0.0), 0.5))[-1]
    assert server.call(lambda c: c.rejected_attitude_targets) - rejected_before >= 70
    assert abs(out.roll) < math.radians(3.0), "a rejected target stops the copter and holds it level"
    assert server.call(lambda c: (c.mode_number, c.armed, c.landed)) == (4, True, False)
    after = fly(gcs, 0.3, rates_command(p=0.5, thrust=0.5))[-1]  # a valid target takes over again
    assert after.roll - out.roll > 0.08


def test_auto_disarm_after_disarm_delay_on_the_ground(server_and_gcs):
    server, gcs = server_and_gcs
    guided_and_armed(gcs)
    t_arm_s = server.sim_time_s
    gcs.set_interval(ATTITUDE_ID, 20)
    disarmed_at = []

    def idle_on_ground(att):
        if not disarmed_at and not server.call(lambda c: c.armed):
            disarmed_at.append(att.time_boot_ms / 1000.0)
        return 0x80, [1.0, 0.0, 0.0, 0.0], (0.0, 0.0, 0.0), 0.5  # 0.5 = zero climb: no takeoff demand

    fly(gcs, 11.0, idle_on_ground)
    delay = server.call(lambda c: c.params.get("DISARM_DELAY"))
    assert disarmed_at, "the vehicle never auto-disarmed"
    assert abs(disarmed_at[0] - t_arm_s - delay) < 0.5, (disarmed_at[0] - t_arm_s, delay)
    hb = gcs.recv("HEARTBEAT", timeout_s=3.0)
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_lockstep_flight_is_repeatable(make_server, make_gcs):
    """Same commands -> the same ATTITUDE sequence (to round-off), whatever the wall-clock timing of the runs."""

    def run() -> list[tuple]:
        server = make_server(lockstep_timeout_s=10.0)  # a loaded machine must not turn a late answer into a timeout
        gcs = make_gcs(server.port)
        gcs.hello()
        take_off(server, gcs, climb_s=1.5)
        got = fly(gcs, 0.5, lambda att: (0x80, [1.0, 0, 0, 0], (0.4, -0.2, 0.3), 0.55))
        t0 = got[0].time_boot_ms
        assert server.counters["lockstep_timeouts"] == 0
        server.stop()
        return [(m.time_boot_ms - t0, m.roll, m.pitch, m.yaw, m.rollspeed) for m in got]

    first, second = run(), run()
    assert [m[0] for m in first] == [m[0] for m in second]  # same sample times
    # the idle time on the ground before takeoff differs with wall timing; it only leaves round-off
    worst = max(abs(a - b) for m1, m2 in zip(first, second) for a, b in zip(m1[1:], m2[1:]))
    assert worst < 1e-6, worst


def test_lockstep_paces_on_when_the_controller_stops_answering(make_server, make_gcs):
    """A dead bridge must not freeze simulated time: GUID_TIMEOUT still fires after 3 s of simulated time."""
    server = make_server(speedup=10.0)
    gcs = make_gcs(server.port)
    gcs.hello()
    take_off(server, gcs, climb_s=1.0)
    tilted = fly(gcs, 0.3, rates_command(p=0.5, thrust=0.5))[-1]
    assert tilted.roll > 0.1
    t_silent = server.sim_time_s
    gcs.close()  # the controller disappears
    assert server.wait_until(lambda c: server.sim_time_s > t_silent + 4.5, timeout_s=20.0)
    assert server.counters["lockstep_controller_lost"] == 1
    assert server.call(lambda c: abs(c.euler_rad[0])) < math.radians(2.0), "GUID_TIMEOUT levelled the vehicle"
