"""The session: what the bridge does with each sample over a flight.

``sample_stage`` (the state stage: dt, duplicates, restarts, rates) -> ``offboard_session`` (the state machine:
engagement, failsafes, the level hold) -> ``session_output`` (the setpoint gate and the record of each sample);
``session_counters``, its counts in one record. Drives the cycle and writes the record; never opens the link.
"""
