"""ArduPilot's sqrt_controller (mavastsm.ap_math, the one copy the bridge and the sim use) against values computed by
hand from AP_Math/control.cpp:

    if second_ord_lim <= 0:   correction = error * p
    elif p == 0:              correction = sign(error) sqrt(2 second_ord_lim |error|)
    else: linear_dist = second_ord_lim / p^2
          |error| > linear_dist: correction = sign(error) sqrt(2 second_ord_lim (|error| - linear_dist / 2))
          else:                  correction = error * p
    if dt > 0: correction = constrain(correction, -|error| / dt, |error| / dt)
"""

from __future__ import annotations

import math

import pytest

from mavastsm.ap_math import sqrt_controller


@pytest.mark.parametrize("error,p,lim,dt,want", [
    (0.01, 4.0, 10.0, 0.0, 0.04),                     # linear: 0.01 < linear_dist = 10 / 16 = 0.625
    (0.625, 4.0, 10.0, 0.0, 2.5),                     # at linear_dist: still p e
    (1.0, 4.0, 10.0, 0.0, math.sqrt(13.75)),          # sqrt(2 * 10 * (1 - 0.3125)) = 3.70809...
    (-1.0, 4.0, 10.0, 0.0, -math.sqrt(13.75)),
    (0.25, 0.0, 8.0, 0.0, 2.0),                       # p = 0: sqrt(2 * 8 * 0.25) = 2
    (-0.25, 0.0, 8.0, 0.0, -2.0),
    (0.3, 4.5, 0.0, 0.0, 1.35),                       # no limit: p e
    (0.3, 4.5, -1.0, 0.0, 1.35),
    (1.0, 4.0, 10.0, 0.25, math.sqrt(13.75)),         # |e| / dt = 4 > 3.708: not clamped
    (1.0, 4.0, 10.0, 0.3, 1.0 / 0.3),                 # |e| / dt = 3.333 < 3.708: clamped (no overshoot in one step)
    (0.001, 4.0, 10.0, 0.5, 0.002),                   # linear 0.004 clamped to 0.001 / 0.5
    (-0.001, 4.0, 10.0, 0.5, -0.002),
])
def test_sqrt_controller_matches_hand_computed_ap_math(error, p, lim, dt, want):
    assert sqrt_controller(error, p, lim, dt) == pytest.approx(want, rel=1e-12, abs=1e-15)


def test_the_bridge_and_the_sim_use_this_copy():
    from mavastsm.bridge.cycle import autopilot_target_model, reference_shaping
    from mavastsm_sim import attitude_math

    assert reference_shaping.sqrt_controller is autopilot_target_model.sqrt_controller is attitude_math.sqrt_controller is sqrt_controller


def test_one_settling_time_and_overshoot_for_offline_the_bridge_and_the_tests():
    """Hand-computed: a 10-unit step at t = 1 s, samples every 0.1 s; error -10 -> -6 -> 1.2 (12 % overshoot) ->
    -0.6 (outside the 5 % band of 0.5) -> 0.3 -> 0.1 ...: last outside at 1.3 s, back inside at 1.4 s -> 0.4 s."""
    from mavastsm.bridge.record.tracking_metrics import axis_metrics
    from mavastsm.offline import metrics as offline
    from mavastsm.step_metrics import overshoot_pct, settling_time_s

    t = [0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6]
    e = [0.0, -10.0, -6.0, 1.2, -0.6, 0.3, 0.1, 0.0]
    assert settling_time_s(t, e, 0.5, 1.0) == pytest.approx(0.4)
    assert overshoot_pct(t, e, 10.0, 1.0) == pytest.approx(12.0)
    assert offline.settling_time_s is settling_time_s
    m = axis_metrics(list(zip(t, e)), 0, 1.0, 10.0)
    assert m.settling_time_5pct_s == pytest.approx(0.4) and m.overshoot_pct == pytest.approx(12.0)
