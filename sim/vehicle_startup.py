"""ArduCopter's start-up as the simulated vehicle shows it on the wire (the profile's ``prearm_delay_s``).

Texts at the measured moments, the pre-arm reasons given until the delay has passed, the 30 s "PreArm:" reminder,
and HOME_POSITION / GPS_GLOBAL_ORIGIN when the EKF origin is set (docs/sim.md, "Wire parity").
"""

from __future__ import annotations

import math
from typing import Any, Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .vehicle_link import VehicleLink

PREARM_REPORT_INTERVAL_US = 30_000_000  # ArduPilot repeats failing pre-arm checks as "PreArm:" texts every 30 s
# Start-up of genuine ArduCopter 4.7 SITL, measured (docs/sim.md, "Wire parity"), as fractions of the pre-arm delay
# (25 s nominal there): "ArduPilot Ready" 2.45 s, EKF3 initialised 4.46 s, tilt and yaw aligned 5.8-5.9 s, EKF origin
# and home set 20.0 s; the gyros agree and the EKF uses GPS by the end of the delay.
BOOTED_FRACTION = 0.1
ORIGIN_SET_FRACTION = 0.8
STARTUP_TEXTS = (
    (BOOTED_FRACTION, ("ArduPilot Ready", "AHRS: DCM active")),
    (0.18, ("EKF3 IMU0 initialised", "EKF3 IMU1 initialised", "AHRS: EKF3 active")),
    (0.23, ("EKF3 IMU0 tilt alignment complete", "EKF3 IMU1 tilt alignment complete",
            "EKF3 IMU0 MAG0 initial yaw alignment complete", "EKF3 IMU1 MAG0 initial yaw alignment complete")),
    (ORIGIN_SET_FRACTION, ("EKF3 IMU0 origin set", "Field Elevation Set: {home_alt_m:.0f}m", "EKF3 IMU1 origin set")),
    (1.0, ("EKF3 IMU0 is using GPS", "EKF3 IMU1 is using GPS")),
)
POSITION_MODES = frozenset({3, 4, 5, 6, 7})  # AUTO, GUIDED, LOITER, RTL, CIRCLE: Mode::requires_GPS() (emulated set)


class StartupSequence:
    """Where the emulated ArduCopter is in its start-up, and what it says on the way.

    Parameters
    ----------
    link : VehicleLink
        Clock (``now_us``), parameters and the STATUSTEXT queue.
    home_alt_m : float
        Home altitude AMSL [m], named in "Field Elevation Set".
    on_origin_set : callable()
        Sends what is queued, then HOME_POSITION and GPS_GLOBAL_ORIGIN (the moment the EKF origin is set).
    """

    def __init__(self, link: VehicleLink, home_alt_m: float, on_origin_set: Callable[[], None]) -> None:
        self.link = link
        self.profile = link.profile
        self.copter: Any = link.copter
        self.home_alt_m = home_alt_m
        self._on_origin_set = on_origin_set
        self._texts_sent = 0
        self._next_prearm_report_us = PREARM_REPORT_INTERVAL_US

    def fraction(self) -> float:
        """How far through ``prearm_delay_s`` the vehicle is [-] (inf without a delay)."""
        delay_s = self.profile.prearm_delay_s
        return math.inf if delay_s <= 0 else self.link.now_us * 1e-6 / delay_s

    def booting(self) -> bool:
        """True before "ArduPilot Ready" (only with a pre-arm delay): HEARTBEAT says MAV_STATE_BOOT."""
        return self.fraction() < BOOTED_FRACTION

    def failures(self) -> list[str]:
        """Pre-arm reasons ArduCopter gives while it starts up (without the "PreArm: " / "Arm: " prefix); empty once
        ``prearm_delay_s`` has passed, with ARMING_CHECK 0, or without a pre-arm delay. As measured on 4.7 SITL:
        the gyros disagree and the AHRS waits for home until the EKF origin is set, then a mode that needs a position
        waits for the EKF to use GPS."""
        fraction = self.fraction()
        if fraction >= 1.0 or self.link.param("ARMING_CHECK", 1.0) == 0.0:
            return []
        reasons = ["Gyros inconsistent"]
        if fraction < ORIGIN_SET_FRACTION:
            reasons.append("AHRS: waiting for home")
        elif int(self.copter.mode_number) in POSITION_MODES:
            reasons.append("Need Position Estimate")
        return reasons

    def run(self, now_us: int) -> None:
        """Start-up texts and events due by ``now_us`` (only with a pre-arm delay), and the 30 s "PreArm:" reminder."""
        if self.profile.prearm_delay_s <= 0:
            return
        fraction = self.fraction()
        while self._texts_sent < len(STARTUP_TEXTS) and fraction >= STARTUP_TEXTS[self._texts_sent][0]:
            at_fraction, texts = STARTUP_TEXTS[self._texts_sent]
            self._texts_sent += 1
            if at_fraction >= ORIGIN_SET_FRACTION and not self.profile.position_estimate:
                continue  # no GPS: no origin, no home, the EKF never uses GPS
            for text in texts:
                self.link.pending_texts.append((mavlink.MAV_SEVERITY_INFO, text.format(home_alt_m=self.home_alt_m)))
            if at_fraction == ORIGIN_SET_FRACTION:
                self._on_origin_set()
        if fraction < 1.0 and now_us >= self._next_prearm_report_us:
            self._next_prearm_report_us += PREARM_REPORT_INTERVAL_US
            if not self.copter.armed:
                for reason in self.failures():
                    self.link.pending_texts.append((mavlink.MAV_SEVERITY_CRITICAL, f"PreArm: {reason}"))
