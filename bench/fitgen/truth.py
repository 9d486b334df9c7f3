"""The ground truth of a generated fit: what a benchmark needs to judge a seat, as JSON.

One small JSON file (``fit.json``) beside each generated scene holds a :class:`FitTruth`:
lengths in the scene's unit, directions as unit vectors in part 1's frame (the fixed part's
file frame), angles in degrees, the assembled pose as the scene stores it (part 2's file
frame in part 1's, turning about part 2's file origin).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

#: Name of the truth file beside each scene.
TRUTH_FILE = "fit.json"
#: Bumped when what the generator models changes (the same seed then gives other pairs).
GENERATOR_VERSION = 2


@dataclass(frozen=True)
class FitTruth:
    """The ground truth of one generated pair.

    Attributes
    ----------
    family, description : str
        The family (a key of ``bench.fitgen.families.FAMILIES``) and one line of sizes.
    seed, index : int
        Which draw made it.
    unit : str
        The scene's unit; every length below is in it.
    fixed_file, moving_file : str
        The part files, relative to the pair's folder.
    formats : (str, str)
        ``step``, ``stl`` or ``obj`` for each part.
    open_mesh : (bool, bool)
        Whether each part's mesh was deliberately left open (T-junctions).
    nominal, clearance, radial_play : float
        Nominal size, diametral clearance of the main fit, largest sideways move of part 2
        from its centred seat before contact.
    angular_play_deg : float
        Largest turn of part 2 from its seat about a constrained axis (small-angle estimate).
    min_gap : float
        Smallest gap anywhere in the fit at the centred seat (a key's side, a flank).
    free_translations, free_rotations : tuple of (3,) tuple
        Unit vectors (part 1's frame) of the directions the fit leaves free.
    insertion_axis, lateral : (3,) tuple
        The direction part 2 travels to seat, and the constrained direction across it that
        the benchmark's misaim offsets the proxy along (unit vectors, part 1's frame).
    width : float
        Part 2's extent along ``lateral`` (the benchmark's width).
    centre : (3,) tuple
        Part 2's fit centre in its own file's frame: on the fit's axis, halfway along the
        engagement (the misaim turns about it; position errors are measured there).
    assembled_pose : (6,) tuple
        Part 2 in part 1's frame when seated (the scene's ``assembled_pose``).
    chord_tolerance : float
        Tessellation chord error the mesh files were written with, below every gap of the
        fit; a STEP part must be tessellated at least this finely or the parts touch.
    triangles : (int, int)
        Triangles in each part's mesh as written (STEP: as tessellated at chord_tolerance).
    generator : int
        :data:`GENERATOR_VERSION`.
    """

    family: str
    description: str
    seed: int
    index: int
    unit: str
    fixed_file: str
    moving_file: str
    formats: tuple[str, str]
    open_mesh: tuple[bool, bool]
    nominal: float
    clearance: float
    radial_play: float
    angular_play_deg: float
    min_gap: float
    free_translations: tuple[tuple[float, float, float], ...]
    free_rotations: tuple[tuple[float, float, float], ...]
    insertion_axis: tuple[float, float, float]
    lateral: tuple[float, float, float]
    width: float
    centre: tuple[float, float, float]
    assembled_pose: tuple[float, ...]
    chord_tolerance: float
    triangles: tuple[int, int]
    generator: int = GENERATOR_VERSION

    @property
    def free_names(self) -> str:
        """The free directions in words: ``t`` translations and ``r`` rotations, or none."""
        parts = ([f"t{len(self.free_translations)}"] if self.free_translations else []) + \
            ([f"r{len(self.free_rotations)}"] if self.free_rotations else [])
        return " ".join(parts) or "none"


def _tuples(value):
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    return value


def write_truth(truth: FitTruth, path: Path) -> None:
    """Write ``truth`` as JSON: sorted keys, round-trip floats (same truth, same bytes)."""
    data = asdict(truth)
    Path(path).write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


def read_truth(path: Path) -> FitTruth:
    """The truth in a ``fit.json`` (a folder is read as its ``fit.json``)."""
    p = Path(path)
    if p.is_dir():
        p = p / TRUTH_FILE
    data = json.loads(p.read_text())
    names = {f.name for f in fields(FitTruth)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(f"{p}: unknown keys {sorted(unknown)}; regenerate the pair")
    return FitTruth(**{key: _tuples(value) for key, value in data.items()})


def unit_vectors(vectors) -> np.ndarray:
    """(k, 3) float64 of a sequence of 3-vectors (k may be 0)."""
    return np.asarray(vectors, dtype=np.float64).reshape(-1, 3)
