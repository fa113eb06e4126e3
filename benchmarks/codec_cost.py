"""What a hand-written codec for the two hot messages could save: pymavlink's cost per ATTITUDE parsed and per
SET_ATTITUDE_TARGET encoded, against the floor a fast path could not go under (``struct`` on the payload alone,
no header, CRC or signature).

Issue 30 lists "a fast path for the two hot messages (decode ATTITUDE, encode and sign SET_ATTITUDE_TARGET)" as a
candidate for cutting the bridge's cycle. This measures the most it could save before anyone writes a second codec:
the parse is the bridge's own (``mavlink_datagram.parse_datagram`` on one datagram, as the link's reader does), the
encode is the link's (``set_attitude_target_encode`` + ``pack``), each unsigned and signed (MAVLink 2 signing, HMAC
SHA-256 per frame). CPU time of this process (``time.process_time``), best of 5; treat as +-20 %.

Run: ``python benchmarks/codec_cost.py [--calls N] [--cycle-cpu-us US]``; ``--cycle-cpu-us`` is the bridge's CPU per
cycle from ``mavastsm bench`` (docs/benchmarks.md), for the share column. Prints a table; asserts only that the
signed frames it times are accepted (a refused one would be timed on another path).
"""

from __future__ import annotations

import argparse
import struct
import time
import timeit

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavastsm.mavlink_datagram import parse_datagram

ATTITUDE_PAYLOAD = struct.Struct("<Iffffff")  # time_boot_ms, roll, pitch, yaw, rollspeed, pitchspeed, yawspeed
TARGET_PAYLOAD = struct.Struct("<I4fffffBBB")  # SET_ATTITUDE_TARGET in wire order (MAVLink 2 field reordering)


def cpu_us_per_call(fn, calls: int, repeats: int = 5) -> float:
    """Best of ``repeats`` runs of ``calls`` calls: CPU microseconds per call (``timeit`` on this process's CPU time)."""
    return min(timeit.repeat(fn, timer=time.process_time, number=calls, repeat=repeats)) / calls * 1e6


def _codec(signed: bool, system: int) -> mavlink.MAVLink:
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=1)
    mav.robust_parsing = True
    if signed:
        mav.signing.secret_key = bytes(range(32))
        mav.signing.link_id = 1
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = 1
    return mav


def measure(calls: int) -> list[tuple[str, float]]:
    rows = []
    for signed in (False, True):
        tag = "signed" if signed else "unsigned"
        vehicle, bridge = _codec(signed, 1), _codec(signed, 255)
        # a new frame per call: a signed frame parsed twice is a replay, refused on another path
        frames = iter([bytes(mavlink.MAVLink_attitude_message(1234 + k, 0.1, -0.2, 0.3, 0.01, 0.02, -0.03).pack(vehicle))
                       for k in range(5 * calls)])
        frame = next(frames)
        parsed = parse_datagram(bridge, frame)[0]
        assert parsed and parsed[0].get_type() == "ATTITUDE", parsed  # the frame is accepted, not refused
        rows.append((f"parse one ATTITUDE datagram, pymavlink ({tag})", cpu_us_per_call(lambda: parse_datagram(bridge, next(frames)), calls - 1)))
        rows.append((f"encode + pack SET_ATTITUDE_TARGET, pymavlink ({tag})", cpu_us_per_call(
            lambda: bridge.set_attitude_target_encode(1000, 1, 1, 7, [1.0, 0.0, 0.0, 0.0], 0.1, 0.2, 0.3, 0.5).pack(bridge), calls)))
    payload = frame[10:10 + ATTITUDE_PAYLOAD.size]
    rows.append(("floor: struct.unpack of the ATTITUDE payload alone", cpu_us_per_call(lambda: ATTITUDE_PAYLOAD.unpack(payload), calls)))
    rows.append(("floor: struct.pack of the SET_ATTITUDE_TARGET payload alone", cpu_us_per_call(
        lambda: TARGET_PAYLOAD.pack(1000, 1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.5, 1, 1, 7), calls)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=20000, help="calls per timed run (default 20000)")
    ap.add_argument("--cycle-cpu-us", type=float, default=400.0, help="the bridge's CPU per cycle [us] for the share column (default 400)")
    args = ap.parse_args()
    rows = measure(args.calls)
    print(f"| step | CPU us per message | share of {args.cycle_cpu_us:g} us per cycle |")
    print("|---|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.2f} | {100.0 * us / args.cycle_cpu_us:.1f} % |")


if __name__ == "__main__":
    main()
