"""Property: whatever arrives, every SET_ATTITUDE_TARGET the bridge puts on the wire is finite, inside
the configured limits, addressed to the vehicle, and carries a type_mask ArduCopter accepts.

Hypothesis generates sequences of valid and invalid inbound datagrams; they are injected into a real
bridge (public ``Bridge`` API, real pymavlink link, real session and safety gate) that is flying the
sim in lockstep, interleaved with the sim's own ATTITUDE stream. The outbound side is read from the
wire (proxy tap), not from the bridge's bookkeeping. ``derandomize=True``: the same examples on
every run. One bridge session serves all examples (starting one per example would cost ~2 s each).
"""

from __future__ import annotations

import math
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402  (test code is a MAVLink peer)

pytestmark = pytest.mark.sitl

VEHICLE = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
STRANGER = mavlink2.MAVLink(None, srcSystem=3, srcComponent=1)

finite_angle = st.floats(-0.6, 0.6)  # inside the 35 deg envelope: drives the controller, not the envelope failsafe
rate = st.floats(-19.9, 19.9)  # inside max_input_rate_rads (20): valid, but far beyond what the vehicle does
bad_float = st.sampled_from([math.nan, math.inf, -math.inf, 1e30, -1e30, 50.0])

# Each inbound item: (kind, payload parameters). Times are relative to the vehicle clock at injection [ms].
valid_attitude = st.tuples(st.just("attitude"), st.sampled_from([1, 0, -40]), finite_angle, finite_angle,
                           st.floats(-math.pi, math.pi), rate, rate, rate)
invalid_attitude = st.tuples(st.just("attitude"), st.sampled_from([1, 1000]), bad_float, finite_angle,
                             st.floats(-math.pi, math.pi), rate, bad_float, rate)
inbound = st.one_of(
    valid_attitude,
    invalid_attitude,
    st.tuples(st.just("foreign attitude"), finite_angle, finite_angle),
    st.tuples(st.just("random bytes"), st.binary(min_size=1, max_size=300)),
    st.tuples(st.just("truncated"), st.integers(1, 30)),
    st.tuples(st.just("foreign heartbeat"), st.integers(0, 30)),
    st.tuples(st.just("command ack"), st.integers(0, 600), st.integers(0, 9)),
)


def encode(item, vehicle_ms: int) -> bytes:
    kind = item[0]
    if kind == "attitude":
        _, dt_ms, roll, pitch, yaw, p, q, r = item
        return VEHICLE.attitude_encode(max(0, vehicle_ms + dt_ms), roll, pitch, yaw, p, q, r).pack(VEHICLE)
    if kind == "foreign attitude":
        return STRANGER.attitude_encode(vehicle_ms + 1, item[1], item[2], 0.0, 0.0, 0.0, 0.0).pack(STRANGER)
    if kind == "random bytes":
        return item[1]
    if kind == "truncated":
        frame = VEHICLE.attitude_encode(vehicle_ms + 1, 0.3, 0.3, 0.0, 5.0, 5.0, 5.0).pack(VEHICLE)
        return frame[: item[1]]
    if kind == "foreign heartbeat":
        return STRANGER.heartbeat_encode(2, 3, 217, item[1], 4).pack(STRANGER)
    if kind == "command ack":
        return VEHICLE.command_ack_encode(item[1], item[2]).pack(VEHICLE)
    raise AssertionError(kind)


@pytest.fixture
def flying_bridge(flight_factory):
    # M2 on roll/pitch (the Solo's description flies M9): M2 builds the command on the measured rate, so the injected
    # extreme rates (+-19.9 rad/s) reach the rate limit and the gate is exercised; an integrated command (M9) does not
    # follow them (checked by test_bridge_pure's M9 tests), and this property is about the gate
    flight = flight_factory(controller="astsm", reference="hold", bridge=dict(duration_s=600.0),
                            overrides={"mapping.roll_pitch_command_base": "measured"})
    flight.wait_engaged()
    yield flight
    flight.bridge.request_stop()


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(sequence=st.lists(inbound, min_size=1, max_size=8))
def test_every_outbound_setpoint_is_finite_within_limits_with_an_accepted_mask(flying_bridge, sequence):
    flight = flying_bridge
    for item in sequence:
        vehicle_ms = int(round(flight.proxy.vehicle_time_s * 1000))
        flight.proxy.inject("from_target", encode(item, vehicle_ms))
    # let the bridge answer a few real samples after the burst, then check everything sent so far
    flight.wait_vehicle_time(flight.server.sim_time_s + 0.01, timeout_s=10.0)
    assert flight.setpoint_violations() == []
    assert flight.bridge.link.stats.reader_errors == 0


def test_property_run_exercised_the_controller_and_the_gate(flight_factory, sitl_record):
    """The property above is only meaningful if the bridge was still commanding while fed garbage:
    run the same kind of input for longer and show the controller kept sending rate setpoints."""
    import random

    # M2 on roll/pitch (the Solo's description flies M9): M2 builds the command on the measured rate, so the injected
    # extreme rates (+-19.9 rad/s) reach the rate limit and the gate is exercised; an integrated command (M9) does not
    # follow them (checked by test_bridge_pure's M9 tests), and this property is about the gate
    flight = flight_factory(controller="astsm", reference="hold", bridge=dict(duration_s=600.0),
                            overrides={"mapping.roll_pitch_command_base": "measured"})
    engage_s = flight.wait_engaged()
    rng = random.Random(7)
    for k in range(200):
        flight.wait_vehicle_time(engage_s + 0.2 + 0.005 * k)
        vehicle_ms = int(round(flight.proxy.vehicle_time_s * 1000))
        item = ("attitude", 1, rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-3, 3),
                rng.uniform(-19, 19), rng.uniform(-19, 19), rng.uniform(-19, 19))
        if k % 3 == 0:
            item = ("attitude", 1, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0)
        flight.proxy.inject("from_target", encode(item, vehicle_ms))
    flight.bridge.request_stop()
    summary = flight.finish()
    lim = flight.bridge.config.limits
    rate_sps = [m for _, m in flight.setpoints if m.type_mask == 0x80]
    at_limit = sum(1 for m in rate_sps if any(abs(abs(w) - mx) < 1e-9 for w, mx in
                                              zip((m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate), lim.max_rate_cmd_rads)))
    sitl_record("property: random valid/invalid inbound sequences", "every outbound SET_ATTITUDE_TARGET finite, "
                "within limits, mask 0x80/0x07/0x87, target sysid 1", category="check",
                setpoints=len(flight.setpoints), rate_setpoints=len(rate_sps), clamped_at_rate_limit=at_limit,
                invalid=summary.invalid, superseded=summary.superseded, failsafe=summary.failsafe.name if summary.failsafe else "none")
    assert flight.setpoint_violations() == []
    assert at_limit > 0, "the injected extremes never reached the rate limit: the gate was not exercised"
    assert summary.invalid > 0
