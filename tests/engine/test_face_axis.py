"""The axis of a picked face: bores, shafts and flat faces, found from the triangles alone."""

import numpy as np
import pytest
import trimesh

from engine.pose import rotation_matrix
from engine.scene.face_axis import FaceAxisError, face_axis


def _turned(mesh: trimesh.Trimesh, rotvec, shift) -> tuple[np.ndarray, np.ndarray]:
    rot = rotation_matrix(np.asarray(rotvec, float))
    return mesh.vertices @ rot.T + np.asarray(shift, float), np.asarray(mesh.faces)


def _nearest_face(vertices, faces, point, normal):
    """The triangle nearest ``point`` whose normal is closest to ``normal``."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    d = np.linalg.norm(mesh.triangles_center - point, axis=1)
    d -= 1e-3 * d.max() * (mesh.face_normals @ normal)
    return int(np.argmin(d))


@pytest.mark.parametrize("sections", [12, 64])
def test_a_bore_in_a_turned_plate_gives_its_axis_radius_and_kind(sections):
    plate = trimesh.creation.box(extents=(40.0, 30.0, 12.0))
    bore = trimesh.creation.cylinder(radius=5.0, height=20.0, sections=sections)
    bore.apply_translation((6.0, -4.0, 0.0))
    rotvec, shift = (0.4, -0.3, 1.1), (100.0, -20.0, 7.0)
    vertices, faces = _turned(plate.difference(bore), rotvec, shift)
    rot = rotation_matrix(np.asarray(rotvec))
    axis, centre = rot @ np.array([0, 0, 1.0]), rot @ np.array([6.0, -4.0, 0]) + shift
    # a point on the bore's wall (normal pointing at the axis)
    wall = centre + rot @ np.array([5.0, 0, 0])
    picked = _nearest_face(vertices, faces, wall, -(rot @ np.array([1.0, 0, 0])))
    found = face_axis(vertices, faces, picked, towards=centre + 50.0 * axis)
    assert found.kind == "hole"
    np.testing.assert_allclose(found.direction, -axis, atol=1e-6)  # from above, into it
    off = (found.point - centre) - ((found.point - centre) @ axis) * axis
    assert np.linalg.norm(off) < 1e-6
    # the model's radius: an inscribed polygon's corners lie on the cylinder
    assert found.radius == pytest.approx(5.0, rel=1e-6)
    assert len(found.faces) >= sections  # the whole wall, not the plate's flat faces


def test_a_shaft_points_outwards_and_a_flat_face_gives_its_normal():
    shaft = trimesh.creation.cylinder(radius=3.0, height=30.0, sections=32)
    vertices, faces = _turned(shaft, (0.0, 1.2, 0.0), (0.0, 0.0, 0.0))
    axis = rotation_matrix(np.array([0.0, 1.2, 0.0])) @ np.array([0, 0, 1.0])
    side = _nearest_face(vertices, faces, 3.0 * np.array([0, 1.0, 0]), np.array([0, 1.0, 0]))
    found = face_axis(vertices, faces, side)
    assert found.kind == "shaft" and found.radius == pytest.approx(3.0, rel=0.01)
    assert abs(found.direction @ axis) > 1 - 1e-9
    end = _nearest_face(vertices, faces, 15.0 * axis, axis)
    flat = face_axis(vertices, faces, end)
    assert flat.kind == "flat" and flat.radius == 0.0
    np.testing.assert_allclose(flat.direction, axis, atol=1e-9)  # outward
    assert abs((flat.point - 15.0 * axis) @ axis) < 1e-9


def test_a_sphere_has_no_axis():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    with pytest.raises(FaceAxisError, match="neither round nor flat"):
        face_axis(ball.vertices, ball.faces, 0)


def test_a_chamfered_bore_leaves_its_chamfer_out():
    plate = trimesh.creation.box(extents=(40.0, 40.0, 12.0))  # top at z = 6
    bore = trimesh.creation.cylinder(radius=5.0, height=20.0, sections=48)
    # a 45 degree countersink: a cone, apex down at z = -2, 8 mm across at the top face
    sink = trimesh.creation.cone(radius=9.0, height=9.0, sections=48)
    sink.apply_transform(trimesh.transformations.rotation_matrix(np.pi, (1, 0, 0)))
    sink.apply_translation((0.0, 0.0, 7.0))
    part = plate.difference(bore).difference(sink)
    wall = _nearest_face(part.vertices, part.faces, np.array([-5.0, 0.0, -3.0]),
                         np.array([1.0, 0.0, 0.0]))
    found = face_axis(part.vertices, part.faces, wall, towards=np.array([0.0, 0.0, 40.0]))
    assert found.kind == "hole"
    np.testing.assert_allclose(found.direction, [0.0, 0.0, -1.0], atol=1e-6)
    assert found.radius == pytest.approx(5.0, rel=1e-6)
    normals = trimesh.Trimesh(part.vertices, part.faces).face_normals[found.faces]
    assert np.max(np.abs(normals[:, 2])) < 0.2  # no chamfer facet, no flat face


def test_the_bundled_blocks_filleted_bore_from_its_step_file():
    # a CAD kernel's tessellation: a 5 mm bore whose mouth is filleted in rows 7 deg apart
    from app.gui.app import DEFAULT_SCENE
    from engine.loading import load_part

    block = load_part(DEFAULT_SCENE.parent / "block.step")
    mesh = trimesh.Trimesh(block.vertices, block.faces, process=False)
    centres, normals = mesh.triangles_center, mesh.face_normals
    radial = np.linalg.norm(centres[:, :2], axis=1)
    wall = np.flatnonzero((np.abs(normals[:, 2]) < 1e-6) & (radial < 6.0)
                          & (centres[:, 2] < -3.0))
    for picked in wall[:: max(1, len(wall) // 5)]:
        found = face_axis(block.vertices, block.faces, int(picked),
                          towards=np.array([0.0, 0.0, 30.0]))
        assert found.kind == "hole", picked
        np.testing.assert_allclose(found.direction, [0.0, 0.0, -1.0], atol=1e-9)
        assert np.linalg.norm(found.point[:2]) < 1e-6
        assert found.radius == pytest.approx(5.0, rel=1e-4)


@pytest.mark.parametrize("subdivisions", [2, 3, 4])
def test_no_triangle_of_a_sphere_is_given_an_axis(subdivisions):
    ball = trimesh.creation.icosphere(subdivisions=subdivisions, radius=5.0)
    for picked in range(0, len(ball.faces), max(1, len(ball.faces) // 12)):
        with pytest.raises(FaceAxisError):
            face_axis(ball.vertices, ball.faces, picked)


def test_the_bundled_pegs_flat_end_beside_its_edge_round_is_flat():
    # a CAD peg whose end meets its side through a rounded edge: picking the end gives the
    # end's normal, not a "cylinder" touching the end and two strips of the side
    from app.gui.app import DEFAULT_SCENE
    from engine.loading import load_part

    peg = load_part(DEFAULT_SCENE.parent / "peg.step")
    normals = trimesh.Trimesh(peg.vertices, peg.faces, process=False).face_normals
    ends = np.flatnonzero(np.abs(normals[:, 2]) > 1 - 1e-9)
    for picked in ends[:: max(1, len(ends) // 4)]:
        found = face_axis(peg.vertices, peg.faces, int(picked))
        assert found.kind == "flat", (picked, found.kind, found.radius)
        assert abs(found.direction[2]) > 1 - 1e-9
