"""``mavastsm identify LOG``: the loop through the autopilot's rate controller, identified from one flight.

The fit and its equations (I1)-(I3): ``mavastsm.bridge.cycle.loop_fit``.

Per axis:

* roll and pitch (command built on the measured rates, M2, with M3 on ArduPilot): ``tau_eff`` replaces the
  vehicle description's ``offboard_loop.rate_time_constant_s``.
* yaw with the command built on the reference (M6, ArduPilot): ArduCopter's heading loop turns the command into
  a heading trim, ``tau_z`` is a tuning gain of that structure, not a loop time constant (docs/bridge.md, M6),
  so the yaw fit is reported but not proposed.
* ``L`` is the transport delay that best explains (I3). It is reported, not proposed: the description's
  ``loop_delay_s`` is the delay of the limit cycle that bounds the adaptive gain, which includes the loop's lag.

From a ``.tlog`` alone (no CSV beside it) the law's torque is unknown, but the mapping's own equation read
backwards gives what it asked for: ``a = (omega_cmd - omega) / tau_b`` with the body rates sent in
SET_ATTITUDE_TARGET and the ATTITUDE each answered. Any ``tau_b`` gives the same ``tau_eff`` (I2); the fit uses
``TLOG_TAU_B_S``. A .tlog does not record the structure flown, so only roll and pitch are proposed there.

Pure math first (``fit_effectiveness``), then reading the log, then the command.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .bridge.cycle.loop_fit import (DEFAULT_MAX_DELAY_S, DEFAULT_WINDOW_S, MIN_FIT_R2, MIN_SAMPLES, AxisFit,  # noqa: F401
                               effective_time_constant, fit_effectiveness, tau_is_no_loop_constant)
from .bridge.link.messages import TYPE_MASK_RATES
from .errors import ConfigError
from .frames import AXES, body_rates_from_euler_rates

TLOG_TAU_B_S = 1.0  # [s] a .tlog's a = (omega_cmd - omega) / tau_b (module docstring); tau_eff does not depend on it


# ----------------------------------------------------------------------------- the flight
@dataclass(frozen=True)
class LoopRecord:
    """What the mapping flew with, from the CSV's sidecar ``mapping`` record (ControlCycle.mapping_record)."""

    rate_time_constant_s: tuple[float, float, float]
    loop_delay_s: tuple[float, float, float]
    command_accel_limit_radss: tuple[float, float, float]
    inertia_diag_kgm2: tuple[float, float, float]
    yaw_from_reference: bool
    method: str
    roll_pitch_integrated: bool = False  # M9: roll/pitch commands are their own integral (tau is no mapping gain there)


def loop_record(meta: dict, source: Path) -> LoopRecord:
    """The sidecar's ``mapping`` record; ConfigError naming the file when the flight did not record it."""
    rec = meta.get("mapping")
    if not isinstance(rec, dict):
        raise ConfigError(f"{source}: the log's .json sidecar has no 'mapping' record (written by mavastsm >= 0.1.0 "
                          "with --log); fly again with --log to identify this vehicle")
    try:
        return LoopRecord(*(tuple(float(x) for x in rec[k]) for k in ("rate_time_constant_s", "loop_delay_s",
                                                                      "command_accel_limit_radss", "inertia_diag_kgm2")),
                          bool(rec["yaw_from_reference"]), str(rec["method"]),
                          rec.get("roll_pitch_command_base", "measured") == "integrated")
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: the sidecar's 'mapping' record is incomplete ({exc})") from None


def commanded_accel(euler_rad, euler_rate_rads, u_nm, rec: LoopRecord) -> tuple[np.ndarray, np.ndarray]:
    """(omega, a) (n, 3) of each engaged cycle: the measured body rates [rad/s, body FRD] (eq. 1) and the body
    acceleration [rad/s^2] the mapping asked for, ``clip(I0^-1 (u + f(omega)))`` (eq. 17), rebuilt from the logged
    torque with the flown I0 and clip."""
    from .bridge.cycle.setpoint_mapping import commanded_body_accel  # the mapping's own eq. 17, on whole columns

    omega = body_rates_from_euler_rates(euler_rad, euler_rate_rads)
    accel = np.column_stack(commanded_body_accel(np.asarray(u_nm, dtype=float).T, omega.T, rec.inertia_diag_kgm2))
    lim = np.asarray(rec.command_accel_limit_radss)
    return omega, np.clip(accel, -lim, lim)


