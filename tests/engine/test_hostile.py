"""A hostile battery: small bad or extreme inputs in the ten areas of reliability issue 33.

Each case is a row of a table: what it feeds, and what must happen. ``refuse`` rows must
end in a user error (an ``InputError``, ``ValueError`` or ``OSError`` subclass, or exit 2
on the command line) whose one-line message contains the expected words: a clear error.
``accept`` rows must succeed with the stated result: no silent wrong answer. Any other
exception is a traceback; a case that runs past its alarm (60 s) is a hang; the ``end``
rows check that outputs survive (a wrong result there is lost data). :func:`outcome` sorts
every run into one of :data:`OUTCOMES`, and each row must have its kind's (a clear error
or the right result). Test ids start with the area and the expected outcome; the counts
by area and outcome: ``python tests/engine/test_hostile.py`` (a Markdown table).

Areas: ``mesh`` (1, welding and load cost), ``read`` (2, bounded reads), ``end`` (3,
endings and the cache's own files), ``jump`` (4, device jumps), ``cap`` (5, the cache cap),
``range`` (6, option ranges), ``msg`` (7, messages naming file and line), ``name`` (8,
output names), ``silent`` (9, silently accepted input), ``json`` (10, ``--json`` errors).
"""

from __future__ import annotations

import json
import os
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from app.cli import build_parser, main
from bench.loading import fan_cylinder, write_stl
from engine import cache, loading
from engine.errors import InputError
from engine.files import TEMP_PREFIX, check_output, input_problem, read_input
from engine.loading import load_part
from engine.recording import COLUMNS, RecordingWriter, load_recording
from engine.scene import load_scene
from engine.scene.reader import locate_late_error

ROOT = Path(__file__).resolve().parents[2]
SLIDE = ROOT / "assets" / "dovetail" / "slide.step"  # 28 triangles: fast
HANG_SECONDS = 60  # a hang guard, not a timing: every case takes well under a second


@dataclass(frozen=True)
class Case:
    """One row: an id, what to run in a fresh folder, and the expected outcome.

    ``run(folder)`` returns a value for ``check`` (accept rows) or raises. ``expect`` is
    ``"refuse"`` (a user error containing every word of ``words``) or ``"accept"``
    (``check(value)`` is true).
    """

    id: str
    run: Callable[[Path], object]
    expect: str
    words: tuple[str, ...] = ()
    check: Callable[[object], bool] | None = None


CASES: list[Case] = []


def refuse(area: str, name: str, run: Callable[[Path], object], *words: str) -> None:
    CASES.append(Case(f"{area}-refuse-{name}", run, "refuse", words))


def accept(area: str, name: str, run: Callable[[Path], object],
           check: Callable[[object], bool]) -> None:  # fmt: skip
    CASES.append(Case(f"{area}-accept-{name}", run, "accept", check=check))


# --------------------------------------------------------------------------- helpers
TETRA = np.array([[[0, 0, 0], [0, 1, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0], [0, 0, 1]],
                  [[0, 0, 0], [0, 0, 1], [0, 1, 0]], [[1, 0, 0], [0, 1, 0], [0, 0, 1]]],
                 dtype=np.float32)  # a closed, outward tetrahedron soup (4, 3, 3)


def _soup_volume(soup: np.ndarray) -> float:
    """Signed volume of a closed (m, 3, 3) triangle soup, in float64."""
    a, b, c = (np.asarray(soup, np.float64)[:, k] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def stl(folder: Path, soup: np.ndarray, name: str = "part.stl") -> Path:
    path = folder / name
    write_stl(path, np.asarray(soup, dtype=np.float32))
    return path


def write(folder: Path, name: str, data: str | bytes) -> Path:
    path = folder / name
    if isinstance(data, str):
        path.write_text(data, encoding="utf-8")
    else:
        path.write_bytes(data)
    return path


def run_cli(*argv: object) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``skelasm ARGV`` in this process."""
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse
            code = int(exc.code or 0)
    return code, out.getvalue(), err.getvalue()


class CliError(InputError):
    """A command-line refusal seen from the battery: exit 2 and its one-line message."""


class TracebackSeen(Exception):
    """A command printed a traceback."""


class NotOneLine(Exception):
    """A command refused with exit 2 but not in one line."""


class UnclearExit(Exception):
    """A command ended with a status other than 0 or 2 (an error it did not name as bad input)."""


def cli(*argv: object) -> Callable[[Path], object]:
    """Run ``skelasm ARGV`` in the case's folder; exit 2 becomes a CliError of its stderr."""

    def run(folder: Path) -> object:
        here = os.getcwd()
        os.chdir(folder)
        try:
            code, out, err = run_cli(*argv)
        finally:
            os.chdir(here)
        if "Traceback" in err:
            raise TracebackSeen(err)
        if code == 2:
            lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("note:")
                     and not ln.startswith("warning:")]
            if len(lines) != 1:
                raise NotOneLine(err)
            raise CliError(lines[0])
        if code != 0:  # exit 1: an error the command did not recognise as the user's
            raise UnclearExit(f"exit {code}: {err.strip()}")
        return code, out, err

    return run


# --------------------------------------------------------------------------- 1 meshes
def _fan(folder: Path, copies: int, jitter: float = 0.0) -> object:
    """A cone: a fan of ``copies`` triangles around one apex stored ``copies`` times."""
    angle = 2 * np.pi * np.arange(copies + 1) / copies
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros(copies + 1)], axis=1)
    apex = np.zeros((copies, 3)) + [0, 0, 1]
    apex += np.random.default_rng(copies).uniform(-jitter, jitter, apex.shape)
    base_centre = np.zeros((copies, 3))
    side = np.stack([apex, ring[:-1], ring[1:]], axis=1)
    base = np.stack([base_centre, ring[1:], ring[:-1]], axis=1)
    part = load_part(stl(folder, np.concatenate([side, base])))
    stats = dict(loading.WELD_STATS)
    return part, stats


for copies in (3, 8, 64, 500, 2000, 8000, 20000):
    for jitter in (0.0, 1e-9):
        accept("mesh", f"fan-{copies}-jitter-{jitter:g}",
               lambda f, c=copies, j=jitter: _fan(f, c, j),
               lambda r, c=copies: (len(r[0].vertices) == c + 2
                                    and r[1]["pairs"] <= 13 * r[1]["cells"]
                                    and abs(r[0].volume - c / 6 * np.sin(2 * np.pi / c))
                                    < 1e-6))
for size in (1_000, 4_000, 16_000, 40_000):
    accept("mesh", f"cylinder-{size}", lambda f, s=size: load_part(stl(f, fan_cylinder(s))),
           lambda p: abs(p.volume - np.pi * 100 * 20) < 0.01 * np.pi * 100 * 20)
for copies in (2, 10, 1000, 10000):
    accept("mesh", f"copies-of-one-triangle-{copies}",
           lambda f, c=copies: load_part(stl(f, np.repeat(TETRA[:1], c, axis=0))),
           lambda p, c=copies: p.triangles == 1 and (
               c == 1 or any(f"{c - 1} duplicate" in w for w in p.warnings)))
