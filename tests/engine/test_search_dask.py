"""The search's blocks on a Dask cluster give the in-process result exactly."""

import numpy as np
import pytest
from gaussian_pair import pair

from engine.correlation import Correlator
from engine.search import SearchSettings, find_fits

distributed = pytest.importorskip("distributed", reason="Dask is not installed")


@pytest.fixture(scope="module")
def corr():
    fixed, moving = pair()
    return Correlator(fixed, moving, modes=8, backend="numpy", use_cache=False)


@pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::ResourceWarning",
                            "ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_two_process_local_cluster_gives_the_in_process_fits(corr):
    from engine.runtime import BackgroundWork
    from engine.search.distributed import DaskWork

    settings = SearchSettings(level=0, scan_modes=8, chunk=10, clusters=3, top=3,
                              refine_levels=1)
    here = find_fits(corr, settings)
    work = DaskWork.connect(workers=2)
    try:
        assert isinstance(work, BackgroundWork)  # the project's verbs for background work
        assert work.workers == 2
        there = find_fits(corr, settings, work=work)
    finally:
        work.shutdown()
    assert there.candidates == here.candidates and len(there.fits) == len(here.fits) >= 1
    for a, b in zip(there.fits, here.fits, strict=True):
        assert np.array_equal(a.rotation, b.rotation)
        assert np.array_equal(a.translation, b.translation)
        assert a.energy == b.energy and a.cluster_size == b.cluster_size
        assert a.joint.kind == b.joint.kind


def test_no_scheduler_at_an_address_is_one_clear_error():
    from engine.errors import InputError
    from engine.search.distributed import DaskWork

    with pytest.raises(InputError, match="no Dask scheduler answers at"):
        DaskWork.connect("tcp://127.0.0.1:9")
