"""Loading parts: STEP files and triangle meshes to checked, closed, outward-oriented meshes.

A part is a triangle mesh in its own frame and its file's own unit: ``vertices (n, 3)
float64`` and ``faces (m, 3) int64``, with faces wound counter-clockwise seen from outside
(outward normals, positive volume).

- STEP (``.step``, ``.stp``) goes through cascadio (OpenCASCADE), which tessellates the
  solids into GLB. GLB is in metres, stores float32 and splits vertices per B-rep face, so the
  loader converts back to the unit written in the STEP header (``SI_UNIT`` /
  ``CONVERSION_BASED_UNIT``; mm in practice) and welds coincident vertices, which closes the
  mesh. Each solid (each product of the file) becomes one :class:`Part`, named after its
  product. The tessellation tolerance is the largest distance between the mesh and the true
  surface, in the file's unit; by default 1/1000 of the file's bounding-box diagonal.
- STL, OBJ, PLY and OFF go through trimesh; their coordinates are taken as stored (these
  formats carry no unit), and the part's ``unit`` is ``"unspecified"``.

Every mesh then passes :func:`check_mesh`: empty meshes, non-finite coordinates and bad
indices are errors (:class:`PartError`, a ``ValueError``, with the file, the problem and the
fix); degenerate and duplicate triangles are dropped, inconsistent winding and inverted
normals are repaired, and holes are reported; each repair adds a line to ``Part.warnings``.
"""

from __future__ import annotations

import io
import math
import os
import re
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType, ModuleType
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from engine.errors import InputError
from engine.files import MAX_PART_BYTES, input_problem, read_input
from engine.params import LENGTH_UNITS

if TYPE_CHECKING:
    import manifold3d
    import trimesh

    #: What a tessellated STEP file or a mesh file reads as.
    Loaded: TypeAlias = trimesh.Scene | trimesh.Trimesh
    #: One body of a tessellation: its name, 4x4 placement, and mesh.
    Body: TypeAlias = tuple[str, np.ndarray, trimesh.Trimesh]

#: File suffixes the loader reads, and what reads them.
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off")
STEP_SUFFIXES = (".step", ".stp")
SUFFIXES = STEP_SUFFIXES + MESH_SUFFIXES

#: Default tessellation tolerance, relative to the bounding-box diagonal of the STEP file.
DEFAULT_RELATIVE_TOLERANCE = 1e-3
#: Largest angle (radians) between neighbouring facets' normals on a curved face.
DEFAULT_ANGULAR_TOLERANCE = 0.35
#: Vertices closer than this times the mesh's diagonal are welded (its size, not its place).
WELD_RELATIVE = 1e-6
#: ... or closer than this many units of the coordinates' resolution at the largest
#: |coordinate| (float32 in STL and GLB: copies of one vertex may differ by a few of those).
WELD_ULPS = 4
#: Relative resolution of float32 coordinates (STL, GLB) and of float64 ones.
FLOAT32_RESOLUTION = 2.0**-23
FLOAT64_RESOLUTION = 2.0**-52
#: OpenCASCADE's geometric precision (Precision::Confusion), in millimetres: a STEP part
#: must be many times larger than this to be tessellated.
OCC_PRECISION_MM = 1e-7
#: Smallest STEP part, in millimetres across, that is tessellated (1000 x OCC's precision).
MIN_STEP_DIAGONAL_MM = 1e3 * OCC_PRECISION_MM
#: Most triangles a STEP tessellation may make (480,000 took 2 minutes here; the memory on
#: the way is about 1 KB per triangle).
MAX_STEP_TRIANGLES = 2_000_000

#: Most triangles a mesh file may hold (a binary STL's header says before it is read;
#: 10^6 load in about 6 s and 350 MB here).
MAX_MESH_TRIANGLES = 10_000_000

#: STEP length units: SI prefix (or conversion-based name) -> (short name, metres per unit).
_SI_PREFIXES = {
    "$": ("m", 1.0),
    ".KILO.": ("km", 1e3),
    ".CENTI.": ("cm", 1e-2),
    ".MILLI.": ("mm", 1e-3),
    ".MICRO.": ("um", 1e-6),
    ".NANO.": ("nm", 1e-9),
    ".DECI.": ("dm", 1e-1),
}
_CONVERSION_UNITS = {
    "INCH": ("in", 0.0254),
    "FOOT": ("ft", 0.3048),
    "MILLIMETRE": ("mm", 1e-3),
    "METRE": ("m", 1.0),
}
#: Named lengths an unnamed conversion-based unit is matched against.
_NAMED_LENGTHS = dict(LENGTH_UNITS)

#: Product names OpenCASCADE writes when the model had none; replaced by the file's stem.
_ANONYMOUS = re.compile(
    r"^(Open CASCADE STEP translator.*|SOLID[_ ]?\d*|Solid[_ ]?\d*|COMPOUND[_ ]?\d*|"
    r"Body[_ ]?\d*|)$"
)


class PartError(InputError):
    """A part file that cannot be used: the message names the file, the problem and the fix."""


@dataclass(frozen=True, eq=False)
class Part:
    """A checked triangle mesh in the part's own frame and its file's unit.

    Attributes
    ----------
    name : str
        The solid's name in a STEP file, else the file's stem.
    vertices : (n, 3) float64
        Vertex positions (read-only array).
    faces : (m, 3) int64
        Triangles as vertex indices, counter-clockwise seen from outside (read-only array).
    source : str or None
        The file it came from (None for meshes built in code).
    unit : str
        Length unit of the coordinates: ``"mm"``, ``"m"``, ``"in"``, ... or
        ``"unspecified"`` for mesh formats, which carry none.
    warnings : tuple of str
        Repairs made and problems found that did not stop loading.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    source: str | None = None
    unit: str = "unspecified"
    warnings: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        f = np.ascontiguousarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must have shape (n, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"faces must have shape (m, 3), got {f.shape}")
        v.setflags(write=False)
        f.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def triangles(self) -> int:
        """Number of triangles."""
        return int(self.faces.shape[0])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: lower and upper corner of the axis-aligned bounding box."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @property
    def extent(self) -> np.ndarray:
        """(3,) float64: size of the bounding box along x, y, z."""
        b = self.bounds
        return b[1] - b[0]

    @property
    def diagonal(self) -> float:
        """Length of the bounding box's diagonal."""
        return float(np.linalg.norm(self.extent))

    @property
    def volume(self) -> float:
        """Enclosed volume (divergence theorem; exact for a closed mesh)."""
        return _signed_volume(self.vertices, self.faces)

    @property
    def area(self) -> float:
        """Surface area."""
        return float(_areas(self.vertices, self.faces).sum())


