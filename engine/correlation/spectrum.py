"""Spectra of descriptors: zero-padded FFTs of (nx, ny, nz) complex64 fields, centred.

A spectrum here is the continuous Fourier transform ``rho^(w) = integral rho(p)
exp(-2 pi i w.p) dV`` of a sampled field, evaluated on the frequency lattice
``w = k / (M h)`` (``k`` integer, FFT order, ``M`` the padded size, ``h`` the grid
spacing), *relative to the grid centre* ``c``::

    values[k] = h^3 * sum_n rho[n] exp(-2 pi i w.(x_n - c))      (x_n = origin + h n)

so that ``rho^(w) = exp(-2 pi i w.c) * values[k]``. Centring keeps the phase of the
spectrum slowly varying, which is what makes interpolating it at rotated frequencies
accurate. For the moving part the three moment spectra ``(q - c) rho(q)`` are computed as
well (torque); ``q rho(q)`` about the part's origin is ``moments + c * values``.

Spectra are cached on disk through :mod:`engine.cache`, keyed by the field's bytes, the
grid, the padded size, whether moments were asked for, and a digest of this package's code
(a change to it never serves a stale spectrum).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.fft

from engine import cache
from engine.backend import thread_budget
from engine.grid import Grid, check_fft_memory

#: Bumped whenever the stored layout or the definition of a spectrum changes.
SPECTRUM_VERSION = 2


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """Digest of the code that shapes a cached spectrum (this package's folder)."""
    return cache.code_digest(__name__)


def fast_size(target: int) -> int:
    """Smallest even integer ``>= target`` whose prime factors are all 2, 3, 5 or 7.

    Even sizes keep the Nyquist frequency on the lattice, so the band is symmetric
    around zero except for that one plane.
    """
    n = max(2, int(target))
    while True:
        if n % 2 == 0:
            m = n
            for p in (2, 3, 5, 7):
                while m % p == 0:
                    m //= p
            if m == 1:
                return n
        n += 1


@dataclass(frozen=True)
class Spectrum:
    """Centred spectrum of a descriptor on an ``(M, M, M)`` frequency lattice.

    Attributes
    ----------
    values : (M, M, M) complex64
        ``h^3 sum rho[n] exp(-2 pi i w.(x_n - c))`` at ``w = k / (M h)``, FFT order.
    moments : (3, M, M, M) complex64 or None
        The same transform of ``(q - c) * rho(q)``, one per axis; None when not asked for.
    centre : (3,) float64
        The grid centre ``c`` the phases refer to (part frame).
    spacing : float
        Grid spacing ``h``.
    size : int
        Padded FFT size ``M`` (frequency step ``1 / (M h)``).
    from_cache : bool
        Whether the arrays were read from the on-disk cache.
    """

    values: np.ndarray
    moments: np.ndarray | None
    centre: np.ndarray
    spacing: float
    size: int
    from_cache: bool = False

    @property
    def frequency_step(self) -> float:
        """Distance ``1 / (M h)`` between neighbouring lattice frequencies."""
        return 1.0 / (self.size * self.spacing)


def _centred_ramp(n: int, size: int) -> np.ndarray:
    """(size,) complex128 ``exp(2 pi i k (n - 1) / (2 size))`` for signed FFT-order ``k``."""
    k = np.fft.fftfreq(size, 1.0 / size)  # signed integers, FFT order
    return np.exp(2j * np.pi * k * (n - 1) / (2.0 * size))


def _padded_fft(field: np.ndarray, size: int, ramps: list[np.ndarray], scale: float) -> np.ndarray:
    """FFT of ``field`` zero-padded to ``size^3``, times the centring ramps and ``scale``."""
    padded = np.zeros((size, size, size), dtype=np.complex64)
    nx, ny, nz = field.shape
    padded[:nx, :ny, :nz] = field
    out = scipy.fft.fftn(padded, workers=thread_budget(), overwrite_x=True)
    out *= ramps[0].astype(np.complex64)[:, None, None] * np.complex64(scale)
    out *= ramps[1].astype(np.complex64)[None, :, None]
    out *= ramps[2].astype(np.complex64)[None, None, :]
    return out


def compute_spectrum(
    rho: np.ndarray,
    grid: Grid,
    size: int,
    *,
    moments: bool = False,
    use_cache: bool = True,
) -> Spectrum:
    """Centred, zero-padded spectrum of one descriptor field (cached).

    Parameters
    ----------
    rho : (nx, ny, nz) complex64
        Descriptor samples on ``grid``.
    grid : Grid
        Where the samples lie (part frame).
    size : int
        Padded FFT size ``M`` along every axis, at least ``max(grid.shape)``.
    moments : bool
        Also compute the three moment spectra of ``(q - c) rho(q)`` (for the torque).
    use_cache : bool
        Read and write the on-disk cache.

    Returns
    -------
    Spectrum
    """
    rho = np.asarray(rho)
    if rho.ndim != 3 or tuple(rho.shape) != tuple(grid.shape):
        raise ValueError(
            f"descriptor shape {rho.shape} does not match its grid shape {grid.shape}"
        )
    if size < max(grid.shape):
        raise ValueError(f"FFT size {size} is smaller than the grid {grid.shape}")
    if not np.all(np.isfinite(rho)):
        raise ValueError("descriptor contains NaN or infinite values: recompute the descriptor")
    # the padded cube and the FFT's output, plus the three moment cubes and a temporary
    check_fft_memory(size, 2 + 4 * int(moments), f"the spectrum's {size}^3 FFT")
    rho = rho.astype(np.complex64, copy=False)
    h = grid.spacing

    def compute() -> dict[str, np.ndarray]:
        ramps = [_centred_ramp(n, size) for n in grid.shape]
        arrays = {"values": _padded_fft(rho, size, ramps, h**3)}
        if moments:
            out = np.empty((3, size, size, size), dtype=np.complex64)
            for axis, n in enumerate(grid.shape):
                offset = h * (np.arange(n) - 0.5 * (n - 1))  # q - c along this axis
                shape = [1, 1, 1]
                shape[axis] = n
                weighted = rho * offset.reshape(shape).astype(np.float32)
                out[axis] = _padded_fft(weighted, size, ramps, h**3)
            arrays["moments"] = out
        return arrays

    key = {
        "version": SPECTRUM_VERSION,
        "code": code_digest(),
        "rho": rho,
        "origin": list(grid.origin),
        "spacing": grid.spacing,
        "shape": list(grid.shape),
        "size": int(size),
        "moments": bool(moments),
    }
    arrays, hit = cache.load_or_compute("spectrum", key, compute, use_cache=use_cache)
    return Spectrum(
        values=arrays["values"],
        moments=arrays.get("moments"),
        centre=np.asarray(grid.centre, dtype=np.float64),
        spacing=h,
        size=int(size),
        from_cache=hit,
    )


def kept_indices(modes: int, size: int) -> np.ndarray:
    """Signed frequency indices kept along one axis for ``modes`` per axis: a symmetric band.

    ``-(modes // 2) ... modes // 2``: ``modes`` indices when ``modes`` is odd, ``modes + 1``
    when it is even, the two end indices ``+-modes / 2`` then weighted by one half
    (:func:`kept_weights`). A band symmetric about zero keeps the truncated correlation's
    symmetries: a pair mirror-symmetric about a plane through the grid centres feels no
    force across that plane at its seat, at every K. The lopsided band ``-K/2 ... K/2 - 1``
    of an even K kept ``-K/2`` without ``+K/2`` and pushed such a pair sideways (by 0.4 N
    on the bundled peg at its seat at K = 16). At ``modes == size`` (even) both ends wrap
    onto the Nyquist index, each with half its weight: the whole lattice, weighted once.

    Returns
    -------
    (modes,) or (modes + 1,) int64
    """
    if not 1 <= modes <= size:
        raise ValueError(f"modes per axis must be between 1 and the FFT size {size}, got {modes}")
    half = modes // 2
    return np.arange(-half, half + 1, dtype=np.int64)


#: The tapers :func:`kept_weights` knows. "lanczos" weighs mode ``k`` of the band
#: ``-(K // 2) ... K // 2`` by Lanczos' sigma factor ``sinc(k / (K // 2 + 1))`` per axis;
#: "none" keeps the box band. A box band of a sharp density rings (Gibbs): along the normal
#: of two big flat faces the energy at K = 25 rose and fell in barriers up to 20 times the
#: correlation's own, and they held a generated plate 30 % of its width short of its pins,
#: which the taper seats (docs/correlation.md).
TAPERS = ("lanczos", "none")
#: The shapes :func:`cube_weights` knows. "ball" keeps the modes of the cube
#: ``-(K // 2) ... K // 2`` whose signed index ``k`` has ``|k| <= K // 2 + 1/2``; "cube" keeps
#: the whole cube. A cube is not turned with the parts: a pair mirror-symmetric about a plane
#: that is not a plane of the grid feels a force across it at a symmetric pose, as the
#: cube's corners reach further along some directions than along their mirror images. The
#: ball is the same along every direction (the FFT lattice has one size and one spacing
#: along every axis).
SHAPES = ("ball", "cube")


@dataclass(frozen=True)
class Band:
    """Which modes the modal sum keeps, how it weighs them, and of which densities.

    Attributes
    ----------
    shape : {"cube", "ball"}
        The kept modes (:data:`SHAPES`).
    taper : {"none", "lanczos"}
        Their weights (:data:`TAPERS`).
    windowed : bool
        Whether each density's outside tail is ended by a window that follows its part
        (:func:`engine.correlation.support.supported`) before it is transformed, rather
        than where its grid's box cuts it.
    """

    shape: str = "cube"
    taper: str = "none"
    windowed: bool = False

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"unknown band shape {self.shape!r}; valid: {', '.join(SHAPES)}")
        if self.taper not in TAPERS:
            raise ValueError(f"unknown band taper {self.taper!r}; valid: {', '.join(TAPERS)}")


