"""The Solo's physics for genuine PX4 SITL over PX4's simulator interface (``simulator_mavlink``, as jMAVSim and
Gazebo Classic use it; PX4 airframe 10016 ``none_iris`` with ``configs/px4/solo.params``).

What PX4 v1.15 does (src/modules/simulation/simulator_mavlink/SimulatorMavlink.cpp; ``px4-rc.simulator``):

- it connects as a TCP client to port 4560 + instance of this simulator (``simulator_mavlink start -c 4560``)
  and holds its start-up script until the first HIL_SENSOR has set its clock;
- HIL_SENSOR with ``id`` 0 drives PX4's clock (lockstep): PX4 sets CLOCK_MONOTONIC to its ``time_usec``, so
  PX4's ``time_boot_ms`` in ATTITUDE is this physics' time, and PX4 runs no faster or slower than we step;
- each HIL_SENSOR carries the field groups named in ``fields_updated``: accel [m/s^2, FRD specific force], gyro
  [rad/s, FRD], mag [gauss, FRD], baro (``abs_pressure`` [hPa], ``pressure_alt`` [m], ``temperature`` [degC]);
  ``id`` 0 is the accelerometer/gyro 1310988 and magnetometer 197388 that PX4's rcS calibrates (CAL_*_ID);
- HIL_GPS carries lat/lon [1e-7 deg], alt [mm AMSL], velocities [cm/s NED], eph/epv [cm];
- HIL_STATE_QUATERNION (requested by PX4 every 5 ms) becomes PX4's ground-truth topics, for its logs;
- after each sensor step PX4 answers with HIL_ACTUATOR_CONTROLS: ``controls[0..3]`` the motors in [0, 1], zeros
  while disarmed, in the order of CA_ROTOR0..3, which configs/px4/solo.params places as ArduPilot's quad X
  (front right CCW, back left CCW, front left CW, back right CW): the same order as ``mixer.QUAD_X_LAYOUT``.

EKF2 compares the magnetometer with the World Magnetic Model at the GPS position (strength, inclination) and takes
its declination from it, so the simulated field is PX4's own table (geo_magnetic_tables.hpp, WMM-2020) interpolated
as PX4 interpolates it at the home location, PX4's default SITL home (Zurich).

Sensor noise (``Px4SensorNoise``, seeded) is a 3DR Solo's class of sensors (Pixhawk 2: MPU-9250 IMU, MS5611
barometer, a u-blox GPS), not SIH's ten times larger IMU noise. Pure parts (the physics, the sensor messages)
are :class:`Px4HilPhysics`; :class:`Px4HilServer` owns the TCP socket and the lockstep loop.
"""

from __future__ import annotations

import logging
import math
import random
import socket
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2

from .attitude_math import q_rotate_inverse
from .json_physics import DISTURBANCE_STARTS, specific_force_frd
from .solo_plant import SoloPlant
from .vehicle_config import load_vehicle_config

LOG = logging.getLogger("mavastsm_sim.px4_hil")

PX4_SIMULATOR_PORT = 4560  # + PX4 instance
CATCH_UP_LIMIT_S = 0.02  # [s] behind the pace by more than this: the pace restarts (lockstep owes no wall time)
HIL_SENSOR_ALL_FIELDS = 0x1BFF  # accel, gyro, mag (0-8), abs pressure (9), pressure alt (11), temperature (12)
EARTH_RADIUS_M = 6371000.0
PX4_HOME = (47.397742, 8.545594, 488.0)  # PX4's default SITL home (lat, lon [deg], alt [m AMSL])
# PX4's WMM table corners around the home, (lat, lon) -> (declination, inclination [1e-4 rad], strength [1e-4 gauss])
WMM_CORNERS = {(40, 0): (218, 9581, 4513), (40, 10): (580, 9746, 4593), (50, 0): (157, 11387, 4860),
               (50, 10): (660, 11493, 4911)}


