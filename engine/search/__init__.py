"""Where part 2 fits on part 1, and what joint each fit is: a search over all rotations.

Works on a pair's :class:`~engine.correlation.Correlator` (or a scene). Modules:

- :mod:`~engine.search.rotations`: the nested uniform rotation grid (Hopf fibration);
- :mod:`~engine.search.settings`: :class:`SearchSettings`;
- :mod:`~engine.search.scan`: per rotation, the landscape over every translation, the best
  kept (blocks of rotations, run anywhere);
- :mod:`~engine.search.work` and :mod:`~engine.search.distributed`: where blocks run (here,
  or as Dask tasks);
- :mod:`~engine.search.cluster`: poses that put part 2's surface in one place, as one fit;
- :mod:`~engine.search.refine`: down the grid's children, then a local minimisation;
- :mod:`~engine.search.joint`: the joint kind from the energy's second derivatives;
- :mod:`~engine.search.driver`: :func:`find_fits`, the stages together;
- :mod:`~engine.search.from_scene`: :func:`search_scene`.

docs/search.md describes the method and its measured cost.
"""

from engine.search.driver import Fit, SearchResult, find_fits
from engine.search.from_scene import search_scene
from engine.search.joint import KINDS, Joint, find_joint
from engine.search.rotations import RotationGrid, level_for
from engine.search.settings import SearchSettings

__all__ = [
    "KINDS",
    "Fit",
    "Joint",
    "RotationGrid",
    "SearchResult",
    "SearchSettings",
    "find_fits",
    "find_joint",
    "level_for",
    "search_scene",
]