for copies in (2, 50, 3000):
    accept("mesh", f"tetra-doubled-{copies}",
           lambda f, c=copies: load_part(stl(f, np.tile(TETRA, (c, 1, 1)))),
           lambda p: p.triangles == 4 and abs(p.volume - 1 / 6) < 1e-6
           and any("duplicate" in w for w in p.warnings))
for scale, where in ((1e-6, 1.0), (1.0, 1e4), (1e3, 0.0), (1e-3, 0.0), (1.0, -5e3)):
    accept("mesh", f"tetra-scale-{scale:g}-at-{where:g}",
           lambda f, s=scale, w=where: load_part(stl(f, TETRA.astype(np.float64) * s + w)),
           lambda p, s=scale, w=where: abs(p.volume - _soup_volume(
               (TETRA.astype(np.float64) * s + w).astype(np.float32))) < 1e-6 * s**3)
for name, data in [
    ("empty", b""), ("random-bytes", bytes(range(256)) * 20), ("header-only", b"\0" * 84),
    ("count-too-large", b"\0" * 80 + (10**6).to_bytes(4, "little") + b"\0" * 100),
    ("truncated", b"\0" * 80 + (4).to_bytes(4, "little") + b"\0" * 150),
    ("text-not-stl", b"hello world\n" * 100),
    ("solid-without-facets", b"solid x\n" + b"junk\n" * 1000),
    ("nan-coordinates", None), ("inf-coordinates", None), ("all-degenerate", None),
]:
    if data is None:
        continue
    refuse("mesh", f"stl-{name}", lambda f, d=data: load_part(write(f, "bad.stl", d)),
           "bad.stl")
refuse("mesh", "stl-nan-coordinates",
       lambda f: load_part(stl(f, np.where(TETRA == 1, np.nan, TETRA))), "non-finite")
refuse("mesh", "stl-inf-coordinates",
       lambda f: load_part(stl(f, np.where(TETRA == 1, np.inf, TETRA))), "non-finite")
refuse("mesh", "stl-all-degenerate",
       lambda f: load_part(stl(f, np.zeros((10, 3, 3)))), "part.stl", "no usable triangles")
refuse("mesh", "stl-all-collinear",
       lambda f: load_part(stl(f, np.tile([[0, 0, 0], [1, 1, 1], [2, 2, 2]], (10, 1, 1)))),
       "part.stl", "no usable triangles")
refuse("mesh", "stl-over-the-triangle-bound",
       lambda f: load_part(write(f, "big.stl", b"\0" * 80
                                 + (loading.MAX_MESH_TRIANGLES + 1).to_bytes(4, "little")
                                 + b"\0" * 50 * 0)), "big.stl")
for name, text in [("no-faces", "v 0 0 0\nv 1 0 0\n"), ("bad-index", "v 0 0 0\nf 1 2 9\n"),
                   ("empty-obj", "# nothing\n"), ("words", "hello\nworld\n")]:
    refuse("mesh", f"obj-{name}", lambda f, t=text: load_part(write(f, "bad.obj", t)),
           "bad.obj")
for name, text in [("ply-garbage", "ply\nformat nonsense\n"), ("off-garbage", "OFF\n3 1\n")]:
    suffix = name.split("-")[0]
    refuse("mesh", name, lambda f, t=text, s=suffix: load_part(write(f, f"bad.{s}", t)),
           f"bad.{suffix}")
refuse("mesh", "unknown-suffix", lambda f: load_part(write(f, "part.xyz", "x")), ".xyz")
refuse("mesh", "step-not-step", lambda f: load_part(write(f, "p.step", "hello")), "p.step")
refuse("mesh", "step-empty-header",
       lambda f: load_part(write(f, "p.step", "ISO-10303-21;\nEND-ISO-10303-21;\n")), "p.step")


# --------------------------------------------------------------------------- 2 bounded reads
def _fifo(folder: Path, name: str) -> Path:
    path = folder / name
    os.mkfifo(path)
    return path


def _loop(folder: Path, name: str) -> Path:
    path = folder / name
    path.symlink_to(path)
    return path


def _dangling(folder: Path, name: str) -> Path:
    path = folder / name
    path.symlink_to(folder / "nowhere" / name)
    return path


def _folder(folder: Path, name: str) -> Path:
    path = folder / name
    path.mkdir()
    return path


READERS: dict[str, tuple[str, Callable[[Path], object], str]] = {
    "scene": (".toml", load_scene, "scene file"),
    "trajectory": (".csv", lambda p: __import__("engine.devices", fromlist=["x"])
                   .read_trajectory(p), "trajectory file"),
    "recording": (".csv", load_recording, "recording"),
    "part-stl": (".stl", load_part, "part file"),
    "part-obj": (".obj", load_part, "part file"),
    "part-step": (".step", load_part, "part file"),
}
SPECIALS: dict[str, tuple[Callable[[Path, str], Path], tuple[str, ...]]] = {
    "dev-zero": (lambda f, n: Path("/dev/zero"), ("/dev/zero", "not a regular file")),
    "dev-urandom": (lambda f, n: Path("/dev/urandom"), ("/dev/urandom", "not a regular file")),
    "fifo": (_fifo, ("FIFO",)),
    "symlink-loop": (_loop, ("loop of symbolic links",)),
    "dangling-link": (_dangling, ("link to a missing file",)),
    "folder": (_folder, ("is a folder",)),
}
for reader, (suffix, read, _what) in READERS.items():
    for special, (make, words) in SPECIALS.items():
        if special.startswith("dev-") and reader.startswith("part-"):
            # /dev/zero has no part suffix: the suffix is refused first, which is fine too
            refuse("read", f"{reader}-{special}",
                   lambda f, r=read, m=make: r(m(f, "x")), "part file type")
            continue
        refuse("read", f"{reader}-{special}",
               lambda f, r=read, m=make, s=suffix: r(m(f, f"in{s}")), *words)


def _oversized(limit_name: str, reader: Callable[[Path], object], suffix: str):
    def run(folder: Path) -> object:
        import engine.devices
        import engine.files
        import engine.loading
        import engine.recording
        import engine.scene.reader

        path = write(folder, f"big{suffix}", b"x" * 2048)
        saved = {}
        for module in (engine.files, engine.devices, engine.loading, engine.recording,
                       engine.scene.reader):
            if hasattr(module, limit_name):
                saved[module] = getattr(module, limit_name)
                setattr(module, limit_name, 1024)
        try:
            return reader(path)
        finally:
            for module, value in saved.items():
                setattr(module, limit_name, value)

    return run


refuse("read", "scene-oversized", _oversized("MAX_SCENE_BYTES", load_scene, ".toml"),
       "big.toml", "more than")
refuse("read", "trajectory-oversized",
       _oversized("MAX_TRAJECTORY_BYTES", READERS["trajectory"][1], ".csv"), "big.csv",
       "more than")
