"""Fixtures for black-box tests of the simulated vehicle: a VehicleServer on an ephemeral loopback port and
plain pymavlink peers (``mavlink_peer_tools.py``) talking to it over real UDP. Everything is torn down even
when a test fails.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

sys.path.insert(0, str(Path(__file__).parent))  # --import-mode=importlib: make mavlink_peer_tools importable

from mavlink_peer_tools import Gcs  # noqa: E402

from mavastsm_sim.vehicle_server import VehicleServer  # noqa: E402


@pytest.fixture
def make_server() -> Iterator[Callable[..., VehicleServer]]:
    """Factory: a started VehicleServer listening on an ephemeral loopback port (lockstep by default)."""
    servers: list[VehicleServer] = []

    def factory(**kwargs: Any) -> VehicleServer:
        kwargs.setdefault("clock", "lockstep")
        kwargs.setdefault("listen", ("127.0.0.1", 0))
        server = VehicleServer(**kwargs)
        servers.append(server)
        return server.start()

    yield factory
    for server in servers:
        server.stop()
        assert server.error is None, f"simulation loop crashed: {server.error!r}"


@pytest.fixture
def make_gcs() -> Iterator[Callable[..., Gcs]]:
    """Factory: pymavlink peers connected to a port; closed at teardown."""
    peers: list[Gcs] = []

    def factory(port: int, **kwargs: Any) -> Gcs:
        gcs = Gcs(port, **kwargs)
        peers.append(gcs)
        return gcs

    yield factory
    for gcs in peers:
        gcs.close()


@pytest.fixture
def server_and_gcs(make_server, make_gcs):
    """A lockstep server and one GCS that has exchanged heartbeats with it."""
    server = make_server()
    gcs = make_gcs(server.port)
    gcs.hello()
    return server, gcs
