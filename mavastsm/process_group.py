"""Ending a child process started with ``start_new_session=True``: the one way the sim's genuine-autopilot launcher,
the bench and the tests stop what they started (the child and everything it spawned share its process group)."""

from __future__ import annotations

import os
import signal
import subprocess


def end_process_group(proc: subprocess.Popen | None, grace_s: float = 3.0) -> None:
    """SIGTERM ``proc``'s process group, SIGKILL it if still alive after ``grace_s`` [s] (0: SIGKILL at once), and
    reap ``proc``. Never raises: a group already gone, or not ours to signal, is left as it is."""
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
