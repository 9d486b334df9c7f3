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
about that to the relative L2 error of the whole grid.

Where the cube's 4 x 4 x 4 stencil (the cube and one coarse sample beyond it on every side)
is inside the grid, on one side and clear of the surface, the samples are interpolated
tricubically instead (separable cubic midpoints, weights -1, 9, 9, -1 over 16) when the
estimated cubic error, ``(3/128) (|d4x| + |d4y| + |d4z|)`` from fourth differences, is
under the same tolerance at every stencil sample, and the signed distance has no kink in
the stencil (:func:`_no_kink`: a cubic across the medial axis misses the cusp by some 16
times what fourth differences say). Far from the surface and inside thick walls the
density is smooth but curved enough that second differences reject many cubes a cubic
passes. A sample on the grid's last face counts as in the last cube along that axis.
docs/descriptor.md gives the measured errors and gains.
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


def _fourth_difference_error(rho: np.ndarray) -> np.ndarray:
    """(nx, ny, nz) estimated tricubic error at midpoints next to each sample.

    The cubic through four equally spaced samples misses the midpoint of its middle
    interval by ``(9/16) (1/24) h^4 f4 = (3/128) d4`` (``f4`` the fourth derivative, ``d4``
    the fourth difference), summed over the three axes. A sample within two of the border
    takes its nearest inner neighbour's.
    """
    est = np.zeros(rho.shape)
    for axis in range(3):
        a = np.moveaxis(rho, axis, 0)
        d4 = np.abs(a[4:] - 4.0 * a[3:-1] + 6.0 * a[2:-2] - 4.0 * a[1:-3] + a[:-4])
        full = np.concatenate([d4[:1], d4[:1], d4, d4[-1:], d4[-1:]], axis=0)
        est += np.moveaxis(full, 0, axis)
    return est * (3.0 / 128.0)


def _no_kink(xi: np.ndarray, stride: float) -> np.ndarray:
    """(nx, ny, nz) True where the signed distance has no kink next to the sample.

    The distance bends smoothly (its second difference is about ``h^2`` over the distance
    to the nearest centre of curvature) except across the medial axis, where its slope
    jumps and the density has a cusp. A cusp hides from fourth differences (a cubic's
    error there is some 16 times what they estimate), so a cubic stencil must not span
    one: every second difference of ``xi`` at most ``ADAPTIVE_KINK`` times the spacing,
    that is, at least ``1 / ADAPTIVE_KINK`` spacings from any centre of curvature.
    """
    ok = np.ones(xi.shape, dtype=bool)
    for axis in range(3):
        a = np.moveaxis(xi, axis, 0)
        d2 = np.abs(a[2:] - 2.0 * a[1:-1] + a[:-2])
        full = np.concatenate([d2[:1], d2, d2[-1:]], axis=0)
        ok &= np.moveaxis(full, 0, axis) <= _c.ADAPTIVE_KINK * stride
    return ok


def _window_all(ok: np.ndarray, side: np.ndarray, width: int) -> np.ndarray:
    """Per window of ``width`` samples along each axis: all ``ok`` and all on one side.

    Window ``(i, j, k)`` spans samples ``i..i+width-1`` along each axis; the result has
    ``n - width + 1`` windows per axis.
    """

    def every(mask: np.ndarray) -> np.ndarray:
        for axis in range(3):
            a = np.moveaxis(mask, axis, 0)
            n = a.shape[0] - width + 1
            acc = a[:n].copy()
            for d in range(1, width):
                acc &= a[d:d + n]
            mask = np.moveaxis(acc, 0, axis)
        return mask

    return every(ok) & (every(side) | every(~side))


def _upsample(c: np.ndarray, *, cubic: bool) -> np.ndarray:
    """``c`` refined to ``2 n - 1`` samples per axis, midpoints interpolated axis by axis.

    Midpoints are linear, or cubic (weights -1, 9, 9, -1 over 16) where two samples lie on
    either side of them (the two end intervals stay linear).
    """
    out = c
    for axis in range(3):
        a = np.moveaxis(out, axis, 0)
        up = np.empty((2 * a.shape[0] - 1, *a.shape[1:]), dtype=a.dtype)
        up[::2] = a
        mid = 0.5 * (a[:-1] + a[1:])
        if cubic and a.shape[0] >= 4:
            mid[1:-1] = (9.0 * (a[1:-2] + a[2:-1]) - (a[:-3] + a[3:])) / 16.0
        up[1::2] = mid
        out = np.moveaxis(up, 0, axis)
    return out


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
        ``"exact"`` and ``"interpolated"`` sample counts, and ``"cubic"``: how many of the
        interpolated ones are tricubic.
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
                {"exact": rho.size, "interpolated": 0, "cubic": 0})  # fmt: skip
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
    limit = _c.ADAPTIVE_TOLERANCE * scale
    clear = np.abs(xi_c) >= _c.ADAPTIVE_CLEARANCE * stride
    side = xi_c > 0
    # A cube (i, j, k) has corners (i..i+1, j..j+1, k..k+1) of the coarse grid; its cubic
    # stencil is (i-1..i+2, ...), so only cubes one node in from the border have one.
    linear = _window_all((_second_difference_error(rho_c) <= limit) & clear, side, 2)
    cubic = np.zeros_like(linear)
    if min(rho_c.shape) >= 5:
        node_ok = (_fourth_difference_error(rho_c) <= limit) & clear & _no_kink(xi_c, stride)
        cubic[1:-1, 1:-1, 1:-1] = _window_all(node_ok, side, 4)

    rho = np.empty(shape, dtype=np.complex128)
    xi = np.empty(shape)
    exact = np.zeros(shape, dtype=bool)
    rho[::2, ::2, ::2] = rho_c
    xi[::2, ::2, ::2] = xi_c
    exact[::2, ::2, ::2] = exact_c
    idx = np.indices(shape).reshape(3, -1)
    fine = np.any(idx % 2 == 1, axis=0)
    fi = idx[:, fine]
    # The cube holding each fine sample (a sample on the grid's last face lies on a face of
    # the last cube along that axis).
    cube = np.minimum(fi // 2, np.asarray(linear.shape)[:, None] - 1)
    use_cubic = cubic[cube[0], cube[1], cube[2]]
    use = linear[cube[0], cube[1], cube[2]] | use_cubic

    # Interpolated values: tricubic where the cube's stencil allows, else trilinear, both
    # separable (midpoints along each axis in turn); xi is always trilinear.
    ii = fi[:, use]
    value = _upsample(rho_c, cubic=False)[ii[0], ii[1], ii[2]]
    if use_cubic.any():
        pick = use_cubic[use]
        value[pick] = _upsample(rho_c, cubic=True)[ii[0, pick], ii[1, pick], ii[2, pick]]
    rho[ii[0], ii[1], ii[2]] = value
    xi[ii[0], ii[1], ii[2]] = _upsample(xi_c, cubic=False)[ii[0], ii[1], ii[2]]

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
              "interpolated": counts["interpolated"] + int(use.sum()),
              "cubic": counts["cubic"] + int(use_cubic.sum())}  # fmt: skip
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
