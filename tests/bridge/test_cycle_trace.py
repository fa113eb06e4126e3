"""One engaged cycle, socket to socket, traced: each safety gate is entered once.

A lockstep pair (``mavastsm.lockstep_pair``) flies the paper's steps; after engagement a profiler
(``threading.setprofile``, installed before the bridge's threads start) records, in the bridge's reader thread, every
Python call and return and the socket calls, for a short window. A cycle is what lies between a ``recvmsg`` (or ``recvfrom``) and the
next ``sendto`` that contains the session's ``on_attitude`` and the control cycle's ``step``. In each such cycle
every safety function the data passes (the input gate ``attitude_sample_problem``, ``envelope_breach``,
``clip_reference_tilt``, ``last_setpoint_safe_rates``, the output gate ``OutputGate.admit`` and ``highest_priority``)
is entered exactly once, and nothing else of ``safety.py`` (the final check ``OutputGate.verify`` is for setpoints the
cycle did not admit); and from ``on_attitude`` on, the first call into the link is the send (the cycle never asks the
link for anything). The modules the cycle enters are printed, by floor of the bridge (docs/bridge.md, "One cycle, traced").
"""

from __future__ import annotations

import threading
import time
import pytest

GATES = {"attitude_sample_problem": 1, "envelope_breach": 1, "clip_reference_tilt": 1, "last_setpoint_safe_rates": 1,
         "admit": 1, "highest_priority": 1}
HELPERS = {"all_finite", "clamp", "<genexpr>", "predicted", "predicted_excursion_rad", "last_setpoint_rate_bound",
           "_quaternion_allowed", "__init__", "update", "_prune", "reason"}  # inside a gate, or the saturation monitor's


def _module(frame) -> str | None:
    """The project module a frame runs in (``mavastsm.bridge.cycle.safety``), by its name, so that an installed wheel and
    an editable checkout read alike; None for the standard library, pymavlink or generated code."""
    name = frame.f_globals.get("__name__", "")
    return name if name.split(".")[0] in ("mavastsm", "mavastsm_sim") else None


@pytest.mark.sitl
def test_one_engaged_cycle_enters_each_safety_gate_once(capsys):
    events: list[tuple[int, str, str | None, str]] = []
    recording = threading.Event()

    def profile(frame, event, arg):
        if not recording.is_set():
            return
        if event in ("call", "return"):
            events.append((threading.get_ident(), event, _module(frame), frame.f_code.co_name))
        elif event == "c_call":
            events.append((threading.get_ident(), event, None, getattr(arg, "__name__", "")))

    from mavastsm.lockstep_pair import LockstepPair

    threading.setprofile(profile)
    try:
        with LockstepPair(scenario="nominal", seed=1) as pair:
            pair.start()
            pair.start_bridge(mode="GUIDED", arm=True, takeoff_alt_m=0.5)
            deadline = time.monotonic() + 120.0
            while pair.engage_time_s is None and time.monotonic() < deadline:
                time.sleep(0.01)
            assert pair.engage_time_s is not None, "the bridge did not engage"
            time.sleep(0.3)
            recording.set()
            time.sleep(0.3)
            recording.clear()
    finally:
        threading.setprofile(None)

    reader = {t for t, _, _, name in events if name == "on_attitude"}
    assert len(reader) == 1, "on_attitude seen in more than one thread"
    seq = [(e, m, name) for t, e, m, name in events if t in reader]
    cycles = []
    start = None
    for i, (e, _, name) in enumerate(seq):
        if e == "c_call" and name in ("recvfrom", "recvmsg", "recv"):
            start = i
        elif e == "c_call" and name == "sendto" and start is not None:
            window = seq[start:i + 1]
            names = [n for ev, _, n in window if ev == "call"]
            if "on_attitude" in names and "step" in names:
                cycles.append(window)
            start = None
    assert cycles, "no complete engaged cycle in the recording"
    for window in cycles:
        entered: dict[str, int] = {}
        for e, m, name in window:
            if e == "call" and m == "mavastsm.bridge.cycle.safety" and name not in HELPERS:
                entered[name] = entered.get(name, 0) + 1
        assert entered == GATES, entered
        # one way: from the session's on_attitude to the send, the cycle calls nothing of the link (the latest
        # ATTITUDE_TARGET comes with the sample); the first link call after on_attitude is the send itself
        start = next(i for i, (e, _, name) in enumerate(window) if e == "call" and name == "on_attitude")
        link_calls = [name for e, m, name in window[start:] if e == "call" and m == "mavastsm.bridge.link.mavlink_link"]
        assert link_calls[:1] == ["send_setpoint"], link_calls
    modules = sorted({m for _, m, _ in cycles[0] if m is not None})
    by_floor: dict[str, list[str]] = {}
    for m in modules:
        parts = m.split(".")
        floor = parts[2] if parts[:2] == ["mavastsm", "bridge"] else ("law" if parts[:2] == ["mavastsm", "control"] else "shared")
        by_floor.setdefault(floor, []).append(parts[-1])
    with capsys.disabled():
        print(f"\none engaged cycle enters {len(modules)} modules of the project: "
              + "; ".join(f"{floor} {len(names)} ({', '.join(names)})" for floor, names in by_floor.items()))
