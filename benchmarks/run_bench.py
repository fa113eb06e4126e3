"""Same as ``mavastsm bench``: every benchmark, table + optional JSON/markdown (``--quick`` is the short run).

Usage: ``python benchmarks/run_bench.py [--quick] [--json out.json] [--markdown out.md] [--clients ...] [--rates-hz ...]``
"""

import sys

from mavastsm.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
