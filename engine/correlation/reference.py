"""The numpy reference of the per-pose sums: vectorised, reading the spectra in place.

Works on a pair's :class:`~engine.correlation.tables.Spectra` and one
:class:`~engine.correlation.tables.ModeTable`; sums the same seven raw numbers as the
compiled kernels (see :mod:`engine.correlation.finishing`) with the same interpolation
functions (:mod:`engine.correlation.interpolation`, called on arrays), and finishes them
with the same :func:`~engine.correlation.finishing.finish`. It serves as the reference the
kernels are tested against, for mode counts whose table would be too large for the
kernels, and for landscapes (:func:`interpolate_rows`).
"""

from __future__ import annotations

import numpy as np

import engine.correlation.interpolation as interpolation
from engine.correlation.finishing import boxes_overlap, finish, phase_offset
from engine.correlation.tables import ModeTable, Spectra, gradient_factor

#: Modes per chunk (bounds the temporaries to a few tens of MB).
CHUNK = 1 << 16


def interpolate_rows(
    spectra: Spectra, rk: np.ndarray, reach: float, gradient: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """Part 2's spectrum at ``-R^T w`` and its lattice gradient.

    With rotation on (moment spectra present) the interpolant is the cubic Hermite one
    of :func:`engine.correlation.interpolation.hermite`; without, plain trilinear.

    Parameters
    ----------
    spectra : Spectra
    rk : (n, 3) float64
        Rows ``R^T k`` (``k`` integer frequency indices).
    reach : float
        Reach of the mode set these rows belong to (picks the refined table or the ``q``
        lattice, as the kernels' tables do).
    gradient : bool
        Also return the interpolant's gradient ``dG/du`` (needs rotation on).

    Returns
    -------
    values : (n,) complex128
    gradients : (3, n) complex128 or None
    """
    rotation = spectra.geometry.rotation
    if gradient and not rotation:
        raise ValueError("the interpolant's gradient needs rotation on (moment spectra)")
    fine = spectra.fine_for(reach)
    scale = spectra.lattice_scale(fine)
    values = moments = flat = None
    if fine:
        assert spectra.fine_table is not None
        fine_table = spectra.fine_table.view(np.complex64)  # (B, B, B, P)
        side = fine_table.shape[0]
        flat = fine_table.reshape(-1, fine_table.shape[-1])
        offset = spectra.fine_radius
    else:
        moving = spectra.moving
        side = moving.size
        offset = 0
        values = moving.values.ravel()
        moments = None if moving.moments is None else moving.moments.reshape(3, -1)
    u = -scale * rk + offset
    base = np.floor(u)
    frac = u - base
    base = base.astype(np.int64)
    n = len(rk)
    channels = 4 if rotation else 1
    # the 8 corners of each row's cell as rows 8 i + 4 dx + 2 dy + dz of a small table
    corners = np.empty((n, 8, channels), dtype=np.complex128)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                ix, iy, iz = base[:, 0] + dx, base[:, 1] + dy, base[:, 2] + dz
                corner = 4 * dx + 2 * dy + dz
                if flat is not None:
                    corners[:, corner, :] = flat[(ix * side + iy) * side + iz, :channels]
                else:
                    assert values is not None
                    idx = (np.mod(ix, side) * side + np.mod(iy, side)) * side + np.mod(iz, side)
                    corners[:, corner, 0] = values[idx]
                    if rotation:
                        assert moments is not None
                        corners[:, corner, 1:] = moments[:, idx].T
    if rotation:
        corners[:, :, 1:] *= gradient_factor(spectra, fine)  # M -> dG/du
    table = np.empty((8 * n, 2 * channels))
    table[:, 0::2] = corners.reshape(8 * n, channels).real
    table[:, 1::2] = corners.reshape(8 * n, channels).imag
    b00 = 8 * np.arange(n)
    cell = (b00, b00 + 2, b00 + 4, b00 + 6, frac[:, 0], frac[:, 1], frac[:, 2])
    if not rotation:
        g = interpolation.lerp(table, 0, cell) + 1j * interpolation.lerp(table, 1, cell)
        return g, None
    re = interpolation.hermite(table, 0, cell)
    im = interpolation.hermite(table, 1, cell)
    g = re[0] + 1j * im[0]
    grad = np.stack([re[a] + 1j * im[a] for a in (1, 2, 3)]) if gradient else None
    return g, grad


def raw_sums(spectra: Spectra, table: ModeTable, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(7,) float64 ``[Re f, S_k (3), S_u (3)]`` over the kept modes (the finishing's input).

    Over kept integer ``k`` (``w = k / (N h)``): ``c = rho1c^(w) dw exp(2 pi i w.(t + R c2
    - c1))``, ``G`` part 2's interpolated spectrum at ``-R^T w``; ``f = sum c G``,
    ``S_k = Im sum c G k``, ``S_u = sum Re(c dG/du) x R^T k``.
    """
    geometry = table.geometry
    n_h = geometry.n_h
    shift = phase_offset(rot, t, geometry.centre_fixed, geometry.centre_moving)
    if table.kept is not None:
        assert table.fixed_kept is not None
        kept = table.kept
        phase = [np.exp(2j * np.pi * kept * shift[a] / n_h) for a in range(3)]
        coeff = (table.fixed_kept.astype(np.complex128) * phase[0][:, None, None]
                 * phase[1][None, :, None] * phase[2][None, None, :]).ravel()
        kx, ky, kz = np.meshgrid(kept, kept, kept, indexing="ij")
        kvec = np.stack([kx.ravel(), ky.ravel(), kz.ravel()], axis=1)  # (m', 3)
    else:
        assert table.mode_k is not None and table.mode_a is not None
        kvec = table.mode_k
        coeff = table.mode_a.astype(np.complex128) * np.exp(2j * np.pi * (kvec @ shift) / n_h)
    total = np.zeros(7)
    for lo in range(0, len(kvec), CHUNK):
        kc = kvec[lo : lo + CHUNK]
        cc = coeff[lo : lo + CHUNK]
        rk = kc @ rot  # (n, 3): rows are R^T k
        g, grad = interpolate_rows(spectra, rk, table.reach, geometry.rotation)
        cg = cc * g
        total[0] += cg.real.sum()
        total[1:4] += cg.imag @ kc
        if grad is not None:
            re_cd = (cc * grad).real.T  # (n, 3): Re(c dG/du)
            total[4:7] += np.cross(re_cd, rk).sum(axis=0)
    return total


def pose(spectra: Spectra, table: ModeTable, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(7,) float64 ``[E, F (3), T (3)]`` at one pose (zeros where the boxes are apart)."""
    g = table.geometry
    if not boxes_overlap(rot, t, g.centre_fixed, g.centre_moving, g.half_fixed, g.half_moving,
                         g.spacing):
        return np.zeros(7)
    return finish(raw_sums(spectra, table, rot, t), rot, g.centre_moving, g.kappa, g.n_h,
                  table.scale, g.rotation)
