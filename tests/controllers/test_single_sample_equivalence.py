"""The single-sample fast path (Python floats, batch_shape ()) equals the NumPy path to ~1e-12.

Reference: the same controller built with batch_shape (1,) (the array code the offline simulator runs) fed
with ``tracking_error`` of (1, 3) arrays. Candidate: batch_shape () fed with ``tracking_error`` of tuples
(the live bridge's case). Seeded random sequences mix large errors (torque saturation, alpha up to its
clamp) and tiny ones (|sigma| < mu: alpha down to alpha_m, then the eta branch), random dt, and a reset
half-way; outputs, every diagnostics key and the state attributes are compared at every step.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavastsm.control import CONTROLLERS, make_controller, tracking_error
from mavastsm.control.controller_interface import TrackingError
from mavastsm.control.single_sample import AxisState, FloatDiagnostics, diagnostics_floats, sgn
from mavastsm.frames import (
    body_rates_from_euler_rates,
    body_rates_from_euler_rates_floats,
    euler_rates_from_body_rates,
    euler_rates_from_body_rates_floats,
    wrap_angle,
    wrap_angle_float,
)
from mavastsm.solo_model import load_solo

SOLO = load_solo()
TOL = dict(rtol=1e-12, atol=1e-12)
DTS = (1e-4, 1e-3, 2.5e-3, 1e-2)
ERR_FIELDS = ("angle_error_rad", "euler_rate_error_rads", "ref_euler_accel_radss", "body_rates_rads", "euler_rad", "ref_euler_rate_rads")

# (registry key, overrides): defaults, torque limits on, and the branches each law has
CASES = [
    ("astsm", {}),
    ("astsm", {"torque_limit_enabled": True, "alpha_max": 5.0}),
    ("astsm", {"torque_limit_enabled": True, "gain_units": "torque", "beta_offset": 0.3}),
    ("stsm", {}),
    ("stsm", {"torque_limit_enabled": True}),
    ("smc", {}),
    ("smc", {"torque_limit_enabled": True, "boundary_layer": 0.05}),
    ("atsm", {}),
    ("atsm", {"torque_limit_enabled": True}),
    ("pid", {}),
    ("pid", {"rate_feedforward_enabled": False, "torque_limit_enabled": True}),
    ("pid_fair", {}),
]


def random_inputs(rng):
    """One sample's (euler, body rates, ref, ref rate, ref accel) as tuples, with a random error scale."""
    scale = rng.choice([1e-5, 1e-2, 0.3, 1.0, 30.0])  # 30: rates and accelerations that saturate the torque
    euler = rng.uniform([-0.6, -0.6, -np.pi], [0.6, 0.6, np.pi])
    ref = euler + min(scale, 1.0) * rng.uniform(-1, 1, 3)
    ref[2] += rng.choice([0.0, 2 * np.pi, -2 * np.pi])  # yaw wrap
    rates = scale * rng.uniform(-3, 3, 3)
    rr = euler_rates_from_body_rates(euler, rates) + scale * rng.uniform(-1, 1, 3)
    ra = scale * rng.uniform(-5, 5, 3)
    return tuple(tuple(x.tolist()) for x in (euler, rates, ref, rr, ra))


def assert_err_equal(fast: TrackingError, ref: TrackingError, row=0):
    for f in ERR_FIELDS:
        np.testing.assert_allclose(getattr(fast, f), np.asarray(getattr(ref, f))[row], **TOL, err_msg=f)


def state_names(ctrl):
    return [k for cls in type(ctrl).__mro__ for k, v in vars(cls).items() if isinstance(v, AxisState)]


