"""The batched RK4 plant and the simulator loop against analytic solutions and invariants."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.errors import ConfigError
from mavastsm.offline.plant import Rk4AttitudePlant
from mavastsm.offline.simulator import RunSpec, simulate_runs
from mavastsm.scenarios import load_scenario

I_DIAG = np.diag([8.85e-3, 15.5e-3, 23.09e-3])


def integrate(plant, x, torque, h, n):
    z = np.zeros_like(torque)
    for _ in range(n):
        x = plant.step(x, torque, z, z, z, h)
    return x


def test_constant_roll_torque_from_rest_is_exact():
    # only roll moves: phi_dot = p, p_dot = tau / Ixx -> p = tau t / Ixx, phi = tau t^2 / (2 Ixx)
    plant = Rk4AttitudePlant(I_DIAG[None])
    tau = np.array([[0.01], [0.0], [0.0]])
    x = integrate(plant, np.zeros((6, 1)), tau, 2.5e-4, 400)  # 0.1 s
    np.testing.assert_allclose(x[3, 0], 0.01 * 0.1 / 8.85e-3, rtol=1e-12)
    np.testing.assert_allclose(x[0, 0], 0.01 * 0.01 / (2 * 8.85e-3), rtol=1e-10)
    assert np.all(x[[1, 2, 4, 5], 0] == 0.0)


def test_torque_free_energy_and_momentum_conserved_with_full_inertia():
    inertia = load_scenario("variation").true_inertia(np.diag(I_DIAG))  # with products of inertia
    plant = Rk4AttitudePlant(inertia[None])
    x0 = np.array([[0.0], [0.0], [0.0], [1.0], [-2.0], [3.0]])
    x = integrate(plant, x0.copy(), np.zeros((3, 1)), 2.5e-4, 4000)  # 1 s
    w0, w1 = x0[3:, 0], x[3:, 0]
    energy = lambda w: 0.5 * w @ inertia @ w  # noqa: E731
    np.testing.assert_allclose(energy(w1), energy(w0), rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(inertia @ w1), np.linalg.norm(inertia @ w0), rtol=1e-9)
    assert not np.allclose(w1, w0)  # the body does tumble (non-trivial test)


def test_paper_kinematics_option_differs_only_when_tilted():
    tau = np.zeros((3, 1))
    x0 = np.array([[0.3], [0.2], [0.0], [0.0], [0.5], [0.5]])
    exact = integrate(Rk4AttitudePlant(I_DIAG[None], True), x0.copy(), tau, 1e-3, 100)
    paper = integrate(Rk4AttitudePlant(I_DIAG[None], False), x0.copy(), tau, 1e-3, 100)
    assert np.abs(exact[:3] - paper[:3]).max() > 1e-3
    np.testing.assert_allclose(exact[3:], paper[3:], rtol=1e-12)  # body dynamics do not depend on the kinematics


def test_batch_rows_are_independent(compressed):
    scn = compressed("disturbance", 0.2)  # steps at 0.1/0.2/0.4 s, 0.5 N m from 0.8 s, 1.4 s long
    short = [RunSpec("astsm", scn), RunSpec("smc", scn), RunSpec("astsm", compressed("nominal", 0.2))]
    together = simulate_runs(short, 2e-3, 1e-3)
    alone = simulate_runs([short[1]], 2e-3, 1e-3)
    np.testing.assert_allclose(together[1].euler_rad, alone[0].euler_rad, rtol=0, atol=1e-12)
    assert together[2].t_s[-1] < together[0].t_s[-1]  # each run keeps its own duration (1.0 s vs 1.4 s)
    on = together[0].t_s >= 0.8 - 1e-9
    np.testing.assert_array_equal(together[0].dist_nm[on][0], [0.5, 0.5, 0.5])
    assert not together[0].dist_nm[~on].any()


@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan")])
def test_bad_controller_period(dt):
    with pytest.raises(ConfigError, match="must be > 0"):
        simulate_runs([RunSpec("astsm", load_scenario("nominal"))], dt)


def test_diverging_run_is_frozen_and_reported():
    # ASTSM in torque units with Table-2 gains at 10 ms and the literal Iyy: pitch blows up
    spec = RunSpec("astsm", load_scenario("nominal"), config="astsm_paper", inertia_variant="paper_literal")
    (run,) = simulate_runs([spec], 1e-2, max_substep_s=1e-2)
    assert np.isfinite(run.diverged_at_s) and 0.0 < run.diverged_at_s < 5.0
    assert np.all(np.isfinite(run.euler_rad))
