"""Typed values past the link: what the link hands to preflight and the bridge is a small frozen dataclass built
from the message (AUTOPILOT_VERSION, GLOBAL_POSITION_INT, LOCAL_POSITION_NED), never the pymavlink message itself."""

from __future__ import annotations

import dataclasses
import time
from types import SimpleNamespace

import pytest

from mavastsm.bridge.link.messages import (
    AutopilotVersion,
    GlobalPosition,
    LocalPosition,
    autopilot_version,
    global_position,
    local_position,
)
from mavastsm.bridge.link.mavlink_link import MSG_ID_AUTOPILOT_VERSION, MavlinkLink

from .fake_autopilot import FakeAutopilot


def test_autopilot_version_decodes_the_packed_version():
    msg = SimpleNamespace(flight_sw_version=(4 << 24) | (5 << 16) | (7 << 8) | 255, capabilities=0b1010)
    v = autopilot_version(msg)
    assert v == AutopilotVersion((4, 5, 7), 255, 0b1010)
    assert v.text == "4.5.7"
    with pytest.raises(dataclasses.FrozenInstanceError):
        v.version = (9, 9, 9)  # type: ignore[misc]


def test_global_position_is_in_metres():
    gp = global_position(SimpleNamespace(time_boot_ms=1234, alt=584_500, relative_alt=5_250))
    assert gp == GlobalPosition(1234, 584.5, 5.25)
    assert gp.home_amsl_m == pytest.approx(579.25)


def test_local_position_keeps_ned_signs():
    lp = local_position(SimpleNamespace(time_boot_ms=7, x=1.0, y=-2.0, z=-5.0, vx=0.1, vy=0.2, vz=-0.5))
    assert lp == LocalPosition(7, (1.0, -2.0, -5.0), (0.1, 0.2, -0.5))
    assert all(isinstance(c, float) for c in lp.position_ned_m + lp.velocity_ned_ms)


def test_the_link_hands_on_a_typed_autopilot_version():
    with FakeAutopilot(version=(4, 3, 2)) as fake:
        link = MavlinkLink(fake.url, target_system=1)
        try:
            link.open(3.0)
            assert link.autopilot_version() is None or isinstance(link.autopilot_version(), AutopilotVersion)
            assert link.requests.request_message(MSG_ID_AUTOPILOT_VERSION, 2.0) is True
            v = link.autopilot_version()
            assert isinstance(v, AutopilotVersion) and v.version == (4, 3, 2) and v.release_type == 255
            deadline = time.monotonic() + 2.0
            while link.global_position() is None and time.monotonic() < deadline:
                time.sleep(0.02)
            gp = link.global_position()  # the fake streams GLOBAL_POSITION_INT with its altitude
            assert isinstance(gp, GlobalPosition) and gp.relative_alt_m == pytest.approx(fake.alt_m, abs=1e-3)
            lp = link.local_position()
            assert lp is None or isinstance(lp, LocalPosition)
        finally:
            link.close()
