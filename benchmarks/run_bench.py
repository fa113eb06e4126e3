"""Same as ``mavastsm bench``: every benchmark, table + optional JSON (``--quick`` < 2 minutes).

Usage: ``python benchmarks/run_bench.py [--quick] [--json out.json] [--clients ...] [--rates-hz ...]``
"""

import argparse
import sys

from mavastsm import bench

if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="benchmarks/run_bench.py", description=__doc__.splitlines()[0])
    bench.configure(parser)
    sys.exit(bench.run(parser.parse_args()))