def run_pair(name, overrides, seed, steps=120):
    """Step the fast (batch ()) and array (batch (1,)) controllers side by side; return coverage counters."""
    fast = make_controller(name, SOLO, overrides=overrides)
    ref = make_controller(name, SOLO, overrides=overrides, batch_shape=(1,))
    assert fast._single and not ref._single
    rng = np.random.default_rng(seed)
    seen = {"saturated": 0, "alpha_max": 0, "alpha_min": 0, "steps": 0}
    for k in range(steps):
        if k == steps // 2:
            fast.reset(), ref.reset()
        euler, rates, r, rr, ra = random_inputs(rng)
        dt = float(rng.choice(DTS))
        e_fast = tracking_error(euler, rates, r, rr, ra)
        e_ref = tracking_error(*(np.array([x]) for x in (euler, rates, r, rr, ra)))
        assert_err_equal(e_fast, e_ref)
        u_fast, u_ref = fast.update(e_fast, dt), ref.update(e_ref, dt)
        assert isinstance(u_fast, np.ndarray) and u_fast.shape == (3,)
        np.testing.assert_allclose(u_fast, u_ref[0], **TOL, err_msg=f"u at step {k}")
        d_fast, d_ref = fast.diagnostics(), ref.diagnostics()
        assert list(d_fast) == list(d_ref)
        for key in d_ref:
            np.testing.assert_allclose(d_fast[key], d_ref[key][0], **TOL, err_msg=f"diagnostics[{key}] at step {k}")
        for attr in state_names(fast):
            a, b = getattr(fast, attr), getattr(ref, attr)
            assert (a is None) == (b is None), attr
            if a is not None:
                np.testing.assert_allclose(a, b[0], **TOL, err_msg=f"{attr} at step {k}")
        limit = getattr(fast, "_limit", None)
        if limit is not None:
            seen["saturated"] += int(np.sum(np.abs(u_ref[0]) >= limit))
        if name == "astsm":
            seen["alpha_max"] += int(np.sum(ref.alpha[0] >= fast.gains.alpha_max))
            seen["alpha_min"] += int(np.sum(ref.alpha[0] <= fast.gains.alpha_min))
        seen["steps"] += 1
    return seen


@pytest.mark.parametrize("name,overrides", CASES, ids=[f"{n}-{i}" for i, (n, _) in enumerate(CASES)])
def test_fast_path_equals_numpy_path(name, overrides):
    seen = run_pair(name, overrides, seed=20261122)
    if overrides.get("torque_limit_enabled"):
        assert seen["saturated"] > 0, "the sequence never saturated: the anti-windup branch was not compared"
    if name == "astsm" and "alpha_max" in overrides:
        assert seen["alpha_max"] > 0 and seen["alpha_min"] > 0, f"alpha clamp not exercised: {seen}"


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
@settings(max_examples=10, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), limited=st.booleans())
def test_fast_path_equals_numpy_path_random_seeds(name, seed, limited):
    run_pair(name, {"torque_limit_enabled": limited}, seed, steps=40)


def test_pid_feedforward_without_reference_rate():
    """TrackingError built by hand with ref_euler_rate_rads = None: PID recovers Theta_dot_d on both paths."""
    rng = np.random.default_rng(7)
    fast, ref = make_controller("pid", SOLO), make_controller("pid", SOLO, batch_shape=(1,))
    for _ in range(30):
        full = tracking_error(*random_inputs(rng))
        parts = [getattr(full, f) for f in ERR_FIELDS[:5]]
        u_fast = fast.update(TrackingError(*parts), 1e-3)
        u_ref = ref.update(TrackingError(*(p[None] for p in parts)), 1e-3)
        np.testing.assert_allclose(u_fast, u_ref[0], **TOL)


def test_tracking_error_fast_path_matches_batch_rows_and_input_types():
    rng = np.random.default_rng(3)
    samples = [random_inputs(rng) for _ in range(64)]
    batch = tracking_error(*(np.array(col) for col in zip(*samples)))
    assert batch.angle_error_rad.shape == (64, 3)
    for i, s in enumerate(samples):
        for convert in (tuple, list, np.array):
            assert_err_equal(tracking_error(*(convert(x) for x in s)), batch, row=i)
        assert_err_equal(tracking_error(*s[:3]), tracking_error(*(np.array([x]) for x in s[:3])))  # rates default to 0


