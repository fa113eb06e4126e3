"""Process-wide runtime tuning for a process that runs the bridge, in one place, applied by the command line
(``connect``, ``demo``) and never by library classes: a program that embeds :class:`mavastsm.bridge.Bridge` owns
its interpreter settings and decides for itself (it can use this module the same way).

* ``timing.gil_switch_interval_s`` (bridge.yaml): ``sys.setswitchinterval`` while the bridge runs, so the control
  thread gets the interpreter lock back quickly from the supervisor, the log writer and the dashboard; restored
  on exit. This includes a dashboard that draws its Live view in a thread of this process
  (``DashboardRunner.draws_in_this_process``: an injected console, tests and screenshots), whose frames hold the
  lock for many control periods; the dashboard used to lower the interval itself, and no longer touches it.
* ``timing.gc_freeze_s``: while the bridge is engaged, ``gc.freeze()`` that often, so a full collection never
  scans the growing in-memory record (docs/bridge.md; bridge.yaml says why).
"""

from __future__ import annotations

import gc
import sys
import time


class ProcessTuning:
    """``apply()``/``restore()`` (or a ``with`` block) around the bridge's run; call :meth:`tick` from the loop that waits for the bridge."""

    def __init__(self, timing) -> None:
        self.switch_interval_s = float(timing.gil_switch_interval_s)
        self.gc_freeze_s = float(timing.gc_freeze_s)
        self._saved: float | None = None
        self._last_freeze = time.monotonic()
        self.freezes = 0

    def apply(self) -> "ProcessTuning":
        """Set the switch interval (saved for :meth:`restore`)."""
        if self.switch_interval_s > 0 and self._saved is None:
            self._saved = sys.getswitchinterval()
            sys.setswitchinterval(self.switch_interval_s)
        return self

    def restore(self) -> None:
        """Put the switch interval back (idempotent)."""
        if self._saved is not None:
            sys.setswitchinterval(self._saved)
            self._saved = None

    def __enter__(self) -> "ProcessTuning":
        return self.apply()

    def __exit__(self, *exc) -> None:
        self.restore()

    def tick(self, engaged: bool) -> None:
        """gc.freeze() at most every ``gc_freeze_s`` while ``engaged`` (0 = leave the collector alone)."""
        now = time.monotonic()
        if self.gc_freeze_s > 0 and engaged and now - self._last_freeze >= self.gc_freeze_s:
            gc.freeze()
            self._last_freeze = now
            self.freezes += 1


def run_tuned(bridge, poll_s: float = 0.2):
    """``bridge.run()`` as the command line runs it: with the process tuning applied, ticked and restored."""
    with ProcessTuning(bridge.config.timing) as tuning:
        bridge.start()
        while (summary := bridge.wait(poll_s)) is None:
            tuning.tick(bridge.state == "engaged")
    return summary