@dataclass(frozen=True)
class Identification:
    source: Path
    vehicle: str
    flown: LoopRecord
    fits: tuple[AxisFit, AxisFit, AxisFit]
    tau_eff_s: tuple[float, float, float]  # (I2) per axis
    proposed: tuple[bool, bool, bool]  # per axis: tau_eff replaces the description's value
    cycles: int = 0  # controller cycles fitted
    engaged_s: float = 0.0  # [s] vehicle time they span
    ended_by: str = ""  # the FailsafeReason that ended the engaged flight ("" when it ran to its end)
    kind: str = "csv"  # "csv" (the flight log and its sidecar) or "tlog" (a .tlog alone: flown is TLOG_TAU_B_S)

    def why_not(self, axis: int) -> str:
        """Why tau_eff is not proposed on this axis ("" when it is)."""
        fit = self.fits[axis]
        if self.proposed[axis]:
            return ""
        if self.kind == "tlog" and axis == 2:
            return ("a .tlog does not record whether yaw was built on the reference (M6, ArduPilot's default), where "
                    "tau_z is a tuning gain: identify the flight's CSV")
        if _tau_is_no_loop_constant(axis, self.flown):
            return "yaw is built on the reference (M6)" if axis == 2 else "roll and pitch are integrated (M9)"
        if fit.why_not:
            return fit.why_not
        return f"the fit explains R² {fit.r2:.2f} of the rate's motion (at least {MIN_FIT_R2} to propose)"


def identify_flight(path: str | Path, window_s: float = DEFAULT_WINDOW_S, max_delay_s: float = DEFAULT_MAX_DELAY_S) -> Identification:
    """Fit (I1) per axis to the controller's cycles of a flight CSV (and its sidecar)."""
    from .bridge.record.flight_log import read_flight_rows, read_metadata

    source = Path(path)
    try:
        rows = read_flight_rows(source)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{source}: cannot read the flight log ({exc})") from None
    try:
        meta = read_metadata(source)
    except (OSError, ValueError):
        meta = {}
    rec = loop_record(meta, source)
    if rec.method != "first_order":
        raise ConfigError(f"{source}: flown with mapping.method={rec.method}; the fit identifies the first_order mapping's loop only")
    cycles, ended_by = engaged_cycles(rows)
    if len(cycles) < MIN_SAMPLES:
        before = f" before {ended_by}" if ended_by else ""
        raise ConfigError(f"{source}: {len(cycles)} controller cycles{before} in the log; the fit needs at least "
                          f"{MIN_SAMPLES} spanning more than its {window_s:g} s window")
    t = np.array([s.vehicle_time_s for s in cycles])
    omega, accel = commanded_accel([s.euler_rad for s in cycles], [s.euler_rate_rads for s in cycles], [s.u_nm for s in cycles], rec)
    fits = tuple(fit_effectiveness(t, accel[:, i], omega[:, i], window_s, max_delay_s) for i in range(3))
    tau = tuple(effective_time_constant(ft, f) for ft, f in zip(rec.rate_time_constant_s, fits))
    proposed = tuple(bool(math.isfinite(x) and f.r2 >= MIN_FIT_R2 and not _tau_is_no_loop_constant(i, rec))
                     for i, (x, f) in enumerate(zip(tau, fits)))
    return Identification(source, str(meta.get("vehicle", "")), rec, fits, tau, proposed,  # type: ignore[arg-type]
                          len(cycles), float(t[-1] - t[0]), ended_by)


def identify_tlog(path: str | Path, window_s: float = DEFAULT_WINDOW_S, max_delay_s: float = DEFAULT_MAX_DELAY_S) -> Identification:
    """Fit (I1) per axis to the law's cycles in a .tlog alone (module docstring): a = (omega_cmd - omega) /
    TLOG_TAU_B_S, so tau_eff = TLOG_TAU_B_S / k. Roll and pitch are proposed where the fit holds; yaw is not (the
    .tlog does not say whether it was built on the reference)."""
    source = Path(path)
    t, omega, omega_cmd = tlog_cycles(source)
    if t.size < MIN_SAMPLES:
        raise ConfigError(f"{source}: {t.size} controller setpoints (body rates, type_mask 0x80) answering an ATTITUDE in this .tlog; "
                          f"the fit needs at least {MIN_SAMPLES} spanning more than its {window_s:g} s window")
    accel = (omega_cmd - omega) / TLOG_TAU_B_S
    fits = tuple(fit_effectiveness(t, accel[:, i], omega[:, i], window_s, max_delay_s) for i in range(3))
    tau = tuple(effective_time_constant(TLOG_TAU_B_S, f) for f in fits)
    proposed = tuple(bool(i < 2 and math.isfinite(x) and f.r2 >= MIN_FIT_R2) for i, (x, f) in enumerate(zip(tau, fits)))
    nan3 = (float("nan"),) * 3
    flown = LoopRecord((TLOG_TAU_B_S,) * 3, nan3, (float("inf"),) * 3, nan3, False, "first_order")
    return Identification(source, "", flown, fits, tau, proposed, int(t.size), float(t[-1] - t[0]), "", "tlog")  # type: ignore[arg-type]


