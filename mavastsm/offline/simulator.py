"""Offline paper-mode simulator: many (controller, scenario, inertia) runs integrated as one batch.

Every run shares the controller period T and the time grid; runs with the same controller (key, preset,
overrides) share one batched controller instance (per-row nominal inertia I0 and swept gains are set on
it), and all rows share one vectorised RK4
plant (``plant.py``). The controller is sampled at T and held (ZOH); the plant is integrated with RK4
substeps of at most ``max_substep_s`` (0.25 ms default). No motor dynamics (paper mode);
optional torque limits are a controller option (``torque_limit_enabled``); optional white sensor noise on
what the controller sees (``RunSpec.sensor_noise_std``, drawn from each run's own seed).

Inside the loop nothing raises: a non-finite controller output is replaced by zero torque and counted
(``RunResult.nonfinite_outputs``); a run whose body rate exceeds DIVERGED_RATE_RADS or turns non-finite is
frozen at its last state and reported (``RunResult.diverged_at_s``).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..config_loading import per_axis
from ..control import make_controller
from ..control.controller_interface import TrackingError, tracking_error
from ..errors import ConfigError
from ..frames import wrap_angle
from ..scenarios import Scenario
from ..solo_model import SoloRigidBody, load_solo
from .plant import Rk4AttitudePlant

DIVERGED_RATE_RADS = 1.0e3  # |omega| above this (about 160 rev/s) means the run has diverged
RECORD_BLOCK = 32  # steps recorded time-major before they are copied run-major (see simulate_runs)


@dataclass(frozen=True)
class RunSpec:
    """One simulation run.

    Attributes
    ----------
    controller : registry key (``astsm``, ``pid``, ...)
    scenario : Scenario
    config : controller preset name or YAML path (None = the class default)
    overrides : controller parameter overrides (validated against the YAML)
    inertia_variant : 'corrected' | 'paper_literal' (Table 1 Iyy); sets I0 and the plant's base inertia
    label : display name (default ``controller`` or ``controller[config]``)
    gain_matrix : optional per-run gain arrays for batched gain sweeps (see StsmController.set_gains)
    sensor_noise_std : (attitude [rad], body rate [rad/s]) std of white noise on what the controller sees
        (the plant and the recorded histories stay noise-free); (0, 0) = none
    noise_seed : seed of this run's own noise generator (same noise whatever the batch it runs in)
    """

    controller: str
    scenario: Scenario
    config: str | None = None
    overrides: Mapping[str, Any] | None = None
    inertia_variant: str = "corrected"
    label: str = ""
    gain_matrix: Mapping[str, tuple] | None = None
    sensor_noise_std: tuple[float, float] = (0.0, 0.0)
    noise_seed: int = 0

    @property
    def display(self) -> str:
        return self.label or (f"{self.controller}[{self.config}]" if self.config else self.controller)


@dataclass
class RunResult:
    """Time histories of one run at the controller sample times (arrays (n, 3) unless noted).

    From ``simulate_runs`` the recorded histories (euler_rad, omega_rads, u_nm, alpha, sigma) are views into one
    run-major array of the batch (no per-run copy): copy them before changing them in place.

    t_s (n,) [s]; euler_rad, ref_rad [rad]; omega_rads [rad/s body FRD]; u_nm [N m] (held over each
    period); dist_nm [N m] at the sample times; alpha, sigma: controller diagnostics (NaN when the law
    has none).
    """

    spec: RunSpec
    dt_s: float
    t_s: np.ndarray
    euler_rad: np.ndarray
    ref_rad: np.ndarray
    omega_rads: np.ndarray
    u_nm: np.ndarray
    dist_nm: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray
    alpha_min: tuple = (float("nan"),) * 3  # per axis (ASTSM's alpha_m; NaN for laws without an adaptive gain)
    mu: tuple = (float("nan"),) * 3  # per axis [rad/s]
    nonfinite_outputs: int = 0
    diverged_at_s: float = float("nan")
    metrics: dict = field(default_factory=dict)

    @property
    def error_rad(self) -> np.ndarray:
        """e = Theta - Theta_d [rad] with the yaw component wrapped to (-pi, pi]."""
        e = self.euler_rad - self.ref_rad
        e[:, 2] = wrap_angle(e[:, 2])
        return e


@contextlib.contextmanager
def _small_pages():
    """Arrays allocated inside are not advised to use transparent huge pages (NumPy advises it for every array of
    4 MB or more; the same as ``NUMPY_MADVISE_HUGEPAGE=0`` for these arrays only). The histories are written once and
    read once: with the kernel's default ``defrag = madvise`` a fresh process waits for huge pages to be compacted,
    0.8 s against 0.12 s for the first touch of 300 MB on the 2-core machine of docs/sweep.md. Values are unchanged."""
    core = getattr(np, "_core", None) or getattr(np, "core", None)  # NumPy 2 / 1.x
    toggle = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
    if toggle is None:
        yield
        return
    before = toggle(False)
    try:
        yield
    finally:
        toggle(before)


def _group_key(spec: RunSpec):
    ov = tuple(sorted((spec.overrides or {}).items(), key=lambda kv: kv[0]))
    ov = tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in ov)
    return (spec.controller, spec.config, ov)


def _measurement_noise(ordered: Sequence[RunSpec], n_steps: int) -> np.ndarray | None:
    """(n_steps, 6, n) white noise [rad, rad/s] per row from the row's own seed (state layout: step k is added to the
    state (6, n)), or None when no row has noise."""
    if not any(any(s.sensor_noise_std) for s in ordered):
        return None
    out = np.zeros((n_steps, 6, len(ordered)))
    for row, s in enumerate(ordered):
        att, gyro = s.sensor_noise_std
        if att or gyro:
            draw = np.random.default_rng(s.noise_seed).standard_normal((n_steps, 6))
            out[:, 0:3, row] = att * draw[:, 0:3]
            out[:, 3:6, row] = gyro * draw[:, 3:6]
    return out


def _batched_controllers(specs: Sequence[RunSpec], groups: dict[Any, list[int]], solos: dict[str, SoloRigidBody]) -> list:
    """One batched controller per group of ``specs`` (rows in ``groups`` order): [(row slice, controller)]. A group
    with several inertia variants gets per-row model I0; a group with gain matrices gets per-row gains (rows
    without one keep the configured gains)."""
    controllers = []
    start = 0
    for idx in groups.values():
        first = specs[idx[0]]
        ctrl = make_controller(first.controller, solos[first.inertia_variant], first.config, first.overrides, batch_shape=(len(idx),))
        variants = {specs[i].inertia_variant for i in idx}
        if len(variants) > 1 and hasattr(ctrl, "set_model_inertia"):  # one instance, per-row nominal model I0
            ctrl.set_model_inertia(np.array([solos[specs[i].inertia_variant].inertia_diag for i in idx]))
        swept = sorted({k for i in idx for k in (specs[i].gain_matrix or {})})
        if swept:  # batched gain sweep: rows without a gain_matrix keep the configured gains
            defaults = {k: np.broadcast_to(getattr(ctrl.gains, k), (3,)) for k in swept}
            ctrl.set_gains(**{k: np.array([(specs[i].gain_matrix or {}).get(k, defaults[k]) for i in idx]) for k in swept})
        controllers.append((slice(start, start + len(idx)), ctrl))
        start += len(idx)
    return controllers


@dataclass
class _BatchInputs:
    """What every run of a batch is fed: references and disturbance torques evaluated once per distinct one (a
    sweep's rows share a few) and gathered per step into the batch layout by index (a batch-sized copy of them
    costs more than the gathers), and each run's true inertia."""

    refs: np.ndarray  # time x (reference, rate, acceleration) x axis x distinct reference
    ref_idx: np.ndarray  # run -> its reference's index
    dist: np.ndarray  # half-substep time x axis x distinct disturbance [N m]
    dist_idx: np.ndarray  # run -> its disturbance's index
    inertia: np.ndarray  # run x 3 x 3 [kg m^2]


