"""Translational energy landscapes: E(t) (and F(t)) on a regular grid of translations.

Works on a pair's :class:`~engine.correlation.tables.Spectra`: for one rotation ``R`` of
the moving part, :func:`compute_landscape` computes the score for every translation of the
FFT lattice with one inverse FFT (three more for the force). The result is a
:class:`Landscape`: the energy on an ``(N, N, N)`` float32 grid of translations
``t = t0 + h * (i, j, k)``, optionally the force on the same grid, 2D sections for views,
and a lookup for scenes that lock the rotation.

:func:`compute_landscape` reads only the immutable spectra and returns a new immutable
object, so it may run on a worker thread while poses are evaluated. It raises
:class:`LandscapeError` when a landscape cannot be computed (and
:class:`engine.errors.Cancelled` when cancelled).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.fft

from engine.backend import thread_budget
from engine.correlation.finishing import Evaluation, overlap_bounds
from engine.correlation.interpolation import hermite
from engine.correlation.reference import interpolate_rows
from engine.correlation.spectrum import cube_weights, kept_indices
from engine.correlation.tables import ModeTable, Spectra, cube_reach, largest_modes
from engine.errors import Cancelled

PLANES = ("xy", "xz", "yz")


class LandscapeError(RuntimeError):
    """A translational energy landscape could not be computed (the message says why)."""


@dataclass(frozen=True)
class Landscape:
    """Energy (and force) over a grid of translations, for one fixed rotation.

    Attributes
    ----------
    energy : (N, N, N) float32
        ``E(t)`` at ``t = (x[i], y[j], z[k])``; exactly 0 where the parts' grid boxes
        cannot overlap.
    force : (3, N, N, N) float32 or None
        ``F(t) = -dE/dt``, when computed.
    translations : tuple of three (N,) float64
        Translation axes ``x, y, z`` (part 2 relative to part 1, part 1's frame).
    rotation : (3, 3) float64
        The rotation of part 2 the landscape is for.
    modes : int
        Modes per axis kept in the sum.
    seconds : float
        Time taken to compute it.
    """

    energy: np.ndarray
    force: np.ndarray | None
    translations: tuple[np.ndarray, np.ndarray, np.ndarray]
    rotation: np.ndarray
    modes: int
    seconds: float = 0.0

    @property
    def spacing(self) -> float:
        """Translation step (the grid spacing ``h``)."""
        x = self.translations[0]
        return float(x[1] - x[0]) if len(x) > 1 else 1.0

    def minimum(self) -> tuple[np.ndarray, float]:
        """Translation (3,) float64 of the lowest energy sample, and that energy."""
        idx = np.unravel_index(int(np.argmin(self.energy)), self.energy.shape)
        t = np.array([ax[i] for ax, i in zip(self.translations, idx, strict=True)])
        return t, float(self.energy[idx])

    def section(
        self, plane: str = "xy", offset: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A plane of the landscape, linearly interpolated at ``offset`` along its normal.

        Parameters
        ----------
        plane : {"xy", "xz", "yz"}
            The two translation axes spanning the section.
        offset : float
            Translation along the remaining axis.

        Returns
        -------
        energy : (nu, nv) float32
            Indexed ``[u, v]`` by the plane's first and second axis.
        u, v : (nu,), (nv,) float64
            The axes' translation values.
        """
        if plane not in PLANES:
            raise ValueError(f"unknown plane {plane!r}; valid: {', '.join(PLANES)}")
        normal = {"xy": 2, "xz": 1, "yz": 0}[plane]
        axes = [a for a in range(3) if a != normal]
        coord = self.translations[normal]
        pos = (offset - coord[0]) / self.spacing
        if pos < 0 or pos > len(coord) - 1:
            raise ValueError(
                f"offset {offset:g} is outside the landscape "
                f"[{coord[0]:g}, {coord[-1]:g}] along {'xyz'[normal]}"
            )
        i0 = min(int(np.floor(pos)), len(coord) - 2)
        frac = pos - i0
        a = np.take(self.energy, i0, axis=normal)
        b = np.take(self.energy, i0 + 1, axis=normal)
        energy = ((1.0 - frac) * a + frac * b).astype(np.float32)
        return energy, self.translations[axes[0]], self.translations[axes[1]]

    def lookup(self, translation: np.ndarray) -> Evaluation:
        """Energy and force at one translation.

        With the force field present the energy is interpolated by the cubic Hermite
        scheme of :func:`engine.correlation.interpolation.hermite` (the force is the
        energy's derivative on the lattice) and the force returned is minus the gradient
        of that interpolant, so a part moving in a locked-rotation scene sees a
        conservative field. Without it, the energy is trilinear and the force zero.

        Parameters
        ----------
        translation : (3,) float
            Part 2 relative to part 1 (with this landscape's rotation).

        Returns
        -------
        Evaluation
            ``torque`` is None (the rotation is locked); outside the landscape the energy
            and force are 0 (the parts' grid boxes do not overlap there). The force is
            zeros when the landscape was computed with ``forces=False``.
        """
        start = time.perf_counter()
        t = np.asarray(translation, dtype=np.float64).reshape(3)
        origin = np.array([ax[0] for ax in self.translations])
        n = np.array(self.energy.shape)
        pos = (t - origin) / self.spacing
        if np.any(~np.isfinite(pos)) or np.any(pos < 0) or np.any(pos > n - 1):
            energy = 0.0
            force = np.zeros(3)
        else:
            i0 = np.minimum(np.floor(pos).astype(int), n - 2)
            fr = pos - i0
            wx = np.array([1 - fr[0], fr[0]])
            wy = np.array([1 - fr[1], fr[1]])
            wz = np.array([1 - fr[2], fr[2]])
            weights = wx[:, None, None] * wy[None, :, None] * wz[None, None, :]  # (2, 2, 2)
            sl = (slice(i0[0], i0[0] + 2), slice(i0[1], i0[1] + 2), slice(i0[2], i0[2] + 2))
            if self.force is not None:
                energy, force = _hermite_lookup(self.energy[sl], self.force[(slice(None),) + sl],
                                                fr, self.spacing)
            else:
                energy = float(np.sum(weights * self.energy[sl]))
                force = np.zeros(3)
        return Evaluation(
            energy=energy,
            force=force,
            torque=None,
            microseconds=(time.perf_counter() - start) * 1e6,
            modes=self.modes,
        )


def _hermite_lookup(
    energy: np.ndarray, force: np.ndarray, frac: np.ndarray, spacing: float
) -> tuple[float, np.ndarray]:
    """Energy and ``-grad`` of the cubic Hermite interpolant in one lattice cell.

    ``energy`` (2, 2, 2) and ``force`` (3, 2, 2, 2) at the cell's corners, ``frac`` (3,) the
    position in the cell. The corners become rows ``4 dx + 2 dy + dz`` of a table whose
    columns are the energy and its lattice derivatives ``dE/du = -F h`` (the layout
    :func:`engine.correlation.interpolation.hermite` reads, imaginary columns zero).
    """
    table = np.zeros((8, 8))
    table[:, 0] = energy.reshape(8)
    for a in range(3):
        table[:, 2 + 2 * a] = -spacing * force[a].reshape(8)
    cell = (0, 2, 4, 6, float(frac[0]), float(frac[1]), float(frac[2]))
    g, gx, gy, gz = hermite(table, 0, cell)
    return float(g), np.array([-gx, -gy, -gz]) / spacing


def compute_landscape(
    spectra: Spectra,
    rotation: np.ndarray,
    modes: int,
    *,
    forces: bool = True,
    table: ModeTable | None = None,
    lattice: int | None = None,
    real: bool = False,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> Landscape:
    """Energy (and force) over every lattice translation, by one inverse FFT each.

    The translations are ``t = c1 - R c2 + h * j`` for ``j = -N/2 ... N/2 - 1`` per axis
    (centred on the pose that puts the two grid centres together), which covers every
    translation at which the grid boxes overlap; elsewhere the energy is 0 (as the per-pose
    path says). The kept modes, their interpolation and the energy scale are the per-pose
    path's: at a lattice translation the landscape equals the per-pose energy.

    Parameters
    ----------
    spectra : Spectra
        The pair's spectra (read only).
    rotation : (3, 3) float
        Rotation of part 2 relative to part 1.
    modes : int
        Modes per axis ``K`` (clipped to ``N``).
    forces : bool
        Also compute the force field (three more inverse FFTs).
    table : ModeTable, optional
        The current truncation, whose mode list is reused when it has ``modes`` modes
        (selection "largest").
    lattice : int, optional
        Samples per axis of the translation lattice (default ``N``, the FFT size: a step
        of ``h``). The kept modes are band-limited, so any even ``M`` above twice the
        largest kept ``|k|`` samples the same function over the same period ``N h`` at a
        step of ``N h / M``, by an ``M^3`` transform instead of ``N^3`` (the rotation
        search scans at ``M`` near ``2 K``).
    real : bool
        Inverse-transform only the Hermitian part of each spectrum (``irfftn``, half the
        work): the energy and force are real parts, so the result is the same to float32
        rounding. It costs a mirrored copy of each ``M^3`` spectrum.
    progress, cancel
        Fractions 0..1; a cancel returning True raises :class:`engine.errors.Cancelled`.

    Raises
    ------
    LandscapeError
        The rotation is not a finite rotation matrix, or the landscape does not fit in
        memory.
    """
    start = time.perf_counter()

    def step(fraction: float) -> None:
        if cancel is not None and cancel():
            raise Cancelled("the landscape was cancelled")
        if progress is not None:
            progress(fraction)

    rot = np.asarray(rotation, dtype=np.float64)
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)) or not np.allclose(
            rot @ rot.T, np.eye(3), atol=1e-6):
        raise LandscapeError(f"the landscape needs a finite 3 x 3 rotation matrix, got "
                             f"{np.array2string(rot, precision=4)}")
    step(0.0)
    try:
        return _landscape(spectra, rot, modes, forces, table, step, start,
                          lattice=lattice, real=real)
    except MemoryError as exc:
        n = spectra.geometry.size
        raise LandscapeError(
            f"the landscape over {n}^3 translations needs about "
            f"{(5 if forces else 2) * 8 * n**3 / 2**30:.1f} GiB more memory than is free: "
            "ask for it without forces, or use a coarser grid") from exc


