"""Hand-made telemetry for dashboard tests: deterministic signals with known values."""

from __future__ import annotations

import io
import math

import pytest
from rich.console import Console

from mavastsm.state_types import FailsafeReason
from mavastsm.telemetry import ControlSample, LinkStatus, SessionInfo, TelemetryBuffer, TelemetrySnapshot

DEG = math.pi / 180.0


def make_sample(t_s: float, failsafe: FailsafeReason | None = None, alpha=(0.01, 0.02, 0.01),
                sigma=(0.004, -0.006, 0.002), u_nm=(0.0123, -0.0456, 0.00789)) -> ControlSample:
    """One cycle with round numbers: reference 10 deg roll, angle 9.5 deg -> error -0.5 deg."""
    return ControlSample(
        vehicle_time_s=t_s,
        reference_rad=(10 * DEG, -5 * DEG, 90 * DEG),
        euler_rad=(9.5 * DEG, -4.75 * DEG, 89.0 * DEG),
        euler_rate_rads=(12.5 * DEG, -3.25 * DEG, 0.5 * DEG),
        error_rad=(-0.5 * DEG, 0.25 * DEG, -1.0 * DEG),
        sigma=sigma,
        alpha=alpha,
        beta=(0.012, 0.024, 0.012),
        nu=(0.0015, -0.0021, 0.0003),
        u_eq=(0.0100, -0.0400, 0.0070),
        u_d=(0.0023, -0.0056, 0.00089),
        u_nm=u_nm,
        commanded_rates_rads=(20 * DEG, -7.5 * DEG, 2.5 * DEG),
        thrust_norm=0.5,
        latency_s=0.0004,
        failsafe=failsafe,
    )


LINK = LinkStatus(
    url="udpin:127.0.0.1:14550", autopilot="ArduPilot", firmware_version="4.5.7", mode="GUIDED",
    armed=True, thrust_semantics="climb_rate", attitude_rate_requested_hz=400.0,
    attitude_rate_achieved_hz=398.7, latency_p50_s=0.00041, latency_p99_s=0.00123, cycles=4936,
    missed=0, dropped=3, duplicate=1, superseded=2, invalid=4, time_since_attitude_s=0.0021,
    signing=False,
)

SESSION = SessionInfo(
    controller="astsm", gain_summary={"Λ": "3.89", "ϖ": "1000", "ε": "0.6", "γ1": "6.6"},
    mu=(0.01, 0.01, 0.01), alpha_min=(0.01, 0.01, 0.01), alpha_max=(1000.0, 1000.0, 1000.0),
    reference_name="paper-steps", reference_start_vehicle_time_s=10.0, reference_duration_s=12.0,
    on_failsafe="level hold 2 s, then hand back to LOITER", on_exit="level hold, then LOITER",
    log_paths=("logs/run-001.csv",),
)


def make_buffer(n: int = 2000, rate_hz: float = 400.0, t0_s: float = 10.0, **sample_kw) -> TelemetryBuffer:
    """A buffer holding ``n`` cycles at ``rate_hz``; u alternates sign to give a known chattering."""
    buf = TelemetryBuffer(capacity=4000)
    buf.set_link(LINK)
    buf.set_session(SESSION)
    for k in range(n):
        buf.publish(make_sample(t0_s + k / rate_hz, **sample_kw))
    return buf


def make_snapshot(**kw) -> TelemetrySnapshot:
    return make_buffer(**kw).snapshot()


@pytest.fixture
def snapshot_maker():
    """``make_snapshot(**kw)`` as a fixture (conftest modules are not importable by name)."""
    return make_snapshot


@pytest.fixture
def buffer_maker():
    return make_buffer


def record_console(width: int, height: int, terminal: bool = False) -> Console:
    """Fixed-size recording console without colour (rich tests/test_live.py style)."""
    return Console(width=width, height=height, file=io.StringIO(), color_system=None, legacy_windows=False,
                   force_terminal=terminal, record=True, _environ={})


@pytest.fixture
def console_maker():
    return record_console
