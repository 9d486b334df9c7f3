"""Generate a seeded set of unseen fits: parts, scenes (through ``scene new``) and their truth.

Pair ``i`` of seed ``S`` is drawn from its own random stream (``S``, ``i``), so the first
ten pairs of a set of a hundred are the set of ten, and the same seed gives the same files.
The family of pair ``i`` cycles through :data:`bench.fitgen.families.FAMILIES` in an order
shuffled per block of families by the seed: every block of ``len(FAMILIES)`` pairs holds
each family once.

Each pair is modelled in the canonical frame (:mod:`bench.fitgen.families`) and placed:

- part 1's file frame (part 1's frame of the scene) is a rigid transform of the canonical
  one: the insertion axis along a coordinate axis (either sign) in half of the pairs, in any
  direction in the others; its origin off the fit's axis, up to three sizes away;
- part 2's file is written either in the same frame (exported from the assembly: the
  assembled pose is zero) or in a frame of its own (an axis-aligned turn and an origin off
  its axis); the assembled pose then maps one to the other;
- the unit is mm or m; each part is STEP, STL or OBJ; some meshes are left open.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.fitgen import kernel
from bench.fitgen.export import FORMATS, UNITS, export_part
from bench.fitgen.families import FAMILIES, FitDesign
from bench.fitgen.scenes import scene_new
from bench.fitgen.truth import GENERATOR_VERSION, TRUTH_FILE, FitTruth, write_truth

#: The manifest of a generated set, at its root.
MANIFEST = "manifest.json"
#: Chord error of the tessellation, as a fraction of the fit's smallest gap.
CHORD_FRACTION = 0.3
#: Share of mesh files left open (T-junctions), and how many edges are split in one.
OPEN_SHARE, OPEN_EDGES = 0.25, 12


@dataclass(frozen=True)
class GeneratedPair:
    """One pair on disk: its folder, scene file and truth."""

    folder: Path
    scene: Path
    truth: FitTruth


def family_of(seed: int, index: int) -> str:
    """The family of pair ``index`` of seed ``seed`` (every block holds each family once)."""
    names = list(FAMILIES)
    block, at = divmod(index, len(names))
    order = np.random.default_rng([seed, 1, block]).permutation(len(names))
    return names[int(order[at])]


def design(seed: int, index: int) -> tuple[FitDesign, np.random.Generator]:
    """Pair ``index``'s design and the random stream that places and writes it."""
    rng = np.random.default_rng([seed, 0, index])
    return FAMILIES[family_of(seed, index)](rng), rng


