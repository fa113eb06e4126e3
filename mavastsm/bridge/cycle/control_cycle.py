"""One control cycle per fresh ATTITUDE sample: reference -> tracking error -> controller -> mapping -> limits.

No I/O and no threads: the session calls ``step`` with a validated sample and the dt taken from the
vehicle clock, and gets back the limited setpoint plus the telemetry row. Nothing in here raises on
bad numbers: a non-finite torque becomes ``FailsafeReason.NON_FINITE_COMMAND``.

Reference: the profile runs on the vehicle clock from the engagement sample. Its yaw is applied
relative to the heading at engagement (a +45 deg yaw step means engage heading + 45 deg); roll and
pitch are relative to level (so a hold profile levels the vehicle) and clipped to the tilt limit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ...config_loading import per_axis
from ...control.controller_interface import tracking_error_and_euler_rates
from ...control.single_sample import diagnostics_floats
from ...frames import body_rates_from_euler_rates_floats, q_from_euler
from ...state_types import FailsafeReason
from ...telemetry import DIAGNOSTIC_FIELDS, NAN3, ControlSample
from ..bridge_config import BridgeConfig
from .autopilot_target_model import AutopilotTargetModel
from ..link.messages import AttitudeSample, Setpoint
from .reference_shaping import AccelLimitedShaper
from .loop_identification import LoopIdentification, LoopIdentified
from .safety import CommandSaturationMonitor, OutputGate, clip_reference_tilt, envelope_breach, highest_priority, last_setpoint_safe_rates
from ..autopilots.profile import AutopilotProfile
from .setpoint_mapping import (AltitudeHold, RateMapping, hold_thrust, integrated_axes, level_hold_setpoint, rate_setpoint,
                               yaw_from_reference, yaw_trim_error)


def _diag3(diag, key) -> tuple[float, float, float]:
    return diagnostics_floats(diag, key) or NAN3


@dataclass(slots=True)
class CycleResult:
    """What one cycle produced: the (already limited) setpoint or a failsafe, plus what the telemetry row needs."""

    setpoint: Setpoint | None
    vehicle_time_s: float
    failsafe: FailsafeReason | None = None
    euler: tuple = NAN3
    ref: tuple = NAN3
    euler_rates: tuple = NAN3
    error: tuple = NAN3
    diag: dict = field(default_factory=dict)
    u: tuple = NAN3
    detail: str = ""  # why the failsafe, in a few words (for the end reason)
    identifying: bool = False  # a cycle of the in-flight identification phase (loop_identification)
    profile_started: bool = False  # the phase ended with this cycle: the law is engaged again, the profile starts

    def telemetry(self, latency_s: float = float("nan")) -> ControlSample:
        """The ControlSample of this cycle (built after the setpoint went out)."""
        d = self.diag
        sp = self.setpoint
        return ControlSample(
            self.vehicle_time_s, reference_rad=self.ref, euler_rad=self.euler, euler_rate_rads=self.euler_rates,
            error_rad=self.error, sigma=_diag3(d, "sigma"), alpha=_diag3(d, "alpha"), beta=_diag3(d, "beta"), nu=_diag3(d, "nu"),
            u_eq=_diag3(d, "u_eq"), u_d=_diag3(d, "u_d"), u_nm=self.u,
            commanded_rates_rads=sp.body_rates_rads if sp is not None else NAN3,
            thrust_norm=sp.thrust_norm if sp is not None else float("nan"), latency_s=latency_s, failsafe=self.failsafe,
            extra=tuple((k, _diag3(d, k)) for k in d if k not in DIAGNOSTIC_FIELDS), identifying=self.identifying,
        )


class ReferenceTable:
    """The reference profile sampled on the vehicle's 1 ms clock grid, in chunks (exactly ``profile.at``
    at integer milliseconds, without a vectorised NumPy evaluation per cycle).

    Parameters
    ----------
    profile : ReferenceProfile (``.at(t_array) -> (n, 3) arrays``)
    chunk_ms : samples per chunk (computed on demand, one vectorised evaluation per chunk)
    """

    def __init__(self, profile, chunk_ms: int = 2_000) -> None:
        self.profile = profile
        self.chunk_ms = chunk_ms
        self._start = None
        self._arrays = None

    def at_ms(self, t_ms: int):
        """(Theta_d, Theta_dot_d, Theta_ddot_d) as 3-tuples at t = t_ms / 1000 s since engagement."""
        t_ms = max(0, int(t_ms))
        if self._start is None or not (self._start <= t_ms < self._start + self.chunk_ms):
            self._start = t_ms
            a, r, acc = self.profile.at((t_ms + np.arange(self.chunk_ms)) / 1000.0)
            self._arrays = (np.asarray(a, dtype=float), np.asarray(r, dtype=float), np.asarray(acc, dtype=float))
        i = t_ms - self._start
        a, r, acc = self._arrays
        return tuple(a[i].tolist()), tuple(r[i].tolist()), tuple(acc[i].tolist())


def command_clip_mode(mapping_config, adaptive_gain: bool) -> str:
    """``mapping.command_accel_clip`` with ``auto`` resolved: authority_roll_pitch for an adaptive-gain law, else autopilot."""
    mode = mapping_config.command_accel_clip
    if mode == "auto":
        return "authority_roll_pitch" if adaptive_gain else "autopilot"
    return mode


def command_torque_limit_nm(mapping_config, inertia_diag, autopilot_accel_radss, adaptive_gain: bool = False) -> tuple[float, float, float]:
    """Per-axis torque [N m] a command may ask for: the command clip (/ I0) and the controller's torque limit.

    ``command_accel_clip``: ``autopilot`` = I0 * ATC_ACCEL_*_MAX (0.056 / 0.097 / 0.028 N m on the Solo);
    ``authority_roll_pitch`` = roll/pitch at ``torque_authority_nm``, yaw at I0_zz * ATC_ACCEL_Y_MAX;
    ``authority`` = every axis at ``torque_authority_nm``; ``auto`` = authority_roll_pitch when the controller
    adapts its switching gain (``adaptive_gain``), else autopilot. Measured trade-offs: docs/bridge.md.
    """
    autopilot = tuple(float(i * a) for i, a in zip(inertia_diag, autopilot_accel_radss))
    authority = tuple(float(x) for x in mapping_config.torque_authority_nm)
    mode = command_clip_mode(mapping_config, adaptive_gain)
    if mode == "autopilot":
        return autopilot  # type: ignore[return-value]
    if mode == "authority":
        return authority  # type: ignore[return-value]
    return (authority[0], authority[1], min(authority[2], autopilot[2]))


class ControlCycle:
    """Reference, controller, torque -> rate mapping and limits for one vehicle.

    Parameters
    ----------
    controller : AttitudeController (update(err, dt) -> torque [N m])
    reference : ReferenceProfile (``.at(t) -> (Theta_d, Theta_dot_d, Theta_ddot_d)``, ``.relative_to``)
    inertia_diag : [kg m^2] nominal I0 used by the mapping (same as the controller's model)
    profile : AutopilotProfile (thrust semantics)
    config : BridgeConfig
    alpha_max : adaptive-gain upper clamp per axis, or one for all (None when the controller has no adaptive gain)
    accel_limit_radss : [rad/s^2] (3,) the autopilot's rate-target slew limit ATC_ACCEL_*_MAX, used by the reference
        shaping (None = config.mapping.accel_limit_radss)
    angle_p : [1/s] (3,) the autopilot's ATC_ANG_RLL/PIT/YAW_P, read at preflight; with it (ArduPilot, and
        ``mapping.compensate_autopilot_target``) the cycle models ArduCopter's hidden attitude target
        (``target_model``, compensating yaw only when the yaw command is not built on the reference, M6)
    vertical_state : callable -> (z [m, NED down], vz [m/s, down]) for the altitude hold (gains from ``config.thrust``),
        given only when the flight plan holds altitude (``FlightPlan.hold_altitude``: a collective thrust field and
        ``thrust.altitude_hold``); None = no altitude hold
    pinned_failsafe : ADAPTIVE_GAIN_PINNED when alpha sits at alpha_max (runaway adaptation). The bridge turns it
        off when alpha_max is at or below the loop-delay ceiling (``mapping.bound_adaptive_gain`` sets it there for a
        registered ASTSM): alpha cannot run away, and alpha at its clamp is the law's designed maximum gain
        (COMMAND_SATURATION and ENVELOPE_BREACH remain).
    identify_in_flight : the first engagement flies ``loop_identification``'s excitation, fits the loop, sets the
        mapping's tau from it, then engages again on the profile (``identifying`` while it runs; ``identified``)
    setpoint_timeout_s : [s] how long the vehicle obeys our last setpoint once the stream stops (GUID_TIMEOUT /
        COM_OF_LOSS_T, read at preflight; None = ``limits.setpoint_timeout_s``). With ``limits.last_setpoint_lag_s``
        and the braking acceleration ``accel_limit_radss`` it bounds every roll/pitch command
        (``safety.last_setpoint_safe_rates``): the last setpoint of a bridge that dies is survivable.
    torque_authority_nm : [N m] (3,) what the command may ask for; the commanded acceleration is clipped to
        torque_authority / I0 (None = ``command_torque_limit_nm(config.mapping, ...)``). An axis whose torque
        held at this limit on the same side (sustained saturation, not chattering between the limits) is
        physics, not wind-up: its alpha at alpha_max does not count towards ADAPTIVE_GAIN_PINNED.
    """

    def __init__(self, controller, reference, inertia_diag, profile: AutopilotProfile, config: BridgeConfig, alpha_max: float | None = None,
                 accel_limit_radss=None, angle_p=None, torque_authority_nm=None,
                 setpoint_timeout_s: float | None = None, pinned_failsafe: bool = True, vertical_state=None,
                 identify_in_flight: bool = False) -> None:
        self.controller = controller
        self.base_reference = reference
        if config.mapping.prefilter_wn_rads > 0 and hasattr(reference, "with_prefilter"):
            self.base_reference = reference.with_prefilter(config.mapping.prefilter_wn_rads)
        self.reference = self.base_reference
        self.reference_table = ReferenceTable(self.reference)
        self.profile = profile
        self.config = config
        accel = config.mapping.accel_limit_radss if accel_limit_radss is None else accel_limit_radss
        if torque_authority_nm is None:
            torque_authority_nm = command_torque_limit_nm(config.mapping, inertia_diag, accel, alpha_max is not None)
        self.torque_authority_nm = tuple(float(x) for x in torque_authority_nm)
        self._saturated_at = tuple(t * (1.0 - 1e-6) for t in self.torque_authority_nm)
        self._pushing = (0, 0, 0)
        command_accel = tuple(t / i for t, i in zip(self.torque_authority_nm, inertia_diag))
        m = config.mapping
        self.mapping = RateMapping(m.method, inertia_diag, m.rate_time_constant_s, command_accel, integrated_axes(m))
        self.yaw_from_reference = yaw_from_reference(m.method, m.yaw_command_base, profile)  # M6
        self._yaw_trim_gain = float(m.yaw_trim_gain_per_s)  # [1/s] M10
        self._yaw_trim_limit = float(m.yaw_trim_error_limit_rad)  # [rad] M10: trim rate <= gain x limit
        self._yaw_trim_band = float(m.yaw_trim_band_rad)  # [rad] M10: errors inside it are not integrated
        lim = config.limits
        timeout = lim.setpoint_timeout_s if setpoint_timeout_s is None else float(setpoint_timeout_s)
        self.last_setpoint_hold_s = timeout + lim.last_setpoint_lag_s
        self._decel = (float(accel[0]), float(accel[1]))
        self._tilt_last = lim.last_setpoint_tilt_rad
        envelope = (self.last_setpoint_hold_s, self._decel, self._tilt_last, m.shaping_envelope_fraction)
        self.shaper = AccelLimitedShaper([f * a for f, a in zip(m.shaping_accel_fraction, accel)], m.shaping_p,
                                         envelope=envelope) if m.reference_shaping else None
        self.pinned_failsafe = pinned_failsafe
        tc = config.thrust
        self.vertical_state = vertical_state
        self.altitude_hold = (AltitudeHold(tc.altitude_kp, tc.altitude_ki, tc.altitude_kd, tc.altitude_max_delta_norm)
                              if vertical_state is not None else None)
        self.altitude_offset_norm = 0.0  # [-] the altitude hold's last collective offset, kept by level_hold
        self.alpha_max = None if alpha_max is None else per_axis(alpha_max)
        self.target_model: AutopilotTargetModel | None = None
        if m.compensate_autopilot_target and angle_p is not None and profile.hidden_attitude_target:
            self.target_model = AutopilotTargetModel(angle_p, accel, compensate_yaw=not self.yaw_from_reference)
        self.engage_ms: int | None = None
        self.engage_yaw_rad = 0.0
        self.alpha_pinned_s = 0.0
        self._thr = (lim.thrust_min_norm, lim.thrust_max_norm)
        self.gate = OutputGate(lim.max_rate_cmd_rads, *self._thr)  # the output gate, once per setpoint
        self._tilt_ref = lim.max_reference_tilt_rad
        self._envelope = lim.envelope_tilt_rad
        self.identification = (LoopIdentification(self.mapping.tau_s, inertia_diag, command_accel, self.yaw_from_reference,
                                                  self.mapping.integrated[0]) if identify_in_flight else None)
        self.identifying = False  # flying the identification phase's excitation
        self.identified: LoopIdentified | None = None  # what the phase found (None: no phase, or not finished)
        self.saturation = CommandSaturationMonitor(lim.saturation_window_s, lim.saturation_fraction, lim.oscillation_max_hz,
                                                   lim.oscillation_swing_rads, lim.saturation_hold_s)

    def mapping_record(self) -> dict:
        """What the torque -> rate mapping flies with, for the log's sidecar (``mavastsm identify`` rebuilds the
        wanted body rates from it): the assumed rate-loop tau and delay, the command's acceleration clip, I0."""
        m = self.config.mapping
        return {"method": m.method, "rate_time_constant_s": list(self.mapping.tau_s), "loop_delay_s": list(m.loop_delay_s),
                "command_accel_limit_radss": list(self.mapping.accel_limit),  # always set here (torque authority / I0)
                "inertia_diag_kgm2": list(self.mapping.inertia_diag), "yaw_from_reference": self.yaw_from_reference,
                "roll_pitch_command_base": m.roll_pitch_command_base, "yaw_trim_gain_per_s": self._yaw_trim_gain,
                "yaw_trim_error_limit_rad": self._yaw_trim_limit, "yaw_trim_band_rad": self._yaw_trim_band,
                "compensate_autopilot_target": self.target_model is not None,
                "identified_in_flight": self.identified.record() if self.identified is not None else None}

    def mapping_text(self, adaptive: bool) -> str:
        """The mapping in words for the preflight summary: method, tau, M9/M6 where they apply, the command torque
        limit and how it clips (``adaptive``: the law's switching gain adapts)."""
        m = self.config.mapping
        return (f"{m.method} (tau {', '.join(f'{t:g}' for t in m.rate_time_constant_s)} s"
                f"{', roll/pitch integrated (M9)' if self.mapping.integrated[0] else ''}"
                f"{', yaw on the reference rate (M6)' if self.yaw_from_reference else ''}), "
                f"command torque limit {', '.join(f'{t:.3g}' for t in self.torque_authority_nm)} N m "
                f"({command_clip_mode(m, adaptive)})")

    # ------------------------------------------------------------------
    def engage(self, sample: AttitudeSample) -> None:
        """(Re-)engage at this sample: reset integrators and adaptive gains, restart the reference."""
        self.controller.reset()
        self.mapping.reset(sample.body_rates_rads)
        self.engage_ms = sample.time_boot_ms
        self.engage_yaw_rad = sample.euler_rad[2]
        self.identifying = self.identification is not None and self.identified is None
        if self.identifying:
            self.identification.restart()  # the phase is flown whole from this engagement
        base = self.identification.reference if self.identifying else self.base_reference
        rel = getattr(base, "relative_to", None)
        self.reference = rel((0.0, 0.0, self.engage_yaw_rad)) if rel else base
        self.reference_table = ReferenceTable(self.reference)
        self.reference_table.at_ms(0)  # first chunk now, not in the first cycle
        self.alpha_pinned_s = 0.0
        self._pushing = (0, 0, 0)
        self.saturation.reset()
        self.altitude_offset_norm = 0.0
        if self.altitude_hold is not None:
            v = self.vertical_state()
            self.altitude_hold.reset(v[0] if v is not None else None)
        if self.shaper is not None:
            self.shaper.reset(sample.euler_rad)
        if self.target_model is not None:
            self.target_model.last_sync_ms = None
            self.target_model.reset(q_from_euler(*sample.euler_rad), sample.body_rates_rads)
            self._sync_target(sample)

    def _sync_target(self, sample: AttitudeSample) -> None:
        """Re-synchronise the hidden-target model on the ATTITUDE_TARGET the link handed on with ``sample``."""
        target = sample.autopilot_target
        if target is not None:
            self.target_model.sync(target.time_boot_ms, target.q_wxyz, target.body_rates_rads)

    def reference_time_s(self, time_boot_ms: int) -> float:
        return 0.0 if self.engage_ms is None else (time_boot_ms - self.engage_ms) / 1000.0

    def set_hover_collective(self, hover_norm: float) -> None:
        """Fly ``hover_norm`` [-] as the hover collective from the next setpoint on (PX4: measured from its own hold
        before the guided mode). Ignored unless finite within the thrust limits, so every setpoint stays bounded."""
        lo, hi = self._thr
        if math.isfinite(hover_norm) and lo <= hover_norm <= hi:
            self.profile = dataclasses.replace(self.profile, hover_thrust_norm=float(hover_norm))

    def thrust_hold(self, euler_rad) -> float:
        t = self.config.thrust
        return hold_thrust(self.profile, euler_rad[0], euler_rad[1], t.tilt_compensation, t.max_tilt_compensation)

    def limited(self, sp: Setpoint) -> Setpoint | None:
        """``sp`` through the output gate (``safety.OutputGate.admit``): clamped into the command limits, or None."""
        return self.gate.admit(sp)

    def level_hold(self, yaw_rad: float) -> Setpoint:
        """Level attitude at ``yaw_rad`` with the hold thrust (always within limits). With a collective thrust the
        altitude hold's last offset is kept (frozen): without it PX4's hover collective alone let the vehicle
        climb or sink during the hold before the hand-back (a 0.3 m climb in one genuine-PX4 CI run)."""
        thrust = hold_thrust(self.profile, 0.0, 0.0, False) + self.altitude_offset_norm
        sp = self.limited(level_hold_setpoint(yaw_rad, thrust))
        assert sp is not None  # finite by construction
        return sp

    # ------------------------------------------------------------------
    def step(self, sample: AttitudeSample, dt_s: float) -> CycleResult:
        """One cycle (sample already validated by safety.attitude_sample_problem).

        The per-cycle path uses floats where they suffice (NumPy call overhead dominates for
        3-vectors); only the controller sees arrays. The telemetry row is built after the send
        (``CycleResult.telemetry``).
        """
        t_vehicle = sample.time_boot_ms / 1000.0
        euler = sample.euler_rad
        breach = envelope_breach(euler, self._envelope)
        if breach is not None:
            return CycleResult(None, t_vehicle, failsafe=breach, euler=euler)
        ref, ref_rate, ref_acc = self.reference_table.at_ms(sample.time_boot_ms - (self.engage_ms or 0))
        ref = clip_reference_tilt(ref, self._tilt_ref)
        if self.shaper is not None:
            ref, ref_rate, ref_acc = self.shaper.step(ref, ref_rate, dt_s)
        err, euler_rates = tracking_error_and_euler_rates(euler, sample.body_rates_rads, ref, ref_rate, ref_acc)
        torque = self.controller.update(err, dt_s)
        u = tuple(np.asarray(torque, dtype=float).reshape(-1)[:3].tolist())
        res = CycleResult(None, t_vehicle, euler=euler, ref=tuple(ref), euler_rates=euler_rates,
                          error=tuple(err.angle_error_rad.tolist()), diag=self.controller.diagnostics(), u=u)
        if not all(math.isfinite(x) for x in u):
            res.failsafe = FailsafeReason.NON_FINITE_COMMAND
            return res
        base = None
        if self.yaw_from_reference:  # M6: yaw built on the (shaped) reference's body yaw rate, eq. 1 at the measured angles
            p, q, _ = sample.body_rates_rads  # M10: plus the heading trim -k_I e_psi (ArduCopter's target integrates it)
            trim = self._yaw_trim_gain * yaw_trim_error(res.error[2], self._yaw_trim_band, self._yaw_trim_limit)
            base = (p, q, body_rates_from_euler_rates_floats(euler[0], euler[1], ref_rate[0], ref_rate[1], ref_rate[2] - trim)[2])
        rates_cmd = self.mapping(u, sample.body_rates_rads, dt_s, base)
        if self.target_model is not None:
            self._sync_target(sample)
            rates_cmd = self.target_model.compensate(q_from_euler(*euler), rates_cmd)
        requested = rates_cmd
        rates_cmd = last_setpoint_safe_rates(rates_cmd, euler, self.last_setpoint_hold_s, self._decel, self._tilt_last)
        thrust = self.thrust_hold(euler)
        if self.altitude_hold is not None:
            v = self.vertical_state()
            if v is not None:
                self.altitude_offset_norm = self.altitude_hold(v[0], v[1], dt_s)
                thrust += self.altitude_offset_norm
        sp = self.limited(rate_setpoint(rates_cmd, thrust))
        if sp is None:
            res.failsafe = FailsafeReason.NON_FINITE_COMMAND
            return res
        # both monitors run every cycle (they keep state); when both fire, the one rule decides (safety.highest_priority)
        saturated = self.saturation.update(t_vehicle, requested, sp.body_rates_rads)
        pinned = self._alpha_pinned(res.diag, u, dt_s)
        reason = highest_priority((FailsafeReason.COMMAND_SATURATION if saturated else None,
                                   FailsafeReason.ADAPTIVE_GAIN_PINNED if pinned else None))
        if reason is not None:
            res.failsafe = reason
            res.detail = self.saturation.reason if reason is FailsafeReason.COMMAND_SATURATION else ""
            return res
        if self.target_model is not None:
            self.target_model.advance(sp.body_rates_rads, dt_s)
        self.mapping.saturated_to(requested, sp.body_rates_rads)
        res.setpoint = sp
        if self.identifying:
            self._identification_step(sample, u, res)
        return res

    def _identification_step(self, sample: AttitudeSample, u, res: CycleResult) -> None:
        """Keep this phase cycle; at the excitation's end fit the loop, fly the tau it found (loop_identification)
        and engage again on the profile."""
        ident = self.identification
        ident.record(sample.time_boot_ms / 1000.0, sample.body_rates_rads, u)
        res.identifying = True
        if self.reference_time_s(sample.time_boot_ms) < ident.duration_s:
            return
        self.identified = ident.finish()
        self.mapping.tau_s = self.identified.tau_s
        self.engage(sample)
        res.profile_started = True

    def _alpha_pinned(self, diag, u, dt_s: float) -> bool:
        """ADAPTIVE_GAIN_PINNED condition: alpha at alpha_max for timing.alpha_pinned_s on an axis that is not held
        at its torque authority. Alpha at alpha_max on an axis saturated at its authority is physics (a
        disturbance larger than the vehicle can reject), not the law winding up, so only unsaturated axes count."""
        alpha = diag.get("alpha") if self.alpha_max is not None and self.pinned_failsafe else None
        if alpha is None:
            return False
        pushing = tuple((1 if ui >= lim else (-1 if ui <= -lim else 0)) for ui, lim in zip(u, self._saturated_at))
        held = tuple(p != 0 and p == q for p, q in zip(pushing, self._pushing))  # saturated, same side, two cycles
        self._pushing = pushing
        pinned = any(a >= top * (1.0 - 1e-9) and not h
                     for a, top, h in zip(np.asarray(alpha, dtype=float).reshape(-1).tolist(), self.alpha_max, held))
        self.alpha_pinned_s = self.alpha_pinned_s + dt_s if pinned else 0.0
        return pinned and self.alpha_pinned_s >= self.config.timing.alpha_pinned_s
