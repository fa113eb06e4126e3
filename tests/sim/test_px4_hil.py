"""PX4's simulator interface on the Solo physics (sim/px4_hil.py): the sensor messages, the motor order PX4 is told
(configs/px4/solo.params) against the one the physics flies, and the lockstep loop over a real TCP socket with a
client that answers as PX4's simulator_mavlink does."""

from __future__ import annotations

import math
import re
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavastsm_sim.genuine_sitl import px4_solo_params_path
from mavastsm_sim.mixer import motor_positions_frd, motor_spin_ccw
from mavastsm_sim.px4_hil import (HIL_SENSOR_ALL_FIELDS, PX4_HOME, WMM_CORNERS, Px4HilPhysics, Px4HilServer,
                                  isa_pressure_hpa, px4_magnetic_field_ned_gauss)

G = 9.81


def _params() -> dict[str, float]:
    text = px4_solo_params_path().read_text()
    return {m[1]: float(m[2]) for m in re.finditer(r"^param set (\w+) (\S+)$", text, re.M)}


def test_at_rest_hil_sensor_reads_gravity_the_home_field_and_the_home_pressure():
    p = Px4HilPhysics(noise=False)
    m = p.hil_sensor()
    assert m.fields_updated == HIL_SENSOR_ALL_FIELDS and m.id == 0 and m.time_usec == p.step_us
    assert (m.xacc, m.yacc) == pytest.approx((0.0, 0.0), abs=1e-9) and m.zacc == pytest.approx(-G)
    assert (m.xgyro, m.ygyro, m.zgyro) == (0.0, 0.0, 0.0)
    assert (m.xmag, m.ymag, m.zmag) == pytest.approx(px4_magnetic_field_ned_gauss())  # level, facing north: body = NED
    assert m.abs_pressure == pytest.approx(isa_pressure_hpa(PX4_HOME[2])) and m.pressure_alt == pytest.approx(PX4_HOME[2])
    assert 950.0 < m.abs_pressure < 960.0  # 488 m AMSL


def test_the_field_is_pxs_own_table_at_its_grid_points_and_between():
    """At a grid corner PX4's bilinear lookup returns the table value: strength 0.4513 gauss at 40 N 0 E."""
    n, e, d = px4_magnetic_field_ned_gauss(40.0, 0.0)
    dec, inc, strength = (v * 1e-4 for v in WMM_CORNERS[(40, 0)])
    assert math.sqrt(n * n + e * e + d * d) == pytest.approx(strength)
    assert math.atan2(e, n) == pytest.approx(dec) and math.atan2(d, math.hypot(n, e)) == pytest.approx(inc)
    home = px4_magnetic_field_ned_gauss()
    assert 0.45 < math.sqrt(sum(v * v for v in home)) < 0.49 and 60.0 < math.degrees(math.atan2(home[2], math.hypot(*home[:2]))) < 66.0
    with pytest.raises(ValueError, match="no WMM table cell"):
        px4_magnetic_field_ned_gauss(-35.0, 149.0)


def test_px4_is_told_the_rotor_positions_and_spins_the_physics_flies():
    """CA_ROTORi_PX/PY/KM of configs/px4/solo.params = the physics' motor i (ArduPilot order) and its reaction torque."""
    p = Px4HilPhysics(noise=False)
    params = _params()
    positions = motor_positions_frd(p.config.rigid_body.arm_length)
    kappa = p.config.propulsion.yaw_torque_per_thrust
    assert params["CA_ROTOR_COUNT"] == 4
    for i, ((x, y), spin) in enumerate(zip(positions, motor_spin_ccw())):
        assert (params[f"CA_ROTOR{i}_PX"], params[f"CA_ROTOR{i}_PY"]) == pytest.approx((x, y), abs=5e-4), i
        assert params[f"CA_ROTOR{i}_KM"] == pytest.approx(spin * kappa), i
    hover = p.plant.weight_n / (4 * p.config.propulsion.max_thrust_per_motor)
    assert params["THR_MDL_FAC"] == 1.0 and params["MPC_THR_HOVER"] == pytest.approx(hover, abs=5e-4)


