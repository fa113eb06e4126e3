"""From the paper's torque-level law to what the autopilot accepts (pure math, no I/O).

The controllers output a body torque u [N m] (paper eq. 18). Neither ArduCopter nor PX4 accepts
torques from a companion computer: SET_ATTITUDE_TARGET carries body rates [rad/s, FRD] plus a
thrust field. The autopilot's own rate loop sits between our command and the motors. We therefore

1. turn u into the body angular acceleration it would produce on the nominal rigid body
   (eqs. 6-7 / 12-14 with f(X) of eq. 17 evaluated at the measured body rates)::

       a = I0^-1 (u + f(omega)),   f(omega) = -omega x (I0 omega)

2. turn a into a body-rate command, by one of

   * ``first_order`` (default): model the autopilot's closed rate loop as omega_dot = (omega_cmd - omega)/tau
     and invert it: ``omega_cmd = omega + tau a``;
   * ``integrate``: ``omega_cmd[k] = omega_cmd[k-1] + a dt`` (the rate target is the integral of
     the commanded acceleration, started from the measured rate at engagement).

3. on ArduPilot (``first_order``, ``mapping.yaw_command_base = reference``, the default), build the yaw
   command on the reference's body yaw rate r_d instead of the measured r (M6 in docs/bridge.md)::

       r_cmd = r_d + tau_z a_z,   r_d = -sin(phi) theta_dot_d + cos(phi) cos(theta) psi_dot_d   (eq. 1)

   ArduCopter integrates every rate command into its own attitude target; with r_d as the base that
   target's heading follows the reference (plus tau_z times the integral of a_z), so ArduCopter's
   yaw angle and rate loops hold the heading against a yaw torque, and the controller trims the
   target. With the measured r as the base the target follows the vehicle wherever a torque turns it.

Thrust semantics are applied here and only here (``hold_thrust``, from the AutopilotProfile): ArduCopter's default
is a *climb rate* (0.5 = hold altitude), ArduCopter with GUID_OPTIONS bit 3 and PX4 take a
normalised *collective* (hover value configurable, optional tilt compensation).
"""

from __future__ import annotations

import math

from ..autopilots.profile import CLIMB_RATE, AutopilotProfile
from ..link.messages import TYPE_MASK_ATTITUDE, TYPE_MASK_RATES, ZERO_Q, Setpoint


def commanded_body_accel(torque_nm, body_rates_rads, inertia_diag) -> tuple[float, float, float]:
    """a = I0^-1 (u + f(omega)) [rad/s^2, body FRD], f = -omega x I0 omega (eq. 17), diagonal I0."""
    p, q, r = body_rates_rads
    ixx, iyy, izz = inertia_diag
    fx = (iyy - izz) * q * r
    fy = (izz - ixx) * p * r
    fz = (ixx - iyy) * p * q
    return ((torque_nm[0] + fx) / ixx, (torque_nm[1] + fy) / iyy, (torque_nm[2] + fz) / izz)


def rates_first_order(body_rates_rads, accel_radss, tau_s) -> tuple[float, float, float]:
    """omega_cmd = omega + tau a: inverse of a first-order rate loop omega_dot = (omega_cmd - omega)/tau (tau per axis)."""
    return tuple(w + t * a for w, a, t in zip(body_rates_rads, accel_radss, tau_s))  # type: ignore[return-value]


def rates_integrated(previous_cmd_rads, accel_radss, dt_s: float) -> tuple[float, float, float]:
    """omega_cmd[k] = omega_cmd[k-1] + a dt."""
    return tuple(w + a * dt_s for w, a in zip(previous_cmd_rads, accel_radss))  # type: ignore[return-value]


