"""The band's taper (``spectrum.BAND_TAPER``, off by default): no spurious barrier on the way in.

A truncated Fourier series of a sharp density rings (Gibbs): the box band ``-K/2 ... K/2``
of a plate's and a base's big flat faces gives an energy that rises and falls along the
faces' normal, barriers a user's push must climb that the full correlation does not have.
Lanczos' sigma factors (``sinc(k / (K // 2 + 1))`` per axis) damp the ringing. Here a
plate is lowered onto a base along its normal: on the way in, the tapered band's largest
rise of the energy (its barrier) at K = 13 and 17 is within the full lattice's own (the
descriptors' outside tails, which repel), where the box band's is larger. A ball band of
densities whose tails end at one distance from their parts (``spectrum.BAND_SHAPE``,
``engine.correlation.support``, options, off) rings less than the cube of the densities as
sampled, but rings. Why neither is the default yet: docs/correlation.md and
docs/fine_level.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from engine.correlation import spectrum
from engine.correlation.spectrum import kept_indices, kept_weights

SCENE = """name = "plate over a base"
units = "mm"
assembled_pose = [0, 0, 0, 0, 0, 0]
insertion_axis = [0, 0, -1]
[descriptor]
grid = 24
[correlation]
modes = 9
[[part]]
name = "base"
file = "base.stl"
pose = [0, 0, 0, 0, 0, 0]
fixed = true
[[part]]
name = "plate"
file = "plate.stl"
pose = [0, 0, 30, 0, 0, 0]
"""


def test_the_band_is_tapered_by_lanczos_sigma_factors_and_the_whole_lattice_is_not():
    for k in (1, 4, 7, 8, 13, 25):
        half = k // 2
        index = kept_indices(k, 64)
        w = kept_weights(k, 64, taper="lanczos")
        box = kept_weights(k, 64, taper="none")
        np.testing.assert_array_equal(kept_weights(k, 64), box)  # the default: untapered
        np.testing.assert_allclose(w, box * np.sinc(index / (half + 1)), rtol=1e-12)
        np.testing.assert_array_equal(w, w[::-1])  # still symmetric about zero
        assert w[half] == 1.0 and np.all(np.diff(w[half:]) < 0)  # k = 0 whole, falling off
        assert np.all(w[1:-1] > 0)
    # the whole lattice is no truncation: every mode once, untapered
    np.testing.assert_array_equal(kept_weights(16, 16, taper="lanczos"),
                                  kept_weights(16, 16, taper="none"))
    with pytest.raises(ValueError, match="taper"):
        kept_weights(5, 64, taper="hann")


def _barrier(energy: np.ndarray) -> float:
    """Largest rise of the energy met on the way in (``energy`` ordered from the seat out)."""
    worst, low = 0.0, np.inf
    for value in energy[::-1]:
        low = min(low, value)
        worst = max(worst, value - low)
    return worst


@pytest.fixture(scope="module")
def plate_scene(tmp_path_factory):
    trimesh = pytest.importorskip("trimesh")
    folder = tmp_path_factory.mktemp("plate")
    base = trimesh.creation.box((60, 50, 20))
    base.apply_translation((0, 0, -10))
    plate = trimesh.creation.box((50, 40, 6))
    plate.apply_translation((0, 0, 3))
    base.export(folder / "base.stl")
    plate.export(folder / "plate.stl")
    (folder / "scene.toml").write_text(SCENE)
    from engine.scene import load_scene

    return load_scene(folder / "scene.toml")


def test_the_tapered_band_adds_no_barrier_on_the_way_in(plate_scene, monkeypatch):
    """(and the cube band does: see the module; the ball band in use does not either)"""
    from engine.correlation import support
    from engine.correlation.from_scene import correlator_for_scene

    def profile(modes: int) -> np.ndarray:
        """Energy on the plate's axis from its seat up, from the landscape (one FFT)."""
        corr = correlator_for_scene(plate_scene, modes=modes, backend="numpy")
        land = corr.landscape(np.eye(3), modes=modes, forces=False)
        axes = [np.asarray(a) for a in land.translations]
        i, j = (int(np.argmin(np.abs(a))) for a in axes[:2])
        assert abs(axes[0][i]) < 1e-9 and abs(axes[1][j]) < 1e-9
        up = (axes[2] >= -1e-9) & (axes[2] <= 40.0)  # past where the grids stop meeting
        return np.asarray(land.energy, np.float64)[i, j, up]

    # the ball band of densities whose tails end at one distance from their parts (an
    # option, off by default)
    monkeypatch.setattr(spectrum, "BAND_SHAPE", "ball")
    monkeypatch.setattr(support, "SUPPORT_WINDOW", True)
    ball = {modes: profile(modes) for modes in (13, 17)}
    ball_full = profile(10_000)
    # the cube band of the densities as sampled, with their tails cut by the grids
    monkeypatch.setattr(spectrum, "BAND_SHAPE", "cube")
    monkeypatch.setattr(support, "SUPPORT_WINDOW", False)
    full = profile(10_000)  # the whole lattice: the correlation itself
    assert full.min() < 0 and _barrier(full) > 0  # outside tails facing each other repel
    # the windowed tails repel less (14,062 against 21,692 here)
    assert 0 < _barrier(ball_full) < 0.8 * _barrier(full)
    for modes in (13, 17):
        with monkeypatch.context() as m:
            m.setattr(spectrum, "BAND_TAPER", "lanczos")
            tapered = profile(modes)
            # the whole lattice stays untapered
            np.testing.assert_allclose(profile(10_000), full, rtol=1e-6)
        assert tapered.min() < 0
        assert _barrier(tapered) <= _barrier(full), modes
        box = profile(modes)
        # the cube band rings: its barrier exceeds the correlation's own
        assert _barrier(box) > 1.2 * _barrier(full) and _barrier(box) > 3 * _barrier(tapered)
        # the ball band of the windowed densities rings less, but rings (10,660
        # and 23,940 against the cube's 27,415 and 38,705 at K = 13 and 17)
        assert ball[modes].min() < 0
        assert 0 < _barrier(ball[modes]) < 0.7 * _barrier(box), modes
