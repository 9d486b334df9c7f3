"""A second part opened beside a first: where its file draws it, or parked clear of it."""

import numpy as np
import trimesh

from engine.loading import part_from_mesh
from engine.pose import pose_to_matrix
from engine.scene.placement import interpenetration, place_second


def _part(mesh: trimesh.Trimesh, name: str):
    return part_from_mesh(mesh.vertices, mesh.faces, name=name, unit="mm")


def _plate_with_hole():
    plate = trimesh.creation.box(extents=(30.0, 30.0, 6.0))
    hole = trimesh.creation.cylinder(radius=4.0, height=10.0, sections=48)
    return _part(plate.difference(hole), "plate")


def test_a_peg_drawn_in_its_hole_stays_where_its_file_draws_it():
    plate = _plate_with_hole()
    # drawn seated, off the origin (as an assembly exports it): 0.1 mm of play
    peg = trimesh.creation.cylinder(radius=3.9, height=20.0, sections=48)
    peg.apply_translation((0.0, 0.0, 4.0))
    first = np.array([5.0, -2.0, 1.0, 0.0, 0.0, 0.3])
    pose, reason = place_second(plate, _part(peg, "peg"), first)
    np.testing.assert_array_equal(pose, first)
    assert "where its file draws it" in reason


def test_parts_drawn_inside_each_other_are_parked_above():
    plate = _plate_with_hole()
    # a solid block centred on the origin like the plate: half of it in the plate's body
    block = _part(trimesh.creation.box(extents=(20.0, 6.0, 10.0)), "block")
    first = np.zeros(6)
    assert interpenetration(plate, block, first) > 0.1
    pose, reason = place_second(plate, block, first)
    assert "inside plate" in reason and "starts above" in reason
    lowest = (block.vertices @ pose_to_matrix(pose)[:3, :3].T + pose[:3])[:, 2].min()
    assert lowest > plate.vertices[:, 2].max()
    assert interpenetration(plate, block, pose) == 0.0


def test_interpenetration_counts_the_share_inside():
    slab = _part(trimesh.creation.box(extents=(10.0, 10.0, 10.0)), "slab")
    # a thin plate moved half into the slab along x: about half its surface inside
    thin = _part(trimesh.creation.box(extents=(10.0, 10.0, 0.5)), "thin")
    share = interpenetration(slab, thin, np.array([5.0, 0, 0, 0, 0, 0]))
    assert 0.35 < share < 0.65
    assert interpenetration(slab, thin, np.array([20.0, 0, 0, 0, 0, 0])) == 0.0
