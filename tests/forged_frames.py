"""Frames an attacker without the signing key can send, shared by the bridge's and the sim's signing tests."""

from __future__ import annotations

import os


def forged_heartbeat(mavlink, src_system: int, src_component: int, link_id: int, timestamp: int, mav_type: int, autopilot: int) -> bytes:
    """A HEARTBEAT with a victim stream's identity and link id, the signed flag and ``timestamp``, signed with a
    random key: what anyone on the network can send without the key. ``mavlink`` is the dialect module."""
    attacker = mavlink.MAVLink(None, srcSystem=src_system, srcComponent=src_component)
    attacker.signing.secret_key = os.urandom(32)
    attacker.signing.sign_outgoing = True
    attacker.signing.link_id = link_id
    attacker.signing.timestamp = timestamp
    return bytes(attacker.heartbeat_encode(mav_type, autopilot, 0, 0, 0).pack(attacker))
