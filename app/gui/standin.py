"""A stand-in engine loop used only while ``engine.loop`` (or the scene loader) is missing.

It speaks the real ``engine.api`` types (commands in, ``Frame`` and events out) so that the
window can be built and run before the simulation lands. Nothing it computes is a skeletal
density or a correlation energy: the part follows the proxy with a first-order lag, the
"descriptor" is a smooth inside/outside field of the bounding box and the "landscape" is a
bowl. The window shows "preview engine" in its title while this is in use, and no test of
the real engine goes through it.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import tomllib

from engine import api
from engine.grid import Grid, grid_for_bounds
from engine.simconfig import SimConfig

NAME = "preview engine"


@dataclass(frozen=True)
class StandinDescriptor:
    rho: np.ndarray
    grid: Grid


def _box_field(vertices: np.ndarray, grid: Grid, sigma: float, penalty: float) -> np.ndarray:
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    pts = grid.points()
    d = np.maximum(lo - pts, pts - hi).max(axis=-1)  # box distance, + outside
    s = np.tanh(-d / (sigma * 4 * grid.spacing))
    return (1j * np.where(s > 0, penalty * s, s)).astype(np.complex64)


def _load_mesh(path: Path):
    import trimesh

    mesh = trimesh.load(str(path), force="mesh")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: no triangles found; is it a mesh or STEP file?")
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)


def open_scene(path) -> api.SceneHandle:
    path = Path(path)
    if path.suffix.lower() == ".toml":
        spec = tomllib.loads(path.read_text())
        entries = [
            (p["name"], path.parent / p["file"], tuple(p.get("pose", [0.0] * 6)))
            for p in spec["part"]
        ]
        assembled = spec.get("assembled_pose", [0.0] * 6)
        name = spec.get("name", path.stem)
    else:
        entries = [(path.stem, path, (0.0,) * 6)]
        assembled = [0.0] * 6
        name = path.stem
    parts, specs = [], []
    for pname, f, pose in entries:
        v, fc = _load_mesh(f)
        parts.append(SimpleNamespace(name=pname, vertices=v, faces=fc, warnings=()))
        specs.append(SimpleNamespace(name=pname, file=str(f), pose=tuple(pose)))
    scene = SimpleNamespace(name=name, path=str(path), parts=tuple(specs),
                            assembled_pose=tuple(assembled))
    from engine.pose import relative_pose

    start = relative_pose(specs[0].pose, specs[-1].pose) if len(specs) > 1 else np.zeros(6)
    return api.SceneHandle(scene=scene, config=SimConfig(), parts=tuple(parts),
                           start_pose=np.asarray(start), assembled_pose=np.asarray(assembled),
                           path=path)


class StandinLoop:
    def __init__(self, handle: api.SceneHandle, modes: int = 16):
        self.handle = handle
        self.modes = modes
        self.commands: queue.Queue = queue.Queue()
        self.frames: queue.Queue = queue.Queue(maxsize=64)
        self.events: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="standin-engine", daemon=True)
        self._thread.start()

    def send(self, command) -> None:
        self.commands.put(command)

    def poll_frames(self, max_frames=None) -> list:
        out = []
        while max_frames is None or len(out) < max_frames:
            try:
                out.append(self.frames.get_nowait())
            except queue.Empty:
                break
        return out

    def poll_events(self) -> list:
        out = []
        while True:
            try:
                out.append(self.events.get_nowait())
            except queue.Empty:
                return out

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        self._thread.join(timeout)

    def _descriptors(self, sigma: float, penalty: float):
        out = []
        for part in self.handle.parts[:2]:
            v = part.vertices
            g = grid_for_bounds(v.min(0), v.max(0), samples=32, padding=4)
            out.append(StandinDescriptor(_box_field(v, g, sigma, penalty), g))
        return tuple(out)

    def _landscape(self):
        v = self.handle.parts[0].vertices
        g = grid_for_bounds(v.min(0), v.max(0), samples=32, padding=6)
        pts = g.points() - np.asarray(self.handle.assembled_pose[:3])
        scale = float(np.ptp(v, axis=0).max())
        from engine.landscape import Landscape

        energy = -np.exp(-np.sum(pts**2, -1) / (0.1 * scale) ** 2).astype(np.float32)
        return Landscape(energy, None, g.axes(), np.eye(3), self.modes)

    def _put(self, q: queue.Queue, item) -> None:
        try:
            q.put_nowait(item)
        except queue.Full:
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            q.put_nowait(item)

    def _run(self) -> None:
        proxy = np.asarray(self.handle.start_pose, float).copy()
        part = proxy.copy()
        modes = self.modes
        recompute = None
        self.events.put(api.ReadyEvent(self._descriptors(0.5, 3.0), backend=NAME))
        t0 = last = time.perf_counter()
        step = 0
        paused = False
        while not self._stop.is_set():
            while True:
                try:
                    c = self.commands.get_nowait()
                except queue.Empty:
                    break
                if isinstance(c, api.SetProxyPose):
                    proxy = np.asarray(c.pose, float)
                elif isinstance(c, api.SetModes):
                    modes = c.modes
                elif isinstance(c, api.SetDescriptorParams):
                    recompute = (time.perf_counter(), c)
                elif isinstance(c, api.CancelRecompute) and recompute is not None:
                    recompute = None
                    self.events.put(api.ProgressEvent("descriptors", 1.0, "cancelled"))
                elif isinstance(c, api.RequestLandscape):
                    self.events.put(api.LandscapeReady(self._landscape()))
                elif isinstance(c, api.Pause):
                    paused = c.paused
                elif isinstance(c, api.Reset):
                    proxy = np.asarray(self.handle.start_pose, float).copy()
                    part = proxy.copy()
                elif isinstance(c, api.Stop):
                    self._stop.set()
            now = time.perf_counter()
            dt, last = now - last, now
            if not paused:
                part = part + (1.0 - math.exp(-dt / 0.05)) * (proxy - part)
            frac = None
            if recompute is not None:
                frac = min((now - recompute[0]) / 3.0, 1.0)
                self.events.put(api.ProgressEvent("descriptors", frac))
                if frac >= 1.0:
                    c = recompute[1]
                    self.events.put(api.DescriptorsSwapped(
                        self._descriptors(c.sigma or 0.5, c.penalty or 3.0)))
                    recompute, frac = None, None
            step += 1
            z = np.zeros(3)
            self._put(self.frames, api.Frame(
                time=now - t0, step=step, proxy_pose=proxy.copy(), part_pose=part.copy(),
                energy=-float(np.exp(-np.sum((part[:3] - self.handle.assembled_pose[:3]) ** 2)
                                     / 100.0)),
                force=10.0 * (proxy[:3] - part[:3]), torque=z, coupling_force=z,
                coupling_torque=z, haptic_force=z, haptic_torque=z,
                eval_us=0.06 * modes**3, step_us=0.07 * modes**3,
                period=api.PeriodStats(rate_hz=1.0 / max(dt, 1e-6)), modes=modes,
                paused=paused, recompute=frac, device="mouse"))
            time.sleep(0.002)
        self.events.put(api.StoppedEvent(step))


def start_engine(handle: api.SceneHandle, **kwargs) -> api.EngineHandle:
    return api.EngineHandle(StandinLoop(handle, modes=kwargs.get("modes") or 16))