def test_rotor0_alone_rolls_the_vehicle_left_as_px4s_front_right_rotor_must():
    p = Px4HilPhysics(noise=False)
    p.plant.reset((0.0, 0.0, -10.0))  # in the air
    p.set_controls([0.8, 0.0, 0.0, 0.0])
    for _ in range(25):
        p.step()
    assert p.plant.x[10] < -0.5 and p.plant.x[11] > 0.5  # front right pushed up: roll left (p < 0), nose up (q > 0)


def test_non_finite_controls_are_counted_and_replaced_by_zero():
    p = Px4HilPhysics(noise=False)
    assert p.set_controls([float("nan"), 0.5, float("inf"), 2.0]) == 2
    assert p.controls == [0.0, 0.5, 0.0, 1.0]


def test_noise_is_seeded_and_of_the_documented_size():
    a, b = Px4HilPhysics(seed=7), Px4HilPhysics(seed=7)
    ma, mb = [a.hil_sensor() for _ in range(2000)], [b.hil_sensor() for _ in range(2000)]
    assert [m.xgyro for m in ma] == [m.xgyro for m in mb]
    std = math.sqrt(sum(m.xgyro ** 2 for m in ma) / len(ma))
    assert std == pytest.approx(a.noise.gyro_std_rads, rel=0.1)


def test_lockstep_over_tcp_steps_once_per_answer_and_holds_the_answered_motors():
    """A client that answers each HIL_SENSOR with HIL_ACTUATOR_CONTROLS, as PX4 does: one step per sensor message,
    PX4's clock (time_usec) advancing by one sensor period, the motors it sent flown."""
    server = Px4HilServer(Px4HilPhysics(noise=False), port=0, speed=0.0).open()
    server.start()
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    times = []
    try:
        with socket.create_connection(server.listener.getsockname(), timeout=5.0) as s:
            deadline = time.monotonic() + 10.0
            while len(times) < 50 and time.monotonic() < deadline:
                for m in mav.parse_buffer(s.recv(4096)) or ():
                    if m.get_type() == "HIL_SENSOR":
                        times.append(m.time_usec)
                        out = mavlink2.MAVLink_hil_actuator_controls_message(m.time_usec, [0.5, 0.5, 0.5, 0.5] + [0.0] * 12, 129, 1)
                        s.sendall(out.pack(mav))
    finally:
        server.stop()
    assert server.error is None, repr(server.error)
    assert times[:50] == [4000 * (i + 1) for i in range(50)]
    assert server.physics.controls == [0.5, 0.5, 0.5, 0.5]
    assert server.counters.actuator_messages >= 49 and server.counters.actuator_timeouts == 0, server.counters.summary()


def test_missing_px4_is_a_one_line_error_with_exit_2(monkeypatch, capsys):
    from mavastsm_sim.command import main as sim_main

    monkeypatch.delenv("MAVASTSM_PX4", raising=False)
    assert sim_main(["--autopilot", "px4"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "MAVASTSM_PX4" in err and "--px4" in err, err
    assert sim_main(["--autopilot", "px4", "--px4", "/nonexistent/px4"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "/nonexistent/px4" in err, err
    assert sim_main(["--autopilot", "px4", "--lockstep"]) == 2  # the in-repo sim's options are refused by name
    assert "--lockstep applies to the in-repo sim only, not to --autopilot px4" in capsys.readouterr().err


def test_a_ground_impact_never_ends_the_simulation():
    """Landing hard stops the vehicle within one 1 ms physics step: hundreds of g (7.7 m/s from 3 m: 785 g), beyond
    HIL_STATE_QUATERNION's int16 mG fields. The messages are still built, clamped (in the variation benchmark an
    unclamped one ended the simulator loop)."""
    p = Px4HilPhysics(noise=False)
    p.plant.accel_ned_ms2 = (0.0, 0.0, -7700.0)
    p.plant.x[5] = 400.0  # [m/s] beyond int16 cm/s too
    mav = mavlink2.MAVLink(None)
    for m in (p.hil_sensor(), p.hil_gps(), p.hil_state_quaternion()):
        m.pack(mav)
    assert p.hil_state_quaternion().zacc == -32768 and p.hil_state_quaternion().vz == 32767