refuse("read", "recording-oversized",
       _oversized("MAX_TRAJECTORY_BYTES", load_recording, ".csv"), "big.csv", "more than")
refuse("read", "part-oversized", _oversized("MAX_PART_BYTES", load_part, ".stl"), "big.stl",
       "more than")
for name, data, words in [
    ("trajectory-binary", bytes(range(256)) * 4, ("traj.csv:", "not UTF-8")),
    ("trajectory-latin1", "t,tx,ty,tz,rx,ry,rz\n0,0,0,0,0,0,0\n# caf\xe9\n".encode("latin-1"),
     ("traj.csv:3", "not UTF-8")),
    ("trajectory-nul", b"\0" * 1000, ("traj.csv",)),
]:
    refuse("read", name, lambda f, d=data: READERS["trajectory"][1](write(f, "traj.csv", d)),
           *words)
for name, data in [("scene-binary", bytes(range(256)) * 4),
                   ("scene-latin1", 'name = "caf\xe9"\n'.encode("latin-1"))]:
    refuse("read", name, lambda f, d=data: load_scene(write(f, "s.toml", d)), "s.toml",
           "not UTF-8")
refuse("read", "scene-missing", lambda f: load_scene(f / "none.toml"), "no such scene file")
refuse("read", "trajectory-missing", lambda f: READERS["trajectory"][1](f / "none.csv"),
       "no such trajectory file")
refuse("read", "part-missing", lambda f: load_part(f / "none.stl"), "no such file")
refuse("read", "part-path-through-a-file",
       lambda f: load_part(write(f, "plain", "x") / "p.stl"), "p.stl")
accept("read", "input-problem-regular-file",
       lambda f: input_problem(write(f, "ok.csv", "x"), what="t", limit=10), lambda r: r is None)
accept("read", "read-input-exact-limit",
       lambda f: read_input(write(f, "ok.csv", "x" * 10), what="t", limit=10),
       lambda r: r == b"x" * 10)
refuse("read", "read-input-one-past-limit",
       lambda f: read_input(write(f, "ok.csv", "x" * 11), what="t", limit=10), "ok.csv")
refuse("read", "cli-evaluate-dev-zero", cli("evaluate", "/dev/zero"), "/dev/zero")
refuse("read", "cli-simulate-dev-urandom", cli("simulate", "/dev/urandom"), "/dev/urandom")
refuse("read", "cli-precompute-dev-zero-toml", cli("precompute", "/dev/zero"), "/dev/zero")
refuse("read", "cli-trajectory-dev-zero",
       cli("simulate", ROOT / "assets" / "peg_in_hole" / "scene.toml", "--trajectory",
           "/dev/zero"), "/dev/zero")


# --------------------------------------------------------------------------- 3 endings
class _Stop:
    """A raw file whose ``n``-th write stores ``keep`` of the bytes, then raises."""

    def __init__(self, fh, n: int, keep: float):
        self.fh, self.n, self.keep = fh, n, keep

    def write(self, data):
        self.n -= 1
        if self.n == 0:
            self.fh.write(bytes(data[: int(len(data) * self.keep)]))
            raise KeyboardInterrupt
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)


def _interrupted_log(folder: Path, suffix: str, rows: int, at: int, keep: float):
    path = folder / f"log{suffix}"
    writer = RecordingWriter(path)
    data = np.arange(rows * len(COLUMNS), dtype=float).reshape(rows, len(COLUMNS)) / 7.0
    data[:, 0] = np.arange(rows)
    writer._fh = _Stop(writer._fh, at, keep)
    interrupted = False
    try:
        writer.append(data)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        writer._fh = writer._fh.fh  # one signal: the writes after it go through
    writer.close()
    assert interrupted, "the case never reached the write it stops"
    kept = load_recording(path)
    leftovers = [p for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX)]
    return kept, data, writer.count, leftovers


for suffix in (".csv", ".npz"):
    for rows, at in ((300, 1), (600, 1), (600, 2), (1000, 2), (1000, 3), (257, 1)):
        for keep in (0.0, 0.5, 0.999):
            accept("end", f"log{suffix}-{rows}-rows-stopped-at-write-{at}-kept-{keep:g}",
                   lambda f, s=suffix, r=rows, a=at, k=keep: _interrupted_log(f, s, r, a, k),
                   lambda res: (len(res[0]) == res[2] and res[3] == []
                                and np.array_equal(res[0], res[1][:res[2]])))


def _stale(folder: Path, name: str, pid: int) -> Path:
    path = folder / f"{TEMP_PREFIX}{name}.{pid}.abcd1234.partial"
    path.write_text("torn")
    return path


def _dead_pid() -> int:
    import subprocess

    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    return int(done.stdout)


accept("end", "stale-partial-of-a-dead-writer-removed",
       lambda f: (check_output(f / "out.csv"), _stale(f, "out.csv", _dead_pid()).exists(),
                  check_output(f / "out.csv"),
                  [p.name for p in f.iterdir() if p.name.startswith(TEMP_PREFIX)]),
       lambda r: r[3] == [])
accept("end", "partial-of-a-live-writer-kept",
       lambda f: (_stale(f, "out.csv", os.getpid()), check_output(f / "out.csv"),
                  [p.name for p in f.iterdir() if p.name.startswith(TEMP_PREFIX)]),
       lambda r: len(r[2]) == 1)
accept("end", "partial-of-another-file-kept",
       lambda f: (_stale(f, "mine.csv", _dead_pid()), check_output(f / "out.csv"),
                  [p.name for p in f.iterdir() if p.name.startswith(TEMP_PREFIX)]),
       lambda r: len(r[2]) == 1)


def _evict_with(folder: Path, names: list[str]) -> list[bool]:
    import time as _time

    saved = os.environ.get("SKELASM_CACHE")
    os.environ["SKELASM_CACHE"] = str(folder)
    try:
        cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(3)})
        past = _time.time() - 2 * cache.STALE_SECONDS
        paths = [folder / "descriptor" / n for n in names]
        for p in paths:
            p.write_bytes(b"user")
            os.utime(p, (past, past))
        cache.evict()
        return [p.exists() for p in paths]
    finally:
        if saved is None:
            os.environ.pop("SKELASM_CACHE", None)
        else:
            os.environ["SKELASM_CACHE"] = saved


for user_name in (".skelasm-notes.partial", ".skelasm-thesis.tex.partial",
                  ".skelasm-a.b.c.partial", "tmp-report.tmp.npz", "results.npz",
                  ".skelasm-" + "A" * 64 + ".npz.x.partial", "notes.partial",
                  ".skelasm-" + "a" * 63 + ".npz.x.partial"):
    accept("end", f"eviction-keeps-user-file-{user_name}",
           lambda f, n=user_name: _evict_with(f, [n]), lambda r: r == [True])
