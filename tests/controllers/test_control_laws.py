"""One controller step per law against values worked out by hand from the equations (not from the code).

Shared sample: e = [0.01, -0.02, 0] rad, e_dot = [0.1, 0, -0.05] rad/s, Theta_ddot_d = 0,
omega = [0.2, -0.1, 0.3] rad/s, I0 = diag(8.85e-3, 15.5e-3, 23.09e-3) kg m^2 (corrected), T = 1 ms.
Lambda = diag(3.89, 3.89, 4.36) -> sigma = e_dot + Lambda e = [0.1389, -0.0778, -0.05] rad/s.
u_eq = -I0 Lambda e_dot + omega x I0 omega:
  -I0 Lambda e_dot = [-8.85e-3*0.389, 0, +23.09e-3*0.218] = [-3.44265e-3, 0, 5.03362e-3]
  gyro = [(Izz-Iyy) q r, (Ixx-Izz) p r, (Iyy-Ixx) p q]
       = [7.59e-3*(-0.03), -14.24e-3*0.06, 6.65e-3*(-0.02)] = [-2.277e-4, -8.544e-4, -1.33e-4]
  u_eq = [-3.67035e-3, -8.544e-4, 4.90062e-3] N m
"""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.control import make_controller
from mavastsm.control.controller_interface import TrackingError
from mavastsm.errors import ConfigError
from mavastsm.solo_model import load_solo

SOLO = load_solo()
I0 = np.array([8.85e-3, 15.5e-3, 23.09e-3])
SIGMA = np.array([0.1389, -0.0778, -0.05])
SGN = np.array([1.0, -1.0, -1.0])
U_EQ = np.array([-3.67035e-3, -8.544e-4, 4.90062e-3])
ERR = TrackingError(
    angle_error_rad=np.array([0.01, -0.02, 0.0]),
    euler_rate_error_rads=np.array([0.1, 0.0, -0.05]),
    ref_euler_accel_radss=np.zeros(3),
    body_rates_rads=np.array([0.2, -0.1, 0.3]),
    euler_rad=np.array([0.01, -0.02, 0.0]),
)
SQRT_SIGMA = np.sqrt(np.abs(SIGMA))  # [0.372693, 0.278927, 0.223607]


def test_astsm_accel_units_two_steps():
    c = make_controller("astsm", SOLO)
    u = c.update(ERR, 1e-3)
    d = c.diagnostics()
    np.testing.assert_allclose(d["sigma"], SIGMA, atol=1e-12)
    np.testing.assert_allclose(d["u_eq"], U_EQ, atol=1e-9)
    # alpha = alpha_m = 0.01, nu = 0: v = -0.01 sqrt|sigma| sgn(sigma) [rad/s^2]; u_D = I0 v
    v = -0.01 * SQRT_SIGMA * SGN
    np.testing.assert_allclose(d["u_d"], I0 * v, rtol=1e-9)
    np.testing.assert_allclose(u, U_EQ + I0 * v, rtol=1e-6)
    # after the step: alpha <= alpha_m so alpha_dot = eta = 0.01 -> 0.01001; beta = 2*0.6*0.01 = 0.012;
    # nu = -T beta/2 sgn = -6e-6 sgn(sigma)
    np.testing.assert_allclose(c.alpha, 0.01001, rtol=1e-12)
    np.testing.assert_allclose(c.nu, -6e-6 * SGN, rtol=1e-9)
    np.testing.assert_allclose(d["beta"], 0.012, rtol=1e-12)
    c.update(ERR, 1e-3)
    # now alpha > alpha_m and |sigma| > mu = 0.01: alpha += T * 1000 sqrt(3.3) = 1.8165902
    np.testing.assert_allclose(c.alpha, 0.01001 + 1.81659021, rtol=1e-7)
    # nu decreases by T * (2*0.6*0.01001)/2 = 6.006e-6 more
    np.testing.assert_allclose(c.nu, -(6e-6 + 6.006e-6) * SGN, rtol=1e-9)


def test_astsm_paper_torque_units_step_and_alpha_clamp():
    c = make_controller("astsm", SOLO, config="astsm_paper")
    u = c.update(ERR, 1e-3)
    v = -0.01 * SQRT_SIGMA * SGN  # torque units: u_D = v [N m]
    np.testing.assert_allclose(c.diagnostics()["u_d"], v, rtol=1e-9)
    np.testing.assert_allclose(u, U_EQ + v, rtol=1e-6)
    # inside the mu band alpha decreases by T*200*sqrt(3.3) = 0.363 per step but is clamped at alpha_m
    small = TrackingError(np.zeros(3), np.full(3, 1e-4), np.zeros(3), np.zeros(3), np.zeros(3))
    for _ in range(5):
        c.update(small, 1e-3)
        assert np.all(c.alpha >= 0.01)