# --------------------------------------------------------------------------- public API
def load_parts(
    path: str | os.PathLike, *, tolerance: float | None = None, unit: str | None = None
) -> list[Part]:
    """Load every solid of a STEP file, or the mesh of a mesh file, as checked parts.

    Parameters
    ----------
    path : path-like
        A ``.step``/``.stp``, ``.stl``, ``.obj``, ``.ply`` or ``.off`` file.
    tolerance : float, optional
        STEP only: tessellation tolerance (largest distance between mesh and surface) in the
        file's unit. Default: 1/1000 of the file's bounding-box diagonal. Ignored for meshes.
    unit : str, optional
        The unit the file's coordinates are in (a key of ``engine.params.LENGTH_UNITS``),
        overriding the STEP header's declaration (a warning says so when they differ);
        for a mesh file, the unit it is in. Default: the STEP header's unit, and
        ``"unspecified"`` for meshes. Coordinates are never scaled here: they stay the
        numbers written in the file, labelled with their unit.

    Returns
    -------
    list of Part
        One per solid of a STEP file (in file order, unique names), one for a mesh file.

    Raises
    ------
    PartError
        The file is missing, unreadable, of an unknown type, empty or unusable.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise PartError(
            f"{p}: unknown part file type {p.suffix or '(none)'!r}; "
            f"use one of {', '.join(SUFFIXES)}"
        )
    if not p.exists() and not p.is_symlink():
        raise PartError(f"{p}: no such file; check the path (relative paths in a scene file "
                        "are relative to the scene file)")
    problem = input_problem(p, what="part file", limit=MAX_PART_BYTES)
    if problem:
        raise PartError(problem)
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise PartError(f"tessellation tolerance must be a positive number, got {tolerance!r}")
    if unit is not None and unit not in LENGTH_UNITS:
        raise PartError(f"{p}: unknown length unit {unit!r}; use one of "
                        f"{', '.join(LENGTH_UNITS)}")
    if suffix in STEP_SUFFIXES:
        return _load_step(p, tolerance, unit)
    return [_load_mesh(p, unit)]


def load_part(
    path: str | os.PathLike,
    *,
    tolerance: float | None = None,
    body: str | None = None,
    unit: str | None = None,
) -> Part:
    """Load one part: the only solid of the file, or the solid named ``body``.

    ``tolerance`` and ``unit`` are as in :func:`load_parts`.

    Raises
    ------
    PartError
        As :func:`load_parts`, or the file holds several solids and ``body`` is not given or
        names none of them (the message lists the names).
    """
    parts = load_parts(path, tolerance=tolerance, unit=unit)
    names = [p.name for p in parts]
    if body is not None:
        for part in parts:
            if part.name == body:
                return part
        raise PartError(f"{path}: no body named {body!r}; the file holds {_names(names)}")
    if len(parts) != 1:
        raise PartError(
            f"{path}: the file holds {len(parts)} bodies ({_names(names)}); "
            "choose one by name (--body NAME, or `body = \"NAME\"` in the scene's [[part]])"
        )
    return parts[0]


def part_from_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    name: str = "mesh",
    source: str | None = None,
    unit: str = "unspecified",
) -> Part:
    """A checked :class:`Part` from arrays (``check_mesh`` applied, warnings kept)."""
    v, f, warnings = check_mesh(vertices, faces, source=source or name)
    return Part(name=name, vertices=v, faces=f, source=source, unit=unit, warnings=warnings)


def check_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    source: str,
    weld_tolerance: float | None = None,
    report_degenerate: bool = True,
    resolution: float | None = None,
    union: bool = True,
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Check and repair a triangle mesh; raise for what cannot be repaired.

    Steps: reject empty meshes, non-finite coordinates and out-of-range indices; weld
    vertices closer than ``weld_tolerance``; drop degenerate (zero-area or repeated-vertex)
    and duplicate triangles; make the winding consistent across shared edges; flip all
    faces when the enclosed volume is negative (normals pointing in); report boundary and
    non-manifold edges (winding-number membership still works on slightly open meshes);
    join closed shells that overlap into one solid (:func:`union_shells`), since the
    winding number would count their common volume twice.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    source : str
        The file (or name) that messages refer to.
    weld_tolerance : float, optional
        Default ``max(WELD_RELATIVE * diagonal, WELD_ULPS * resolution * largest
        |coordinate|)``: from the part's size, with a floor at the coordinates' resolution
        where it lies.
    report_degenerate : bool
        Warn about dropped degenerate triangles (False for our own STEP tessellation, whose
        poles and seams collapse to a few of them after welding: nothing the user can fix).
    resolution : float, optional
        Relative resolution of the coordinates as stored: ``FLOAT32_RESOLUTION`` when every
        coordinate is a float32 value (STL), else ``FLOAT64_RESOLUTION``.
    union : bool
        Join overlapping closed shells (:func:`union_shells`).

    Returns
    -------
    vertices : (n', 3) float64
        Welded, only the vertices the faces use.
    faces : (m', 3) int64
        Outward-oriented triangles.
    warnings : tuple of str
        One line per repair or problem found, naming ``source``.

    Raises
    ------
    PartError
        Empty mesh, non-finite coordinates, bad indices, nothing left after repair, or
        overlapping shells that cannot be joined.
    """
    warnings: list[str] = []
    try:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise PartError(f"{source}: vertices and faces are not numeric arrays ({exc})") from exc
    if v.size == 0 or f.size == 0:
        raise PartError(
            f"{source}: the mesh is empty (no triangles); export the part as a closed "
            "surface mesh or a STEP solid"
        )
    if v.ndim != 2 or v.shape[1] != 3:
        raise PartError(f"{source}: vertices must be (n, 3), got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise PartError(
            f"{source}: faces must be triangles, (m, 3), got shape {f.shape}; triangulate "
            "the mesh before export"
        )
    if not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
            raise PartError(f"{source}: face indices are not integers")
    f = f.astype(np.int64)
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise PartError(
            f"{source}: {int(bad.sum())} of {len(v)} vertices have non-finite coordinates "
            "(NaN or infinity); repair or re-export the mesh"
        )
    if f.min() < 0 or f.max() >= len(v):
        raise PartError(
            f"{source}: face indices outside 0..{len(v) - 1} (found {int(f.min())}.."
            f"{int(f.max())}); the file is damaged, re-export it"
        )

    # weld
    lower, upper = v[f.ravel()].min(axis=0), v[f.ravel()].max(axis=0)
    diagonal = float(np.linalg.norm(upper - lower))
    largest = float(np.abs(v[f.ravel()]).max())
    if resolution is None:
        resolution = (FLOAT32_RESOLUTION if np.array_equal(v.astype(np.float32), v)
                      else FLOAT64_RESOLUTION)
    floor = WELD_ULPS * resolution * largest
    tol = max(WELD_RELATIVE * diagonal, floor) if weld_tolerance is None else float(weld_tolerance)
    if tol > 0 and len(v) > 1:
        v, f = _weld(v, f, tol)

    # degenerate triangles: a repeated vertex (welding collapsed an edge) is dropped, which
    # keeps a closed surface closed; three distinct collinear corners are removed by an edge
    # flip with the neighbour across the longest edge, which keeps it closed and unchanged
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    if repeated.any():
        if report_degenerate:
            warnings.append(
                f"{source}: dropped {int(repeated.sum())} degenerate triangles (a repeated "
                "vertex); harmless, but a finer or cleaner export avoids them"
            )
        f = f[~repeated]
    f, flipped_flat, dropped_flat = _flip_collinear(v, f, max(tol, 1e-12 * diagonal))
    if flipped_flat and report_degenerate:
        warnings.append(
            f"{source}: {flipped_flat} zero-area triangles (three collinear corners) were "
            "removed by edge flips with their neighbours; the surface is unchanged"
        )
    if dropped_flat:
        warnings.append(
            f"{source}: dropped {dropped_flat} degenerate triangles (zero area, with no single "
            "neighbour to flip with); check the mesh near them"
        )
    if len(f):
        _, first = np.unique(_row_keys(np.sort(f, axis=1), len(v)), return_index=True)
        if len(first) < len(f):
            warnings.append(
                f"{source}: dropped {len(f) - len(first)} duplicate triangles; check the "
                "export for doubled faces"
            )
            f = f[np.sort(first)]
    if len(f) == 0:
        if weld_tolerance is None and floor >= WELD_RELATIVE * diagonal:
            raise PartError(
                f"{source}: no usable triangles: the part is {diagonal:.3g} across as stored "
                f"but has coordinates as large as {largest:.3g}, where they resolve only "
                f"{resolution * largest:.2g}; move the part near the origin before export, or "
                "export it in a smaller unit"
            )
        raise PartError(
            f"{source}: no usable triangles (all were degenerate); the mesh has no area, "
            "re-export the part as a solid"
        )

    # drop unused vertices, renumber
    used = np.flatnonzero(np.bincount(f.ravel(), minlength=len(v)))
    renumber = np.zeros(len(v), dtype=np.int64)
    renumber[used] = np.arange(len(used))
    v = v[used]
    f = renumber[f]

    # consistent winding, then outward orientation
    f, flipped = _orient_consistently(f)
    if flipped:
        warnings.append(
            f"{source}: {flipped} of {len(f)} triangles were wound against their neighbours "
            "(inconsistent normals) and were flipped; check the exporter's normals"
        )
    boundary, nonmanifold = _edge_defects(f)
    volume = _signed_volume(v, f, about=v.mean(axis=0))
    if volume < 0:
        f = f[:, ::-1].copy()
        warnings.append(
            f"{source}: the normals pointed inwards (negative volume); all triangles were "
            "flipped to face outwards"
        )
    if union and not boundary and not nonmanifold:
        v, f, joined = union_shells(v, f, source=source)
        if joined:
            warnings.append(joined)
        crossing = buried_triangles(v, f)
        if crossing is not None:
            warnings.append(
                f"{source}: the surface intersects itself or overlaps itself (near "
                f"({', '.join(f'{c:.4g}' for c in crossing)}), a triangle lies inside the "
                "solid or two layers cover one place); the inside is ambiguous there: repair "
                "the mesh (a mesh repair or a CAD 'make solid') for reliable results"
            )
    if boundary or nonmanifold:
        what = []
        if boundary:
            what.append(f"{boundary} boundary edges (holes)")
        if nonmanifold:
            what.append(f"{nonmanifold} edges shared by more than two triangles")
        warnings.append(
            f"{source}: the mesh is not watertight: {' and '.join(what)}; membership by "
            "winding number still works for small holes, but close the mesh (or export a "
            "STEP solid) for reliable results"
        )
    return np.ascontiguousarray(v), np.ascontiguousarray(f), tuple(warnings)


