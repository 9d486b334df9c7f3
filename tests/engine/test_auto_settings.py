"""Settings chosen from the parts: the fit measured at the seat, and what follows from it.

A round peg in a blind bore, modelled with a known clearance, width and depth, is measured
at its assembled pose; the choices (grid spacing, K, STEP chord tolerance) are checked
against the measure, against each other (a narrower fit asks for more modes, a tighter one
for a finer tessellation) and against what the user gives (always kept).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from engine.loading import Part

trimesh = pytest.importorskip("trimesh")

#: The descriptor's settings no size changes, said with their reasons when a scene leaves them.
SCALE_FREE = ["descriptor.sigma", "descriptor.penalty", "descriptor.padding"]


def _part(mesh, name: str) -> Part:
    return Part(name=name, vertices=np.asarray(mesh.vertices, np.float64),
                faces=np.asarray(mesh.faces, np.int64), source=None, unit="mm")


@functools.cache
def peg_and_bore(diameter: float, clearance: float, *, depth: float = 12.0,
                 sections: int = 128) -> tuple[Part, Part]:
    """A block with a blind bore ``diameter + 2 clearance`` wide, and a peg of ``diameter``.

    The bore's floor at z = -depth; the peg's end at its own z = 0; it seats at
    (0, 0, -depth). Bore and peg are prisms on ``sections``-gons, the bore's circumscribed
    (its flats, not its corners, at the bore's radius) so the gap is the clearance.
    """
    r_bore = 0.5 * diameter + clearance
    bore = trimesh.creation.cylinder(radius=r_bore / np.cos(np.pi / sections),
                                     height=depth + 1.0, sections=sections)
    bore.apply_translation((0, 0, -depth + 0.5 * (depth + 1.0)))
    block = trimesh.creation.box(extents=(4 * diameter, 4 * diameter, depth + 8.0))
    block.apply_translation((0, 0, -0.5 * (depth + 8.0)))
    block = block.difference(bore)
    peg = trimesh.creation.cylinder(radius=0.5 * diameter, height=2 * depth, sections=sections)
    peg.apply_translation((0, 0, depth))
    return _part(block, "block"), _part(peg, "peg")


SEAT = np.array([0.0, 0.0, -12.0, 0.0, 0.0, 0.0])
AXIS = np.array([0.0, 0.0, -1.0])


@pytest.mark.parametrize("clearance", [0.02, 0.2])
def test_the_fit_is_measured_at_the_seat(clearance):
    from engine.sim.auto import measure_fit

    block, peg = peg_and_bore(10.0, clearance)
    fit = measure_fit(block, peg, SEAT, AXIS)
    assert fit.clearance == pytest.approx(clearance, rel=0.15)
    assert fit.tightest is not None and 0.5 * clearance < fit.tightest <= fit.clearance
    assert fit.width == pytest.approx(10.0, rel=0.05)
    # the fit is where the peg is in the bore: across the bore, and down to its floor
    assert fit.box_lo[2] == pytest.approx(-12.0, abs=0.5)
    assert fit.box_hi[2] == pytest.approx(0.0, abs=1.0)
    assert np.all(fit.box_hi[:2] - fit.box_lo[:2] < 10.0 + 4 * clearance)
    # and its cylinder about the axis: on the bore's axis, the peg's radius, as deep
    centre, axis, radius, half = fit.cylinder
    assert abs(float(axis @ AXIS)) == pytest.approx(1.0, abs=1e-9)
    assert np.linalg.norm(centre[:2]) < 0.05 and radius == pytest.approx(5.0, rel=0.02)
    assert centre[2] - half == pytest.approx(fit.box_lo[2], abs=1e-6)
    assert centre[2] + half == pytest.approx(fit.box_hi[2], abs=1e-6)


def test_a_fit_measured_again_is_kept_as_it_was(monkeypatch):
    from engine.sim import auto

    monkeypatch.setattr(auto, "_FITS", {})
    block, peg = peg_and_bore(10.0, 0.2, sections=48)
    calls = []
    measure = auto._measure_fit
    monkeypatch.setattr(auto, "_measure_fit", lambda *a: calls.append(a) or measure(*a))
    first = auto.measure_fit(block, peg, SEAT, AXIS)
    first.box_lo[:] = 0.0  # a caller's change does not reach the kept measure
    again = auto.measure_fit(block, peg, SEAT, AXIS)
    moved = auto.measure_fit(block, peg, SEAT + [0.0, 0.0, 1.0, 0.0, 0.0, 0.0], AXIS)
    assert len(calls) == 2  # the same parts at the same pose are measured once
    fresh = measure(block, peg, SEAT, AXIS)
    assert again.clearance == fresh.clearance and again.tightest == fresh.tightest
    assert (again.size, again.width, again.points) == (fresh.size, fresh.width, fresh.points)
    np.testing.assert_array_equal(again.box_lo, fresh.box_lo)
    np.testing.assert_array_equal(again.box_hi, fresh.box_hi)
    assert moved.box_lo[2] != again.box_lo[2]
    for i in range(auto.FITS_KEPT + 1):  # the oldest are let go
        auto.measure_fit(block, peg, SEAT + [0.0, 0.0, 0.01 * (i + 2), 0.0, 0.0, 0.0], AXIS)
    assert len(auto._FITS) == auto.FITS_KEPT
    auto.measure_fit(block, peg, SEAT, AXIS)
    assert len(calls) == 2 + auto.FITS_KEPT + 2


def _scene(block: Part, peg: Part, tmp_path, **given):
    """A scene in code for the two parts (saved as STL), giving only ``given``."""
    from engine.params import CorrelationParams, DescriptorParams
    from engine.scene import PartSpec, Scene

    files = []
    for part in (block, peg):
        path = tmp_path / f"{part.name}.stl"
        trimesh.Trimesh(part.vertices, part.faces, process=False).export(path)
        files.append(path)
    specs = (PartSpec(name="block", file=files[0], pose=np.zeros(6), fixed=True),
             PartSpec(name="peg", file=files[1], pose=SEAT, fixed=False))
    keys = {"grid": "descriptor.grid", "modes": "correlation.modes", "sigma": "descriptor.sigma"}
    return Scene(path=tmp_path / "scene.toml", name="fit", parts=specs, assembled_pose=SEAT,
                 insertion_axis=AXIS,
                 descriptor=DescriptorParams(grid=given.get("grid", 64),
                                             sigma=given.get("sigma", 0.5)),
                 correlation=CorrelationParams(modes=given.get("modes", 16)),
                 given=frozenset(keys[k] for k in given))


def test_modes_are_odd_and_capped_by_the_budget(tmp_path):
    from engine.sim.auto import choose_settings

    block, peg = peg_and_bore(5.0, 0.05)
    free = choose_settings(_scene(block, peg, tmp_path), [block, peg], budget=(127, "test"))
    assert free.modes % 2 == 1  # a band symmetric about zero
    assert "wavelength" in free.reasons["correlation.modes"]
    capped = choose_settings(_scene(block, peg, tmp_path), [block, peg],
                             budget=(11, "a test's budget"))
    assert free.modes > 11 and capped.modes == 11
    assert "a test's budget" in capped.reasons["correlation.modes"]
    assert "coarsely" in capped.reasons["correlation.modes"]


def test_a_narrower_fit_in_the_same_part_asks_for_more_modes(tmp_path):
    from engine.sim.auto import choose_settings

    chosen = []
    for diameter in (20.0, 5.0):
        block = trimesh.creation.box(extents=(80.0, 80.0, 20.0))
        block.apply_translation((0, 0, -10.0))
        radius = (0.5 * diameter + 0.05) / np.cos(np.pi / 128)
        bore = trimesh.creation.cylinder(radius=radius, height=13.0, sections=128)
        bore.apply_translation((0, 0, -5.5))
        _, peg = peg_and_bore(diameter, 0.05)
        fixed = _part(block.difference(bore), "block")
        s = choose_settings(_scene(fixed, peg, tmp_path), [fixed, peg], budget=(127, "test"))
        assert s.fit.width == pytest.approx(diameter, rel=0.05)
        chosen.append(s)
    assert chosen[1].modes > chosen[0].modes
    assert chosen[1].spacing < chosen[0].spacing


def test_a_tighter_fit_asks_for_a_finer_tessellation(tmp_path):
    from engine.sim.auto import choose_settings

    tolerances = []
    for clearance in (0.2, 0.02):
        block, peg = peg_and_bore(10.0, clearance)
        s = choose_settings(_scene(block, peg, tmp_path), [block, peg], budget=(25, "test"))
        assert s.tolerance is not None and s.tolerance < s.fit.tightest
        assert "tightest gap" in s.reasons["part.tolerance"]
        tolerances.append(s.tolerance)
    assert tolerances[1] < 0.2 * tolerances[0]


def test_a_tolerance_at_its_floor_says_so(tmp_path):
    """A gap so tight that a third of it is below the floor: the floor is chosen, and the
    reason names the floor, not the third of the gap.
    """
    from engine.sim.auto import TOLERANCE_FLOOR, choose_settings

    block, peg = peg_and_bore(10.0, 0.0005)
    s = choose_settings(_scene(block, peg, tmp_path), [block, peg], budget=(25, "test"))
    assert s.tolerance == pytest.approx(TOLERANCE_FLOOR * s.fit.size, rel=1e-2)
    assert s.tolerance > s.fit.tightest / 3.0
    assert "of the parts' size" in s.reasons["part.tolerance"]
    assert "finest kept" in s.reasons["part.tolerance"]


def test_what_the_user_gives_wins_and_the_rest_is_chosen(tmp_path):
    from engine.sim.auto import complete_scene

    block, peg = peg_and_bore(10.0, 0.05)
    given = _scene(block, peg, tmp_path, grid=40, modes=12)
    scene, parts = complete_scene(given)
    assert scene.descriptor.grid == 40 and scene.modes == 12 and scene.chosen == ()
    assert len(parts) == 2
    chosen, _ = complete_scene(_scene(block, peg, tmp_path, modes=12))
    assert chosen.modes == 12 and chosen.descriptor.spacing is not None
    assert [key for key, _, _ in chosen.chosen] == ["descriptor.spacing", *SCALE_FREE]
    free, _ = complete_scene(_scene(block, peg, tmp_path))
    keys = [key for key, _, _ in free.chosen]
    assert keys == ["descriptor.spacing", "correlation.modes", *SCALE_FREE]
    assert free.modes % 2 == 1 and all(reason for _, _, reason in free.chosen)
    # a sigma the scene sets is the scene's: kept, and not said to be chosen
    own, _ = complete_scene(_scene(block, peg, tmp_path, sigma=0.7))
    assert own.descriptor.sigma == 0.7
    assert [key for key, _, _ in own.chosen] == ["descriptor.spacing", "correlation.modes",
                                                 "descriptor.penalty", "descriptor.padding"]


def test_scene_new_writes_each_choice_with_its_reason(tmp_path, capsys, monkeypatch):
    from app.cli import main
    from engine.scene import load_scene

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path / "cache"))
    block, peg = peg_and_bore(10.0, 0.05)
    scene = _scene(block, peg, tmp_path)
    out = tmp_path / "new.toml"
    assert main(["scene", "new", str(scene.parts[0].file), str(scene.parts[1].file), "-o",
                 str(out), "--assembled", *map(str, SEAT)]) == 0
    printed = capsys.readouterr().out
    assert "chose      descriptor.spacing" in printed and "chose      correlation.modes" in printed
    text = out.read_text()
    assert text.count("# chosen: ") == 2 + len(SCALE_FREE)
    back = load_scene(out)
    assert back.descriptor.spacing is not None and back.gives("descriptor.spacing")
    # K is written "auto" with the value chosen here: the machine's budget bounds it, so it
    # is chosen again where the scene loads (a GPU's K on a GPU), and the same here
    assert 'modes = "auto"  # chosen: ' in text and not back.gives("correlation.modes")
    from engine.sim.auto import complete_scene
    again, _ = complete_scene(back)
    assert again.modes % 2 == 1 and f"correlation.modes = {again.modes}:" in printed
    assert [key for key, _, _ in again.chosen] == ["correlation.modes"]
    smaller, _ = complete_scene(back, budget=(9, "a smaller machine's budget in this test"))
    assert smaller.modes <= 9 < again.modes
    # a user's --modes is kept, and not annotated
    out2 = tmp_path / "given.toml"
    assert main(["scene", "new", str(scene.parts[0].file), str(scene.parts[1].file), "-o",
                 str(out2), "--assembled", *map(str, SEAT), "--modes", "14"]) == 0
    assert load_scene(out2).modes == 14
    assert out2.read_text().count("# chosen: ") == 1 + len(SCALE_FREE)


def test_a_band_that_would_half_resolve_the_fit_is_kept_at_its_outline(tmp_path):
    """Over every budget, the chosen band's shortest wavelength is never between 0.9 and 1.5
    widths of the fit: a band that would half-resolve the fit keeps to its outline.
    """
    from engine.sim.auto import (
        NEAR_WAVELENGTHS,
        OUTLINE_WAVELENGTHS,
        WAVELENGTH_PER_WIDTH,
        _fft_size,
        choose_settings,
        measure_fit,
    )

    block = trimesh.creation.box(extents=(80.0, 80.0, 20.0))
    block.apply_translation((0, 0, -10.0))
    bore = trimesh.creation.cylinder(radius=2.55 / np.cos(np.pi / 128), height=13.0,
                                     sections=128)
    bore.apply_translation((0, 0, -5.5))
    _, peg = peg_and_bore(5.0, 0.05)
    fixed = _part(block.difference(bore), "block")
    scene = _scene(fixed, peg, tmp_path)
    fit = measure_fit(fixed, peg, SEAT, AXIS)
    regimes = set()
    for budget in range(9, 128, 2):
        s = choose_settings(scene, [fixed, peg], fit=fit, budget=(budget, "test"))
        span = _fft_size([fixed, peg], s.spacing, scene.descriptor.padding) * s.spacing
        shortest = span / (s.modes // 2) / s.fit.width  # in widths of the fit
        assert s.modes <= budget and s.modes % 2 == 1
        assert not NEAR_WAVELENGTHS < shortest < OUTLINE_WAVELENGTHS, (budget, shortest)
        reason = s.reasons["correlation.modes"]
        regimes.add("outline" if "outline" in reason else "coarsely" if "coarsely" in reason
                    else "resolved")
        if "wavelength of" in reason:
            assert shortest <= WAVELENGTH_PER_WIDTH + 1e-9
    assert {"outline", "coarsely"} <= regimes  # (resolved: this fit asks for more than 127)


@pytest.mark.slow
def test_evaluate_reports_the_choices_of_a_scene_that_leaves_them_open(tmp_path, capsys,
                                                                      monkeypatch):
    import json

    from app.cli import main

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path / "cache"))
    block, peg = peg_and_bore(10.0, 0.1)
    scene = _scene(block, peg, tmp_path)
    (tmp_path / "open.toml").write_text(
        'name = "left open"\nunits = "mm"\nassembled_pose = [0, 0, -12, 0, 0, 0]\n'
        "insertion_axis = [0, 0, -1]\n\n"
        f'[[part]]\nname = "block"\nfile = "{scene.parts[0].file.name}"\n'
        "pose = [0, 0, 0, 0, 0, 0]\nfixed = true\n\n"
        f'[[part]]\nname = "peg"\nfile = "{scene.parts[1].file.name}"\n'
        "pose = [0, 0, 5, 0, 0, 0]\n")
    # without the fine level (its descriptors, twice as fine, were most of a minute here)
    assert main(["evaluate", str(tmp_path / "open.toml"), "--json", "--repeat", "1",
                 "--backend", "numba", "--no-fine"]) == 0
    out = json.loads(capsys.readouterr().out)
    keys = [c["key"] for c in out["chosen"]]
    assert keys == ["descriptor.spacing", "correlation.modes", *SCALE_FREE]
    assert out["modes"] == int(out["chosen"][1]["value"]) and out["modes"] % 2 == 1
    assert all(c["reason"] for c in out["chosen"])
    # and the coupling's gains the simulation would use, each with what decided it
    gains = {c["key"]: c for c in out["coupling"]}
    assert {"coupling.stiffness", "coupling.angular_stiffness"} <= set(gains)
    assert all(c["value"] > 0 and c["reason"] for c in gains.values())