class RateMapping:
    """Stateful wrapper choosing the mapping method per axis (state only for integrated axes).

    Parameters
    ----------
    method : "first_order" | "integrate" | "integrate_lead" (every axis)
    inertia_diag : [kg m^2] nominal I0 (3,)
    tau_s : [s] assumed rate-loop time constant per axis (first_order); a scalar applies to all axes
    accel_limit_radss : [rad/s^2] (3,) clip of the commanded acceleration (the autopilot's
        ATC_ACCEL_R/P/Y_MAX rate shaping would otherwise distort the command); None = no clip
    integrated_axes : (3,) bool, with ``first_order``: axes whose command is its own integral instead
        (omega_cmd[k] = omega_cmd[k-1] + a dt; M9, ``mapping.roll_pitch_command_base: integrated``)
    """

    def __init__(self, method: str, inertia_diag, tau_s: float, accel_limit_radss=None, integrated_axes=(False, False, False)) -> None:
        if method not in ("first_order", "integrate", "integrate_lead"):
            raise ValueError(f"unknown mapping method {method!r}")
        self.lead = method == "integrate_lead"
        self.method = "integrate" if self.lead else method
        self.integrated = (True, True, True) if self.method == "integrate" else tuple(bool(x) for x in integrated_axes)
        self.inertia_diag = tuple(float(x) for x in inertia_diag)
        self.tau_s = tuple(float(t) for t in tau_s) if hasattr(tau_s, "__len__") else (float(tau_s),) * 3
        self.accel_limit = None if accel_limit_radss is None else tuple(float(x) for x in accel_limit_radss)
        self._cmd: tuple[float, float, float] | None = None

    def reset(self, body_rates_rads=None) -> None:
        """Forget the integrated rate target (it restarts from the measured rates)."""
        self._cmd = None if body_rates_rads is None else tuple(float(x) for x in body_rates_rads)  # type: ignore[assignment]

    def __call__(self, torque_nm, body_rates_rads, dt_s: float, base_rates_rads=None) -> tuple[float, float, float]:
        """Body-rate command [rad/s, FRD] for torque u [N m] at measured body rates [rad/s] after dt [s].

        ``base_rates_rads`` (first_order axes only): the rates the command is built around, omega_cmd =
        base + tau a; None = the measured rates (M2). ControlCycle passes the reference's yaw rate for M6.
        """
        accel = commanded_body_accel(torque_nm, body_rates_rads, self.inertia_diag)
        if self.accel_limit is not None:
            accel = tuple(min(max(a, -m), m) for a, m in zip(accel, self.accel_limit))
        base = body_rates_rads if base_rates_rads is None else base_rates_rads
        first_order = rates_first_order(base, accel, self.tau_s)
        if not any(self.integrated):
            return first_order
        prev = self._cmd if self._cmd is not None else tuple(body_rates_rads)
        cmd = rates_integrated(prev, accel, dt_s)
        self._cmd = cmd
        if self.lead:
            cmd = rates_first_order(cmd, accel, self.tau_s)
        return tuple(c if on else f for c, f, on in zip(cmd, first_order, self.integrated))  # type: ignore[return-value]

    def saturated_to(self, requested_cmd, sent_cmd) -> None:
        """Anti-windup (back-calculation): where the safety clamps cut the command, the integrated target loses the
        part that was not sent, so it never runs ahead of what the vehicle was told."""
        if self._cmd is not None and any(self.integrated):
            self._cmd = tuple(c - (r - s) if on else c for c, r, s, on in  # type: ignore[assignment]
                              zip(self._cmd, requested_cmd, sent_cmd, self.integrated))


STA_DESCRIBING_FUNCTION = 1.113  # first harmonic of sqrt|x| sgn(x) for x = A sin(wt): b1 = 1.113 sqrt(A)


def adaptive_gain_ceiling(mu_rads: float, loop_delay_s: float) -> float:
    """[rad/s^2] The largest super-twisting gain alpha (accel units) whose chattering through a loop with
    delay ``loop_delay_s`` stays inside the adaptation band ``mu_rads`` (eq. 34).

    Harmonic balance of v = -alpha sqrt|sigma| sgn(sigma) (eq. 25; describing function N(A) = 1.113 alpha / sqrt(A))
    with sigma_dot = v(t - L) (the autopilot's rate loop, its filters and the link as a delay L): the phase
    condition -pi/2 - w L = -pi gives w = pi / (2 L), the gain condition N(A) / w = 1 gives the limit cycle's
    amplitude in sigma, A = (2 * 1.113 alpha L / pi)^2 = (0.709 alpha L)^2. The adaptation (eq. 34) raises alpha
    while |sigma| > mu, so above A = mu, i.e. above alpha = sqrt(mu) / (0.709 L), the chattering it causes
    raises it further and alpha runs to its clamp: the limit cycle and unbounded alpha seen on genuine ArduCopter
    (docs/bridge.md, "Adaptive gain and loop delay"). Below it, alpha comes back to alpha_m after each transient.
    """
    return math.sqrt(mu_rads) * math.pi / (2.0 * STA_DESCRIBING_FUNCTION * loop_delay_s)