def test_tracking_error_non_finite_inputs_match_numpy():
    """NaN / inf propagate like NumPy (no exception inside the control loop)."""
    base = ((0.1, -0.2, 3.0), (0.5, -0.4, 0.3), (0.0, 0.1, -3.0), (0.1, 0.0, 0.2), (1.0, 2.0, 3.0))
    for i in range(3):
        for j in range(3):
            for bad in (math.nan, math.inf, -math.inf):
                args = [list(x) for x in base]
                args[i][j] = bad
                fast = tracking_error(*(tuple(a) for a in args))
                with np.errstate(invalid="ignore"):
                    ref = tracking_error(*(np.array([a]) for a in args))
                for f in ERR_FIELDS:
                    np.testing.assert_allclose(getattr(fast, f), getattr(ref, f)[0], **TOL, equal_nan=True, err_msg=f)


def test_scalar_twins_of_frames_functions():
    rng = np.random.default_rng(5)
    e = rng.uniform(-1.2, 1.2, (200, 3))
    w = rng.uniform(-4, 4, (200, 3))
    er = euler_rates_from_body_rates(e, w)
    br = body_rates_from_euler_rates(e, w)
    ang = rng.uniform(-20, 20, 200)
    wr = wrap_angle(ang)
    for k in range(200):
        np.testing.assert_allclose(euler_rates_from_body_rates_floats(e[k, 0], e[k, 1], *w[k].tolist()), er[k], **TOL)
        np.testing.assert_allclose(body_rates_from_euler_rates_floats(e[k, 0], e[k, 1], *w[k].tolist()), br[k], **TOL)
        assert wrap_angle_float(float(ang[k])) == pytest.approx(float(wr[k]), abs=1e-12)
    assert wrap_angle_float(math.pi) == math.pi and wrap_angle_float(-math.pi) == math.pi  # (-pi, pi]


def test_sgn_matches_numpy_sign():
    for x in (-2.0, -1e-300, -0.0, 0.0, 1e-300, 3.0, math.inf, -math.inf):
        assert sgn(x) == np.sign(x)
    assert math.isnan(sgn(math.nan))


def test_state_attributes_read_as_arrays_and_can_be_assigned():
    c = make_controller("astsm", SOLO)
    assert isinstance(c.alpha, np.ndarray) and c.alpha.shape == (3,)
    c.alpha = [1.0, 2.0, 3.0]
    np.testing.assert_array_equal(c.alpha, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        c.nu = np.zeros((2, 3))
    c.reset()
    np.testing.assert_array_equal(c.alpha, c.gains.alpha_min)


def test_single_sample_controller_rejects_a_batch():
    c = make_controller("stsm", SOLO)
    errs = tracking_error(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="one 3-vector"):
        c.update(errs, 1e-3)


def test_fast_diagnostics_mapping_is_lazy_and_a_snapshot():
    c = make_controller("astsm", SOLO)
    err = tracking_error((0.1, 0.0, 0.2), (0.3, 0.0, 0.0), (0.0, 0.0, 0.0))
    c.update(err, 1e-3)
    d1 = c.diagnostics()
    assert isinstance(d1, FloatDiagnostics) and "alpha" in d1 and "missing" not in d1
    alpha1 = d1["alpha"]
    c.update(err, 1e-3)
    np.testing.assert_array_equal(d1["alpha"], alpha1)  # an earlier mapping does not change
    assert diagnostics_floats(c.diagnostics(), "u") == tuple(c.diagnostics()["u"].tolist())
    assert diagnostics_floats({"u": np.array([1.0, 2.0, 3.0])}, "u") == (1.0, 2.0, 3.0)
    assert diagnostics_floats(d1, "missing") is None
