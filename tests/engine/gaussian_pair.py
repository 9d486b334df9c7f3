"""A small pair of descriptors made of Gaussian blobs, on two grids of one spacing.

For tests of the correlation's pieces that need real spectra but no mesh: part 1 on a
13^3 grid, part 2 on 11 x 9 x 11, both complex (``rho`` complex64), spacing 0.5.
"""

from __future__ import annotations

import types

import numpy as np

from engine.grid import Grid

H = 0.5
GRID1 = Grid((-3.0, -3.0, -3.0), H, (13, 13, 13))
GRID2 = Grid((-2.5, -2.0, -2.5), H, (11, 9, 11))


def gaussian(grid, mu, s, a):
    """``a exp(-|p - mu|^2 / 2 s^2)`` at the grid's points, complex64."""
    p = grid.points()
    return (a * np.exp(-np.sum((p - np.asarray(mu)) ** 2, -1) / (2 * s * s))).astype(np.complex64)


def pair():
    """(fixed, moving): objects with ``.rho`` and ``.grid``, as a Correlator takes."""
    r1 = gaussian(GRID1, (0.2, -0.1, 0.3), 0.8, 1 + 1j) + gaussian(GRID1, (-1, 0.5, 0), 0.7, -1j)
    r2 = gaussian(GRID2, (0.3, 0.2, -0.2), 0.7, 2 - 1j)
    return (types.SimpleNamespace(rho=r1, grid=GRID1), types.SimpleNamespace(rho=r2, grid=GRID2))
