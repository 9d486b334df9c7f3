"""The CAD kernel behind the fit generator: gmsh's OpenCASCADE modeller, and solid primitives.

Solids are OpenCASCADE volumes held by integer tags in gmsh's one global model; every length
is in millimetres (gmsh writes STEP in millimetres). gmsh is GPL, so it is only a development
dependency (the ``assets`` and ``test`` extras): it is imported here, when a generator asks
for it, and never by the installed program.
"""

from __future__ import annotations

import math
import os
import re
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

#: What to run when gmsh is missing.
INSTALL_HINT = 'pip install -e ".[assets]"'


class KernelMissing(RuntimeError):
    """gmsh (the CAD kernel the generator models with) is not installed."""


def require_gmsh():
    """The gmsh module, or a :class:`KernelMissing` whose one line says how to install it."""
    try:
        import gmsh
    except ImportError as exc:
        raise KernelMissing(
            "the fit generator needs gmsh (its OpenCASCADE kernel models the parts), which is "
            f"not installed; install the development extra: {INSTALL_HINT} (gmsh is GPL and "
            "never used by the installed program)") from exc
    return gmsh


#: Signals whose handling gmsh's initialisation changes behind Python's back: it stops
#: ignoring SIGPIPE (a later write to a dead child's pipe then kills the whole process, as
#: it did a test run) and takes SIGINT from Python's handler.
_KEPT_SIGNALS = ("SIGPIPE", "SIGINT", "SIGTERM", "SIGHUP")


def _restore_signals(saved: dict[int, object]) -> None:
    """Install the Python-level handlers ``saved`` again at the operating system's level."""
    for number, handler in saved.items():
        if handler is not None:
            signal.signal(number, handler)  # type: ignore[arg-type]


@contextmanager
def session() -> Iterator[object]:
    """Initialise gmsh for modelling in millimetres, silent; finalised on exit.

    The process's signal handling is put back as it was after gmsh's initialisation and
    after its finalisation (main thread only).
    """
    gmsh = require_gmsh()
    main = threading.current_thread() is threading.main_thread()
    saved = {getattr(signal, n): signal.getsignal(getattr(signal, n))
             for n in _KEPT_SIGNALS if hasattr(signal, n)} if main else {}
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    _restore_signals(saved)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setString("Geometry.OCCTargetUnit", "MM")
        yield gmsh
    finally:
        gmsh.finalize()
        _restore_signals(saved)


@contextmanager
def _native_quiet() -> Iterator[None]:
    """Send what native code prints to the standard output to /dev/null meanwhile."""
    sys.stdout.flush()
    saved = os.dup(1)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


def _occ():
    return require_gmsh().model.occ


def new_model() -> None:
    """Start an empty model (one part at a time is modelled)."""
    gmsh = require_gmsh()
    gmsh.clear()
    gmsh.model.add("part")


# --------------------------------------------------------------------------- booleans
def _one(out) -> int:
    vols = [t for d, t in out if d == 3]
    if len(vols) != 1:
        raise RuntimeError(f"a boolean operation gave {len(vols)} volumes, expected 1")
    return vols[0]


def fuse(a: int, others: list[int]) -> int:
    """One volume: ``a`` united with ``others``."""
    if not others:
        return a
    return _one(_occ().fuse([(3, a)], [(3, t) for t in others])[0])


def cut(a: int, tools: list[int]) -> int:
    """One volume: ``a`` less ``tools``."""
    if not tools:
        return a
    return _one(_occ().cut([(3, a)], [(3, t) for t in tools])[0])


def intersect(a: int, b: int) -> int:
    """One volume: the common part of ``a`` and ``b``."""
    return _one(_occ().intersect([(3, a)], [(3, b)])[0])


# --------------------------------------------------------------------------- primitives
def box(x0: float, y0: float, z0: float, dx: float, dy: float, dz: float) -> int:
    """An axis-aligned box from the corner (x0, y0, z0)."""
    return _occ().addBox(x0, y0, z0, dx, dy, dz)


def centred_box(dx: float, dy: float, z0: float, dz: float) -> int:
    """A box centred on the z axis, from height z0 up by dz."""
    return box(-dx / 2, -dy / 2, z0, dx, dy, dz)


def cylinder(z0: float, length: float, radius: float, x: float = 0.0, y: float = 0.0) -> int:
    """A cylinder along +z from (x, y, z0)."""
    return _occ().addCylinder(x, y, z0, 0, 0, length, radius)


