"""A controller with a bug, for the CONTROLLER_FAULT tests on our sim and on genuine ArduCopter."""

from __future__ import annotations


class RaisingController:
    """A real ASTSM that raises after ``after`` updates: a law with a bug, mid-flight."""

    def __init__(self, after: int, overrides: dict | None = None) -> None:
        from mavastsm.control import make_controller
        from mavastsm.solo_model import load_solo

        self._law = make_controller("astsm", load_solo(None), "astsm_mavlink", overrides)
        self.name = "raising-astsm"
        self.gains = self._law.gains
        self.after = after
        self.updates = 0

    def reset(self) -> None:
        self._law.reset()

    def update(self, err, dt_s):
        self.updates += 1
        if self.updates > self.after:
            raise ZeroDivisionError("the law divided by zero")
        return self._law.update(err, dt_s)

    def diagnostics(self):
        return self._law.diagnostics()

    def adaptive_gain(self):
        return self._law.adaptive_gain()

    def limit_overrides(self, torque_limit_nm=None, adaptive_gain_range=None, integral_off=None):
        return {}  # flown as built
