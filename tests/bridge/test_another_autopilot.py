"""A third autopilot added exactly as docs/bridge.md "Another autopilot" says: one adapter file plus one registry line.

The adapter is the code block of that section, taken from the docs as written (``forkpilot_adapter.py``: an
ArduCopter derivative whose HEARTBEAT names MAV_AUTOPILOT_GENERIC, 0), installed the way ``pip install`` of its
distribution would (a ``.dist-info`` whose ``entry_points.txt`` holds the one registry line, on PYTHONPATH); no file
of the package is touched. ``mavastsm sim --set heartbeat_autopilot=0`` stands in for the vehicle, and
``mavastsm connect`` flies it through the adapter: takeoff, the flight, the LAND hand-back. Without the adapter the
same vehicle is refused at preflight in one line naming its id and the adapters known.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAVASTSM = str(Path(sys.executable).with_name("mavastsm"))  # the console script pip installs
REGISTRY_LINE = "forkpilot = forkpilot_adapter:ADAPTER"


def _docs_adapter() -> str:
    """The adapter of docs/bridge.md, "Another autopilot", as printed there."""
    section = (ROOT / "docs" / "bridge.md").read_text(encoding="utf-8").split("### Another autopilot", 1)[1]
    block = re.search(r"```python\n(# forkpilot_adapter\.py.*?)```", section, re.S)
    assert block, "docs/bridge.md 'Another autopilot' lost its forkpilot_adapter.py block"
    return block.group(1)


@pytest.fixture
def installed(tmp_path: Path) -> Path:
    """A site folder with the adapter module and its distribution's metadata: the one registry line."""
    site = tmp_path / "site"
    info = site / "forkpilot-0.1.dist-info"
    info.mkdir(parents=True)
    (site / "forkpilot_adapter.py").write_text(_docs_adapter(), encoding="utf-8")
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: forkpilot\nVersion: 0.1\n", encoding="utf-8")
    (info / "entry_points.txt").write_text(f"[mavastsm.autopilots]\n{REGISTRY_LINE}\n", encoding="utf-8")
    return site


def _env(site: Path | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(COLUMNS="160", PYTHONUNBUFFERED="1")
    if site is not None:
        env["PYTHONPATH"] = str(site)
    return env


def _fly(site: Path | None, log_dir: Path) -> tuple[int, str]:
    """``mavastsm sim`` announcing MAV_AUTOPILOT_GENERIC, and ``mavastsm connect`` flying it: (exit status, output)."""
    env = _env(site)
    procs = []
    try:
        sim = subprocess.Popen([MAVASTSM, "sim", "--listen", "127.0.0.1:0", "--lockstep", "--scenario", "nominal",
                                "--set", "heartbeat_autopilot=0"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
        procs.append(sim)
        first = sim.stdout.readline()
        port = re.search(r"udp 127\.0\.0\.1:(\d+)", first)
        assert port, f"sim did not print its port: {first!r}"
        bridge = subprocess.Popen([MAVASTSM, "connect", f"udpout:127.0.0.1:{port.group(1)}", "--mode", "GUIDED", "--arm",
                                   "--takeoff", "0.5", "--on-exit", "LAND", "--no-dashboard", "--log", str(log_dir),
                                   "--set", "timing.stale_timeout_s=0.5", "--set", "timing.overrun_cycles=100000"],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
        procs.append(bridge)
        out, err = bridge.communicate(timeout=150)
        return bridge.returncode, out + err
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
            p.communicate(timeout=20)


def test_the_registry_finds_the_installed_adapter_and_keeps_the_packaged_ones(installed):
    code = ("from mavastsm.bridge.autopilots import adapter_for, known_autopilots\n"
            "print(type(adapter_for(0)).__name__, adapter_for(3).name, adapter_for(12).name, '|', known_autopilots())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(installed), check=True).stdout
    assert out.split() [:3] == ["ForkPilotAdapter", "ArduPilot", "PX4"], out
    assert "ForkPilot (0), ArduPilot (3), PX4 (12)" in out, out


@pytest.mark.sitl
@pytest.mark.slow
def test_connect_flies_our_sim_through_the_docs_adapter(installed, tmp_path):
    status, out = _fly(installed, tmp_path)
    assert status == 0, f"connect exited {status}: {out[-2500:]}"
    assert "ForkPilot" in out and "climb rate, 0.5 holds altitude" in out, out[:3000]
    assert "end: duration complete" in out and "hand-back: LAND accepted" in out, out[-2000:]
    sidecar = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert sidecar["autopilot"] == "ForkPilot", sidecar


@pytest.mark.sitl
def test_without_the_adapter_the_vehicle_is_refused_in_one_line(tmp_path):
    status, out = _fly(None, tmp_path)
    assert status != 0, out[-2000:]
    refusal = [line for line in out.splitlines() if "no adapter for HEARTBEAT autopilot 0" in line]
    assert len(refusal) == 1 and "known: ArduPilot (3), PX4 (12)" in refusal[0], out[-2000:]
    assert "docs/bridge.md, 'Another autopilot'" in refusal[0], refusal
