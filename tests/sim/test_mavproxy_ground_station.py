"""A real ground station nobody here wrote (MAVProxy from PyPI) drives the simulated vehicle: it connects,
fetches all parameters, switches to GUIDED and arms. Assertions are on what the vehicle saw and did."""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

MAVPROXY = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent)) or shutil.which("mavproxy.py")


@pytest.fixture
def mavproxy(tmp_path):
    """Start MAVProxy (no GUI modules) against a port; yields a function that writes a console command and a
    queue of its output lines. Its whole process group is killed at teardown."""
    procs: list[subprocess.Popen] = []
    lines: queue.Queue[str] = queue.Queue()

    def start(port: int):
        env = dict(os.environ, HOME=str(tmp_path))  # no ~/.mavproxy of the user is read or written
        proc = subprocess.Popen([MAVPROXY, f"--master=udpout:127.0.0.1:{port}", f"--state-basedir={tmp_path}"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                cwd=tmp_path, env=env, start_new_session=True)
        procs.append(proc)
        threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()

        def command(text: str) -> None:
            proc.stdin.write(text + "\n")
            proc.stdin.flush()

        return command

    yield start, lines
    for proc in procs:
        for sig, wait_s in ((signal.SIGTERM, 1.0), (signal.SIGKILL, 5.0)):  # MAVProxy often ignores TERM
            try:
                os.killpg(proc.pid, sig)
                proc.wait(wait_s)
                break
            except (ProcessLookupError, subprocess.TimeoutExpired):
                continue


def wait_for_line(lines: queue.Queue, needle: str, timeout_s: float) -> str | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=max(deadline - time.monotonic(), 0.01))
        except queue.Empty:
            return None
        if needle in line:
            return line
    return None


def test_mavproxy_fetches_params_sets_guided_and_arms(make_server, mavproxy):
    assert MAVPROXY is not None, "mavproxy.py not found: MAVProxy is a test dependency (pip install '.[test]')"
    server = make_server(clock="realtime")
    start, lines = mavproxy
    command = start(server.port)
    assert server.wait_until(lambda c: server.counters.get("messages_in", 0) > 0, timeout_s=30.0), \
        "MAVProxy never talked to the vehicle"
    command("param fetch")
    count = server.call(lambda c: c.params.count)
    assert server.wait_until(lambda c: server.counters.get("param_values_sent", 0) >= count, timeout_s=20.0)
    assert wait_for_line(lines, f"Received {count} parameters", timeout_s=20.0) is not None
    command("mode GUIDED")
    assert server.wait_until(lambda c: c.mode_number == 4, timeout_s=15.0)
    command("arm throttle")
    assert server.wait_until(lambda c: c.armed, timeout_s=15.0)
    counters = server.counters
    assert counters["param_lists_requested"] >= 1 and counters["bad_input_total"] == 0
