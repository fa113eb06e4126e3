"""The bridge over a real serial device: a pseudo-terminal pair, with ``--baud``, against our sim.

The sim speaks UDP; a relay thread copies bytes between the pty's master side and the sim's socket, so the
bridge opens the slave side exactly as it opens /dev/ttyACM0 on a companion computer (pymavlink through
pyserial, a runtime dependency).
"""

from __future__ import annotations

import os
import select
import socket
import subprocess
import sys
import threading
import tty
from pathlib import Path

import pytest

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm_sim.vehicle_server import VehicleServer

pytestmark = pytest.mark.sitl


class PtyUdpRelay:
    """Bytes between a pty master and a UDP peer (the sim), both ways, until stopped."""

    def __init__(self, udp_port: int) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.device = os.ttyname(slave)
        self._slave = slave  # kept open so the master never sees EOF between the bridge's opens
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.connect(("127.0.0.1", udp_port))
        self.bytes_to_sim = self.bytes_to_bridge = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master, self.sock], [], [], 0.05)
            if self.master in ready:
                data = os.read(self.master, 4096)
                if data:
                    self.sock.send(data)
                    self.bytes_to_sim += len(data)
            if self.sock in ready:
                data = self.sock.recv(65536)
                os.write(self.master, data)
                self.bytes_to_bridge += len(data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for fd in (self.master, self._slave):
            os.close(fd)
        self.sock.close()


@pytest.fixture
def serial_sim():
    server = VehicleServer(clock="lockstep", listen=("127.0.0.1", 0))
    server.start()
    relay = PtyUdpRelay(server.port)
    try:
        yield server, relay
    finally:
        relay.close()
        server.stop()


def test_bridge_flies_the_sim_over_a_serial_device(serial_sim):
    server, relay = serial_sim
    opts = BridgeOptions(relay.device, baud=921600, controller="astsm", reference="hold", duration_s=1.0, mode="GUIDED_NOGPS",
                         arm=True, takeoff_alt_m=0.5, on_exit="LAND",
                         overrides={"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5})
    s = Bridge(opts).run()
    assert s.failsafe is None and s.end_reason == "duration complete", s.end_reason
    assert s.handback.startswith("LAND accepted"), s.handback
    assert s.cycles > 100 and relay.bytes_to_sim > 10_000 and relay.bytes_to_bridge > 10_000


def test_connect_command_opens_a_serial_device_with_baud(serial_sim):
    """The README's real-vehicle form, `mavastsm connect DEVICE --baud 921600 ...`, as a subprocess."""
    server, relay = serial_sim
    exe = Path(sys.executable).with_name("mavastsm")
    p = subprocess.run([str(exe), "connect", relay.device, "--baud", "921600", "--mode", "GUIDED_NOGPS", "--arm", "--takeoff", "0.5",
                        "--reference", "hold", "--duration", "1", "--on-exit", "LAND", "--no-dashboard",
                        "--set", "timing.prestream_s=0.2", "--set", "timing.overrun_cycles=2000", "--set", "timing.stale_timeout_s=0.5"],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    assert "end: duration complete; hand-back: LAND accepted" in p.stdout
    assert "No module named 'serial'" not in p.stdout + p.stderr
