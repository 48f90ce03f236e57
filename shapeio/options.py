"""What the command lines of ``python -m csgnet`` and ``python -m shapeprog`` share: argparse ``type=`` functions
that range-check a number, so that a value out of range is one line (exit 2) before any work, and the help
formatter that shows each option's default and a command's example as written.

Example:
    >>> int_in(1, 64)("8"), float_in(0.0, 1.0)("0.5")
    (8, 0.5)
"""
from __future__ import annotations

import argparse
import math

__all__ = ["HelpFormatter", "float_in", "int_in"]


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


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help that names each option's default (none for options without one, flags that are off, or help texts
    that say their default themselves) and keeps the epilog's example lines as written."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (action.default is None or action.default is False or action.default == []
                or action.default is argparse.SUPPRESS or "%(default)" in text or "(default" in text
                or not action.option_strings):
            return text
        return text + " (default: %(default)s)"

    def _fill_text(self, text, width, indent):
        if text.startswith("example:"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)
