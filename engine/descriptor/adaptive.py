"""Adaptive sampling of the descriptor on a grid: exact where it is rough, else interpolated.

Works on a grid given by its three axes (1D float64 arrays, local units) and an evaluator
``evaluate(points (k, 3) float64, progress, hints) -> (k, 4) float64`` (Re rho, Im rho,
xi, winding) that computes points exactly. Returns ``rho (nx, ny, nz) complex128`` and
``xi`` on the grid.

Why it works. The skeletal density is scale-free: at a point ``|xi|`` from the surface it
varies over lengths of about ``sigma |xi|``, so away from the surface a grid resolves it
with room to spare. The grid's every second sample along each axis (the *coarse* grid, an
eighth of the points) is sampled first, by this same procedure one level down
(:data:`~engine.descriptor.constants.ADAPTIVE_LEVELS` levels, the coarsest evaluated
exactly). A coarse cube (eight coarse samples) is *smooth* when

- no surface can cross it: every corner is on the same side, at least
  ``ADAPTIVE_CLEARANCE`` times the cube's side from the surface (a surface point in the
  cube lies within half its diagonal, 0.87 of its side, of some corner), and
- the trilinear interpolation error estimated from the coarse samples is small: at every
  corner, ``(|d2x| + |d2y| + |d2z|) / 8 <= ADAPTIVE_TOLERANCE * rms(rho)``, with ``d2``
  the second differences of the coarse samples along each axis (the leading error term
  of linear interpolation at a midpoint). This also catches the cusp the density has on
  the medial axis, where the second difference is as large as the slope jump.

The fine samples inside smooth cubes are interpolated trilinearly from the cube's corners;
every other fine sample is evaluated exactly. Since each interpolated value carries an
estimated error under ``ADAPTIVE_TOLERANCE * rms(rho)``, the interpolation adds at most
about that to the relative L2 error of the whole grid; docs/descriptor.md gives the
measured errors and gains.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

import engine.descriptor.constants as _c

#: ``evaluate(points (k, 3) float64, progress, hints (k, 2) or None) -> (k, 4) float64``;
#: ``hints`` as :func:`engine.descriptor.numba_kernels.evaluate` takes them.
Evaluator = Callable[[np.ndarray, Callable[[float], None] | None, np.ndarray | None],
                     np.ndarray]


def _points(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray) -> np.ndarray:
    return np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)


def _odd(axis: np.ndarray) -> np.ndarray:
    """The axis as given when it has an odd number of samples, else one step longer."""
    if len(axis) % 2:
        return axis
    return np.append(axis, 2.0 * axis[-1] - axis[-2])


def _second_difference_error(rho: np.ndarray) -> np.ndarray:
    """(nx, ny, nz) estimated trilinear error at midpoints next to each sample.

    ``(|d2x| + |d2y| + |d2z|) / 8``; a sample on the grid's boundary takes its inner
    neighbour's second difference along that axis.
    """
    est = np.zeros(rho.shape)
    for axis in range(3):
        a = np.moveaxis(rho, axis, 0)
        d2 = np.abs(a[2:] - 2.0 * a[1:-1] + a[:-2])
        full = np.concatenate([d2[:1], d2, d2[-1:]], axis=0)
        est += np.moveaxis(full, 0, axis)
    return est / 8.0


def sample_grid(
    xs: np.ndarray,
    ys: np.ndarray,
    zs: np.ndarray,
    evaluate: Evaluator,
    *,
    levels: int | None = None,
    progress: Callable[[float], None] | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """The skeletal density rho and signed distance xi on the grid ``xs x ys x zs``.

    Samples are evaluated exactly where needed and interpolated from coarser levels where
    the estimated error allows (see the module docstring).

    Parameters
    ----------
    xs, ys, zs : (nx,), (ny,), (nz,) float64
        Equally spaced sample coordinates along each axis, local units (grid cells).
    evaluate : callable
        Exact evaluation of points, ``(k, 3) -> (k, 4)`` (re, im, xi, winding), taking an
        optional progress callback (fraction of its points done).
    levels : int, optional
        Coarse levels below this grid (default ``ADAPTIVE_LEVELS``); 0 evaluates every
        point exactly.
    progress : callable(float), optional
        Fraction of the exactly evaluated points done (an estimate while levels run).

    Returns
    -------
    rho : (nx, ny, nz) complex128
    xi : (nx, ny, nz) float64
    counts : dict
        ``"exact"`` and ``"interpolated"`` sample counts.
    """
    levels = _c.ADAPTIVE_LEVELS if levels is None else int(levels)
    rho, xi, _, counts = _sample(xs, ys, zs, evaluate, levels, progress)
    return rho, xi, counts


def _sample(
    xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, evaluate: Evaluator, levels: int,
    progress: Callable[[float], None] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, int]]:
    """:func:`sample_grid`, plus the mask of the samples evaluated exactly."""
    shape = (len(xs), len(ys), len(zs))
    if levels <= 0 or min(shape) < 5:
        out = evaluate(_points(xs, ys, zs), progress, None)
        rho = (out[:, 0] + 1j * out[:, 1]).reshape(shape)
        return (rho, out[:, 2].reshape(shape), np.ones(shape, dtype=bool),
                {"exact": rho.size, "interpolated": 0})  # fmt: skip
    if any(n % 2 == 0 for n in shape):
        # An even axis ends on a fine sample that no coarse cube holds, so a whole layer
        # of the grid (3 n^2 samples of an n^3 grid, most far from the surface, the costly
        # kind) would be evaluated exactly. Sample one more step along it instead and crop:
        # the coarse grid then spans the whole grid.
        rho, xi, exact, counts = _sample(_odd(xs), _odd(ys), _odd(zs), evaluate, levels,
                                         progress)  # fmt: skip
        crop = (slice(0, shape[0]), slice(0, shape[1]), slice(0, shape[2]))
        return rho[crop], xi[crop], exact[crop], counts
    # The coarse level is about an eighth of the points: give it that share of progress.
    total = float(np.prod(shape))
    coarse_share = np.prod([(n + 1) // 2 for n in shape]) / total

    def coarse_progress(f: float) -> None:
        if progress is not None:
            progress(coarse_share * f)

    rho_c, xi_c, exact_c, counts = _sample(xs[::2], ys[::2], zs[::2], evaluate, levels - 1,
                                           coarse_progress)  # fmt: skip
    stride = float(xs[2] - xs[0]) if len(xs) > 2 else 1.0
    scale = float(np.sqrt(np.mean(np.abs(rho_c) ** 2))) or 1.0
    node_ok = (_second_difference_error(rho_c) <= _c.ADAPTIVE_TOLERANCE * scale) & (
        np.abs(xi_c) >= _c.ADAPTIVE_CLEARANCE * stride
    )
    side = xi_c > 0
    # A cube (i, j, k) has corners (i..i+1, j..j+1, k..k+1) of the coarse grid.
    smooth = np.ones(tuple(n - 1 for n in rho_c.shape), dtype=bool)
    same_side_pos = np.ones_like(smooth)
    same_side_neg = np.ones_like(smooth)
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                sl = (slice(di, di + smooth.shape[0]), slice(dj, dj + smooth.shape[1]),
                      slice(dk, dk + smooth.shape[2]))  # fmt: skip
                smooth &= node_ok[sl]
                same_side_pos &= side[sl]
                same_side_neg &= ~side[sl]
    smooth &= same_side_pos | same_side_neg

    rho = np.empty(shape, dtype=np.complex128)
    xi = np.empty(shape)
    exact = np.zeros(shape, dtype=bool)
    rho[::2, ::2, ::2] = rho_c
    xi[::2, ::2, ::2] = xi_c
    exact[::2, ::2, ::2] = exact_c
    idx = np.indices(shape).reshape(3, -1)
    fine = np.any(idx % 2 == 1, axis=0)
    fi = idx[:, fine]
    cube = fi // 2  # the cube holding each fine sample (its lower corner)
    inside = np.all(cube < np.asarray(smooth.shape)[:, None], axis=0)
    use = np.zeros(fi.shape[1], dtype=bool)
    use[inside] = smooth[cube[0, inside], cube[1, inside], cube[2, inside]]

    # Trilinear interpolation from the cube's corners (fractions 0 or 1/2 per axis).
    ii = fi[:, use]
    frac = (ii % 2) * 0.5
    base = ii // 2
    r_acc = np.zeros(ii.shape[1], dtype=np.complex128)
    x_acc = np.zeros(ii.shape[1])
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                w = ((frac[0] if di else 1 - frac[0]) * (frac[1] if dj else 1 - frac[1])
                     * (frac[2] if dk else 1 - frac[2]))  # fmt: skip
                nz = w > 0
                ci, cj, ck = base[0, nz] + di, base[1, nz] + dj, base[2, nz] + dk
                r_acc[nz] += w[nz] * rho_c[ci, cj, ck]
                x_acc[nz] += w[nz] * xi_c[ci, cj, ck]
    rho[ii[0], ii[1], ii[2]] = r_acc
    xi[ii[0], ii[1], ii[2]] = x_acc

    ex = fi[:, ~use]
    if ex.shape[1]:
        pts = np.stack([xs[ex[0]], ys[ex[1]], zs[ex[2]]], axis=1)

        def fine_progress(f: float) -> None:
            if progress is not None:
                progress(coarse_share + (1.0 - coarse_share) * f)

        hints = _hints(ex, pts, (xs[::2], ys[::2], zs[::2]), xi_c, exact_c)
        out = evaluate(pts, fine_progress, hints)
        rho[ex[0], ex[1], ex[2]] = out[:, 0] + 1j * out[:, 1]
        xi[ex[0], ex[1], ex[2]] = out[:, 2]
        exact[ex[0], ex[1], ex[2]] = True
    elif progress is not None:
        progress(1.0)
    counts = {"exact": counts["exact"] + int(ex.shape[1]),
              "interpolated": counts["interpolated"] + int(use.sum())}  # fmt: skip
    return rho, xi, exact, counts


def _hints(fine: np.ndarray, pts: np.ndarray, coarse_axes: tuple[np.ndarray, ...],
           xi_c: np.ndarray, exact_c: np.ndarray) -> np.ndarray:  # fmt: skip
    """(k, 2) what the exactly evaluated corners of its cube tell of each fine sample.

    A corner ``q`` evaluated exactly with signed distance ``x``, ``d`` from the sample: no
    surface lies within ``|x|`` of ``q``, so the sample's distance is at most ``|x| + d``
    and, when ``|x| > d`` (by more than ``2 EPS_FLOOR``, so that it is not within the
    regularisation distance of the surface either), it lies on ``q``'s side. Column 0: the
    least such bound (``inf`` if none); column 1: the side (+1 outside, -1 inside, 0
    unknown). Interpolated corners are not used: their ``xi`` is not a distance.
    """
    hints = np.empty((pts.shape[0], 2))
    hints[:, 0] = np.inf
    hints[:, 1] = 0.0
    base = fine // 2
    limit = np.asarray(xi_c.shape)[:, None] - 1
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                c = np.minimum(base + np.array([[di], [dj], [dk]]), limit)
                ok = exact_c[c[0], c[1], c[2]]
                x = np.abs(xi_c[c[0], c[1], c[2]])
                q = np.stack([coarse_axes[a][c[a]] for a in range(3)], axis=1)
                d = np.linalg.norm(pts - q, axis=1)
                np.minimum(hints[:, 0], np.where(ok, x + d, np.inf), out=hints[:, 0])
                # (by more than the regularisation distance: a sample on the surface
                # counts as inside whatever side its neighbour is on)
                known = ok & (x > d + 2.0 * _c.EPS_FLOOR)
                hints[known, 1] = np.sign(xi_c[c[0], c[1], c[2]])[known]
    return hints
