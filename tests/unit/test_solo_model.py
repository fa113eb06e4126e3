"""Solo model: Table 1 values, inertia variants and the nominal drift f(X) (eq. 17) by hand."""

from __future__ import annotations

import numpy as np
import pytest

from mavastsm.solo_model import load_solo, nominal_drift_torque


def test_table1_and_variants():
    solo = load_solo()
    assert solo.mass == 1.5 and solo.arm_length == 0.205
    np.testing.assert_allclose(solo.inertia_diag, [8.85e-3, 15.5e-3, 23.09e-3])
    literal = load_solo(inertia_variant="paper_literal")
    np.testing.assert_allclose(literal.inertia_diag, [8.85e-3, 1.55e-3, 23.09e-3])
    # the corrected variant satisfies the triangle inequality of principal moments; the literal one does not
    assert solo.inertia_zz <= solo.inertia_xx + solo.inertia_yy
    assert literal.inertia_zz > literal.inertia_xx + literal.inertia_yy


def test_nominal_drift_hand_values():
    # omega = (1, 2, 3) rad/s: f = [(Iyy-Izz) q r, (Izz-Ixx) p r, (Ixx-Iyy) p q]
    #   = [(-7.59e-3)(6), (14.24e-3)(3), (-6.65e-3)(2)] = [-0.04554, 0.04272, -0.0133] N m
    f = nominal_drift_torque([8.85e-3, 15.5e-3, 23.09e-3], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(f, [-0.04554, 0.04272, -0.0133], rtol=1e-12)
    # f = -omega x (I omega)
    w = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(f, -np.cross(w, np.diag([8.85e-3, 15.5e-3, 23.09e-3]) @ w), rtol=1e-12)


def test_nominal_drift_broadcasts():
    w = np.random.default_rng(0).normal(size=(4, 3))
    f = nominal_drift_torque([1.0, 2.0, 3.0], w)
    assert f.shape == (4, 3)
    np.testing.assert_allclose(f[2], nominal_drift_torque([1.0, 2.0, 3.0], w[2]))


def test_bad_variant_rejected():
    from mavastsm.errors import ConfigError

    with pytest.raises(ConfigError, match="inertia_variant.*must be one of"):
        load_solo(inertia_variant="heavy")
