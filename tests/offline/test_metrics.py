"""Metrics on synthetic histories with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.offline.metrics import alpha_return_time_s, compute_metrics, settling_time_s, switching_rate_hz, welch_hf_ratio
from mavastsm.offline.simulator import RunResult, RunSpec
from mavastsm.scenarios import load_scenario

DT = 1e-3


def synthetic_run(scenario_name="nominal", tau=0.2, overshoot=0.0):
    """Each axis follows its step as r (1 - e^{-(t - t_i)/tau}) (+ an optional overshoot bump)."""
    scn = load_scenario(scenario_name)
    t = np.arange(int(round(scn.duration_s / DT))) * DT
    ref, _, _ = scn.reference.at(t)
    euler = np.zeros_like(ref)
    for i in range(3):
        t_i = scn.reference.event_times_s(i)[0]
        r = scn.reference.step_size_rad(i)
        s = np.clip(t - t_i, 0, None)
        euler[:, i] = r * (1 - np.exp(-s / tau)) * (t >= t_i) + overshoot * r * np.sin(np.pi * s / 0.4) * ((s > 0) & (s < 0.4))
    u = np.zeros_like(ref)
    u[:, 0] = np.where(np.arange(t.size) % 2 == 0, 1.0, -1.0)  # alternating every sample: maximal chattering on roll
    nan = np.full_like(ref, np.nan)
    return RunResult(RunSpec("astsm", scn), DT, t, euler, ref, np.zeros_like(ref), u, scn.disturbance_torque_nm(t), nan, nan)


def test_first_order_response_settling_and_iae():
    m = compute_metrics(synthetic_run(tau=0.2))
    # |e| = |r| e^{-s/tau} <= 0.02 |r|  <=>  s >= tau ln 50 = 0.7824 s ; 5 %: tau ln 20 = 0.5991 s
    np.testing.assert_allclose(m["settling_2pct_s"], 0.2 * np.log(50), atol=2 * DT)
    np.testing.assert_allclose(m["settling_5pct_s"], 0.2 * np.log(20), atol=2 * DT)
    np.testing.assert_array_equal(m["overshoot_pct"], 0.0)
    # IAE = |r| tau (1 - e^{-(T_end - t_i)/tau}) in deg s: roll 10 deg * 0.2 s
    np.testing.assert_allclose(m["iae_deg_s"], [10 * 0.2, 10 * 0.2, 45 * 0.2], rtol=2e-2)
    assert m["dist_peak_deg"][0] != m["dist_peak_deg"][0]  # NaN without a disturbance
    np.testing.assert_array_equal(m["alpha_peak"], np.nan)


def test_overshoot_measured():
    m = compute_metrics(synthetic_run(tau=0.05, overshoot=0.1))
    assert 5.0 < m["overshoot_pct"][0] < 10.0


def test_chattering_metrics_on_alternating_input():
    m = compute_metrics(synthetic_run())
    # u alternates +-1 every 1 ms: |du| = 2 per sample, 1000 samples in the steady window (last 1 s)
    assert m["tv_steady_nm"][0] == pytest.approx(2 * 999)
    assert m["switching_rate_hz"][0] == pytest.approx(998, abs=2)
    assert m["hf_ratio"][0] > 0.99
    assert m["tv_steady_nm"][1] == 0.0 and m["switching_rate_hz"][1] == 0.0


def test_welch_hf_ratio_of_sines():
    t = np.arange(2000) * DT
    assert welch_hf_ratio(np.sin(2 * np.pi * 100 * t), DT) > 0.99
    assert welch_hf_ratio(np.sin(2 * np.pi * 2 * t), DT) < 0.05


def test_settling_edge_cases():
    t = np.arange(100) * 0.01
    assert settling_time_s(t, np.zeros(100), 0.1, 0.0, 1.0) == 0.0
    assert settling_time_s(t, np.ones(100), 0.1, 0.0, 1.0) == np.inf
    assert switching_rate_hz(np.array([0.0, 1e-9, 0.0, 1e-9]), 1.0) == 0.0  # round-off is not switching


def test_disturbance_recovery_on_synthetic_error():
    run = synthetic_run("disturbance", tau=0.05)
    # after 4 s add a deviation of 1 deg decaying with 0.1 s: recovery to < 0.2 deg at 0.1 ln 5 = 0.161 s
    s = np.clip(run.t_s - 4.0, 0, None)
    run.euler_rad[:, 2] += np.radians(1.0) * np.exp(-s / 0.1) * (run.t_s >= 4.0)
    m = compute_metrics(run)
    np.testing.assert_allclose(m["dist_peak_deg"][2], 1.0, atol=1e-6)
    np.testing.assert_allclose(m["dist_recovery_s"][2], 0.1 * np.log(5), atol=2 * DT)


def test_alpha_return_time():
    t = np.arange(0, 3, 0.01)
    alpha = np.where((t >= 1.0) & (t < 1.3), 5.0, 0.01)
    assert alpha_return_time_s(t, alpha, [1.0], 0.011) == pytest.approx(0.3, abs=0.011)
    assert alpha_return_time_s(t, np.full_like(t, 5.0), [1.0], 0.011) == np.inf
