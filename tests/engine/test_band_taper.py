"""The guidance's band: no spurious barrier on the way in.

A truncated Fourier series of a sharp density rings (Gibbs): the box band ``-K/2 ... K/2``
of a plate's and a base's big flat faces gives an energy that rises and falls along the
faces' normal, barriers a user's push must climb that the full correlation does not have.
Lanczos' sigma factors (``sinc(k / (K // 2 + 1))`` per axis) damp the ringing. Here a
plate is lowered onto a base along its normal: on the way in, the smooth band's largest
rise of the energy (its barrier) at K = 13 and 17 (a ball of modes, tapered, of densities
whose tails end at one distance from their parts: the guidance's band) is within its
densities' own (their outside tails, which repel), where the box band's is larger than
the correlation's. docs/correlation.md and docs/fine_level.md.
"""

from __future__ import annotations

import numpy as np
import pytest

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


def test_the_guidance_band_adds_no_barrier_on_the_way_in(plate_scene):
    """The box band rings: on the way in its barrier exceeds the correlation's own; the
    smooth band (a ball, Lanczos-tapered, of the windowed tails) adds none to its own.
    """
    from engine.correlation.from_scene import correlator_for_scene

    def profile(modes: int, band: str) -> np.ndarray:
        """Energy on the plate's axis from its seat up, from the landscape (one FFT)."""
        corr = correlator_for_scene(plate_scene, modes=modes, backend="numpy", band=band)
        land = corr.landscape(np.eye(3), modes=modes, forces=False)
        axes = [np.asarray(a) for a in land.translations]
        i, j = (int(np.argmin(np.abs(a))) for a in axes[:2])
        assert abs(axes[0][i]) < 1e-9 and abs(axes[1][j]) < 1e-9
        up = (axes[2] >= -1e-9) & (axes[2] <= 40.0)  # past where the grids stop meeting
        return np.asarray(land.energy, np.float64)[i, j, up]

    full = profile(10_000, "box")  # the whole lattice: the correlation itself
    assert full.min() < 0 and _barrier(full) > 0  # outside tails facing each other repel
    # the whole lattice is no truncation: the smooth band's is of the windowed densities,
    # untapered, and their tails repel less
    smooth_full = profile(10_000, "smooth")
    assert 0 < _barrier(smooth_full) < 0.8 * _barrier(full)
    for modes in (13, 17):
        box = profile(modes, "box")
        smooth = profile(modes, "smooth")
        assert box.min() < 0 and smooth.min() < 0
        # the box band rings: its barrier exceeds the correlation's own
        assert _barrier(box) > 1.2 * _barrier(full), modes
        # the smooth band adds none to its densities' own
        assert _barrier(smooth) <= _barrier(smooth_full), modes
        assert _barrier(box) > 3 * _barrier(smooth), modes


def test_the_bands_are_named_alike_in_the_settings_and_the_engine():
    from engine.correlation.spectrum import BANDS, Band, band_named
    from engine.errors import InputError
    from engine.params import BAND_NAMES, GUIDANCE_BAND, CorrelationParams

    assert tuple(BANDS) == BAND_NAMES and GUIDANCE_BAND in BANDS
    assert band_named("box") == Band("cube", "none", False)
    assert band_named("smooth") == Band("ball", "lanczos", True)
    with pytest.raises(ValueError, match="unknown band"):
        band_named("round")
    with pytest.raises(ValueError, match="taper"):
        Band("cube", "hann")
    with pytest.raises(InputError, match="band"):
        CorrelationParams(band="ball")
