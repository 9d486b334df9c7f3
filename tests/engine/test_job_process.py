"""The job process: a pair's truncations, landscapes and rotation caches computed apart.

Every result is checked against the in-process function on the same spectra (the same
arrays, bit for bit); the channel's failure modes (cancel, an error in the child, a child
that died, a parent that died) against what the module promises.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from gaussian_pair import pair

from engine.correlation import Correlator, LandscapeError, compute_landscape
from engine.correlation.tables import truncate
from engine.errors import Cancelled
from engine.pose import rotation_matrix
from engine.runtime.job_process import JobProcess, RemoteSpectral, read_arrays, write_arrays

pytest.importorskip("numba")

ROT = rotation_matrix(np.array([0.3, -0.2, 0.4]))


@pytest.fixture(scope="module")
def correlator():
    d1, d2 = pair()
    return Correlator(d1, d2, modes=8, backend="numba", use_cache=False)


@pytest.fixture
def jobs():
    process = JobProcess()
    yield process
    process.close()


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_arrays_travel_through_a_file_and_come_back_writable(tmp_path):
    obj = {"a": np.arange(10, dtype=np.float32), "b": (np.ones((3, 4), np.complex64) * 2j),
           "empty": np.zeros(0), "strided": np.arange(12.0)[::2], "n": 3}
    path = str(tmp_path / "t")
    head, layout = write_arrays(obj, path)
    assert all(start % 64 == 0 for start, _ in layout)
    back = read_arrays(path, head, layout)
    assert not os.path.exists(path)  # unlinked once read
    for key in ("a", "b", "empty", "strided"):
        np.testing.assert_array_equal(back[key], obj[key])
        assert back[key].dtype == obj[key].dtype
    assert back["n"] == 3
    assert back["a"].flags.writeable and back["a"].flags.c_contiguous
    back["a"][0] = 99.0  # its own memory
    assert obj["a"][0] == 0.0


def test_results_equal_the_in_process_functions(correlator, jobs):
    remote = jobs.spectral(correlator.spectra)
    spectra = correlator.spectra
    table = remote.truncate(12)
    local = truncate(spectra, 12)
    assert table.modes == local.modes == 12 and table.radius == local.radius
    for name in ("kept", "fixed_kept", "moving"):
        np.testing.assert_array_equal(getattr(table, name), getattr(local, name))
        assert getattr(table, name).flags.writeable
    np.testing.assert_array_equal(table.geometry.centre_moving, local.geometry.centre_moving)
    land = remote.landscape(ROT, 10, forces=True, table=None, progress=None, cancel=None)
    expect = compute_landscape(spectra, ROT, 10, forces=True)
    np.testing.assert_array_equal(land.energy, expect.energy)
    np.testing.assert_array_equal(land.force, expect.force)
    for a, b in zip(land.translations, expect.translations, strict=True):
        np.testing.assert_array_equal(a, b)
    assert land.modes == 10
    assert os.listdir(jobs.folder) == []  # every transfer file unlinked


def test_an_offloaded_correlator_gives_the_same_poses(correlator, jobs):
    d1, d2 = pair()
    corr = Correlator(d1, d2, modes=8, backend="numba", use_cache=False)
    corr.spectral = jobs.spectral(corr.spectra)
    other = corr.with_modes(10)
    assert isinstance(other.spectral, RemoteSpectral) and other.spectral is corr.spectral
    t = np.array([0.4, 0.1, -0.2])
    for k, c in ((10, other), (8, corr)):
        expect = Correlator(d1, d2, modes=k, backend="numba", use_cache=False).evaluate(ROT, t)
        got = c.evaluate(ROT, t)
        assert got.energy == expect.energy
        np.testing.assert_array_equal(got.torque, expect.torque)
    land = other.landscape(ROT, forces=False)
    np.testing.assert_array_equal(
        land.energy, compute_landscape(corr.spectra, ROT, 10, forces=False).energy)
    assert corr.spectral.here == 0  # nothing was computed here


def test_progress_errors_and_cancel_cross_the_boundary(correlator, jobs):
    remote = jobs.spectral(correlator.spectra)
    seen: list[float] = []
    remote.landscape(ROT, 8, forces=True, table=None, progress=seen.append, cancel=None)
    assert seen and seen[-1] == 1.0 and seen == sorted(seen)
    # the child's error arrives as its own type and message
    with pytest.raises(LandscapeError, match="rotation"):
        remote.landscape(np.full((3, 3), np.nan), 8, forces=False, table=None,
                         progress=None, cancel=None)
    # cancelled before it is sent: nothing is sent
    with pytest.raises(Cancelled):
        remote.landscape(ROT, 8, forces=True, table=None, progress=None,
                         cancel=lambda: True)
    # cancelled once the child started it: the child is told (or had finished, and the
    # answer is dropped); either way the caller gets Cancelled and the child serves on
    started: list[float] = []
    with pytest.raises(Cancelled):
        remote.landscape(ROT, 12, forces=True, table=None, progress=started.append,
                         cancel=lambda: bool(started))
    assert started
    table = remote.truncate(6)
    np.testing.assert_array_equal(table.moving, truncate(correlator.spectra, 6).moving)
    deadline = time.monotonic() + 10
    while os.listdir(jobs.folder) and time.monotonic() < deadline:
        time.sleep(0.05)  # the cancelled reply's file is dropped when it arrives
    assert os.listdir(jobs.folder) == []


def test_a_job_process_that_died_leaves_the_work_here(correlator, jobs):
    remote = jobs.spectral(correlator.spectra)
    os.kill(jobs.pid, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while jobs.alive and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not jobs.alive and "ended" in jobs.problem
    table = remote.truncate(9)
    np.testing.assert_array_equal(table.moving, truncate(correlator.spectra, 9).moving)
    land = remote.landscape(ROT, 9, forces=False, table=None, progress=None, cancel=None)
    np.testing.assert_array_equal(
        land.energy, compute_landscape(correlator.spectra, ROT, 9, forces=False).energy)
    assert remote.here == 2


def test_a_command_that_cannot_start_reports_why():
    jobs = JobProcess(command=["/nonexistent/python-for-skelasm"])
    try:
        assert not jobs.alive and "could not be started" in jobs.problem
    finally:
        jobs.close()
    assert not os.path.exists(jobs.folder)


def test_the_job_process_ends_with_its_parent(tmp_path):
    """A parent killed outright: the child sees end-of-file and ends, removing its folder."""
    program = textwrap.dedent("""
        import sys, time
        from engine.runtime.job_process import JobProcess
        jobs = JobProcess()
        print(jobs.pid, jobs.folder, flush=True)
        time.sleep(600)
    """)
    parent = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE,
                              text=True)
    try:
        pid_text, folder = parent.stdout.readline().split()
        child = int(pid_text)
        time.sleep(0.5)
        assert alive(child) and os.path.isdir(folder)
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        deadline = time.monotonic() + 20
        while alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(child)
        deadline = time.monotonic() + 5
        while os.path.isdir(folder) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not os.path.isdir(folder)
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()


def test_no_room_for_the_transfer_files_leaves_the_work_here(correlator, jobs):
    remote = jobs.spectral(correlator.spectra)
    shutil.rmtree(jobs.folder)  # as a full /dev/shm would: the child cannot write its answer
    table = remote.truncate(7)
    np.testing.assert_array_equal(table.moving, truncate(correlator.spectra, 7).moving)
    assert remote.here == 1 and jobs.alive  # the child serves on; this call was done here


def test_transfer_files_go_to_shared_memory_only_where_it_has_room(monkeypatch):
    from engine.runtime import job_process

    monkeypatch.setattr(job_process, "SHM_FREE", 1 << 62)  # more than any /dev/shm has
    folder = job_process.transfer_folder()
    try:
        assert not folder.startswith("/dev/shm/") and os.path.isdir(folder)
    finally:
        os.rmdir(folder)
