"""Number flags within bounds: argparse types that refuse what a command cannot use.

A flag out of its bounds (NaN, an infinity, a 400-digit integer, a rate so low that its period
overflows) is one argparse error line naming the flag, and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def bounded_float(low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a finite number in [``low``, ``high``]."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError as err:
            msg = f"{text!r} is not a number"
            raise argparse.ArgumentTypeError(msg) from err
        if not (math.isfinite(value) and low <= value <= high):
            msg = f"{text[:40]!r} is not a number in [{low:g}, {high:g}]"
            raise argparse.ArgumentTypeError(msg)
        return value

    return parse


def bounded_int(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an integer in [``low``, ``high``]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError as err:  # also past Python's 4300-digit limit
            msg = f"{text[:40]!r} is not an integer"
            raise argparse.ArgumentTypeError(msg) from err
        if not low <= value <= high:
            msg = f"{text[:40]!r} is not an integer in [{low}, {high}]"
            raise argparse.ArgumentTypeError(msg)
        return value

    return parse


#: Seconds a command may be told to wait at most (one day).
MAX_WAIT_S = 86_400.0
#: Frames a command may be told to count or send at most.
MAX_COUNT = 10**9
#: Frame rates, Hz: one frame every 100 s at the least, 10 kHz at the most.
MIN_RATE_HZ, MAX_RATE_HZ = 0.01, 10_000.0
#: The demo's frame rates, Hz: below 1 Hz a drive of 12 s would have no frame.
DEMO_MIN_FPS, DEMO_MAX_FPS = 1.0, 240.0
