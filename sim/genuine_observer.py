"""A genuine SITL as the tests and the benchmarks use it (one harness for both; benchmarks never import tests): booted until armable (``boot_arducopter``,
``boot_px4``), with a ground-station-side observer on its own MAVLink link (inside the SITL's namespace),
whose reader thread keeps every ATTITUDE, altitude, HEARTBEAT and text, plus a few GCS actions (set a
parameter, switch mode). The observer judges what the *vehicle* did, independent of the bridge."""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass, field

from pymavlink import mavutil

from .genuine_sitl import start_arducopter, start_arducopter_on_solo_physics, start_px4, wait_for

PREARM_BIT = mavutil.mavlink.MAV_SYS_STATUS_PREARM_CHECK


@dataclass
class Track:
    """What the observer saw, host-monotonic stamped: (t, roll, pitch, yaw) [rad], (t, alt above home) [m]."""

    attitude: list = field(default_factory=list)
    altitude: list = field(default_factory=list)
    modes: list = field(default_factory=list)  # (t, mode, armed)
    texts: list = field(default_factory=list)  # (t, text)
    params: dict = field(default_factory=dict)  # name -> the last PARAM_VALUE's value
    prearm_ok: bool = False
    heartbeat: object = None


class Observer:
    def __init__(self, sitl, url: str | None = None, source_system: int = 250) -> None:
        self.sitl = sitl
        self.track = Track()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        if "MAVLINK20" not in os.environ or mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # MAVLink 2 from the first
            os.environ["MAVLINK20"] = "1"  # byte, chosen where the connection is opened (as the bridge's link does)
            mavutil.set_dialect(mavutil.current_dialect)
        self.conn = sitl.netns.call(lambda: mavutil.mavlink_connection(url or sitl.observer_url, source_system=source_system))

        self._thread = threading.Thread(target=self._read, name="observer", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        c = self.conn
        next_heartbeat = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_heartbeat:  # 1 Hz, as a ground station: our sim forgets peers silent for 10 s
                next_heartbeat = time.monotonic() + 1.0
                c.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
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
                elif k == "PARAM_VALUE":
                    self.track.params[m.param_id] = m.param_value

    def _greet(self) -> bool:
        """A ground station's HEARTBEAT (a vehicle that answers only peers it has heard, like our sim, then talks
        to us; one sent before it listens is lost, so this repeats while waiting). True once the vehicle is heard."""
        if self.track.heartbeat is None:
            self.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        return self.track.heartbeat is not None

    def wait_heartbeat(self, timeout_s: float = 60.0) -> None:
        wait_for(self._greet, timeout_s, "observer: autopilot HEARTBEAT", self.sitl, poll_s=0.2)
        hb = self.track.heartbeat
        self.target = (hb.get_srcSystem(), 1)

    def request_streams(self, rates_hz: dict[int, float]) -> None:
        for msg_id, hz in rates_hz.items():
            self.conn.mav.command_long_send(*self.target, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0)

    def set_param(self, name: str, value: float, timeout_s: float = 20.0) -> None:
        """PARAM_SET, sent again every half second until the vehicle echoes the value (a lost datagram once could
        leave SIM_SPEEDUP at 5 for a whole module, and nothing said so); TimeoutError names the parameter."""
        with self._lock:
            self.track.params.pop(name, None)

        def echoed() -> bool:
            with self._lock:
                got = self.track.params.get(name)
            if got is not None and abs(got - value) <= 1e-6 * max(1.0, abs(value)):
                return True
            self.conn.mav.param_set_send(*self.target, name.encode(), float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            return False

        wait_for(echoed, timeout_s, f"{name} = {value:g} echoed by the vehicle", self.sitl, poll_s=0.5)

    def set_mode(self, name: str) -> None:
        """pymavlink's set_mode picks PX4's or ArduPilot's mode table from the last HEARTBEAT on the connection, from
        whoever sent it; PX4 forwards the bridge's own HEARTBEAT (autopilot INVALID), and the ArduPilot table has no
        "LAND" for it (a teardown once died with struct.error). The vehicle's own HEARTBEAT decides here."""
        hb = self.track.heartbeat
        if hb is not None and hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4:
            self.conn.set_mode_px4(name, 0, 0)
        else:
            self.conn.set_mode_apm(name)

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

    def last_seen(self, n_texts: int = 15) -> str:
        """What the vehicle said and did lately (for a timeout's message): modes, altitude, attitude, STATUSTEXTs."""
        with self._lock:
            modes = self.track.modes[-4:]
            alt = self.track.altitude[-1] if self.track.altitude else None
            att = self.track.attitude[-1] if self.track.attitude else None
            texts = self.track.texts[-n_texts:]
        now = time.monotonic()
        lines = ["observer, last seen: modes " + ", ".join(f"{m}{' armed' if a else ''} ({t - now:+.1f} s)" for t, m, a in modes)]
        if alt is not None:
            lines.append(f"altitude {alt[1]:.2f} m ({alt[0] - now:+.1f} s)")
        if att is not None:
            lines.append("attitude roll/pitch/yaw " + " / ".join(f"{math.degrees(v):.1f}" for v in att[1:]) + f" deg ({att[0] - now:+.1f} s)")
        lines += [f"STATUSTEXT ({t - now:+.1f} s): {x}" for t, x in texts]
        return "\n".join(lines)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        try:
            self.conn.close()
        except Exception:
            pass


OBSERVER_STREAMS = {30: 50.0, 33: 10.0, 1: 2.0}  # ATTITUDE, GLOBAL_POSITION_INT, SYS_STATUS


class Vehicle:
    """One genuine SITL + a ground-station observer (its own link), for one test module or test."""

    def __init__(self, sitl, observer: Observer) -> None:
        self.sitl = sitl
        self.observer = observer
        self.bridges: list = []  # bridge_process.BridgeProcess

    def bridge(self, args: list[str]):
        """``mavastsm ARGS`` in this vehicle's namespace (bridge_process.BridgeProcess), killed by ``after_test``."""
        from bridge_process import BridgeProcess

        b = BridgeProcess(self.sitl, args)
        self.bridges.append(b)
        return b

    def after_test(self) -> None:
        """Leave the vehicle as the next test expects it: no bridge, landed, disarmed."""
        for b in self.bridges:
            b.kill()
        self.bridges.clear()
        self.land_and_disarm()

    def wait_disarmed(self, timeout_s: float = 90.0) -> None:
        try:
            wait_for(lambda: self.observer.mode_now() is not None and not self.observer.mode_now()[1], timeout_s,
                     "vehicle disarmed", self.sitl)
        except TimeoutError as e:
            raise TimeoutError(f"{e}\n{self.observer.last_seen()}") from None

    def land_and_disarm(self) -> None:
        """Ground-station LAND (the bridge may have died) and wait for the disarm after touch-down."""
        if self.observer.mode_now() and self.observer.mode_now()[1]:
            self.observer.set_mode("LAND")
            self.wait_disarmed()

    def close(self) -> None:
        for b in self.bridges:
            b.kill()
        self.observer.close()
        self.sitl.stop()

    def __enter__(self) -> "Vehicle":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def boot_arducopter(build, *, fast_prearm: bool, extra_defaults=(), model: str = "quad") -> Vehicle:
    """Genuine ArduCopter from a cold start. ``fast_prearm``: SIM_SPEEDUP 5 until the pre-arm checks pass,
    then real time (the tests that are not about start-up do not wait 25 s of simulated sensor settling).
    ``extra_defaults``: parameter files loaded after copter.parm (what must hold from boot, e.g. BRD_OPTIONS);
    ``model``: SITL's built-in frame (``--model``: quad, hexa, octa, ...)."""
    sitl = start_arducopter(*build, speedup=5.0 if fast_prearm else 1.0, extra_defaults=list(extra_defaults), model=model)
    try:
        ob = Observer(sitl)
        ob.wait_heartbeat(90.0)
        ob.request_streams(OBSERVER_STREAMS)
        if fast_prearm:
            wait_for(lambda: ob.track.prearm_ok, 120.0, "ArduCopter pre-arm checks", sitl)
            ob.set_param("SIM_SPEEDUP", 1.0)
    except BaseException:
        sitl.stop()
        raise
    return Vehicle(sitl, ob)


def boot_arducopter_solo_physics(build, *, fast_prearm: bool, scenario=None, seed: int = 0, noise: bool = False,
                                 disturbance_start: str = "liftoff", attitude_history_s: float = 0.0) -> Vehicle:
    """Genuine ArduCopter tuned as a Solo (solo.parm) flying our Solo physics over the JSON SITL protocol
    (sim/json_physics.py), from a cold start, ready to arm; ``fast_prearm`` as :func:`boot_arducopter`. The physics
    server is ``vehicle.sitl.companions[0]`` (its ``counters`` say what it stepped and rejected); ``disturbance_start``
    and ``attitude_history_s`` as ``JsonPhysics`` ("held": the scenario's clock waits for the caller, e.g. the bridge's
    engagement)."""
    from .json_physics import JsonPhysics

    sitl = start_arducopter_on_solo_physics(*build, JsonPhysics(scenario=scenario, seed=seed, noise=noise,
                                                                                disturbance_start=disturbance_start,
                                                                                attitude_history_s=attitude_history_s),
                                            speedup=5.0 if fast_prearm else 1.0)
    try:
        ob = Observer(sitl)
        ob.wait_heartbeat(90.0)
        ob.request_streams(OBSERVER_STREAMS)
        wait_for(lambda: ob.track.prearm_ok, 150.0, "ArduCopter pre-arm checks on the Solo physics", sitl)
        if fast_prearm:
            ob.set_param("SIM_SPEEDUP", 1.0)
    except BaseException:
        sitl.stop()
        raise
    return Vehicle(sitl, ob)


def boot_px4(build, *, ready: bool = True) -> Vehicle:
    """Genuine PX4 SITL with SIH; ``ready``: wait until its estimator has an attitude and its health checks pass
    (about 35 s); False: return at once, cold (the observer's streams are asked for by ``observe_cold``)."""
    sitl = start_px4(*build)
    try:
        vehicle = Vehicle(sitl, Observer(sitl))
        if ready:
            wait_px4_ready(vehicle)
    except BaseException:
        sitl.stop()
        raise
    return vehicle


def wait_px4_ready(vehicle: Vehicle) -> None:
    """Ask for the observer's streams, then wait until PX4's estimator has an attitude and its health checks pass."""
    ob = vehicle.observer
    observe_cold(vehicle)
    wait_for(lambda: ob.track.prearm_ok and bool(ob.track.attitude), 150.0, "PX4 estimator and health checks", vehicle.sitl)


def boot_px4_solo_physics(build, *, ready: bool = False, scenario=None, seed: int = 0, speed: float = 1.0,
                          attitude_history_s: float = 0.0, disturbance_start: str = "liftoff", params=None) -> Vehicle:
    """Genuine PX4 tuned as a Solo (configs/px4/solo.params, or the file ``params``) flying our Solo physics over its
    simulator interface (sim/px4_hil.py); ``ready`` as :func:`boot_px4` (False: cold, ``observe_cold`` asks for the
    observer's streams).
    The simulator server is ``vehicle.sitl.companions[0]`` (its ``counters``; its ``physics`` keeps the true attitude)."""
    from .genuine_sitl import start_px4_on_solo_physics
    from .px4_hil import Px4HilPhysics

    physics = Px4HilPhysics(scenario=scenario, seed=seed, attitude_history_s=attitude_history_s, disturbance_start=disturbance_start)
    sitl = start_px4_on_solo_physics(*build, physics, speed=speed, params=params)
    try:
        vehicle = Vehicle(sitl, Observer(sitl))
        if ready:
            wait_px4_ready(vehicle)
        return vehicle
    except BaseException:
        sitl.stop()
        raise


def observe_cold(vehicle: Vehicle) -> None:
    """The observer's streams from a vehicle booted cold (after its first HEARTBEAT)."""
    vehicle.observer.wait_heartbeat(90.0)
    vehicle.observer.request_streams(OBSERVER_STREAMS)


def against_truth(samples, truth) -> list:
    """The samples with the attitude replaced by ``truth(vehicle time [s])`` (a quaternion [w, x, y, z], or None where
    unknown: that row is left out), for the metrics of the true attitude next to the autopilot's estimate."""
    import dataclasses

    from .attitude_math import q_to_euler

    out = []
    for s in samples:
        q = truth(s.vehicle_time_s)
        if q is not None:
            out.append(dataclasses.replace(s, euler_rad=tuple(q_to_euler(q))))
    return out