accept("end", "eviction-removes-its-own-stale-temporary",
       lambda f: _evict_with(f, [".skelasm-" + "a" * 64 + ".npz.1234.abcdefgh.partial"]),
       lambda r: r == [False])


# --------------------------------------------------------------------------- 4 device jumps
def _jump(folder: Path, far: list[float], gap_steps: int) -> object:
    import trimesh

    from engine.devices import Device, DeviceCapabilities
    from engine.params import Effects, SimConfig
    from engine.runtime.loop import EngineLoop
    from engine.sim import NullField, RigidBody, Simulation, resolve_physics

    class Peer(Device):
        capabilities = DeviceCapabilities("udp", dof=6)

        def __init__(self, poses):
            self.poses = list(poses)

        def read_pose(self, time_s):
            return self.poses.pop(0) if self.poses else None

    mesh = trimesh.creation.box(extents=(10.0, 10.0, 30.0))
    config = SimConfig(effects=Effects())
    phys = resolve_physics(config, np.asarray(mesh.vertices), np.asarray(mesh.faces))
    sim = Simulation(RigidBody(phys.mass, phys.inertia, phys.centre), phys, config.effects,
                     NullField(), np.zeros(6), dt=config.simulation.dt)
    poses = [np.zeros(6)] * gap_steps + [np.asarray(far, float)] + [None] * 5 + [np.zeros(6)]
    loop = EngineLoop(sim, device=Peer(poses), realtime=False)
    loop.run(max_steps=gap_steps + 400)
    return sim.part_pose(), loop.poll_events()


for far in ([1980, 0, 0, 0, 0, 0], [0, 1980, 0, 0, 0, 0], [0, 0, -1980, 0, 0, 0],
            [500, 500, 500, 0, 0, 0], [0, 0, 0, 3.1, 0, 0], [0, 0, 0, 0, -3.1, 0],
            [0, 0, 0, 1.0, 1.0, 1.0], [1000, 0, 0, 0, 0, 3.0], [29000, 0, 0, 0, 0, 0],
            [30, 0, 0, 0, 0, 0]):
    for gap in (1, 300):
        accept("jump", f"peer-{'-'.join(f'{x:g}' for x in far)}-after-{gap}-steps",
               lambda f, p=far, g=gap: _jump(f, p, g),
               lambda r: (np.all(np.isfinite(r[0]))
                          and not any(type(e).__name__ == "ErrorEvent" for e in r[1])))
accept("jump", "peer-jump-said-once-naming-the-device-in-part-lengths",
       lambda f: [e.message for e in _jump(f, [0, 1980, 0, 0, 0, 0], 300)[1]
                  if type(e).__name__ == "DeviceEvent"],
       lambda r: len(r) == 1 and r[0].startswith("udp's pose jumped 1980 (")
       and "part lengths) in one reading" in r[0])
refuse("jump", "peer-out-of-reach-dropped-with-a-word",
       lambda f: (_ for _ in ()).throw(InputError(next(
           e.message for e in _jump(f, [1e9, 0, 0, 0, 0, 0], 1)[1]
           if type(e).__name__ == "ErrorEvent"))), "udp", "pose dropped")


# --------------------------------------------------------------------------- 5 cache cap
def _cap(value: str) -> int:
    saved = os.environ.get("SKELASM_CACHE_MAX_GB")
    os.environ["SKELASM_CACHE_MAX_GB"] = value
    try:
        return cache.max_bytes()
    finally:
        if saved is None:
            os.environ.pop("SKELASM_CACHE_MAX_GB", None)
        else:
            os.environ["SKELASM_CACHE_MAX_GB"] = saved


for value, expected in (("0", 0), ("1", 2**30), ("0.5", 2**29), ("1e300", 2**70),
                        ("1.7e308", 2**70), ("1e30", 2**70), ("1e12", 10**12 * 2**30),
                        ("1e13", 2**70),
                        ("2e-9", 2), ("  3  ", 3 * 2**30)):
    accept("cap", f"value-{value.strip()}", lambda f, v=value: _cap(v),
           lambda r, e=expected: r == e)
for value in ("inf", "-inf", "nan", "-1", "-1e300", "abc", "1GB", "0x10", "1e400"):
    refuse("cap", f"value-{value}", lambda f, v=value: _cap(v), "SKELASM_CACHE_MAX_GB")


# --------------------------------------------------------------------------- 6 ranges
def _parse(*argv: str) -> Callable[[Path], object]:
    def run(folder: Path) -> object:
        import contextlib
        import io

        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                return build_parser().parse_args(list(argv))
        except SystemExit as exc:
            lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
            if exc.code != 2 or len(lines) != 1:
                raise NotOneLine(err.getvalue()) from None
            raise CliError(lines[0]) from None

    return run


SCENE = str(ROOT / "assets" / "peg_in_hole" / "scene.toml")
for value in ("0", "-1", "-100", "1e12", "100001", "1.5", "abc", "nan", "inf", "1e400"):
    refuse("range", f"evaluate-repeat-{value}", _parse("evaluate", SCENE, "--repeat", value),
           "--repeat")
for value, n in (("1", 1), ("100", 100), ("1e3", 1000), ("100000", 100000)):
    accept("range", f"evaluate-repeat-{value}", _parse("evaluate", SCENE, "--repeat", value),
           lambda a, n=n: a.repeat == n)
for value in ("-1", "0", "1", "2", "3", "2049", "1e9", "4.5", "x"):
    refuse("range", f"precompute-grid-{value}", _parse("precompute", "p.stl", "--grid", value),
           "--grid")
for value in ("4", "16", "2048"):
    accept("range", f"precompute-grid-{value}", _parse("precompute", "p.stl", "--grid", value),
           lambda a, v=value: a.grid == int(v))
for value in ("nan", "inf", "-inf", "x"):
    for option in ("--sigma", "--penalty", "--spacing", "--tolerance"):
        refuse("range", f"precompute{option}-{value}",
               _parse("precompute", "p.stl", option, value), option)
for option in ("--sigma", "--penalty", "--spacing", "--tolerance"):
    for value in ("0", "-1"):
        refuse("range", f"precompute{option}-{value}",
               _parse("precompute", "p.stl", option, value), option)
for rotation in ("1e6", "-1e6", "1e300", "10001", "-1e5"):
    refuse("range", f"evaluate-pose-rotation-{rotation}",
           cli("evaluate", SCENE, "--pose", 0, 0, 0, rotation, 0, 0), "--pose", "rotation")
    refuse("range", f"landscape-rotation-{rotation}",
           cli("landscape", SCENE, "--rotation", rotation, 0, 0, "-o", "l.png"), "--rotation")
for value in ("nan", "inf", "-inf"):
    refuse("range", f"evaluate-pose-{value}",
           _parse("evaluate", SCENE, "--pose", "0", "0", "0", value, "0", "0"), "--pose")
    refuse("range", f"simulate-start-{value}",
           _parse("simulate", SCENE, "--start", value, "0", "0", "0", "0", "0"), "--start")
    refuse("range", f"simulate-seconds-{value}",
           _parse("simulate", SCENE, "--seconds", value), "--seconds")