def _batch_inputs(ordered: Sequence[RunSpec], solos: dict[str, SoloRigidBody], t: np.ndarray, t_half: np.ndarray) -> _BatchInputs:
    n = len(ordered)
    refs: dict[int, tuple[int, Any]] = {}
    torques: dict[tuple, tuple[int, Scenario]] = {}
    ref_idx = np.empty(n, dtype=np.intp)
    dist_idx = np.empty(n, dtype=np.intp)
    inertia = np.empty((n, 3, 3))
    for row, s in enumerate(ordered):
        ref_idx[row] = refs.setdefault(id(s.scenario.reference), (len(refs), s.scenario.reference))[0]
        dist_idx[row] = torques.setdefault(s.scenario.disturbances, (len(torques), s.scenario))[0]
        inertia[row] = s.scenario.true_inertia(solos[s.inertia_variant].inertia_diag)
    # time x (reference, rate, acceleration) x axis x distinct: a step's gather is axis-first like the state
    distinct_refs = np.empty((t.size, 3, 3, len(refs)))
    for j, reference in refs.values():
        distinct_refs[:, :, :, j] = np.stack(reference.at(t), axis=1)
    distinct_dist = np.empty((t_half.size, 3, len(torques)))
    for j, scenario in torques.values():
        distinct_dist[:, :, j] = scenario.disturbance_torque_nm(t_half)
    return _BatchInputs(distinct_refs, ref_idx, distinct_dist, dist_idx, inertia)