#: The bands by name (``CorrelationParams.band``). "box": the cube of modes, untapered, of
#: the densities as their grids cut them: the correlation's plain truncation, what the
#: search ranks with and the landscape tests judge. "smooth": the ball, Lanczos-tapered, of
#: the windowed densities: the same along every direction and without the box band's
#: ringing, what guides a part (:data:`engine.params.GUIDANCE_BAND`; docs/fine_level.md).
BANDS = {"box": Band(), "smooth": Band("ball", "lanczos", True)}


def band_named(name: str | Band) -> Band:
    """The :class:`Band` called ``name`` in :data:`BANDS` (a Band passes through)."""
    if isinstance(name, Band):
        return name
    try:
        return BANDS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown band {name!r}; valid: {', '.join(BANDS)}") from None


def kept_weights(modes: int, size: int | None = None, *, taper: str = "none"
                 ) -> np.ndarray:
    """(L,) float64 weights of :func:`kept_indices`'s band, tapered as ``taper``.

    An even K keeps ``+-K/2`` at half weight, between the odd bands ``K - 1`` and ``K + 1``
    (their average), so the correlation changes smoothly with K. With ``taper="lanczos"``
    a truncated band (``modes < size``, or ``size`` None) is then multiplied by Lanczos'
    sigma factors, which damp the band's ringing; the whole lattice (``modes == size``) is
    no truncation and is kept untapered, every mode once. A mode's weight in
    the cube is the product of its three axes' weights.
    """
    if taper not in TAPERS:
        raise ValueError(f"unknown band taper {taper!r}; valid: {', '.join(TAPERS)}")
    half = int(modes) // 2
    weights = np.ones(2 * half + 1, dtype=np.float64)
    if modes % 2 == 0 and half > 0:
        weights[0] = weights[-1] = 0.5
    if taper == "lanczos" and (size is None or modes < size):
        weights *= np.sinc(np.arange(-half, half + 1) / (half + 1))
    return weights


