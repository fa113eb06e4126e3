"""The rich ``Console`` every report command prints through (check-config, list-controllers, simulate, reproduce,
bench, demo).

On a terminal it is rich's usual console (the terminal's width, colour). When the output is piped or
redirected (a file, ``| less``, a CI log), rich would assume 80 columns and cut or wrap table cells ("0.0…",
key names truncated, a claims table wrapped into hundreds of lines); here the width is then PIPED_WIDTH, so
every cell is printed whole on one line, and no colour codes are written.
"""

from __future__ import annotations

import sys

from rich.console import Console

PIPED_WIDTH = 10_000  # columns: wide enough for any of our tables at their natural width


def report_console(stderr: bool = False) -> Console:
    stream = sys.stderr if stderr else sys.stdout
    if stream.isatty():
        return Console(stderr=stderr)
    return Console(stderr=stderr, width=PIPED_WIDTH, color_system=None, soft_wrap=True)
