"""The cycle: one ATTITUDE sample in, one admitted setpoint out (pure math, no I/O).

``control_cycle`` runs reference shaping (``reference_shaping``) -> the law -> the mapping to body rates + thrust
(``setpoint_mapping``, with ArduCopter's hidden target in ``autopilot_target_model``) -> the gates (``safety``);
``loop_identification`` and ``loop_fit``, the in-flight identification phase. Reads the link's typed messages and
the autopilot's profile, never the link itself.
"""