def simulate_runs(
    specs: Sequence[RunSpec],
    dt_control_s: float = 1e-3,
    max_substep_s: float = 2.5e-4,
    exact_kinematics: bool = True,
    progress: Callable[[float], None] | None = None,
    solo_config: str | None = None,
) -> list[RunResult]:
    """Simulate all ``specs`` as one vectorised batch; returns one RunResult per spec (same order).

    Parameters
    ----------
    dt_control_s : [s] controller period T (ZOH), > 0. 1 ms default; 2.5 ms = ArduCopter's 400 Hz loop
    max_substep_s : [s] largest RK4 step; the plant uses ceil(T / max_substep_s) substeps per period
    exact_kinematics : exact ZYX Euler kinematics (default) or the paper's Theta_dot = omega
    progress : optional callback with the completed fraction in [0, 1] (called ~50 times)
    """
    if not (np.isfinite(dt_control_s) and dt_control_s > 0):
        raise ConfigError(f"controller period dt = {dt_control_s!r} s breaks rule: must be > 0")
    if not (np.isfinite(max_substep_s) and max_substep_s > 0):
        raise ConfigError(f"RK4 substep = {max_substep_s!r} s breaks rule: must be > 0")
    if not specs:
        return []
    solos: dict[str, SoloRigidBody] = {}
    for s in specs:
        if s.inertia_variant not in solos:
            solos[s.inertia_variant] = load_solo(solo_config, s.inertia_variant)
    # order rows so every controller group is a contiguous slice (views, not copies, in the loop)
    groups: dict[Any, list[int]] = {}
    for i, s in enumerate(specs):
        groups.setdefault(_group_key(s), []).append(i)
    order = [i for idx in groups.values() for i in idx]
    ordered = [specs[i] for i in order]
    controllers = _batched_controllers(specs, groups, solos)

    duration = max(s.scenario.duration_s for s in ordered)
    n_steps = int(round(duration / dt_control_s))
    n_sub = max(1, int(np.ceil(dt_control_s / max_substep_s - 1e-9)))
    h = dt_control_s / n_sub
    t = np.arange(n_steps) * dt_control_s
    inputs = _batch_inputs(ordered, solos, t, np.arange(2 * n_steps * n_sub + 1) * (0.5 * h))
    history = _fly_batch(controllers, inputs, Rk4AttitudePlant(inputs.inertia, exact_kinematics),
                         _measurement_noise(ordered, n_steps), t, dt_control_s, n_sub, progress)
    return _results(specs, order, controllers, inputs, history, t, dt_control_s, n_sub)


@dataclass
class _BatchHistory:
    """What ``_fly_batch`` recorded: histories run x time x axis, and per run how it ended."""

    rec: np.ndarray  # (euler, omega, u, alpha, sigma) x run x time x axis
    nonfinite: np.ndarray  # per run: control periods whose torque was not finite (replaced by 0)
    diverged_at: np.ndarray  # per run: [s] when it diverged, NaN when it did not