for value in ("0", "-1", "-1e-9"):
    refuse("range", f"simulate-seconds-{value}",
           _parse("simulate", SCENE, "--seconds", value), "--seconds")
for value in ("0", "-3", "129", "1000"):
    refuse("range", f"evaluate-modes-{value}", cli("evaluate", SCENE, "--modes", value),
           "modes")
    refuse("range", f"simulate-modes-{value}", cli("simulate", SCENE, "--modes", value),
           "modes")


# --------------------------------------------------------------------------- 7 messages
PARTS_SCENE = """\
units = "mm"
assembled_pose = [0, 0, -1, 0, 0, 0]
[descriptor]
grid = 8
[[part]]
file = "a.stl"
fixed = true
[[part]]
file = "b.stl"
pose = [0, 0, 3, 0, 0, 0]
"""


def _scene(folder: Path, text: str, name: str = "s.toml") -> Path:
    stl(folder, TETRA * 2.0, "a.stl")
    stl(folder, TETRA, "b.stl")
    return write(folder, name, text)


def _line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


SCENE_EDITS: list[tuple[str, str, str, tuple[str, ...]]] = [
    # (case, old, new, words); the line is the new text's
    ("pose-rotation-1e300", "pose = [0, 0, 3, 0, 0, 0]", "pose = [0, 0, 3, 1e300, 0, 0]",
     ("rotation vector",)),
    ("pose-rotation-1e5", "pose = [0, 0, 3, 0, 0, 0]", "pose = [0, 0, 3, 0, 1e5, 0]",
     ("rotation vector",)),
    ("pose-translation-1e300", "pose = [0, 0, 3, 0, 0, 0]", "pose = [1e300, 0, 3, 0, 0, 0]",
     ("from the origin",)),
    ("assembled-rotation-1e300", "assembled_pose = [0, 0, -1, 0, 0, 0]",
     "assembled_pose = [0, 0, -1, 0, 0, 1e300]", ("rotation vector",)),
    ("assembled-translation-1e30", "assembled_pose = [0, 0, -1, 0, 0, 0]",
     "assembled_pose = [1e30, 0, -1, 0, 0, 0]", ("from the origin",)),
    ("pose-five-numbers", "pose = [0, 0, 3, 0, 0, 0]", "pose = [0, 0, 3, 0, 0]", ("pose",)),
    ("pose-string", "pose = [0, 0, 3, 0, 0, 0]", 'pose = "up"', ("pose",)),
    ("grid-2", "grid = 8", "grid = 2", ("grid",)),
    ("grid-negative", "grid = 8", "grid = -8", ("grid",)),
    ("grid-float", "grid = 8", "grid = 8.5", ("grid",)),
    ("grid-and-spacing", "grid = 8", "grid = 8\nspacing = 0.1", ("spacing",)),
    ("spacing-zero", "grid = 8", "spacing = 0", ("spacing",)),
    ("spacing-negative", "grid = 8", "spacing = -1", ("spacing",)),
    ("unknown-key", "grid = 8", "grid = 8\ngird = 9", ("gird",)),
    ("units-unknown", 'units = "mm"', 'units = "furlong"', ("units",)),
    ("units-number", 'units = "mm"', "units = 3", ("units",)),
    ("part-file-missing", 'file = "b.stl"', 'file = "nothing.stl"', ("nothing.stl",)),
    ("part-fixed-string", "fixed = true", 'fixed = "yes"', ("fixed",)),
    ("bad-toml", "grid = 8", "grid = = 8", ("not valid TOML",)),
    ("mass-negative", "pose = [0, 0, 3, 0, 0, 0]", "pose = [0, 0, 3, 0, 0, 0]\nmass = -1",
     ("mass",)),
    ("mass-1e300", "pose = [0, 0, 3, 0, 0, 0]", "pose = [0, 0, 3, 0, 0, 0]\nmass = 1e300",
     ("mass",)),
    ("inertia-two", "pose = [0, 0, 3, 0, 0, 0]",
     "pose = [0, 0, 3, 0, 0, 0]\ninertia = [1, 2]", ("inertia",)),
    ("kappa-negative", "grid = 8", "grid = 8\n[simulation]\nkappa = -1", ("kappa",)),
    ("kappa-string", "grid = 8", 'grid = 8\n[simulation]\nkappa = "big"', ("kappa",)),
    ("rate-zero", "grid = 8", "grid = 8\n[simulation]\nrate_hz = 0", ("rate_hz",)),
    ("rate-1e9", "grid = 8", "grid = 8\n[simulation]\nrate_hz = 1e9", ("rate_hz",)),
    ("modes-zero", "grid = 8", "grid = 8\n[correlation]\nmodes = 0", ("modes",)),
    ("modes-1000", "grid = 8", "grid = 8\n[correlation]\nmodes = 1000", ("modes",)),
    ("sigma-1e-9", "grid = 8", "grid = 8\nsigma = 1e-9", ("sigma",)),
    ("sigma-1e9", "grid = 8", "grid = 8\nsigma = 1e9", ("sigma",)),
    ("padding-1e308", "grid = 8", "grid = 8\npadding = 1e308", ("padding",)),
    ("udp-port-99999", "grid = 8", 'grid = 8\n[device]\nkind = "udp"\nport = 99999',
     ("port",)),
    ("udp-port-negative", "grid = 8", 'grid = 8\n[device]\nkind = "udp"\nport = -5',
     ("port",)),
    ("device-unknown", "grid = 8", 'grid = 8\n[device]\nkind = "joystick"', ("kind",)),
    ("gravity-huge", "grid = 8", "grid = 8\n[effects]\ngravity = true\ngravity_direction = "
     "[0, 0, 0]", ("gravity",)),
]
for case, old, new, words in SCENE_EDITS:
    text = PARTS_SCENE.replace(old, new)
    assert text != PARTS_SCENE, case
    line = _line_of(text, new.splitlines()[-1])

    def run_scene(folder: Path, t: str = text) -> object:
        return load_scene(_scene(folder, t))

    refuse("msg", f"scene-{case}", run_scene, f"s.toml:{line}", *words)
refuse("msg", "scene-nested-5000", lambda f: load_scene(_scene(f, PARTS_SCENE.replace(
    "grid = 8", "grid = 8\ndeep = " + "[" * 5000 + "]" * 5000))), "s.toml")
accept("msg", "scene-byte-order-mark",
       lambda f: load_scene(_scene(f, "\ufeff" + PARTS_SCENE)), lambda s: s.units == "mm")
accept("msg", "scene-crlf-lines",
       lambda f: load_scene(_scene(f, PARTS_SCENE.replace("\n", "\r\n"))),
       lambda s: s.units == "mm")