def shells(f: np.ndarray) -> np.ndarray:
    """(m,) int64 label of the connected shell (faces sharing vertices) of each face."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(f)
    n = int(f.max()) + 1 if m else 0
    rows = np.repeat(np.arange(m), 3)
    graph = coo_matrix((np.ones(3 * m), (rows, m + f.ravel())), shape=(m + n, m + n))
    _, labels = connected_components(graph, directed=False)
    _, dense = np.unique(labels[:m], return_inverse=True)
    return dense.astype(np.int64).ravel()


def union_shells(v: np.ndarray, f: np.ndarray, *, source: str
                 ) -> tuple[np.ndarray, np.ndarray, str | None]:  # fmt: skip
    """Join overlapping closed shells into one solid with a mesh boolean union.

    A mesh of several closed shells (common in real exports: one shell per brick of a
    model) describes their union, but a winding number sums them, counting their common
    volume twice. Shells whose boxes overlap go through manifold3d's boolean union (shells
    with negative volume, cavities, are subtracted); when the union's volume equals the sum
    of the shells' signed volumes nothing overlapped and the mesh is returned unchanged.

    Parameters
    ----------
    v : (n, 3) float64
    f : (m, 3) int64
        A closed, outward-oriented mesh (each shell watertight).
    source : str
        The file, for messages.

    Returns
    -------
    v : (n', 3) float64
    f : (m', 3) int64
    warning : str or None
        What was joined, or None when nothing overlapped.

    Raises
    ------
    PartError
        Shells overlap and cannot be joined (a shell is not a closed 2-manifold, or
        manifold3d is missing).
    """
    labels = shells(f)
    count = int(labels.max()) + 1 if len(labels) else 0
    if count < 2:
        return v, f, None
    p = v[f]  # (m, 3, 3)
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, labels, p.min(axis=1))
    np.maximum.at(hi, labels, p.max(axis=1))
    margin = 1e-9 * float(np.linalg.norm(hi.max(axis=0) - lo.min(axis=0)))
    overlap = np.all((lo[:, None] < hi[None] - margin) & (lo[None] < hi[:, None] - margin),
                     axis=2)
    np.fill_diagonal(overlap, False)
    if not overlap.any():
        return v, f, None
    try:
        import manifold3d
    except ImportError as exc:  # pragma: no cover - a dependency
        raise PartError(f"{source}: {count} shells overlap and joining them needs the "
                        "manifold3d package (`pip install manifold3d`)") from exc
    solids: list[manifold3d.Manifold] = []
    cavities: list[manifold3d.Manifold] = []
    volumes = np.zeros(count)
    for k in range(count):
        fk = f[labels == k]
        used, local = np.unique(fk.ravel(), return_inverse=True)
        tris = local.reshape(-1, 3)
        volumes[k] = _signed_volume(v[used], tris)
        if volumes[k] < 0:
            tris = tris[:, ::-1]
        mesh = manifold3d.Mesh64(vert_properties=np.ascontiguousarray(v[used]),
                                 tri_verts=np.ascontiguousarray(tris, dtype=np.uint64))
        solid = manifold3d.Manifold(mesh)
        if solid.status() != manifold3d.Error.NoError:
            raise PartError(
                f"{source}: shell {k + 1} of {count} overlaps another but is not a closed "
                f"surface ({solid.status().name}); its volume would count twice: repair the "
                "mesh or export the part as one solid"
            )
        (cavities if volumes[k] < 0 else solids).append(solid)
    joined = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    if cavities:
        joined = manifold3d.Manifold.batch_boolean([joined, *cavities],
                                                   manifold3d.OpType.Subtract)
    total = float(volumes.sum())
    if abs(joined.volume() - total) <= 1e-9 * max(abs(total), 1e-300):
        return v, f, None  # boxes overlapped, volumes did not (a cavity, shells side by side)
    out = joined.to_mesh64()
    v2 = np.ascontiguousarray(out.vert_properties[:, :3], dtype=np.float64)
    f2 = np.ascontiguousarray(out.tri_verts, dtype=np.int64)
    pieces = len(joined.decompose())
    return v2, f2, (
        f"{source}: {count} closed shells overlap (their common volume, "
        f"{total - joined.volume():.4g}, would count twice); joined into {pieces} solid"
        f"{'s' if pieces != 1 else ''} by a mesh union (volume {joined.volume():.6g})"
    )


#: Triangles whose sides are probed for self-intersection (all of them below this count).
SELF_INTERSECTION_SAMPLES = 64


#: A direction no mesh an exporter writes is aligned with, for ray crossings.
_RAY = np.array([0.5773502691896257, 0.6123724356957945, 0.5400617248673217])


def winding_numbers(v: np.ndarray, f: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(k,) winding numbers of ``points (k, 3)`` for the closed mesh ``v``, ``f``.

    The signed count of the triangles a ray from each point crosses (+1 leaving through an
    outward face, -1 entering): 1 inside a closed outward surface, 0 outside, 2 where two
    layers overlap. Only triangles whose shadow along the ray covers the point are tested
    exactly, so a point costs a few comparisons per triangle: 128 points on 10^6 triangles
    take a fraction of a second (the solid-angle sum took half a minute). The ray's
    direction is irrational to the axes, so it passes through an edge or a vertex only
    for a point placed there on purpose.
    """
    d = _RAY / np.linalg.norm(_RAY)
    u = np.cross(d, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(d, u)  # (u, w, d) right-handed: a projected triangle's turn is sign(n . d)
    tri = v[f]  # (m, 3, 3)
    flat = np.stack([tri @ u, tri @ w], axis=-1)  # (m, 3, 2)
    depth = tri @ d  # (m, 3)
    lo, hi = flat.min(axis=1), flat.max(axis=1)  # (m, 2)
    far = depth.max(axis=1)  # (m,)
    out = np.zeros(len(points))
    for i, p in enumerate(np.asarray(points, dtype=np.float64)):
        q = np.array([p @ u, p @ w])
        near = np.flatnonzero((lo[:, 0] <= q[0]) & (hi[:, 0] >= q[0]) & (lo[:, 1] <= q[1])
                              & (hi[:, 1] >= q[1]) & (far > p @ d))
        if len(near) == 0:
            continue
        a, b, c = flat[near, 0], flat[near, 1], flat[near, 2]  # (h, 2) each
        area = _cross2(b - a, c - a)
        la, lb, lc = _cross2(b - q, c - q), _cross2(c - q, a - q), _cross2(a - q, b - q)
        inside = (np.sign(la) == np.sign(area)) & (np.sign(lb) == np.sign(area)) & (
            np.sign(lc) == np.sign(area)) & (area != 0)
        z = depth[near]
        hit = (la * z[:, 0] + lb * z[:, 1] + lc * z[:, 2]) / np.where(area == 0, 1.0, area)
        crossed = inside & (hit > p @ d)
        out[i] = float(np.sign(area[crossed]).sum())
    return out


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(h,) z component of the cross products of (h, 2) vectors."""
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def buried_triangles(v: np.ndarray, f: np.ndarray, *,
                     samples: int = SELF_INTERSECTION_SAMPLES) -> np.ndarray | None:  # fmt: skip
    """Where a closed mesh intersects or overlaps itself, as far as a sample shows; or None.

    Just in front of each probed triangle (along its normal, a thousandth of its inradius
    away) the winding number is 0 on a valid closed outward surface and just behind it 1; a
    triangle buried in the solid, or a second layer over the same place, shows 1 and 2 (or
    -1 and 0). Every triangle is probed up to ``samples`` triangles; beyond, a fixed sample
    of that many, so a small local fold may go unseen. Returns the centroid (3,) of one
    such triangle.
    """
    m = len(f)
    if m == 0:
        return None
    pick = (np.arange(m) if m <= samples
            else np.sort(np.random.default_rng(0).choice(m, samples, replace=False)))
    p = v[f[pick]]  # (s, 3, 3)
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    double_area = np.linalg.norm(normal, axis=1)
    good = double_area > 0
    p, normal, double_area, pick = p[good], normal[good], double_area[good], pick[good]
    perimeter = sum(np.linalg.norm(p[:, k] - p[:, (k + 1) % 3], axis=1) for k in range(3))
    offset = 1e-3 * double_area / perimeter  # a thousandth of the inradius
    unit = normal / double_area[:, None]
    centre = p.mean(axis=1)
    front = winding_numbers(v, f, centre + offset[:, None] * unit)
    back = winding_numbers(v, f, centre - offset[:, None] * unit)
    bad = (np.abs(front) > 0.5) | (np.abs(back - 1) > 0.5)
    if not bad.any():
        return None
    return centre[int(np.argmax(bad))]


# --------------------------------------------------------------------------- STEP
_ENTITY = re.compile(r"#(\d+)\s*=\s*(.*?);\s*(?=#\d+\s*=|ENDSEC)", re.S)


def _length_unit_of(entity: str, entities: dict[int, str], depth: int = 0
                    ) -> tuple[str, float] | None:
    """(short name, metres per unit) of one STEP length-unit entity's text, or None."""
    m = re.search(r"SI_UNIT\s*\(\s*(\$|\.\w+\.)\s*,\s*\.METRE\.\s*\)", entity, re.I)
    if m:
        return _SI_PREFIXES.get(m.group(1).upper())
    m = re.search(r"CONVERSION_BASED_UNIT\s*\(\s*'([^']*)'\s*,\s*#(\d+)", entity, re.I)
    if not m:
        return None
    if m.group(1).upper() in _CONVERSION_UNITS:
        return _CONVERSION_UNITS[m.group(1).upper()]
    # an unnamed conversion: LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(factor), #base)
    measure = entities.get(int(m.group(2)), "")
    f = re.search(r"LENGTH_MEASURE\s*\(\s*([-+0-9.eE]+)\s*\)\s*,\s*#(\d+)", measure)
    if not f or depth > 4:
        return None
    base = _length_unit_of(entities.get(int(f.group(2)), ""), entities, depth + 1)
    if base is None:
        return None
    metres = float(f.group(1)) * base[1]
    for name, value in _NAMED_LENGTHS.items():
        if math.isclose(value, metres, rel_tol=1e-6):
            return name, value
    return m.group(1).lower() or "unnamed", metres


def step_units(text: str) -> list[tuple[str, float]]:
    """Every distinct length unit a STEP file's geometry contexts declare, in file order.

    Reads the ``GLOBAL_UNIT_ASSIGNED_CONTEXT`` of each representation context and the
    ``LENGTH_UNIT`` among the units it names: ``SI_UNIT(.MILLI.,.METRE.)`` or a
    ``CONVERSION_BASED_UNIT('INCH', ...)``. Units that only define another one (the
    millimetre an inch is defined from) are not declarations and are not listed.
    """
    found: list[tuple[str, float]] = []
    contexts = list(re.finditer(r"GLOBAL_UNIT_ASSIGNED_CONTEXT\s*\(\s*\(([^)]*)\)", text,
                                re.I))
    if contexts:
        entities = {int(m.group(1)): m.group(2) for m in _ENTITY.finditer(text)}
        for context in contexts:
            for ref in re.findall(r"#(\d+)", context.group(1)):
                entity = entities.get(int(ref), "")
                if not re.search(r"LENGTH_UNIT\s*\(\s*\)", entity, re.I):
                    continue
                unit = _length_unit_of(entity, entities)
                if unit is not None and unit not in found:
                    found.append(unit)
    return found


def step_unit(text: str) -> tuple[str, float] | None:
    """Length unit of a STEP file's text: (short name, metres per unit), or None if absent.

    The first unit :func:`step_units` finds; for a file without unit contexts, the first
    ``LENGTH_UNIT`` entity, named or SI.
    """
    units = step_units(text)
    if units:
        return units[0]
    for entity in re.finditer(r"\(([^;]*?LENGTH_UNIT\s*\(\s*\)[^;]*)\)\s*;", text, re.S | re.I):
        unit = _length_unit_of(entity.group(1), {})
        if unit is not None:
            return unit
    return None


def _load_step(path: Path, tolerance: float | None, unit: str | None) -> list[Part]:
    try:
        import cascadio

        import_trimesh()  # first, holding signals (see import_holding_signals)
        import trimesh
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise PartError(
            f"{path}: reading STEP needs the cascadio and trimesh packages "
            "(`pip install cascadio trimesh`)"
        ) from exc
    try:
        data = read_input(path, what="part file", limit=MAX_PART_BYTES)
    except InputError as exc:
        raise PartError(str(exc)) from None
    head = data[:4096].lstrip()
    if not head.startswith(b"ISO-10303-21"):
        raise PartError(
            f"{path}: not a STEP file (it does not start with ISO-10303-21); check the file, "
            "or give it the suffix of its real format"
        )
    text = data.decode("latin-1")
    warnings: list[str] = []
    declared = step_units(text)
    if len(declared) > 1:
        names = ", ".join(u for u, _ in declared)
        warnings.append(
            f"{path}: the STEP file declares several length units ({names}); read in "
            f"{declared[0][0]}, the first; if the part comes out the wrong size, give its "
            "[[part]] the right `unit`"
        )
    found = declared[0] if declared else step_unit(text)
    if found is None:
        found = ("mm", 1e-3)
        if unit is None:
            warnings.append(f"{path}: no length unit in the STEP header; assumed millimetres "
                            "(give the [[part]] a `unit` if it is in another)")
    # OpenCASCADE reads the coordinates in the declared unit; dividing its metres by the
    # declared unit gives the numbers written in the file back
    metres = found[1]
    unit_name = found[0]
    if unit is not None:
        if unit != found[0]:
            warnings.append(
                f"{path}: the STEP header declares {found[0]}; its coordinates are read as "
                f"{unit}, as the scene's `unit` asks"
            )
        unit_name = unit
    # OpenCASCADE tessellates in its session unit, millimetres, whatever the file's unit
    mm_per_unit = metres * 1e3

    def tessellate(tol_mm: float, angular: float) -> Loaded:
        with _native_output() as captured:
            glb = cascadio.load(
                data, file_type="step", tol_linear=tol_mm, tol_angular=angular,
                merge_primitives=True, use_parallel=False,
            )
        if not glb:
            detail = _occt_error(captured[0] if captured else "")
            raise PartError(
                f"{path}: OpenCASCADE could not read this STEP file{detail}; the file is "
                "damaged or not a STEP AP203/AP214/AP242 model: re-export it from the CAD "
                "program"
            )
        try:
            scene = trimesh.load(io.BytesIO(glb), file_type="glb", process=False)
        except Exception as exc:  # noqa: BLE001 - any parser failure is a bad file here
            raise PartError(f"{path}: the STEP file's tessellation is unreadable ({exc})") from exc
        if not isinstance(scene, (trimesh.Scene, trimesh.Trimesh)):
            raise PartError(f"{path}: the STEP file's tessellation holds no surfaces "
                            f"(a {type(scene).__name__}); re-export it as solids")
        return scene

    coarse = tessellate(1e30, 1.0)
    box = _scene_bounds(coarse)
    if box is None:
        raise PartError(_no_solid_message(path))
    diagonal_mm = float(np.linalg.norm(box[1] - box[0])) * 1e3
    if not diagonal_mm >= MIN_STEP_DIAGONAL_MM:
        raise PartError(
            f"{path}: the model is {diagonal_mm / mm_per_unit:.3g} {found[0]} "
            f"({diagonal_mm:.3g} mm) across, too small for OpenCASCADE to tessellate (its "
            f"precision is {OCC_PRECISION_MM:g} mm; at least {MIN_STEP_DIAGONAL_MM:g} mm "
            "is needed); check the file's length unit, or scale the part up"
        )
    default_mm = DEFAULT_RELATIVE_TOLERANCE * diagonal_mm
    if tolerance is None:
        tol_mm = default_mm
    else:
        tol_mm = float(tolerance) * mm_per_unit
        if tol_mm < default_mm:
            _check_triangle_budget(path, coarse, tessellate(default_mm, DEFAULT_ANGULAR_TOLERANCE),
                                   default_mm, tol_mm, mm_per_unit, unit_name)
    scene = tessellate(tol_mm, DEFAULT_ANGULAR_TOLERANCE)

    parts: list[Part] = []
    seen: dict[str, int] = {}
    items: list[Body] = []
    if isinstance(scene, trimesh.Trimesh):
        items = [(path.stem, np.eye(4), scene)]
    else:
        for node in scene.graph.nodes_geometry:
            transform, geometry_name = scene.graph[node]
            geometry = scene.geometry[geometry_name]
            if isinstance(geometry, trimesh.Trimesh):
                items.append((str(geometry_name), transform, geometry))
    items = [it for it in items if len(it[2].faces)]
    items = _name_and_order(items, step_products(text))
    if not items:
        raise PartError(_no_solid_message(path))
    for index, (raw_name, transform, mesh) in enumerate(items):
        name = _clean_name(str(raw_name), path.stem, index, len(items))
        if name in seen:
            seen[name] += 1
            name = f"{name}_{seen[name]}"
        else:
            seen[name] = 1
        v = np.asarray(mesh.vertices, dtype=np.float64)
        v = v @ np.asarray(transform)[:3, :3].T + np.asarray(transform)[:3, 3]
        v = _snap_float32(v / metres)  # GLB metres -> the file's unit
        source = f"{path} (body {name!r})" if len(items) > 1 else str(path)
        v, f, w = check_mesh(v, np.asarray(mesh.faces), source=source, report_degenerate=False,
                             resolution=FLOAT32_RESOLUTION)
        parts.append(
            Part(name=name, vertices=v, faces=f, source=str(path), unit=unit_name,
                 warnings=tuple(warnings) + w)
        )
    return parts


def _triangles(scene: Loaded) -> int:
    """Triangles of a tessellation (a trimesh Scene or mesh)."""
    if hasattr(scene, "geometry"):
        return int(sum(len(getattr(g, "faces", ())) for g in scene.geometry.values()))
    return int(len(getattr(scene, "faces", ())))


def _check_triangle_budget(path: Path, coarse: Loaded, reference: Loaded, reference_mm: float,
                           tol_mm: float, mm_per_unit: float, unit: str) -> None:  # fmt: skip
    """Refuse a tolerance whose tessellation would exceed MAX_STEP_TRIANGLES, before making it.

    On curved faces the chord error of a triangle of side s on a radius r is s^2 / (8 r),
    so the triangle count grows as 1 / tolerance; flat faces keep their count. From the
    coarsest tessellation (flat) and one at ``reference_mm``, the count at ``tol_mm`` is
    about ``flat + 0.5 (reference - flat) reference_mm / tol_mm``: the factor 0.5 was fitted
    on the bundled parts at tolerances 10 to 150 times finer than the default (measured
    0.40 to 0.48, so the estimate errs on the high side).
    """
    flat = _triangles(coarse)
    curved = 0.5 * max(_triangles(reference) - flat, 0)
    estimate = flat + curved * reference_mm / tol_mm
    if estimate <= MAX_STEP_TRIANGLES:
        return
    finest = reference_mm * curved / max(MAX_STEP_TRIANGLES - flat, 1)
    raise PartError(
        f"{path}: a tessellation tolerance of {tol_mm / mm_per_unit:.3g} {unit} would make "
        f"about {estimate:.3g} triangles (at most {MAX_STEP_TRIANGLES:,} are made: beyond, "
        f"minutes and gigabytes); use a tolerance of at least {finest / mm_per_unit:.3g} {unit}"
    )


def _snap_float32(v: np.ndarray) -> np.ndarray:
    """Round coordinates to the decimal step just above float32's resolution.

    GLB stores float32 metres, so 20 mm comes back as 19.99999955 mm. Rounding to a decimal
    step of about 2.4e-7 times the largest coordinate (four float32 ulps) gives the design's
    round dimensions back exactly and loses nothing float32 had kept.
    """
    largest = float(np.abs(v).max()) if v.size else 0.0
    if not largest > 0:
        return v
    decimals = -int(math.ceil(math.log10(largest * 2.4e-7)))
    return np.round(v, decimals)


def _no_solid_message(path: Path) -> str:
    return (
        f"{path}: the STEP file holds no solid or surface to tessellate; export the part as "
        "a solid body"
    )


def _scene_bounds(scene) -> np.ndarray | None:
    try:
        b = scene.bounds
    except Exception:  # noqa: BLE001
        return None
    if b is None or not np.all(np.isfinite(b)):
        return None
    return np.asarray(b, dtype=np.float64)


def step_products(text: str) -> list[tuple[str, str]]:
    """(id, name) of each part product of a STEP file (assemblies left out), in file order.

    ``PRODUCT('id', 'name', ...)``; a product is an assembly when one of its definitions
    is the relating side of a ``NEXT_ASSEMBLY_USAGE_OCCURRENCE``.
    """
    products = [(int(m.group(1)), m.group(2), m.group(3)) for m in re.finditer(
        r"#(\d+)\s*=\s*PRODUCT\s*\(\s*'([^']*)'\s*,\s*'([^']*)'", text)]
    if not products:
        return []
    formation = {int(m.group(1)): int(m.group(2)) for m in re.finditer(
        r"#(\d+)\s*=\s*PRODUCT_DEFINITION_FORMATION\w*\s*\(\s*'[^']*'\s*,\s*'[^']*'\s*,"
        r"\s*#(\d+)", text)}
    definition = {int(m.group(1)): int(m.group(2)) for m in re.finditer(
        r"#(\d+)\s*=\s*PRODUCT_DEFINITION\s*\(\s*'[^']*'\s*,\s*'[^']*'\s*,\s*#(\d+)", text)}
    assemblies = set()
    for m in re.finditer(r"NEXT_ASSEMBLY_USAGE_OCCURRENCE\s*\(\s*'[^']*'\s*,\s*'[^']*'\s*,"
                         r"\s*'[^']*'\s*,\s*#(\d+)", text):
        assemblies.add(formation.get(definition.get(int(m.group(1)), -1), -1))
    return [(pid, name) for ref, pid, name in products if ref not in assemblies]


def _name_and_order(items: list[Body], products: list[tuple[str, str]]) -> list[Body]:
    """Bodies in the STEP file's order, each named after its product where the file says.

    OpenCASCADE names a body after its product's name; a product named like ``SOLID``
    (some exporters put the real name in the id) comes back as ``SOLID``, ``SOLID_1``,
    ... in file order, so the n-th such body takes the id of the n-th product of that name.
    GLB scene graphs are unordered; the STEP's PRODUCT entities are not.
    """
    names = [n for _, n in products]
    renamed: list[tuple[int, str, np.ndarray, trimesh.Trimesh]] = []
    for raw, transform, mesh in items:
        order, name = len(products), raw
        if raw in names:
            order = names.index(raw)
        if _ANONYMOUS.match(raw):
            m = re.fullmatch(r"(.*?)(?:_(\d+))?", raw)
            base, rank = (m.group(1), int(m.group(2) or 0)) if m else (raw, 0)
            same = [i for i, n in enumerate(names) if n == base]
            if rank < len(same):
                order = same[rank]
            if order < len(products) and not _ANONYMOUS.match(products[order][0]):
                name = products[order][0]
        renamed.append((order, name, transform, mesh))
    renamed.sort(key=lambda it: it[0])
    return [(name, transform, mesh) for _, name, transform, mesh in renamed]


def _clean_name(raw: str, stem: str, index: int, count: int) -> str:
    name = raw.strip()
    if _ANONYMOUS.match(name):
        return stem if count == 1 else f"{stem}_{index + 1}"
    return name


def _occt_error(text: str) -> str:
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", ln).strip(" *") for ln in text.splitlines()]
    lines = [ln.strip() for ln in lines if "ERR" in ln or "rror" in ln]
    return f" ({lines[0]})" if lines else ""


_capture_lock = threading.Lock()


@contextmanager
def _native_output() -> Iterator[list[str]]:
    """Capture what native code writes to file descriptors 1 and 2 (OpenCASCADE's messages).

    OpenCASCADE prints parser messages straight to the process's stdout, which would corrupt
    a ``--json`` result; they are kept here and quoted in the error message instead. The
    redirection is process-wide for the few milliseconds of a tessellation (other threads'
    output in that window lands in the capture too); a lock keeps two loads from nesting it.
    """
    with _capture_lock:
        with _redirected() as captured:
            yield captured


@contextmanager
def _redirected() -> Iterator[list[str]]:
    captured: list[str] = []
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = (os.dup(1), os.dup(2))
    except (OSError, ValueError, AttributeError):
        yield captured
        return
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            yield captured
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            tmp.seek(0)
            captured.append(tmp.read(65536).decode("utf-8", errors="replace"))


# --------------------------------------------------------------------------- meshes
#: Signals held while a module that swallows them is imported (see import_holding_signals).
HELD_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


def import_holding_signals(name: str) -> ModuleType:
    """Import module ``name`` with Ctrl+C, SIGTERM and SIGHUP held until the import ends.

    trimesh guards its optional imports with ``except BaseException``: a Ctrl+C landing in
    one (or the SIGTERM or SIGHUP the command line turns into an exception) was swallowed
    and the run went on into work that no signal could stop for minutes. Here a signal that
    arrives during the import is noted, and passed to its own handler once the import is
    done, so it acts as soon as the import returns (a fraction of a second). Only handlers
    written in Python are held (the default action still ends the process at once), and only
    in the main thread, where Python runs them.
    """
    import importlib
    import signal

    if name in sys.modules:
        return sys.modules[name]
    caught: list[int] = []
    held: dict[int, Callable[[int, FrameType | None], object]] = {}
    if threading.current_thread() is threading.main_thread():
        for sig_name in HELD_SIGNALS:
            number = getattr(signal, sig_name, None)
            current = signal.getsignal(number) if number is not None else None
            if number is not None and callable(current):
                held[number] = current
                signal.signal(number, lambda signum, frame: caught.append(signum))
    try:
        return importlib.import_module(name)
    finally:
        for number, handler in held.items():
            signal.signal(number, handler)
        if caught:
            held[caught[0]](caught[0], None)


#: What trimesh imports inside its guards and takes longest: imported first, where a signal
#: acts at once, so that only trimesh's own modules are imported with signals held. On a
#: loaded 2-core machine ``import trimesh`` took 1.1 s, of which 0.18 s once these were
#: in. (cascadio, its STEP reader, imports trimesh itself, so it stays in the held part.)
TRIMESH_DEPENDENCIES = ("numpy", "scipy.spatial", "scipy.sparse", "scipy.optimize",
                        "PIL.Image", "rtree.index", "manifold3d")


def import_trimesh() -> ModuleType:
    """The trimesh module, imported with signals held (:func:`import_holding_signals`).

    Its slow dependencies (:data:`TRIMESH_DEPENDENCIES`) are imported before, unheld: a
    signal during the whole import then waits at most for trimesh's own modules.
    """
    import importlib

    if "trimesh" not in sys.modules:
        for name in TRIMESH_DEPENDENCIES:
            try:
                importlib.import_module(name)
            except ImportError:  # optional for trimesh as well
                pass
    return import_holding_signals("trimesh")


def _load_mesh(path: Path, unit: str | None = None) -> Part:
    import_trimesh()  # first, holding signals (see import_holding_signals)
    import trimesh

    if path.stat().st_size == 0:
        raise PartError(f"{path}: the file is empty; export the part again")
    if path.suffix.lower() == ".stl":
        _check_stl(path)
    elif path.suffix.lower() == ".obj":
        _check_obj(path)
    try:
        loaded = trimesh.load(str(path), process=False)
    except ImportError as exc:  # trimesh guesses a text encoding with an optional module
        raise PartError(
            f"{path}: cannot read this {path.suffix} file: it is not valid {path.suffix} text "
            "(not UTF-8); check that it is a mesh of that format, or re-export it"
        ) from exc
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for bad files
        raise PartError(
            f"{path}: cannot read this {path.suffix} file ({type(exc).__name__}: {exc}); "
            "check that it is a valid mesh, or re-export it"
        ) from exc
    if isinstance(loaded, trimesh.Scene):  # several objects in one file
        meshes = []
        for node in loaded.graph.nodes_geometry:
            transform, name = loaded.graph[node]
            g = loaded.geometry[name]
            if isinstance(g, trimesh.Trimesh) and len(g.faces):
                v = np.asarray(g.vertices, dtype=np.float64)
                t = np.asarray(transform)
                meshes.append((v @ t[:3, :3].T + t[:3, 3], np.asarray(g.faces)))
        if not meshes:
            vertices, faces = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        else:
            offsets = np.cumsum([0] + [len(m[0]) for m in meshes[:-1]])
            vertices = np.concatenate([m[0] for m in meshes])
            faces = np.concatenate([m[1] + o for m, o in zip(meshes, offsets, strict=True)])
    elif isinstance(loaded, trimesh.Trimesh):
        vertices, faces = np.asarray(loaded.vertices), np.asarray(loaded.faces)
    else:
        raise PartError(
            f"{path}: the file holds no triangles (a point cloud or curves?); export a "
            "surface mesh"
        )
    v, f, warnings = check_mesh(vertices, faces, source=str(path))
    return Part(name=path.stem, vertices=v, faces=f, source=str(path),
                unit=unit or "unspecified", warnings=warnings)


#: An OBJ face line with a vertex index 0 (OBJ counts from 1; negative counts from the end).
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t](?:[^\n]*[ \t])?[-+]?0+(?=[/ \t\r\n]|$)", re.M)


def _check_obj(path: Path) -> None:
    """Raise for a face that names vertex 0: OBJ counts from 1, so the file is damaged.

    trimesh reads index 0 as the last vertex (0 - 1 = -1), which makes a wrong triangle
    out of a damaged file without a word.
    """
    data = read_input(path, what="part file", limit=MAX_PART_BYTES)
    m = _OBJ_ZERO_INDEX.search(data)
    if m is None:
        return
    line = data.count(b"\n", 0, m.start()) + 1
    text = data[m.start():data.find(b"\n", m.start()) if b"\n" in data[m.start():]
                else len(data)].decode("utf-8", "replace").strip()
    raise PartError(f"{path}:{line}: the face {text[:60]!r} names vertex 0, but OBJ counts "
                    "vertices from 1: the file is damaged or was written by a faulty "
                    "exporter; re-export it")


def _check_stl(path: Path) -> None:
    """Raise unless ``path`` is a binary STL (size matches its count) or ASCII STL text."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if size >= 84:
        count = int.from_bytes(head[80:84], "little")
        if size == 84 + 50 * count:
            if count > MAX_MESH_TRIANGLES:
                raise PartError(
                    f"{path}: {count:,} triangles, more than the {MAX_MESH_TRIANGLES:,} a part "
                    "may have (each costs about 700 bytes while it loads); export it coarser"
                )
            return
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        text = ""
    if text.lstrip().lower().startswith("solid") and (len(head) < 4096 or "facet" in text):
        return
    expected = (f"its header announces {int.from_bytes(head[80:84], 'little')} triangles, "
                f"{84 + 50 * int.from_bytes(head[80:84], 'little')} bytes, but it has {size}"
                if size >= 84 else f"it has only {size} bytes")
    raise PartError(
        f"{path}: not an STL file: not binary STL ({expected}) and not ASCII STL text "
        "(starting with 'solid' and listing facets); the file is damaged or of another "
        "format: re-export it"
    )


# --------------------------------------------------------------------------- mesh algorithms
def _areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(m,) float64 triangle areas."""
    if len(f) == 0:
        return np.zeros(0)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _signed_volume(v: np.ndarray, f: np.ndarray, about: np.ndarray | None = None) -> float:
    """Signed enclosed volume; ``about`` (a point) only matters for open meshes."""
    if len(f) == 0:
        return 0.0
    o = np.zeros(3) if about is None else np.asarray(about, dtype=np.float64)
    a, b, c = v[f[:, 0]] - o, v[f[:, 1]] - o, v[f[:, 2]] - o
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _weld(v: np.ndarray, f: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices closer than ``tol`` (connected clusters), keep the first of each.

    Linear memory and O(n log n) time whatever the mesh: the vertices are binned on a grid
    of cells ``tol`` wide; a cell's vertices are one cluster, and two neighbouring cells
    join when their vertices' boxes lie within ``tol`` of each other. Every pair closer
    than ``tol`` is joined (its two cells are the same or neighbours, and their boxes are
    at most that far apart); a pair up to ``(1 + 2 sqrt 3) tol`` apart may be joined too.
    Listing every close pair instead (``cKDTree.query_pairs``) costs k^2 for a vertex
    stored k times: a fan of 8,000 triangles around a cap's centre took minutes and
    gigabytes.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(v)
    cells, pairs = _cell_pairs(v, tol)
    WELD_STATS["vertices"] = n
    WELD_STATS["cells"] = int(cells.max()) + 1 if n else 0
    WELD_STATS["pairs"] = len(pairs)
    count = WELD_STATS["cells"]
    if count == n and len(pairs) == 0:
        return v, f
    if len(pairs):
        graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])),
                           shape=(count, count))
        _, cell_label = connected_components(graph, directed=False)
        labels = cell_label[cells]
    else:
        labels = cells
    # representative: lowest original index in each cluster, kept in original order
    _, first = np.unique(labels, return_index=True)  # (clusters,) first index of each
    reps = np.sort(first)
    new_index = np.empty(int(labels.max()) + 1, dtype=np.int64)
    new_index[labels[reps]] = np.arange(len(reps))
    return v[reps], new_index[labels][f]


