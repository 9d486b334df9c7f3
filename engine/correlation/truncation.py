"""How much of a pair's correlation spectrum a mode count leaves out: a truncation indicator.

Works on two descriptors (``rho (nx, ny, nz) complex64`` on grids of one spacing ``h``) and
the padded FFT size ``N`` of their correlation. The score is a sum over the frequency
lattice ``w = k / (N h)`` of ``rho1^(w)`` times part 2's spectrum at the rotated frequency
and a unit phase; keeping the band of ``K`` at its weights ``W_K(k)``
(:func:`engine.correlation.spectrum.cube_weights`: 1 at ``k = 0``, 0 outside the band's
ball, or cube) drops the rest, so at part 2's scene orientation (``R = I``) the
dropped part of the score is at most

    sum over k of (1 - W_K(k)) |rho1^(k)| |rho2^(k)|

at every translation, and the whole score at most the same sum over every ``k`` of
``|rho1^| |rho2^|``. Their ratio, the *share of the weight outside the band*, bounds the
truncation error of the score (hence the energy) relative to its largest possible value.
The force is the score's gradient in the translation: each term is multiplied by
``2 pi i w``, so with
``quantity="force"`` the weight is ``|k| |rho1^| |rho2^|``, a larger share (the force
reads higher frequencies than the energy). It is a bound, not the error (phases cancel
at most poses), it holds exactly at the unrotated orientation only (a rotation moves
part 2's spectrum around the cube, but its radial fall-off, which decides the share, is
the same), and it says nothing of the interpolation or the descriptor's sampling. It costs
two FFTs once per pair and ``K^3`` terms per K.
"""

from __future__ import annotations

import numpy as np
import scipy.fft

from engine.correlation.spectrum import cube_weights, kept_indices

#: FFT workers (the target machine has two cores).
WORKERS = 2


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
    total = float(weight.sum())
    if not total > 0:
        return np.zeros(size + 1)
    # inside[K]: the kept cube's weight at the band's own weights (an even band's ends at
    # one half, a truncated band tapered), the cube of K being the centre of the shifted
    # lattice; K^3 terms per K
    centred = np.fft.fftshift(weight)
    inside = np.zeros(size + 1)
    for k in range(1, size):
        index = np.mod(kept_indices(k, size) + size // 2, size)
        block = centred[np.ix_(index, index, index)]
        inside[k] = float(np.sum(block * cube_weights(k, size)))
    inside[size] = total  # the whole lattice, untapered (the Nyquist index wraps onto itself)
    return np.clip(1.0 - inside / total, 0.0, 1.0)
