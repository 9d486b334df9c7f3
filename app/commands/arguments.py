"""Argument types shared by the subcommands: numbers checked where they are parsed.

Each type reads any notation Python's ``float()`` reads (the parser itself accepts
negative numbers such as ``-4.2e-18`` as values: :class:`app.cli.Parser`) and raises
``argparse.ArgumentTypeError`` with the range, so a bad value exits 2 with one line.
"""

from __future__ import annotations

import argparse
import math


def finite_float(text: str) -> float:
    """A finite number (NaN and infinity refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def positive_float(text: str) -> float:
    """A finite number above zero."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value
