"""The GUI's side of the engine boundary: open scenes, run the engine, drain its output.

Everything here runs on the GUI thread except :func:`_open_worker`, which loads a scene in
a short-lived thread and hands the frozen ``SceneHandle`` (or the exception) back through a
queued Qt signal. The engine thread is reached only through ``engine.runtime``: commands go in
with :meth:`Session.send`, frames and events come out of :meth:`Session.poll`.
"""

from __future__ import annotations

import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PySide6 import QtCore

from app.gui.quantities import MovingPart, moving_part
from engine import pose as posemath
from engine import runtime

SCENE_SUFFIXES = (".toml",)
PART_SUFFIXES = (".step", ".stp", ".stl", ".obj", ".ply", ".off")
FILE_FILTER = (
    "Scenes and parts (*.toml *.step *.stp *.stl *.obj *.ply *.off);;"
    "Scenes (*.toml);;Parts (*.step *.stp *.stl *.obj *.ply *.off);;All files (*)"
)


@dataclass(frozen=True)
class PartView:
    """What the 3D view needs of a part: its mesh in its own frame and its world pose."""

    name: str
    vertices: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64
    pose: np.ndarray  # (6,) float64 world pose
    moving: bool
    centre: np.ndarray | None = None  # (3,) float64 pivot drags turn about, own frame