def test_astsm_saturation_freezes_alpha_and_nu():
    c = make_controller("astsm", SOLO, overrides={"torque_limit_enabled": True, "torque_limit_nm": [1e-5, 1e-5, 1e-5]})
    big = TrackingError(np.full(3, 0.3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    for _ in range(10):
        u = c.update(big, 1e-3)
        np.testing.assert_allclose(np.abs(u), 1e-5)
    # alpha may only take its eta restart steps (never the 1.8/step growth); nu pushes further -> frozen
    assert np.all(c.alpha < 0.0101)
    np.testing.assert_array_equal(c.nu, 0.0)


def test_smc_step():
    c = make_controller("smc", SOLO)
    u = c.update(ERR, 1e-3)
    # v = -K sgn(sigma) - Q sigma, K = (75.6, 45.3, 32.1), Q = 2
    v = np.array([-75.6 - 0.2778, 45.3 + 0.1556, 32.1 + 0.1])
    np.testing.assert_allclose(u, U_EQ + I0 * v, rtol=1e-6)


def test_stsm_step():
    c = make_controller("stsm", SOLO)
    u = c.update(ERR, 1e-3)
    v = -np.array([35.65, 26.94, 22.07]) * SQRT_SIGMA * SGN
    np.testing.assert_allclose(u, U_EQ + I0 * v, rtol=1e-6)
    # nu1 = -T k2 sgn(sigma) = -1e-3 (621.5, 354.8, 238.2) sgn
    np.testing.assert_allclose(c.nu, -1e-3 * np.array([621.5, 354.8, 238.2]) * SGN, rtol=1e-12)


def test_atsm_two_steps():
    c = make_controller("atsm", SOLO)
    u = c.update(ERR, 1e-3)
    # first sample: sigma_dot = 0 -> v = -(r1 + 10|sigma|) sgn(sigma)
    r1 = np.array([110.9, 67.6, 48.7])
    v = -(r1 + 10 * np.abs(SIGMA)) * SGN
    np.testing.assert_allclose(u, U_EQ + I0 * v, rtol=1e-6)
    # second sample with sigma changed by +0.001 on every axis: raw derivative 1.0 rad/s^2,
    # filtered a = T/(T + 1/(2 pi 100)) = 0.385869 -> sigma_dot = 0.385869; r2 term: -(r2) sgn(+)
    err2 = TrackingError(ERR.angle_error_rad, ERR.euler_rate_error_rads + 0.001, np.zeros(3), ERR.body_rates_rads, ERR.euler_rad)
    u2 = c.update(err2, 1e-3)
    np.testing.assert_allclose(c.diagnostics()["sigma_dot"], 0.3858695, rtol=1e-6)
    r2 = np.array([33.3, 20.3, 14.6])
    sigma2 = SIGMA + 0.001
    v2 = -(r1 + 10 * np.abs(sigma2)) * np.sign(sigma2) - r2
    ueq2 = U_EQ - I0 * np.array([3.89, 3.89, 4.36]) * 0.001
    np.testing.assert_allclose(u2, ueq2 + I0 * v2, rtol=1e-6)


def test_atsm_rejects_r1_not_above_r2():
    with pytest.raises(ConfigError, match="r1"):
        make_controller("atsm", SOLO, overrides={"r1": [10.0, 10.0, 10.0], "r2": [20.0, 5.0, 5.0]})


def test_pid_step():
    """Level attitude, e = [0.1, 0, 0] rad (roll 0.1 rad right of the reference), omega = 0."""
    c = make_controller("pid", SOLO)
    err = TrackingError(np.array([0.1, 0.0, 0.0]), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    u = c.update(err, 1e-3)
    # rate target = -4.5 * 0.1 = -0.45 rad/s; P = 0.135 * -0.45 = -0.06075; I = 0.09 * -0.45 * 1e-3 = -4.05e-5;
    # D = 0 on the first sample; tau = 2.9 * (-0.06075 - 4.05e-5) = -0.17629245 N m
    np.testing.assert_allclose(u, [-0.17629245, 0.0, 0.0], atol=1e-12)
    u2 = c.update(err, 1e-3)
    # error unchanged -> derivative 0; integrator doubles
    np.testing.assert_allclose(u2[0], 2.9 * (-0.06075 - 8.1e-5), rtol=1e-12)


def test_pid_integrator_clamped_at_imax():
    c = make_controller("pid", SOLO)
    err = TrackingError(np.array([0.0, 0.0, 0.05]), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    for _ in range(20000):
        c.update(err, 1e-2)
    # yaw: rate target -0.171 -> P = -0.1573 and I clamped to -IMAX = -0.1 -> |u_n| = 0.2573 < 1
    assert c.integrator[2] == pytest.approx(-0.1)


def test_astsm_sampling_warnings_match_the_presets_intended_periods():
    from mavastsm.control.astsm import sampling_warnings

    def gains(preset):
        return make_controller("astsm", SOLO, config=preset).gains

    assert sampling_warnings(gains("astsm"), 1e-3) == []
    assert sampling_warnings(gains("astsm_400hz"), 2.5e-3) == []
    assert sampling_warnings(gains("astsm_paper"), 5e-4) == []
    assert any("mu" in w for w in sampling_warnings(gains("astsm"), 2.5e-3))
    assert any("torque" in w for w in sampling_warnings(gains("astsm_paper"), 1e-3))
