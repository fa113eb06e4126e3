"""Any controller's diagnostics reach the telemetry, the flight CSV and the dashboard (safe-simple issue, item 3):
PID's internals, which have no field of their own, travel as ``ControlSample.extra``."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from rich.console import Console

from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
from mavastsm.bridge.bridge_config import load_bridge_config
from mavastsm.bridge.cycle.control_cycle import ControlCycle
from mavastsm.bridge.record.flight_log import FlightLog, read_flight_rows
from mavastsm.bridge.link.messages import AttitudeSample
from mavastsm.control import make_controller
from mavastsm.dashboard.panels import build_view
from mavastsm.references import load_reference
from mavastsm.solo_model import load_solo
from mavastsm.telemetry import SessionInfo, TelemetryBuffer, extra_diagnostic_keys

PID_KEYS = ("rate_target", "rate_error", "integrator", "derivative", "u_norm")


def _pid_samples(n=40, dt=0.0025):
    solo = load_solo()
    ctl = make_controller("pid", solo)
    cycle = ControlCycle(ctl, load_reference("hold"), solo.inertia_diag, ardupilot_profile("climb_rate"), load_bridge_config(), None,
                         (6.28, 6.28, 1.22), torque_authority_nm=(2.9, 2.9, 0.4))
    cycle.engage(AttitudeSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0))
    out = []
    for k in range(1, n + 1):  # a 3 deg roll offset and a small pitch rate: the integrator and rate error move
        res = cycle.step(AttitudeSample(int(k * dt * 1000), (0.05, 0.0, 0.0), (0.0, 0.1, 0.0), 0), dt)
        assert res.failsafe is None
        out.append((res.telemetry(), {k: np.array(v) for k, v in ctl.diagnostics().items()}))
    return ctl, out


def test_pid_internals_travel_in_the_sample_with_the_controllers_values():
    ctl, samples = _pid_samples()
    assert extra_diagnostic_keys(ctl.diagnostics()) == PID_KEYS
    sample, diag = samples[-1]
    assert tuple(k for k, _ in sample.extra) == PID_KEYS
    for key, values in sample.extra:
        np.testing.assert_array_equal(values, diag[key])
    assert dict(sample.extra)["integrator"][0] != 0.0 and sample.u_nm == tuple(diag["u"].tolist())


def test_pid_internals_are_csv_columns_at_full_precision(tmp_path):
    ctl, samples = _pid_samples()
    log = FlightLog(tmp_path / "f.csv", extra_diagnostic_keys(ctl.diagnostics()))
    for sample, _ in samples:
        log.append(sample)
    log.close()
    header = (tmp_path / "f.csv").read_text().splitlines()[0].split(",")
    assert header[-15:] == [f"diag_{k}_{a}" for k in PID_KEYS for a in ("roll", "pitch", "yaw")]
    rows = read_flight_rows(tmp_path / "f.csv")
    assert [r.sample.extra for r in rows] == [s.extra for s, _ in samples]  # every digit back


def test_pid_internals_are_on_the_dashboard():
    _, samples = _pid_samples()
    buf = TelemetryBuffer(capacity=100)
    nan3 = (math.nan,) * 3
    buf.set_session(SessionInfo(controller="pid", gain_summary={}, mu=nan3, alpha_min=nan3, alpha_max=nan3, reference_name="hold",
                                reference_start_vehicle_time_s=0.0, reference_duration_s=10.0, on_failsafe="LAND", on_exit="LAND",
                                log_paths=()))
    for sample, _ in samples:
        buf.publish(sample)
    for width, height in ((120, 40), (140, 50)):
        console = Console(width=width, height=height, file=io.StringIO(), color_system=None, record=True, _environ={})
        console.print(build_view(buf.snapshot(), width, height))
        text = console.export_text()
        for key in PID_KEYS:
            assert key in text, (width, height, text)
        integ = dict(samples[-1][0].extra)["integrator"][0]
        assert f"{integ:+.4g}" in text
        assert len(text.splitlines()) <= height
