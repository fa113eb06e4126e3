"""Latency of one offboard client against the stub vehicle (the measurement behind ``mavastsm bench``).

Usage: ``python benchmarks/client_latency.py pymavlink --rate-hz 400 --window-s 10 [--dashboard]``
Clients: bridge, pymavlink, mavsdk-async, mavsdk-callback. Prints one JSON row.
"""

import argparse
import json

from mavastsm.bench import CLIENT_LABELS, measure_client

if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="benchmarks/client_latency.py", description=__doc__.splitlines()[0])
    parser.add_argument("client", choices=list(CLIENT_LABELS))
    parser.add_argument("--rate-hz", type=float, default=400.0, help="ATTITUDE rate [Hz], 1..1000")
    parser.add_argument("--window-s", type=float, default=10.0, help="measurement window [s]")
    parser.add_argument("--warmup-s", type=float, default=1.0, help="delay after the first reply [s]")
    parser.add_argument("--dashboard", action="store_true", help="bridge only: render the dashboard")
    a = parser.parse_args()
    print(json.dumps(measure_client(a.client, a.rate_hz, a.window_s, a.warmup_s, dashboard=a.dashboard), indent=2))