#: What the last weld examined (for tests and the loader benchmark): vertices, occupied
#: grid cells, and pairs of neighbouring cells joined.
WELD_STATS: dict[str, int] = {}

#: The 13 neighbour offsets of a cell with a larger key (the other 13 are their opposites).
_HALF_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1)
                             for k in (-1, 0, 1) if (i, j, k) > (0, 0, 0)], dtype=np.int64)


def _cell_pairs(v: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The grid cell of each vertex, and the pairs of neighbouring cells within ``tol``.

    Returns ``cells (n,) int64`` (dense cell numbers) and ``pairs (p, 2) int64`` (cells
    whose vertices' boxes are closer than ``tol``; at most 13 per cell).
    """
    lower = v.min(axis=0)
    span = (v.max(axis=0) - lower) / tol
    if not np.all(span < 2.0**20):
        # too many cells per side for one int64 key: fall back to a coarser grid; the weld
        # stays exact for copies and joins at most a few cells' width more
        tol = float(np.max(v.max(axis=0) - lower)) / 2.0**20
        span = (v.max(axis=0) - lower) / tol
    index = np.floor((v - lower) / tol).astype(np.int64)  # (n, 3)
    side = np.int64(2**20 + 3)  # cell index + 1 in 1..2^20 + 1, a neighbour's in 0..2^20 + 2
    key = ((index[:, 0] + 1) * side + (index[:, 1] + 1)) * side + (index[:, 2] + 1)
    keys, cells = np.unique(key, return_inverse=True)
    cells = cells.ravel()
    count = len(keys)
    order = np.argsort(cells, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(cells[order]) != 0])
    lo = np.minimum.reduceat(v[order], starts, axis=0)  # (cells, 3) box of each cell
    hi = np.maximum.reduceat(v[order], starts, axis=0)
    found: list[np.ndarray] = []
    for di, dj, dk in _HALF_NEIGHBOURS.tolist():
        other = keys + (di * side + dj) * side + dk
        at = np.searchsorted(keys, other)
        at[at == count] = 0
        hit = np.flatnonzero(keys[at] == other)
        if len(hit) == 0:
            continue
        a, b = hit, at[hit]
        gap = np.maximum(np.maximum(lo[b] - hi[a], lo[a] - hi[b]), 0.0)  # (h, 3)
        close = np.einsum("ij,ij->i", gap, gap) <= tol * tol
        if close.any():
            found.append(np.stack([a[close], b[close]], axis=1))
    pairs = np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
    return cells, pairs


def _heights(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height of each triangle over its longest side, and the corner opposite that side.

    Returns two (m,) arrays: the heights (float64) and which corner (0..2) lies opposite the
    longest side (int64).
    """
    p = v[f]  # (m, 3, 3)
    sides = np.stack([p[:, 2] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 0]], axis=1)
    lengths = np.linalg.norm(sides, axis=2)  # (m, 3): side k is opposite corner k
    opposite = np.argmax(lengths, axis=1)
    longest = lengths[np.arange(len(f)), opposite]
    area2 = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return area2 / np.maximum(longest, 1e-300), opposite


def _flip_collinear(v: np.ndarray, f: np.ndarray, tol: float, rounds: int = 20
                    ) -> tuple[np.ndarray, int, int]:
    """Remove triangles whose three distinct corners are collinear, keeping the surface closed.

    A triangle ``(x, y, m)`` whose corner ``m`` lies within ``tol`` of its longest side
    ``x-y`` is flipped with the one neighbour across that side, ``(y, x, c)``: the two
    become ``(m, x, c)`` and ``(y, m, c)``, the neighbour split at ``m``. The surface is the
    same point set, every edge keeps its two triangles, and the winding is kept. A flat
    triangle with no single neighbour across its longest side is dropped (counted apart).

    Returns the faces, how many triangles were flipped away and how many were dropped.
    """
    flipped = dropped = 0
    f = f.copy()
    for _ in range(rounds):
        if len(f) == 0:
            break
        heights, opposite = _heights(v, f)
        flat = np.nonzero(heights <= tol)[0]
        if len(flat) == 0:
            break
        changed: set[int] = set()
        drop: list[int] = []
        for d in flat.tolist():
            if d in changed:
                continue  # a neighbour of an earlier flip this round: look again next round
            k = int(opposite[d])
            m = int(f[d, k])
            x, y = int(f[d, (k + 1) % 3]), int(f[d, (k + 2) % 3])  # d runs x -> y -> m
            across = np.nonzero((f == x).any(axis=1) & (f == y).any(axis=1))[0]
            across = across[across != d]
            if len(across) != 1 or int(across[0]) in changed:
                if len(across) != 1:
                    drop.append(d)
                    changed.add(d)
                continue
            n = int(across[0])
            c = int(next(q for q in f[n].tolist() if q not in (x, y)))
            if c == m:  # two flat triangles back to back: a fin, no area on either side
                drop.extend([d, n])
                changed.update((d, n))
                continue
            f[d] = (m, x, c)
            f[n] = (y, m, c)
            changed.update((d, n))
            flipped += 1
        if drop:
            keep = np.ones(len(f), dtype=bool)
            keep[drop] = False
            f = f[keep]
            dropped += len(drop)
    return f, flipped, dropped


def _row_keys(rows: np.ndarray, n: int) -> np.ndarray:
    """(k,) int64 keys equal exactly when rows of ``rows (k, c)`` (indices below ``n``) are.

    ``np.unique(rows, axis=0)`` sorts rows as opaque bytes, ten times slower than sorting
    one int64 per row; the digits in base ``n`` are that number when they fit in 63 bits,
    else the rows' rank in a lexicographic sort.
    """
    rows = np.asarray(rows, dtype=np.int64)
    k, c = rows.shape
    if k == 0:
        return np.zeros(0, dtype=np.int64)
    base = max(int(n), 1)
    if base ** c < 2**63:
        key = rows[:, 0].copy()
        for j in range(1, c):
            key *= base
            key += rows[:, j]
        return key
    order = np.lexsort(rows.T[::-1])
    step = np.r_[True, np.any(rows[order][1:] != rows[order][:-1], axis=1)]
    rank = np.empty(k, dtype=np.int64)
    rank[order] = np.cumsum(step) - 1
    return rank


def _directed_edges(f: np.ndarray) -> np.ndarray:
    """(3m, 2) directed edges, row 3*i + k belongs to face i."""
    return np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)