def _centring_phase(sel: tuple[np.ndarray, ...], n: int) -> np.ndarray:
    """``(-1)^(kx + ky + kz)`` at the kept modes: the inverse FFT comes out centred.

    An inverse FFT of a spectrum times ``exp(-2 pi i (k . s) / n)`` is the inverse FFT
    rolled by ``s`` along each axis; with ``s = n / 2`` (``n`` is even: the correlator makes
    it so) the factor is ``(-1)^(kx + ky + kz)``, exactly, and the roll is the one
    ``np.fft.fftshift`` makes: the translation ``j = 0`` lands at index ``n / 2``. The sign
    touches the ``K^3`` kept modes only; ``fftshift`` copied the whole grid (four times
    with forces) in slices that held the interpreter lock for up to a few milliseconds
    each, and a loop thread waiting for the lock missed its period.

    ``sel`` is the index of the kept modes into the ``(n, n, n)`` spectrum: an open mesh
    (``np.ix_``) or three index arrays; the result broadcasts as ``spectrum[sel]``.
    """
    if n % 2:
        raise ValueError(f"the landscape's FFT size must be even, got {n}")
    odd = np.zeros((), dtype=np.int64)
    for index in sel:
        odd = odd + np.asarray(index, dtype=np.int64)
    return np.where(odd % 2 == 1, np.float32(-1.0), np.float32(1.0))


