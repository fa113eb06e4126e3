"""The dashboard's drawing process: ``python -m mavastsm.dashboard.render_process``.

Why a separate process: building and drawing one frame with rich is many control periods of pure Python
(docs/dashboard.md has the measurement).
In the bridge's process that time is spent holding the interpreter lock, and a 400 Hz control
thread waiting for the lock shows it directly in its latency tail (measured in
``tests/dashboard/test_dashboard_loop_impact.py`` and docs/dashboard.md). Here the bridge side only
copies the new samples out of the ``TelemetryBuffer`` and pickles them (a small fraction of a frame's cost),
and this process does the drawing on the other core.

Protocol (stdin, a stream of pickles written by ``DashboardRunner``, trusted: parent only):
``("frame", FrameUpdate)`` adds samples and draws one frame unless ``draw`` is False; ``("stop", None)`` or end of stream draws the last
frame and exits. This process ignores SIGINT: Ctrl-C belongs to the bridge, which then closes the
stream. It never reads the keyboard (the parent does).
"""

from __future__ import annotations

import argparse
import pickle
import signal
import sys
from dataclasses import dataclass

from rich.console import Console
from rich.live import Live

from ..state_types import FailsafeReason
from ..telemetry import ControlSample, LinkStatus, SessionInfo, TelemetryBuffer
from .panels import HISTORY_WINDOW_S, build_view


@dataclass(frozen=True, slots=True)
class FrameUpdate:
    """What changed since the previous frame. ``link``/``session`` are None when unchanged."""

    samples: tuple[ControlSample, ...]
    link: LinkStatus | None
    session: SessionInfo | None
    active_failsafe: FailsafeReason | None
    paused: bool
    draw: bool = True  # False for the leading chunks of a large update
    messages: tuple[str, ...] = ()  # one-off lines printed above the view (DashboardRunner.print_line)


def apply_update(buffer: TelemetryBuffer, update: FrameUpdate) -> None:
    """Replay one update into the local buffer (the child's copy of the parent's telemetry)."""
    for sample in update.samples:
        buffer.publish(sample)
    if update.link is not None:
        buffer.set_link(update.link)
    if update.session is not None:
        buffer.set_session(update.session)
    buffer.active_failsafe = update.active_failsafe


def run_renderer(stream, console: Console, capacity: int, window_s: float) -> int:
    """Read updates from ``stream`` (binary) and draw them on ``console`` until stop or EOF."""
    buffer = TelemetryBuffer(capacity=capacity)
    paused = False
    errors = 0
    live = Live(console=console, auto_refresh=False, transient=False, redirect_stdout=False,
                redirect_stderr=False, vertical_overflow="crop")
    with live:
        while True:
            try:
                kind, payload = pickle.load(stream)
            except (EOFError, OSError, pickle.UnpicklingError):
                break
            if kind == "stop":
                break
            if kind != "frame":
                continue
            apply_update(buffer, payload)
            for message in payload.messages:
                console.print(message, markup=False, highlight=False, soft_wrap=True, emoji=False)
            paused = payload.paused
            if not payload.draw:
                continue
            try:
                width, height = console.size
                live.update(build_view(buffer.snapshot(), width, height, paused=paused, window_s=window_s),
                            refresh=True)
            except Exception:  # noqa: BLE001 - a bad frame must not end the dashboard
                errors += 1
    return 0 if errors == 0 else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mavastsm.dashboard.render_process",
                                     description="draw mavastsm dashboard frames read from stdin (internal)")
    parser.add_argument("--capacity", type=int, default=4000)
    parser.add_argument("--window-s", type=float, default=HISTORY_WINDOW_S)
    parser.add_argument("--width", type=int, default=None, help="fixed width (tests); default: terminal")
    parser.add_argument("--height", type=int, default=None, help="fixed height (tests); default: terminal")
    parser.add_argument("--force-terminal", action="store_true", help="draw even when stdout is not a TTY (tests)")
    parser.add_argument("--no-color", action="store_true")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    console = Console(width=args.width, height=args.height, force_terminal=True if args.force_terminal else None,
                      color_system=None if args.no_color else "auto")
    return run_renderer(sys.stdin.buffer, console, args.capacity, args.window_s)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
