"""Reference profiles: paper steps, prefilter derivatives, ramp, sine, relative_to, bad files."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.errors import ConfigError
from mavastsm.references import load_reference

D = np.radians


def test_paper_steps_values_and_zero_derivatives():
    ref = load_reference("paper_steps")
    assert ref.name == "paper_steps" and ref.duration_s == 5.0
    t = np.array([0.0, 0.49, 0.5, 0.99, 1.0, 1.99, 2.0, 4.9])
    th, thd, thdd = ref.at(t)
    np.testing.assert_allclose(np.degrees(th), [[0, 0, 0], [0, 0, 0], [-10, 0, 0], [-10, 0, 0], [-10, 10, 0],
                                                [-10, 10, 0], [-10, 10, 45], [-10, 10, 45]], atol=1e-12)
    assert not thd.any() and not thdd.any()
    scalar = ref.at(2.5)
    assert all(a.shape == (3,) for a in scalar)
    assert ref.event_times_s(2) == [2.0] and ref.step_size_rad(0) == pytest.approx(D(-10))


def test_prefilter_is_consistent_with_its_derivatives():
    ref = load_reference("paper_steps_prefiltered")
    assert ref.prefilter_wn_rads == 10.0
    t = np.arange(0.0, 5.0, 1e-4)
    th, thd, thdd = ref.at(t)
    # numerical derivatives agree with the closed forms; output starts at 0, ends at the step
    np.testing.assert_allclose(np.gradient(th[:, 2], t)[100:-100], thd[100:-100, 2], atol=2e-3)
    # the filtered step's acceleration jumps at the step instant (wn^2 A), so skip samples next to it
    smooth = np.abs(t - 0.5) > 2e-4
    np.testing.assert_allclose(np.gradient(thd[:, 0], t)[smooth], thdd[smooth, 0], atol=5e-2)
    assert th[0].tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(np.degrees(th[-1]), [-10, 10, 45], atol=0.05)
    # critically damped: never overshoots
    assert np.degrees(th[:, 2]).max() <= 45.0 + 1e-9
    # hand value: 0.1 s after the yaw step, y = 45 deg (1 - (1 + 1) e^-1) = 45 * 0.2642411
    np.testing.assert_allclose(np.degrees(ref.at(2.1)[0][2]), 45 * 0.26424112, rtol=1e-6)


def test_ramp_and_sine():
    ramp = load_reference("yaw_ramp")
    th, thd, _ = ramp.at(np.array([0.5, 2.0, 3.5]))
    np.testing.assert_allclose(np.degrees(th[:, 2]), [0, 45, 90], atol=1e-9)
    np.testing.assert_allclose(np.degrees(thd[:, 2]), [0, 45, 0], atol=1e-9)
    sine = load_reference("roll_sine")
    th, thd, thdd = sine.at(np.array([1.0, 1.5, 2.0]))
    # 5 deg at 0.5 Hz from t = 1 s: sin(pi/2) at t = 1.5, rate 5 deg * pi at the start
    np.testing.assert_allclose(np.degrees(th[:, 0]), [0, 5, 0], atol=1e-9)
    np.testing.assert_allclose(np.degrees(thd[0, 0]), 5 * np.pi, rtol=1e-12)
    np.testing.assert_allclose(np.degrees(thdd[1, 0]), -5 * np.pi**2, rtol=1e-12)


def test_relative_to_engage_attitude_and_yaw_wrap():
    ref = load_reference("paper_steps").relative_to(D([2.0, -1.0, 170.0]))
    th, _, _ = ref.at(3.0)
    np.testing.assert_allclose(np.degrees(th), [-8.0, 9.0, -145.0], atol=1e-9)  # 170 + 45 wraps to -145
    hold = load_reference("hold").relative_to(D([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(np.degrees(hold.at(4.0)[0]), [1, 2, 3], atol=1e-12)


@pytest.mark.parametrize(
    "body, match",
    [
        ("reference:\n  roll: []\n", "missing key 'reference.duration_s'"),
        ("reference:\n  duration_s: -1\n", "duration_s.*must be > 0"),
        ("reference:\n  duration_s: 5\n  roll:\n    - {type: jump, time_s: 1}\n", "needs 'type'"),
        ("reference:\n  duration_s: 5\n  roll:\n    - {type: step, time_s: 1}\n", "missing \\['angle_deg'\\]"),
        ("reference:\n  duration_s: 5\n  pitch:\n    - {type: ramp, start_time_s: 2, end_time_s: 1, angle_deg: 3}\n", "must be > start_time_s"),
        ("reference:\n  duration_s: 5\n  speed: 3\n", "unknown key"),
        ("nothing: 1\n", "missing section 'reference'"),
    ],
)
def test_bad_reference_files(tmp_path, body, match):
    f = tmp_path / "r.yaml"
    f.write_text(body)
    with pytest.raises(ConfigError, match=match):
        load_reference(f)


def test_unknown_reference_name_lists_packaged():
    with pytest.raises(ConfigError, match="packaged references: .*paper_steps"):
        load_reference("zigzag")