def switching_delay_s(mapping) -> tuple[float, float, float]:
    """[s] Per axis, the delay L that ``adaptive_gain_ceiling`` bounds the switching gain by: ``mapping.loop_delay_s``,
    plus the rate loop's time constant tau on an integrated axis (M9). There the command omega_cmd = integral of a is
    tracked by the autopilot's rate loop with its lag tau, which the first-order mapping's lead (omega + tau a, M2)
    used to cancel; the switching term sees both (measured on genuine ArduCopter with the Solo physics: the pitch
    axis, tau about 0.04 s, chattered 0.73-0.75 deg peak to peak with L = 0.04 s and held 0.13 deg with 0.08 s)."""
    tau = mapping.rate_time_constant_s
    return tuple(float(d) + (float(t) if on else 0.0)  # type: ignore[return-value]
                 for d, t, on in zip(mapping.loop_delay_s, tau, integrated_axes(mapping)))


def yaw_from_reference(method: str, yaw_command_base: str, profile: AutopilotProfile) -> bool:
    """True when the yaw command is built on the reference's yaw rate (M6): an autopilot with a hidden
    attitude target (ArduPilot), first_order, ``yaw_command_base == "reference"``. PX4 has no attitude target
    behind body-rate setpoints that could hold the heading, and ``integrate`` builds on its own integrated target."""
    return yaw_command_base == "reference" and method == "first_order" and profile.hidden_attitude_target


def yaw_trim_error(error_rad: float, band_rad: float, limit_rad: float) -> float:
    """[rad] The heading error M10 integrates into ArduCopter's attitude target (docs/bridge.md, eq. M10): what lies
    beyond +-``band_rad`` (so the hold's own wobble and the law's small steady error are left alone), bounded at
    ``limit_rad`` (so a large excursion does not wind the target up by its whole integral), with the error's sign."""
    beyond = min(max(abs(error_rad) - band_rad, 0.0), limit_rad)
    return math.copysign(beyond, error_rad)


def integrated_axes(mapping) -> tuple[bool, bool, bool]:
    """Per axis: is the rate command its own integral, omega_cmd[k] = omega_cmd[k-1] + a dt (M9: roll and pitch with
    ``mapping.roll_pitch_command_base: integrated``, or every axis with ``mapping.method: integrate``)?"""
    if mapping.method != "first_order":
        return (True, True, True)
    rp = mapping.roll_pitch_command_base == "integrated"
    return (rp, rp, False)


def tilt_factor(roll_rad: float, pitch_rad: float, max_factor: float) -> float:
    """1 / (cos roll cos pitch), bounded to [1, max_factor] (vertical thrust kept while tilted)."""
    c = math.cos(roll_rad) * math.cos(pitch_rad)
    if c <= 1.0 / max_factor:
        return max_factor
    return 1.0 / c


def hold_thrust(profile: AutopilotProfile, roll_rad: float = 0.0, pitch_rad: float = 0.0, tilt_compensation: bool = True, max_tilt_factor: float = 1.5) -> float:
    """Thrust field that holds altitude: 0.5 climb rate, or hover collective (tilt-compensated)."""
    if profile.thrust_semantics == CLIMB_RATE:
        return profile.hover_thrust_norm
    if not tilt_compensation:
        return profile.hover_thrust_norm
    return profile.hover_thrust_norm * tilt_factor(roll_rad, pitch_rad, max_tilt_factor)


