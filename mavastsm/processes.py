"""Processes the commands start and stop: ending a child's process group (the sim's genuine-autopilot launcher, the
bench and the tests stop what they started this one way), and a command's clean stop on Ctrl-C / SIGTERM."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
from typing import Callable, Iterator


def end_process_group(proc: subprocess.Popen | None, grace_s: float = 3.0) -> None:
    """SIGTERM ``proc``'s process group (started with ``start_new_session=True``), SIGKILL it if still alive after
    ``grace_s`` [s] (0: SIGKILL at once), and reap ``proc``. Never raises: a group already gone, or not ours to
    signal, is left as it is."""
    if proc is None or proc.poll() is not None:
        return
    for sig, wait_s in (((signal.SIGTERM, grace_s),) if grace_s > 0 else ()) + ((signal.SIGKILL, 5.0),):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            return
        try:
            proc.wait(wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


@contextlib.contextmanager
def stopping_on_signals(on_stop: Callable[[], None]) -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM call ``on_stop()`` (which asks for a clean stop) instead of ending the
    process; the previous handlers come back on leaving it. Python lets only the main thread set handlers: called
    from another thread (a test running the command in a thread), this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, lambda _signum, _frame: on_stop()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
