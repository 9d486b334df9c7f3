"""How much of a pair's correlation spectrum a mode count leaves out: a truncation indicator.

Works on two descriptors (``rho (nx, ny, nz) complex64`` on grids of one spacing ``h``) and
the padded FFT size ``N`` of their correlation. The score is a sum over the frequency
lattice ``w = k / (N h)`` of ``rho1^(w)`` times part 2's spectrum at the rotated frequency
and a unit phase; keeping the cube of ``K`` modes per axis drops the rest, so at part 2's
scene orientation (``R = I``) the dropped part of the score is at most

    sum over k outside the cube of |rho1^(k)| |rho2^(k)|

at every translation, and the whole score at most the same sum over every ``k``. Their
ratio, the *share of the weight outside the cube*, bounds the truncation error of the
score (hence the energy) relative to its largest possible value. The force is the
score's gradient in the translation: each term is multiplied by ``2 pi i w``, so with
``quantity="force"`` the weight is ``|k| |rho1^| |rho2^|``, a larger share (the force
reads higher frequencies than the energy). It is a bound, not the error (phases cancel
at most poses), it holds exactly at the unrotated orientation only (a rotation moves
part 2's spectrum around the cube, but its radial fall-off, which decides the share, is
the same), and it says nothing of the interpolation or the descriptor's sampling. It costs
two FFTs once per pair; every K is then read from one array.
"""

from __future__ import annotations

import numpy as np
import scipy.fft

#: FFT workers (the target machine has two cores).
WORKERS = 2


def smallest_cube(size: int) -> np.ndarray:
    """(size,) int64: for each FFT-ordered index ``k``, the K whose band first reaches it.

    The band of ``K`` keeps ``-(K // 2) ... K // 2``
    (:func:`engine.correlation.spectrum.kept_indices`): ``2 |k|``. ``k`` is kept whole from
    ``K = 2|k| + 1``, and at half weight at ``K = 2|k|`` (an even band's end).
    """
    k = np.fft.fftfreq(size, 1.0 / size).round().astype(np.int64)  # signed indices
    return 2 * np.abs(k)


#: What the weight bounds: the energy (``|rho1^| |rho2^|``) or the force (times ``|k|``).
QUANTITIES = ("energy", "force")


def truncation_profile(fixed, moving, size: int, *, quantity: str = "energy") -> np.ndarray:
    """Share of the correlation spectrum's weight outside the kept cube, for every K.

    Parameters
    ----------
    fixed, moving : descriptor
        Objects with ``.rho`` ((nx, ny, nz) complex64) and ``.grid``, both grids of one
        spacing and no larger than ``size`` along any axis.
    size : int
        The padded FFT size ``N`` of the pair (``Correlator.size``).
    quantity : {"energy", "force"}
        Weight ``|rho1^| |rho2^|`` (energy, score) or ``|k| |rho1^| |rho2^|`` (force).

    Returns
    -------
    outside : (size + 1,) float64
        ``outside[K]`` for ``K = 0 .. size``: 1 at K = 0, 0 at K = size, never increasing.
    """
    if quantity not in QUANTITIES:
        raise ValueError(f"unknown quantity {quantity!r}; valid: {', '.join(QUANTITIES)}")
    shapes = (fixed.rho.shape, moving.rho.shape)
    if any(len(s) != 3 or max(s) > size for s in shapes):
        raise ValueError(f"grids {shapes[0]} and {shapes[1]} must be 3-D and fit the FFT "
                         f"size {size}; pass the pair's Correlator.size")
    a = np.abs(scipy.fft.fftn(fixed.rho, s=(size,) * 3, workers=WORKERS))  # (N, N, N)
    b = np.abs(scipy.fft.fftn(moving.rho, s=(size,) * 3, workers=WORKERS))
    weight = (a * b).astype(np.float64)
    signed = np.fft.fftfreq(size, 1.0 / size)  # (N,) signed indices
    if quantity == "force":
        weight *= np.sqrt(signed[:, None, None] ** 2 + signed[None, :, None] ** 2
                          + signed[None, None, :] ** 2)
    need = smallest_cube(size)
    nx, ny, nz = need[:, None, None], need[None, :, None], need[None, None, :]
    cube = np.maximum(np.maximum(nx, ny), nz)  # (N, N, N): whole from K = cube + 1
    # at K = cube (even) the mode is kept at (1/2)^(axes at the band's end) of its weight
    ends = (nx == cube).astype(np.int64) + (ny == cube) + (nz == cube)
    whole = np.bincount(cube.ravel(), weights=weight.ravel(), minlength=size + 2)
    half = np.bincount(cube.ravel(), weights=(weight * 0.5 ** ends).ravel(),
                       minlength=size + 2)
    total = float(whole.sum())
    if not total > 0:
        return np.zeros(size + 1)
    # inside[K] = sum of modes with cube < K, plus the half-weighted ones with cube == K
    before = np.concatenate([[0.0], np.cumsum(whole)])[: size + 1]
    inside = before + half[: size + 1]
    inside[0] = 0.0  # K = 0 keeps nothing (k = 0 has cube 0)
    inside[size] = total  # the whole lattice (the Nyquist index wraps onto itself)
    return np.clip(1.0 - inside / total, 0.0, 1.0)
