"""Frames and kinematics against values worked out by hand (mavastsm/frames.py)."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.frames import (
    body_rates_from_euler_rates,
    euler_from_quaternion,
    euler_rate_matrix,
    euler_rates_from_body_rates,
    quaternion_from_euler,
    quaternion_multiply,
    rotation_frd2ned_from_quaternion,
    wrap_angle,
)

D = np.radians


def test_body_rates_from_euler_rates_hand_values():
    # phi = 0.1, theta = 0.2 rad; Euler rates (0.01, 0.02, 0.03) rad/s (eq. 1 with the Theta_dot factor):
    # p = 0.01 - 0.03 sin 0.2                       = 0.01 - 0.03*0.1986693     = 0.0040399
    # q = 0.02 cos 0.1 + 0.03 cos 0.2 sin 0.1       = 0.0199001 + 0.0029353    = 0.0228354
    # r = -0.02 sin 0.1 + 0.03 cos 0.2 cos 0.1      = -0.0019967 + 0.0292551   = 0.0272584
    w = body_rates_from_euler_rates([0.1, 0.2, 0.3], [0.01, 0.02, 0.03])
    np.testing.assert_allclose(w, [0.0040399, 0.0228354, 0.0272584], atol=2e-7)
    np.testing.assert_allclose(euler_rate_matrix([0.1, 0.2, 0.3]) @ [0.01, 0.02, 0.03], w, atol=1e-15)


def test_level_attitude_rates_are_equal():
    np.testing.assert_allclose(euler_rates_from_body_rates(np.zeros(3), [0.3, -0.2, 0.1]), [0.3, -0.2, 0.1])


def test_pure_yaw_rate_while_rolled():
    # rolled 90 deg right, a body pitch rate q turns the heading: psi_dot = (q s_phi + r c_phi)/c_theta = q
    rates = euler_rates_from_body_rates([D(90), 0.0, 0.0], [0.0, 0.5, 0.0])
    np.testing.assert_allclose(rates, [0.0, 0.0, 0.5], atol=1e-12)


def test_euler_body_rate_round_trip():
    rng = np.random.default_rng(1)
    e = rng.uniform([-1, -1.2, -3], [1, 1.2, 3], size=(50, 3))
    d = rng.uniform(-2, 2, size=(50, 3))
    np.testing.assert_allclose(euler_rates_from_body_rates(e, body_rates_from_euler_rates(e, d)), d, atol=1e-12)


def test_roll_right_puts_right_wing_down():
    # +30 deg roll: q = [cos 15, sin 15, 0, 0]; body y (right wing) in NED = [0, cos 30, sin 30] (z down)
    q = quaternion_from_euler([D(30), 0, 0])
    np.testing.assert_allclose(q, [np.cos(D(15)), np.sin(D(15)), 0, 0], atol=1e-15)
    np.testing.assert_allclose(rotation_frd2ned_from_quaternion(q) @ [0, 1, 0], [0, np.cos(D(30)), 0.5], atol=1e-15)


def test_plus_90_yaw_points_nose_east():
    r = rotation_frd2ned_from_quaternion(quaternion_from_euler([0, 0, D(90)]))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)


def test_pitch_up_raises_nose():
    r = rotation_frd2ned_from_quaternion(quaternion_from_euler([0, D(10), 0]))
    np.testing.assert_allclose(r @ [1, 0, 0], [np.cos(D(10)), 0, -np.sin(D(10))], atol=1e-15)  # NED z down: nose up = -z


def test_quaternion_round_trip_and_composition():
    rng = np.random.default_rng(2)
    e = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], size=(200, 3))
    np.testing.assert_allclose(euler_from_quaternion(quaternion_from_euler(e)), e, atol=1e-9)
    # q and -q are the same rotation; unnormalised input is accepted
    q = quaternion_from_euler(e)
    np.testing.assert_allclose(euler_from_quaternion(-3.0 * q), e, atol=1e-9)
    # ZYX = yaw then pitch then roll: q = q_yaw * q_pitch * q_roll
    qz, qy, qx = (quaternion_from_euler(v) for v in ([0, 0, 0.3], [0, 0.2, 0], [0.1, 0, 0]))
    np.testing.assert_allclose(quaternion_multiply(quaternion_multiply(qz, qy), qx), quaternion_from_euler([0.1, 0.2, 0.3]), atol=1e-15)


@pytest.mark.parametrize(
    "angle, wrapped",
    [(0.0, 0.0), (np.pi, np.pi), (-np.pi, np.pi), (1.5 * np.pi, -0.5 * np.pi), (-1.5 * np.pi, 0.5 * np.pi), (2 * np.pi, 0.0), (7.0, 7.0 - 2 * np.pi)],
)
def test_wrap_angle(angle, wrapped):
    assert wrap_angle(angle) == pytest.approx(wrapped, abs=1e-12)


def test_float_quaternions_are_the_numpy_ones_and_hand_computed():
    """The q_* float helpers (what the sim's autopilot loop and the bridge's target model fly) against the NumPy
    functions and against values by hand: yaw 90 deg -> (cos 45, 0, 0, sin 45); a rotation vector (0, 0, pi/2) is
    the same quaternion; rotating body x by it gives NED east."""
    import math

    from mavastsm import frames

    h = math.sqrt(0.5)
    assert frames.q_from_euler(0.0, 0.0, math.pi / 2) == pytest.approx((h, 0.0, 0.0, h), abs=1e-15)
    assert frames.q_from_rotation_vector(0.0, 0.0, math.pi / 2) == pytest.approx((h, 0.0, 0.0, h), abs=1e-15)
    assert frames.q_rotate((h, 0.0, 0.0, h), 1.0, 0.0, 0.0) == pytest.approx((0.0, 1.0, 0.0), abs=1e-15)
    assert frames.q_to_rotation_vector((h, 0.0, 0.0, h)) == pytest.approx((0.0, 0.0, math.pi / 2), abs=1e-15)
    assert frames.q_normalize((0.0, 0.0, 0.0, 0.0)) == (1.0, 0.0, 0.0, 0.0)
    rng = np.random.default_rng(7)
    for _ in range(50):
        e = rng.uniform([-1.5, -1.5, -3.1], [1.5, 1.5, 3.1])
        q = frames.q_from_euler(*e)
        np.testing.assert_allclose(q, frames.quaternion_from_euler(e), atol=1e-15)
        np.testing.assert_allclose(frames.q_to_euler(q), frames.euler_from_quaternion(q), atol=1e-12)
        b = frames.q_from_euler(*rng.uniform(-1, 1, 3))
        np.testing.assert_allclose(frames.q_mul(q, b), frames.quaternion_multiply(q, b), atol=1e-15)
        np.testing.assert_allclose(frames.q_rotate(q, 1.0, 2.0, 3.0), frames.rotation_frd2ned_from_quaternion(q) @ [1.0, 2.0, 3.0], atol=1e-12)
