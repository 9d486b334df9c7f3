"""Tessellation and export of a modelled part: STEP, or STL and OBJ meshed as CAD exporters do.

Data: a part is a gmsh volume (millimetres, canonical frame) placed by a rigid transform
(4, 4) into its file's frame. STEP is OpenCASCADE's writer (millimetres). Meshes come from
OpenCASCADE's B-rep mesher through the project's own STEP loader at a chord tolerance below
the fit's smallest gap, which gives what CAD exporters give (full-length strips on cylinders
and cones, fans of long slivers on flat faces with circular edges); they are written in the
scene's unit, STL binary as a triangle soup, OBJ indexed. Some meshes are deliberately left
open by T-junctions (an edge split on one side only), as some exporters and mesh tools
leave them: the surface is unchanged, its edges no longer pair up.
"""

from __future__ import annotations

import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.fitgen import kernel

#: File formats a part may be written in.
FORMATS = ("step", "stl", "obj")
#: Scene units a pair may be in, and their size in millimetres.
UNITS = {"mm": 1.0, "m": 1000.0}


@dataclass(frozen=True)
class ExportedPart:
    """A part as written.

    Attributes
    ----------
    file : Path
    vertices : (n, 3) float64
        The mesh in the file's frame and the scene's unit (for STEP: as tessellated at the
        chord tolerance, for checks).
    faces : (m, 3) int64
    """

    file: Path
    vertices: np.ndarray
    faces: np.ndarray


def export_part(build, matrix: np.ndarray, path: Path, *, fmt: str, unit: str,
                chord_mm: float, open_edges: int = 0,
                rng: np.random.Generator | None = None) -> ExportedPart:
    """Model a part, place it by ``matrix`` (4, 4; mm) and write it to ``path`` as ``fmt``.

    ``open_edges`` > 0 splits that many edges on one side only (T-junctions; meshes only).
    """
    from engine.loading import load_part

    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; use one of {', '.join(FORMATS)}")
    kernel.new_model()
    vol = build()
    kernel.place(vol, matrix)
    scale = 1.0 / UNITS[unit]
    with tempfile.TemporaryDirectory() as tmp:
        step = path if fmt == "step" else Path(tmp) / f"{path.stem}.step"
        kernel.write_step(step, path.stem)
        mesh = load_part(step, tolerance=chord_mm)
    v = np.array(mesh.vertices, np.float64) * scale
    f = np.array(mesh.faces, np.int64)
    if fmt == "step":
        return ExportedPart(path, v, f)
    if open_edges:
        v, f = t_junctions(v, f, open_edges, rng or np.random.default_rng(0))
    if fmt == "stl":
        write_stl(path, v, f, path.stem)
    else:
        write_obj(path, v, f, path.stem)
    return ExportedPart(path, v, f)


def t_junctions(vertices: np.ndarray, faces: np.ndarray, count: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Split ``count`` edges at their midpoints on one side only (T-junctions).

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    count : int
        Edges to split, each in a different triangle.

    Returns
    -------
    (n + count, 3) float64, (m + count, 3) int64
        The same surface whose split edges are each used once (the mesh is open).
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    chosen = rng.choice(len(f), size=min(count, len(f)), replace=False)
    corner = rng.integers(0, 3, size=len(chosen))
    new_v, new_f, keep = [v], [], np.ones(len(f), bool)
    split: set[tuple[int, int]] = set()
    n = len(v)
    for tri, j in zip(chosen.tolist(), corner.tolist(), strict=True):
        a, b, c = (int(x) for x in np.roll(f[tri], -j))
        edge = (min(a, b), max(a, b))
        if edge in split:  # its other side split too would pair the edges up again
            continue
        split.add(edge)
        new_v.append(((v[a] + v[b]) / 2)[None])
        new_f += [(a, n, c), (n, b, c)]
        keep[tri] = False
        n += 1
    out_f = np.concatenate([f[keep], np.array(new_f, np.int64).reshape(-1, 3)])
    return np.concatenate(new_v), out_f


def write_stl(path: Path, vertices: np.ndarray, faces: np.ndarray, name: str) -> None:
    """Binary STL, a triangle soup with facet normals, as CAD programs write it."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # (m, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    record = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)),
                                       ("attr", "<u2")])
    record["n"], record["v"] = normal, tri
    header = f"binary STL {name} (skelasm fit generator)".encode("ascii")[:80].ljust(80)
    path.write_bytes(header + struct.pack("<I", len(tri)) + record.tobytes())


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray, name: str) -> None:
    """Indexed OBJ text, ten significant digits (sub-micrometre in metres)."""
    lines = [f"# {name} (skelasm fit generator)", f"o {name}"]
    lines += [f"v {x:.10g} {y:.10g} {z:.10g}" for x, y, z in np.asarray(vertices).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces).tolist()]
    path.write_text("\n".join(lines) + "\n")
