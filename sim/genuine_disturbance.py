"""Rotational disturbances on genuine ArduCopter SITL's own physics, and how far they turned the vehicle.

ArduPilot SITL adds ``SIM_TWIST_X/Y/Z`` [rad/s^2, body] to the airframe's angular acceleration for
``SIM_TWIST_TIME`` [ms] from the moment that parameter is set non-zero, then clears it (SIM_Aircraft.cpp,
``add_twist_forces``): a torque pulse of known size and length that no controller is told about. ``twist`` applies
one; ``deviation`` measures, from the observer's ATTITUDE track (host-monotonic stamped), the peak excursion and the
time back inside a band after the pulse's end; ``fly_alone`` is ArduCopter's own attitude controller holding level
through SET_ATTITUDE_TARGET attitude targets (type_mask 0x07), the floor the bridge is judged against. The harness
of tests and benchmarks alike (benchmarks never import tests)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from pymavlink import mavutil

from .genuine_sitl import wait_for

AXES = ("roll", "pitch", "yaw")
TWIST_PARAM = {"roll": "SIM_TWIST_X", "pitch": "SIM_TWIST_Y", "yaw": "SIM_TWIST_Z"}
BAND_DEG = 0.5  # "back within 0.5 deg" of the disturbance bounds
BASELINE_S = 1.0  # the attitude held before a pulse: the mean over this long before it


@dataclass(frozen=True)
class Pulse:
    """One SIM_TWIST pulse: ``accel_radss`` [rad/s^2, body FRD] about ``axis`` for ``duration_s`` [s], sent at host
    time ``t_start`` [s, monotonic]."""

    axis: str
    accel_radss: float
    duration_s: float
    t_start: float = float("nan")

    @property
    def t_end(self) -> float:
        return self.t_start + self.duration_s


def twist(observer, axis: str, accel_radss: float, duration_s: float) -> Pulse:
    """Apply one pulse through the observer's link: the acceleration first (echo awaited), then SIM_TWIST_TIME, sent
    once (a resend after the pulse ended would start a second one) and its echo awaited. Returns the pulse, stamped
    with the host time SIM_TWIST_TIME was sent."""
    for other in AXES:
        observer.set_param(TWIST_PARAM[other], accel_radss if other == axis else 0.0)
    ob = observer
    with ob._lock:
        ob.track.params.pop("SIM_TWIST_TIME", None)
    t0 = time.monotonic()
    ob.conn.mav.param_set_send(*ob.target, b"SIM_TWIST_TIME", float(round(duration_s * 1000.0)), mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
    wait_for(lambda: ob.track.params.get("SIM_TWIST_TIME") is not None, 2.0, "SIM_TWIST_TIME echoed", ob.sitl)
    return Pulse(axis, accel_radss, duration_s, t0)


def _wrap_deg(x: float) -> float:
    return math.degrees(math.remainder(x, 2.0 * math.pi))


def deviation(observer, pulse: Pulse, after_s: float = 4.0, band_deg: float = BAND_DEG) -> dict:
    """What the pulse did to its axis, from the observer's track: ``peak_deg`` the largest |angle - baseline| from the
    pulse's start to ``after_s`` past its end (baseline: the mean over BASELINE_S before the start), ``back_s`` the time
    from the pulse's end until the angle is back inside +-``band_deg`` for good within that window (0 if it never left
    after the end; NaN if it is still outside at the window's end) and ``other_peak_deg`` the other axes' peaks."""
    i = AXES.index(pulse.axis)
    with observer._lock:
        att = list(observer.track.attitude)
    before = [a for a in att if pulse.t_start - BASELINE_S <= a[0] < pulse.t_start]
    window = [a for a in att if pulse.t_start <= a[0] <= pulse.t_end + after_s]
    if not before or not window:
        raise ValueError(f"no ATTITUDE around the {pulse.axis} pulse at {pulse.t_start:.1f} s")
    base = [math.atan2(sum(math.sin(a[1 + k]) for a in before), sum(math.cos(a[1 + k]) for a in before)) for k in range(3)]
    err = [(a[0], [_wrap_deg(a[1 + k] - base[k]) for k in range(3)]) for a in window]
    outside = [t for t, e in err if t >= pulse.t_end and abs(e[i]) > band_deg]
    if not outside:
        back = 0.0
    elif err[-1][0] - outside[-1] < 0.5:  # still outside (or only just back) at the window's end
        back = float("nan")
    else:
        back = outside[-1] - pulse.t_end
    return {"axis": pulse.axis, "accel_radss": pulse.accel_radss, "duration_s": pulse.duration_s,
            "peak_deg": round(max(abs(e[i]) for _, e in err), 2), "back_s": round(back, 2),
            "other_peak_deg": {AXES[k]: round(max(abs(e[k]) for _, e in err), 2) for k in range(3) if k != i}}


def _quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr, cp, sp, cy, sy = (f(0.5 * x) for x in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]


GUIDED_NOGPS = 20
LAND = 9


def fly_alone(vehicle, pulses, takeoff_m: float = 2.0, settle_s: float = 4.0, gap_s: float = 5.0,
              climb_thrust: float = 0.75, rate_hz: float = 50.0, timeout_s: float = 120.0) -> list[dict]:
    """ArduCopter alone: a peer on the bridge's link (the bridge must not run) arms in GUIDED_NOGPS, climbs at
    ``climb_thrust`` to ``takeoff_m`` [m], then holds level at the heading it had there (SET_ATTITUDE_TARGET 0x07,
    thrust 0.5 = hold altitude, at ``rate_hz``) while each (axis, accel_radss, duration_s) of ``pulses`` is applied
    ``settle_s`` and then ``gap_s`` apart; then LAND, and the disarm awaited. Returns ``deviation`` per pulse."""
    m = mavutil.mavlink
    ob = vehicle.observer
    conn = vehicle.sitl.netns.call(lambda: mavutil.mavlink_connection(vehicle.sitl.bridge_url, source_system=246))
    results = []
    try:
        if conn.wait_heartbeat(timeout=30) is None:
            raise TimeoutError("ArduCopter alone: no HEARTBEAT on the bridge link")
        tgt = (conn.target_system, 1)
        conn.mav.command_long_send(*tgt, m.MAV_CMD_SET_MESSAGE_INTERVAL, 0, m.MAVLINK_MSG_ID_ATTITUDE, 1e6 / rate_hz, 0, 0, 0, 0, 0)
        deadline = time.monotonic() + timeout_s
        yaw0, next_arm, climbing = None, 0.0, True
        while time.monotonic() < deadline:  # arm and climb
            msg = conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.5)
            if msg is None:
                continue
            mode = ob.mode_now()
            armed = mode is not None and mode[1] and mode[0] == "GUIDED_NOGPS"
            if not armed and time.monotonic() >= next_arm:
                next_arm = time.monotonic() + 1.0
                conn.mav.command_long_send(*tgt, m.MAV_CMD_DO_SET_MODE, 0, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED_NOGPS, 0, 0, 0, 0, 0)
                conn.mav.command_long_send(*tgt, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            yaw0 = msg.yaw if yaw0 is None or not armed else yaw0
            climbing = climbing and not (armed and ob.altitude_now() >= takeoff_m - 0.05)
            conn.mav.set_attitude_target_send(msg.time_boot_ms, *tgt, 0x07, _quaternion(0.0, 0.0, yaw0), 0, 0, 0,
                                              climb_thrust if armed and climbing else 0.5)
            if armed and not climbing:
                break
        else:
            raise TimeoutError(f"ArduCopter alone: not armed and at {takeoff_m:g} m within {timeout_s:g} s\n{ob.last_seen()}")
        q = _quaternion(0.0, 0.0, yaw0)

        def hold(seconds: float, then=None):
            end = time.monotonic() + seconds
            sent = None
            while time.monotonic() < end:
                conn.mav.set_attitude_target_send(0, *tgt, 0x07, q, 0, 0, 0, 0.5)
                if then is not None and sent is None:
                    sent = then()
                time.sleep(1.0 / rate_hz)
            return sent

        hold(settle_s)
        for axis, accel, dur in pulses:
            p = hold(dur + gap_s, lambda a=axis, x=accel, d=dur: twist(ob, a, x, d))
            results.append(deviation(ob, p, after_s=gap_s))
        conn.mav.command_long_send(*tgt, m.MAV_CMD_DO_SET_MODE, 0, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LAND, 0, 0, 0, 0, 0)
        vehicle.wait_disarmed(90.0)
    finally:
        conn.close()
    return results
