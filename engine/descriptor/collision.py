"""Collision-only density: the paper's baseline, a soft indicator of the solid.

Works on a part's mesh (vertices (n, 3) float64, faces (m, 3) int64) sampled on the grid of
its skeletal descriptor. The density is

    rho_c(p) = i * lambda_in * clip(w(p), 0, 1)

with ``w`` the generalised winding number (1 inside, 0 outside, smooth across the surface
at the grid's resolution once low-passed). In the correlation the product of two such
densities is ``-lambda_in^2 w1 w2``: the score is minus the (soft) overlap volume and the
energy ``E = kappa lambda_in^2 * overlap``, a pure penalty on interpenetration with no
reward for a fit. Using ``lambda_in`` of the skeletal parameters keeps the collision
stiffness on the scale of the skeletal density's inside-inside term, so that guided and
collision-only runs differ by the guidance, not by a gain.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from engine.cache import load_or_compute
from engine.descriptor.compute import winding_number
from engine.descriptor.store import Descriptor, descriptor_code_digest
from engine.grid import Grid
from engine.loading import Part


def collision_density(
    vertices: np.ndarray, faces: np.ndarray, grid: Grid, lambda_in: float
) -> np.ndarray:
    """(nx, ny, nz) complex64 collision-only density on ``grid``.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    grid : engine.grid.Grid
    lambda_in : float
    """
    points = grid.points().reshape(-1, 3)
    w = np.clip(winding_number(vertices, faces, points), 0.0, 1.0)
    return (1j * lambda_in * w).astype(np.complex64).reshape(grid.shape)


def collision_descriptor(descriptor: Descriptor, part: Part) -> Descriptor:
    """The collision-only counterpart of a skeletal descriptor (same grid, cached).

    Parameters
    ----------
    descriptor : Descriptor
        Supplies the grid and ``params.lambda_in``.
    part : engine.loading.Part
        The mesh.

    Returns
    -------
    Descriptor
        ``descriptor`` with ``rho`` replaced by :func:`collision_density`.
    """
    grid = descriptor.grid
    lam = float(descriptor.params.lambda_in)
    key = {
        "vertices": np.asarray(part.vertices, np.float64),
        "faces": np.asarray(part.faces, np.int64),
        "grid": [list(grid.origin), grid.spacing, list(grid.shape)],
        "lambda_in": lam,
        "version": 1,
        "code": descriptor_code_digest(),
    }
    arrays, _ = load_or_compute(
        "collision", key,
        lambda: {"rho": collision_density(part.vertices, part.faces, grid, lam)},
    )
    return dataclasses.replace(descriptor, rho=arrays["rho"])