# --------------------------------------------------------------------------- placement
def _axis_aligned_turns() -> list[np.ndarray]:
    """The 24 proper rotations that map coordinate axes to coordinate axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, s) in enumerate(zip(perm, signs, strict=True)):
                m[row, col] = s
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


_TURNS = _axis_aligned_turns()


def _any_turn(rng: np.random.Generator) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = rng.normal(size=4)
    return Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()


def _placement(rng: np.random.Generator, size: float, *, any_direction: bool) -> np.ndarray:
    """A rigid transform (4, 4; mm) of the canonical frame whose origin is off the z axis.

    The file's origin lies 0.5 to 3 ``size`` from the part, at least ``size`` / 4 from the
    fit's axis (the canonical z axis).
    """
    rot = _any_turn(rng) if any_direction else _TURNS[int(rng.integers(len(_TURNS)))]
    axis = rot[:, 2]
    while True:
        direction = rng.normal(size=3)
        t = direction / np.linalg.norm(direction) * size * rng.uniform(0.5, 3.0)
        t = np.round(t, 3)
        if np.linalg.norm(t - (t @ axis) * axis) >= 0.25 * size:
            break
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, t
    return m


def _pose_of(matrix: np.ndarray, scale: float) -> np.ndarray:
    from engine.pose import matrix_to_pose

    pose = matrix_to_pose(matrix)
    pose[:3] *= scale
    return pose


# --------------------------------------------------------------------------- one pair
def make_pair(seed: int, index: int, root: Path) -> GeneratedPair:
    """Model, place, export pair ``index`` of ``seed`` into ``root``, make its scene and truth.

    gmsh must be initialised (:func:`bench.fitgen.kernel.session`).
    """
    fit, rng = design(seed, index)
    folder = Path(root) / f"{index:03d}_{fit.family}"
    folder.mkdir(parents=True, exist_ok=True)
    unit = "mm" if rng.uniform() < 0.5 else "m"
    scale = 1.0 / UNITS[unit]
    formats = tuple(str(rng.choice(FORMATS)) for _ in range(2))
    open_mesh = tuple(bool(f != "step" and rng.uniform() < OPEN_SHARE) for f in formats)
    size = 2.0 * fit.nominal
    fixed_frame = _placement(rng, size, any_direction=bool(rng.uniform() < 0.5))
    as_assembled = bool(rng.uniform() < 0.4)
    moving_frame = fixed_frame if as_assembled else _placement(rng, size, any_direction=False)
    chord = CHORD_FRACTION * fit.min_gap
    parts = []
    for name, build, frame, fmt, opened in zip(fit.names, (fit.fixed, fit.moving),
                                               (fixed_frame, moving_frame), formats, open_mesh,
                                               strict=True):
        parts.append(export_part(build, frame, folder / f"{name}.{fmt}", fmt=fmt, unit=unit,
                                 chord_mm=chord, open_edges=OPEN_EDGES if opened else 0,
                                 rng=rng))
    assembled = fixed_frame @ np.linalg.inv(moving_frame)  # part 2's file -> part 1's file
    pose = _pose_of(assembled, scale)
    rot = fixed_frame[:3, :3]
    axis = rot @ np.array([0.0, 0.0, -1.0])
    lateral = rot @ np.asarray(fit.lateral, float)
    moving_in_fixed = parts[1].vertices @ assembled[:3, :3].T + assembled[:3, 3] * scale
    width = float(np.ptp(moving_in_fixed @ lateral))
    centre = (moving_frame[:3, :3] @ np.asarray(fit.centre, float) + moving_frame[:3, 3]) * scale
    scene = scene_new(parts[0].file, parts[1].file, folder / "scene.toml", unit=unit,
                      assembled=pose, insertion_axis=axis)

    def vectors(vs) -> tuple:
        return tuple(tuple(_clean(rot @ np.asarray(v, float))) for v in vs)

    truth = FitTruth(
        family=fit.family, description=fit.description, seed=int(seed), index=int(index),
        unit=unit, fixed_file=parts[0].file.name, moving_file=parts[1].file.name,
        formats=formats, open_mesh=open_mesh, nominal=fit.nominal * scale,
        clearance=fit.clearance * scale, radial_play=fit.radial_play * scale,
        angular_play_deg=math.degrees(fit.angular_play), min_gap=fit.min_gap * scale,
        free_translations=vectors(fit.free_translations),
        free_rotations=vectors(fit.free_rotations),
        insertion_axis=tuple(_clean(axis)), lateral=tuple(_clean(lateral)), width=width,
        centre=tuple(float(x) for x in centre), assembled_pose=tuple(float(x) for x in pose),
        chord_tolerance=chord * scale,
        triangles=(int(len(parts[0].faces)), int(len(parts[1].faces))))
    write_truth(truth, folder / TRUTH_FILE)
    return GeneratedPair(folder=folder, scene=scene, truth=truth)


def _clean(v: np.ndarray) -> list[float]:
    """Floats of a unit vector, with rounding noise of an axis-aligned turn removed."""
    out = np.asarray(v, float).copy()
    out[np.abs(out) < 1e-15] = 0.0
    return [float(x) + 0.0 for x in out]


# --------------------------------------------------------------------------- a set
def generate(count: int, seed: int, root: Path, *,
             progress: Callable[[int, str], None] | None = None) -> list[GeneratedPair]:
    """Generate ``count`` pairs of ``seed`` into the folder ``root``.

    ``root`` is made if missing and must hold no other set; a folder holding this very set
    already is reused as it is.

    ``progress(i, family)`` is called before pair ``i`` is made.

    Raises
    ------
    bench.fitgen.kernel.KernelMissing
        gmsh is not installed (the message says how to install it).
    FileExistsError
        ``root`` holds files of something else.
    """
    from bench.fitgen.truth import read_truth

    kernel.require_gmsh()
    root = Path(root)
    manifest = {"generator": GENERATOR_VERSION, "seed": int(seed), "count": int(count)}
    if root.is_dir() and any(root.iterdir()):
        found = root / MANIFEST
        if found.is_file() and json.loads(found.read_text()).get("set") == manifest:
            folders = json.loads(found.read_text())["pairs"]
            return [GeneratedPair(root / f, root / f / "scene.toml", read_truth(root / f))
                    for f in folders]
        raise FileExistsError(f"{root}: the folder holds other files; give an empty or new "
                              "folder (or the folder of this very seed and count)")
    root.mkdir(parents=True, exist_ok=True)
    pairs = []
    with kernel.session():
        for index in range(count):
            if progress is not None:
                progress(index, family_of(seed, index))
            pairs.append(make_pair(seed, index, root))
    (root / MANIFEST).write_text(json.dumps(
        {"set": manifest, "pairs": [p.folder.name for p in pairs]}, indent=1) + "\n")
    return pairs
