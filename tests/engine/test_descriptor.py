"""Skeletal density descriptor: known values, reference vs kernels, symmetries, hard cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from engine.descriptor import (
    compute_descriptor,
    descriptor_at_points,
    signed_distance,
    winding_number,
)
from engine.errors import Cancelled, InputError, ResourceError
from engine.grid import Grid, grid_for_bounds
from engine.params import DescriptorParams


def _box(extents=(2.0, 2.0, 2.0)):
    m = trimesh.creation.box(extents=extents)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _mesh(m):
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _rel_l2(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# Known values (docs/descriptor.md; an independent brute-force quadrature converged to about 0.5%):
# box 2 x 2 x 2 at the origin, sigma 0.5, lambda_in 3, lambda_out 1.
BOX_POINTS = np.array(
    [(0, 0, 0), (0.5, 0.2, 0.1), (0.13, 0.21, 0.9), (1.5, 0, 0), (3, 0.2, 0.3), (1.4, 1.3, 0.2)],
    float,
)
BOX_RHO = np.array(
    [-2.80 + 15.08j, -1.46 + 4.13j, -0.83 + 3.17j, -0.268 - 1.050j, 0.040 - 0.149j,
     -0.115 - 0.368j]
)  # fmt: skip


def test_params_validate_and_lambda_in():
    p = DescriptorParams(sigma=0.7, penalty=2.0, lambda_out=1.5)
    assert p.lambda_in == pytest.approx(3.0)
    for bad in (dict(sigma=0.0), dict(penalty=-1.0), dict(lambda_out=float("nan"))):
        with pytest.raises(InputError, match=next(iter(bad))):
            DescriptorParams(**bad)


@pytest.mark.parametrize("method", ["tree", "brute"])
def test_box_known_values(descriptor_backend, method):
    # The reference is good to about 0.5% and printed to 3 digits; our quadrature (centroid
    # rule, pieces under 0.25 rad) is within 0.2% of it; 1.5% leaves room for both.
    v, f = _box()
    rho = descriptor_at_points(v, f, BOX_POINTS, spacing=0.05, backend=descriptor_backend,
                               method=method)  # fmt: skip
    err = np.abs(rho - BOX_RHO) / np.abs(BOX_RHO)
    assert np.all(err < 0.015), err


def test_face_limit_is_reached_near_a_face(descriptor_backend):
    # docs/descriptor.md: at (0.13, 0.21, 1 -/+ d) rho stays at -0.83+3.17i inside and
    # -0.276-1.056i outside for d from 0.3 down to 0.003: adaptive subdivision, no cap.
    v, f = _box()
    d = np.array([0.3, 0.03, 0.003, 3e-4])
    pts_in = np.stack([np.full_like(d, 0.13), np.full_like(d, 0.21), 1 - d], axis=1)
    pts_out = pts_in.copy()
    pts_out[:, 2] = 1 + d
    rho = descriptor_at_points(v, f, np.vstack([pts_in, pts_out]), spacing=0.05,
                               backend=descriptor_backend)  # fmt: skip
    assert np.all(np.abs(rho[:4] - (-0.83 + 3.17j)) < 0.015 * abs(-0.83 + 3.17j))
    assert np.all(np.abs(rho[4:] - (-0.276 - 1.056j)) < 0.015 * abs(-0.276 - 1.056j))


@pytest.mark.parametrize("sigma", [0.5, 2.0])
def test_sphere_centre_closed_form(sigma):
    # At the centre of a sphere of radius R every boundary point has eta = |xi| = R and
    # n || (q - p): rho = lambda_in * g(0) * 4 pi R^2 * (i / 2R^2) = lambda_in i sqrt(2 pi)/sigma
    # for every sigma. The icosphere's faces sit up to 0.1% inside the sphere and rho moves
    # to first order with eta/|xi| - 1 (about 3x that with a flat g): 1% tolerance.
    v, f = _mesh(trimesh.creation.icosphere(subdivisions=4))
    params = DescriptorParams(sigma=sigma)
    rho = descriptor_at_points(v, f, np.zeros((1, 3)), params, spacing=0.1, backend="numba")[0]
    expected = 1j * params.lambda_in * math.sqrt(2 * math.pi) / sigma
    assert abs(rho - expected) < 0.01 * abs(expected)


def test_winding_number_and_signed_distance_on_a_box(descriptor_backend):
    v, f = _box()
    pts = np.array([(0, 0, 0), (0.9, -0.9, 0.5), (1.5, 0, 0), (3, 3, 3), (0, 0, -1.25)])
    w = winding_number(v, f, pts, backend=descriptor_backend)
    np.testing.assert_allclose(w, [1, 1, 0, 0, 0], atol=1e-5)
    sd = signed_distance(v, f, pts, backend=descriptor_backend)
    np.testing.assert_allclose(sd, [-1, -0.1, 0.5, 2 * math.sqrt(3), 0.25], rtol=1e-5, atol=1e-6)


def test_winding_number_tree_matches_exact_on_an_annulus(descriptor_backend):
    # The annulus has a hole through it: points in the hole are outside.
    v, f = _mesh(trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=1.0, sections=32))
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1.3, 1.3, size=(400, 3))
    r = np.hypot(pts[:, 0], pts[:, 1])
    # Stay clear of the faceted walls (the polygon lies within cos(pi/32) of the circle).
    ok = (np.abs(r - 0.5) > 0.02) & (np.abs(r - 1.0) > 0.02)
    ok &= np.abs(np.abs(pts[:, 2]) - 0.5) > 0.02
    pts = pts[ok]
    r = r[ok]
    inside = (r > 0.5) & (r < 1.0) & (np.abs(pts[:, 2]) < 0.5)
    w = winding_number(v, f, pts, backend=descriptor_backend)
    np.testing.assert_allclose(w, inside.astype(float), atol=0.02)


MESHES = {
    "box": lambda: _box((2.0, 1.0, 0.6)),
    "icosphere": lambda: _mesh(trimesh.creation.icosphere(subdivisions=3)),
    "annulus": lambda: _mesh(trimesh.creation.annulus(r_min=0.4, r_max=1.0, height=0.8)),
    "cylinder": lambda: _mesh(trimesh.creation.cylinder(radius=0.6, height=2.0, sections=48)),
}


@pytest.mark.parametrize("name", sorted(MESHES))
def test_tree_matches_brute_force(name):
    v, f = MESHES[name]()
    lo, hi = v.min(axis=0), v.max(axis=0)
    grid = grid_for_bounds(lo, hi, samples=10, padding=2)
    brute = compute_descriptor(v, f, grid, backend="numba", method="brute")
    tree = compute_descriptor(v, f, grid, backend="numba", method="tree")
    assert _rel_l2(tree, brute) <= 1e-3


def test_opencl_matches_numpy(opencl_backend):
    # Same algorithm and constants; the kernel computes geometry in float32 and may then
    # split a piece the float64 reference keeps whole (or the reverse) when the size test
    # sits within rounding of its threshold: that changes a point's value by the quadrature
    # error of that piece, ~1e-3 of it. Hence 1e-3 relative L2 over the grid and 2e-3 of
    # max |rho| per point, not float32 epsilon.
    for name in ("box", "annulus", "icosphere"):
        v, f = MESHES[name]()
        grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=10, padding=2)
        for method in ("tree", "brute"):
            ref = compute_descriptor(v, f, grid, backend="numba", method=method)
            got = compute_descriptor(v, f, grid, backend=opencl_backend, method=method)
            assert got.dtype == np.complex64 and got.shape == grid.shape
            assert _rel_l2(got, ref) <= 1e-3, (name, method)
            np.testing.assert_allclose(got, ref, rtol=0, atol=2e-3 * np.abs(ref).max())


def test_opencl_float_accumulation_matches_numpy(opencl_backend):
    # GPUs without cl_khr_fp64 accumulate in float: a few thousand terms per point lose
    # ~1e-6 relative each, well inside the 1e-3 budget.
    from engine.descriptor import compute as d
    from engine.descriptor.opencl_kernels import OpenCLDescriptor

    v, f = MESHES["icosphere"]()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=8, padding=2)
    local = d._localise(v[f], grid.centre, grid.spacing, True)
    points = (grid.points().reshape(-1, 3) - grid.centre) / grid.spacing
    params = DescriptorParams()
    ref = d._run(local, points, 2, params, d.resolve_backend("numba"))
    evaluate = OpenCLDescriptor(opencl_backend, double=False).prepare(
        local.tri, local.tree, params.sigma, params.lambda_in, params.lambda_out
    )
    got = evaluate(points, 2)
    np.testing.assert_allclose(got[:, 2], ref[:, 2], atol=1e-4)  # xi
    off = np.abs(ref[:, 2]) > 1e-3  # the winding number is undefined on the surface
    np.testing.assert_allclose(got[off, 3], ref[off, 3], atol=1e-4)
    rho_ref = ref[:, 0] + 1j * ref[:, 1]
    assert _rel_l2(got[:, 0] + 1j * got[:, 1], rho_ref) < 1e-3


def test_opencl_descriptors_on_one_context_share_the_program_not_the_kernel(opencl_backend):
    # the program is built once per context; each descriptor object takes a kernel of its
    # own. Reading ``program.skeletal`` twice made pyopencl warn (RepeatedKernelRetrieval),
    # an error under the tests' filters: the window's engine failed to start on Python 3.10
    import warnings

    from engine.descriptor.opencl_kernels import OpenCLDescriptor

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        first = OpenCLDescriptor(opencl_backend)
        second = OpenCLDescriptor(opencl_backend)
    assert first.program is second.program
    assert first.kernel is not second.kernel


def test_opencl_launches_split_a_chunk_into_work_groups(opencl_backend, monkeypatch):
    # with the work-group size left to the driver, PoCL ran each chunk (thousands of
    # points) as one work-group: one CPU core busy, the descriptor twice as slow on two.
    # Every launch now names its work-group size and covers the chunk with whole groups;
    # the items past the chunk's end must write nothing (the kernel's guard)
    from engine.descriptor import compute as d
    from engine.descriptor.opencl_kernels import LOCAL_SIZE, OpenCLDescriptor

    v, f = MESHES["icosphere"]()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=12, padding=2)
    local = d._localise(v[f], grid.centre, grid.spacing, True)
    points = ((grid.points().reshape(-1, 3) - grid.centre) / grid.spacing)[:999]
    assert len(points) % 2  # odd: the chunk does not fill its last group
    params = DescriptorParams()
    runner = OpenCLDescriptor.for_backend(opencl_backend)  # the shared one: one kernel
    launches = []
    real = runner.kernel

    def spy(queue, global_size, local_size, *args):
        launches.append((global_size, local_size))
        return real(queue, global_size, local_size, *args)

    monkeypatch.setattr(runner, "kernel", spy)
    evaluate = runner.prepare(local.tri, local.tree, params.sigma, params.lambda_in,
                              params.lambda_out)
    got = evaluate(points, 2)
    group = runner.local_size
    assert 1 <= group <= LOCAL_SIZE
    assert launches == [((-(-len(points) // group) * group,), (group,))]
    assert len(points) // group >= 2  # two cores can share it
    ref = d._run(local, points, 2, params, d.resolve_backend("numba"))
    rho_ref = ref[:, 0] + 1j * ref[:, 1]
    assert got.shape == (len(points), 4)
    assert _rel_l2(got[:, 0] + 1j * got[:, 1], rho_ref) < 1e-3


def test_sign_and_size_inside_and_outside(descriptor_backend):
    v, f = MESHES["annulus"]()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=12, padding=2)
    rho = compute_descriptor(v, f, grid, backend=descriptor_backend)
    pts = grid.points().reshape(-1, 3)
    sd = signed_distance(v, f, pts, backend="numba")
    im = rho.reshape(-1).imag
    clear = np.abs(sd) > 0.5 * grid.spacing
    assert np.all(im[clear & (sd < 0)] > 0)
    assert np.all(im[clear & (sd > 0)] < 0)
    # Almost purely imaginary near the surface, |rho| of order lambda (3 in, 1 out).
    near_in = clear & (sd < 0) & (sd > -1.5 * grid.spacing)
    near_out = clear & (sd > 0) & (sd < 1.5 * grid.spacing)
    assert 1.0 < np.median(im[near_in]) < 10.0
    assert -3.0 < np.median(im[near_out]) < -0.3
    assert np.median(np.abs(rho.reshape(-1).real[clear]) / np.abs(im[clear])) < 0.5


def test_moving_the_mesh_moves_rho():
    v, f = MESHES["cylinder"]()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=10, padding=2)
    shift = np.array([123.4, -56.7, 8.9])
    moved = Grid(tuple(np.asarray(grid.origin) + shift), grid.spacing, grid.shape)
    a = compute_descriptor(v, f, grid, backend="numba")
    b = compute_descriptor(v + shift, f, moved, backend="numba")
    # Same local coordinates up to rounding of the shift (1e-14), which can still flip a
    # split decision sitting on its threshold: a few 1e-5, far below the 1e-3 error budget.
    assert _rel_l2(b, a) < 1e-4


def test_mirror_symmetric_part_gives_mirror_symmetric_rho():
    v, f = MESHES["annulus"]()  # symmetric under z -> -z
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=10, padding=2)
    rho = compute_descriptor(v, f, grid, backend="numba")
    assert _rel_l2(rho[:, :, ::-1], rho) < 1e-3


@pytest.mark.parametrize(
    "scale, offset", [(1e-3, 0.0), (1e4, 0.0), (1.0, 1e4)], ids=["micro", "huge", "far"]
)
def test_scale_and_far_coordinates_change_nothing(descriptor_backend, scale, offset):
    # rho is scale-free and moves with the part; local units (grid cells about the grid
    # centre) keep float32 accurate for parts at 1e-3 mm or 1e4 mm.
    v, f = _box((2.0, 1.0, 0.6))
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=8, padding=2)
    ref = compute_descriptor(v, f, grid, backend="numba")
    g2 = Grid(tuple(np.asarray(grid.origin) * scale + offset), grid.spacing * scale, grid.shape)
    got = compute_descriptor(v * scale + offset, f, g2, backend=descriptor_backend)
    assert np.all(np.isfinite(got))
    assert _rel_l2(got, ref) < 2e-3


def test_points_on_and_near_the_boundary_stay_finite_and_bounded(descriptor_backend):
    v, f = _box()
    h = 0.05
    # On a face, on an edge, on a corner, and within a hair of each.
    base = np.array([(0.13, 0.21, 1.0), (0.13, 1.0, 1.0), (1.0, 1.0, 1.0)])
    pts = np.vstack([base, base - 1e-7, base + 1e-7, base - 1e-3 * h, base + 2e-3 * h])
    rho = descriptor_at_points(v, f, pts, spacing=h, backend=descriptor_backend)
    assert np.all(np.isfinite(rho))
    assert np.abs(rho).max() < 20.0
    # A point exactly on a face counts as inside and takes the inner one-sided limit.
    assert abs(rho[0] - (-0.83 + 3.17j)) < 0.05


def test_thin_wall_slivers_and_degenerate_triangles_stay_finite(descriptor_backend):
    # A plate a fifth of a cell thick, a fan of slivers, and a zero-area triangle.
    plate = trimesh.creation.box(extents=(1.0, 1.0, 0.02))
    cyl = trimesh.creation.cylinder(radius=0.3, height=0.5, sections=200)  # sliver caps
    cyl.apply_translation((0, 0, 1.0))
    merged = trimesh.util.concatenate([plate, cyl])
    v = np.asarray(merged.vertices, float)
    f = np.vstack([merged.faces, [[0, 0, 1]]]).astype(np.int64)  # degenerate triangle
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), spacing=0.1, padding=1)
    rho = compute_descriptor(v, f, grid, backend=descriptor_backend)
    assert np.all(np.isfinite(rho))
    assert np.abs(rho).max() < 50.0
    # Inside the thin plate (grid points there are within 0.01 of both faces).
    mid = descriptor_at_points(v, f, np.array([[0.1, 0.1, 0.0]]), spacing=0.1,
                               backend=descriptor_backend)  # fmt: skip
    assert mid[0].imag > 0


def test_mesh_with_a_small_hole():
    m = trimesh.creation.icosphere(subdivisions=3)
    v, f = _mesh(m)
    holed = f[1:]  # one triangle missing
    pts = np.array([[0, 0, 0], [0.3, -0.2, 0.1], [1.5, 0, 0], [0, -2, 0.5]])
    w = winding_number(v, holed, pts, backend="numba")
    assert np.all((w > 0.5) == np.array([True, True, False, False]))
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=8, padding=1)
    closed = compute_descriptor(v, f, grid, backend="numba")
    rho = compute_descriptor(v, holed, grid, backend="numba")
    assert np.all(np.isfinite(rho))
    assert _rel_l2(rho, closed) < 0.05


def test_large_sigma_limit():
    # docs/descriptor.md: sigma -> infinity flattens g, so sqrt(2 pi) sigma rho tends to the
    # sigma-free c(p) * sum zeta^-2 dA_perp, with an O(1/sigma^2) remainder.
    v, f = MESHES["box"]()
    pts = np.array([[0.3, 0.1, 0.05], [1.4, 0.2, 0.1]])

    def scaled(sigma):
        rho = descriptor_at_points(v, f, pts, DescriptorParams(sigma=sigma), spacing=0.1,
                                   backend="numba")  # fmt: skip
        return math.sqrt(2 * math.pi) * sigma * rho

    s10, s20, s40 = scaled(10.0), scaled(20.0), scaled(40.0)
    d1 = np.abs(s20 - s10)
    d2 = np.abs(s40 - s20)
    assert np.all(d2 < 0.35 * d1)  # about 1/4 for an O(1/sigma^2) remainder
    assert s40[0].imag > 0 and s40[1].imag < 0


def test_bad_inputs_have_messages():
    v, f = _box()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=6)
    with pytest.raises(InputError, match="empty"):
        compute_descriptor(v, np.zeros((0, 3), np.int64), grid)
    bad = v.copy()
    bad[0, 1] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        compute_descriptor(bad, f, grid)
    with pytest.raises(InputError, match="index"):
        compute_descriptor(v, f + 100, grid)
    with pytest.raises(ValueError, match="adaptive, tree, brute"):
        compute_descriptor(v, f, grid, method="fast")
    huge = Grid((0.0, 0.0, 0.0), 0.001, (4000, 4000, 4000))
    with pytest.raises(ResourceError, match=r"4000x4000x4000.*GiB.*coarser"):
        compute_descriptor(v, f, huge)


def test_progress_and_cancel(monkeypatch):
    import engine.descriptor.constants as c

    monkeypatch.setattr(c, "CHUNK_POINTS", 100)
    # chunks are otherwise sized by time (tests/engine/test_limits.py): here every chunk
    # is allowed all the time it needs, so each holds exactly CHUNK_POINTS points
    import engine.descriptor.compute as compute

    monkeypatch.setattr(compute, "CHUNK_SECONDS", math.inf)
    v, f = _box()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=6, padding=1)
    seen: list[float] = []
    compute_descriptor(v, f, grid, backend="numba", method="tree", progress=seen.append)
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == math.ceil(grid.size / 100)
    # Adaptive sampling reports its levels in order, ending at 1.
    big = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=16, padding=6)
    seen = []
    compute_descriptor(v, f, big, backend="numba", method="adaptive", progress=seen.append)
    assert seen == sorted(seen) and seen[-1] == pytest.approx(1.0) and len(seen) > 3
    for method in ("tree", "adaptive"):
        calls: list[int] = []

        def cancel(calls: list[int] = calls) -> bool:
            calls.append(1)
            return len(calls) > 2

        with pytest.raises(Cancelled):
            compute_descriptor(v, f, big, backend="numba", method=method, cancel=cancel)


# --------------------------------------------------------------------------- CAD slivers
def _cad(name):
    from bench.cad_meshes import cad_peg, cad_plate_with_hole

    if name == "peg":  # 96 side strips 24 mm long, 2.6 mm wide (aspect ~90), capped by fans
        return cad_peg(diameter=8.0, length=24.0, segments=96)
    return cad_plate_with_hole(segments=48)


def test_cad_meshes_are_closed_slivered_solids():
    from bench.cad_meshes import aspect_ratios, cad_peg

    for name in ("peg", "plate"):
        v, f = _cad(name)
        m = trimesh.Trimesh(v, f, process=False)
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0, name
    v, f = cad_peg()
    assert len(f) == 1148 and aspect_ratios(v, f).max() > 250


def test_split_slivers_tiles_each_triangle():
    from engine.descriptor.tree import split_slivers

    rng = np.random.default_rng(3)
    a = rng.normal(size=(40, 3))
    long_dir = rng.normal(size=(40, 3))
    side = rng.normal(size=(40, 3))
    slivers = np.stack([a, a + 30 * long_dir, a + 0.05 * side], axis=1)
    fat = np.stack([a, a + np.eye(3)[0], a + np.eye(3)[1]], axis=1)  # right isoceles
    tris = np.concatenate([slivers, fat])
    pieces, source = split_slivers(tris, floor=0.1, width_factor=3.0, budget=10**6)

    def area_vectors(t):
        return 0.5 * np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])

    total = np.zeros((len(tris), 3))
    np.add.at(total, source, area_vectors(pieces))
    np.testing.assert_allclose(total, area_vectors(tris), atol=1e-9)  # same surface...
    assert np.all((area_vectors(pieces) * area_vectors(tris)[source]).sum(axis=1) >= 0)
    # ... and every piece inside its triangle (barycentric coordinates in [0, 1]).
    t = tris[source]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    gram = np.stack([np.stack([(e1 * e1).sum(1), (e1 * e2).sum(1)], 1),
                     np.stack([(e1 * e2).sum(1), (e2 * e2).sum(1)], 1)], 1)  # fmt: skip
    for corner in range(3):
        d = pieces[:, corner] - t[:, 0]
        rhs = np.stack([(d * e1).sum(1), (d * e2).sum(1)], 1)
        uv = np.linalg.solve(gram, rhs[..., None])[..., 0]
        assert uv.min() > -1e-9 and (uv.sum(1)).max() < 1 + 1e-9
    # Slivers are cut into pieces no longer than 3 times their width (or the floor), up
    # to the shortest edge (a strip's diagonal); well-shaped triangles are kept whole.
    def lengths(t):
        e = np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 1], t[:, 0] - t[:, 2]], axis=1)
        return np.sqrt((e**2).sum(axis=2))

    longest, shortest = lengths(tris).max(1), lengths(tris).min(1)
    width = 2 * np.linalg.norm(area_vectors(tris), axis=1) / longest
    bound = np.maximum(0.1, 3 * width) + shortest
    assert np.all(lengths(pieces).max(1) <= bound[source] * (1 + 1e-9))
    counts = np.bincount(source, minlength=len(tris))
    assert counts[:40].min() > 50 and np.all(counts[40:] == 1)


@pytest.mark.parametrize("name", ["peg", "plate"])
def test_tree_matches_brute_force_on_cad_slivers(name):
    # The CAD tessellation's slivers are cut into pieces for the tree; brute force sums over
    # the triangles as given. Grid points plus points near the surface (where the
    # quadrature works hardest), relative L2 within the 1e-3 budget.
    v, f = _cad(name)
    lo, hi = v.min(axis=0), v.max(axis=0)
    grid = grid_for_bounds(lo, hi, samples=14, padding=2)
    rng = np.random.default_rng(7)
    pts = grid.points().reshape(-1, 3)
    pts = pts[rng.choice(len(pts), 300, replace=False)]
    tri = v[f][rng.choice(len(f), 60)]
    w = rng.dirichlet(np.ones(3), size=60)[:, :, None]
    on = (w * tri).sum(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    near = on + normal * rng.uniform(-0.3, 0.3, size=(60, 1)) * grid.spacing
    pts = np.vstack([pts, near])
    tree = descriptor_at_points(v, f, pts, spacing=grid.spacing, backend="numba")
    brute = descriptor_at_points(v, f, pts, spacing=grid.spacing, backend="numba",
                                 method="brute")  # fmt: skip
    assert _rel_l2(tree, brute) <= 1e-3


@pytest.mark.parametrize("name", ["peg", "plate"])
def test_distances_run_over_the_uncut_triangles(name, descriptor_backend):
    # The sum runs over the slivers' pieces (compact clusters), the nearest distance over
    # the triangles as given: a point near the peg's axis is about equally far from every
    # piece of the 96 side strips (13,000 pieces at grid 14), all of which a search over
    # pieces visits, against 96 strips. The distance and the side must be those of brute
    # force either way (exact), on the grid and near the surface.
    from engine.descriptor import compute as d

    v, f = _cad(name)
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=14, padding=2)
    local = d._localise(v[f], grid.centre, grid.spacing, True)
    assert local.tree.n_triangles > 2 * len(f)  # slivers were cut for the sum
    assert local.surface.n_triangles == len(f)  # and left whole for the distance
    rng = np.random.default_rng(3)
    pts = grid.points().reshape(-1, 3)
    pts = (pts[rng.choice(len(pts), 400, replace=False)] - grid.centre) / grid.spacing
    tree = d._run(local, pts, 1, DescriptorParams(), descriptor_backend)
    brute = d._run(d._localise(v[f], grid.centre, grid.spacing, False), pts, 1,
                   DescriptorParams(), d.resolve_backend("numba"))  # fmt: skip
    np.testing.assert_allclose(tree[:, 2], brute[:, 2], atol=2e-4 * np.abs(brute[:, 2]).max())


# --------------------------------------------------------------------------- adaptive grids
@pytest.mark.parametrize("name", ["torus", "peg"])
def test_adaptive_sampling_matches_brute_force(name):
    # Interpolated samples carry an estimated error under ADAPTIVE_TOLERANCE * rms(rho);
    # over the grid the result stays within the 1e-3 budget against brute force, and a
    # good part of the grid is interpolated (else the method would gain nothing).
    from engine.descriptor import adaptive

    if name == "torus":
        v, f = _mesh(trimesh.creation.torus(1.0, 0.35, major_sections=32, minor_sections=16))
    else:
        v, f = _cad("peg")
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=40, padding=6)
    counts = {}
    real = adaptive.sample_grid

    def spy(*args, **kwargs):
        rho, xi, c = real(*args, **kwargs)
        counts.update(c)
        return rho, xi, c

    import unittest.mock

    with unittest.mock.patch.object(adaptive, "sample_grid", spy):
        import engine.descriptor.compute as compute

        with unittest.mock.patch.object(compute, "sample_grid", spy):
            rho = compute_descriptor(v, f, grid, backend="numba", method="adaptive")
    assert counts["interpolated"] > 0.15 * grid.size
    rng = np.random.default_rng(5)
    idx = rng.choice(grid.size, 400, replace=False)
    pts = grid.points().reshape(-1, 3)[idx]
    brute = descriptor_at_points(v, f, pts, spacing=grid.spacing, backend="numba",
                                 method="brute")  # fmt: skip
    assert _rel_l2(rho.reshape(-1)[idx], brute) <= 1e-3


def test_adaptive_sampling_is_exact_where_the_field_is_rough():
    # Samples next to the surface and every sample of the coarsest level are evaluated,
    # never interpolated: there the adaptive result equals the tree's.
    v, f = _box((2.0, 1.0, 0.6))
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=24, padding=10)
    tree = compute_descriptor(v, f, grid, backend="numba", method="tree")
    adapt = compute_descriptor(v, f, grid, backend="numba", method="adaptive")
    sd = signed_distance(v, f, grid.points().reshape(-1, 3)).reshape(grid.shape)
    near = np.abs(sd) < 1.0 * grid.spacing
    np.testing.assert_array_equal(adapt[near], tree[near])
    np.testing.assert_array_equal(adapt[::4, ::4, ::4], tree[::4, ::4, ::4])
    assert not np.array_equal(adapt, tree)  # and something was interpolated


@pytest.mark.parametrize("name", ["torus", "peg"])
def test_hints_from_coarse_samples_change_no_value(name):
    # The adaptive sampler hands each exactly evaluated fine sample a distance bound and,
    # where a corner of its cube is farther from the surface than from it, its side
    # (engine.descriptor.adaptive._hints). The kernel then skips the winding number and
    # prunes the distance search; rho and xi must be exactly those computed without.
    import engine.descriptor.compute as compute
    from engine.descriptor import adaptive

    if name == "torus":
        v, f = _mesh(trimesh.creation.torus(1.0, 0.35, major_sections=32, minor_sections=16))
    else:
        v, f = _cad("peg")
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=16, padding=3)
    local = compute._localise(compute._triangles(v, f), grid.centre, grid.spacing, True)
    be = compute.resolve_backend("numba")
    xs, ys, zs = ((a - c) / grid.spacing for a, c in zip(grid.axes(), grid.centre, strict=True))
    xs, ys, zs = (adaptive._odd(a) for a in (xs, ys, zs))
    shape = (len(xs), len(ys), len(zs))
    pts = adaptive._points(xs, ys, zs)
    plain = compute._run(local, pts, 2, DescriptorParams(), be)
    xi = plain[:, 2].reshape(shape)
    fine = np.indices(shape).reshape(3, -1)
    odd = np.any(fine % 2 == 1, axis=0)
    fine, fpts = fine[:, odd], pts[odd]
    coarse = xi[::2, ::2, ::2]
    hints = adaptive._hints(fine, fpts, (xs[::2], ys[::2], zs[::2]), coarse,
                            np.ones(coarse.shape, dtype=bool))  # fmt: skip
    true = plain[odd, 2]
    assert np.all(hints[:, 0] >= np.abs(true) - 1e-9)  # a bound, and a tight one
    known = hints[:, 1] != 0
    assert known.mean() > 0.5 and np.all(np.sign(true[known]) == hints[known, 1])
    hinted = compute._run(local, fpts, 2, DescriptorParams(), be, hints=hints)
    np.testing.assert_array_equal(hinted[:, :3], plain[odd, :3])
    # A wrong side is not silently corrected (so the comparison above can fail).
    wrong = hints.copy()
    wrong[known, 1] *= -1.0
    flipped = compute._run(local, fpts, 2, DescriptorParams(), be, hints=wrong)
    assert not np.array_equal(flipped[:, :3], plain[odd, :3])


def test_adaptive_sampling_interpolates_the_last_layer_of_an_even_grid():
    # An even number of samples along an axis leaves the last layer outside every coarse
    # cube; the sampler samples one step beyond and crops, so that layer is interpolated
    # where smooth, not evaluated everywhere, and stays within the error budget.
    import engine.descriptor.compute as compute
    from engine.descriptor import adaptive

    v, f = _mesh(trimesh.creation.torus(1.0, 0.35, major_sections=32, minor_sections=16))
    lo, hi = v.min(axis=0), v.max(axis=0)
    n = 28
    spacing = float((hi - lo).max()) / (n - 9)
    origin = 0.5 * (lo + hi) - 0.5 * spacing * (n - 1)
    grid = Grid(tuple(origin), spacing, (n, n, n))
    counts = {}
    real = adaptive.sample_grid

    def spy(*args, **kwargs):
        rho, xi, c = real(*args, **kwargs)
        counts.update(c)
        assert rho.shape == (n, n, n) and xi.shape == (n, n, n)
        return rho, xi, c

    import unittest.mock

    with unittest.mock.patch.object(compute, "sample_grid", spy):
        adapt = compute_descriptor(v, f, grid, backend="numba", method="adaptive")
    tree = compute_descriptor(v, f, grid, backend="numba", method="tree")
    last = np.concatenate([adapt[-1].ravel(), adapt[:, -1].ravel(), adapt[:, :, -1].ravel()])
    exact = np.concatenate([tree[-1].ravel(), tree[:, -1].ravel(), tree[:, :, -1].ravel()])
    assert np.mean(last != exact) > 0.3  # most of the layer is far from the surface
    # The promise of the method: an interpolated sample's error under ADAPTIVE_TOLERANCE
    # times the RMS of rho over the grid (the layer's own values are small, far field).
    from engine.descriptor import constants

    rms = np.sqrt(np.mean(np.abs(tree) ** 2))
    assert np.sqrt(np.mean(np.abs(last - exact) ** 2)) <= constants.ADAPTIVE_TOLERANCE * rms
    assert _rel_l2(adapt.ravel(), tree.ravel()) <= 1e-3
    # The samples one step beyond the grid are counted: more than n^3 in all.
    assert counts["exact"] + counts["interpolated"] == (n + 1) ** 3


def test_cubic_midpoints_are_exact_for_cubics_and_estimated_for_quartics():
    # The tricubic interpolation and its error estimate (engine.descriptor.adaptive):
    # interior midpoints of a cubic polynomial are exact along each axis and in 3D, and
    # for x^4 the estimate (3/128) d4 equals the true error at every interior midpoint.
    from engine.descriptor import adaptive

    n = 9
    x = np.arange(n, dtype=float)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    cubic = 0.3 * X**3 - X * Y * Z + 2.0 * Y**2 * Z - Z**3 + 1.0
    up = adaptive._upsample(cubic, cubic=True)
    xf = np.arange(2 * n - 1) / 2.0
    XF, YF, ZF = np.meshgrid(xf, xf, xf, indexing="ij")
    truth = 0.3 * XF**3 - XF * YF * ZF + 2.0 * YF**2 * ZF - ZF**3 + 1.0
    inner = (slice(2, -2),) * 3  # the two end intervals of each axis stay linear
    np.testing.assert_allclose(up[inner], truth[inner], atol=1e-9)
    linear = adaptive._upsample(cubic, cubic=False)
    assert np.abs(linear[inner] - truth[inner]).max() > 0.1  # so the check above can fail
    quartic = X**4
    err = np.abs(adaptive._upsample(quartic, cubic=True) - XF**4)[3:-3:2, ::2, ::2]
    est = adaptive._fourth_difference_error(quartic)[1:-2, :, :]
    np.testing.assert_allclose(err, est, rtol=1e-12)


def test_window_all_is_every_sample_of_the_window_on_one_side():
    from engine.descriptor import adaptive

    rng = np.random.default_rng(3)
    ok = rng.random((9, 8, 7)) > 0.01
    side = np.indices(ok.shape)[0] + rng.integers(0, 2, ok.shape[1:]) < 4  # a ragged plane
    for width in (2, 4):
        got = adaptive._window_all(ok, side, width)
        want = np.zeros(tuple(s - width + 1 for s in ok.shape), dtype=bool)
        for i, j, k in np.ndindex(want.shape):
            win = (slice(i, i + width), slice(j, j + width), slice(k, k + width))
            want[i, j, k] = ok[win].all() and (side[win].all() or not side[win].any())
        np.testing.assert_array_equal(got, want)
        assert got.any() and not got.all()


def test_a_cubic_stencil_never_spans_a_kink():
    # A cubic misses a slope jump (the density's cusp on the medial axis) by about 16 times
    # what fourth differences estimate, so the sampler keeps cubic stencils off kinks of
    # the signed distance. A synthetic field with a ridge where the distance has its kink
    # (deep inside, so the clearance test passes everywhere): every interpolated sample
    # stays within ADAPTIVE_TOLERANCE times the RMS, and the smooth part is still cubic.
    from engine.descriptor import adaptive, constants

    axis = np.arange(33, dtype=float)
    ridge = 17.0  # midway between two coarse samples: the worst place for a kink

    def field(p):
        xi = -(200.0 - np.abs(p[:, 2] - ridge))
        rho = 20.0 + 0.5 * np.abs(p[:, 2] - ridge) + 1e-4 * (p[:, 0] - 16.0) ** 3
        return xi, rho

    def evaluate(points, progress, hints):
        xi, rho = field(points)
        return np.stack([rho, np.zeros_like(rho), xi, np.ones_like(rho)], axis=1)

    rho, _, counts = adaptive.sample_grid(axis, axis, axis, evaluate, levels=1)
    _, truth = field(adaptive._points(axis, axis, axis))
    truth = truth.reshape(rho.shape)
    rms = np.sqrt(np.mean(truth**2))
    assert np.abs(rho.real - truth).max() <= constants.ADAPTIVE_TOLERANCE * rms
    assert counts["cubic"] > 0.3 * rho.size


def test_adaptive_sampling_interpolates_the_last_face_of_an_odd_grid():
    # A fine sample on the grid's last face lies on a face of the last coarse cube; it is
    # interpolated where that cube is smooth (it used to be evaluated every time).

    v, f = _mesh(trimesh.creation.torus(1.0, 0.35, major_sections=32, minor_sections=16))
    lo, hi = v.min(axis=0), v.max(axis=0)
    n = 29
    spacing = float((hi - lo).max()) / (n - 11)
    origin = 0.5 * (lo + hi) - 0.5 * spacing * (n - 1)
    grid = Grid(tuple(origin), spacing, (n, n, n))
    adapt = compute_descriptor(v, f, grid, backend="numba", method="adaptive")
    tree = compute_descriptor(v, f, grid, backend="numba", method="tree")
    face = (adapt[-1], adapt[:, -1], adapt[:, :, -1])
    exact = (tree[-1], tree[:, -1], tree[:, :, -1])
    assert all(np.mean(a != t) > 0.3 for a, t in zip(face, exact, strict=True))
    assert _rel_l2(adapt.ravel(), tree.ravel()) <= 1e-3


# ------------------------------------------------------------- the lumped terms' order
def _patch_exact(corners, xi, sigma, m=240):
    """Sum of zeta^-2 g(eta/|xi| - 1) n.u dA over a flat triangle (p at the origin).

    By the midpoint rule on m^2 sub-triangles (g without its constant).
    """
    a, b, c = corners
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    keep = i + j < m
    # the m^2 sub-triangles: m(m+1)/2 upright ones and m(m-1)/2 flipped ones
    up = np.stack([(i + 1 / 3) / m, (j + 1 / 3) / m], -1)[keep]
    flip = np.stack([(i + 2 / 3) / m, (j + 2 / 3) / m], -1)[i + j < m - 1]
    uv = np.vstack([up, flip])
    q = a + uv[:, :1] * (b - a) + uv[:, 1:] * (c - a)
    n = np.cross(b - a, c - a) / 2  # area vector
    eta = np.linalg.norm(q, axis=1)
    x = eta / abs(xi) - 1
    w = np.exp(-x * x / (2 * sigma * sigma)) / (xi + 1j * eta) ** 2
    return np.mean(w * (q @ n) / eta)


def _lumped_piece(corners, xi, sigma):
    from engine.descriptor.numba_kernels import _term

    c = corners.mean(axis=0)
    n = np.cross(corners[1] - corners[0], corners[2] - corners[0]) / 2
    u = c / np.linalg.norm(c)
    d = corners - c
    trq = float(np.sum(d * d)) / 12
    quq = float(np.sum((d @ u) ** 2)) / 12
    re, im = _term(0.0, 0.0, 0.0, *c, *n, xi, 1 / abs(xi), 1 / (2 * sigma * sigma), trq, quq)
    return re + 1j * im


def _lumped_cluster(corners, xi, sigma):
    """The same triangle, cut in four, as one cluster of the hierarchy (its root)."""
    from engine.descriptor.numba_kernels import _node_term
    from engine.descriptor.tree import build_tree

    a, b, c = corners
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    tree = build_tree(np.array([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]),
                      leaf_size=1)
    re, im = _node_term(0.0, 0.0, 0.0, tree.node, 0, xi, 1 / abs(xi), 1 / (2 * sigma * sigma))
    return re + 1j * im


@pytest.mark.parametrize("lumped", [_lumped_piece, _lumped_cluster])
def test_a_lumped_flat_piece_has_no_second_order_error(lumped):
    # The centroid rule with every second-order term (numba_kernels._radial and, for a
    # cluster, its N.Q.u term) errs by the third power of a triangle's size over its
    # distance (a triangle's third moment about its centroid does not vanish): halving the
    # piece divides the error by about 8. With the radial term alone (the rule before) it
    # was a second-order rule: about 4, and 36 times the error at the smaller size here.
    rng = np.random.default_rng(7)
    sigma = 0.5
    ratios, small = [], []
    for xi in (5.0, -5.0):
        for _ in range(6):
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            centre = d * abs(xi) * rng.uniform(1.05, 1.6)
            shape = rng.normal(size=(3, 3))
            shape -= shape.mean(axis=0)
            shape /= np.sqrt(np.sum(shape * shape) / 3)  # corners at RMS radius 1
            errs = []
            for size in (0.8, 0.4):
                corners = centre + size * shape
                exact = _patch_exact(corners, xi, sigma)
                area = np.linalg.norm(np.cross(corners[1] - corners[0], corners[2] - corners[0]))
                scale = area / 2 / abs(xi + 1j * np.linalg.norm(centre)) ** 2
                errs.append(abs(lumped(corners, xi, sigma) - exact) / scale)
            ratios.append(errs[0] / errs[1])
            small.append(errs[1])
    assert np.median(ratios) > 6.0, ratios
    assert np.median(small) < 1e-4, small


def test_bent_clusters_are_opened_where_a_part_is_small_on_its_grid():
    # A pin 2 to 3 cells across on a coarse grid: most samples are far away, where clusters
    # pass the size tests while spanning much of the pin's round. A lumped cluster takes its
    # third moment as N Q, which curvature breaks: without NODE_BEND the adaptive descriptor
    # was 2e-3 from a converged one here (the budget is 1e-3).
    from pathlib import Path

    from engine.descriptor import constants as c
    from engine.loading import load_part

    folder = Path(__file__).resolve().parents[2] / "assets" / "real" / "iso_pin_5_H7h6_through"
    part = load_part(folder / "pin.stl", unit="mm")
    lo, hi = part.vertices.min(axis=0), part.vertices.max(axis=0)
    grid = grid_for_bounds(lo, hi, samples=8, padding=6)  # 5 mm across: 2 cells
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(c, "THETA", 0.15)
        mp.setattr(c, "THETA_NODE", 0.15)
        ref = compute_descriptor(part.vertices, part.faces, grid, backend="numba",
                                 method="tree")  # fmt: skip
    rho = compute_descriptor(part.vertices, part.faces, grid, backend="numba")
    assert _rel_l2(rho, ref) < 1e-3


def test_a_slice_at_other_parameters_is_that_plane_of_the_grid():
    # the window's preview of a new sigma or penalty: one plane, computed alone, must be
    # the plane of the whole grid computed at those parameters
    from engine.descriptor import descriptor_slice

    v, f = MESHES["annulus"]()
    grid = grid_for_bounds(v.min(axis=0), v.max(axis=0), samples=10, padding=2)
    params = DescriptorParams(sigma=0.8, penalty=5.0)
    whole = compute_descriptor(v, f, grid, params, backend="numba", method="tree")
    for axis, index in ((0, 3), (1, grid.shape[1] // 2), (2, 0)):
        plane = descriptor_slice(v, f, grid, axis, index, params, backend="numba")
        np.testing.assert_allclose(plane, np.take(whole, index, axis=axis), rtol=1e-5,
                                   atol=1e-6 * np.abs(whole).max())
    with pytest.raises(ValueError, match="no plane 99 along axis 2"):
        descriptor_slice(v, f, grid, 2, 99, params)