def _real_ifft(spectrum: np.ndarray) -> np.ndarray:
    """``Re ifftn(spectrum)`` (M, M, M) by ``irfftn`` of its Hermitian part's half."""
    m = spectrum.shape[0]
    neg = (-np.arange(m)) % m
    half = m // 2 + 1
    mirrored = spectrum[np.ix_(neg, neg, neg[:half])]  # S(-k) on the half the transform reads
    folded = np.add(spectrum[:, :, :half], np.conj(mirrored, out=mirrored), out=mirrored)
    folded *= np.float32(0.5)
    return scipy.fft.irfftn(folded, s=spectrum.shape, overwrite_x=True,
                            workers=thread_budget())


def _landscape(
    spectra: Spectra, rot: np.ndarray, modes: int, forces: bool, table: ModeTable | None,
    step: Callable[[float], None], start: float, *, lattice: int | None = None,
    real: bool = False,
) -> Landscape:
    g = spectra.geometry
    big = g.size
    k_modes = min(int(modes), big)
    if k_modes < 1:
        raise LandscapeError(f"modes per axis must be at least 1, got {modes}")
    n = big if lattice is None else int(lattice)
    if n != big:
        widest = (k_modes // 2 if spectra.selection == "cube"
                  else int(np.abs(largest_modes(spectra, k_modes)[0]).max()))
        if n % 2 or n <= 2 * widest or n > big:
            raise LandscapeError(
                f"a translation lattice of {n} samples cannot hold modes up to |k| = "
                f"{widest} of an FFT of {big}: ask for an even size from {2 * widest + 2} "
                f"to {big}")
    h = g.n_h / n  # the lattice step: g.spacing when n is the FFT size
    if spectra.selection == "cube":
        kept = kept_indices(k_modes, big)
        wrapped = np.mod(kept, n)
        sel: tuple[np.ndarray, ...] = np.ix_(wrapped, wrapped, wrapped)
        in_fixed = np.ix_(*(np.mod(kept, big),) * 3)  # part 1's spectrum has N per axis
        kf = kept.astype(np.float64)
        # every kept mode in one call: per call the interpolation's numpy overhead was
        # most of a landscape's time at the search's K (13 calls of 169 rows at K = 12)
        kvec = np.stack(np.meshgrid(kf, kf, kf, indexing="ij"), axis=-1).reshape(-1, 3)
        values = interpolate_rows(spectra, kvec @ rot, cube_reach(k_modes),
                                  False)[0].astype(np.complex64).reshape((len(kept),) * 3)
    else:
        if table is not None and table.modes == k_modes and table.mode_k is not None:
            kvec_int, reach = table.mode_k.astype(np.int64), table.reach
        else:
            kvec_int, reach = largest_modes(spectra, k_modes)
        wrapped = np.mod(kvec_int, n)
        sel = (wrapped[:, 0], wrapped[:, 1], wrapped[:, 2])
        in_fixed = tuple(np.mod(kvec_int[:, a], big) for a in range(3))
        values = interpolate_rows(spectra, kvec_int.astype(np.float64) @ rot, reach,
                                  False)[0].astype(np.complex64)
    step(0.3)
    coeff = spectra.fixed.values[in_fixed].astype(np.complex64)
    if spectra.selection == "cube":
        # the band's weights: tapered, and 0 outside a ball, where the band says so
        coeff *= cube_weights(k_modes, big, band=spectra.band).astype(np.float32)
    # f(t0 + h j) = sum_k rho1c^ rho2c^ dw exp(2 pi i k.j / N), with t0 + R c2 - c1 = 0,
    # for j = -N/2 ... N/2 - 1: the centring phase puts j = 0 at index N // 2
    spectrum = np.zeros((n, n, n), dtype=np.complex64)
    terms = coeff * values * _centring_phase(sel, n) * np.float32(1.0 / g.n_h ** 3)
    if spectra.selection == "cube" and len(kept) > n:
        # the whole even band: -N/2 and +N/2 wrap onto one index, each half of it
        np.add.at(spectrum, sel, terms)
    else:
        spectrum[sel] = terms
    scale = float(n) ** 3
    # The transforms run in place (overwrite_x) in one work array, the energy's last in the
    # spectrum itself: a new N^3 array per transform, allocated and freed while the
    # interpreter lock is held, kept a thread beside this one waiting for milliseconds.
    force = None
    if forces:
        force = np.empty((3, n, n, n), dtype=np.float32)
        work = np.empty_like(spectrum)
        freq = (np.fft.fftfreq(n, 1.0 / n) / g.n_h).astype(np.float32)
        for a in range(3):
            shape = [1, 1, 1]
            shape[a] = n
            np.multiply(spectrum, np.complex64(2j * np.pi) * freq.reshape(shape), out=work)
            part = (_real_ifft(work) if real
                    else scipy.fft.ifftn(work, overwrite_x=True, workers=thread_budget()).real)
            np.multiply(part, g.kappa * scale, out=force[a])
            del part
            step(0.15 * (a + 1) + 0.3)
        del work
    field = (_real_ifft(spectrum) if real
             else scipy.fft.ifftn(spectrum, overwrite_x=True, workers=thread_budget()).real)
    del spectrum
    energy = np.multiply(field, -g.kappa * scale, dtype=np.float32)
    del field
    step(0.9)
    t0 = g.centre_fixed - rot @ g.centre_moving
    axes = (t0[0] + h * (np.arange(n) - n // 2), t0[1] + h * (np.arange(n) - n // 2),
            t0[2] + h * (np.arange(n) - n // 2))
    # zero where the grid boxes cannot overlap (the per-pose path's test)
    offset, reach = overlap_bounds(rot, g.centre_fixed, g.centre_moving, g.half_fixed,
                                   g.half_moving, g.spacing)
    masks = [np.abs(axes[a] + offset[a]) < reach[a] for a in range(3)]
    inside = masks[0][:, None, None] & masks[1][None, :, None] & masks[2][None, None, :]
    np.multiply(energy, inside, out=energy)  # a ufunc: the lock released, unlike a mask
    if force is not None:
        np.multiply(force, inside, out=force)
    step(1.0)
    return Landscape(energy=energy, force=force, translations=axes, rotation=rot,
                     modes=k_modes, seconds=time.perf_counter() - start)