def cube_weights(modes: int, size: int | None = None, *, band: Band = BANDS["box"]
                 ) -> np.ndarray:
    """(L, L, L) float64: the kept cube's mode weights for ``band``.

    The outer product of :func:`kept_weights` along the three axes, times 0 outside the
    ball of radius ``K // 2 + 1/2`` when the band is a ball and truncated (``modes <
    size``, or ``size`` None).
    """
    w = kept_weights(modes, size, taper=band.taper)
    cube = w[:, None, None] * w[None, :, None] * w[None, None, :]
    if band.shape == "ball" and (size is None or modes < size):
        half = int(modes) // 2
        k = np.arange(-half, half + 1, dtype=np.float64) ** 2
        cube = cube * ((k[:, None, None] + k[None, :, None] + k[None, None, :])
                       <= (half + 0.5) ** 2)
    return cube


def refined_table(
    rho: np.ndarray,
    grid: Grid,
    size: int,
    refine: int,
    radius: int,
    *,
    moments: bool = False,
    use_cache: bool = True,
) -> np.ndarray:
    """Centred spectrum on a ``refine`` times finer lattice, in a cube around ``w = 0``.

    The values at ``w = j / (refine * size * h)`` for ``j = -radius ... radius + 1`` per
    axis, computed exactly (no interpolation) as the separable Fourier sum of the samples:
    ``h^3 sum_n rho[n] prod_a exp(-2 pi i w_a (x_a - c_a))``, one contraction per axis with
    a ``(B, n_a)`` table of phases. Only the ``B^3`` wanted frequencies are
    computed, so this costs far less than the ``refine^3`` zero-padded FFTs of size
    ``size`` that give the same lattice. This is what the interpolation at rotated
    frequencies reads; its error falls as ``refine^-2`` for trilinear interpolation and
    faster for the cubic Hermite one.

    Parameters
    ----------
    rho : (nx, ny, nz) complex64
    grid : Grid
    size : int
        Coarse FFT size (frequency step ``1 / (size h)``).
    refine : int
        Refinement factor (>= 1).
    radius : int
        Fine index 0 lies at position ``radius`` along each axis.
    moments : bool
        Also tabulate the three moment spectra of ``(q - c) rho(q)``.

    Returns
    -------
    (B, B, B, C) float32
        ``B = 2 radius + 2``; ``C = 8`` (values, then moments x, y, z; real and imaginary
        parts interleaved) or ``C = 2`` without moments.
    """
    rho = np.asarray(rho).astype(np.complex64, copy=False)
    if refine < 1 or radius < 1:
        raise ValueError(f"refine and radius must be positive, got {refine}, {radius}")
    h = grid.spacing

    def compute() -> dict[str, np.ndarray]:
        side = 2 * radius + 2
        fine = np.arange(-radius, radius + 2, dtype=np.float64)
        phases, offsets = [], []
        for n in grid.shape:
            offset = h * (np.arange(n) - 0.5 * (n - 1))  # (n,) x - c along this axis
            # (B, n): h exp(-2 pi i w_j (x_n - c)), w_j = j / (refine size h)
            angle = -2.0 * np.pi * np.outer(fine, offset) / (refine * size * h)
            phases.append((h * np.exp(1j * angle)).astype(np.complex64))
            offsets.append(offset.astype(np.float32))
        channels = [_separable_sum(rho, phases)]
        if moments:
            for axis in range(3):
                weighted = list(phases)
                weighted[axis] = phases[axis] * offsets[axis][None, :]
                channels.append(_separable_sum(rho, weighted))
        out = np.empty((side, side, side, 2 * len(channels)), dtype=np.float32)
        for c, values in enumerate(channels):
            out[..., 2 * c] = values.real
            out[..., 2 * c + 1] = values.imag
        return {"table": out}

    key = {
        "version": SPECTRUM_VERSION,
        "code": code_digest(),
        "rho": rho,
        "origin": list(grid.origin),
        "spacing": grid.spacing,
        "shape": list(grid.shape),
        "size": int(size),
        "refine": int(refine),
        "radius": int(radius),
        "moments": bool(moments),
    }
    arrays, _ = cache.load_or_compute("spectrum-table", key, compute, use_cache=use_cache)
    return arrays["table"]


