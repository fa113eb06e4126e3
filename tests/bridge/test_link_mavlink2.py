"""MAVLink 2 from the first byte, with no import-time environment change: importing the link (or the sim's
vehicle) leaves ``MAVLINK20`` alone; the link selects MAVLink 2 when it opens a connection, so its very first
frame (a HEARTBEAT, sent before anything is heard) starts with the MAVLink 2 magic 0xFD. Run in a fresh
interpreter, because other test modules set ``MAVLINK20`` for the whole process."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

PROBE = textwrap.dedent("""
    import os, socket
    assert "MAVLINK20" not in os.environ
    import mavastsm_sim.mavlink_vehicle as vehicle
    import mavastsm.bridge.link.mavlink_link as link_module
    from mavastsm.errors import LinkError
    assert "MAVLINK20" not in os.environ, "importing changed the environment"
    assert vehicle.mavlink.WIRE_PROTOCOL_VERSION == "2.0"
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(3.0)
    link = link_module.MavlinkLink(f"udpout:127.0.0.1:{peer.getsockname()[1]}", target_system=1)
    try:
        link.open(1.5)
    except LinkError:
        pass  # nobody answers: only the first frame matters
    finally:
        link.close()
    first, _ = peer.recvfrom(512)
    print(hex(first[0]), os.environ.get("MAVLINK20"))
""")


def test_link_speaks_mavlink2_from_its_first_frame_without_import_side_effects():
    env = {k: v for k, v in os.environ.items() if k != "MAVLINK20"}
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["0xfd", "1"]
