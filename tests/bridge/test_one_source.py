"""No single datagram ends a flight; two vehicles claiming one identity are named, not mixed (issue 28).

Over real UDP against the in-repo sim: ATTITUDE frames with the vehicle's identity and an odd time_boot_ms injected
into the bridge's port with plain pymavlink (the issue's table), and a second simulated vehicle with the same
system id. The rule is mavastsm.bridge.link.vehicle_clock's; its arithmetic is tested in tests/unit/test_vehicle_clock.py.
"""

from __future__ import annotations

import socket
import time

import pytest

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.bridge.link.mavlink_link import mavlink
from mavastsm.errors import LinkError
from mavastsm.state_types import FailsafeReason
from mavastsm_sim.copter import SimulatedCopter
from mavastsm_sim.vehicle_server import VehicleServer

pytestmark = pytest.mark.sitl
FAST = {"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5}


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(condition, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.01)  # polling a condition with a deadline, not timing behaviour
    raise AssertionError(f"timed out waiting for {what}")


def _engaged(b: Bridge, min_vehicle_ms: int = 0) -> bool:
    s = b.session
    return s is not None and s.cycle.engage_ms is not None and (s.last_ms or 0) >= min_vehicle_ms


def test_forged_frames_two_and_ten_seconds_either_way_never_end_the_flight():
    """The issue's table, in one flight: one frame 2 s ahead, one 2 s back, three 10 s ahead, three 4 s back and
    three 10 s back (100 ms apart), each with valid fields and the vehicle's system and component id, sent twice:
    from the vehicle's own address (a spoofer on its network: the sim's own socket sends them) and from another
    one. Before, each ended the flight (STALE_ATTITUDE or VEHICLE_RESTARTED, LAND). Now the flight completes with no
    restart; the 11 from the vehicle's address are clock outliers, the 11 from elsewhere never reach the clock
    (counted as foreign)."""
    with VehicleServer(clock="realtime", listen=("127.0.0.1", 0)) as server:
        b = Bridge(BridgeOptions(f"udpout:127.0.0.1:{server.port}", controller="astsm", reference="hold", duration_s=14.0,
                                 mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=0.5, on_exit="LAND", overrides=FAST))
        b.start()
        try:
            _wait(lambda: _engaged(b, 10_500), 40.0, "engagement and 10.5 s of vehicle clock")
            spoof = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
            bridge = ("127.0.0.1", b.link._conn.port.getsockname()[1])
            foreign_before = b.link.stats.foreign_attitude
            plan = [(2_000, 1), (-2_000, 1), (10_000, 3), (-4_000, 3), (-10_000, 3)]
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as elsewhere:
                for sock in (server.transport.sock, elsewhere):
                    for offset_ms, count in plan:
                        for _ in range(count):
                            t = b.session.last_ms + offset_ms
                            sock.sendto(bytes(spoof.attitude_encode(t, 0.3, -0.2, 1.0, 0.0, 0.0, 0.0).pack(spoof)), bridge)
                            time.sleep(0.1)  # the pacing of repeated frames
                        time.sleep(0.2)
            summary = b.wait(60.0)
        finally:
            b.stop()
    assert summary.failsafe is None and summary.end_reason == "duration complete", summary.end_reason
    assert summary.vehicle_restarts == 0 and summary.vehicle_sessions == 1
    assert summary.clock_outliers == 11, summary.clock_outliers
    assert "clock outliers 11" in summary.format()
    assert b.link.stats.foreign_attitude - foreign_before == 11
    assert b.link.clock.conflict is None
    assert summary.handback == "LAND accepted", summary.handback


def _second_vehicle(bridge_port: int) -> tuple[VehicleServer, socket.socket]:
    """A second sim with the same system id (1/1) sending to the bridge's port, its ATTITUDE stream at 50 Hz
    asked for by a ground station of its own (the bridge never talks to it)."""
    other = VehicleServer(clock="realtime", listen=("127.0.0.1", 0), target=("127.0.0.1", bridge_port)).start()
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    ask = mav.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_ATTITUDE, 20_000,
                                  0, 0, 0, 0, 0)
    gcs.sendto(bytes(ask.pack(mav)), ("127.0.0.1", other.port))
    return other, gcs


