"""The link: the pymavlink side of the bridge.

``mavlink_link`` (the socket, signing, datagram handling, the receive thread) and its request/reply half
``vehicle_requests``; ``messages``, the typed messages in (ATTITUDE -> ``AttitudeSample``, HEARTBEAT, ...) and out
(``Setpoint``, one SET_ATTITUDE_TARGET); ``vehicle_clock``, which frames belong to the vehicle's clock. Imports
nothing else of the bridge.
"""
