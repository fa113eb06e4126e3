"""argparse ``type=`` converters shared by the commands of ``mavastsm`` and of the sim (``mavastsm_sim``).

A foundation module: it imports nothing of the package, so the sim's command line can use it without importing
``mavastsm.cli`` (which loads the sim's command module in turn: tests/test_architecture.py keeps that edge one-way).
"""

from __future__ import annotations

import argparse
import math


def positive_number(unit: str):
    """argparse ``type=`` for a finite number > 0 in ``unit``; the unit is named in the one-line error."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number [{unit}]") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{text!r} must be a finite number > 0 [{unit}]")
        return value

    return parse
