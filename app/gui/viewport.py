"""The 3D view: both parts, the proxy ghost, force and torque arrows, and mouse dragging.

Meshes are added once; each frame only sets actor transforms (``SetUserMatrix``), so a frame
costs one render and no geometry upload. Rendering happens on the window's render timer when
something changed (:meth:`Viewport.render_if_dirty`), never from the engine thread.

Dragging (left button on the moving part or its ghost):
- plain drag: translate the proxy in the view plane;
- Shift + vertical drag, or the wheel while dragging: translate along the view direction;
- Ctrl + drag: rotate the proxy about its centre with an arcball.
Anywhere else the mouse drives the camera as usual.
"""

from __future__ import annotations

import time

import numpy as np
import pyvista as pv
import vtk
from PySide6 import QtCore, QtGui, QtWidgets
from pyvistaqt import QtInteractor

from app.gui import geometry
from engine import pose as posemath

FIXED_COLOUR = "#b0b4ba"
MOVING_COLOUR = "#f28e2b"
GHOST_COLOUR = "#4e9ad6"


def _vtk_matrix(m: np.ndarray) -> vtk.vtkMatrix4x4:
    out = vtk.vtkMatrix4x4()
    for i in range(4):
        for j in range(4):
            out.SetElement(i, j, float(m[i, j]))
    return out


def _set_matrix(actor, m: np.ndarray) -> None:
    vm = actor.GetUserMatrix()
    if vm is None:
        actor.SetUserMatrix(_vtk_matrix(m))
        return
    vm.DeepCopy(tuple(float(x) for x in np.asarray(m).ravel()))  # one call; bumps MTime


def _software_opengl(plotter) -> bool:
    """True when OpenGL is a software rasteriser (llvmpipe, softpipe, swrast)."""
    try:
        report = plotter.ren_win.ReportCapabilities()
    except Exception:  # noqa: BLE001 -- no context yet: assume hardware
        return False
    return any(name in report.lower() for name in ("llvmpipe", "softpipe", "swrast"))


def _faces_to_vtk(faces: np.ndarray) -> np.ndarray:
    f = np.asarray(faces, dtype=np.int64)
    return np.hstack([np.full((len(f), 1), 3, dtype=np.int64), f]).ravel()