def tlog_cycles(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s, vehicle time_boot_ms], omega (n, 3), omega_cmd (n, 3) [rad/s, body FRD]) of the first unbroken run of
    the law's setpoints in a .tlog (type_mask TYPE_MASK_RATES, rates not all exactly zero: the pre-stream's hold sends
    zeros), each with the latest ATTITUDE recorded before it (the sample it answered; the .tlog's record time orders
    them). A failsafe's hold (attitude or zero-rate setpoints) ends the run. ConfigError (one line) for an
    unreadable file or one without ATTITUDE."""
    from .bridge.link.mavlink_link import read_tlog_flight

    attitude, setpoints = read_tlog_flight(path)
    att, sp = np.array(attitude, dtype=float).reshape(-1, 8), np.array(setpoints, dtype=float).reshape(-1, 6)
    rates = (sp[:, 1].astype(int) == TYPE_MASK_RATES) & (sp[:, 2:5] != 0.0).any(axis=1) if len(sp) else np.zeros(0, dtype=bool)
    first = int(np.argmax(rates)) if rates.any() else len(sp)
    end = first + (int(np.argmin(rates[first:])) if not rates[first:].all() else len(sp) - first)
    run = sp[first:end]
    answered = np.searchsorted(att[:, 0], run[:, 0], side="right") - 1  # the latest ATTITUDE recorded before each
    run, sample = run[answered >= 0], att[answered[answered >= 0]]
    return sample[:, 7] / 1000.0, sample[:, 4:7], run[:, 2:5]


def engaged_cycles(rows) -> tuple[list, str]:
    """(the controller's cycles up to the first failsafe, that failsafe's name or ""): a flight ended by a failsafe
    is fitted on what it flew before it (the level hold and hand-back after it are not the law's)."""
    from .bridge.record.flight_log import ENGAGED_PHASE

    cycles = []
    for r in rows:
        if r.sample.failsafe is not None:
            return cycles, r.sample.failsafe.name
        if r.phase == ENGAGED_PHASE and r.sample.failsafe is None and math.isfinite(r.sample.u_nm[0]):
            cycles.append(r.sample)
    return cycles, ""


def _tau_is_no_loop_constant(axis: int, rec: LoopRecord) -> bool:
    return tau_is_no_loop_constant(axis, rec.yaw_from_reference, rec.roll_pitch_integrated)


def proposed_time_constants(result: Identification) -> list[float | None]:
    """The ``offboard_loop.rate_time_constant_s`` to fly: tau_eff where proposed, the flown value elsewhere (None
    for an axis of a .tlog: it does not record what was flown)."""
    return [round(x, 3) if use else None if result.kind == "tlog" else flown
            for x, use, flown in zip(result.tau_eff_s, result.proposed, result.flown.rate_time_constant_s)]


# ----------------------------------------------------------------------------- the command
def configure(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Identify, from a flight flown with --log, how much of the body acceleration the controller asked for the "
        "vehicle realised through its autopilot's rate loop (control effectiveness k and delay L per axis), and "
        "the rate-loop time constant the torque->rate mapping should use (tau_b / k). Fly once with any vehicle "
        "description (e.g. the default), identify, then fly with --set mapping.rate_time_constant_s=[...] or a "
        "description carrying the value. Details: docs/bridge.md, 'Identifying the loop'.")
    p.add_argument("log", metavar="LOG", help="flight CSV written by --log (its .json sidecar must sit beside it), its .tlog "
                   "(the CSV beside it is read; alone, roll and pitch are fitted from the rates sent), or the --log "
                   "folder (its newest flight). A flight ended by a failsafe is fitted on the cycles before it; an axis "
                   "the data cannot determine says why")
    p.add_argument("--window-ms", type=float, default=DEFAULT_WINDOW_S * 1000.0,
                   help="integration window h of the fit [ms] (default: %(default)s)")
    p.add_argument("--max-delay-ms", type=float, default=DEFAULT_MAX_DELAY_S * 1000.0,
                   help="largest delay L tried [ms] (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print the fit as JSON instead of a table")


def run(args) -> int:
    if not (math.isfinite(args.window_ms) and args.window_ms > 0 and math.isfinite(args.max_delay_ms) and args.max_delay_ms >= 0):
        raise ConfigError(f"--window-ms {args.window_ms} must be > 0 and --max-delay-ms {args.max_delay_ms} >= 0")
    from .flight_plot import find_log

    log, kind = find_log(args.log)
    fit = identify_tlog if kind == "tlog" else identify_flight
    result = fit(log, args.window_ms / 1000.0, args.max_delay_ms / 1000.0)
    tau_fly = proposed_time_constants(result)
    if args.json:
        print(json.dumps({"log": str(result.source), "kind": result.kind, "vehicle": result.vehicle, "rate_time_constant_s": tau_fly,
                          "cycles": result.cycles, "engaged_s": result.engaged_s, "ended_by": result.ended_by or None,
                          "axes": {a: {"effectiveness": f.effectiveness, "delay_s": f.delay_s, "r2": f.r2, "windows": f.windows,
                                       "flown_tau_s": None if result.kind == "tlog" else ft, "tau_eff_s": te, "proposed": use, "why_not": result.why_not(i)}
                                   for i, (a, f, ft, te, use) in enumerate(zip(AXES, result.fits, result.flown.rate_time_constant_s,
                                                                               result.tau_eff_s, result.proposed))}}))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"rate loop identified from {result.source.name} (flown as {result.vehicle or 'unknown'})")
    for col in ("axis", "tau flown [s]", "k [-]", "L [s]", "R² [-]", "tau_eff [s]", "proposed"):
        table.add_column(col, justify="left" if col in ("axis", "proposed") else "right")
    for i, (a, f, ft, te, use) in enumerate(zip(AXES, result.fits, result.flown.rate_time_constant_s, result.tau_eff_s, result.proposed)):
        why = ("yes" if use else ("no (M6)" if i == 2 else "no (M9)") if _tau_is_no_loop_constant(i, result.flown)
               else "no (not fitted)" if f.why_not else f"no (R² < {MIN_FIT_R2})")
        why = "no (.tlog)" if result.kind == "tlog" and i == 2 else why
        flown = "-" if result.kind == "tlog" else f"{ft:.3f}"
        table.add_row(a, flown, f"{f.effectiveness:.2f}", f"{f.delay_s:.3f}", f"{f.r2:.2f}", f"{te:.3f}", why)
    console = Console()
    say = lambda text: console.print(text, markup=False, highlight=False)  # noqa: E731
    say(f"fitted on {result.cycles} controller cycles ({result.engaged_s:.2f} s)"
        + (f", up to the {result.ended_by} failsafe that ended the flight" if result.ended_by else "")
        + (" from the .tlog alone: the law's acceleration read back from the rates sent, a = (omega_cmd - omega) / "
           f"{TLOG_TAU_B_S:g} s, so k is per second of rate error" if result.kind == "tlog" else ""))
    console.print(table)
    for i, a in enumerate(AXES):
        if result.fits[i].why_not:
            say(f"{a}: not fitted: {result.fits[i].why_not}")
    say("k: realised / commanded body acceleration; L: delay; tau_eff = tau flown / k (eq. I2 of mavastsm.identify)."
        + (" Yaw is built on the reference (M6): tau_z is a tuning gain there, not a loop time constant."
           if result.flown.yaw_from_reference else ""))
    if result.kind == "tlog":
        say(f"{AXES[2]}: not proposed: {result.why_not(2)}. Roll and pitch: tau_eff is the mapping's time constant where "
            "they are built on the measured rates (M2); flown integrated (M9, the Solo's description) it is no mapping gain.")
    say(f"fly with: --set mapping.rate_time_constant_s=[{','.join('TAU' if x is None else f'{x:g}' for x in tau_fly)}]  "
        + ("(TAU: your description's value) " if None in tau_fly else "")
        + "(or put the value in the vehicle description's offboard_loop.rate_time_constant_s)")
    return 0
