"""Plain-pymavlink peer tools for the black-box tests of the simulated vehicle (imported by tests/sim/*).

Tests that fly use the lockstep clock and measure time from ``time_boot_ms`` (simulated time), never from
wall-clock sleeps; wall-clock timeouts only bound waits so a broken vehicle fails fast instead of hanging.
"""

from __future__ import annotations

import os
import time
from typing import Any, Callable

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink

GCS_SYSID = 255
GCS_COMPID = 190
VEHICLE_SYSID = 1
VEHICLE_COMPID = 1
ATTITUDE_ID = mavlink.MAVLINK_MSG_ID_ATTITUDE


class Gcs:
    """A minimal pymavlink ground station (udpout to the vehicle's listening port)."""

    def __init__(self, port: int, source_system: int = GCS_SYSID, source_component: int = GCS_COMPID) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=source_system,
                                               source_component=source_component)
        self.mav = self.conn.mav

    def hello(self, timeout_s: float = 5.0) -> Any:
        """Send our HEARTBEAT (the vehicle only answers peers it has heard) and return the vehicle's."""
        self.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = self.recv("HEARTBEAT", timeout_s)
        assert hb is not None, "no HEARTBEAT from the vehicle"
        self.conn.target_system, self.conn.target_component = hb.get_srcSystem(), hb.get_srcComponent()
        return hb

    def recv(self, msg_type: str | list[str], timeout_s: float = 2.0,
             condition: Callable[[Any], bool] | None = None) -> Any:
        """Next message of ``msg_type`` (and satisfying ``condition``) within ``timeout_s`` wall seconds."""
        deadline = time.monotonic() + timeout_s
        types = [msg_type] if isinstance(msg_type, str) else msg_type
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            msg = self.conn.recv_match(type=types, blocking=True, timeout=remaining)
            if msg is None:
                return None
            if condition is None or condition(msg):
                return msg

    def command(self, command: int, *params: float, timeout_s: float = 3.0, use_int: bool = False,
                target_system: int = VEHICLE_SYSID) -> Any:
        """Send COMMAND_LONG (or COMMAND_INT) and return its COMMAND_ACK (None if none came)."""
        p = list(params) + [0.0] * (7 - len(params))
        if use_int:
            self.mav.command_int_send(target_system, VEHICLE_COMPID, 0, command, 0, 0, p[0], p[1], p[2], p[3],
                                      int(p[4]), int(p[5]), p[6])
        else:
            self.mav.command_long_send(target_system, VEHICLE_COMPID, command, 0, *p)
        return self.recv("COMMAND_ACK", timeout_s, lambda m: m.command == command)

    def set_interval(self, msg_id: int, rate_hz: float) -> Any:
        """SET_MESSAGE_INTERVAL for ``msg_id`` at ``rate_hz`` [Hz] (<0 stop, 0 default); returns the ACK."""
        interval_us = rate_hz if rate_hz <= 0 else 1e6 / rate_hz
        return self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)

    def set_param(self, name: str, value: float, timeout_s: float = 3.0) -> Any:
        """PARAM_SET and wait for the PARAM_VALUE echo of ``name``."""
        self.mav.param_set_send(VEHICLE_SYSID, VEHICLE_COMPID, name.encode(), value,
                                mavlink.MAV_PARAM_TYPE_REAL32)
        return self.recv("PARAM_VALUE", timeout_s, lambda m: m.param_id == name)

    def close(self) -> None:
        self.conn.close()


def fly(gcs: Gcs, duration_s: float, command: Callable[[Any], tuple[int, list[float], tuple[float, float, float], float]],
        timeout_s: float = 30.0, extra_types: tuple[str, ...] = ()) -> list[Any]:
    """Close the loop in lockstep: answer every ATTITUDE with ``command(attitude)`` until ``duration_s`` of
    simulated time (from ``time_boot_ms``) has passed. ``command`` returns (type_mask, q, rates, thrust);
    returning None sends nothing (the vehicle's lockstep gate then waits out its timeout).
    Returns every ATTITUDE (and ``extra_types``) message received, in order."""
    got: list[Any] = []
    t_start_ms = None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = gcs.conn.recv_match(type=["ATTITUDE", *extra_types], blocking=True, timeout=1.0)
        if msg is None:
            continue
        got.append(msg)
        if msg.get_type() != "ATTITUDE":
            continue
        if t_start_ms is None:
            t_start_ms = msg.time_boot_ms
        out = command(msg)
        if out is not None:
            mask, q, rates, thrust = out
            gcs.mav.set_attitude_target_send(msg.time_boot_ms, VEHICLE_SYSID, VEHICLE_COMPID, mask, q,
                                             rates[0], rates[1], rates[2], thrust)
        if msg.time_boot_ms - t_start_ms >= duration_s * 1000.0:
            return got
    raise AssertionError(f"lockstep flight of {duration_s} s simulated did not finish in {timeout_s} s wall")


def rates_command(p: float = 0.0, q: float = 0.0, r: float = 0.0, thrust: float = 0.5):
    """A ``fly`` command: body rates [rad/s, FRD] + thrust with type_mask 0x80 (ArduCopter 4.2+ rate mode)."""
    return lambda att: (0x80, [1.0, 0.0, 0.0, 0.0], (p, q, r), thrust)


def wrap_pi(angle_rad: float) -> float:
    from mavastsm.frames import wrap_angle_float  # the package's one wrap

    return wrap_angle_float(angle_rad)




def guided_and_armed(gcs: Gcs) -> None:
    """Switch to GUIDED (4) and arm, asserting both ACKs are ACCEPTED."""
    ack = gcs.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)
    assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
    ack = gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED, ack
