"""Fourier correlation of two descriptors: score, energy, force and torque for any pose.

Works on two descriptor fields (``.rho`` (nx, ny, nz) complex64 on ``.grid``, one shared
spacing ``h``): part 1 fixed, part 2 moved by ``(R, t)`` (a point ``q`` of part 2 goes to
``R q + t`` in part 1's frame). With ``^`` the continuous Fourier transform and
``v2(q) = q rho2(q)`` (DESIGN.md section 2)::

    f(R, t)   = sum_w rho1^(w) rho2^(-R^T w) exp(2 pi i w.t) dw
    E = -kappa Re f,   F = -dE/dt = kappa Re df/dt,   T = -dE/dtheta = kappa Re df/dtheta
    df/dt     = sum_w (2 pi i w) rho1^(w) rho2^(-R^T w) exp(2 pi i w.t) dw
    df/dtheta = sum_w 2 pi i ((R v2^(-R^T w)) x w) rho1^(w) exp(2 pi i w.t) dw

How it is evaluated
-------------------
* Both fields are zero-padded to one FFT size ``N`` (even, 2-3-5-7 smooth) large enough
  that no periodic image of the rotated part 2 reaches part 1 for any pose at which the
  two grid boxes overlap (``N h >= L1 + 2 r2 + 3 h``, ``r2`` the half-diagonal of part 2's
  grid box). Where the boxes cannot overlap, the result is exactly zero.
* Spectra are centred on each grid's centre (:mod:`engine.spectrum`), so the rotated
  spectrum of part 2 is smooth and is interpolated on a lattice ``q`` times finer than part
  1's (``q`` = ``oversample`` relative to part 2's extent, at least 1, so that at ``R = I``
  every needed sample lies on the lattice: no interpolation there). The centring phases
  combine with ``exp(2 pi i w.t)`` into ``exp(2 pi i w.(t + R c2 - c1))``, which is
  separable over the kept cube of modes: three tables of ``K`` values per call.
* With rotation on, the interpolation is gradient-enhanced (:func:`_hermite`): the moment
  spectra are the spectrum's derivatives, and trilinear interpolation plus a per-axis
  correction from them is exact for quadratics. The torque sums differentiate this same
  interpolant, so the torque is exactly ``-dE/dtheta`` of the reported energy (a
  conservative field). Without rotation the interpolation is trilinear.
* For ``K <= fine_modes`` (24) the interpolation reads a table ``refine`` (2) times finer
  still, tabulated exactly over the ball the kept modes reach
  (:func:`engine.spectrum.refined_table`): the interpolation error drops about 15-fold.
* The kept modes are the cube of the ``K`` lowest frequencies per axis (``m' = K^3``), or
  with ``selection="largest"`` the ``K^3`` largest by magnitude anywhere on the lattice.
  :meth:`Correlator.set_modes` only re-slices precomputed spectra.
* A :class:`Correlator` is not meant to be evaluated from two threads at once (the
  compiled backends reuse scratch buffers); landscapes may be computed alongside.

Per-pose backends: ``numpy`` (reference, vectorised), ``numba`` (compiled in process; the
fast path on CPUs, DESIGN.md section 4; one thread unless ``SKELASM_CORRELATION_THREADS``
asks for more and they measure clearly faster) and ``opencl`` (one fused kernel, buffers kept on
the device; :mod:`engine.correlation_cl`). ``auto`` measures the compiled ones at start-up
and keeps the faster; :attr:`Correlator.backend_name` says which and why.
"""

from __future__ import annotations

import math
import os
import time
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

from engine.landscape import Landscape
from engine.spectrum import (
    Spectrum,
    compute_spectrum,
    fast_size,
    kept_indices,
    refined_table,
)

PER_POSE_BACKENDS = ("numpy", "numba", "opencl")
SELECTIONS = ("cube", "largest")
BACKEND_CHOICES = ("auto",) + PER_POSE_BACKENDS
TWO_PI = 2.0 * math.pi

#: Modes per chunk in the numpy reference (bounds its temporaries to a few tens of MB).
_NUMPY_CHUNK = 1 << 16

#: Largest per-pose table (bytes) the compiled backends get; beyond it (K near the full
#: lattice) evaluation runs on the numpy reference, which reads the spectra in place.
MAX_TABLE_BYTES = 256 << 20


@dataclass(frozen=True)
class Evaluation:
    """Energy, force and torque on part 2 at one pose.

    Attributes
    ----------
    energy : float
        ``E = -kappa Re f``.
    force : (3,) float64
        ``-dE/dt`` in part 1's frame.
    torque : (3,) float64 or None
        ``-dE/dtheta`` about part 2's origin, world axes; None when rotation is off.
    microseconds : float
        Wall time of the evaluation.
    modes : int
        Modes per axis used (``m' = modes^3``).
    """

    energy: float
    force: np.ndarray
    torque: np.ndarray | None
    microseconds: float
    modes: int


def _check_descriptor(obj: Any, name: str) -> None:
    if not hasattr(obj, "rho") or not hasattr(obj, "grid"):
        raise TypeError(f"{name} must have .rho and .grid (a store.Descriptor)")


