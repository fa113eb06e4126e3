"""ArduPilot's AP_Math control functions the bridge and the sim both need, written once (AP_Math/control.cpp).

Tested against values computed by hand from AP_Math's code in tests/unit/test_ap_math.py.
"""

from __future__ import annotations

import math


def sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float = 0.0) -> float:
    """ArduPilot's ``sqrt_controller`` (AP_Math/control.cpp): P near zero, sqrt (constant deceleration)
    far away, and never more than ``|error| / dt`` so it cannot overshoot in one step (as AP_Math, only when
    ``dt`` > 0: ``dt`` = 0 leaves the correction unclamped).

    error [any unit], p [1/s], second_ord_lim [error unit / s^2] (<= 0: P only), dt [s]."""
    if second_ord_lim <= 0.0:
        correction = error * p
    elif p == 0.0:
        correction = math.copysign(math.sqrt(2.0 * second_ord_lim * abs(error)), error)
    else:
        linear_dist = second_ord_lim / (p * p)
        if error > linear_dist:
            correction = math.sqrt(2.0 * second_ord_lim * (error - linear_dist / 2.0))
        elif error < -linear_dist:
            correction = -math.sqrt(2.0 * second_ord_lim * (-error - linear_dist / 2.0))
        else:
            correction = error * p
    if dt > 0.0:
        lim = abs(error) / dt
        correction = min(max(correction, -lim), lim)
    return correction