LATE = [
    ("kappa", "grid = 8\n[simulation]\nkappa = 1e300", "kappa = 1e+300 is far above",
     "kappa = 1e300"),
    ("inertia", "grid = 8", "part inertia (principal moments 1e-12)", None),
    ("proxy-pose", "grid = 8", "proxy pose puts part 2 1e+12 from part 1", None),
    ("spacing", "grid = 8", "spacing = 1e-09 gives 4e+10 samples", None),
]
for name, edit, message, needle in LATE:
    text = PARTS_SCENE.replace("grid = 8", edit)
    if name == "inertia":
        text = text.replace("pose = [0, 0, 3, 0, 0, 0]",
                            "pose = [0, 0, 3, 0, 0, 0]\ninertia = [1e-12, 1e-12, 1e-12]")
        needle = "inertia = "
    if name == "proxy-pose":
        needle = "pose = [0, 0, 3"
    if name == "spacing":
        text = text.replace("grid = 8", "spacing = 1e-9")
        needle = "spacing = 1e-9"
    line = _line_of(text, needle)

    def late(folder: Path, t: str = text, m: str = message) -> object:
        located = locate_late_error(_scene(folder, t), m)
        raise located if located is not None else AssertionError("not located")

    refuse("msg", f"late-{name}", late, f"s.toml:{line}")
accept("msg", "late-error-of-a-key-the-scene-does-not-set",
       lambda f: locate_late_error(_scene(f, PARTS_SCENE), "kappa = 1e+300 is far above"),
       lambda r: r is None)
refuse("msg", "cli-late-inertia",
       lambda f: cli("simulate", _scene(f, PARTS_SCENE.replace(
           "pose = [0, 0, 3, 0, 0, 0]",
           "pose = [0, 0, 3, 0, 0, 0]\ninertia = [1e-12, 1e-12, 1e-12]")), "--seconds", "0.01",
           "--guidance", "none")(f), "s.toml:11", "inertia")
refuse("msg", "part-is-a-folder", lambda f: load_part(_folder(f, "p.stl")), "is a folder")
refuse("msg", "part-is-a-fifo", lambda f: load_part(_fifo(f, "p.stl")), "FIFO")
refuse("msg", "part-symlink-loop", lambda f: load_part(_loop(f, "p.stl")), "loop")
refuse("msg", "cli-option-error-one-line", cli("evaluate"), "scene")
refuse("msg", "cli-unknown-option-one-line", cli("evaluate", SCENE, "--bogus"), "--bogus")
refuse("msg", "cli-no-command-one-line", cli(), "COMMAND")


# --------------------------------------------------------------------------- 8 output names
def _precompute(*extra: object) -> Callable[[Path], object]:
    return cli("precompute", SLIDE, "--grid", "4", "--padding", "0", "--backend", "numba",
               *extra)


for name in ("out", "out.NPZ", "out.npz.txt", "/dev/null", "out.csv"):
    refuse("name", f"precompute-o-{name.replace('/', '_')}", _precompute("-o", name, "--force"),
           "ends in .npz")
accept("name", "precompute-o-folder-writes-inside",
       lambda f: (_folder(f, "descr"), _precompute("-o", "descr")(f),
                  sorted(p.name for p in (f / "descr").iterdir()),
                  sorted(p.name for p in f.iterdir())),
       lambda r: r[2] == ["slide.npz"] and "descr.npz" not in r[3])
accept("name", "precompute-o-npz-as-given",
       lambda f: (_precompute("-o", "mine.npz")(f), sorted(p.name for p in f.iterdir())),
       lambda r: r[1] == ["mine.npz"])
for name in ("peg.step", "scene", "scene.tml", "a.csv"):
    refuse("name", f"scene-new-o-{name}",
           cli("scene", "new", SLIDE, SLIDE, "-o", name, "--force"), "ends in .toml")
refuse("name", "precompute-o-an-input", _precompute("-o", SLIDE, "--force"), "ends in .npz")
refuse("name", "landscape-o-unknown-format", cli("landscape", SCENE, "-o", "l.xyz"), "l.xyz")


# --------------------------------------------------------------------------- 9 silent input
for face in ("f 0 1 2", "f 1 2 0", "f 0/1 2/2 3/3", "f 1//1 0//1 2//1", "f -0 1 2",
             "f 1 2 00", "f 1 2 3 0", "  f\t0 1 2"):
    refuse("silent", f"obj-face-{face.strip().replace(' ', '_').replace('/', '-')}",
           lambda f, fc=face: load_part(write(f, "z.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                              "v 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\n"
                                              f"{fc}\n")), "z.obj:8", "vertex 0")