def _separable_sum(rho: np.ndarray, phases: list[np.ndarray]) -> np.ndarray:
    """(Bx, By, Bz) complex64 ``sum_n rho[n] Ex[i, nx] Ey[j, ny] Ez[k, nz]``.

    rho (nx, ny, nz) complex64; phases: three (B_a, n_a) complex64 matrices. One contraction
    per axis, z first, each as a sum of ``n_a`` scaled copies: the matrix products are small
    and thin, and BLAS's threads spin badly on a loaded two-core machine (measured: 0.3 to
    0.7 s per call with threads, 10 ms without; this form takes about 30 ms either way).
    """
    ex, ey, ez = phases
    nx, ny, nz = rho.shape
    a = np.zeros((nx, ny, ez.shape[0]), dtype=np.complex64)
    for n in range(nz):
        a += rho[:, :, n, None] * ez[None, None, :, n]
    b = np.zeros((nx, ey.shape[0], ez.shape[0]), dtype=np.complex64)
    for n in range(ny):
        b += ey[None, :, n, None] * a[:, n, None, :]
    out = np.zeros((ex.shape[0], ey.shape[0], ez.shape[0]), dtype=np.complex64)
    for n in range(nx):
        out += ex[:, n, None, None] * b[n][None, :, :]
    return out
