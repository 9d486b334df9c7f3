"""Translational energy landscapes: E(t) (and F(t)) on a regular grid of translations.

For one rotation ``R`` of the moving part, :meth:`engine.correlation.Correlator.landscape`
computes the score for every translation of the FFT lattice with one inverse FFT. The
result is a :class:`Landscape`: the energy on an ``(N, N, N)`` float32 grid of translations
``t = t0 + h * (i, j, k)``, optionally the force on the same grid, 2D sections for views,
and trilinear lookup for scenes that lock the rotation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

PLANES = ("xy", "xz", "yz")


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

    def lookup(self, translation: np.ndarray):
        """Energy and force at one translation.

        With the force field present the energy is interpolated by the gradient-enhanced
        scheme of :func:`engine.correlation._hermite` (the force is the energy's derivative
        on the lattice) and the force returned is minus the gradient of that interpolant, so
        a part moving in a locked-rotation scene sees a conservative field. Without it, the
        energy is trilinear and the force zero.

        Parameters
        ----------
        translation : (3,) float
            Part 2 relative to part 1 (with this landscape's rotation).

        Returns
        -------
        engine.correlation.Evaluation
            ``torque`` is None (the rotation is locked); outside the landscape the energy
            and force are 0 (the parts' grid boxes do not overlap there). The force is
            zeros when the landscape was computed with ``forces=False``.
        """
        from engine.correlation import Evaluation

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
    """Energy and ``-grad`` of the gradient-enhanced interpolant in one lattice cell.

    ``energy`` (2, 2, 2) and ``force`` (3, 2, 2, 2) at the cell's corners, ``frac`` (3,) the
    position in the cell. The corners become rows ``4 dx + 2 dy + dz`` of a table whose
    columns are the energy and its lattice derivatives ``dE/du = -F h`` (the layout
    :func:`engine.correlation._hermite` reads, imaginary columns zero).
    """
    from engine.correlation import _hermite, _python

    table = np.zeros((8, 8))
    table[:, 0] = energy.reshape(8)
    for a in range(3):
        table[:, 2 + 2 * a] = -spacing * force[a].reshape(8)
    cell = (0, 2, 4, 6, float(frac[0]), float(frac[1]), float(frac[2]))
    g, gx, gy, gz = _python(_hermite)(table, 0, cell)
    return float(g), np.array([-gx, -gy, -gz]) / spacing
