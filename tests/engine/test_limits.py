"""Limits: every parameter has a range, memory and time are bounded before work starts.

Each command-line case asserts the message, exit status 2 and, where the input would have
cost minutes or gigabytes, that the refusal comes before the work: the expensive function
is replaced by one that fails the test if it is reached. The scene is the peg in hole at
grid 16, K = 8 (docs/limits.md lists every range and why).
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import types
from pathlib import Path

import numpy as np
import pytest

import engine.descriptor.compute as compute
import engine.grid
from app.cli import main
from engine.errors import Cancelled, Diverged, InputError, ResourceError
from engine.grid import Grid, grid_for_bounds
from engine.params import (
    MAX_MODES,
    SIGMA_RANGE,
    CorrelationParams,
    DescriptorParams,
    MassSpec,
    Physics,
    SimulationParams,
    check_modes,
)

ROOT = Path(__file__).resolve().parents[2]
PEG = ROOT / "assets" / "peg_in_hole"
SCENE = """name = "Peg in hole, small"
units = "mm"
assembled_pose = [0, 0, -15, 0, 0, 0]
insertion_axis = [0, 0, -1]
{top}
[descriptor]
grid = 16
padding = 6
{descriptor}
[correlation]
modes = 8
{tables}
[[part]]
name = "block"
file = "block.step"
fixed = true
[[part]]
name = "peg"
file = "peg.step"
pose = [0, 0, 5, 0, 0, 0]
{part}
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A folder with the peg's parts and a private cache shared by this module's tests."""
    path = tmp_path_factory.mktemp("limits")
    for name in ("block.step", "peg.step"):
        shutil.copy(PEG / name, path / name)
    return path


@pytest.fixture(autouse=True)
def private_cache(folder, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(folder / "cache"))
    for name in ("SKELASM_DEVICE", "SKELASM_CORRELATION_THREADS", "SKELASM_BACKEND"):
        monkeypatch.delenv(name, raising=False)


def scene(folder: Path, *, top="", descriptor="", tables="", part="", name="s.toml") -> Path:
    path = folder / name
    path.write_text(SCENE.format(top=top, descriptor=descriptor, tables=tables, part=part))
    return path


def run(capsys, *argv) -> tuple[int, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's refusals of an option's value
        code = int(exc.code or 0)
    return code, capsys.readouterr().err


def refused(capsys, *argv) -> str:
    """Run the command line; assert exit status 2 and one line of error; return it."""
    code, err = run(capsys, *argv)
    assert code == 2, err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("skelasm ")
    return err


@pytest.fixture
def no_work(monkeypatch):
    """Reaching a descriptor computation or a simulation fails the test."""

    def reached(*args, **kwargs):
        raise AssertionError("the work started before the input was refused")

    import engine.descriptor.store
    import engine.sim

    monkeypatch.setattr(compute, "compute_descriptor", reached)
    monkeypatch.setattr(engine.descriptor.store, "descriptor_and_side", reached)
    monkeypatch.setattr(engine.sim, "build_simulation", reached)


# --------------------------------------------------------------------------- descriptor
@pytest.mark.parametrize("key,value,match", [
    ("sigma", "1e-3", "sigma = 0.001 is outside its range 0.05 to 50: a smaller sigma"),
    ("sigma", "1e6", "sigma = 1e\\+06 is outside its range 0.05 to 50"),
    ("sigma", "20", "sigma = 20 is above 10, the most a descriptor on a grid allows"),
    ("penalty", "1e6", "penalty = 1e\\+06 is outside its range 0.001 to 1000: .*single"),
    ("lambda-out", "1e9", "lambda_out = 1e\\+09 is outside its range 1e-06 to 1e"),
    ("padding", "1e308", "padding = 1e\\+308 cells is outside its range 0 to 64"),
    ("spacing", "1e-9", "spacing = 1e-09 gives 3e\\+10 samples along the part's longest side "
                        "\\(30\\), above 2048: for this part the spacing must be at least 0.0146"),
])
def test_precompute_refuses_out_of_range_before_work(folder, capsys, no_work, key, value, match):
    err = refused(capsys, "precompute", folder / "peg.step", f"--{key}", value,
                  "-o", folder / "out.npz")
    assert err.count("\n") == 1
    import re

    assert re.search(match, err), err
    assert not (folder / "out.npz").exists()


@pytest.mark.parametrize("text,match", [
    ("sigma = 1e-3", "sigma = 0.001 is outside its range"),
    ("sigma = 1e6", "sigma = 1e+06 in [descriptor] is above 10"),
    ("sigma = 20", "sigma = 20 in [descriptor] is above 10"),
    ("penalty = 1e-9", "penalty = 1e-09 is outside its range"),
    ("grid = 100000000000000000000", "grid must be an integer from 4 to 2048"),
    ("padding = 1000", "padding = 1000 is outside its range 0 to 64"),
    ("modes = 1000", "modes in [correlation] must be an integer from 1 to 128"),
])
def test_scene_descriptor_ranges_name_file_and_line(folder, capsys, no_work, text, match):
    key = text.split(" =")[0]
    # K goes to [correlation] (the tables follow its `modes = 8`), the others to [descriptor]
    path = scene(folder, tables=text) if key == "modes" else scene(folder, descriptor=text)
    base = {"grid": "grid = 16\n", "padding": "padding = 6\n", "modes": "modes = 8\n"}.get(key)
    if base is not None:  # the scene's own line goes, so the key is not given twice
        path.write_text(path.read_text().replace(base, "", 1))
    err = refused(capsys, "precompute", path, "-o", folder)
    assert f"{path}:" in err and match in err, err


def test_params_ranges_hold_in_the_python_api():
    low, high = SIGMA_RANGE
    DescriptorParams(sigma=low)
    DescriptorParams(sigma=high)  # the ends are inside
    for bad in (dict(sigma=low / 2), dict(sigma=high * 2), dict(penalty=1e4),
                dict(lambda_out=1e-7), dict(grid=4096), dict(padding=65.0)):
        with pytest.raises(InputError, match="range|from 4 to"):
            DescriptorParams(**bad)
    with pytest.raises(InputError, match=f"from 1 to {MAX_MODES}"):
        check_modes(MAX_MODES + 1)
    assert CorrelationParams(modes=10_000).modes == 10_000  # the engine's "all modes"
    with pytest.raises(InputError, match="rate_hz = 1e\\+12 is outside its range 1 to 100000"):
        SimulationParams(rate_hz=1e12)
    with pytest.raises(InputError, match="mass = 1e\\+300 is outside"):
        MassSpec(mass=1e300)


def test_grid_sizes_are_counted_in_python_integers():
    lo, hi = np.zeros(3), np.full(3, 30.0)
    for kwargs, match in [(dict(spacing=1e-9), "3e\\+10 samples"),
                          (dict(spacing=1e-300), "3e\\+301 samples"),
                          (dict(samples=10**19), "above 2048"),
                          (dict(spacing=1.0, padding=1e308), "outside its range 0 to 64")]:
        with pytest.raises(InputError, match=match):
            grid_for_bounds(lo, hi, **kwargs)
    g = grid_for_bounds(lo, hi, spacing=1.0, padding=2)
    assert g.shape == (35, 35, 35)


def test_memory_refusals_exit_2_before_allocating(folder, capsys, monkeypatch, no_work):
    # a machine of 1 GiB: a 600-sample grid (600^3 samples at 128 bytes) is refused
    monkeypatch.setattr(engine.grid, "physical_memory", lambda: 2**30)
    monkeypatch.setattr(engine.grid, "available_memory", lambda: None)
    err = refused(capsys, "precompute", folder / "peg.step", "--grid", "600",
                  "-o", folder / "out.npz")
    assert "descriptor grid needs about" in err and "this machine has 1.0 GiB (at most 0.5" in err
    assert "coarser grid" in err


def test_fft_is_guarded_before_it_allocates(monkeypatch):
    from engine.correlation.spectrum import compute_spectrum

    monkeypatch.setattr(engine.grid, "physical_memory", lambda: 2**40)
    monkeypatch.setattr(engine.grid, "available_memory", lambda: 2**33)  # 8 GiB free now
    grid = Grid((0.0, 0.0, 0.0), 1.0, (8, 8, 8))
    rho = np.ones((8, 8, 8), np.complex64)
    with pytest.raises(ResourceError, match=r"the spectrum's 588\^3 FFT .*needs about 9.1 GiB.*"
                                            r"8.0 GiB of it available now.*coarser grid"):
        compute_spectrum(rho, grid, 588, moments=True, use_cache=False)


# --------------------------------------------------------------------------- cancel
#: A closed tetrahedron (vertices, faces): a mesh for the chunking and interrupt tests,
#: whose kernels are replaced.
TETRAHEDRON = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float),
               np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


def test_descriptor_chunks_are_sized_by_time(monkeypatch):
    """Cancel is polled between chunks; each chunk takes about CHUNK_SECONDS of (fake) time.

    The numba kernel is replaced by one that advances a fake clock by 1 ms per point (the
    cost near the surface at the smallest sigma allowed), so the test is deterministic.
    """
    clock = [0.0]
    chunks: list[float] = []

    def kernel(points, *args):
        cost = 1e-3 * len(points)
        clock[0] += cost
        chunks.append(cost)
        args[-1][:] = 0.0

    monkeypatch.setattr(compute, "_evaluate_numba", kernel)
    monkeypatch.setattr(compute.time, "perf_counter", lambda: clock[0])
    v, f = TETRAHEDRON
    grid = grid_for_bounds(v.min(0), v.max(0), samples=16, padding=6)
    polls: list[float] = []

    def cancel() -> bool:
        polls.append(clock[0])
        return clock[0] > 3.0

    with pytest.raises(Cancelled):
        compute.compute_descriptor(v, f, grid, backend="numba", method="tree", cancel=cancel)
    assert max(chunks) <= 0.3  # the first chunk: 256 points, then about CHUNK_SECONDS each
    assert max(np.diff(polls)) <= 0.3 and polls[-1] < 3.3


def _blocking_kernel(release: object, timed_out: list[bool]):
    """A descriptor kernel that blocks in C, where Python runs no signal handler: it waits
    on a POSIX mutex another thread holds until ``release`` is set (or 20 s pass, noted in
    ``timed_out``), and sends this process SIGINT 0.2 s after it starts waiting.
    """
    import ctypes
    import os
    import signal
    import threading

    libc = ctypes.CDLL(None)
    mutex = ctypes.create_string_buffer(128)  # pthread_mutex_t, zeroed: a default mutex
    libc.pthread_mutex_init(mutex, None)
    held = threading.Event()

    def hold() -> None:
        libc.pthread_mutex_lock(mutex)
        held.set()
        timed_out.append(not release.wait(20.0))  # type: ignore[attr-defined]
        libc.pthread_mutex_unlock(mutex)

    threading.Thread(target=hold, daemon=True).start()
    held.wait(5.0)

    def kernel(points, *args):
        threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT)).start()
        libc.pthread_mutex_lock(mutex)  # a signal does not end this wait (POSIX)
        libc.pthread_mutex_unlock(mutex)
        args[-1][:] = 0.0

    return kernel


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="POSIX mutex via glibc")
def test_ctrl_c_acts_while_a_chunk_of_points_is_still_running(monkeypatch):
    """Ctrl+C during one long compiled chunk (a point took a second on a 10^6-triangle fan
    mesh) acts while the chunk still runs: the chunk runs on a worker and the main thread's
    wait is interrupted (:func:`engine.interrupt.call_interruptibly`). Run on the main
    thread, the chunk would hold the handler until it returned, 20 s here.
    """
    import signal
    import threading

    import engine.interrupt as interrupt

    monkeypatch.setattr(interrupt, "_enabled", True)  # as the console script has it
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    release = threading.Event()
    timed_out: list[bool] = []
    monkeypatch.setattr(compute, "_evaluate_numba", _blocking_kernel(release, timed_out))
    v, f = TETRAHEDRON
    grid = grid_for_bounds(v.min(0), v.max(0), samples=8, padding=2)
    try:
        with pytest.raises(KeyboardInterrupt):
            compute.compute_descriptor(v, f, grid, backend="numba", method="tree")
        still_running = not timed_out  # the chunk has not been let go yet
        in_flight = interrupt.in_flight()
    finally:
        release.set()
        signal.signal(signal.SIGINT, previous)
    assert still_running and in_flight
    for _ in range(200):  # the abandoned chunk ends once let go
        if not interrupt.in_flight():
            break
        threading.Event().wait(0.05)
    assert not interrupt.in_flight()


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
@pytest.mark.filterwarnings("ignore:This process .* is multi-threaded:DeprecationWarning")
def test_a_forked_child_calls_directly_without_the_parents_worker(monkeypatch):
    """A child forked after the routing is on has no worker thread: it calls directly (a
    call queued for the parent's worker would wait for ever).
    """
    import multiprocessing

    import engine.interrupt as interrupt

    monkeypatch.setattr(interrupt, "_enabled", True)
    assert interrupt.call_interruptibly(sum, (1, 2)) == 3  # the parent's worker started
    context = multiprocessing.get_context("fork")
    with context.Pool(1) as pool:
        state = pool.apply_async(_routing_in_child).get(timeout=30)
    assert state == (False, True, 3)


def _routing_in_child() -> tuple[bool, bool, int]:
    import engine.interrupt as interrupt

    return interrupt._enabled, interrupt._jobs is None, interrupt.call_interruptibly(sum,
                                                                                      (1, 2))


def test_a_signal_that_leaves_a_compiled_call_running_ends_the_process_at_once(monkeypatch):
    """The console script leaves by ``os._exit`` with the signal's status while an abandoned
    call still runs (finalising PoCL under it aborted the exit); a Python caller gets the
    status back, and with nothing in flight the exit is the ordinary one.
    """
    import app.cli as cli
    import engine.interrupt as interrupt

    exits: list[int] = []
    monkeypatch.setattr(cli.os, "_exit", exits.append)
    monkeypatch.setattr(interrupt, "in_flight", lambda: True)
    assert cli._leave(143, ["precompute"]) == 143 and exits == []
    cli._leave(130, None)
    assert exits == [130]
    monkeypatch.setattr(interrupt, "in_flight", lambda: False)
    assert cli._leave(130, None) == 130 and exits == [130]


def test_a_kernels_own_error_comes_back_through_the_worker(monkeypatch):
    """An exception the chunk raises on the worker is raised in the caller, unchanged."""

    def kernel(points, *args):
        raise InputError("the kernel's own message")

    monkeypatch.setattr(compute, "_evaluate_numba", kernel)
    v, f = TETRAHEDRON
    grid = grid_for_bounds(v.min(0), v.max(0), samples=8, padding=2)
    with pytest.raises(InputError, match="the kernel's own message"):
        compute.compute_descriptor(v, f, grid, backend="numba", method="tree")


def test_opencl_chunks_grow_past_a_fixed_launch_latency(monkeypatch):
    """On a GPU a launch costs about 20 ms whatever the chunk holds; chunks sized by the rate
    of a small one used to stay small (an H100 ran a 32^3 grid as 808 chunks of ~70 points,
    16 s). Here a fake OpenCL evaluation costs 20 ms plus 1 us per point on a fake clock:
    the grid must go in a handful of launches, each short enough for cancel.
    """
    clock = [0.0]
    sizes: list[int] = []

    class Runner:
        def prepare(self, *args, **kwargs):
            def evaluate(points, mode):
                sizes.append(len(points))
                clock[0] += 0.02 + 1e-6 * len(points)
                return np.zeros((len(points), 4))

            return evaluate

    monkeypatch.setattr(compute.OpenCLDescriptor, "for_backend",
                        classmethod(lambda cls, backend: Runner()))
    monkeypatch.setattr(compute.time, "perf_counter", lambda: clock[0])
    backend = types.SimpleNamespace(name="opencl")
    v, f = TETRAHEDRON
    grid = grid_for_bounds(v.min(0), v.max(0), samples=40, padding=4)
    local = compute._localise(compute._triangles(v, f), grid.centre, grid.spacing, True)
    points = grid.points().reshape(-1, 3)
    out = compute._run(local, points, 2, compute.DescriptorParams(), backend)
    assert out.shape == (len(points), 4) and sum(sizes) == len(points)
    assert len(sizes) <= 12, f"{len(sizes)} launches for {len(points)} points"
    # every launch (latency included) stays well inside the second cancel is promised in
    assert 0.02 + 1e-6 * max(sizes) < 0.5


@pytest.mark.slow
def test_ctrl_c_stops_a_slow_descriptor_within_a_second(tmp_path):
    """A timing check (slow-marked, skipped on a loaded machine): SIGINT during the
    computation at the smallest sigma allowed ends the process within a second.
    """
    import os
    import signal
    import subprocess
    import time

    if os.getloadavg()[0] > 0.5 * (os.cpu_count() or 1):
        pytest.skip(f"machine loaded (load average {os.getloadavg()[0]:.1f})")
    env = dict(os.environ, SKELASM_CACHE=str(tmp_path / "cache"))
    # the console script, as a user runs it (main() called from Python does not route the
    # compiled calls through the worker); grid 96: about a minute on a quiet 2-core machine
    script = str(Path(sys.executable).with_name("skelasm"))
    proc = subprocess.Popen(
        [script, "precompute", str(PEG / "peg.step"), "--grid", "96",
         "--sigma", str(SIGMA_RANGE[0]), "--no-cache", "-o", str(tmp_path / "p.npz")],
        env=env, stderr=subprocess.DEVNULL, cwd=ROOT)
    time.sleep(12.0)  # imports, the STEP part, then well into the computation
    if proc.poll() is not None:
        pytest.skip(f"the computation ended (exit {proc.returncode}) before the signal: this "
                    "machine is too fast for the check")
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    assert time.monotonic() - sent < 1.0 and proc.returncode == 130


# --------------------------------------------------------------------------- simulation
@pytest.mark.parametrize("kwargs,match", [
    (dict(part="inertia = [1, 1, 1]"),
     "part inertia \\(principal moments 1, 1, 1\\) is 80.8 times smaller than the mesh's own"
     ".*kg mm\\^2.*kg m\\^2 is 1e\\+06 times smaller"),
    (dict(tables="[simulation]\nkappa = 1e300"),
     "kappa = 1e\\+300 is .* times its scale-free default"),
    (dict(tables="[effects]\ngravity = [0, 0, -1e300]"),
     "gravity in \\[effects\\] has magnitude 1e\\+300 mm/s\\^2, above 100 standard gravities"),
    (dict(part="mass = 1e300"), "part mass = 1e\\+300 is outside its range 1e-09 to 1e\\+09"),
    (dict(tables="[simulation]\nrate_hz = 1e12"), "rate_hz = 1e\\+12 is outside its "
                                                  "range 1 to 100000"),
])
def test_simulation_values_that_used_to_break(folder, capsys, kwargs, match):
    import re

    err = refused(capsys, "simulate", scene(folder, **kwargs), "--seconds", "0.2")
    assert re.search(match, err), err
    assert "math domain error" not in err


@pytest.mark.parametrize("rows,match", [
    ("0,0,0,5,0,0,0\n0.1,1e300,0,5,0,0,0", "row 3: the pose puts part 2 1e\\+300 from part 1"),
    ("0,0,0,5,0,0,0\n0.1,0,0,5,1e300,0,0", "row 3: the pose has a rotation vector of 1e\\+300"),
    ("0,0,0,5,0,0,0\n0.1,nan,0,5,0,0,0", "not finite|NaN"),
    ("-2,0,0,5,0,0,0\n-1,0,0,5,0,0,0", "its times run from -2 to -1 s; they are seconds from "
                                        "the start"),
    ("0,0,0,5,0,0,0\n1e9,0,0,5,0,0,0", "its last time \\+ 1 s = 1e\\+09 s at 1000 Hz is 1e\\+12 "
                                       "steps.*not Unix times"),
])
def test_trajectories_are_checked_before_the_run(folder, capsys, no_work, rows, match):
    import re

    traj = folder / "t.csv"
    traj.write_text("t,tx,ty,tz,rx,ry,rz\n" + rows + "\n")
    err = refused(capsys, "simulate", scene(folder), "--trajectory", traj, "--log",
                  folder / "log.csv")
    assert re.search(match, err), err
    assert "--seconds must be positive" not in err
    assert not (folder / "log.csv").exists()


@pytest.mark.parametrize("argv,match", [
    (["--modes", "0"], "--modes K = 0 must be an integer from 1 to 128"),
    (["--modes", "1000"], "--modes K = 1000 must be an integer from 1 to 128"),
    (["--seconds", "-1"], "argument --seconds: must be positive"),
    (["--seconds", "inf"], "argument --seconds: must be a finite number"),
    (["--seconds", "1e9"], "--seconds = 1e\\+09 s at 1000 Hz is 1e\\+12 steps"),
    (["--start", "0", "0", "nan", "0", "0", "0"], "argument --start: must be a finite number"),
])
def test_simulate_options_have_ranges(folder, capsys, no_work, argv, match):
    import re

    err = refused(capsys, "simulate", scene(folder), *argv)
    assert re.search(match, err), err


def test_negative_numbers_in_any_float_notation(folder, capsys):
    from app.cli import build_parser

    args = build_parser().parse_args(
        ["simulate", "s.toml", "--start", "0", "-0.3", "38.8", "-4.2e-18", "0.0685", "3.14"])
    assert args.start == [0.0, -0.3, 38.8, -4.2e-18, 0.0685, 3.14]
    args = build_parser().parse_args(
        ["evaluate", "s.toml", "--pose", "-1E+2", "-.5", "-1_0.5", "-0", "-3.", "-2e0"])
    assert args.pose == [-100.0, -0.5, -10.5, 0.0, -3.0, -2.0]
    with pytest.raises(SystemExit):  # an unknown option is still an option
        build_parser().parse_args(["simulate", "s.toml", "-e5"])


def test_landscape_rotation_nan_is_refused(folder, capsys, no_work):
    err = refused(capsys, "landscape", scene(folder), "--rotation", "nan", "0", "0",
                  "-o", folder / "l.png")
    assert "argument --rotation: must be a finite number, got nan" in err


def test_deep_toml_names_the_file(folder, capsys):
    path = folder / "deep.toml"
    path.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    err = refused(capsys, "simulate", path)
    assert f"{path}: nested too deeply to read" in err


@pytest.mark.parametrize("name,value,match", [
    ("SKELASM_CORRELATION_THREADS", "abc", "SKELASM_CORRELATION_THREADS = 'abc' is not a "
                                           "positive whole number"),
    ("SKELASM_CORRELATION_THREADS", "0", "is not a positive whole number"),
    ("SKELASM_DEVICE", "bogus", "SKELASM_DEVICE = 'bogus' picks no usable OpenCL device"),
    ("SKELASM_BACKEND", "cuda", "SKELASM_BACKEND = 'cuda': unknown backend"),
])
def test_bad_environment_variables_are_named(folder, capsys, monkeypatch, no_work, name, value,
                                             match):
    monkeypatch.setenv(name, value)
    err = refused(capsys, "simulate", scene(folder))
    assert match in err, err


def test_gui_without_its_extra_names_the_extra(monkeypatch, capsys):
    import app.gui.app

    def missing(*args, **kwargs):
        raise ModuleNotFoundError("No module named 'PySide6'", name="PySide6")

    monkeypatch.setattr(app.gui.app, "run", missing)
    code, err = run(capsys, "gui", "--quit-after", "0")
    assert code == 1 and "Traceback" not in err  # an installation problem, not an input
    assert "needs the `gui` extra" in err and "pip install 'skelasm[gui]'" in err
    assert "PySide6 is not installed" in err


def test_poses_out_of_reach_of_the_parts_warn(folder, capsys):
    # units = "m" over poses written in millimetres: the peg starts 5 m from a 40 mm block
    path = scene(folder, name="metres.toml")
    path.write_text(path.read_text().replace('units = "mm"', 'units = "m"'))
    from engine.scene import load_scene, load_scene_parts

    parts = load_scene_parts(load_scene(path))
    warning = parts[1].warnings[-1]
    assert "part 2 starts 5 m from part 1 and is assembled 15 m from it" in warning
    assert "the energy is 0" in warning and "units" in warning
    # the same scene in millimetres gives no such warning
    parts = load_scene_parts(load_scene(scene(folder)))
    assert not any("never meet" in w for p in parts for w in p.warnings)


def test_poses_a_sliver_of_the_parts_warn(folder):
    # units = "um" over poses written in millimetres: the STEP parts, converted from their
    # millimetres, are 40,000 um; the poses move the peg by 5 and 15 um
    path = scene(folder, name="micrometres.toml")
    path.write_text(path.read_text().replace('units = "mm"', 'units = "um"'))
    from engine.scene import load_scene, load_scene_parts

    parts = load_scene_parts(load_scene(path))
    warning = parts[1].warnings[-1]
    assert "part 2 starts 5 um from part 1 and is assembled 15 um from it" in warning
    assert "the parts overlap" in warning and "units" in warning
    # the commands print it as a warning, the loader's repairs as notes
    from engine.scene.parts import say_notes

    said = say_notes([warning, "welded 3 duplicate vertices"])
    assert said[0].startswith("warning: units: ") and "part 2 starts 5 um" in said[0]
    assert said[1] == "note: welded 3 duplicate vertices"
    # the same scene in millimetres gives no such warning
    parts = load_scene_parts(load_scene(scene(folder)))
    assert not any("overlap wherever" in w for p in parts for w in p.warnings)


# --------------------------------------------------------------------------- divergence
def _free_body_sim(k_lin: float, start=(0.0, 0.0, 0.0, 0, 0, 0)):
    from engine.params import Effects
    from engine.sim import NullField, RigidBody, Simulation

    physics = Physics(k_lin=k_lin, c_lin=0.0, k_rot=1.0, c_rot=0.0, length=10.0)
    body = RigidBody(1.0, np.eye(3), np.zeros(3))
    sim = Simulation(body, physics, Effects(guidance="none", damping=False), NullField(),
                     np.asarray(start, float), dt=1e-3)
    sim.set_proxy(np.array([1.0, 0, 0, 0, 0, 0]))
    return sim


def test_integrator_stops_on_divergence_with_the_cause():
    sim = _free_body_sim(k_lin=1e9)  # sqrt(k/m) dt = 31.6: far beyond the limit of 2
    with pytest.raises(Diverged, match="the simulation diverged at t = .* Likely cause: the "
                                       "coupling stiffness 1e\\+09 for mass 1 is too stiff"):
        sim.run(200)
    assert sim.steps < 20  # caught while every number was finite, long before overflow
    assert all(math.isfinite(v) for v in sim.state.velocity)
    stable = _free_body_sim(k_lin=100.0)
    stable.run(2000)  # a sound coupling runs on
    assert stable.steps == 2000


def test_proxy_poses_out_of_reach_are_refused():
    sim = _free_body_sim(k_lin=100.0)
    for pose, match in [([1e300, 0, 0, 0, 0, 0], "1e\\+300 from part 1"),
                        ([0, 0, 0, 1e300, 0, 0], "rotation vector of 1e\\+300"),
                        ([0, 0, float("nan"), 0, 0, 0], "not finite")]:
        with pytest.raises(InputError, match=match):
            sim.set_proxy(np.array(pose))


def test_argument_types_read_python_floats():
    from app.commands.arguments import finite_float, positive_float

    assert finite_float("-4.2e-18") == -4.2e-18 and finite_float("1_000.5") == 1000.5
    for bad in ("nan", "inf", "-inf", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            finite_float(bad)
    with pytest.raises(argparse.ArgumentTypeError, match="positive"):
        positive_float("0")


def test_scene_fft_is_refused_before_its_descriptors(folder, monkeypatch, no_work):
    """A grid of 300 passes the descriptor check; its 588^3 FFT is refused before work."""
    from engine.pose import rotation_matrix
    from engine.runtime import open_scene
    from engine.sim.build import SceneModel

    path = scene(folder, name="grid300.toml")
    path.write_text(path.read_text().replace("grid = 16", "grid = 300"))
    model = SceneModel(open_scene(path))
    monkeypatch.setattr(engine.grid, "physical_memory", lambda: 16 * 2**30)
    monkeypatch.setattr(engine.grid, "available_memory", lambda: None)
    effects = model.config.effects
    with pytest.raises(ResourceError, match=r"the correlation's 588\^3 FFT \(6 arrays of "
                                            r"588\^3 complex64\) needs about 9.1 GiB"):
        model.field(effects, 1.0, rotation_matrix(np.zeros(3)))
