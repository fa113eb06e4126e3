"""The link's reader in a burst (several ATTITUDE frames queued at once): only the newest valid sample is acted on,
but an invalid one (NaN) goes to the session in arrival order, after the valid sample that arrived before it.

The session ends the engagement on ``timing.invalid_samples`` (3) *consecutive* invalid samples. Delivered NaN-first,
a burst valid, NaN, valid, NaN, valid, NaN looked like three in a row: on a loaded machine the garbage-injection
property test (tests/sitl/test_outbound_setpoint_properties.py) ended in INVALID_INPUT before any injected extreme
reached the gate in 4 of 20 runs with two CPU hogs; 0 of 16 after. Fed frame by frame here, no socket."""

from __future__ import annotations

import math
from types import SimpleNamespace

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavastsm.bridge.link.mavlink_link import MavlinkLink

PEER = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)


def _frame(ms: int, roll: float):
    return mavlink2.MAVLink(None).decode(bytearray(PEER.attitude_encode(ms, roll, 0.0, 0.0, 0.0, 0.0, 0.0).pack(PEER)))


def _burst_link(got: list) -> MavlinkLink:
    link = MavlinkLink("udpout:127.0.0.1:9", target_system=1)
    link.on_attitude = got.append
    link._receiver = SimpleNamespace(queue=[b"queued"])  # every frame has another queued behind it: one burst
    return link


def test_an_invalid_attitude_in_a_burst_follows_the_valid_one_that_arrived_before_it():
    got: list = []
    link = _burst_link(got)
    pending = None
    for ms, roll in ((1000, 0.1), (1002, math.nan), (1005, 0.2), (1007, math.nan), (1010, 0.3), (1012, math.nan)):
        pending = link._on_attitude_frame(_frame(ms, roll), ms * 1_000_000, None, False, pending, None)
    assert [s.time_boot_ms for s in got] == [1000, 1002, 1005, 1007, 1010, 1012]  # never two invalid in a row
    assert pending is None and link.stats.superseded == 0


def test_valid_attitudes_in_a_burst_still_collapse_to_the_newest():
    got: list = []
    link = _burst_link(got)
    pending = None
    for ms in (1000, 1002, 1005):
        pending = link._on_attitude_frame(_frame(ms, 0.1), ms * 1_000_000, None, False, pending, None)
    assert got == [] and pending.time_boot_ms == 1005 and pending.superseded == 2 and link.stats.superseded == 2
