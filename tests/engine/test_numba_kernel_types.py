"""The per-pose numba kernel is called with the argument types it was compiled for ahead.

numba compiles one variant per argument type; a read-only or non-contiguous array is a
type of its own. ``compile_now`` compiles the kernel early on a worker thread with
``warm_arguments``; a first pose passing other types (a scene's read-only pose) would
compile it a second time, seconds more (docs/correlation.md, "Preparation and progress").
No compilation happens in this test: it compares numba's types of the arguments.
"""

from __future__ import annotations

import types

import numba
import numpy as np
import pytest

from engine.correlation import numba_kernels
from engine.correlation.correlator import Correlator
from engine.grid import Grid


def _field(shape, seed):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)


@pytest.mark.parametrize("selection", ["cube", "largest"])
def test_first_pose_has_the_types_compile_now_compiled(selection):
    g1 = Grid((0.0, 0.0, 0.0), 1.0, (12, 11, 10))
    g2 = Grid((1.0, 2.0, 0.5), 1.0, (8, 9, 7))
    d1 = types.SimpleNamespace(rho=_field(g1.shape, 1), grid=g1)
    d2 = types.SimpleNamespace(rho=_field(g2.shape, 2), grid=g2)
    corr = Correlator(d1, d2, modes=8, backend="numpy", selection=selection, use_cache=False)
    table = corr.table
    for name in ("moving", "fixed_kept", "kept", "mode_k", "mode_a"):
        array = getattr(table, name)
        if array is not None:  # as a table read back from a file may be
            array.flags.writeable = False
    rot = np.eye(3)[:, [0, 1, 2]].T  # a transposed (Fortran-ordered) view
    t = np.array([0.5, 0.25, 0.0])
    t.flags.writeable = False  # a scene's assembled pose is read-only
    kind = "cube" if selection == "cube" else "list"
    real = (numba_kernels._plain(rot), numba_kernels._plain(t),
            *numba_kernels._arguments(table))  # fmt: skip
    warm = numba_kernels.warm_arguments(kind)
    assert [numba.typeof(a) for a in real] == [numba.typeof(a) for a in warm]
    # And without the conversion the types would differ (the test can fail).
    assert numba.typeof(t) != numba.typeof(warm[1])