def _edge_defects(f: np.ndarray) -> tuple[int, int]:
    """(boundary edges, non-manifold edges) of a triangle mesh."""
    e = np.sort(_directed_edges(f), axis=1)
    _, counts = np.unique(_row_keys(e, int(f.max()) + 1 if len(f) else 0), return_counts=True)
    return int((counts == 1).sum()), int((counts > 2).sum())


def _orient_consistently(f: np.ndarray) -> tuple[np.ndarray, int]:
    """Flip faces so that every manifold edge is traversed in opposite directions.

    Breadth-first over the face adjacency of manifold edges; each connected component keeps
    the orientation of its majority. Returns the faces and how many were flipped.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    m = len(f)
    directed = _directed_edges(f)
    undirected = np.sort(directed, axis=1)
    _, edge_id, counts = np.unique(_row_keys(undirected, int(f.max()) + 1), return_inverse=True,
                                   return_counts=True)
    edge_id = edge_id.ravel()
    manifold = counts[edge_id] == 2
    rows = np.nonzero(manifold)[0]
    order = np.argsort(edge_id[rows], kind="stable")
    rows = rows[order]
    a, b = rows[0::2], rows[1::2]  # the two half-edges of each manifold edge
    if len(a) == 0:
        return f, 0
    # same direction along a shared edge = the two faces disagree
    disagree = directed[a, 0] == directed[b, 0]
    if not disagree.any():
        return f, 0
    fa, fb = a // 3, b // 3
    parity = coo_matrix(
        (np.concatenate([disagree, disagree]).astype(np.int8) + 1,
         (np.concatenate([fa, fb]), np.concatenate([fb, fa]))),
        shape=(m, m),
    ).tocsr()
    parity.sum_duplicates()
    _, labels = connected_components(parity, directed=False)
    _, starts, sizes = np.unique(labels, return_index=True, return_counts=True)
    flip = np.zeros(m, dtype=bool)
    for start in starts[sizes > 1]:
        nodes, pred = breadth_first_order(parity, start, directed=False)
        child, parent = nodes[1:], pred[nodes[1:]]
        odd = np.asarray(parity[child, parent]).ravel() == 2  # (k,) bool
        # parents come before their children in breadth-first order
        for node, p, o in zip(child.tolist(), parent.tolist(), odd.tolist(), strict=True):
            flip[node] = flip[p] ^ o
        if flip[nodes].sum() * 2 > len(nodes):
            flip[nodes] = ~flip[nodes]
    count = int(flip.sum())
    if count:
        f = f.copy()
        f[flip] = f[flip][:, ::-1]
    return f, count


def _names(names: list[str]) -> str:
    return ", ".join(repr(n) for n in names)
