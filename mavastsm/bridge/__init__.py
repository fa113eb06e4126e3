"""The offboard attitude bridge (``mavastsm connect``): ATTITUDE in, SET_ATTITUDE_TARGET body rates + thrust out.

Public API: :class:`Bridge`, :class:`BridgeOptions`, :class:`BridgeSummary` (see ``bridge_api`` and
docs/bridge.md). Only ``mavlink_link`` and its request/reply half ``vehicle_requests`` import pymavlink.
"""

from .bridge_api import Bridge, BridgeOptions
from .run_record import BridgeSummary

__all__ = ["Bridge", "BridgeOptions", "BridgeSummary"]
