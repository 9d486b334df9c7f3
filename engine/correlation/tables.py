"""Frozen inputs of the per-pose sums: a pair's spectra, and the table of one truncation.

Works on two descriptor fields (``rho (nx, ny, nz) complex64`` on grids of one spacing
``h``), transformed once into :class:`Spectra` (part 1's centred spectrum on the FFT
lattice of size ``N``; part 2's on a lattice ``q`` times finer, with its three moment
spectra; part 2's refined table), and, per mode count ``K``, a :class:`ModeTable`: the
kept modes, part 1's coefficients at them and the slice of part 2's spectra they can reach,
interleaved for the kernels.

Both are immutable once built. Building a :class:`ModeTable` (:func:`truncate`) reads only
the spectra, so it may run on any thread while another evaluates poses with an older
table; the caller swaps the new table in. The per-pose kernels receive a table and never
look at the :class:`~engine.correlation.Correlator`.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import numpy as np

from engine.correlation.spectrum import (
    BANDS,
    Band,
    Spectrum,
    compute_spectrum,
    cube_weights,
    kept_indices,
    refined_table,
)
from engine.correlation.support import supported
from engine.errors import Cancelled
from engine.grid import Grid

TWO_PI = 2.0 * math.pi

P = TypeVar("P")

#: Largest per-pose table (bytes) the compiled kernels get; beyond it (K near the full
#: lattice) evaluation runs on the numpy reference, which reads the spectra in place.
MAX_TABLE_BYTES = 256 << 20


def cube_reach(modes: int) -> float:
    """Largest ``|k|`` of the kept cube, with one step to spare: ``sqrt(3) (K // 2 + 1)``."""
    return math.sqrt(3.0) * (modes // 2 + 1)


def table_radius(reach: float, scale: float) -> int:
    """Table radius (lattice steps) that covers frequencies up to ``reach``, +1."""
    return int(math.ceil(scale * reach)) + 1


@dataclass(frozen=True)
class PairGeometry:
    """The constants of a pair the finishing and the overlap test need.

    Attributes
    ----------
    centre_fixed, centre_moving : (3,) float64
        Grid centres ``c1``, ``c2`` (each part's frame).
    half_fixed, half_moving : (3,) float64
        Half extents of the grid boxes.
    spacing : float
        The shared grid spacing ``h``.
    size : int
        FFT size ``N`` (frequency step ``1 / (N h)``).
    kappa : float
        Energy scale, ``E = -kappa Re f``.
    rotation : bool
        Whether moment spectra exist and the torque is computed.
    """

    centre_fixed: np.ndarray
    centre_moving: np.ndarray
    half_fixed: np.ndarray
    half_moving: np.ndarray
    spacing: float
    size: int
    kappa: float
    rotation: bool

    @property
    def n_h(self) -> float:
        """``N h``: the period of the DFT box."""
        return self.size * self.spacing


@dataclass(frozen=True, eq=False)
class Spectra:
    """What a pair's descriptors are transformed into, once (see :func:`build_spectra`).

    Attributes
    ----------
    geometry : PairGeometry
    fixed : Spectrum
        Part 1's centred spectrum on the ``N`` lattice.
    moving_rho : (nx, ny, nz) complex64
        Part 2's samples (its spectrum is computed on first use, :attr:`moving`).
    moving_grid : Grid
    oversample_factor : int
        ``q``: part 2's lattice is ``q`` times finer than part 1's.
    refine : int
        The refined table is ``refine`` times finer still (1: none).
    fine_modes : int
        Largest ``K`` the refined table serves (0: none).
    fine_table : (B, B, B, C) float32 or None
        Part 2's spectrum (and moment spectra) on the refined lattice, index 0 at
        :attr:`fine_radius`.
    fine_scale, fine_reach : float
        Refined lattice steps per unit of ``k``; largest ``|k|`` it covers.
    fine_radius : int
    selection : {"cube", "largest"}
    use_cache : bool
    band : Band
        The kept modes' shape and taper (:func:`truncate`), and whether the densities were
        windowed before they were transformed.
    """

    geometry: PairGeometry
    fixed: Spectrum
    moving_rho: np.ndarray
    moving_grid: Grid
    oversample_factor: int
    refine: int
    fine_modes: int
    fine_table: np.ndarray | None
    fine_scale: float
    fine_reach: float
    fine_radius: int
    selection: str
    use_cache: bool
    band: Band = BANDS["box"]
    _lazy: dict[str, object] = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __getstate__(self) -> dict[str, object]:
        """Pickled without the lock (spectra go to the runtime's job process whole)."""
        state = dict(self.__dict__)
        del state["_lock"]
        with self._lock:
            state["_lazy"] = dict(self._lazy)
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        """Unpickled with a lock of its own."""
        self.__dict__.update(state)
        self.__dict__["_lock"] = threading.Lock()

    @property
    def moving(self) -> Spectrum:
        """Part 2's centred spectrum and moment spectra on the ``q N`` lattice.

        Computed on first use (thread-safe): the refined table serves ``K <= fine_modes``
        alone, so the usual mode counts never need it.
        """
        with self._lock:
            spectrum = self._lazy.get("moving")
            if spectrum is None:
                spectrum = compute_spectrum(
                    self.moving_rho, self.moving_grid,
                    self.geometry.size * self.oversample_factor,
                    moments=self.geometry.rotation, use_cache=self.use_cache,
                )
                self._lazy["moving"] = spectrum
        assert isinstance(spectrum, Spectrum)
        return spectrum

    def fine_for(self, reach: float) -> bool:
        """Whether modes reaching ``|k| <= reach`` are read from the refined table."""
        return self.fine_table is not None and reach <= self.fine_reach + 1e-9

    def lattice_scale(self, fine: bool) -> float:
        """Lattice steps per unit of ``k`` of the refined table or of the ``q`` lattice."""
        return self.fine_scale if fine else float(self.oversample_factor)

    def radial_profile(self) -> np.ndarray:
        """(R,) float64 RMS of ``|rho2c^|`` on spheres ``|k| = 0, 1, ...`` (part 1's steps).

        A rotation-invariant estimate of what part 2 contributes at each frequency.
        """
        with self._lock:
            profile = self._lazy.get("radial")
        if profile is None:
            spec = self.moving
            fm = np.fft.fftfreq(spec.size, 1.0 / spec.size) / self.oversample_factor
            radius = np.sqrt(fm[:, None, None] ** 2 + fm[None, :, None] ** 2
                             + fm[None, None, :] ** 2)
            bins = np.rint(radius).astype(np.int64).ravel()
            power = np.bincount(bins, weights=np.abs(spec.values.ravel()) ** 2)
            counts = np.maximum(np.bincount(bins), 1)
            profile = np.sqrt(power / counts)
            with self._lock:
                self._lazy["radial"] = profile
        assert isinstance(profile, np.ndarray)
        return profile


def build_spectra(
    fixed_rho: np.ndarray,
    fixed_grid: Grid,
    moving_rho: np.ndarray,
    moving_grid: Grid,
    geometry: PairGeometry,
    *,
    oversample: float,
    refine: int,
    fine_modes: int,
    selection: str,
    use_cache: bool,
    band: Band = BANDS["box"],
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> Spectra:
    """Transform a pair once: part 1's spectrum, part 2's refined table (the costly part).

    ``band``: the :class:`~engine.correlation.spectrum.Band` the truncations keep (its
    densities windowed here when it says so). ``progress`` gets fractions 0..1;
    ``cancel`` returning True raises :class:`engine.errors.Cancelled` between the steps.
    """
    size = geometry.size

    def step(fraction: float) -> None:
        if cancel is not None and cancel():
            raise Cancelled("building the correlation spectra was cancelled")
        if progress is not None:
            progress(fraction)

    step(0.0)
    if band.windowed:  # each tail ends at one distance from its part, all round
        fixed_rho = supported(fixed_rho, fixed_grid)
        moving_rho = supported(moving_rho, moving_grid)
    q = max(1, int(math.ceil(oversample * max(moving_grid.shape) / size)))
    fixed = compute_spectrum(fixed_rho, fixed_grid, size, moments=False, use_cache=use_cache)
    step(0.3)
    refine = max(1, int(refine))
    fine = max(1, min(int(fine_modes), size)) if refine > 1 else 0
    fine_table, fine_scale, fine_reach, fine_radius = None, 0.0, 0.0, 0
    if fine:
        fine_scale = float(q * refine)
        fine_reach = cube_reach(fine)
        fine_radius = table_radius(fine_reach, fine_scale)
        fine_table = refined_table(moving_rho, moving_grid, size * q, refine, fine_radius,
                                   moments=geometry.rotation, use_cache=use_cache)
    step(1.0)
    return Spectra(
        geometry=geometry, fixed=fixed,
        moving_rho=np.asarray(moving_rho).astype(np.complex64, copy=False),
        moving_grid=moving_grid, oversample_factor=q, refine=refine, fine_modes=fine,
        fine_table=fine_table, fine_scale=fine_scale, fine_reach=fine_reach,
        fine_radius=fine_radius, selection=selection, use_cache=use_cache, band=band,
    )


@dataclass(frozen=True, eq=False)
class ModeTable:
    """The kept modes of one truncation and the table the kernels read (immutable).

    Attributes
    ----------
    modes : int
        ``K`` (``m' = K^3`` modes kept).
    geometry : PairGeometry
    reach : float
        Largest ``|k|`` among the kept modes, plus one step.
    fine : bool
        Whether the modes read the refined table (else the ``q`` lattice).
    scale : float
        Lattice steps per unit of ``k``: the rotated frequency ``-R^T w`` lies at lattice
        index ``u = -scale R^T k``.
    kept : (L,) float64 or None
        Signed frequency indices per axis (selection "cube"): the symmetric band
        ``-(K // 2) ... K // 2`` (:func:`~engine.correlation.spectrum.kept_indices`; ``L = K``
        for odd K, ``K + 1`` for even K).
    fixed_kept : (L, L, L) complex64 or None
        ``rho1c^(w) dw`` on the kept cube, times the band's weights (an even K's end modes
        count one half per axis).
    mode_k : (m', 3) float64 or None
        Signed frequency indices (selection "largest").
    mode_a : (m',) complex64 or None
        ``rho1c^(w) dw`` at them.
    moving : (B^3, C) float32 or None
        Part 2's interleaved table: ``C = 8`` (``G`` and its lattice derivatives ``dG/du``
        along x, y, z; real and imaginary parts) with rotation, ``C = 2`` without; None
        when it would exceed :data:`MAX_TABLE_BYTES` (then the reference runs).
    radius : int
        Lattice index 0 lies at row offset ``radius`` along each axis; side ``2 radius + 2``.
    """

    modes: int
    geometry: PairGeometry
    reach: float
    fine: bool
    scale: float
    kept: np.ndarray | None
    fixed_kept: np.ndarray | None
    mode_k: np.ndarray | None
    mode_a: np.ndarray | None
    moving: np.ndarray | None
    radius: int

    @property
    def side(self) -> int:
        """Rows per axis of :attr:`moving`."""
        return 2 * self.radius + 2

    @property
    def channels(self) -> int:
        """Floats per row of :attr:`moving`: 8 with rotation, 2 without."""
        return 8 if self.geometry.rotation else 2


#: Tables a compiled kernel keeps prepared (:class:`PerTable`): the field in use, the one
#: being built for a new K, and one more.
KEPT_TABLES = 3


class PerTable(Generic[P]):
    """What a compiled kernel prepares per table, for the last few tables, thread-safe.

    What is prepared: kernel arguments, device buffers. :data:`KEPT_TABLES` tables are
    kept.

    The runtime's worker times and warms a new field while the loop evaluates the field in
    use, and the two share the kernels (:meth:`Correlator.with_modes`). A kernel that kept
    only its last table would prepare the tables again each time the threads take turns,
    and one thread could run with what the other just prepared. Here each thread gets what
    belongs to its own table, prepared once.

    Parameters
    ----------
    prepare : callable
        ``prepare(table)`` makes what a table needs; it runs outside the lock (an upload may
        take a while), so two threads asking for a new table at once may both prepare it.
    """

    def __init__(self, prepare: Callable[[ModeTable], P]) -> None:
        self._prepare = prepare
        self._kept: OrderedDict[int, tuple[ModeTable, P]] = OrderedDict()
        self._lock = threading.Lock()
        #: How many times a table was prepared.
        self.prepared = 0

    def get(self, table: ModeTable) -> P:
        """What ``table`` needs, prepared on its first use."""
        key = id(table)
        with self._lock:
            kept = self._kept.get(key)
            if kept is not None and kept[0] is table:
                self._kept.move_to_end(key)
                return kept[1]
        value = self._prepare(table)
        with self._lock:
            self.prepared += 1
            self._kept[key] = (table, value)
            self._kept.move_to_end(key)
            while len(self._kept) > KEPT_TABLES:
                self._kept.popitem(last=False)
        return value


def truncate(spectra: Spectra, modes: int) -> ModeTable:
    """The :class:`ModeTable` keeping ``modes`` per axis (clipped to ``N``).

    Reads only the spectra: no transform is computed again, and nothing shared changes.
    """
    k = int(modes)
    if k < 1:
        raise ValueError(f"modes per axis must be at least 1, got {k}")
    geometry = spectra.geometry
    n = geometry.size
    k = min(k, n)
    dw = np.float32(1.0 / geometry.n_h ** 3)
    kept = fixed_kept = mode_k = mode_a = None
    if spectra.selection == "cube":
        indices = kept_indices(k, n)  # (L,) signed, symmetric: L = K, or K + 1 for even K
        wrapped = np.mod(indices, n)
        # (L, L, L): rho1c^(w) dw, times the band's weights (1/2 at an even band's ends,
        # and the taper of a truncated band)
        fixed_kept = (spectra.fixed.values[np.ix_(wrapped, wrapped, wrapped)]
                      * (cube_weights(k, n, band=spectra.band) * dw)).astype(np.complex64)
        kept = indices.astype(np.float64)
        reach = cube_reach(k)
    else:
        kvec, reach = largest_modes(spectra, k)
        wrapped = np.mod(kvec, n)
        mode_k = np.ascontiguousarray(kvec, dtype=np.float64)  # (m', 3)
        mode_a = (spectra.fixed.values[wrapped[:, 0], wrapped[:, 1], wrapped[:, 2]] * dw
                  ).astype(np.complex64)  # (m',)
    fine = spectra.fine_for(reach)
    scale = spectra.lattice_scale(fine)
    radius = table_radius(reach, scale)
    channels = 8 if geometry.rotation else 2
    moving = None
    if fine or (2 * radius + 2) ** 3 * channels * 4 <= MAX_TABLE_BYTES:
        moving = _moving_table(spectra, fine, radius)
    return ModeTable(modes=k, geometry=geometry, reach=reach, fine=fine, scale=scale,
                     kept=kept, fixed_kept=fixed_kept, mode_k=mode_k, mode_a=mode_a,
                     moving=moving, radius=radius)


def largest_modes(spectra: Spectra, k: int) -> tuple[np.ndarray, float]:
    """The ``k^3`` lattice frequencies of largest ``|rho1^(w)| P2(|w|)``.

    ``P2`` is :meth:`Spectra.radial_profile`. Returns the signed frequency indices
    ``(k^3, 3) int64``, sorted (for locality), and the largest ``|k|`` among them plus one.
    """
    n = spectra.geometry.size
    freq = np.fft.fftfreq(n, 1.0 / n)
    profile = spectra.radial_profile()
    radius = np.sqrt(freq[:, None, None] ** 2 + freq[None, :, None] ** 2
                     + freq[None, None, :] ** 2)
    weight = np.abs(spectra.fixed.values.ravel()) * np.interp(
        radius.ravel(), np.arange(len(profile)), profile)
    count = min(k**3, weight.size)
    if count < weight.size:
        flat = np.argpartition(-weight, count - 1)[:count]
    else:
        flat = np.arange(weight.size)
    ix, iy, iz = np.unravel_index(np.sort(flat), (n, n, n))
    kvec = np.stack([freq[ix], freq[iy], freq[iz]], axis=1).astype(np.int64)
    reach = float(np.sqrt((kvec.astype(np.float64) ** 2).sum(axis=1)).max()) + 1.0
    return kvec, reach


def gradient_factor(spectra: Spectra, fine: bool) -> complex:
    """``-2 pi i / a``: from a moment spectrum ``M`` to the lattice derivative ``dG/du``.

    ``a = scale N h`` lattice steps per unit of frequency, and ``M = (i a / 2 pi) dG/du``.
    """
    return -2j * np.pi / (spectra.lattice_scale(fine) * spectra.geometry.n_h)


def _moving_table(spectra: Spectra, fine: bool, radius: int) -> np.ndarray:
    """(B^3, C) float32: part 2's lattice around ``w = 0`` that the modes can reach."""
    to_gradient = gradient_factor(spectra, fine)
    if fine:
        assert spectra.fine_table is not None
        lo = spectra.fine_radius - radius
        hi = lo + 2 * radius + 2
        table = spectra.fine_table[lo:hi, lo:hi, lo:hi].copy()
        if spectra.geometry.rotation:
            # moment spectra M to dG/du = -2 pi i M / a, as (re, im) pairs
            factor = to_gradient.imag  # -2 pi / a
            raw = table[..., 2:].copy()
            table[..., 2::2] = -factor * raw[..., 1::2]
            table[..., 3::2] = factor * raw[..., 0::2]
    else:
        spectrum = spectra.moving
        idx = np.mod(np.arange(-radius, radius + 2), spectrum.size)
        sel = np.ix_(idx, idx, idx)
        parts = [spectrum.values[sel]]
        if spectra.geometry.rotation and spectrum.moments is not None:
            parts += [spectrum.moments[a][sel] * np.complex64(to_gradient) for a in range(3)]
        stacked = np.stack(parts, axis=-1)  # (B, B, B, P) complex64
        table = np.empty(stacked.shape[:3] + (2 * len(parts),), dtype=np.float32)
        table[..., 0::2] = stacked.real
        table[..., 1::2] = stacked.imag
    return np.ascontiguousarray(table.reshape(-1, table.shape[-1]))
