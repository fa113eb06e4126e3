"""Plain one-line status, printed once per second when the Live view is off (``--no-dashboard``,
pipes, CI, systemd). Pure: ``TelemetrySnapshot`` in, ``str`` out (no colour, no control codes)."""

from __future__ import annotations

from ..telemetry import TelemetrySnapshot
from .panels import AXES, fmt, fmt_deg, fmt_ms


def format_status_line(snapshot: TelemetrySnapshot) -> str:
    """One line, e.g.::

        t=12.34s GUIDED ARMED ATT 398/400Hz p50 0.41 ms p99 1.20 ms cycles 4936 missed 0 drop 0 |
        e[deg] roll +0.12 pitch -0.05 yaw +0.30 | sigma[rad/s] ... | alpha ... | u[N.m] ... | failsafe none
    """
    link, s = snapshot.link, snapshot.latest
    parts = []
    parts.append(f"t={fmt(s.vehicle_time_s, '.2f')}s" if s is not None else "t=—")
    parts.append(f"{link.mode or '—'} {'ARMED' if link.armed else 'disarmed'}")
    if link.phase:
        parts.append(f"[{link.phase}]")
    parts.append(f"ATT {fmt(link.attitude_rate_achieved_hz, '.0f')}/{fmt(link.attitude_rate_requested_hz, '.0f')}Hz")
    parts.append(f"p50 {fmt_ms(link.latency_p50_s)} p99 {fmt_ms(link.latency_p99_s)}")
    parts.append(f"cycles {link.cycles} missed {link.missed} drop {link.dropped} "
                 f"superseded {link.superseded} invalid {link.invalid} refused {link.refused_frames}")
    line = " ".join(parts)
    if s is not None:
        line += " | e[deg] " + " ".join(f"{a} {fmt_deg(v)}" for a, v in zip(AXES, s.error_rad))
        line += " | sigma[rad/s] " + " ".join(fmt(v, "+.4f") for v in s.sigma)
        line += " | alpha " + " ".join(fmt(v, ".3g") for v in s.alpha)
        line += " | u[N.m] " + " ".join(fmt(v, "+.3g") for v in s.u_nm)
        line += " | cmd[deg/s] " + " ".join(fmt_deg(v, "+.1f") for v in s.commanded_rates_rads)
    fs = snapshot.active_failsafe
    line += f" | failsafe {fs.label if fs is not None else 'none'}"
    return line
