"""Regular sampling grids in a part's own frame.

A grid is an origin (where index (0, 0, 0) lies), one spacing ``h`` shared by the three
axes and by every part of a scene, and a shape ``(nx, ny, nz)``. Sample ``(i, j, k)``
lies at ``origin + h * (i, j, k)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.params import DEFAULT_PADDING


@dataclass(frozen=True)
class Grid:
    """A regular grid of sample points.

    Attributes
    ----------
    origin : tuple of 3 float
        Position of sample (0, 0, 0) in the part's frame.
    spacing : float
        Distance ``h`` between neighbouring samples along each axis.
    shape : tuple of 3 int
        Number of samples ``(nx, ny, nz)``.
    """

    origin: tuple[float, float, float]
    spacing: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.spacing) and self.spacing > 0):
            raise ValueError(f"grid spacing must be a positive finite number, got {self.spacing!r}")
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise ValueError(f"grid shape must be three positive integers, got {self.shape!r}")
        if len(self.origin) != 3 or not all(math.isfinite(float(o)) for o in self.origin):
            raise ValueError(f"grid origin must be three finite numbers, got {self.origin!r}")
        object.__setattr__(self, "origin", tuple(float(o) for o in self.origin))
        object.__setattr__(self, "spacing", float(self.spacing))
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))

    @property
    def size(self) -> int:
        """Number of samples."""
        return int(np.prod(self.shape))

    @property
    def upper(self) -> np.ndarray:
        """(3,) float64: position of the last sample."""
        return np.asarray(self.origin) + self.spacing * (np.asarray(self.shape) - 1)

    @property
    def center(self) -> np.ndarray:
        """(3,) float64: the midpoint between the first and the last sample."""
        return 0.5 * (np.asarray(self.origin) + self.upper)

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample coordinates along x, y and z: three 1D float64 arrays."""
        return tuple(  # type: ignore[return-value]
            o + self.spacing * np.arange(n) for o, n in zip(self.origin, self.shape, strict=True)
        )

    def points(self) -> np.ndarray:
        """(nx, ny, nz, 3) float64: every sample position, C order (z fastest)."""
        x, y, z = self.axes()
        return np.stack(np.meshgrid(x, y, z, indexing="ij"), axis=-1)

    def bytes_complex64(self) -> int:
        """Memory of one complex64 field on this grid."""
        return self.size * 8


def grid_for_bounds(
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    samples: int | None = None,
    spacing: float | None = None,
    padding: float = DEFAULT_PADDING,
) -> Grid:
    """Grid covering an axis-aligned box with ``padding`` cells to spare on every side.

    Exactly one of ``samples`` (samples along the box's longest side, so
    ``h = longest / samples``) and ``spacing`` is given. The grid is centred on the box.

    Parameters
    ----------
    lower, upper : (3,) float
        Corners of the box (a part's bounds in its own frame).
    samples : int, optional
        Samples along the longest side, padding not included.
    spacing : float, optional
        Grid spacing ``h``.
    padding : float
        Free space on each side, in cells.
    """
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    if lower.shape != (3,) or upper.shape != (3,):
        raise ValueError("bounds must be two 3-vectors")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise ValueError("bounds are not finite")
    extent = upper - lower
    longest = float(extent.max())
    if (samples is None) == (spacing is None):
        raise ValueError("give exactly one of samples and spacing")
    if samples is not None:
        if samples < 2:
            raise ValueError(f"samples must be at least 2, got {samples}")
        if longest <= 0:
            raise ValueError("the part has zero extent: cannot derive a spacing from it")
        spacing = longest / samples
    assert spacing is not None
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive finite number, got {spacing!r}")
    if padding < 0:
        raise ValueError(f"padding must be non-negative, got {padding!r}")
    shape = np.ceil(extent / spacing - 1e-9).astype(int) + 1 + 2 * int(math.ceil(padding))
    center = 0.5 * (lower + upper)
    origin = center - 0.5 * spacing * (shape - 1)
    return Grid(tuple(origin), spacing, tuple(int(n) for n in shape))  # type: ignore[arg-type]