class Viewport(QtCore.QObject):
    """Owns the QtInteractor and the actors of one scene.

    Signals
    -------
    proxy_dragged(object)
        (6,) float64 world pose requested for the proxy while dragging.
    drag_state(bool)
        True when a drag of the moving part starts, False when it ends.
    """

    proxy_dragged = QtCore.Signal(object)
    drag_state = QtCore.Signal(bool)

    def __init__(self, parent: QtWidgets.QWidget):
        super().__init__(parent)
        # No multisampling: on a software OpenGL (Mesa llvmpipe, as under Xvfb) 8x MSAA
        # made a render 5x slower (111 ms against 23 ms for the peg-in-hole window).
        self.plotter = QtInteractor(parent, auto_update=False, multi_samples=0)
        # the window handles dropped files; pyvistaqt's own handler would add raw meshes
        self.plotter.setAcceptDrops(False)
        self.plotter.set_background("#f4f5f7", top="#d9dde3")
        self.software_gl = _software_opengl(self.plotter)
        if not self.software_gl:
            self.plotter.enable_anti_aliasing("fxaa")  # cheap on a GPU, not on llvmpipe
        else:
            # one light instead of pyvista's five-light kit: lighting is per pixel, and
            # on llvmpipe a frame took 17 ms instead of 25 to 33 (708 x 879 view)
            self.plotter.renderer.remove_all_lights()
            # a camera light above and to the right of the eye, not on it: from the eye, the
            # three faces of a box seen isometrically would get the same shade
            self.plotter.renderer.add_light(
                pv.Light(position=(0.4, 1.0, 0.6), light_type="camera light"))
        # with a single light, faces seen at a slant need ambient light to stay readable
        self._material = {"ambient": 0.35, "diffuse": 0.7} if self.software_gl else {}
        self.widget: QtWidgets.QWidget = self.plotter
        self._actors: dict[str, object] = {}
        self._centroid = np.zeros(3)  # moving part's centroid in its own frame
        self._proxy_pose = np.zeros(6)
        self._part_pose = np.zeros(6)
        self._size = 1.0
        self._dirty = True
        self.frames_rendered = 0
        self.arrow_scale = 1.0
        self._drag = None  # dict while a drag is in progress
        self._picker = vtk.vtkPropPicker()
        # force and torque arrows live in an overlay layer sharing the camera, so they stay
        # visible where they start: inside the part
        self._overlay = vtk.vtkRenderer()
        self._overlay.SetLayer(1)
        self._overlay.InteractiveOff()
        self._overlay.SetActiveCamera(self.plotter.renderer.GetActiveCamera())
        self.plotter.ren_win.SetNumberOfLayers(2)
        self.plotter.ren_win.AddRenderer(self._overlay)
        self.plotter.installEventFilter(self)
        self._slice_plane_actor = None
        self._arrow_matrices: dict[str, np.ndarray] = {}
        self.min_render_interval = 1.0 / 40.0  # seconds; caps the render rate
        self._last_render = 0.0

    # ----------------------------------------------------------------- scene
    def set_scene(self, parts) -> None:
        """Replace all actors. ``parts``: sequence of PartView (last one moves)."""
        self.plotter.clear_actors()
        self._actors.clear()
        self._arrow_matrices.clear()
        self._slice_plane_actor = None
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for part in parts:
            mesh = pv.PolyData(np.asarray(part.vertices, float), _faces_to_vtk(part.faces))
            world = posemath.pose_to_matrix(part.pose)
            pts = part.vertices @ world[:3, :3].T + world[:3, 3]
            lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
            if part.moving:
                actor = self.plotter.add_mesh(
                    mesh, color=MOVING_COLOUR, smooth_shading=False, specular=0.3,
                    name="moving", pickable=True, **self._material,
                )
                ghost = self.plotter.add_mesh(
                    mesh, color=GHOST_COLOUR, opacity=0.25, name="ghost", pickable=True,
                )
                ghost_edges = self.plotter.add_mesh(
                    mesh.extract_feature_edges(30), color=GHOST_COLOUR,
                    line_width=2.5 if self.software_gl else 1.5,
                    name="ghost_edges", pickable=False,
                )
                if self.software_gl:
                    # a translucent surface cost ~20 ms a frame on llvmpipe (blending over
                    # the whole part); the ghost is drawn by its edges alone there
                    ghost.SetVisibility(False)
                self._actors.update(moving=actor, ghost=ghost, ghost_edges=ghost_edges)
                self._centroid = np.asarray(part.vertices, float).mean(axis=0)
                self._proxy_pose = np.asarray(part.pose, float).copy()
                self._part_pose = np.asarray(part.pose, float).copy()
                _set_matrix(actor, world)
                _set_matrix(ghost, world)
                _set_matrix(ghost_edges, world)
            else:
                actor = self.plotter.add_mesh(
                    mesh, color=FIXED_COLOUR, specular=0.2, name=f"fixed_{part.name}",
                    pickable=False, **self._material,
                )
                _set_matrix(actor, world)
                self._actors[f"fixed_{part.name}"] = actor
        self._size = float(np.linalg.norm(hi - lo)) if np.all(np.isfinite(hi - lo)) else 1.0
        self.arrow_scale = 0.3 * self._size
        self._overlay.RemoveAllViewProps()
        self._overlay.SetActiveCamera(self.plotter.renderer.GetActiveCamera())
        for key, colour in (("force", "#d62728"), ("torque", "#9467bd")):
            arrow = pv.Arrow(start=(0, 0, 0), direction=(1, 0, 0), scale=1.0,
                             tip_length=0.25, tip_radius=0.07, shaft_radius=0.025)
            mapper = vtk.vtkPolyDataMapper()
            mapper.SetInputData(arrow)
            a = vtk.vtkActor()
            a.SetMapper(mapper)
            a.GetProperty().SetColor(pv.Color(colour).float_rgb)
            a.PickableOff()
            a.SetVisibility(False)
            self._overlay.AddActor(a)
            self._actors[key] = a
        self.plotter.add_axes()
        self.plotter.reset_camera()
        self.plotter.camera.zoom(1.2)
        self._dirty = True

    # ----------------------------------------------------------------- per frame
    def _moved(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True if two poses differ visibly (a ten-thousandth of the scene, 0.01 degree)."""
        d = np.abs(np.asarray(a) - np.asarray(b))
        return bool(d[:3].max() > 1e-4 * self._size or d[3:].max() > 2e-4)

    def set_poses(self, proxy_pose: np.ndarray | None, part_pose: np.ndarray | None) -> None:
        """Move the ghost and the moving part (world poses, (6,) float64).

        Nothing is marked for rendering when neither moved visibly, so a part at rest
        costs no renders (a render holds the GIL, and with it the engine thread).
        """
        if proxy_pose is not None and not self._moved(proxy_pose, self._proxy_pose):
            proxy_pose = None
        if part_pose is not None and not self._moved(part_pose, self._part_pose):
            part_pose = None
        if proxy_pose is not None and "ghost" in self._actors and self._drag is None:
            self._proxy_pose = np.asarray(proxy_pose, float).copy()
            m = posemath.pose_to_matrix(self._proxy_pose)
            _set_matrix(self._actors["ghost"], m)
            _set_matrix(self._actors["ghost_edges"], m)
            self._dirty = True
        if part_pose is not None and "moving" in self._actors:
            self._part_pose = np.asarray(part_pose, float).copy()
            _set_matrix(self._actors["moving"], posemath.pose_to_matrix(self._part_pose))
            self._dirty = True

    def set_wrench(self, force: np.ndarray, torque: np.ndarray | None, force_scale: float,
                   torque_scale: float) -> None:
        """Point the force and torque arrows (world frame) from the part's centre.

        An arrow's length is ``min(|v| * scale, 1)`` times a fifth of the scene's size.
        """
        if "force" not in self._actors:
            return
        centre = posemath.pose_to_matrix(self._part_pose)[:3] @ np.append(self._centroid, 1.0)
        changed = False
        for key, vec, scale in (("force", force, force_scale), ("torque", torque, torque_scale)):
            actor = self._actors[key]
            v = None if vec is None else np.asarray(vec, float)
            n = 0.0 if v is None else float(np.linalg.norm(v))
            if n * scale < 1e-3 or not np.isfinite(n):
                if actor.GetVisibility():
                    actor.SetVisibility(False)
                    changed = True
                continue
            length = min(n * scale, 1.0) * self.arrow_scale
            x = v / n
            helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0, 0])
            y = np.cross(helper, x)
            y /= np.linalg.norm(y)
            z = np.cross(x, y)
            m = np.eye(4)
            m[:3, 0], m[:3, 1], m[:3, 2] = x * length, y * length, z * length
            m[:3, 3] = centre
            last = self._arrow_matrices.get(key)
            if last is not None and actor.GetVisibility() and \
                    np.abs(last - m).max() < 2e-3 * self.arrow_scale:
                continue  # no visible change
            self._arrow_matrices[key] = m
            _set_matrix(actor, m)
            actor.SetVisibility(True)
            changed = True
        self._dirty |= changed

    def show_slice_plane(self, corners: np.ndarray | None) -> None:
        """Show a translucent quad (4, 3) world corners for the descriptor slice, or hide it."""
        if corners is None:
            if self._slice_plane_actor is not None:
                self._slice_plane_actor.SetVisibility(False)
                self._dirty = True
            return
        quad = pv.PolyData(np.asarray(corners, float), np.array([4, 0, 1, 2, 3]))
        if self._slice_plane_actor is None:
            self._slice_plane_actor = self.plotter.add_mesh(
                quad, color="#2ca02c", opacity=0.2, name="slice_plane", pickable=False
            )
            self._slice_quad = self._slice_plane_actor.GetMapper().GetInput()
        else:
            self._slice_quad.points = np.asarray(corners, float)
            self._slice_quad.Modified()
        self._slice_plane_actor.SetVisibility(True)
        self._dirty = True

    def request_render(self) -> None:
        """Mark the view as changed; the next :meth:`render_if_dirty` renders it."""
        self._dirty = True

    def render_if_dirty(self, *, force: bool = False) -> bool:
        """Render once if anything changed and the last render is old enough; True if it rendered.

        Renders only when something changed since the last render and that render is at least
        :attr:`min_render_interval` old (or ``force``).
        """
        if not self._dirty or not self.plotter.isVisible():
            return False
        now = time.perf_counter()
        if not force and now - self._last_render < self.min_render_interval:
            return False
        self._last_render = now
        self._dirty = False
        # Through Qt: the widget's paintEvent renders. Rendering here directly as well made
        # two renders per frame, as Qt repaints the native VTK window after each one.
        self.plotter.update()
        self.frames_rendered += 1
        return True

    @property
    def proxy_pose(self) -> np.ndarray:
        """(6,) float64 world pose of the proxy (the ghost), a copy."""
        return self._proxy_pose.copy()

    @property
    def part_pose(self) -> np.ndarray:
        """(6,) float64 world pose of the moving part, a copy."""
        return self._part_pose.copy()

    # ----------------------------------------------------------------- picking
    def _display_xy(self, pos: QtCore.QPointF) -> tuple[float, float]:
        dpr = self.plotter.devicePixelRatioF()
        return pos.x() * dpr, (self.plotter.height() - pos.y() - 1) * dpr

    def moving_part_screen_position(self) -> QtCore.QPoint:
        """Widget coordinates (Qt, y down) of the moving part's centre; for tests and hints."""
        centre = posemath.pose_to_matrix(self._part_pose)[:3] @ np.append(self._centroid, 1.0)
        x, y, _ = self._world_to_display(centre)
        dpr = self.plotter.devicePixelRatioF()
        return QtCore.QPoint(int(round(x / dpr)), int(round(self.plotter.height() - 1 - y / dpr)))

    def _world_to_display(self, p: np.ndarray) -> np.ndarray:
        ren = self.plotter.renderer
        ren.SetWorldPoint(float(p[0]), float(p[1]), float(p[2]), 1.0)
        ren.WorldToDisplay()
        return np.array(ren.GetDisplayPoint())

    def _display_to_world(self, x: float, y: float, z: float) -> np.ndarray:
        ren = self.plotter.renderer
        ren.SetDisplayPoint(x, y, z)
        ren.DisplayToWorld()
        w = np.array(ren.GetWorldPoint())
        return w[:3] / (w[3] if w[3] != 0 else 1.0)

    def pick_moving(self, pos: QtCore.QPointF) -> bool:
        """True if the moving part or its ghost is under widget position ``pos``."""
        if "moving" not in self._actors:
            return False
        x, y = self._display_xy(pos)
        if not self._picker.PickProp(x, y, self.plotter.renderer):
            return False
        actor = self._picker.GetViewProp()
        return actor is self._actors["moving"] or actor is self._actors["ghost"]

    # ----------------------------------------------------------------- dragging
    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        """Drag the proxy with the left mouse button when the press hits the moving part.

        While dragging, mouse moves and the release move the proxy and the wheel changes the drag
        depth. Returns True for events it used, which the 3D view then does not see (so the
        camera does not turn while a part is dragged).
        """
        et = event.type()
        if et == QtCore.QEvent.MouseButtonPress and event.button() == QtCore.Qt.LeftButton:
            if self.pick_moving(event.position()):
                self._begin_drag(event.position(), event.modifiers())
                return True
            return False
        if self._drag is not None:
            if et == QtCore.QEvent.MouseMove:
                self._drag_to(event.position(), event.modifiers())
                return True
            if et == QtCore.QEvent.MouseButtonRelease:
                self._drag_to(event.position(), event.modifiers())
                self._drag = None
                self.drag_state.emit(False)
                return True
            if et == QtCore.QEvent.Wheel:
                steps = event.angleDelta().y() / 120.0
                self._drag["depth"] += steps * 0.05 * self._size
                self._drag_to(self._drag["last"], self._drag["mods"])
                return True
        return False

    def _begin_drag(self, pos: QtCore.QPointF, mods) -> None:
        centre = posemath.pose_to_matrix(self._proxy_pose)[:3] @ np.append(self._centroid, 1.0)
        disp = self._world_to_display(centre)
        x, y = self._display_xy(pos)
        self._drag = {
            "start_pos": QtCore.QPointF(pos),
            "start_xy": (x, y),
            "start_pose": self._proxy_pose.copy(),
            "centre": centre,
            "centre_disp": disp,
            "grab_world": self._display_to_world(x, y, disp[2]),
            "depth": 0.0,
            "last": QtCore.QPointF(pos),
            "mods": mods,
        }
        self.drag_state.emit(True)

    def _camera_basis(self) -> np.ndarray:
        """(3, 3) columns: camera right, up, back (towards the viewer) in world coordinates."""
        cam = self.plotter.camera
        direction = np.asarray(cam.GetDirectionOfProjection(), float)
        up = np.asarray(cam.GetViewUp(), float)
        right = np.cross(direction, up)
        right /= np.linalg.norm(right)
        up = np.cross(right, direction)
        return np.column_stack([right, up, -direction])

    def _drag_to(self, pos: QtCore.QPointF, mods) -> None:
        d = self._drag
        d["last"], d["mods"] = QtCore.QPointF(pos), mods
        x, y = self._display_xy(pos)
        basis = self._camera_basis()
        pose = d["start_pose"].copy()
        if mods & QtCore.Qt.ControlModifier:
            cx, cy = d["centre_disp"][0], d["centre_disp"][1]
            radius = 0.35 * min(self.plotter.width(), self.plotter.height())
            radius *= self.plotter.devicePixelRatioF()
            v0 = geometry.arcball_vector(*d["start_xy"], cx, cy, radius)
            v1 = geometry.arcball_vector(x, y, cx, cy, radius)
            rv = basis @ geometry.arcball_rotation(v0, v1)
            pose = geometry.rotate_pose_about(pose, rv, d["centre"])
        elif mods & QtCore.Qt.ShiftModifier:
            world_per_px = self._world_per_pixel(d)
            pose[:3] += basis[:, 2] * (y - d["start_xy"][1]) * world_per_px
        else:
            now = self._display_to_world(x, y, d["centre_disp"][2])
            pose[:3] += now - d["grab_world"]
        pose[:3] += basis[:, 2] * d["depth"]
        self._proxy_pose = pose
        m = posemath.pose_to_matrix(pose)
        _set_matrix(self._actors["ghost"], m)
        _set_matrix(self._actors["ghost_edges"], m)
        self._dirty = True
        self.proxy_dragged.emit(pose.copy())

    def _world_per_pixel(self, d) -> float:
        cx, cy, cz = d["centre_disp"]
        a = self._display_to_world(cx, cy, cz)
        b = self._display_to_world(cx + 1.0, cy, cz)
        return float(np.linalg.norm(b - a))

    @property
    def dragging(self) -> bool:
        """True while the user drags the proxy."""
        return self._drag is not None

    def close(self) -> None:
        """Stop filtering the 3D view's events and close it."""
        self.plotter.removeEventFilter(self)
        self.plotter.close()


def grab_render(plotter: QtInteractor) -> QtGui.QImage:
    """The current 3D render as a QImage (for screenshots of the view alone)."""
    arr = plotter.screenshot(return_img=True)
    h, w, _ = arr.shape
    return QtGui.QImage(np.ascontiguousarray(arr).data, w, h, 3 * w,
                        QtGui.QImage.Format_RGB888).copy()