def _cube_reach(modes: int) -> float:
    """Largest ``|k|`` of the kept cube, with one step to spare: ``sqrt(3) (K // 2 + 1)``."""
    return math.sqrt(3.0) * (modes // 2 + 1)


def _radius(reach: float, scale: float) -> int:
    """Table radius (lattice steps) that covers frequencies up to ``reach``, +1."""
    return int(math.ceil(scale * reach)) + 1


def required_fft_size(shape1: tuple[int, ...], shape2: tuple[int, ...]) -> int:
    """Smallest FFT size for which no periodic image interferes at any pose.

    ``N >= n1 - 1 + 2 r2 / h + 3`` along every axis, with ``r2 / h`` the half-diagonal of
    part 2's grid box in cells (its largest extent under any rotation) and one cell of
    margin on each side for the overlap test.
    """
    half_diag = 0.5 * float(np.linalg.norm(np.asarray(shape2) - 1))
    need = max(shape1) - 1 + 2.0 * half_diag + 3.0
    return fast_size(int(math.ceil(need)))


class Correlator:
    """Energy, force and torque between a fixed and a moving descriptor.

    Parameters
    ----------
    fixed, moving : store.Descriptor
        Objects with ``.rho`` ((nx, ny, nz) complex64) and ``.grid`` (:class:`engine.grid.Grid`);
        both grids must share one spacing.
    modes : int
        ``K``, modes kept per axis (``m' = K^3``), clipped to the FFT size.
    rotation : bool
        Compute the torque. When False no moment spectra are computed and
        :meth:`evaluate` returns ``torque=None``.
    backend : {"auto", "numpy", "numba", "opencl"}
        Per-pose backend. ``auto`` measures numba and OpenCL (when present) and keeps the
        faster.
    kappa : float
        Energy scale, ``E = -kappa Re f``.
    oversample : float
        Oversampling of part 2's spectrum relative to its own grid extent (>= 1); the
        interpolation lattice is an integer multiple ``q`` of part 1's.
    fft_size : int, optional
        Override the padded size ``N`` (must be at least :func:`required_fft_size` to be
        free of periodic images; smaller values are accepted for tests and experiments).
    refine : int
        For ``K <= fine_modes`` the rotated spectrum is interpolated on a lattice ``refine``
        times finer still, tabulated exactly (no interpolation) over the ball the kept
        modes can reach (:func:`engine.spectrum.refined_table`): the interpolation error
        falls as ``refine^-2`` (trilinear) or faster (gradient-enhanced, rotation on: about
        15x at refine 2) for a table of a few tens of MB. 1 switches this off.
    fine_modes : int
        Largest ``K`` the refined table serves; larger ``K`` use the ``q`` lattice. The
        refined table is ``refine^3`` times larger for the same ``K``; at ``K = 32`` it no
        longer fits the CPU caches (about 58 MB) and a pose costs several ms instead of
        about 0.5 ms, hence the default 24.
    selection : {"cube", "largest"}
        Which ``K^3`` modes to keep: the cube of the lowest frequencies (separable phases,
        all backends), or the ``K^3`` of largest ``|rho1^(w)| * P2(|w|)`` anywhere on the
        lattice (``P2``: RMS of ``|rho2^|`` over the sphere ``|w|``, a rotation-invariant
        estimate of what the product keeps; numpy and numba only).
    use_cache : bool
        Use the on-disk spectrum cache.

    Attributes
    ----------
    stats : dict
        Counters of the work done: ``spectra`` (FFT spectra computed or loaded),
        ``moment_spectra`` (moment spectra computed or loaded), ``evaluations``,
        ``torque_sums`` (evaluations that summed the torque), ``truncations``,
        ``reference_fallbacks`` (evaluations run on numpy because the compiled backends'
        table for K would exceed :data:`MAX_TABLE_BYTES`).
    backend_name : str
        The per-pose backend in use and why.
    """

    def __init__(
        self,
        fixed: Any,
        moving: Any,
        *,
        modes: int = 16,
        rotation: bool = True,
        backend: str = "auto",
        kappa: float = 1.0,
        oversample: float = 2.0,
        fft_size: int | None = None,
        refine: int = 2,
        fine_modes: int = 24,
        selection: str = "cube",
        use_cache: bool = True,
    ) -> None:
        _check_descriptor(fixed, "fixed")
        _check_descriptor(moving, "moving")
        backend = str(backend).lower()
        if backend not in BACKEND_CHOICES:
            raise ValueError(f"unknown backend {backend!r}; valid: {', '.join(BACKEND_CHOICES)}")
        g1, g2 = fixed.grid, moving.grid
        h = g1.spacing
        if not math.isclose(g1.spacing, g2.spacing, rel_tol=1e-9, abs_tol=0.0):
            raise ValueError(
                f"the two descriptors have different grid spacings ({g1.spacing:g} and "
                f"{g2.spacing:g}): compute them with one shared spacing "
                "(store.descriptors_for_scene does)"
            )
        if not (math.isfinite(kappa) and kappa > 0):
            raise ValueError(f"kappa must be a positive finite number, got {kappa!r}")
        if selection not in SELECTIONS:
            raise ValueError(f"unknown selection {selection!r}; valid: {', '.join(SELECTIONS)}")
        self.selection = selection
        if not (math.isfinite(oversample) and oversample >= 1):
            raise ValueError(f"oversample must be at least 1, got {oversample!r}")
        self.kappa = float(kappa)
        self.rotation = bool(rotation)
        self.spacing = h
        self.fixed_grid = g1
        self.moving_grid = g2
        size = int(fft_size) if fft_size is not None else required_fft_size(g1.shape, g2.shape)
        if size < max(max(g1.shape), max(g2.shape)) or size % 2:
            raise ValueError(f"fft_size must be even and cover both grids, got {size}")
        self.size = size
        self.oversample_factor = max(1, int(math.ceil(oversample * max(g2.shape) / size)))
        self.stats: dict[str, int] = {
            "spectra": 0,
            "moment_spectra": 0,
            "evaluations": 0,
            "torque_sums": 0,
            "truncations": 0,
            "reference_fallbacks": 0,
        }
        self.spectrum_fixed: Spectrum = compute_spectrum(
            fixed.rho, g1, size, moments=False, use_cache=use_cache
        )
        self.spectrum_moving: Spectrum = compute_spectrum(
            moving.rho, g2, size * self.oversample_factor, moments=self.rotation,
            use_cache=use_cache,
        )
        self.stats["spectra"] += 2
        if self.rotation:
            self.stats["moment_spectra"] += 3
        self.refine = max(1, int(refine))
        self.fine_modes = max(1, min(int(fine_modes), size)) if self.refine > 1 else 0
        self._fine_table: np.ndarray | None = None
        if self.fine_modes:
            self._fine_scale = float(self.oversample_factor * self.refine)
            self._fine_reach = _cube_reach(self.fine_modes)
            self._fine_radius = _radius(self._fine_reach, self._fine_scale)
            self._fine_table = refined_table(
                moving.rho, g2, size * self.oversample_factor, self.refine, self._fine_radius,
                moments=self.rotation, use_cache=use_cache,
            )
            self.stats["spectra"] += 1
        self.centre_fixed = np.asarray(g1.center, dtype=np.float64)
        self.centre_moving = np.asarray(g2.center, dtype=np.float64)
        self.half_fixed = 0.5 * h * (np.asarray(g1.shape, dtype=np.float64) - 1)
        self.half_moving = 0.5 * h * (np.asarray(g2.shape, dtype=np.float64) - 1)
        self._kernels: dict[str, Any] = {}
        self.modes = 0
        self.set_modes(modes)
        self.backend_name = ""
        self._backend = "numpy"
        self._select_backend(backend)

    # ------------------------------------------------------------------ truncation
    def set_modes(self, k: int) -> None:
        """Keep the cube of the ``k`` lowest frequencies per axis (``m' = k^3``).

        Only re-slices the precomputed spectra; nothing is transformed again.
        """
        k = int(k)
        if k < 1:
            raise ValueError(f"modes per axis must be at least 1, got {k}")
        k = min(k, self.size)
        if k == self.modes:
            return
        self.modes = k
        dw = 1.0 / (self.size * self.spacing) ** 3
        if self.selection == "cube":
            self._kept = kept_indices(k, self.size)  # (K,) signed
            wrapped = np.mod(self._kept, self.size)
            self._fixed_kept = (
                self.spectrum_fixed.values[np.ix_(wrapped, wrapped, wrapped)] * np.float32(dw)
            ).astype(np.complex64)  # (K, K, K): rho1c^(w) dw
            self._mode_k = None
            self._reach = _cube_reach(k)
        else:
            kvec, self._reach = self._largest_modes(k)
            wrapped = np.mod(kvec, self.size)
            self._mode_k = np.ascontiguousarray(kvec, dtype=np.float64)  # (m', 3)
            self._mode_a = (
                self.spectrum_fixed.values[wrapped[:, 0], wrapped[:, 1], wrapped[:, 2]]
                * np.float32(dw)
            ).astype(np.complex64)  # (m',)
        self._table: np.ndarray | None = None  # per-pose table, built lazily per backend
        self.stats["truncations"] += 1
        for kernel in self._kernels.values():
            if hasattr(kernel, "set_modes"):
                kernel.set_modes(self)

    def _largest_modes(self, k: int) -> tuple[np.ndarray, float]:
        """The ``k^3`` lattice frequencies of largest ``|rho1^(w)| P2(|w|)``.

        Returns
        -------
        kvec : (k^3, 3) int64
            Signed frequency indices, sorted (for locality).
        reach : float
            Largest ``|k|`` among them plus one.
        """
        n = self.size
        freq = np.fft.fftfreq(n, 1.0 / n)
        if not hasattr(self, "_radial_moving"):
            # RMS of |rho2c^| on spheres, in units of part 1's lattice step
            spec = self.spectrum_moving
            fm = np.fft.fftfreq(spec.size, 1.0 / spec.size) / self.oversample_factor
            radius = np.sqrt(fm[:, None, None] ** 2 + fm[None, :, None] ** 2
                             + fm[None, None, :] ** 2)
            bins = np.rint(radius).astype(np.int64).ravel()
            power = np.bincount(bins, weights=np.abs(spec.values.ravel()) ** 2)
            counts = np.maximum(np.bincount(bins), 1)
            self._radial_moving = np.sqrt(power / counts)
        radius = np.sqrt(freq[:, None, None] ** 2 + freq[None, :, None] ** 2
                         + freq[None, None, :] ** 2)
        profile = np.interp(radius.ravel(), np.arange(len(self._radial_moving)),
                            self._radial_moving)
        weight = np.abs(self.spectrum_fixed.values.ravel()) * profile
        count = min(k**3, weight.size)
        flat = np.argpartition(-weight, count - 1)[:count] if count < weight.size else (
            np.arange(weight.size))
        flat = np.sort(flat)
        ix, iy, iz = np.unravel_index(flat, (n, n, n))
        kvec = np.stack([freq[ix], freq[iy], freq[iz]], axis=1).astype(np.int64)
        reach = float(np.sqrt((kvec.astype(np.float64) ** 2).sum(axis=1)).max()) + 1.0
        return kvec, reach

    def _table_too_large(self) -> bool:
        """Whether the compiled backends' table for the current K would exceed the cap."""
        if self.uses_fine_table():
            return False
        side = 2 * _radius(self._reach, float(self.oversample_factor)) + 2
        channels = 8 if self.rotation else 2
        return side**3 * channels * 4 > MAX_TABLE_BYTES

    def uses_fine_table(self, modes: int | None = None) -> bool:
        """Whether the kept modes (or a cube of ``modes``) read the refined table."""
        reach = self._reach if modes is None else _cube_reach(modes)
        return self._fine_for(reach)

    def _fine_for(self, reach: float) -> bool:
        return self._fine_table is not None and reach <= self._fine_reach + 1e-9

    def moving_table(self) -> tuple[np.ndarray, int, float]:
        """Interleaved lattice of part 2's spectra that the kept modes can reach.

        Returns
        -------
        table : (B, B, B, C) float32
            ``C = 8`` (rho2c^, then its lattice derivatives ``dG/du`` along x, y, z from
            the moment spectra; real and imaginary parts interleaved) with rotation,
            ``C = 2`` without; lattice index ``u`` lies at ``u + radius``.
        radius : int
            Offset of index 0.
        scale : float
            Lattice steps per unit of ``k``: the rotated frequency ``-R^T w`` lies at
            ``u = -scale R^T k``.
        """
        if self._table is None:
            if self.uses_fine_table():
                scale = self._fine_scale
                radius = _radius(self._reach, scale)
                lo = self._fine_radius - radius
                hi = lo + 2 * radius + 2
                assert self._fine_table is not None
                table = self._fine_table[lo:hi, lo:hi, lo:hi]
                if self.rotation:
                    # moment spectra M to lattice derivatives dG/du = -2 pi i M / a
                    factor = TWO_PI / self._gradient_scale(True)
                    table = table.copy()
                    raw = table[..., 2:].copy()
                    table[..., 2::2] = factor * raw[..., 1::2]
                    table[..., 3::2] = -factor * raw[..., 0::2]
            else:
                scale = float(self.oversample_factor)
                m = self.spectrum_moving.size
                radius = _radius(self._reach, scale)
                idx = np.mod(np.arange(-radius, radius + 2), m)
                sel = np.ix_(idx, idx, idx)
                parts = [self.spectrum_moving.values[sel]]
                moments = self.spectrum_moving.moments
                if self.rotation and moments is not None:
                    to_gradient = np.complex64(-2j * np.pi / self._gradient_scale(False))
                    parts += [moments[a][sel] * to_gradient for a in range(3)]
                stacked = np.stack(parts, axis=-1)  # (B, B, B, P) complex64
                table = np.empty(stacked.shape[:3] + (2 * len(parts),), dtype=np.float32)
                table[..., 0::2] = stacked.real
                table[..., 1::2] = stacked.imag
            self._table = np.ascontiguousarray(table)
            self._table_radius = radius
            self._table_scale = scale
        return self._table, self._table_radius, self._table_scale

    def _gradient_scale(self, fine: bool) -> float:
        """``a = scale N h``: lattice steps per unit of frequency ``nu`` of the table read.

        The moment spectrum is ``M = (i / 2 pi) dG/dnu = (i a / 2 pi) dG/du`` (``u`` the
        lattice coordinate), so the tables hold ``dG/du = -2 pi i M / a``.
        """
        scale = self._fine_scale if fine else float(self.oversample_factor)
        return scale * self.size * self.spacing

    def _interpolate_rows(
        self, rk: np.ndarray, reach: float, gradient: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Part 2's spectrum at ``-R^T w`` and its lattice gradient (the reference).

        With rotation on (moment spectra present) the interpolant is the gradient-enhanced
        one of :func:`_hermite`; without, plain trilinear.

        Parameters
        ----------
        rk : (n, 3) float64
            Rows ``R^T k`` (``k`` integer frequency indices).
        reach : float
            Reach of the mode set these rows belong to (picks the refined table or the
            ``q`` lattice, as the compiled backends do).
        gradient : bool
            Also return the interpolant's gradient ``dG/du`` (needs rotation on).

        Returns
        -------
        values : (n,) complex128
        gradients : (3, n) complex128 or None
        """
        fine = self._fine_for(reach)
        if fine:
            scale = self._fine_scale
            assert self._fine_table is not None
            fine_table = self._fine_table.view(np.complex64)  # (B, B, B, P)
            side = fine_table.shape[0]
            flat: np.ndarray | None = fine_table.reshape(-1, fine_table.shape[-1])
            offset = self._fine_radius
            wrap = 0
        else:
            scale = float(self.oversample_factor)
            side = self.spectrum_moving.size
            offset = 0
            wrap = side
            flat = None
        u = -scale * rk + offset
        base = np.floor(u)
        frac = u - base
        base = base.astype(np.int64)
        if gradient and not self.rotation:
            raise ValueError("the interpolant's gradient needs rotation on (moment spectra)")
        n = len(rk)
        channels = 4 if self.rotation else 1
        # the 8 corners of each row's cell as rows 8 i + 4 dx + 2 dy + dz of a small table
        corners = np.empty((n, 8, channels), dtype=np.complex128)
        spec_moments = self.spectrum_moving.moments
        for dx in (0, 1):
            ix = base[:, 0] + dx
            for dy in (0, 1):
                iy = base[:, 1] + dy
                for dz in (0, 1):
                    iz = base[:, 2] + dz
                    corner = 4 * dx + 2 * dy + dz
                    if flat is None:
                        idx = (np.mod(ix, wrap) * wrap + np.mod(iy, wrap)) * wrap + np.mod(iz, wrap)
                        corners[:, corner, 0] = self.spectrum_moving.values.ravel()[idx]
                        if self.rotation:
                            assert spec_moments is not None
                            corners[:, corner, 1:] = spec_moments.reshape(3, -1)[:, idx].T
                    else:
                        idx = (ix * side + iy) * side + iz
                        corners[:, corner, :] = flat[idx, :channels]
        if self.rotation:
            corners[:, :, 1:] *= -2j * np.pi / self._gradient_scale(fine)  # M -> dG/du
        table = np.empty((8 * n, 2 * channels))
        table[:, 0::2] = corners.reshape(8 * n, channels).real
        table[:, 1::2] = corners.reshape(8 * n, channels).imag
        b00 = 8 * np.arange(n)
        cell = (b00, b00 + 2, b00 + 4, b00 + 6, frac[:, 0], frac[:, 1], frac[:, 2])
        if not self.rotation:
            lerp = _python(_lerp)
            return lerp(table, 0, cell) + 1j * lerp(table, 1, cell), None
        hermite = _python(_hermite)
        re = hermite(table, 0, cell)
        im = hermite(table, 1, cell)
        g = re[0] + 1j * im[0]
        grad = np.stack([re[a] + 1j * im[a] for a in (1, 2, 3)]) if gradient else None
        return g, grad

    # ------------------------------------------------------------------ geometry
    def boxes_overlap(self, rotation: np.ndarray, translation: np.ndarray) -> bool:
        """Whether part 2's grid box (rotated, one cell of margin) can meet part 1's."""
        centre = rotation @ self.centre_moving + translation
        extent = np.abs(rotation) @ self.half_moving
        gap = np.abs(centre - self.centre_fixed) - (self.half_fixed + extent + self.spacing)
        return bool(np.all(gap < 0))

    def _shift(self, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """(3,) ``t + R c2 - c1``: the offset the separable phase factors refer to."""
        return translation + rotation @ self.centre_moving - self.centre_fixed

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """Energy, force and torque at one relative pose.

        Parameters
        ----------
        rotation : (3, 3) float
            Rotation of part 2 relative to part 1.
        translation : (3,) float
            Translation of part 2 relative to part 1 (part 1's frame).

        Returns
        -------
        Evaluation
        """
        start = time.perf_counter()
        rot = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
        t = np.ascontiguousarray(translation, dtype=np.float64).reshape(3)
        if not math.isfinite(float(rot.sum()) + float(t.sum())):
            raise ValueError("pose contains NaN or infinite values")
        self.stats["evaluations"] += 1
        if self.rotation:
            self.stats["torque_sums"] += 1
        if self._backend == "numpy" or self._table_too_large():
            if self._backend != "numpy":
                self.stats["reference_fallbacks"] += 1
            if self.boxes_overlap(rot, t):
                sums = self._sums_numpy(rot, t)
            else:
                sums = np.zeros(7)
            energy, force, torque = self._finish(sums, rot)
        else:
            out = self._kernels[self._backend].pose(self, rot, t)
            energy = float(out[0])
            force = out[1:4]
            torque = out[4:7] if self.rotation else None
        return Evaluation(
            energy=energy,
            force=force,
            torque=torque,
            microseconds=(time.perf_counter() - start) * 1e6,
            modes=self.modes,
        )

    def _finish(
        self, sums: np.ndarray, rot: np.ndarray
    ) -> tuple[float, np.ndarray, np.ndarray | None]:
        """Energy, force and torque from the seven raw sums of a backend.

        ``sums = [Re f, Im S_k (3), Im S_m (3)]`` with ``S_k = sum c G k`` and
        ``S_m = sum Im(c m) x (R^T k)`` (both in lattice units, see :meth:`_sums_numpy`).
        """
        nh = self.size * self.spacing
        energy = -self.kappa * float(sums[0])
        force = -TWO_PI * self.kappa * np.asarray(sums[1:4], dtype=np.float64) / nh
        if not self.rotation:
            return energy, force, None
        # Im sum c (V' x R^T k) with V' = m + c2 G:  S_m + c2 x (R^T Im S_k)
        s_k = np.asarray(sums[1:4], dtype=np.float64)
        s_m = np.asarray(sums[4:7], dtype=np.float64)
        local = s_m + np.cross(self.centre_moving, rot.T @ s_k)
        torque = -TWO_PI * self.kappa * (rot @ local) / nh
        return energy, force, torque

    def _sums_numpy(self, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Reference sums over the kept cube, vectorised in chunks.

        Returns ``[Re f, Im S_k (3), Im S_m (3)]`` where, over kept integer ``k``
        (``w = k / (N h)``), ``c = rho1c^(w) dw exp(2 pi i w.(t + R c2 - c1))``,
        ``G = rho2c^(-R^T w)`` (interpolated), ``m = (i a / 2 pi) dG/du`` the moment spectrum
        the interpolant implies (``a`` from :meth:`_gradient_scale`):
        ``f = sum c G``, ``S_k = sum c G k``, ``S_m = sum Im(c m) x (R^T k)``.
        """
        n = self.size
        shift = self._shift(rot, t)
        if self._mode_k is None:
            kept = self._kept.astype(np.float64)
            phase = [np.exp(2j * np.pi * kept * shift[a] / (n * self.spacing)) for a in range(3)]
            coeff = (
                self._fixed_kept.astype(np.complex128)
                * phase[0][:, None, None]
                * phase[1][None, :, None]
                * phase[2][None, None, :]
            ).ravel()
            kx, ky, kz = np.meshgrid(kept, kept, kept, indexing="ij")
            kvec = np.stack([kx.ravel(), ky.ravel(), kz.ravel()], axis=1)  # (m', 3)
        else:
            kvec = self._mode_k
            coeff = self._mode_a.astype(np.complex128) * np.exp(
                2j * np.pi * (kvec @ shift) / (n * self.spacing)
            )
        total = np.zeros(7)
        for lo in range(0, len(kvec), _NUMPY_CHUNK):
            kc = kvec[lo : lo + _NUMPY_CHUNK]
            cc = coeff[lo : lo + _NUMPY_CHUNK]
            rk = kc @ rot  # (n, 3): rows are R^T k
            g, grad = self._interpolate_rows(rk, self._reach, self.rotation)
            cg = cc * g
            total[0] += cg.real.sum()
            total[1:4] += cg.imag @ kc
            if grad is not None:
                re_cd = (cc * grad).real.T  # (n, 3): Re(c dG/du)
                total[4:7] += np.cross(re_cd, rk).sum(axis=0)
        if self.rotation:
            # Im(c M) = (a / 2 pi) Re(c dG/du), M the moment spectrum the interpolant implies
            total[4:7] *= self._gradient_scale(self._fine_for(self._reach)) / TWO_PI
        return total

    # ------------------------------------------------------------------ landscapes
    def landscape(
        self, rotation: np.ndarray, *, modes: int | None = None, forces: bool = True
    ) -> Landscape:
        """Energy (and force) over every lattice translation, by one inverse FFT each.

        The translations are ``t = c1 - R c2 + h * j`` for ``j = -N/2 ... N/2 - 1`` per
        axis (centred on the pose that puts the two grid centres together), which covers
        every translation at which the grid boxes overlap; elsewhere the energy is 0.

        Parameters
        ----------
        rotation : (3, 3) float
            Rotation of part 2 relative to part 1.
        modes : int, optional
            Modes per axis (default: the current :attr:`modes`).
        forces : bool
            Also compute the force field (three more inverse FFTs).
        """
        import scipy.fft

        start = time.perf_counter()
        rot = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
        n = self.size
        h = self.spacing
        k_modes = self.modes if modes is None else min(int(modes), n)
        if self.selection == "cube":
            kept = kept_indices(k_modes, n)
            wrapped = np.mod(kept, n)
            sel = np.ix_(wrapped, wrapped, wrapped)
            g = self._interpolate_moving(rot, kept)  # (K, K, K) complex64
        else:
            if k_modes == self.modes:
                assert self._mode_k is not None
                kvec, reach = self._mode_k.astype(np.int64), self._reach
            else:
                kvec, reach = self._largest_modes(k_modes)
            wrapped = np.mod(kvec, n)
            sel = (wrapped[:, 0], wrapped[:, 1], wrapped[:, 2])
            g = self._interpolate_rows(kvec.astype(np.float64) @ rot, reach, False)[0]
        coeff = self.spectrum_fixed.values[sel].astype(np.complex64)
        # f(t0 + h j) = sum_k rho1c^ rho2c^ dw exp(2 pi i k.j / N): t0 + R c2 - c1 = 0
        spectrum = np.zeros((n, n, n), dtype=np.complex64)
        spectrum[sel] = coeff * g * np.float32(1.0 / (n * h) ** 3)
        scale = float(n) ** 3
        field = scipy.fft.ifftn(spectrum, workers=2)
        energy = np.fft.fftshift(-self.kappa * scale * field.real).astype(np.float32)
        force = None
        if forces:
            force = np.empty((3, n, n, n), dtype=np.float32)
            freq = (np.fft.fftfreq(n, 1.0 / n) / (n * h)).astype(np.float32)
            for a in range(3):
                shape = [1, 1, 1]
                shape[a] = n
                deriv = spectrum * (np.complex64(2j * np.pi) * freq.reshape(shape))
                part = scipy.fft.ifftn(deriv, workers=2)
                force[a] = np.fft.fftshift(self.kappa * scale * part.real)
        t0 = self.centre_fixed - rot @ self.centre_moving
        axes = tuple(t0[a] + h * (np.arange(n) - n // 2) for a in range(3))
        # zero where the grid boxes cannot overlap (matches evaluate)
        extent = np.abs(rot) @ self.half_moving
        masks = []
        for a in range(3):
            centre = axes[a] + (rot @ self.centre_moving)[a]
            gap = np.abs(centre - self.centre_fixed[a]) - (self.half_fixed[a] + extent[a] + h)
            masks.append(gap < 0)
        inside = masks[0][:, None, None] & masks[1][None, :, None] & masks[2][None, None, :]
        energy[~inside] = 0.0
        if force is not None:
            force[:, ~inside] = 0.0
        return Landscape(
            energy=energy,
            force=force,
            translations=axes,  # type: ignore[arg-type]
            rotation=rot,
            modes=k_modes,
            seconds=time.perf_counter() - start,
        )

    def _interpolate_moving(self, rot: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """(K, K, K) complex64: part 2's centred spectrum at ``-R^T w`` for the kept cube."""
        kf = kept.astype(np.float64)
        out = np.empty((len(kept),) * 3, dtype=np.complex64)
        ky, kz = np.meshgrid(kf, kf, indexing="ij")
        for i, kx in enumerate(kf):
            kvec = np.stack([np.full(ky.size, kx), ky.ravel(), kz.ravel()], axis=1)
            g, _ = self._interpolate_rows(kvec @ rot, _cube_reach(len(kept)), False)
            out[i] = g.reshape(ky.shape)
        return out

    # ------------------------------------------------------------------ backends
    def _select_backend(self, backend: str) -> None:
        if backend == "numpy":
            self._backend = "numpy"
            self.backend_name = "numpy (reference, asked for)"
            return
        if backend in ("numba", "opencl"):
            self._kernels[backend] = _make_kernel(backend, self)
            self._backend = backend
            self.backend_name = f"{self._kernels[backend].describe()} (asked for)"
            return
        # auto: measure what is present (interleaved rounds, so that load from other
        # processes affects both alike), keep the fastest
        notes: list[str] = []
        for name in ("numba", "opencl"):
            try:
                self._kernels[name] = _make_kernel(name, self)
            except Exception as exc:  # noqa: BLE001 - a missing backend is a note, not an error
                notes.append(f"{name} unavailable: {str(exc).splitlines()[0]}")
        rounds: dict[str, list[float]] = {name: [] for name in self._kernels}
        for _ in range(6):
            for name, kernel in self._kernels.items():
                rounds[name].append(_median_microseconds(self, kernel, calls=5))
        timings = {name: float(np.median(values)) for name, values in rounds.items()}
        if not timings:
            self._backend = "numpy"
            self.backend_name = "numpy (auto: no compiled backend; " + "; ".join(notes) + ")"
            return
        best = min(timings, key=timings.get)  # type: ignore[arg-type]
        self._backend = best
        measured = ", ".join(f"{k} {v:.0f} us" for k, v in sorted(timings.items()))
        extra = ("; " + "; ".join(notes)) if notes else ""
        self.backend_name = (
            f"{self._kernels[best].describe()} (auto: fastest median at K={self.modes}: "
            f"{measured}{extra})"
        )

    @property
    def backend(self) -> str:
        """Short name of the per-pose backend in use."""
        return self._backend

    def use_backend(self, name: str) -> None:
        """Switch the per-pose backend (building it if needed)."""
        if name not in PER_POSE_BACKENDS:
            raise ValueError(f"unknown backend {name!r}; valid: {', '.join(PER_POSE_BACKENDS)}")
        if name != "numpy" and name not in self._kernels:
            self._kernels[name] = _make_kernel(name, self)
        self._backend = name


def _make_kernel(name: str, correlator: Correlator) -> Any:
    if name == "numba":
        return NumbaKernel(correlator)
    from engine.correlation_cl import OpenCLKernel

    return OpenCLKernel(correlator)


def _median_microseconds(correlator: Correlator, kernel: Any, calls: int = 30) -> float:
    """Median wall time of ``kernel.pose`` at a few generic poses (after one warm-up)."""
    rng = np.random.default_rng(0)
    from engine.pose import rotation_matrix

    rot = rotation_matrix(rng.normal(size=3))
    t = correlator.centre_fixed - rot @ correlator.centre_moving
    kernel.pose(correlator, rot, t)
    times = []
    for _ in range(calls):
        rot = rotation_matrix(rng.normal(size=3))
        t = correlator.centre_fixed - rot @ correlator.centre_moving + rng.normal(size=3)
        start = time.perf_counter()
        kernel.pose(correlator, rot, t)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e6)


# ------------------------------------------------------------ interpolation (shared)
# The helpers below read a table of interleaved float rows (columns: real and imaginary part
# of the value, then of the derivatives along x, y, z) at a lattice cell: the row of the
# cell's lower corner ``b00``, its +y neighbour ``b01``, +x neighbour ``b10`` and +x+y
# neighbour ``b11`` (the +z neighbour of each is the next row), and the fractional position
# ``(tx, ty, tz)`` in the cell. The compiled kernels inline them with scalar indices; the
# numpy reference calls the same Python functions with index and position arrays.
def _cell(ux, uy, uz, radius, side):
    """Lattice cell of the point ``(ux, uy, uz)`` in a table of ``side^3`` rows whose index 0
    lies at ``radius``: ``(b00, b01, b10, b11, tx, ty, tz)``."""
    fx = np.floor(ux)
    fy = np.floor(uy)
    fz = np.floor(uz)
    b00 = ((int(fx) + radius) * side + int(fy) + radius) * side + int(fz) + radius
    return (b00, b00 + side, b00 + side * side, b00 + side * side + side,
            ux - fx, uy - fy, uz - fz)


def _bilinear(d00, d01, d10, d11, u, v):
    """Bilinear interpolation of four corner values ``d[i][j]`` (``i`` along ``u``, ``j``
    along ``v``) at ``(u, v)``, and its two derivatives: ``(value, d/du, d/dv)``."""
    l0 = d00 + v * (d01 - d00)
    l1 = d10 + v * (d11 - d10)
    return l0 + u * (l1 - l0), l1 - l0, (d01 - d00) + u * ((d11 - d10) - (d01 - d00))


def _lerp(table, col, cell):
    """Column ``col`` of the table, interpolated trilinearly in ``cell``."""
    b00, b01, b10, b11, tx, ty, tz = cell
    a00 = table[b00, col] + tz * (table[b00 + 1, col] - table[b00, col])
    a01 = table[b01, col] + tz * (table[b01 + 1, col] - table[b01, col])
    a10 = table[b10, col] + tz * (table[b10 + 1, col] - table[b10, col])
    a11 = table[b11, col] + tz * (table[b11 + 1, col] - table[b11, col])
    return _bilinear(a00, a01, a10, a11, tx, ty)[0]


def _hermite(table, col, cell):
    """Gradient-enhanced interpolation of one real component (``col`` 0: real part, 1:
    imaginary part) in ``cell``: ``(G, dG/dux, dG/duy, dG/duz)``.

    Columns ``col`` (value ``v``) and ``col + 2``, ``col + 4``, ``col + 6`` (the lattice
    derivatives along x, y, z, from the moment spectra) give

        G = trilinear(v) + 1/2 sum_a t_a (1 - t_a) B_a,

    ``B_a`` the bilinear interpolation, over the other two axes, of the drop of the
    ``a``-derivative across the cell (lower face minus upper face). This is exact for
    quadratics (trilinear alone only for linear functions) and continuous across cell
    faces; its gradient, differentiated exactly, is what the torque sums use, so the torque
    is the derivative of the energy that is reported.
    """
    b00, b01, b10, b11, tx, ty, tz = cell
    # trilinear part: along z first, then bilinear over (x, y); its z-derivative is the
    # bilinear interpolation of the z differences
    v000 = table[b00, col]
    v010 = table[b01, col]
    v100 = table[b10, col]
    v110 = table[b11, col]
    e00 = table[b00 + 1, col] - v000
    e01 = table[b01 + 1, col] - v010
    e10 = table[b10 + 1, col] - v100
    e11 = table[b11 + 1, col] - v110
    g, gx, gy = _bilinear(v000 + tz * e00, v010 + tz * e01, v100 + tz * e10, v110 + tz * e11,
                          tx, ty)
    gz = _bilinear(e00, e01, e10, e11, tx, ty)[0]
    # x: drop X(0, y, z) - X(1, y, z), bilinear over (y, z)
    c = col + 2
    b, by, bz = _bilinear(table[b00, c] - table[b10, c], table[b00 + 1, c] - table[b10 + 1, c],
                          table[b01, c] - table[b11, c], table[b01 + 1, c] - table[b11 + 1, c],
                          ty, tz)
    p = 0.5 * tx * (1.0 - tx)
    g += p * b
    gx += (0.5 - tx) * b
    gy += p * by
    gz += p * bz
    # y: drop Y(x, 0, z) - Y(x, 1, z), bilinear over (x, z)
    c = col + 4
    b, bx, bz = _bilinear(table[b00, c] - table[b01, c], table[b00 + 1, c] - table[b01 + 1, c],
                          table[b10, c] - table[b11, c], table[b10 + 1, c] - table[b11 + 1, c],
                          tx, tz)
    p = 0.5 * ty * (1.0 - ty)
    g += p * b
    gy += (0.5 - ty) * b
    gx += p * bx
    gz += p * bz
    # z: drop Z(x, y, 0) - Z(x, y, 1), bilinear over (x, y)
    c = col + 6
    b, bx, by = _bilinear(table[b00, c] - table[b00 + 1, c], table[b01, c] - table[b01 + 1, c],
                          table[b10, c] - table[b10 + 1, c], table[b11, c] - table[b11 + 1, c],
                          tx, ty)
    p = 0.5 * tz * (1.0 - tz)
    g += p * b
    gz += (0.5 - tz) * b
    gx += p * bx
    gy += p * by
    return g, gx, gy, gz


def _python(func: Any) -> Any:
    """The plain Python function behind a numba dispatcher (the numpy reference calls the
    shared helpers on arrays, which the compiled versions are not built for)."""
    return getattr(func, "py_func", func)


# ---------------------------------------------------------------------- numba backend
def _mode_terms(table, cell, c_re, c_im, rk0, rk1, rk2, moments):
    """One mode's contributions: ``Re(c G)``, ``Im(c G)`` and, with ``moments``, the
    torque terms ``Re(c dG/du) x R^T k``. Inlined into the compiled kernels."""
    if moments:
        g_re, gx_re, gy_re, gz_re = _hermite(table, 0, cell)
        g_im, gx_im, gy_im, gz_im = _hermite(table, 1, cell)
        r0 = c_re * gx_re - c_im * gx_im
        r1 = c_re * gy_re - c_im * gy_im
        r2 = c_re * gz_re - c_im * gz_im
        t0 = r1 * rk2 - r2 * rk1
        t1 = r2 * rk0 - r0 * rk2
        t2 = r0 * rk1 - r1 * rk0
    else:
        g_re = _lerp(table, 0, cell)
        g_im = _lerp(table, 1, cell)
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
    return c_re * g_re - c_im * g_im, c_re * g_im + c_im * g_re, t0, t1, t2


def _pose_kernel(
    rot, t, fixed_kept, table, radius, kept, c1, c2, half1, half2, h, n_h, q, kappa,
    moments, partial,
):
    """Energy, force and torque at one pose, all in compiled code: (7,) float64.

    Returns ``[E, F (3), T (3)]`` (torque zeros when ``moments`` is False). Same sums as
    ``Correlator._sums_numpy`` and the same finishing as ``Correlator._finish``.
    fixed_kept (K, K, K) complex64; table (B^3, C) float32 interleaved (C = 8 or 2);
    kept (K,) float64; partial (K, 7) float64 scratch, one row per kx plane (so the kx
    loop can run in parallel without a shared accumulator).
    """
    out = np.zeros(7)
    # part 2's rotated grid box (one cell of margin) must meet part 1's, else all zero
    rc2 = np.empty(3)
    for a in range(3):
        rc2[a] = rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2]
        extent = (abs(rot[a, 0]) * half2[0] + abs(rot[a, 1]) * half2[1]
                  + abs(rot[a, 2]) * half2[2])
        if abs(rc2[a] + t[a] - c1[a]) >= half1[a] + extent + h:
            return out
    nk = kept.shape[0]
    side = 2 * radius + 2
    px = np.empty(nk, dtype=np.complex128)
    py = np.empty(nk, dtype=np.complex128)
    pz = np.empty(nk, dtype=np.complex128)
    scale = 2.0 * np.pi / n_h
    s_x = t[0] + rc2[0] - c1[0]
    s_y = t[1] + rc2[1] - c1[1]
    s_z = t[2] + rc2[2] - c1[2]
    for i in range(nk):
        px[i] = np.exp(1j * (scale * kept[i] * s_x))
        py[i] = np.exp(1j * (scale * kept[i] * s_y))
        pz[i] = np.exp(1j * (scale * kept[i] * s_z))
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    for ix in prange(nk):
        kx = kept[ix]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        s5 = 0.0
        s6 = 0.0
        for iy in range(nk):
            ky = kept[iy]
            pxy = px[ix] * py[iy]
            # R^T k = kx R[0,:] + ky R[1,:] + kz R[2,:]; lattice index u = -q R^T k
            a0 = kx * r00 + ky * r10
            a1 = kx * r01 + ky * r11
            a2 = kx * r02 + ky * r12
            row_im = 0.0
            for iz in range(nk):
                kz = kept[iz]
                rk0 = a0 + kz * r20
                rk1 = a1 + kz * r21
                rk2 = a2 + kz * r22
                cell = _cell(-q * rk0, -q * rk1, -q * rk2, radius, side)
                c = fixed_kept[ix, iy, iz] * pxy * pz[iz]
                cg_re, cg_im, d4, d5, d6 = _mode_terms(
                    table, cell, c.real, c.imag, rk0, rk1, rk2, moments
                )
                s0 += cg_re
                row_im += cg_im
                s3 += cg_im * kz
                s4 += d4
                s5 += d5
                s6 += d6
            s1 += row_im * kx
            s2 += row_im * ky
        partial[ix, 0] = s0
        partial[ix, 1] = s1
        partial[ix, 2] = s2
        partial[ix, 3] = s3
        partial[ix, 4] = s4
        partial[ix, 5] = s5
        partial[ix, 6] = s6
    return _finish_sums(_sum_partials(partial), rot, c2, kappa, n_h, q, moments)


def _sum_partials(partial):
    """(7,) float64: the per-row (or per-chunk) partial sums added up, in a fixed order so the
    result does not depend on the thread count."""
    sums = np.zeros(7)
    for i in range(partial.shape[0]):
        for j in range(7):
            sums[j] += partial[i, j]
    return sums


def _finish_sums(sums, rot, c2, kappa, n_h, q, moments):
    """[E, F (3), T (3)] from the raw sums (see ``Correlator._finish``); the torque sums
    arrive as ``Re(c dG/du) x R^T k`` and are scaled to ``Im(c M) x R^T k`` here."""
    out = np.zeros(7)
    if moments:
        for a in range(4, 7):
            sums[a] *= q * n_h / (2.0 * np.pi)
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    factor = 2.0 * np.pi * kappa / n_h
    out[0] = -kappa * sums[0]
    for a in range(3):
        out[1 + a] = -factor * sums[1 + a]
    if moments:
        # local = S_m + c2 x (R^T S_k); torque = -factor R local
        rs0 = r00 * sums[1] + r10 * sums[2] + r20 * sums[3]
        rs1 = r01 * sums[1] + r11 * sums[2] + r21 * sums[3]
        rs2 = r02 * sums[1] + r12 * sums[2] + r22 * sums[3]
        l0 = sums[4] + c2[1] * rs2 - c2[2] * rs1
        l1 = sums[5] + c2[2] * rs0 - c2[0] * rs2
        l2 = sums[6] + c2[0] * rs1 - c2[1] * rs0
        for a in range(3):
            out[4 + a] = -factor * (rot[a, 0] * l0 + rot[a, 1] * l1 + rot[a, 2] * l2)
    return out


def _pose_kernel_list(
    rot, t, kvec, coeff, table, radius, c1, c2, half1, half2, h, n_h, q, kappa, moments,
    partial,
):
    """As ``_pose_kernel`` for an arbitrary list of modes (selection "largest").

    kvec (m', 3) float64 signed frequency indices; coeff (m',) complex64 rho1c^(w) dw;
    partial (P, 7) float64 scratch, one row per chunk of modes. One sincos per mode (the
    phases are not separable off the cube).
    """
    out = np.zeros(7)
    rc2 = np.empty(3)
    for a in range(3):
        rc2[a] = rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2]
        extent = (abs(rot[a, 0]) * half2[0] + abs(rot[a, 1]) * half2[1]
                  + abs(rot[a, 2]) * half2[2])
        if abs(rc2[a] + t[a] - c1[a]) >= half1[a] + extent + h:
            return out
    side = 2 * radius + 2
    scale = 2.0 * np.pi / n_h
    s_x = scale * (t[0] + rc2[0] - c1[0])
    s_y = scale * (t[1] + rc2[1] - c1[1])
    s_z = scale * (t[2] + rc2[2] - c1[2])
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    nm = kvec.shape[0]
    nchunk = partial.shape[0]
    chunk = (nm + nchunk - 1) // nchunk
    for ci in prange(nchunk):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        s5 = 0.0
        s6 = 0.0
        for m in range(ci * chunk, min(nm, (ci + 1) * chunk)):
            kx = kvec[m, 0]
            ky = kvec[m, 1]
            kz = kvec[m, 2]
            rk0 = kx * r00 + ky * r10 + kz * r20
            rk1 = kx * r01 + ky * r11 + kz * r21
            rk2 = kx * r02 + ky * r12 + kz * r22
            cell = _cell(-q * rk0, -q * rk1, -q * rk2, radius, side)
            ph = kx * s_x + ky * s_y + kz * s_z
            c = coeff[m] * (np.cos(ph) + 1j * np.sin(ph))
            cg_re, cg_im, d4, d5, d6 = _mode_terms(
                table, cell, c.real, c.imag, rk0, rk1, rk2, moments
            )
            s0 += cg_re
            s1 += cg_im * kx
            s2 += cg_im * ky
            s3 += cg_im * kz
            s4 += d4
            s5 += d5
            s6 += d6
        partial[ci, 0] = s0
        partial[ci, 1] = s1
        partial[ci, 2] = s2
        partial[ci, 3] = s3
        partial[ci, 4] = s4
        partial[ci, 5] = s5
        partial[ci, 6] = s6
    return _finish_sums(_sum_partials(partial), rot, c2, kappa, n_h, q, moments)


def _prange_placeholder(n):  # replaced by numba.prange when numba is present
    return range(n)


prange = _prange_placeholder
_NUMBA_FUNCS: dict[tuple[bool, str], Any] = {}


def _numba_function(parallel: bool, kind: str = "cube") -> Any:
    """The compiled sum, serial or parallel (compiled once, cached on disk).

    ``kind`` is "cube" (separable phases over the kept cube) or "list" (any mode list).
    """
    global prange, _finish_sums, _sum_partials, _cell, _bilinear, _lerp, _hermite, _mode_terms
    key = (parallel, kind)
    if key not in _NUMBA_FUNCS:
        import numba

        prange = numba.prange
        if not hasattr(_finish_sums, "py_func"):
            _finish_sums = numba.njit(fastmath=True, cache=True, nogil=True)(_finish_sums)
            _sum_partials = numba.njit(fastmath=True, cache=True, nogil=True)(_sum_partials)
        if not hasattr(_cell, "py_func"):
            inline = numba.njit(inline="always", fastmath=True, cache=True, nogil=True)
            _cell, _bilinear = inline(_cell), inline(_bilinear)
            _lerp, _hermite = inline(_lerp), inline(_hermite)
            _mode_terms = inline(_mode_terms)
        source = _pose_kernel if kind == "cube" else _pose_kernel_list
        # A distinct function object (own name) per variant, so the compiled versions get
        # separate on-disk cache entries.
        name = f"{source.__name__}_{'parallel' if parallel else 'serial'}"
        func = types.FunctionType(source.__code__.replace(co_name=name), globals(), name)
        func.__qualname__ = name
        func.__doc__ = source.__doc__
        _NUMBA_FUNCS[key] = numba.njit(
            fastmath=True, cache=True, parallel=parallel, nogil=True
        )(func)
    return _NUMBA_FUNCS[key]


class NumbaKernel:
    """Per-pose sums compiled in process with numba (one thread unless asked for more)."""

    def __init__(self, correlator: Correlator) -> None:
        try:
            import numba
        except ImportError as exc:  # pragma: no cover - depends on the install
            raise RuntimeError("numba is not installed: `pip install numba`") from exc
        # One thread unless asked for more: on a shared 2-core machine a parallel region
        # whose second thread is not scheduled stalls for a whole time slice (the
        # benchmark saw medians of 36 ms instead of 80 us), which a 1 kHz loop cannot take.
        wanted = int(os.environ.get("SKELASM_CORRELATION_THREADS", "1") or 1)
        self.threads = max(1, min(wanted, numba.get_num_threads()))
        kind = "cube" if correlator.selection == "cube" else "list"
        self._serial = _numba_function(False, kind)
        self._parallel = _numba_function(True, kind) if self.threads > 1 else None
        self.parallel = False
        self._modes = -1
        self.prepare(correlator)
        if self._parallel is not None:
            numba.set_num_threads(self.threads)
            # Interleaved, so that a burst of load from other processes hits both alike;
            # several threads only when clearly faster.
            serial, par = [], []
            for _ in range(6):
                self.parallel = False
                serial.append(_median_microseconds(correlator, self, calls=2))
                self.parallel = True
                par.append(_median_microseconds(correlator, self, calls=2))
            self.parallel = float(np.median(par)) < 0.75 * float(np.median(serial))

    def set_modes(self, correlator: Correlator) -> None:
        self._modes = -1  # rebind lazily: the table is rebuilt on first use

    def describe(self) -> str:
        return f"numba ({self.threads} threads)" if self.parallel else "numba (1 thread)"

    def prepare(self, correlator: Correlator) -> None:
        """Bind the arrays of the current truncation (call after set_modes)."""
        table, radius, scale = correlator.moving_table()
        modes: tuple[Any, ...]
        if correlator.selection == "cube":
            self._partial = np.zeros((correlator.modes, 7))
            modes = (correlator._fixed_kept, table.reshape(-1, table.shape[-1]), radius,
                     correlator._kept.astype(np.float64))
        else:
            assert correlator._mode_k is not None
            self._partial = np.zeros((max(1, min(64, len(correlator._mode_k) // 512)), 7))
            modes = (correlator._mode_k, correlator._mode_a, table.reshape(-1, table.shape[-1]),
                     radius)
        self._args: tuple[Any, ...] = (
            *modes,
            correlator.centre_fixed,
            correlator.centre_moving,
            correlator.half_fixed,
            correlator.half_moving,
            correlator.spacing,
            correlator.size * correlator.spacing,
            float(scale),
            correlator.kappa,
            correlator.rotation,
            self._partial,
        )
        self._modes = correlator.modes

    def pose(self, correlator: Correlator, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) float64 ``[E, F (3), T (3)]`` at one pose."""
        if self._modes != correlator.modes:
            self.prepare(correlator)
        func: Any = self._parallel if self.parallel else self._serial
        return func(rot, t, *self._args)


def correlator_for_scene(
    scene: Any,
    *,
    modes: int | None = None,
    backend: str = "auto",
    rotation: bool = True,
    kappa: float = 1.0,
    progress: Any = None,
    cancel: Any = None,
) -> Correlator:
    """A :class:`Correlator` for a scene's two parts (descriptors from the store, cached).

    Parameters
    ----------
    scene : engine.scene.Scene or path
        The scene (or its TOML file); its first part is fixed, the second moves.
    modes : int, optional
        Modes per axis (default: the scene's ``[correlation] modes``).
    backend, rotation, kappa
        As :class:`Correlator`.
    progress, cancel
        Passed on to the descriptor computation.
    """
    from engine.scene import Scene, load_scene
    from engine.store import descriptors_for_scene

    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if len(scene.parts) < 2:
        raise ValueError(f"{scene.path}: the scene needs two parts to correlate")
    kwargs: dict[str, Any] = {}
    if progress is not None:
        kwargs["progress"] = progress
    if cancel is not None:
        kwargs["cancel"] = cancel
    descriptors = descriptors_for_scene(scene, **kwargs)
    return Correlator(
        descriptors[0],
        descriptors[1],
        modes=int(modes if modes is not None else scene.modes),
        rotation=rotation,
        backend=backend,
        kappa=kappa,
    )
