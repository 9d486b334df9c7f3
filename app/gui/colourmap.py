"""Colour maps for descriptor slices and energy sections: numpy lookup tables, no matplotlib.

A map is a (256, 3) uint8 table; :func:`apply` turns a (h, w) float array into (h, w, 3)
uint8 RGB given the value range.
"""

from __future__ import annotations

import numpy as np

# Moreland's "cool to warm" diverging map (blue, light grey, red), a few control points.
_DIVERGING = np.array(
    [
        [0.00, 59, 76, 192],
        [0.125, 98, 130, 234],
        [0.25, 141, 176, 254],
        [0.375, 184, 208, 249],
        [0.50, 221, 221, 221],
        [0.625, 245, 196, 173],
        [0.75, 244, 154, 123],
        [0.875, 222, 96, 77],
        [1.00, 180, 4, 38],
    ]
)
# Sequential (viridis control points) for magnitudes, which are never negative.
_SEQUENTIAL = np.array(
    [
        [0.00, 68, 1, 84],
        [0.25, 59, 82, 139],
        [0.50, 33, 145, 140],
        [0.75, 94, 201, 98],
        [1.00, 253, 231, 37],
    ]
)

KINDS = ("diverging", "sequential")


def table(kind: str = "diverging") -> np.ndarray:
    """(256, 3) uint8 lookup table of the named map ("diverging" or "sequential")."""
    if kind not in KINDS:
        raise ValueError(f"unknown colour map {kind!r}; valid: {', '.join(KINDS)}")
    points = _DIVERGING if kind == "diverging" else _SEQUENTIAL
    x = np.linspace(0.0, 1.0, 256)
    rgb = [np.interp(x, points[:, 0], points[:, c]) for c in (1, 2, 3)]
    return np.clip(np.stack(rgb, axis=1).round(), 0, 255).astype(np.uint8)


def symmetric_range(values: np.ndarray) -> tuple[float, float]:
    """(-a, a) with a the 99th percentile of |values|: a diverging map centred on zero.

    The percentile, not the maximum, because descriptors peak sharply on the medial axis and
    a max-scaled map would leave everything else grey.
    """
    finite = np.abs(values[np.isfinite(values)])
    a = float(np.percentile(finite, 99)) if finite.size else 1.0
    a = a if a > 0 else 1.0
    return -a, a


def apply(values: np.ndarray, lo: float, hi: float, lut: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 colours of a (h, w) float array mapped linearly from [lo, hi]."""
    span = hi - lo if hi > lo else 1.0
    idx = np.clip((np.nan_to_num(values, nan=lo) - lo) / span * 255.0, 0, 255).astype(np.intp)
    return lut[idx]