def px4_magnetic_field_ned_gauss(lat_deg: float = PX4_HOME[0], lon_deg: float = PX4_HOME[1]) -> tuple[float, float, float]:
    """Earth's field [gauss, NED] as PX4 expects it (geo_mag_declination.cpp: bilinear on the 10 deg WMM grid).

    N = F cos I cos D, E = F cos I sin D, D = F sin I. Only the grid cell around PX4_HOME is held here."""
    lat0, lon0 = math.floor(lat_deg / 10) * 10, math.floor(lon_deg / 10) * 10
    if (lat0, lon0) not in WMM_CORNERS:
        raise ValueError(f"no WMM table cell held for {lat_deg}, {lon_deg} (only the one around PX4's SITL home)")
    a, b = (lat_deg - lat0) / 10.0, (lon_deg - lon0) / 10.0

    def interp(k: int) -> float:
        sw, se = WMM_CORNERS[(lat0, lon0)][k], WMM_CORNERS[(lat0, lon0 + 10)][k]
        nw, ne = WMM_CORNERS[(lat0 + 10, lon0)][k], WMM_CORNERS[(lat0 + 10, lon0 + 10)][k]
        low, high = sw + b * (se - sw), nw + b * (ne - nw)
        return (low + a * (high - low)) * 1e-4

    dec, inc, strength = interp(0), interp(1), interp(2)
    return (strength * math.cos(inc) * math.cos(dec), strength * math.cos(inc) * math.sin(dec), strength * math.sin(inc))


def _int16(value: float) -> int:
    """``value`` rounded into MAVLink's int16 fields (velocities in cm/s, accelerations in mG): a ground impact's
    acceleration spike (the physics stops the vehicle within one 1 ms step) must not end the simulation."""
    return max(-32768, min(32767, int(round(value))))