accept("silent", "obj-negative-indices-are-legal",
       lambda f: load_part(write(f, "n.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                 "f -4 -2 -3\nf -4 -3 -1\nf -4 -1 -2\nf -3 -2 -1\n")),
       lambda p: p.triangles == 4 and abs(p.volume - 1 / 6) < 1e-9)
accept("silent", "obj-texture-index-0-not-a-vertex",
       lambda f: load_part(write(f, "t.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                 "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")),
       lambda p: p.triangles == 4)
for copies in (10, 1000):
    accept("silent", f"identical-triangles-{copies}-have-a-word",
           lambda f, c=copies: load_part(stl(f, np.repeat(TETRA[:1], c, axis=0))),
           lambda p, c=copies: any(f"dropped {c - 1} duplicate" in w for w in p.warnings))
accept("silent", "evaluate-says-what-was-repaired",
       lambda f: cli("evaluate", _scene(f, PARTS_SCENE.replace('file = "b.stl"',
                                                               'file = "dup.stl"')),
                     "--repeat", "1", "--json")(
           stl(f, np.tile(TETRA, (3, 1, 1)), "dup.stl").parent),
       lambda r: r[0] == 0 and any("duplicate" in n for n in json.loads(r[1])["notes"]))


# --------------------------------------------------------------------------- 10 --json
def _json_error(*argv: object) -> Callable[[Path], object]:
    def run(folder: Path) -> object:
        here = os.getcwd()
        os.chdir(folder)
        try:
            code, out, err = run_cli(*argv)
        finally:
            os.chdir(here)
        return code, out, err

    return run


def _is_error_object(r: object, file_end: str | None) -> bool:
    code, out, err = r  # type: ignore[misc]
    if code == 0 or "Traceback" in err:
        return False
    record = json.loads(out.strip().splitlines()[-1])
    if set(record) != {"error", "file", "line"} or record["error"] not in err:
        return False
    return file_end is None or str(record["file"] or "").endswith(file_end)


for argv, file_end in [
    (("evaluate", "missing.toml", "--json"), "missing.toml"),
    (("evaluate", "/dev/zero", "--json"), "/dev/zero"),
    (("simulate", "missing.toml", "--json"), "missing.toml"),
    (("precompute", "missing.stl", "--json"), "missing.stl"),
    (("precompute", "bad.stl", "--json"), "bad.stl"),
    (("precompute", SLIDE, "--grid", "2", "--json"), None),
    (("evaluate", SCENE, "--repeat", "0", "--json"), None),
    (("evaluate", SCENE, "--modes", "0", "--json"), None),
    (("evaluate", SCENE, "--pose", 0, 0, 0, "1e6", 0, 0, "--json"), None),
    (("simulate", SCENE, "--seconds", "-1", "--json"), None),
    (("simulate", SCENE, "--trajectory", "/dev/zero", "--json"), "/dev/zero"),
    (("precompute", SLIDE, "-o", "x.txt", "--json"), "x.txt"),
    (("evaluate", "--json"), None),
    (("simulate", "s.toml", "--json"), "s.toml"),
    (("evaluate", "s.toml", "--json"), "s.toml"),
]:
    def run_json(folder: Path, a: tuple = argv) -> object:
        write(folder, "bad.stl", b"garbage" * 20)
        _scene(folder, PARTS_SCENE.replace("grid = 8", "grid = 2"))
        return _json_error(*a)(folder)

    name = "-".join(str(a).split("/")[-1] for a in argv[:2])
    accept("json", f"{name}-{len(CASES)}", run_json, lambda r, e=file_end: _is_error_object(r, e))
accept("json", "scene-error-carries-its-line",
       lambda f: (_scene(f, PARTS_SCENE.replace("grid = 8", "grid = 2")),
                  _json_error("evaluate", "s.toml", "--json")(f))[1],
       lambda r: json.loads(r[1])["line"] == 4)


# --------------------------------------------------------------------------- 7 again: part files
def _scene_with_part(folder: Path, make: Callable[[Path, str], Path]) -> object:
    """A scene whose moving part is what ``make`` puts at b2.stl (or the path it returns)."""
    made = make(folder, "b2.stl")
    return load_scene(_scene(folder, PARTS_SCENE.replace('file = "b.stl"', f'file = "{made}"')))


PART_LINE = _line_of(PARTS_SCENE, 'file = "b.stl"')
for special, (make, words) in SPECIALS.items():
    refuse("msg", f"scene-part-file-{special}",
           lambda f, m=make: _scene_with_part(f, m), f"s.toml:{PART_LINE}", *words)
    refuse("msg", f"scene-new-part-{special}",
           lambda f, m=make: cli("scene", "new", SLIDE, m(f, "b2.stl"), "-o", "new.toml")(f),
           *words)
refuse("msg", "scene-part-file-missing-is-not-found",
       lambda f: _scene_with_part(f, lambda g, n: g / "absent.stl"), f"s.toml:{PART_LINE}",
       "not found")
refuse("msg", "cli-precompute-part-link-loop",
       lambda f: cli("precompute", _loop(f, "p.stl"))(f), "p.stl", "loop of symbolic links")
refuse("msg", "cli-evaluate-scene-link-loop",
       lambda f: cli("evaluate", _loop(f, "s.toml"))(f), "s.toml", "loop of symbolic links")
refuse("name", "precompute-o-a-link-loop",
       lambda f: _precompute("-o", _loop(f, "o.npz"), "--force")(f), "o.npz",
       "not a regular file")
refuse("name", "precompute-o-a-link-loop-without-force",
       lambda f: _precompute("-o", _loop(f, "o.npz"))(f), "o.npz", "exists")


# --------------------------------------------------------------------------- 1 again: Ctrl+C
SWALLOWER = """\
import os, signal, time
try:  # what trimesh does around its optional imports
    os.kill(os.getpid(), signal.{sig})
    time.sleep(0.05)
except BaseException:
    pass
"""


def _swallowing_import(folder: Path, sig: str, held: bool) -> str:
    """Import a module that signals itself and swallows what the signal raises.

    Returns "interrupted" when the signal's exception reached the caller, else "swallowed".
    SIGTERM gets the command line's handler (an exception, like Ctrl+C).
    """
    import importlib

    name = f"_hostile_swallower_{sig.lower()}_{int(held)}"
    write(folder, f"{name}.py", SWALLOWER.format(sig=sig))
    sys.path.insert(0, str(folder))
    number = getattr(signal, sig)
    previous = signal.signal(number, signal.default_int_handler)
    try:
        if held:
            loading.import_holding_signals(name)
        else:
            importlib.import_module(name)
        return "swallowed"
    except KeyboardInterrupt:
        return "interrupted"
    finally:
        signal.signal(number, previous)
        sys.path.remove(str(folder))
        sys.modules.pop(name, None)


for sig in ("SIGINT", "SIGTERM", "SIGHUP"):
    accept("mesh", f"ctrl-c-in-a-swallowing-import-acts-{sig}",
           lambda f, g=sig: _swallowing_import(f, g, held=True), lambda r: r == "interrupted")
accept("mesh", "ctrl-c-in-a-plain-import-is-swallowed-the-control",
       lambda f: _swallowing_import(f, "SIGINT", held=False), lambda r: r == "swallowed")
accept("mesh", "trimesh-is-imported-holding-signals",
       lambda f: (loading.import_trimesh(), loading.HELD_SIGNALS),
       lambda r: r[0].__name__ == "trimesh" and "SIGINT" in r[1])



def _held_part_of_the_trimesh_import(folder: Path) -> list[str]:
    """Which of trimesh's slow dependencies a fresh interpreter has imported when the import
    with signals held starts (trimesh itself must not be among them).
    """
    import subprocess

    probe = ("import sys, engine.loading as L\n"
             "real = L.import_holding_signals\n"
             "def spy(name):\n"
             "    print(','.join(m for m in L.TRIMESH_DEPENDENCIES + ('trimesh',)"
             " if m in sys.modules))\n"
             "    return real(name)\n"
             "L.import_holding_signals = spy\n"
             "L.import_trimesh()\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         cwd=ROOT, timeout=120, check=True)
    return out.stdout.strip().split(",")


accept("mesh", "trimesh-slow-dependencies-are-imported-before-signals-are-held",
       _held_part_of_the_trimesh_import,
       lambda r: "trimesh" not in r and {"scipy.spatial", "PIL.Image", "rtree.index"} <= set(r))


class _FirstChunk(Exception):
    """Stops a descriptor computation at its first chunk (carrying the chunk's size)."""


def _first_chunk(folder: Path, subdivisions: int) -> tuple[int, int]:
    """(points in the descriptor's first chunk, triangles) for an icosphere."""
    import trimesh

    from engine.descriptor import compute
    from engine.grid import grid_for_bounds

    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    grid = grid_for_bounds(mesh.bounds[0], mesh.bounds[1], samples=8, padding=0.5)

    def first(points, *args):
        raise _FirstChunk(len(points))

    saved = compute._evaluate_numba
    compute._evaluate_numba = first
    try:
        compute.compute_descriptor(np.asarray(mesh.vertices), np.asarray(mesh.faces), grid,
                                   backend="numba")
    except _FirstChunk as stop:
        return int(stop.args[0]), len(mesh.faces)
    finally:
        compute._evaluate_numba = saved
    raise AssertionError("no chunk was computed")


for subdivisions, most in ((2, 256), (6, 62), (7, 16)):
    # 320, 81,920 and 327,680 triangles: a point's cost grows with the triangles near it,
    # and Ctrl+C waits for the chunk in hand (a 10^6-triangle fan took a second a point)
    accept("mesh", f"ctrl-c-first-descriptor-chunk-icosphere-{subdivisions}",
           lambda f, s=subdivisions: _first_chunk(f, s), lambda r, n=most: 4 <= r[0] <= n)


# --------------------------------------------------------------------------- the runner
class Hang(BaseException):
    """A case ran past its alarm (a BaseException: no refusal may swallow it)."""


def _alarm(signum, frame):
    raise Hang(f"a hang: over {HANG_SECONDS} s")


#: The outcome each kind of row must have, and every outcome a case can have.
EXPECTED = {"refuse": "clear error", "accept": "right result"}
OUTCOMES = ("clear error", "right result", "traceback", "hang", "silent wrong result",
            "lost data", "unclear error", "wrong refusal")
#: Areas whose accept rows check that outputs survive: a wrong result there is lost data.
KEEPING_AREAS = ("end",)


def outcome(case: Case, folder: Path) -> tuple[str, str]:
    """(class, detail) of running ``case`` in ``folder``: one of :data:`OUTCOMES`.

    A refusal is a *clear error* when it is a user error (``InputError``, ``ValueError``,
    ``OSError``; exit 2 on the command line) of one line holding the expected words, an
    *unclear error* when it is not one line or lacks them (or the command exited 1), and a
    *silent wrong result* when the input was accepted. An accept row is a *right result*
    when its check holds; otherwise *lost data* in the areas that check kept outputs and a
    *silent wrong result* elsewhere, or a *wrong refusal* when a good input was refused.
    Any other exception is a *traceback*; running past the alarm is a *hang*.
    """
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_SECONDS)
    try:
        try:
            value = case.run(folder)
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
    except Hang as exc:
        return "hang", str(exc)
    except TracebackSeen as exc:
        return "traceback", str(exc)[-400:]
    except (NotOneLine, UnclearExit) as exc:
        return "unclear error", str(exc)[:400]
    except (InputError, ValueError, OSError) as exc:
        message = str(exc)
        if case.expect == "accept":
            return "wrong refusal", message
        if "\n" in message.strip():
            return "unclear error", f"not one line: {message!r}"
        missing = [w for w in case.words if w not in message]
        if missing:
            return "unclear error", f"{missing} not in {message!r}"
        return "clear error", message
    except Exception as exc:  # noqa: BLE001 - any other exception is what a user would see
        import traceback

        return "traceback", "".join(traceback.format_exception(exc))[-600:]
    if case.expect == "refuse":
        return "silent wrong result", f"accepted: {repr(value)[:400]}"
    assert case.check is not None, case.id
    if case.check(value):
        return "right result", ""
    area = case.id.split("-")[0]
    return ("lost data" if area in KEEPING_AREAS else "silent wrong result",
            f"wrong result: {repr(value)[:400]}")


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_hostile(case: Case, tmp_path, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "case"
    folder.mkdir()
    got, detail = outcome(case, folder)
    assert got == EXPECTED[case.expect], f"{got}: {detail}"


def battery_counts() -> dict[str, dict[str, int]]:
    """Run every case (each in a fresh folder and cache); counts by area and outcome."""
    import tempfile

    counts: dict[str, dict[str, int]] = {}
    saved = os.environ.get("SKELASM_CACHE")
    try:
        for case in CASES:
            with tempfile.TemporaryDirectory() as tmp:
                os.environ["SKELASM_CACHE"] = str(Path(tmp) / "cache")
                folder = Path(tmp) / "case"
                folder.mkdir()
                got, detail = outcome(case, folder)
            if got != EXPECTED[case.expect]:
                print(f"{case.id}: {got}: {detail}", file=sys.stderr)
            area = counts.setdefault(case.id.split("-")[0], dict.fromkeys(OUTCOMES, 0))
            area[got] += 1
    finally:
        if saved is None:
            os.environ.pop("SKELASM_CACHE", None)
        else:
            os.environ["SKELASM_CACHE"] = saved
    return counts


def counts_table(counts: dict[str, dict[str, int]]) -> str:
    """A Markdown table of :func:`battery_counts`: one row per area, a total row."""
    head = "| area | cases | " + " | ".join(OUTCOMES) + " |"
    rows = [head, "|" + "---|" * (len(OUTCOMES) + 2)]
    total = dict.fromkeys(OUTCOMES, 0)
    for area, by in counts.items():
        rows.append(f"| {area} | {sum(by.values())} | "
                    + " | ".join(str(by[o]) for o in OUTCOMES) + " |")
        for o in OUTCOMES:
            total[o] += by[o]
    rows.append(f"| all | {sum(total.values())} | "
                + " | ".join(str(total[o]) for o in OUTCOMES) + " |")
    return "\n".join(rows)


def test_outcome_classifies_what_goes_wrong(tmp_path):
    """The classifier tells each failure apart (so the counts mean what they say)."""

    def boom(folder):
        raise KeyError("x")

    def slow(folder):
        raise Hang("over")

    cases = [
        (Case("t-refuse-a", lambda f: 1, "refuse", ("x",)), "silent wrong result"),
        (Case("t-refuse-b", lambda f: (_ for _ in ()).throw(InputError("a\nb")), "refuse"),
         "unclear error"),
        (Case("t-refuse-c", lambda f: (_ for _ in ()).throw(InputError("y")), "refuse",
              ("x",)), "unclear error"),
        (Case("t-refuse-d", lambda f: (_ for _ in ()).throw(InputError("x")), "refuse",
              ("x",)), "clear error"),
        (Case("t-accept-e", boom, "accept", check=bool), "traceback"),
        (Case("t-accept-f", slow, "accept", check=bool), "hang"),
        (Case("end-accept-g", lambda f: 0, "accept", check=bool), "lost data"),
        (Case("name-accept-h", lambda f: 0, "accept", check=bool), "silent wrong result"),
        (Case("t-accept-i", lambda f: (_ for _ in ()).throw(InputError("x")), "accept",
              check=bool), "wrong refusal"),
        (Case("t-accept-j", lambda f: 1, "accept", check=bool), "right result"),
        (Case("t-refuse-k", cli("scene", "new", "--bogus"), "refuse", ("required",)),
         "clear error"),
    ]
    got = [outcome(case, tmp_path)[0] for case, _ in cases]
    assert got == [want for _, want in cases]


def test_the_battery_has_at_least_300_cases_in_ten_areas():
    areas = {c.id.split("-")[0] for c in CASES}
    assert len(CASES) >= 300, len(CASES)
    assert areas == {"mesh", "read", "end", "jump", "cap", "range", "msg", "name", "silent",
                     "json"}
    assert len({c.id for c in CASES}) == len(CASES), "duplicate ids"


if __name__ == "__main__":  # the battery's counts: python tests/engine/test_hostile.py
    print(counts_table(battery_counts()))
