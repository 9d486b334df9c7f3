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


def int_in_range(low: int, high: int, why: str = ""):
    """An argparse type: a whole number from ``low`` to ``high`` (``why`` says why)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            try:
                as_float = float(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
            if not (math.isfinite(as_float) and as_float.is_integer()):
                raise argparse.ArgumentTypeError(
                    f"must be a whole number from {low:,} to {high:,}, got {text}") from None
            value = int(as_float)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be a whole number from {low:,} to {high:,}, got {text}"
                + (f" ({why})" if why else ""))
        return value

    parse.__name__ = "whole number"
    return parse


def check_rotation_vector(rotation, option: str) -> None:
    """Refuse a rotation vector longer than the engine's proxy bound (1e4 rad).

    Beyond it the angle's double precision is coarser than 1e-12 rad per 1e4 rad and a sine
    of it is meaningless; 1e6 rad used to be evaluated as if it meant something.
    """
    from engine.errors import InputError
    from engine.sim.guard import MAX_ROTATION_VECTOR

    angle = math.hypot(*(float(r) for r in rotation))
    if angle > MAX_ROTATION_VECTOR:
        raise InputError(f"{option}: a rotation vector of {angle:.3g} rad is longer than "
                         f"{MAX_ROTATION_VECTOR:g} rad: rotations are rotation vectors in "
                         "radians (reduce it modulo 2 pi)")


def add_band_argument(parser: argparse.ArgumentParser) -> None:
    """``--band``: the modal sum's band, the guidance's unless told (engine.params)."""
    from engine.params import BAND_NAMES, GUIDANCE_BAND

    parser.add_argument("--band", choices=BAND_NAMES, default=None,
                        help=f"the band of modes kept: smooth (a ball, Lanczos-tapered, of "
                        f"the densities windowed where their tails end: what guides a part) "
                        f"or box (the plain cube, what the search ranks with) (default: "
                        f"{GUIDANCE_BAND}; docs/correlation.md)")