def isa_pressure_hpa(alt_amsl_m: float) -> float:
    """International Standard Atmosphere pressure [hPa] at ``alt_amsl_m`` (troposphere)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


@dataclass(frozen=True)
class Px4SensorNoise:
    """White noise per sample (standard deviations) of a 3DR Solo's sensors at 250 Hz, and its GPS error.

    gyro_std_rads : MPU-9250 rate noise density 0.01 deg/s/sqrt(Hz) over 125 Hz -> 0.11 deg/s = 0.0020 rad/s
        (SIH: 0.14/0.07/0.03 rad/s, 15-70 times more)
    accel_std_ms2 : MPU-9250 300 ug/sqrt(Hz) over 125 Hz -> 3.4 mg = 0.033 m/s^2 (SIH: 0.5-1.7 m/s^2)
    mag_std_gauss : HMC5983/AK8963 class, about 0.5 uT = 0.005 gauss
    baro_std_hpa : MS5611 at OSR 4096, 0.012 mbar RMS (about 0.1 m)
    gps_std_m : (horizontal, vertical) [m] of a first-order Gauss-Markov position error with ``gps_tau_s``
        (a u-blox receiver's error wanders slowly; white noise at 10 Hz would look like a drifting fix to EKF2)
    gps_vel_std_ms : white velocity noise [m/s]
    """

    gyro_std_rads: float = 0.0020
    accel_std_ms2: float = 0.033
    mag_std_gauss: float = 0.005
    baro_std_hpa: float = 0.012
    gps_std_m: tuple[float, float] = (0.5, 0.8)
    gps_tau_s: float = 60.0
    gps_vel_std_ms: float = 0.05


NO_NOISE = Px4SensorNoise(0.0, 0.0, 0.0, 0.0, (0.0, 0.0), 60.0, 0.0)


@dataclass
class Px4HilCounters:
    """What the lockstep loop did (one field per event)."""

    steps: int = 0  # sensor steps sent (HIL_SENSOR)
    actuator_messages: int = 0  # HIL_ACTUATOR_CONTROLS received
    actuator_timeouts: int = 0  # steps where PX4 did not answer within the lockstep wait (stepped with the last controls)
    nonfinite_controls: int = 0  # actuator values that were not finite numbers (0 used)
    pace_resets: int = 0  # times the loop fell more than CATCH_UP_LIMIT_S behind its pace and restarted it from there

    def summary(self) -> str:
        return ", ".join(f"{k} {v}" for k, v in asdict(self).items())


class Px4HilPhysics:
    """The Solo plant stepped by PX4's actuator outputs, its sensors as PX4's HIL messages (no I/O).

    Parameters
    ----------
    vehicle_config, scenario, seed : as ``mavastsm sim``; noise : False = exact sensors (tests of the interface)
    sensor_rate_hz : HIL_SENSOR rate [Hz] (PX4's SITL integrates its IMU at 250 Hz, IMU_INTEG_RATE)
    physics_substeps : physics steps per sensor step (4: 1 kHz, as ``mavastsm sim``)
    disturbance_start, attitude_history_s : as ``json_physics.JsonPhysics``; the history is (time [s], true
        attitude quaternion) with the time PX4 reports (``time_boot_ms`` / 1000)
    """

    def __init__(self, vehicle_config: str | Path | None = None, scenario=None, seed: int = 0, noise: bool = True,
                 sensor_rate_hz: int = 250, physics_substeps: int = 4, disturbance_start: str = "liftoff",
                 attitude_history_s: float = 0.0, sensor_noise: Px4SensorNoise = Px4SensorNoise()) -> None:
        if disturbance_start not in DISTURBANCE_STARTS:
            raise ValueError(f"disturbance_start must be one of {DISTURBANCE_STARTS}, got {disturbance_start!r}")
        self.config = load_vehicle_config(vehicle_config)
        self.plant = SoloPlant(self.config, scenario, physics_rate_hz=sensor_rate_hz * physics_substeps)
        self.noise = sensor_noise if noise else NO_NOISE
        self.sensor_rate_hz = int(sensor_rate_hz)
        self.substeps = int(physics_substeps)
        self.step_us = 1_000_000 // self.sensor_rate_hz
        self.time_us = self.step_us  # PX4's clock starts here (its time_boot_ms is time_us / 1000)
        self.disturbance_start = disturbance_start
        self.attitude_history: deque | None = deque(maxlen=int(attitude_history_s * sensor_rate_hz)) if attitude_history_s > 0 else None
        self._rng = random.Random(seed)
        self._gps_error = [0.0, 0.0, 0.0]
        self._airborne_once = False
        self.mag_ned_gauss = px4_magnetic_field_ned_gauss()
        self.controls = [0.0] * 4
        self.plant.disturbances.restart_clock(0.0) if disturbance_start == "boot" else self.plant.disturbances.park()

    @property
    def time_s(self) -> float:
        return self.time_us * 1e-6

    def set_controls(self, controls) -> int:
        """PX4's motor outputs (HIL_ACTUATOR_CONTROLS controls[0..3], [0, 1]) held until the next; returns how many
        were not finite (replaced by 0)."""
        bad = 0
        out = []
        for c in list(controls)[:4]:
            c = float(c)
            if not math.isfinite(c):
                bad, c = bad + 1, 0.0
            out.append(min(max(c, 0.0), 1.0))
        self.controls = out
        return bad

    def step(self) -> None:
        """One sensor period of physics with the held motor outputs."""
        plant, h = self.plant, 1.0 / (self.sensor_rate_hz * self.substeps)
        t = self.time_s
        for i in range(self.substeps):
            plant.step(self.controls, t + i * h, h)
        self.time_us += self.step_us
        if not self._airborne_once and not plant.in_ground_contact:
            self._airborne_once = True
            if self.disturbance_start == "liftoff":
                plant.disturbances.restart_clock(self.time_s)
        if self.attitude_history is not None:
            self.attitude_history.append((self.time_s, tuple(plant.x[6:10])))
        self._step_gps_error()

    def _step_gps_error(self) -> None:
        """First-order Gauss-Markov GPS position error (Px4SensorNoise.gps_std_m, gps_tau_s), advanced one sensor period."""
        n = self.noise
        phi = math.exp(-1.0 / (self.sensor_rate_hz * n.gps_tau_s))
        drive = math.sqrt(1.0 - phi * phi)
        for i, std in enumerate((n.gps_std_m[0], n.gps_std_m[0], n.gps_std_m[1])):
            self._gps_error[i] = phi * self._gps_error[i] + (self._rng.gauss(0.0, std * drive) if std > 0 else 0.0)

    # ------------------------------------------------------------------ sensors as PX4's HIL messages
    def _g(self, std: float) -> float:
        return self._rng.gauss(0.0, std) if std > 0.0 else 0.0

    def hil_sensor(self):
        """HIL_SENSOR (id 0, every field group) for the current true state plus seeded noise."""
        x, n, g = self.plant.x, self.noise, self._g
        q = (x[6], x[7], x[8], x[9])
        ax, ay, az = specific_force_frd(q, self.plant.accel_ned_ms2, self.plant.body.gravity_ms2)
        mx, my, mz = q_rotate_inverse(q, *self.mag_ned_gauss)
        alt = PX4_HOME[2] - x[2]
        return mavlink2.MAVLink_hil_sensor_message(
            self.time_us, ax + g(n.accel_std_ms2), ay + g(n.accel_std_ms2), az + g(n.accel_std_ms2),
            x[10] + g(n.gyro_std_rads), x[11] + g(n.gyro_std_rads), x[12] + g(n.gyro_std_rads),
            mx + g(n.mag_std_gauss), my + g(n.mag_std_gauss), mz + g(n.mag_std_gauss),
            isa_pressure_hpa(alt) + g(n.baro_std_hpa), 0.0, alt, 15.0 - 0.0065 * alt, HIL_SENSOR_ALL_FIELDS, 0)

    def _geodetic(self, north_m: float, east_m: float) -> tuple[float, float]:
        lat0 = math.radians(PX4_HOME[0])
        return (PX4_HOME[0] + math.degrees(north_m / EARTH_RADIUS_M),
                PX4_HOME[1] + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(lat0))))

    def hil_gps(self):
        """HIL_GPS: a 3D fix at the true position plus the Gauss-Markov error, velocity plus white noise."""
        x, n, e = self.plant.x, self.noise, self._gps_error
        lat, lon = self._geodetic(x[0] + e[0], x[1] + e[1])
        vn, ve, vd = (x[3] + self._g(n.gps_vel_std_ms), x[4] + self._g(n.gps_vel_std_ms), x[5] + self._g(n.gps_vel_std_ms))
        return mavlink2.MAVLink_hil_gps_message(
            self.time_us, 3, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round((PX4_HOME[2] - x[2] - e[2]) * 1000)),
            100, 150, min(int(round(math.hypot(vn, ve) * 100)), 65534), _int16(vn * 100), _int16(ve * 100), _int16(vd * 100),
            65535, 12, 0, 0)

    def hil_state_quaternion(self):
        """HIL_STATE_QUATERNION: the true state (PX4 publishes it as its ground-truth topics, for its logs)."""
        x = self.plant.x
        lat, lon = self._geodetic(x[0], x[1])
        a = self.plant.accel_ned_ms2
        return mavlink2.MAVLink_hil_state_quaternion_message(
            self.time_us, [x[6], x[7], x[8], x[9]], x[10], x[11], x[12], int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round((PX4_HOME[2] - x[2]) * 1000)), _int16(x[3] * 100), _int16(x[4] * 100), _int16(x[5] * 100),
            0, 0, _int16(a[0] / 9.81 * 1000), _int16(a[1] / 9.81 * 1000), _int16(a[2] / 9.81 * 1000))

    def true_attitude_at(self, t_s: float):
        """The true attitude quaternion [w, x, y, z] at physics time ``t_s`` [s] (the nearest kept sample), or None."""
        hist = self.attitude_history
        if not hist or t_s < hist[0][0] - 0.5 / self.sensor_rate_hz or t_s > hist[-1][0] + 0.5 / self.sensor_rate_hz:
            return None
        i = min(max(int(round((t_s - hist[0][0]) * self.sensor_rate_hz)), 0), len(hist) - 1)
        return hist[i][1]


class Px4HilServer:
    """:class:`Px4HilPhysics` as PX4's simulator: a TCP server on 127.0.0.1:4560 that PX4 connects to, and the lockstep loop.

    Each loop: send HIL_SENSOR (plus HIL_GPS at ``gps_rate_hz`` and HIL_STATE_QUATERNION at ``truth_rate_hz``); once
    PX4 has answered at least once, wait (at most ``lockstep_timeout_s`` of wall time, counted when it runs out) for
    its HIL_ACTUATOR_CONTROLS; step the physics with the newest controls. ``speed``: simulated seconds per wall
    second (1 = real time), or 0 for as fast as PX4 answers. ``open()`` binds (inside PX4's network namespace),
    ``start()`` runs the loop on a thread, ``stop()`` ends it. Held up (a loaded machine), the loop does not
    catch up in a burst, which would hand PX4's ATTITUDE to the bridge in bursts too: lockstep owes no wall time, so
    the pace restarts from where it is.
    """

    def __init__(self, physics: Px4HilPhysics, host: str = "127.0.0.1", port: int = PX4_SIMULATOR_PORT, speed: float = 1.0,
                 gps_rate_hz: float = 10.0, truth_rate_hz: float = 50.0, lockstep_timeout_s: float = 0.5) -> None:
        self.physics = physics
        self.host, self.port = host, port
        self.speed = float(speed)
        self.counters = Px4HilCounters()
        self.gps_every = max(1, round(physics.sensor_rate_hz / gps_rate_hz))
        self.truth_every = max(1, round(physics.sensor_rate_hz / truth_rate_hz))
        self.lockstep_timeout_s = lockstep_timeout_s
        self.listener: socket.socket | None = None
        self.error: BaseException | None = None
        self.closed_by_px4 = ""  # why PX4's side of the connection ended, when it did
        self.connected = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=51)
        self._mav.robust_parsing = True

    def open(self) -> "Px4HilServer":
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((self.host, self.port))
            s.listen(1)
        except OSError:
            s.close()
            raise
        s.settimeout(0.2)
        self.listener = s
        return self

    def start(self) -> "Px4HilServer":
        if self.listener is None:
            self.open()
        self._thread = threading.Thread(target=self._run, name="px4-hil", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(3.0)
        if self.listener is not None:
            self.listener.close()

    def _accept(self) -> socket.socket | None:
        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except socket.timeout:
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.connected.set()
            return conn
        return None

    def _send(self, conn: socket.socket, msg) -> None:
        conn.sendall(msg.pack(self._mav))

    def _receive(self, conn: socket.socket, wait_s: float) -> bool:
        """Read what PX4 sent, waiting up to ``wait_s`` for a HIL_ACTUATOR_CONTROLS; the newest one's motor values are
        held. True when one came."""
        got = False
        conn.settimeout(wait_s if wait_s > 0 else 0.0)
        while True:
            try:
                data = conn.recv(65536)
            except (socket.timeout, BlockingIOError):
                return got
            if not data:
                raise ConnectionError("PX4 closed the simulator connection")
            for m in self._mav.parse_buffer(data) or ():
                if m.get_type() == "HIL_ACTUATOR_CONTROLS":
                    got = True
                    self.counters.actuator_messages += 1
                    self.counters.nonfinite_controls += self.physics.set_controls(m.controls[:4])
            if got:
                conn.settimeout(0.0)  # take whatever else is already there, then step

    def _run(self) -> None:
        try:
            conn = self._accept()
            if conn is None:
                return
            with conn:
                self._loop(conn)
        except ConnectionError as exc:  # PX4 stopped (killed with its instance, or it exited): the session is over
            self.closed_by_px4 = str(exc)
        except BaseException as exc:  # reported by the owner (command or test), never silently lost
            if not self._stop.is_set():
                self.error = exc
                LOG.error("PX4 simulator loop failed: %r", exc)

    def _loop(self, conn: socket.socket) -> None:
        p, c = self.physics, self.counters
        wall0, sim0 = time.monotonic(), p.time_s
        answered = False
        while not self._stop.is_set():
            self._send(conn, p.hil_sensor())
            if c.steps % self.gps_every == 0:
                self._send(conn, p.hil_gps())
            if c.steps % self.truth_every == 0:
                self._send(conn, p.hil_state_quaternion())
            c.steps += 1
            if answered:
                if not self._receive(conn, self.lockstep_timeout_s):
                    c.actuator_timeouts += 1
            else:
                answered = self._receive(conn, 0.0)
            p.step()
            speed = self.speed if answered or self.speed > 0 else 1.0  # real time until PX4 runs its loop
            if speed > 0:
                ahead = (p.time_s - sim0) / speed - (time.monotonic() - wall0)
                if ahead > 0:
                    time.sleep(ahead)
                elif ahead < -CATCH_UP_LIMIT_S:  # held up (a loaded machine): resume the pace from here, no burst
                    wall0, sim0 = time.monotonic(), p.time_s
                    c.pace_resets += 1
