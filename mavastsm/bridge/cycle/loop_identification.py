"""The in-flight identification phase (issue 27): the loop through the autopilot measured before the profile.

When the flight plan asks for it (``mapping.identify_in_flight``: ``auto`` on a vehicle no packaged description
matches, ``always``), the law's first engagement flies a short excitation instead of the profile
(``EXCITATION``: 5 deg doublets on each axis in turn, 4.6 s) with every failsafe armed. Each of its cycles is kept
(vehicle time, measured body rates, the law's torque); at its end the cycle fits (I1) of ``loop_fit`` per axis to
the commanded acceleration ``clip(I0^-1 (u + f(omega)))`` (eq. 17) and the measured rate, and the mapping flies

    tau = tau_flown / k   (I2)

on every axis where the fit holds and tau is a loop constant (``loop_fit.tau_is_no_loop_constant``: not on an
integrated roll/pitch, M9, nor on yaw built on the reference, M6, where ArduPilot's heading loop sets tau_z,
``flight_plan.yaw_tau_from_heading_loop``). Then the law is engaged again and the profile starts. The delay L the
adaptive-gain ceiling uses is the description's: the fitted L is a transport delay (10-15 ms), not the delay of the
limit cycle the ceiling is about, which includes the loop's lag (docs/bridge.md, "Identifying the loop").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...frames import AXES
from ...references import load_reference
from .loop_fit import MIN_FIT_R2, AxisFit, effective_time_constant, fit_effectiveness, tau_is_no_loop_constant
from .setpoint_mapping import commanded_body_accel

EXCITATION = "identification_doublets"  # configs/references/identification_doublets.yaml
TAU_RANGE_S = (0.01, 0.2)  # [s] a fitted tau outside is not flown (a rate loop of a multicopter; a bad fit otherwise)


def excitation_text() -> str:
    """What the phase flies, from its reference (EXCITATION): "4.6 s of 5 deg doublets per axis"."""
    reference = load_reference(EXCITATION)
    first = {c.axis: abs(math.degrees(c.angle_rad)) for c in reversed(reference.components) if c.kind == "step"}
    sizes = ", ".join(sorted({f"{a:g}" for a in first.values()}))
    return f"{reference.duration_s:g} s of {sizes} deg doublets per axis"


@dataclass(frozen=True)
class LoopIdentified:
    """What the phase found and what the mapping flies from it."""

    fits: tuple[AxisFit, AxisFit, AxisFit]
    tau_flown_s: tuple[float, float, float]  # [s] the mapping's tau during the phase
    tau_eff_s: tuple[float, float, float]  # [s] (I2) per axis (NaN where the fit did not determine k)
    applied: tuple[bool, bool, bool]  # tau_eff replaced tau_flown on this axis
    why_not: tuple[str, str, str]  # why not applied ("" where it was)
    cycles: int
    duration_s: float  # [s] vehicle time the phase took

    @property
    def tau_s(self) -> tuple[float, float, float]:
        """The mapping's tau after the phase [s]."""
        return tuple(round(e, 4) if a else f for e, a, f in zip(self.tau_eff_s, self.applied, self.tau_flown_s))  # type: ignore[return-value]

    def text(self) -> str:
        """One line for the run's summary."""
        axes = []
        for name, fit, flown, eff, applied, why in zip(AXES, self.fits, self.tau_flown_s, self.tau_eff_s, self.applied, self.why_not):
            fitted = (f"k {fit.effectiveness:.2f}, L {fit.delay_s * 1000:.0f} ms, R² {fit.r2:.2f}"
                      if math.isfinite(fit.effectiveness) else "not fitted")
            axes.append(f"{name} tau {flown:g} -> {eff:.3g} s ({fitted})" if applied else f"{name} tau {flown:g} s kept ({fitted}: {why})")
        return f"loop identified in flight ({self.duration_s:.1f} s, {self.cycles} cycles): " + "; ".join(axes)

    def record(self) -> dict:
        """For the flight's sidecar."""
        return {"cycles": self.cycles, "duration_s": self.duration_s, "excitation": EXCITATION,
                "axes": {name: {"effectiveness": f.effectiveness, "delay_s": f.delay_s, "r2": f.r2, "tau_flown_s": flown,
                                "tau_eff_s": eff, "applied": applied, "why_not": why}
                         for name, f, flown, eff, applied, why in zip(AXES, self.fits, self.tau_flown_s, self.tau_eff_s,
                                                                       self.applied, self.why_not)}}