def rod(z0: float, length: float, radius: float, *, chamfer0: float = 0.0,
        chamfer1: float = 0.0, x: float = 0.0, y: float = 0.0) -> int:
    """A round bar along +z from z0, with 45-degree chamfers (cones) on its ends.

    A CAD exporter tessellates the cones as full-length strips, like the cylinder.
    """
    occ = _occ()
    parts = []
    z, top = z0, z0 + length
    if chamfer0 > 0:
        parts.append(occ.addCone(x, y, z0, 0, 0, chamfer0, radius - chamfer0, radius))
        z += chamfer0
    if chamfer1 > 0:
        parts.append(occ.addCone(x, y, top - chamfer1, 0, 0, chamfer1, radius,
                                 radius - chamfer1))
        top -= chamfer1
    return fuse(occ.addCylinder(x, y, z, 0, 0, top - z, radius), parts)


def countersink(z: float, radius: float, chamfer: float, x: float = 0.0,
                y: float = 0.0) -> int:
    """A 45-degree cone that chamfers the mouth (at height z, opening up) of a bore."""
    return _occ().addCone(x, y, z - chamfer, 0, 0, chamfer + 1, radius, radius + chamfer + 1)


def prism_xy(points: list[tuple[float, float]], z0: float, length: float) -> int:
    """A prism of a polygon (x, y) in the plane z = z0, extruded by ``length`` along +z."""
    occ = _occ()
    pts = [occ.addPoint(x, y, z0) for x, y in points]
    lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
    return _one(occ.extrude([(2, surface)], 0, 0, length))


def hexagon(across_flats: float) -> list[tuple[float, float]]:
    """The corners of a regular hexagon centred on the origin, flats parallel to x."""
    r = across_flats / math.sqrt(3.0)  # circumradius
    return [(r * math.cos(math.pi / 6 + k * math.pi / 3), r * math.sin(math.pi / 6
                                                                        + k * math.pi / 3))
            for k in range(6)]


def rotate_z(vol: int, angle: float) -> None:
    """Turn a volume about the z axis by ``angle`` radians."""
    _occ().rotate([(3, vol)], 0, 0, 0, 0, 0, 1, angle)


def fillet_edges_at(vol: int, z: float, reach: float, radius: float) -> int:
    """Round the edges of ``vol`` lying in the plane ``z`` within ``reach`` of the z axis."""
    gmsh = require_gmsh()
    occ = _occ()
    occ.synchronize()
    tol = 1e-3 * max(1.0, reach)
    found = gmsh.model.getEntitiesInBoundingBox(-reach, -reach, z - tol, reach, reach,
                                                z + tol, 1)
    if not found:
        return vol
    return _one(occ.fillet([vol], [t for _, t in found], [radius]))


def place(vol: int, matrix: np.ndarray) -> None:
    """Move a volume by the rigid transform ``matrix`` (4, 4) (x -> R x + t)."""
    occ = _occ()
    m = np.asarray(matrix, float)
    rot = m[:3, :3]
    angle = math.acos(max(-1.0, min(1.0, (np.trace(rot) - 1.0) / 2.0)))
    if angle > 1e-12:
        from scipy.spatial.transform import Rotation

        axis = Rotation.from_matrix(rot).as_rotvec()
        axis = axis / np.linalg.norm(axis)
        occ.rotate([(3, vol)], 0, 0, 0, float(axis[0]), float(axis[1]), float(axis[2]), angle)
    occ.translate([(3, vol)], float(m[0, 3]), float(m[1, 3]), float(m[2, 3]))


def bounding_box(vol: int) -> np.ndarray:
    """(2, 3) float64 lower and upper corners of a volume (OpenCASCADE's, slightly large)."""
    occ = _occ()
    occ.synchronize()
    b = occ.getBoundingBox(3, vol)
    return np.array([b[:3], b[3:]], float)


def write_step(path: Path, name: str) -> None:
    """Write the model's one volume to ``path`` (STEP, millimetres), its product ``name``.

    The header's date is fixed so that the same model gives the same bytes.
    """
    gmsh = require_gmsh()
    _occ().synchronize()
    with _native_quiet():  # OpenCASCADE's STEP writer prints its statistics natively
        gmsh.write(str(path))
    text = path.read_text()
    text = re.sub(r"PRODUCT\('([^']*)',\s*'([^']*)'", f"PRODUCT('{name}',\n  '{name}'", text)
    text = re.sub(r"FILE_NAME\('([^']*)','[^']*'", f"FILE_NAME('{name}','2026-01-01T00:00:00'",
                  text)
    path.write_text(text)