def _fly_batch(controllers, inputs: _BatchInputs, plant, noise, t: np.ndarray, dt_control_s: float, n_sub: int,
               progress: Callable[[float], None] | None) -> _BatchHistory:
    """The closed loop of every run at once: ZOH torque from each group's controller, ``n_sub`` RK4 substeps of
    the plant per period, a diverged run frozen at its last finite state."""
    n_steps, n = t.size, inputs.ref_idx.size
    h = dt_control_s / n_sub
    distinct_refs, ref_idx, distinct_dist, dist_idx = inputs.refs, inputs.ref_idx, inputs.dist, inputs.dist_idx
    x = np.zeros((6, n))  # [roll, pitch, yaw, p, q, r] x runs, all start at rest and level
    alive = np.ones(n, dtype=bool)
    diverged_at = np.full(n, np.nan)
    # histories are handed out run-major, run x time x axis. Each step writes contiguous rows of a small time-major
    # buffer of RECORD_BLOCK steps, and a full buffer is turned run-major in one copy: a run-major write per step
    # touches every run's page every step (TLB misses), and turning whole time-major histories around at the end
    # doubles the memory touched (slow on a fresh process, where every page is touched for the first time).
    with _small_pages():
        rec = np.empty((5, n, n_steps, 3))  # euler, omega, u, alpha, sigma
    block = min(RECORD_BLOCK, n_steps)
    buf = np.empty((block, 15, n))  # step in block x (euler, omega, u, alpha, sigma) rows x run; rows 0:6 = the state
    has_alpha = [("alpha" in c.diagnostics()) for _, c in controllers]
    has_sigma = [("sigma" in c.diagnostics()) for _, c in controllers]
    for gi, (sl, _) in enumerate(controllers):  # NaN where the law has no such diagnostic (never written)
        if not has_alpha[gi]:
            buf[:, 9:12, sl] = np.nan
        if not has_sigma[gi]:
            buf[:, 12:15, sl] = np.nan
    nonfinite = np.zeros(n, dtype=int)
    u = np.zeros((3, n)).T  # (n, 3) as the controllers return it, stored axis-first: u.T is the plant's (3, n)
    report_every = max(1, n_steps // 50)

    for k in range(n_steps):
        kb = k % block
        buf[kb, 0:6] = x
        euler, omega = x[0:3].T, x[3:6].T
        if noise is not None:  # the controller sees noisy measurements, the plant stays exact
            euler, omega = euler + noise[k, 0:3].T, omega + noise[k, 3:6].T
        ref_k = distinct_refs[k][:, :, ref_idx]  # (reference, rate, acceleration) x axis x run
        err = tracking_error(euler, omega, ref_k[0].T, ref_k[1].T, ref_k[2].T)
        for gi, (sl, ctrl) in enumerate(controllers):
            part = TrackingError(err.angle_error_rad[sl], err.euler_rate_error_rads[sl], err.ref_euler_accel_radss[sl], err.body_rates_rads[sl], err.euler_rad[sl], err.ref_euler_rate_rads[sl])
            u[sl] = ctrl.update(part, dt_control_s)
            if has_alpha[gi] or has_sigma[gi]:
                d = ctrl.diagnostics()
                if has_alpha[gi]:
                    buf[kb, 9:12, sl] = d["alpha"].T
                if has_sigma[gi]:
                    buf[kb, 12:15, sl] = d["sigma"].T
        if not np.isfinite(u).all():
            bad = ~np.isfinite(u)
            nonfinite += bad.any(axis=1)
            u[bad] = 0.0
        ut = u.T
        buf[kb, 6:9] = ut
        base = 2 * k * n_sub
        x_prev = x
        with np.errstate(all="ignore"):
            for j in range(n_sub):
                i0 = base + 2 * j
                d = distinct_dist[i0 : i0 + 3][:, :, dist_idx]  # d at t, t + h/2, t + h: (3, 3, n)
                x = plant.step(x, ut, d[0], d[1], d[2], h)
            # fast path: one reduction over the whole batch (NaN fails the comparison); per run only when it fails
            healthy = np.max(np.abs(x[3:6])) < DIVERGED_RATE_RADS and np.isfinite(x[0:3]).all()
            ok = None if healthy else np.all(np.isfinite(x), axis=0) & (np.max(np.abs(x[3:6]), axis=0) < DIVERGED_RATE_RADS)
        if ok is not None and not ok.all():  # freeze a diverged run at its last finite state and report when it happened
            newly = alive & ~ok
            diverged_at[newly] = t[k]
            alive &= ok
            x = np.where(alive, x, x_prev)
        if kb == block - 1 or k == n_steps - 1:  # buffer full (or last step): into the run-major histories
            rec[:, :, k - kb : k + 1] = buf[: kb + 1].reshape(kb + 1, 5, 3, n).transpose(1, 3, 0, 2)
        if progress is not None and (k % report_every == 0 or k == n_steps - 1):
            progress((k + 1) / n_steps)
    return _BatchHistory(rec, nonfinite, diverged_at)


def _results(specs: Sequence[RunSpec], order: list[int], controllers, inputs: _BatchInputs, history: _BatchHistory,
             t: np.ndarray, dt_control_s: float, n_sub: int) -> list[RunResult]:
    """One RunResult per spec (in ``specs`` order), each cut to its own scenario's duration."""
    rec_euler, rec_omega, rec_u, rec_alpha, rec_sigma = history.rec
    results: list[RunResult] = [None] * len(specs)  # type: ignore[list-item]
    dist_at_samples = inputs.dist[0 : 2 * t.size * n_sub : 2 * n_sub]
    for row, spec_index in enumerate(order):
        s = specs[spec_index]
        m = int(round(s.scenario.duration_s / dt_control_s))
        ctrl = next(c for sl, c in controllers if sl.start <= row < sl.stop)
        gains = getattr(ctrl, "gains", None)
        results[spec_index] = RunResult(
            spec=s,
            dt_s=dt_control_s,
            t_s=t[:m].copy(),
            euler_rad=rec_euler[row, :m],
            ref_rad=inputs.refs[:m, 0, :, inputs.ref_idx[row]].copy(),
            omega_rads=rec_omega[row, :m],
            u_nm=rec_u[row, :m],
            dist_nm=dist_at_samples[:m, :, inputs.dist_idx[row]].copy(),
            alpha=rec_alpha[row, :m],
            sigma=rec_sigma[row, :m],
            alpha_min=per_axis(getattr(gains, "alpha_min", np.nan)),
            mu=per_axis(getattr(gains, "mu", np.nan)),
            nonfinite_outputs=int(history.nonfinite[row]),
            diverged_at_s=float(history.diverged_at[row]),
        )
    return results