class Session(QtCore.QObject):
    """One open scene and the engine running on it.

    Signals
    -------
    opened(object)
        A new scene is loaded and its engine started (the ``SceneHandle``).
    open_failed(str, str)
        Path and message of a scene or part that could not be opened; the previous scene
        and its engine keep running.
    """

    opened = QtCore.Signal(object)
    open_failed = QtCore.Signal(str, str)
    _loaded = QtCore.Signal(object, object, str)  # handle or None, exception or None, path

    def __init__(self, parent=None, *, realtime: bool = True, engine_kwargs=None,
                 handle_transform=None):
        super().__init__(parent)
        #: optional callable SceneHandle -> SceneHandle applied before the engine starts
        #: (benchmarks lock rotation this way)
        self.handle_transform = handle_transform
        self.realtime = realtime
        self.engine_kwargs = dict(engine_kwargs or {})
        self.handle: runtime.SceneHandle | None = None
        #: part 2's centre of mass, pivot and size (the seat readout, drags about its pivot)
        self.moving: MovingPart | None = None
        self.engine: runtime.EngineHandle | None = None
        self.loading: str | None = None
        self._tmp = tempfile.TemporaryDirectory(prefix="skelasm-gui-")
        self._generated = 0
        #: generated scenes whose second part still needs its start checked (placement)
        self._to_place: set[Path] = set()
        #: where the last opened second part was put, and why (the window shows it)
        self.placement: str | None = None
        #: generated pairs whose seat is where the files draw the parts (none set up yet)
        self.drawn_seats: set[Path] = set()
        #: scenes are opened off the GUI thread; a newer open supersedes an older one
        self._opener = runtime.JobWorker(name="skelasm-open")
        self._loaded.connect(self._on_loaded)
        #: set by close(): a load that finishes afterwards starts no engine
        self._closed = False

    @property
    def engine_name(self) -> str:
        """How the GUI names the engine in messages: ``"engine process"`` or ``"engine"``."""
        return "engine process" if self.process else "engine"

    @property
    def process(self) -> bool:
        """True when the engine runs in its own process (``start_engine(process=True)``)."""
        return self.engine.process if self.engine is not None else bool(
            self.engine_kwargs.get("process"))

    # ------------------------------------------------------------------ opening
    def open(self, path: str | Path) -> None:
        """Open a scene file, or a part file as the moving part of the current scene.

        Returns at once; ``opened`` or ``open_failed`` follows.
        """
        path = Path(path)
        try:
            scene_path = self._scene_path_for(path)
        except (OSError, ValueError) as exc:
            self.open_failed.emit(str(path), str(exc))
            return
        self.loading = str(path)
        self._opener.submit("open", lambda cancelled: self._open_worker(
            scene_path, str(path), cancelled))

    def open_sync(self, path: str | Path) -> None:
        """Open in the calling thread (command line start-up, tests)."""
        path = Path(path)
        try:
            handle = self._placed(runtime.open_scene(self._scene_path_for(path)))
        except Exception as exc:  # noqa: BLE001 -- every failure becomes a message
            self._on_loaded(None, exc, str(path))
            return
        self._on_loaded(handle, None, str(path))

    def _open_worker(self, scene_path: Path, original: str, cancelled) -> None:
        try:
            handle = self._placed(runtime.open_scene(scene_path))
        except Exception as exc:  # noqa: BLE001 -- every failure becomes a message
            if not cancelled():
                self._loaded.emit(None, exc, original)
            return
        if not cancelled():  # a newer open superseded this one: its answer is dropped
            self._loaded.emit(handle, None, original)

    def _placed(self, handle: runtime.SceneHandle) -> runtime.SceneHandle:
        """A generated pair's second part where its file draws it, or parked clear of part 1.

        Runs where the scene was loaded (a worker): the test samples part 2's surface
        (:func:`engine.scene.placement.place_second`). A parked part's pose is written back
        into the generated scene, so Save keeps it.
        """
        from dataclasses import replace

        from engine.scene import save_scene
        from engine.scene.placement import place_second

        path = Path(handle.path)
        if path not in self._to_place or len(handle.parts) < 2:
            return handle
        self._to_place.discard(path)
        scene = handle.scene
        pose, self.placement = place_second(handle.parts[0], handle.parts[1],
                                            scene.parts[0].pose)
        if np.allclose(pose, scene.parts[1].pose):
            return handle
        parts = (scene.parts[0], replace(scene.parts[1], pose=pose), *scene.parts[2:])
        scene = replace(scene, parts=parts)
        save_scene(scene, path)
        start = posemath.relative_pose(scene.parts[0].pose, pose)
        start.setflags(write=False)
        return replace(handle, scene=scene, start_pose=start)

    def _scene_path_for(self, path: Path) -> Path:
        suffix = path.suffix.lower()
        if not path.exists():
            raise OSError(f"{path}: no such file")
        if suffix in SCENE_SUFFIXES:
            return path
        if suffix not in PART_SUFFIXES:
            raise ValueError(
                f"{path}: unknown file type {suffix or '(none)'}; open a scene (.toml) or a "
                f"part ({', '.join(PART_SUFFIXES)})"
            )
        return self._scene_with_part(path)

    def _scene_with_part(self, part_path: Path) -> Path:
        """A generated scene: the current fixed part and ``part_path`` as the moving part.

        The current scene's tables (descriptor, coupling, effects, ...) are kept. Without a
        current scene the part is shown alone as the fixed part, in a scene that declares
        no unit (so a mesh file's missing unit is reported when it loads).
        """
        from dataclasses import replace

        from engine.params import SeatSpec, SimConfig
        from engine.scene import PartSpec, Scene, save_scene

        self._generated += 1
        out = Path(self._tmp.name) / f"generated_{self._generated}.toml"
        name = f"untitled ({part_path.name})"
        if self.handle is not None:
            scene = self.handle.scene
            first = scene.parts[0]
            # where its file draws it beside the first (the worker parks it where that is
            # inside the first part: engine.scene.placement)
            moving = PartSpec(name=part_path.stem, file=part_path.resolve(),
                              pose=np.array(first.pose, dtype=float), fixed=False)
            if moving.name == first.name:
                moving = replace(moving, name=f"{moving.name} (moving)")
            config = replace(scene.config, masses=scene.config.masses[:1])
            # a new pair: its grid and K are chosen from the two parts (engine.sim.auto)
            given = frozenset(scene.given or ()) - {"descriptor.grid", "descriptor.spacing",
                                                    "correlation.modes"}
            # a new pair: the old one's seat, axis and free axes say nothing of it; its seat
            # is where the files draw the two parts until the user sets the fit up
            generated = replace(scene, path=out, name=name, parts=(first, moving),
                                config=config, given=given, chosen=(),
                                assembled_pose=np.zeros(6), insertion_axis=None,
                                seat=SeatSpec())
            self._to_place.add(out)
            self.drawn_seats.add(out)
        else:
            generated = Scene(path=out, name=name, units_declared=False,
                              assembled_pose=np.zeros(6), config=SimConfig(),
                              parts=(PartSpec(name=part_path.stem, file=part_path.resolve(),
                                              pose=np.zeros(6), fixed=True),))
        return save_scene(generated, out)

    def _on_loaded(self, handle, error, path: str) -> None:
        self.loading = None
        if self._closed:  # a load queued before close(): its engine would never be stopped
            return
        if error is not None:
            self.open_failed.emit(path, _message(error))
            return
        if self.handle_transform is not None:
            handle = self.handle_transform(handle)
        old = self.engine
        self.engine = None
        if old is not None:
            old.stop()
        self.handle = handle
        self.moving = moving_part(handle)
        if len(handle.parts) >= 2:
            try:
                self.engine = runtime.start_engine(
                    handle, realtime=self.realtime, **self.engine_kwargs
                )
            except Exception as exc:  # noqa: BLE001
                self.open_failed.emit(path, f"the engine did not start: {_message(exc)}")
        self.opened.emit(handle)

    # ------------------------------------------------------------------ running
    def send(self, command) -> None:
        """Send a command to the engine (dropped while none runs)."""
        if self.engine is not None:
            self.engine.send(command)

    def poll(self) -> tuple[list, list]:
        """Frames (oldest first) and events since the last call."""
        if self.engine is None:
            return [], []
        return self.engine.poll_frames(), self.engine.poll_events()

    def part_views(self) -> list[PartView]:
        """What the 3D view shows of the open scene: one :class:`PartView` per part.

        Part 2 (the moving one) is placed at the start pose, the others at their scene poses;
        an empty list when no scene is open.
        """
        if self.handle is None:
            return []
        views = []
        n = len(self.handle.parts)
        specs = self.handle.scene.parts
        for i, (part, spec) in enumerate(zip(self.handle.parts, specs, strict=True)):
            moving = i == 1 and n >= 2
            pose = self.handle.world_pose(self.handle.start_pose) if moving else spec.pose
            centre = self.moving.pivot if moving and self.moving is not None else None
            views.append(PartView(part.name, np.asarray(part.vertices, float),
                                  np.asarray(part.faces, np.int64),
                                  np.asarray(pose, float), moving, centre))
        return views

    def world(self, relative_pose: np.ndarray) -> np.ndarray:
        """World pose (6,) float64 of a pose relative to part 1."""
        return self.handle.world_pose(relative_pose)

    def relative(self, world_pose: np.ndarray) -> np.ndarray:
        """Pose relative to part 1, (6,) float64, of a world pose."""
        return self.handle.relative_pose(world_pose)

    def part1_rotation(self) -> np.ndarray:
        """(3, 3) float64 world rotation of part 1."""
        return posemath.rotation_matrix(self.handle.part1_world_pose[3:])

    def close(self) -> None:
        """Stop the engine, wait for its background workers and remove the temporary files."""
        self._closed = True
        self._opener.shutdown(timeout=0.0)  # a scene still loading is dropped
        if self.engine is not None:
            self.engine.stop()
            self.engine = None
            wait_for_workers(3.0)
        self._tmp.cleanup()


def wait_for_workers(timeout: float) -> bool:
    """Join the engine's and the window's background threads (descriptors, landscapes).

    A worker still inside compiled parallel code when the interpreter exits aborts the
    process ("terminate called without an active exception"); stopping the engine cancels
    them, and they notice within seconds. Returns True if none is left.
    """
    deadline = time.perf_counter() + timeout
    for t in threading.enumerate():
        if t is threading.current_thread() or not t.name.startswith(("skelasm-", "gui-")):
            continue
        t.join(max(0.0, deadline - time.perf_counter()))
    return not any(t.is_alive() and t.name.startswith(("skelasm-", "gui-"))
                   for t in threading.enumerate() if t is not threading.current_thread())


def _message(exc: BaseException) -> str:
    text = str(exc) or exc.__class__.__name__
    if isinstance(exc, ValueError | OSError):
        return text
    return f"{exc.__class__.__name__}: {text}"
