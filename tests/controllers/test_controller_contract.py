"""Contract every attitude controller must honour (controller_interface.AttitudeController): the packaged ones, those
installed distributions register (entry-point group mavastsm.controllers), and any law named with ``--law``:

    pytest tests/controllers/test_controller_contract.py --law my_laws:PdController --law path/to/pd_law.py:PdController
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavastsm.control import CONTROLLERS, AttitudeController, installed_laws, law_class, make_controller, tracking_error
from mavastsm.control.single_sample import AxisState
from mavastsm.errors import ConfigError
from mavastsm.solo_model import load_solo

SOLO = load_solo()


def pytest_generate_tests(metafunc):
    """``name`` runs over every packaged and installed law, then over the ``--law`` values (tests/controllers/conftest.py)."""
    if "name" in metafunc.fixturenames:
        metafunc.parametrize("name", [*sorted(CONTROLLERS), *sorted(installed_laws()), *metafunc.config.getoption("law", default=[])])


def zero_error():
    return tracking_error(np.zeros(3), np.zeros(3), np.zeros(3))


def random_error(rng):
    euler = rng.uniform([-0.5, -0.5, -np.pi], [0.5, 0.5, np.pi])
    return tracking_error(euler, rng.uniform(-3, 3, 3), rng.uniform([-0.5, -0.5, -np.pi], [0.5, 0.5, np.pi]), rng.uniform(-1, 1, 3), rng.uniform(-5, 5, 3))


def snapshot(ctrl):
    """Array attributes plus the per-axis state attributes (AxisState: stored as floats on the single-sample path)."""
    state = {k: np.array(v, copy=True) for k, v in vars(ctrl).items() if isinstance(v, np.ndarray)}
    for cls in type(ctrl).__mro__:
        for k, v in vars(cls).items():
            if isinstance(v, AxisState):
                value = getattr(ctrl, k)
                state[k] = None if value is None else np.array(value, copy=True)
    return state


def test_class_metadata_and_protocol(name):
    cls = law_class(name)
    assert (cls.name == name) if ":" not in name else cls.name.isidentifier()  # a key names its law; MODULE:CLASS any
    assert cls.summary and "\n" not in cls.summary
    assert cls.default_config.endswith(".yaml")
    assert isinstance(make_controller(name, SOLO), AttitudeController)


def test_zero_error_gives_zero_switching_term_and_zero_output(name):
    ctrl = make_controller(name, SOLO)
    for _ in range(5):
        u = ctrl.update(zero_error(), 1e-3)
        diag = ctrl.diagnostics()
        if "u_d" in diag:
            np.testing.assert_array_equal(diag["u_d"], 0.0)
        np.testing.assert_array_equal(u, 0.0)


def test_reset_restores_start_state(name):
    ctrl = make_controller(name, SOLO)
    start, start_diag = snapshot(ctrl), {k: np.array(v) for k, v in ctrl.diagnostics().items()}
    rng = np.random.default_rng(3)
    for _ in range(50):
        ctrl.update(random_error(rng), 1e-3)
    ctrl.reset()
    after = snapshot(ctrl)
    assert after.keys() == start.keys()
    for k in start:
        np.testing.assert_array_equal(after[k], start[k], err_msg=k)
    assert {k: np.array(v) for k, v in ctrl.diagnostics().items()}.keys() == start_diag.keys()
    # and the output sequence after reset equals that of a fresh instance
    fresh = make_controller(name, SOLO)
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(4)
    for _ in range(20):
        np.testing.assert_array_equal(ctrl.update(random_error(rng_a), 1e-3), fresh.update(random_error(rng_b), 1e-3))


def test_diagnostics_keys_stable(name):
    ctrl = make_controller(name, SOLO)
    keys0 = set(ctrl.diagnostics())
    rng = np.random.default_rng(5)
    for _ in range(10):
        ctrl.update(random_error(rng), 2.5e-3)
        assert set(ctrl.diagnostics()) == keys0
        assert all(np.shape(v) == (3,) for v in ctrl.diagnostics().values())
    assert "u" in keys0
    if name in ("astsm", "stsm", "smc", "atsm"):
        assert {"sigma", "u_eq", "u_d", "u"} <= keys0
    if name == "astsm":
        assert {"alpha", "beta", "nu"} <= keys0


@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan")])
def test_non_positive_dt_raises(name, dt):
    with pytest.raises(ValueError):
        make_controller(name, SOLO).update(zero_error(), dt)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), dt=st.sampled_from([1e-4, 1e-3, 2.5e-3, 1e-2]))
def test_output_finite_and_bounded_under_random_inputs(name, seed, dt):
    """Finite output; bounded by the torque limit when the law has one (protocol: ``limit_overrides``), by a
    generous bound otherwise."""
    limit = np.array([2.9, 2.9, 0.4])  # the packaged laws' default torque_limit_nm
    free = make_controller(name, SOLO)
    over = free.limit_overrides(torque_limit_nm=tuple(limit))
    limited = make_controller(name, SOLO, overrides=over) if over else None
    rng = np.random.default_rng(seed)
    for _ in range(30):
        err = random_error(rng)
        u_free = free.update(err, dt)
        assert np.all(np.isfinite(u_free)) and np.all(np.abs(u_free) < 1e3)
        if limited is not None:
            u_lim = limited.update(err, dt)
            assert np.all(np.isfinite(u_lim)) and np.all(np.abs(u_lim) <= limit + 1e-12)


def test_limit_members_are_what_a_rebuild_from_the_overrides_gives(name):
    """The protocol's limit members: the overrides a law returns build (make_controller accepts every key) and the
    rebuilt law reports the limits asked for; a law without an adaptive gain says None."""
    ctrl = make_controller(name, SOLO)
    gain = ctrl.adaptive_gain()
    asked = ((0.1, 0.2, 0.3), (5.0, 6.0, 7.0)) if gain is not None else None
    over = ctrl.limit_overrides(torque_limit_nm=(1.0, 1.5, 0.2), adaptive_gain_range=asked, integral_off=(False, False, True))
    rebuilt = make_controller(name, SOLO, overrides=over or None)
    if gain is None:
        assert rebuilt.adaptive_gain() is None
    else:
        assert (rebuilt.adaptive_gain().alpha_min, rebuilt.adaptive_gain().alpha_max) == asked
        assert rebuilt.adaptive_gain().alpha_min == pytest.approx(asked[0])


def test_batched_equals_scalar(name):
    rng = np.random.default_rng(11)
    errs = [random_error(rng) for _ in range(4)]
    batched = make_controller(name, SOLO, batch_shape=(4,))
    scalars = [make_controller(name, SOLO) for _ in range(4)]
    stacked = tracking_error(
        np.stack([e.euler_rad for e in errs]), np.stack([e.body_rates_rads for e in errs]),
        np.stack([e.euler_rad - e.angle_error_rad for e in errs]),
    )
    for _ in range(3):
        ub = batched.update(stacked, 1e-3)
        for i, c in enumerate(scalars):
            e = errs[i]
            us = c.update(tracking_error(e.euler_rad, e.body_rates_rads, e.euler_rad - e.angle_error_rad), 1e-3)
            np.testing.assert_allclose(ub[i], us, rtol=1e-12, atol=1e-12)


def test_unknown_controller_lists_registered():
    with pytest.raises(ConfigError, match="registered: .*astsm"):
        make_controller("lqr", SOLO)
