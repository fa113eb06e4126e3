"""Helpers for fast offline tests: time-compressed copies of the packaged scenarios."""

from __future__ import annotations

from dataclasses import replace

import pytest

from mavastsm.scenarios import Scenario, TorqueEvent, load_scenario


def compressed_scenario(name: str, scale: float) -> Scenario:
    """The packaged scenario with every time (steps, disturbance, duration) multiplied by ``scale``."""
    s = load_scenario(name)
    ref = replace(s.reference, duration_s=s.reference.duration_s * scale,
                  components=tuple(replace(c, start_s=c.start_s * scale, end_s=c.end_s * scale) for c in s.reference.components))
    events = tuple(TorqueEvent(e.start_s * scale, e.end_s * scale, e.torque_nm) for e in s.disturbances)
    return replace(s, duration_s=s.duration_s * scale, reference=ref, disturbances=events)


@pytest.fixture
def compressed():
    """Fixture form of :func:`compressed_scenario` (test modules cannot import conftest reliably)."""
    return compressed_scenario
