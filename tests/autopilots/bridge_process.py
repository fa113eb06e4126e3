"""A ``mavastsm`` command run inside a genuine SITL's network namespace, its output collected line by line.

Imported by name from the tests of this folder (never ``from conftest import``: with several conftest.py in
the suite, the name ``conftest`` may already be another folder's module)."""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

from mavastsm.readme_commands import readme_argv
from mavastsm_sim.genuine_sitl import NetNamespace

README_ARDUCOPTER = readme_argv("arducopter")  # the README's command (mavastsm.readme_commands)
TRACEBACK = re.compile(r"Traceback \(most recent call last\)|^\w+Error: ", re.M)


def mavastsm_executable() -> str:
    exe = Path(sys.executable).with_name("mavastsm")
    return str(exe) if exe.exists() else (shutil.which("mavastsm") or "mavastsm")


class BridgeProcess:
    """``mavastsm ARGS`` started inside a SITL's namespace, its output collected line by line."""

    def __init__(self, sitl, args: list[str]) -> None:
        self.args = args
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self.proc = subprocess.Popen(sitl.netns.command([mavastsm_executable(), *args]), stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True, bufsize=1)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()

    @property
    def output(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def wait_line(self, pattern: str, timeout_s: float) -> str:
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for line in self.lines:
                    if rx.search(line):
                        return line
                left = deadline - time.monotonic()
                if left <= 0 or self.proc.poll() is not None and not self._reader.is_alive():
                    raise AssertionError(f"bridge never printed /{pattern}/ within {timeout_s:g} s:\n{self.output[-3000:]}")
                self._cond.wait(min(left, 0.2))

    def wait(self, timeout_s: float) -> int:
        rc = self.proc.wait(timeout_s)
        self._reader.join(5.0)
        return rc

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5.0)


def assert_no_traceback(text: str) -> None:
    m = TRACEBACK.search(text)
    assert m is None, f"traceback in the bridge's output:\n{text[max(0, m.start() - 200):m.start() + 1500]}"


@contextmanager
def sim_pair_in_private_namespace(args: list[str]):
    """``mavastsm sim ARGS`` (a genuine pair, sim/genuine_pair.py) started inside a new private network namespace, as
    a user starts it on their machine; yields (the BridgeProcess, its rig), whose ``rig.netns`` starts more commands
    beside it.
    On leaving, SIGTERM (the pair's own clean stop, which ends the autopilot's process group), SIGKILL after 30 s."""
    rig = SimpleNamespace(netns=NetNamespace())
    sim = None
    try:
        sim = BridgeProcess(rig, args)
        yield sim, rig
    finally:
        if sim is not None and sim.proc.poll() is None:
            sim.signal(signal.SIGTERM)
            try:
                sim.wait(30.0)
            except subprocess.TimeoutExpired:
                sim.kill()
        rig.netns.close()