class AltitudeHold:
    """Bounded vertical PID for a *collective* thrust field (PX4, or ArduCopter with GUID_OPTIONS bit 3), which
    unlike ArduCopter's climb-rate thrust holds nothing by itself: at PX4's MPC_THR_HOVER alone SIH's quadx
    sank 1.8 m in 3 s. Pure math; NED (z down, vz down) in, a collective offset [0..1 units] out::

        delta = clip(kp (z - z_ref) + kd vz + ki integral(z - z_ref), -max_delta, max_delta)

    added to the tilt-compensated hover collective. The integral (bounded to ``max_delta``) absorbs the
    hover-thrust error; ``z_ref`` is the altitude at engagement.

    Parameters
    ----------
    kp : [1/m] collective per metre below the reference
    ki : [1/(m s)] integral gain
    kd : [s/m] collective per m/s of descent
    max_delta : [-] bound of the offset (and of the integral's share)
    """

    def __init__(self, kp: float, ki: float, kd: float, max_delta: float) -> None:
        self.kp, self.ki, self.kd, self.max_delta = float(kp), float(ki), float(kd), float(max_delta)
        self.z_ref: float | None = None
        self._integral = 0.0

    def reset(self, z_ref_m: float | None) -> None:
        self.z_ref = z_ref_m
        self._integral = 0.0

    def __call__(self, z_m: float, vz_ms: float, dt_s: float) -> float:
        """Collective offset for NED altitude ``z_m`` [m, down] and vertical speed ``vz_ms`` [m/s, down]."""
        if self.z_ref is None or not (math.isfinite(z_m) and math.isfinite(vz_ms)):
            return 0.0
        err = z_m - self.z_ref  # > 0: below the reference
        if self.ki > 0.0:
            self._integral = min(max(self._integral + self.ki * err * dt_s, -self.max_delta), self.max_delta)
        delta = self.kp * err + self.kd * vz_ms + self._integral
        return min(max(delta, -self.max_delta), self.max_delta)


def rate_setpoint(body_rates_rads, thrust_norm: float) -> Setpoint:
    """Body rates + thrust, quaternion ignored (type_mask 0x80)."""
    return Setpoint(TYPE_MASK_RATES, ZERO_Q, tuple(float(x) for x in body_rates_rads), float(thrust_norm))  # type: ignore[arg-type]


def level_hold_setpoint(yaw_rad: float, thrust_norm: float) -> Setpoint:
    """Level attitude at the given heading + thrust (type_mask 0x07, rates ignored).

    Why not 0x87: with a zero quaternion ArduCopter commands zero body rates, i.e. it holds the
    *current* attitude, which is not level after an envelope breach. A level quaternion at the
    current yaw is what "level hold" means and is accepted by ArduCopter 4.2+ and PX4.
    """
    h = 0.5 * yaw_rad
    return Setpoint(TYPE_MASK_ATTITUDE, (math.cos(h), 0.0, 0.0, math.sin(h)), (0.0, 0.0, 0.0), float(thrust_norm))


TAKEOFF_CREEP = 0.1  # the least share of the climb thrust's excess the approach keeps: the climb always arrives


def takeoff_approach(distance_left_m: float, approach_m: float) -> float:
    """The share in [TAKEOFF_CREEP, 1] of the takeoff climb thrust's excess over the zero-climb thrust, ``distance_left_m``
    [m] below the takeoff altitude: 1 farther than ``approach_m``, then in proportion to the distance left. With a
    climb-rate thrust this is a climb rate proportional to the height still to go (a first-order approach at
    full climb rate / approach_m: about 1.3 s^-1 for genuine ArduCopter's 1.3 m/s over the default 1 m), so the
    autopilot never has to brake from full climb at the target (genuine ArduCopter's own deceleration overshot 2 m by
    0.78-0.80 m; docs/bridge.md, "Takeoff: the approach"). 1 when the distance is unknown (NaN) or ``approach_m`` is 0."""
    if approach_m <= 0.0 or not math.isfinite(distance_left_m):
        return 1.0
    return min(1.0, max(TAKEOFF_CREEP, distance_left_m / approach_m))