def test_a_second_vehicle_on_the_same_id_started_mid_flight_is_named_and_handed_back():
    """Two vehicles on system id 1 sending to the README's udpin link; the second is started 10 s after the first
    (its clock is 10 s behind). Before, the bridge flew on whichever frame came last (restarts, stale data). Now the
    named failsafe IDENTITY_CONFLICT ends the flight with both addresses and the fix, and the second vehicle never
    received a setpoint."""
    port = _free_port()
    with VehicleServer(clock="realtime", target=("127.0.0.1", port)) as first:
        b = Bridge(BridgeOptions(f"udpin:127.0.0.1:{port}", controller="astsm", reference="hold", duration_s=30.0,
                                 mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=0.5, on_exit="LAND", on_failsafe="LAND",
                                 overrides=FAST))
        b.start()
        other = gcs = None
        try:
            _wait(lambda: _engaged(b, 10_000), 40.0, "engagement and 10 s of vehicle clock")
            other, gcs = _second_vehicle(port)
            summary = b.wait(60.0)
            to_second = other.counters["attitude_targets_received"]
        finally:
            b.stop()
            if other is not None:
                other.stop()
                gcs.close()
    assert summary.failsafe is FailsafeReason.IDENTITY_CONFLICT, summary.end_reason
    first_addr, second_addr = f"127.0.0.1:{first.port}", f"127.0.0.1:{other.port}"
    assert first_addr in summary.end_reason and second_addr in summary.end_reason, summary.end_reason
    assert "MAV_SYSID" in summary.end_reason and "MAV_SYS_ID" in summary.end_reason
    assert summary.vehicle_restarts == 0
    assert to_second == 0, "setpoints reached the second vehicle"
    assert summary.handback == "LAND accepted", summary.handback


def test_two_vehicles_on_the_same_id_before_start_up_end_it_in_one_line():
    """Both vehicles already streaming when the bridge starts: start-up ends with one line naming both sources and
    the fix (LinkError: the CLI's exit 2), or, when the second clock is recognised only after start-up, the run ends
    before engagement in the same named condition. Nothing is armed and no mode is changed either way."""
    port = _free_port()
    with VehicleServer(clock="realtime", target=("127.0.0.1", port)) as first:
        other, gcs = _second_vehicle(port)
        try:
            _wait(lambda: other.call(lambda c: c.time_boot_ms) > 0, 10.0, "the second vehicle")
            # the first vehicle's stream too, asked for the same way (the bridge would ask it only after start-up)
            mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
            ask = mav.command_long_encode(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_ATTITUDE,
                                          20_000, 0, 0, 0, 0, 0)
            gcs.sendto(bytes(ask.pack(mav)), ("127.0.0.1", first.port))
            b = Bridge(BridgeOptions(f"udpin:127.0.0.1:{port}", controller="astsm", reference="hold", duration_s=5.0,
                                     mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=0.5, on_exit="LAND",
                                     engage_timeout_s=20.0, overrides=FAST))
            try:
                b.start()
            except LinkError as exc:
                text = str(exc)
            else:
                summary = b.wait(60.0)
                assert summary.failsafe is FailsafeReason.IDENTITY_CONFLICT and summary.engagements == 0, summary.end_reason
                text = summary.end_reason
            finally:
                b.stop()
            armed = first.call(lambda c: c.armed) or other.call(lambda c: c.armed)
        finally:
            other.stop()
            gcs.close()
    assert "\n" not in text and "two vehicles claim system 1" in text, text
    assert f"127.0.0.1:{first.port}" in text and f"127.0.0.1:{other.port}" in text, text
    assert not armed


def test_a_sim_restarted_mid_flight_on_a_new_port_is_a_restart_within_half_a_second():
    """A real restart is still one: the vehicle (our sim, sending to the README's udpin link) stops mid-flight and a
    new one boots at once from another port with its ATTITUDE stream on from boot (SR0_EXTRA1 50 Hz, as an
    ArduPilot that saved it). The link follows the new address once the old one is silent and the new clock is
    confirmed: VEHICLE_RESTARTED, not STALE_ATTITUDE, within 0.5 s of the new vehicle's start."""
    port = _free_port()
    copter = SimulatedCopter()
    assert copter.params.set("SR0_EXTRA1", 50.0)[0]
    rebooted = VehicleServer(clock="realtime", target=("127.0.0.1", port), copter=copter)
    with VehicleServer(clock="realtime", target=("127.0.0.1", port)) as first:
        b = Bridge(BridgeOptions(f"udpin:127.0.0.1:{port}", controller="astsm", reference="hold", duration_s=30.0,
                                 mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=0.5, on_exit="LAND", on_failsafe="LAND",
                                 overrides=FAST))
        b.start()
        try:
            _wait(lambda: _engaged(b, 5_000), 40.0, "engagement and 5 s of vehicle clock")
            first.stop()
            t_boot = time.monotonic()
            rebooted.start()
            _wait(lambda: b.session.failsafe is not None, 10.0, "a failsafe")
            reaction_s = time.monotonic() - t_boot
            summary = b.wait(60.0)
        finally:
            b.stop()
            rebooted.stop()
    assert summary.failsafe is FailsafeReason.VEHICLE_RESTARTED, summary.end_reason
    print(f"VEHICLE_RESTARTED {reaction_s:.3f} s after the new vehicle started")
    assert reaction_s <= 0.5, reaction_s
    assert summary.vehicle_restarts == 1 and summary.clock_outliers == 0
    assert b.link.clock.conflict is None