class LoopIdentification:
    """Keeps the phase's cycles and fits them at its end (module docstring).

    Parameters
    ----------
    tau_flown_s : [s] (3,) the mapping's tau during the phase
    inertia_diag : [kg m^2] (3,) the mapping's I0
    accel_limit_radss : [rad/s^2] (3,) the mapping's command clip
    yaw_from_reference, roll_pitch_integrated : the structure flown (M6, M9): those axes keep their tau
    """

    def __init__(self, tau_flown_s, inertia_diag, accel_limit_radss, yaw_from_reference: bool, roll_pitch_integrated: bool) -> None:
        self.reference = load_reference(EXCITATION)
        self.duration_s = float(self.reference.duration_s)
        self.tau_flown_s = tuple(float(t) for t in tau_flown_s)
        self.inertia_diag = tuple(float(i) for i in inertia_diag)
        self.accel_limit = np.asarray(accel_limit_radss, dtype=float)
        self.fixed = tuple(tau_is_no_loop_constant(i, yaw_from_reference, roll_pitch_integrated) for i in range(3))
        self._rows: list[tuple[float, float, float, float, float, float, float]] = []
        fit_effectiveness(np.arange(40) * 0.01, np.ones(40), np.arange(40) * 0.01)  # NumPy's first calls, before flight

    def restart(self) -> None:
        """Forget the cycles kept: the phase starts again (a re-engagement before it ended; on ArduCopter a first
        engagement can come on the guided HEARTBEAT, before the bridge's own takeoff and the engagement after it)."""
        self._rows.clear()

    def record(self, t_s: float, body_rates_rads, torque_nm) -> None:
        """One engaged cycle of the phase: vehicle time [s], measured body rates [rad/s, FRD], the law's torque [N m]."""
        self._rows.append((t_s, *body_rates_rads, *torque_nm))

    def finish(self) -> LoopIdentified:
        """Fit the cycles kept (about 3 ms for the 4.6 s phase at 400 Hz on one core) and decide each axis."""
        rows = np.asarray(self._rows, dtype=float).reshape(-1, 7)
        t, omega, u = rows[:, 0], rows[:, 1:4], rows[:, 4:7]
        accel = np.clip(np.column_stack(commanded_body_accel(u.T, omega.T, self.inertia_diag)), -self.accel_limit, self.accel_limit)
        fits, eff, applied, why = [], [], [], []
        for i in range(3):
            fit = fit_effectiveness(t, accel[:, i], omega[:, i])
            tau = effective_time_constant(self.tau_flown_s[i], fit)
            reason = ("integrated (M9): tau is no loop constant" if self.fixed[i] and i < 2
                      else "built on the reference (M6): the heading loop sets tau_z" if self.fixed[i]
                      else fit.why_not or (f"R² {fit.r2:.2f} < {MIN_FIT_R2}" if not fit.r2 >= MIN_FIT_R2 else "")
                      or ("" if TAU_RANGE_S[0] <= tau <= TAU_RANGE_S[1] else f"outside {TAU_RANGE_S[0]:g}-{TAU_RANGE_S[1]:g} s"))
            fits.append(fit)
            eff.append(tau)
            applied.append(reason == "")
            why.append(reason)
        span = float(t[-1] - t[0]) if t.size else 0.0
        return LoopIdentified(tuple(fits), self.tau_flown_s, tuple(eff), tuple(applied), tuple(why), int(t.size), span)  # type: ignore[arg-type]
