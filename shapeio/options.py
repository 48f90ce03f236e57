"""Command-line option types shared by ``python -m csgnet`` and ``python -m shapeprog``: argparse ``type=``
functions that range-check a number, so that a value out of range is one line (exit 2) before any work.

Example:
    >>> int_in(1, 64)("8"), float_in(0.0, 1.0)("0.5")
    (8, 0.5)
"""
from __future__ import annotations

import argparse
import math

__all__ = ["float_in", "int_in"]


def int_in(low: int, high: int):
    """An argparse type: an int from ``low`` to ``high``."""
    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be an integer from {low} to {high}, got {text[:20]!r}")
        return value
    return convert


def float_in(low: float, high: float, low_open: bool = False, high_open: bool = False):
    """An argparse type: a finite float in the interval from ``low`` to ``high`` (open at an end when asked)."""
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        inside = (low < value if low_open else low <= value) and (value < high if high_open else value <= high)
        if not (math.isfinite(value) and inside):
            raise argparse.ArgumentTypeError(f"must be a number in {'(' if low_open else '['}{low:g}, {high:g}"
                                             f"{')' if high_open else ']'}, got {text[:20]!r}")
        return value
    return convert
