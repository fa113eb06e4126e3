"""Scenarios: disturbance timing, relative and literal Table 3 inertia, errors."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.errors import ConfigError
from mavastsm.scenarios import load_scenario, packaged_scenarios

I0 = np.array([8.85e-3, 15.5e-3, 23.09e-3])


def test_packaged_scenarios_load():
    names = packaged_scenarios()
    assert {"nominal", "disturbance", "variation", "disturbance_roll", "disturbance_pitch", "disturbance_yaw",
            "disturbance_from_start", "disturbance_pulse", "variation_stress"} <= set(names)
    for n in names:
        s = load_scenario(n)
        assert s.duration_s > 0 and s.reference.name == "paper_steps"


def test_disturbance_step_and_pulse():
    d = load_scenario("disturbance")
    assert d.duration_s == 7.0 and d.disturbance_start_s == 4.0
    np.testing.assert_array_equal(d.disturbance_torque_nm(np.array([3.999, 4.0, 6.9])), [[0, 0, 0], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]])
    p = load_scenario("disturbance_pulse")
    np.testing.assert_array_equal(p.disturbance_torque_nm([4.5, 5.0]), [[0.5, 0.5, 0.5], [0, 0, 0]])
    np.testing.assert_array_equal(load_scenario("disturbance_yaw").disturbance_torque_nm(5.0), [0, 0, 0.5])
    assert load_scenario("nominal").disturbance_start_s is None


def test_relative_table3_inertia_hand_values():
    v = load_scenario("variation")
    assert v.payload_mass_kg == 0.8
    it = v.true_inertia(I0)
    # diagonals scale by 1 + delta_ii: 8.85e-3 * 1.4825 = 13.120e-3, 15.5e-3 * 1.2437 = 19.277e-3, 23.09e-3 * 1.2437 = 28.717e-3
    np.testing.assert_allclose(np.diag(it), [13.120125e-3, 19.27735e-3, 28.717033e-3], rtol=1e-6)
    # off-diagonal xy = 0.0044 * sqrt(8.85e-3 * 15.5e-3) = 0.0044 * 11.7122e-3 = 5.1534e-5
    np.testing.assert_allclose(it[0, 1], 5.15337e-5, rtol=1e-4)
    np.testing.assert_allclose(it, it.T)
    assert np.all(np.linalg.eigvalsh(it) > 0)
    np.testing.assert_allclose(load_scenario("nominal").true_inertia(I0), np.diag(I0))


def test_literal_table3_stress():
    it = load_scenario("variation_stress").true_inertia(I0)
    np.testing.assert_allclose(it[0, 0], 8.85e-3 + 0.4825)
    np.testing.assert_allclose(it[1, 2], 0.0115)


@pytest.mark.parametrize(
    "body, match",
    [
        ("scenario:\n  duration_s: 5\n", "missing key 'scenario.reference'"),
        ("scenario:\n  reference: paper_steps\n  duration_s: 0\n", "duration_s.*must be > 0"),
        ("scenario:\n  reference: paper_steps\n  disturbances:\n    - {type: step, start_s: 1, torque_nm: [1, 2]}\n", "3 numbers"),
        ("scenario:\n  reference: paper_steps\n  disturbances:\n    - {type: pulse, start_s: 2, end_s: 1, torque_nm: [1, 2, 3]}\n", "must be > start_s"),
        ("scenario:\n  reference: paper_steps\n  inertia_variation: {mode: scaled, delta: [[0,0,0],[0,0,0],[0,0,0]]}\n", "must be one of"),
        ("scenario:\n  reference: paper_steps\n  inertia_variation: {mode: relative, delta: [[0,1,0],[0,0,0],[0,0,0]]}\n", "symmetric"),
        ("scenario:\n  reference: paper_steps\n  wind: 3\n", "unknown key"),
        ("scenario:\n  reference: no_such_reference\n", "no_such_reference"),
    ],
)
def test_bad_scenario_files(tmp_path, body, match):
    f = tmp_path / "s.yaml"
    f.write_text(body)
    with pytest.raises(ConfigError, match=match):
        load_scenario(f)


def test_unknown_scenario_lists_packaged():
    with pytest.raises(ConfigError, match="packaged scenarios: .*disturbance.*nominal.*variation"):
        load_scenario("hurricane")


def test_beyond_authority_names_each_axis_whose_torque_the_vehicle_cannot_match():
    """Issue 25: a scenario beyond the vehicle's torque authority is said as such before it flies (demo)."""
    from mavastsm.scenarios import beyond_authority

    solo = (2.9, 2.9, 0.23)
    assert beyond_authority(load_scenario("disturbance_yaw"), solo) == ["yaw 0.50 N m > 0.23 N m"]
    assert beyond_authority(load_scenario("disturbance"), solo) == ["yaw 0.50 N m > 0.23 N m"]
    assert beyond_authority(load_scenario("disturbance_within_authority"), solo) == []
    assert beyond_authority(load_scenario("nominal"), solo) == []
    assert beyond_authority(load_scenario("disturbance_roll"), (0.4, 2.9, 0.23)) == ["roll 0.50 N m > 0.40 N m"]
