"""Set-up for every test folder: MAVLink 2 in this process before any test module imports pymavlink.

pymavlink keeps one process-wide dialect (``mavutil.mavlink``), chosen when ``mavutil`` is first imported: MAVLink 1
unless MAVLINK20 is set. Test helpers that are MAVLink peers (tests/sim/mavlink_peer_tools.py,
tests/bridge/fake_autopilot.py, ...) set it and then bind that dialect at import, which only works when they are the
first importer. In CI's full run tests/autopilots, collected first, happened to set it; in a subset such as
``pytest tests --ignore=tests/autopilots`` a module importing ``mavastsm.bridge`` came first and five tests failed
on a MAVLink 1 dialect (signing, MISSION_REQUEST_LIST's mission_type). Set here, every subset sees what the full run
sees. The package itself never relies on it: the link selects MAVLink 2 when it opens a connection
(tests/bridge/test_link_mavlink2.py checks that in a fresh interpreter without MAVLINK20)."""

import os

os.environ.setdefault("MAVLINK20", "1")
