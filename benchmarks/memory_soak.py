"""Memory soak: the bridge's resident memory over a long flight under hostile traffic (a benchmark: prints, asserts nothing).

    python benchmarks/memory_soak.py [--minutes 30] [--garbage-hz 1000] [--names-hz 200] [--every-s 30] [--json OUT]

The bridge (ASTSM, reference ``hold``, ``--log`` to a temporary folder) flies the in-repo sim in real time
(GUIDED_NOGPS, 0.5 m takeoff) for ``--minutes``. An attacker thread sends to the bridge's own UDP port
``--garbage-hz`` datagrams per second of random bytes, truncated and bad-CRC frames, and ``--names-hz``
valid NAMED_VALUE_FLOAT / PARAM_VALUE frames with a new name each (from the vehicle's and other system ids).
Every ``--every-s`` it prints this process's RSS [MB] (bridge and sim share it; the sim's share is flat) and the
link's counters. The verdict line gives the RSS spread after the first sample-memory fill (timing.samples_in_memory).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import sys
import tempfile
import threading
import time

from mavastsm.bridge import Bridge, BridgeOptions
from mavastsm.runtime_tuning import ProcessTuning
from mavastsm.bridge.link.mavlink_link import mavlink
from mavastsm_sim.vehicle_server import VehicleServer


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def attacker(port: int, garbage_hz: float, names_hz: float, stop: threading.Event, sent: list[int]) -> None:
    rng = random.Random(1)
    senders = [mavlink.MAVLink(None, srcSystem=s, srcComponent=1) for s in (1, 7, 42)]
    hb = bytes(senders[0].heartbeat_encode(2, 3, 0, 0, 0).pack(senders[0]))
    i = 0
    period = 1.0 / max(garbage_hz + names_hz, 1.0)
    share = names_hz / max(garbage_hz + names_hz, 1.0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        next_t = time.monotonic()
        while not stop.is_set():
            i += 1
            if rng.random() < share:
                mav = senders[i % 3]
                name = f"n{i:08d}".encode()
                msg = (mav.named_value_float_encode(i, name, 1.0) if i % 2 else
                       mav.param_value_encode(name, 1.0, mavlink.MAV_PARAM_TYPE_REAL32, 65535, 65535))
                data = bytes(msg.pack(mav))
            else:
                kind = i % 3
                if kind == 0:
                    data = rng.randbytes(rng.randrange(1, 300))
                elif kind == 1:
                    data = hb[:rng.randrange(1, len(hb))]  # truncated
                else:
                    b = bytearray(hb)
                    b[-1] ^= 0xFF  # bad CRC
                    data = bytes(b)
            s.sendto(data, ("127.0.0.1", port))
            sent[0] += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                stop.wait(delay)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="flight length [min] (default 30)")
    ap.add_argument("--garbage-hz", type=float, default=1000.0, help="hostile datagrams per second (default 1000)")
    ap.add_argument("--names-hz", type=float, default=200.0, help="valid frames with a new name per second (default 200)")
    ap.add_argument("--every-s", type=float, default=30.0, help="print period [s] (default 30)")
    ap.add_argument("--json", metavar="OUT", help="also write the samples as JSON")
    args = ap.parse_args(argv)
    duration_s = args.minutes * 60.0
    rows = []
    with tempfile.TemporaryDirectory(prefix="mavastsm-soak-") as logdir, \
            VehicleServer(clock="realtime", listen=("127.0.0.1", 0)) as server:
        b = Bridge(BridgeOptions(f"udpout:127.0.0.1:{server.port}", controller="astsm", reference="hold", duration_s=duration_s,
                                 mode="GUIDED_NOGPS", arm=True, takeoff_alt_m=0.5, on_exit="LAND", log_dir=logdir))
        tuning = ProcessTuning(b.config.timing).apply()  # as `mavastsm connect` runs it (gc.freeze ticked below)
        b.start()
        stop = threading.Event()
        sent = [0]
        deadline = time.monotonic() + 60.0
        while (b.session is None or b.session.cycle.engage_ms is None) and time.monotonic() < deadline:
            time.sleep(0.05)
        th = threading.Thread(target=attacker, args=(b.link._conn.port.getsockname()[1], args.garbage_hz, args.names_hz, stop, sent),
                              daemon=True)
        th.start()
        t0 = time.monotonic()
        try:
            while not b.session.done.wait(args.every_s):
                tuning.tick(b.state == "engaged")
                st = b.link.stats
                row = {"t_s": round(time.monotonic() - t0, 1), "rss_mb": round(rss_mb(), 1), "cycles": b.session.counters.cycles,
                       "hostile_sent": sent[0], "refused": st.bad_data, "received": st.received, "failsafe": str(b.session.failsafe)}
                rows.append(row)
                print(json.dumps(row), flush=True)
        except KeyboardInterrupt:
            b.stop()
        finally:
            stop.set()
            th.join(2.0)
            summary = b.wait(120.0)
            tuning.restore()
    fill_s = b.config.timing.samples_in_memory / max(summary.attitude_rate_achieved_hz, 1.0)
    steady = [r["rss_mb"] for r in rows if r["t_s"] >= fill_s + args.every_s]
    verdict = {"end": summary.end_reason, "cycles": summary.cycles, "refused_frames": dict(summary.refused_frames),
               "samples_in_memory_fill_s": round(fill_s, 1),
               "rss_after_fill_min_mb": min(steady) if steady else None, "rss_after_fill_max_mb": max(steady) if steady else None}
    print(json.dumps(verdict), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"rows": rows, "verdict": verdict, "args": vars(args)}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
