"""A ground-station-side observer of a genuine SITL: its own MAVLink link (inside the SITL's namespace),
a reader thread that keeps every ATTITUDE, altitude, HEARTBEAT and text, and a few GCS actions
(set a parameter, switch mode). Used to judge what the *vehicle* did, independent of the bridge."""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

PREARM_BIT = mavutil.mavlink.MAV_SYS_STATUS_PREARM_CHECK


@dataclass
class Track:
    """What the observer saw, host-monotonic stamped: (t, roll, pitch, yaw) [rad], (t, alt above home) [m]."""

    attitude: list = field(default_factory=list)
    altitude: list = field(default_factory=list)
    modes: list = field(default_factory=list)  # (t, mode, armed)
    texts: list = field(default_factory=list)  # (t, text)
    prearm_ok: bool = False
    heartbeat: object = None


class Observer:
    def __init__(self, sitl, url: str | None = None, source_system: int = 250) -> None:
        self.sitl = sitl
        self.track = Track()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.conn = sitl.netns.call(lambda: mavutil.mavlink_connection(url or sitl.observer_url, source_system=source_system))
        # a ground station's HEARTBEAT first: a vehicle that answers only peers it has heard (our sim) then talks to us
        self.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self._thread = threading.Thread(target=self._read, name="observer", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        c = self.conn
        while not self._stop.is_set():
            try:
                m = c.recv_match(blocking=True, timeout=0.1)
            except Exception:
                continue
            if m is None or m.get_srcComponent() != 1:
                continue
            t = time.monotonic()
            k = m.get_type()
            with self._lock:
                if k == "ATTITUDE":
                    self.track.attitude.append((t, m.roll, m.pitch, m.yaw))
                elif k == "GLOBAL_POSITION_INT":
                    self.track.altitude.append((t, m.relative_alt / 1000.0))
                elif k == "HEARTBEAT" and m.type != mavutil.mavlink.MAV_TYPE_GCS and m.autopilot != 8:
                    armed = bool(m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                    mode = mavutil.mode_string_v10(m)
                    if not self.track.modes or self.track.modes[-1][1:] != (mode, armed):
                        self.track.modes.append((t, mode, armed))
                    self.track.heartbeat = m
                elif k == "SYS_STATUS":
                    self.track.prearm_ok = bool(m.onboard_control_sensors_health & PREARM_BIT)
                elif k == "STATUSTEXT":
                    self.track.texts.append((t, m.text))

    def wait_heartbeat(self, timeout_s: float = 60.0) -> None:
        from sim.genuine_sitl import wait_for
        wait_for(lambda: self.track.heartbeat is not None, timeout_s, "observer: autopilot HEARTBEAT", self.sitl)
        hb = self.track.heartbeat
        self.target = (hb.get_srcSystem(), 1)

    def request_streams(self, rates_hz: dict[int, float]) -> None:
        for msg_id, hz in rates_hz.items():
            self.conn.mav.command_long_send(*self.target, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0)

    def set_param(self, name: str, value: float) -> None:
        self.conn.mav.param_set_send(*self.target, name.encode(), float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32)

    def set_mode(self, name: str) -> None:
        self.conn.set_mode(name)

    # ------------------------------------------------------------------ judging
    def mode_now(self) -> tuple[str, bool] | None:
        with self._lock:
            return self.track.modes[-1][1:] if self.track.modes else None

    def altitude_now(self) -> float:
        with self._lock:
            return self.track.altitude[-1][1] if self.track.altitude else float("nan")

    def max_tilt_deg(self, t0: float, t1: float = math.inf) -> float:
        """Largest tilt angle acos(cos roll cos pitch) [deg] seen between host times t0 and t1."""
        with self._lock:
            xs = [math.degrees(math.acos(max(-1.0, min(1.0, math.cos(r) * math.cos(p))))) for t, r, p, _ in self.track.attitude if t0 <= t <= t1]
        return max(xs) if xs else float("nan")

    def min_altitude_m(self, t0: float, t1: float = math.inf) -> float:
        with self._lock:
            xs = [a for t, a in self.track.altitude if t0 <= t <= t1]
        return min(xs) if xs else float("nan")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        try:
            self.conn.close()
        except Exception:
            pass
