"""Regular sampling grids in a part's own frame.

A grid is an origin (where index (0, 0, 0) lies), one spacing ``h`` shared by the three
axes and by every part of a scene, and a shape ``(nx, ny, nz)``. Sample ``(i, j, k)``
lies at ``origin + h * (i, j, k)``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from engine.errors import InputError, ResourceError
from engine.params import DEFAULT_PADDING, MAX_GRID, MAX_PADDING

#: The largest share of the machine's physical memory one computation may plan to use,
#: and of the memory available when it starts.
MEMORY_SHARE = 0.5
AVAILABLE_SHARE = 0.8
#: Bytes per sample a descriptor computation holds at its peak (the result, the adaptive
#: sampler's index and work arrays, the points): measured about 100, rounded up.
DESCRIPTOR_BYTES_PER_SAMPLE = 128


def physical_memory() -> int | None:
    """Bytes of physical memory of this machine (None where the system does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return None


def available_memory() -> int | None:
    """Bytes of memory available now without swapping (Linux's MemAvailable), else None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_memory(need: int, what: str, fix: str) -> None:
    """Refuse a computation that would need more memory than it may plan on.

    That is :data:`MEMORY_SHARE` of the machine's physical memory, and no more than
    :data:`AVAILABLE_SHARE` of what is available now (other programs hold the rest).
    ``need`` is computed by the caller in Python integers (no overflow) before anything is
    allocated.

    Raises
    ------
    ResourceError
        Naming ``what``, the bytes it needs, what the machine has, and ``fix``.
    """
    total = physical_memory()
    if total is None:  # pragma: no cover - non-POSIX
        return
    budget = MEMORY_SHARE * total
    available = available_memory()
    has = f"this machine has {_gib(total)}"
    if available is not None and AVAILABLE_SHARE * available < budget:
        budget = AVAILABLE_SHARE * available
        has += f", {_gib(available)} of it available now"
    if need > budget:
        raise ResourceError(f"{what} needs about {_gib(need)} of memory but {has} (at most "
                            f"{_gib(int(budget))} is planned for one computation): {fix}")


def _gib(n: int) -> str:
    return f"{n / 2**30:.1f} GiB" if n < 2**70 else f"{float(n):.2g} bytes"


def fft_bytes(size: int, arrays: int) -> int:
    """Bytes of ``arrays`` complex64 cubes of ``size^3`` (Python integers)."""
    return int(arrays) * int(size) ** 3 * 8


def check_fft_memory(size: int, arrays: int, what: str) -> None:
    """Refuse an FFT of ``size^3`` holding ``arrays`` complex64 cubes that does not fit."""
    check_memory(fft_bytes(size, arrays), f"{what} ({arrays} arrays of {size}^3 complex64)",
                 "use a coarser grid (a smaller [descriptor] grid or a larger spacing) or "
                 "less padding")


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
    def centre(self) -> np.ndarray:
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
        if samples > MAX_GRID:
            raise InputError(f"grid = {samples} samples is above {MAX_GRID}: "
                             f"{MAX_GRID}^3 samples take 64 GiB per part; use a smaller grid")
        if longest <= 0:
            raise ValueError("the part has zero extent: cannot derive a spacing from it")
        spacing = longest / samples
    assert spacing is not None
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive finite number, got {spacing!r}")
    if not (0 <= padding <= MAX_PADDING):
        raise InputError(f"padding = {padding!r} cells is outside its range 0 to "
                         f"{MAX_PADDING:g}: the outside tail fades within a few cells, more "
                         "only grows the grid and its FFT")
    # Counted in Python numbers first: a tiny spacing must give a clear refusal, not an
    # integer overflow or an allocation of terabytes.
    cells = longest / spacing
    if not (math.isfinite(cells) and cells <= MAX_GRID):
        lo = longest / MAX_GRID
        raise InputError(
            f"spacing = {spacing:g} gives {cells:.3g} samples along the part's longest side "
            f"({longest:g}), above {MAX_GRID}: for this part the spacing must be at least "
            f"{lo:.3g} ({MAX_GRID}^3 samples take 64 GiB)")
    pad = int(math.ceil(padding))
    counts = [int(math.ceil(float(e) / spacing - 1e-9)) + 1 + 2 * pad for e in extent]
    check_memory(DESCRIPTOR_BYTES_PER_SAMPLE * math.prod(counts),
                 f"a {counts[0]} x {counts[1]} x {counts[2]} descriptor grid",
                 "use a coarser grid (a smaller grid, a larger spacing or less padding)")
    shape = np.asarray(counts, dtype=np.int64)
    centre = 0.5 * (lower + upper)
    origin = centre - 0.5 * spacing * (shape - 1)
    return Grid(tuple(origin), spacing, tuple(int(n) for n in shape))  # type: ignore[arg-type]
