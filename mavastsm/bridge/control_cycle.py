"""One control cycle per fresh ATTITUDE sample: reference -> tracking error -> controller -> mapping -> limits.

No I/O and no threads: the session calls ``step`` with a validated sample and the dt taken from the
vehicle clock, and gets back the limited setpoint plus the telemetry row. Nothing in here raises on
bad numbers: a non-finite torque becomes ``FailsafeReason.NON_FINITE_COMMAND``.

Reference: the profile runs on the vehicle clock from the engagement sample. Its yaw is applied
relative to the heading at engagement (a +45 deg yaw step means engage heading + 45 deg); roll and
pitch are relative to level (so a hold profile levels the vehicle) and clipped to the tilt limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control.controller_interface import tracking_error
from ..state_types import FailsafeReason
from ..telemetry import NAN3, ControlSample
from .bridge_config import BridgeConfig
from .autopilot_target_model import AutopilotTargetModel, q_from_euler
from .inbound_messages import AttitudeSample
from .reference_shaping import AccelLimitedShaper
from .safety import clip_reference_tilt, envelope_breach, limit_setpoint
from .setpoint_mapping import AutopilotProfile, RateMapping, Setpoint, hold_thrust, level_hold_setpoint, rate_setpoint


def _t3(a) -> tuple[float, float, float]:
    return tuple(float(x) for x in np.asarray(a, dtype=float).reshape(-1)[:3])  # type: ignore[return-value]


@dataclass(slots=True)
class CycleResult:
    """What one cycle produced: the (already limited) setpoint, the telemetry row and any failsafe."""

    setpoint: Setpoint | None
    telemetry: ControlSample
    failsafe: FailsafeReason | None


class ControlCycle:
    """Reference, controller, torque -> rate mapping and limits for one vehicle.

    Parameters
    ----------
    controller : AttitudeController (update(err, dt) -> torque [N m])
    reference : ReferenceProfile (``.at(t) -> (Theta_d, Theta_dot_d, Theta_ddot_d)``, ``.relative_to``)
    inertia_diag : [kg m^2] nominal I0 used by the mapping (same as the controller's model)
    profile : AutopilotProfile (thrust semantics)
    config : BridgeConfig
    alpha_max : adaptive-gain upper clamp (None when the controller has no adaptive gain)
    accel_limit_radss : [rad/s^2] (3,) commanded-acceleration clip (None = config.mapping.accel_limit_radss)
    target_model : AutopilotTargetModel (ArduPilot) or None
    latest_target : callable -> latest ATTITUDE_TARGET message or None (re-synchronises the model)
    """

    def __init__(self, controller, reference, inertia_diag, profile: AutopilotProfile, config: BridgeConfig, alpha_max: float | None = None,
                 accel_limit_radss=None, target_model: AutopilotTargetModel | None = None, latest_target=None) -> None:
        self.controller = controller
        self.base_reference = reference
        if config.mapping.prefilter_wn_rads > 0 and hasattr(reference, "with_prefilter"):
            self.base_reference = reference.with_prefilter(config.mapping.prefilter_wn_rads)
        self.reference = self.base_reference
        self.profile = profile
        self.config = config
        accel = config.mapping.accel_limit_radss if accel_limit_radss is None else accel_limit_radss
        self.mapping = RateMapping(config.mapping.method, inertia_diag, config.mapping.rate_time_constant_s, accel)
        m = config.mapping
        self.shaper = AccelLimitedShaper([f * a for f, a in zip(m.shaping_accel_fraction, accel)], m.shaping_p) if m.reference_shaping else None
        self.alpha_max = alpha_max
        self.target_model = target_model
        self.latest_target = latest_target
        self.engage_ms: int | None = None
        self.engage_yaw_rad = 0.0
        self.alpha_pinned_s = 0.0
        lim = config.limits
        self._max_rate = lim.max_rate_cmd_rads
        self._thr = (lim.thrust_min_norm, lim.thrust_max_norm)
        self._tilt_ref = lim.max_reference_tilt_rad
        self._envelope = lim.envelope_tilt_rad

    # ------------------------------------------------------------------
    def engage(self, sample: AttitudeSample) -> None:
        """(Re-)engage at this sample: reset integrators and adaptive gains, restart the reference."""
        self.controller.reset()
        self.mapping.reset(sample.body_rates_rads)
        self.engage_ms = sample.time_boot_ms
        self.engage_yaw_rad = sample.euler_rad[2]
        rel = getattr(self.base_reference, "relative_to", None)
        self.reference = rel((0.0, 0.0, self.engage_yaw_rad)) if rel else self.base_reference
        self.alpha_pinned_s = 0.0
        if self.shaper is not None:
            self.shaper.reset(sample.euler_rad)
        if self.target_model is not None:
            self.target_model.last_sync_ms = None
            self.target_model.reset(q_from_euler(*sample.euler_rad), sample.body_rates_rads)
            self._sync_target()

    def _sync_target(self) -> None:
        msg = self.latest_target() if self.latest_target is not None else None
        if msg is not None:
            self.target_model.sync(int(msg.time_boot_ms), tuple(msg.q), (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate))

    def reference_time_s(self, time_boot_ms: int) -> float:
        return 0.0 if self.engage_ms is None else (time_boot_ms - self.engage_ms) / 1000.0

    def thrust_hold(self, euler_rad) -> float:
        t = self.config.thrust
        return hold_thrust(self.profile, euler_rad[0], euler_rad[1], t.tilt_compensation, t.max_tilt_compensation)

    def limited(self, sp: Setpoint) -> Setpoint | None:
        return limit_setpoint(sp, self._max_rate, *self._thr)

    def level_hold(self, yaw_rad: float) -> Setpoint:
        """Level attitude at ``yaw_rad`` with the hold thrust (always within limits)."""
        sp = self.limited(level_hold_setpoint(yaw_rad, hold_thrust(self.profile, 0.0, 0.0, False)))
        assert sp is not None  # finite by construction
        return sp

    # ------------------------------------------------------------------
    def step(self, sample: AttitudeSample, dt_s: float) -> CycleResult:
        """One cycle (sample already validated by safety.attitude_sample_problem)."""
        t_vehicle = sample.time_boot_ms / 1000.0
        euler = sample.euler_rad
        breach = envelope_breach(euler, self._envelope)
        if breach is not None:
            return CycleResult(None, ControlSample(t_vehicle, euler_rad=euler, failsafe=breach), breach)
        t_ref = self.reference_time_s(sample.time_boot_ms)
        ref, ref_rate, ref_acc = self.reference.at(t_ref)
        ref = clip_reference_tilt(ref, self._tilt_ref)
        if self.shaper is not None:
            ref, ref_rate, ref_acc = self.shaper.step(ref, ref_rate, dt_s)
        err = tracking_error(euler, sample.body_rates_rads, ref, ref_rate, ref_acc)
        torque = self.controller.update(err, dt_s)
        diag = self.controller.diagnostics()
        u = _t3(torque)
        ref3 = _t3(ref)
        base = dict(
            reference_rad=ref3,
            euler_rad=euler,
            euler_rate_rads=_t3(err.euler_rate_error_rads + np.asarray(ref_rate, dtype=float)),
            error_rad=_t3(err.angle_error_rad),
            sigma=_t3(diag["sigma"]) if "sigma" in diag else NAN3,
            alpha=_t3(diag["alpha"]) if "alpha" in diag else NAN3,
            beta=_t3(diag["beta"]) if "beta" in diag else NAN3,
            nu=_t3(diag["nu"]) if "nu" in diag else NAN3,
            u_eq=_t3(diag["u_eq"]) if "u_eq" in diag else NAN3,
            u_d=_t3(diag["u_d"]) if "u_d" in diag else NAN3,
            u_nm=u,
        )
        if not all(math.isfinite(x) for x in u):
            reason = FailsafeReason.NON_FINITE_COMMAND
            return CycleResult(None, ControlSample(t_vehicle, failsafe=reason, **base), reason)
        rates_cmd = self.mapping(u, sample.body_rates_rads, dt_s)
        if self.target_model is not None:
            self._sync_target()
            rates_cmd = self.target_model.compensate(q_from_euler(*euler), rates_cmd)
        sp = self.limited(rate_setpoint(rates_cmd, self.thrust_hold(euler)))
        if sp is None:
            reason = FailsafeReason.NON_FINITE_COMMAND
            return CycleResult(None, ControlSample(t_vehicle, failsafe=reason, **base), reason)
        if self.target_model is not None:
            self.target_model.advance(sp.body_rates_rads, dt_s)
        else:
            self.mapping.saturated_to(sp.body_rates_rads)
        reason = None
        if self.alpha_max is not None and "alpha" in diag:
            pinned = any(a >= self.alpha_max * (1.0 - 1e-9) for a in base["alpha"])
            self.alpha_pinned_s = self.alpha_pinned_s + dt_s if pinned else 0.0
            if pinned and self.alpha_pinned_s >= self.config.timing.alpha_pinned_s:
                reason = FailsafeReason.ADAPTIVE_GAIN_PINNED
        if reason is not None:
            return CycleResult(None, ControlSample(t_vehicle, failsafe=reason, **base), reason)
        sample_out = ControlSample(t_vehicle, commanded_rates_rads=sp.body_rates_rads, thrust_norm=sp.thrust_norm, **base)
        return CycleResult(sp, sample_out, None)
