"""The 3D view: both parts, the proxy ghost, force and torque arrows, and mouse dragging.

Meshes are added once; each frame only sets actor transforms (``SetUserMatrix``), so a frame
costs one render and no geometry upload. Rendering happens on the window's render timer when
something changed (:meth:`Viewport.render_if_dirty`), never from the engine thread.

Dragging (left button on the moving part or its ghost):
- plain drag: translate the proxy in the view plane, or, with a constraint on (the
  insertion axis, x, y or z: :attr:`Viewport.constraint`), along that axis only (the point of
  the axis nearest the mouse ray); the axis is drawn through the part while it is on;
- Shift + vertical drag, or the wheel while dragging: translate along the view direction
  (along the constraint axis when one is on);
- Ctrl + drag: rotate the proxy about part 2's pivot (the scene's ``pivot``, else its centre
  of mass), with an arcball, or about the constraint axis through it (horizontal
  mouse travel sets the angle).
Anywhere else the mouse drives the camera as usual. Standard views (:meth:`Viewport.set_view`)
look along the axes of part 1's frame, isometrically, or along the insertion axis.
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
FIT_COLOUR = "#2e8b3e"  # a found fit's edges and free axes (green, as SEATED)
GHOST_COLOUR = "#4e9ad6"
#: The ghost's line actors, drawn over everything (the overlay layer).
GHOST_LINES = ("ghost_edges", "ghost_outline")
OVERLAP_COLOUR = "#d62728"  # the moving part where it interpenetrates the fixed one

#: Drag constraints: free (the view plane) or along one axis.
CONSTRAINTS = ("free", "insertion", "x", "y", "z")
AXIS_COLOURS = {"insertion": "#111111", "x": "#d62728", "y": "#2ca02c", "z": "#1f77b4"}

#: Standard views: name -> (direction the camera looks along, view up), in part 1's frame.
#: "+x" is the view from the +x side (looking along -x).
VIEWS = {
    "+x": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "-x": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "+y": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "-y": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "+z": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "-z": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "iso": ((-1.0, 1.0, -1.0), (0.0, 0.0, 1.0)),
}
VIEW_NAMES = {"+x": "from +X", "-x": "from −X", "+y": "from +Y", "-y": "from −Y",
              "+z": "from +Z (top)", "-z": "from −Z (bottom)", "iso": "isometric",
              "insertion": "along the insertion axis"}


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
    constraint_changed = QtCore.Signal(str)

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
        self._face_pick = None  # callback while the next click picks a face
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
        #: world rotation (3, 3) of part 1: standard views and axis constraints use its axes
        self.frame = np.eye(3)
        self.insertion_axis: np.ndarray | None = None  # (3,) world unit vector, or None
        self.constraint = "free"
        self._centre_world = np.zeros(3)  # scene box centre, where standard views look
        self._clip_plane = vtk.vtkPlane()
        self._fixed_opacity = 1.0
        self._part_actors: list[list[str]] = []  # actor keys of each part, in scene order
        self.overlapping = False  # the moving part drawn in OVERLAP_COLOUR
        self._clip: tuple[int, float, int] | None = None  # (axis, fraction, side removed)
        self._fixed_bounds = (np.zeros(3), np.zeros(3))  # world box of the fixed part

    # ----------------------------------------------------------------- scene
    def set_scene(self, parts, *, frame: np.ndarray | None = None,
                  insertion_axis: np.ndarray | None = None) -> None:
        """Replace all actors and fit the camera to the new scene (isometric).

        ``parts``: sequence of PartView (last one moves); ``frame`` (3, 3) part 1's world
        rotation; ``insertion_axis`` (3,) the scene's insertion direction in world
        coordinates (None: the scene gives none).
        """
        self.frame = np.eye(3) if frame is None else np.asarray(frame, float)
        if insertion_axis is not None:
            axis = np.asarray(insertion_axis, float)
            insertion_axis = axis / np.linalg.norm(axis)
        self.insertion_axis = insertion_axis
        self.plotter.clear_actors()
        self._actors.clear()
        self._part_actors = []
        self.overlapping = False
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
                self._part_actors.append(["moving", "ghost_edges", "ghost_outline"]
                                         + ([] if self.software_gl else ["ghost"]))
                self._centroid = (np.asarray(part.centre, float) if part.centre is not None
                                  else np.asarray(part.vertices, float).mean(axis=0))
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
                self._part_actors.append([f"fixed_{part.name}"])
                self._fixed_bounds = (pts.min(0), pts.max(0))
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
        for part in parts:
            if part.moving:  # a found fit: part 2's edges where the fit puts it (show_fit)
                mesh = pv.PolyData(np.asarray(part.vertices, float), _faces_to_vtk(part.faces))
                fit = self.plotter.add_mesh(mesh.extract_feature_edges(30), color=FIT_COLOUR,
                                            line_width=2.0, name="fit_edges", pickable=False)
                fit.SetVisibility(False)
                self._actors["fit_edges"] = fit
        axis_line = pv.Line((-0.5, 0.0, 0.0), (0.5, 0.0, 0.0))
        handle = self.plotter.add_mesh(axis_line, color="#111111", line_width=3,
                                       name="axis_handle", pickable=False)
        handle.SetVisibility(False)
        self._actors["axis_handle"] = handle
        self._centre_world = 0.5 * (lo + hi) if np.all(np.isfinite(hi - lo)) else np.zeros(3)
        if "ghost_edges" in self._actors:
            self._ghost_on_top(self._actors["ghost_edges"])
        self.plotter.add_axes()
        self._apply_fixed_look()
        self.reset_camera()
        if self.constraint == "insertion" and self.insertion_axis is None:
            self.set_constraint("free")
        self._update_axis_handle()

    def show_fit(self, matrix: np.ndarray | None,
                 axes: list[tuple[np.ndarray, np.ndarray]] | tuple = ()) -> None:
        """Part 2's edges at a found fit, and its free axes as lines.

        ``matrix``: (4, 4) world transform (None hides them); ``axes``: (world point, unit
        direction) per free axis, drawn as long as the scene.
        """
        edges = self._actors.get("fit_edges")
        if edges is None:
            return
        self.plotter.remove_actor("fit_axes")
        if matrix is None:
            edges.SetVisibility(False)
        else:
            _set_matrix(edges, np.asarray(matrix, float))
            edges.SetVisibility(True)
            if axes:
                half = 0.8 * self._size
                lines = pv.merge([pv.Line(p - half * d, p + half * d) for p, d in
                                  ((np.asarray(p, float), np.asarray(d, float))
                                   for p, d in axes)])
                self.plotter.add_mesh(lines, color=FIT_COLOUR, line_width=3,
                                      name="fit_axes", pickable=False)
        self._dirty = True

    # ----------------------------------------------------------------- camera
    def view_direction(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(direction of projection, view up), world unit vectors, of a standard view."""
        if name == "insertion":
            if self.insertion_axis is None:
                raise ValueError("this scene gives no insertion axis")
            d = np.asarray(self.insertion_axis, float)
            up = self.frame[:, 1] if abs(float(d @ self.frame[:, 2])) > 0.9 else self.frame[:, 2]
            return d, up
        if name not in VIEWS:
            raise ValueError(f"unknown view {name!r}; valid: {', '.join([*VIEWS, 'insertion'])}")
        d, up = (np.asarray(v, float) for v in VIEWS[name])
        d = self.frame @ (d / np.linalg.norm(d))
        return d, self.frame @ up

    def set_view(self, name: str) -> None:
        """Look at the scene along a standard direction (see :data:`VIEWS`) and fit it."""
        direction, up = self.view_direction(name)
        cam = self.plotter.camera
        distance = max(self._size, 1e-9) * 3.0
        cam.SetFocalPoint(*self._centre_world)
        cam.SetPosition(*(self._centre_world - direction * distance))
        cam.SetViewUp(*up)
        cam.OrthogonalizeViewUp()
        self.plotter.reset_camera()
        self.plotter.camera.zoom(1.2)
        self._dirty = True

    def reset_camera(self) -> None:
        """The default camera: isometric, the whole scene in view (orientation included)."""
        self.set_view("iso")

    # ----------------------------------------------------------------- constraints
    def set_constraint(self, name: str) -> None:
        """Constrain drags to an axis ("insertion", "x", "y", "z"; part 1's frame) or "free"."""
        if name not in CONSTRAINTS:
            raise ValueError(f"unknown constraint {name!r}; valid: {', '.join(CONSTRAINTS)}")
        if name == "insertion" and self.insertion_axis is None:
            raise ValueError("this scene gives no insertion axis")
        if name != self.constraint:
            self.constraint = name
            self._update_axis_handle()
            self.constraint_changed.emit(name)

    def constraint_axis(self) -> np.ndarray | None:
        """(3,) world unit vector drags are held to, or None for a free drag."""
        if self.constraint == "free":
            return None
        if self.constraint == "insertion":
            return self.insertion_axis
        return self.frame[:, "xyz".index(self.constraint)]

    def _update_axis_handle(self) -> None:
        """Draw the constraint axis through the proxy's centre (hidden for a free drag)."""
        handle = self._actors.get("axis_handle")
        if handle is None:
            return
        axis = self.constraint_axis()
        if axis is None:
            if handle.GetVisibility():
                handle.SetVisibility(False)
                self._dirty = True
            return
        x = np.asarray(axis, float)
        helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0, 0])
        y = np.cross(helper, x)
        y /= np.linalg.norm(y)
        z = np.cross(x, y)
        length = 1.6 * self._size
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2] = x * length, y, z
        m[:3, 3] = self._drag_centre()
        _set_matrix(handle, m)
        handle.GetProperty().SetColor(pv.Color(AXIS_COLOURS[self.constraint]).float_rgb)
        handle.SetVisibility(True)
        self._dirty = True

    # ----------------------------------------------------------------- the fixed part
    def _ghost_on_top(self, edges) -> None:
        """Draw the ghost's feature edges and silhouette over everything (the overlay layer).

        A ghost inside or behind the opaque part, or on it, stays visible.
        """
        self.plotter.renderer.RemoveActor(edges)
        self._overlay.AddActor(edges)
        silhouette = vtk.vtkPolyDataSilhouette()
        silhouette.SetInputData(self._actors["moving"].GetMapper().GetInput())
        silhouette.SetCamera(self.plotter.renderer.GetActiveCamera())
        silhouette.SetEnableFeatureAngle(False)
        mapper = vtk.vtkPolyDataMapper()
        mapper.SetInputConnection(silhouette.GetOutputPort())
        outline = vtk.vtkActor()
        outline.SetMapper(mapper)
        outline.GetProperty().SetColor(pv.Color(GHOST_COLOUR).float_rgb)
        outline.GetProperty().SetLineWidth(edges.GetProperty().GetLineWidth())
        outline.GetProperty().SetLighting(False)
        outline.PickableOff()
        silhouette.SetProp3D(outline)  # the silhouette of the ghost where it is placed
        outline.SetUserMatrix(_vtk_matrix(np.eye(4)))
        outline.GetUserMatrix().DeepCopy(edges.GetUserMatrix())
        self._overlay.AddActor(outline)
        self._actors["ghost_outline"] = outline

    def set_part_visible(self, index: int, shown: bool) -> None:
        """Show or hide part ``index`` of the scene (the moving part with its ghost)."""
        if not 0 <= index < len(self._part_actors):
            return
        for key in self._part_actors[index]:
            self._actors[key].SetVisibility(bool(shown))
        self.request_render()

    def set_overlap(self, overlapping: bool) -> None:
        """Draw the moving part red while it interpenetrates the fixed part, else orange."""
        actor = self._actors.get("moving")
        if actor is None or overlapping == self.overlapping:
            return
        self.overlapping = overlapping
        actor.GetProperty().SetColor(pv.Color(OVERLAP_COLOUR if overlapping
                                              else MOVING_COLOUR).float_rgb)
        self.request_render()

    def set_fixed_opacity(self, opacity: float) -> None:
        """Opacity of the fixed part, 0.05 (nearly clear) to 1 (solid)."""
        self._fixed_opacity = min(max(float(opacity), 0.05), 1.0)
        self._apply_fixed_look()

    def set_clip(self, clip: tuple[int, float, int] | None) -> None:
        """Clip the fixed part by a plane, or not (None).

        ``clip = (axis, fraction, side)``: the plane is normal to axis 0, 1 or 2 of part 1's
        frame, at ``fraction`` (0..1) of the part's extent along it; the side towards
        ``side`` (+1 or -1) times the axis is cut away.
        """
        self._clip = None if clip is None else (int(clip[0]), float(clip[1]), int(clip[2]))
        self._apply_fixed_look()

    def _apply_fixed_look(self) -> None:
        lo, hi = self._fixed_bounds
        for key, actor in self._actors.items():
            if not key.startswith("fixed_"):
                continue
            actor.GetProperty().SetOpacity(self._fixed_opacity)
            mapper = actor.GetMapper()
            mapper.RemoveAllClippingPlanes()
            if self._clip is not None:
                axis, fraction, side = self._clip
                normal = self.frame[:, axis]
                # the box's extent along the normal, in world coordinates
                corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                                    for c in (lo[2], hi[2])])
                along = corners @ normal
                origin = self._centre_world + normal * (
                    along.min() + fraction * (along.max() - along.min())
                    - float(self._centre_world @ normal))
                self._clip_plane.SetOrigin(*origin)
                # VTK keeps the side the plane's normal points to
                self._clip_plane.SetNormal(*(-side * normal))
                mapper.AddClippingPlane(self._clip_plane)
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
            for key in GHOST_LINES:
                _set_matrix(self._actors[key], m)
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

    def pick_face(self, pos: QtCore.QPointF) -> tuple[str, int] | None:
        """(actor name, triangle index) of the shown part under ``pos``, or None.

        The names are ``"moving"`` and ``"fixed_<part name>"``; the index is the part's own
        triangle (the meshes keep the parts' face order).
        """
        keys = [k for k, a in self._actors.items()
                if (k == "moving" or k.startswith("fixed_")) and a.GetVisibility()]
        picker = vtk.vtkCellPicker()
        picker.SetTolerance(0.0005)
        picker.PickFromListOn()
        pickable = {k: self._actors[k].GetPickable() for k in keys}
        for k in keys:
            self._actors[k].PickableOn()
            picker.AddPickList(self._actors[k])
        try:
            x, y = self._display_xy(pos)
            if not picker.Pick(x, y, 0.0, self.plotter.renderer):
                return None
            actor, cell = picker.GetActor(), int(picker.GetCellId())
        finally:
            for k, was in pickable.items():
                self._actors[k].SetPickable(was)
        for k in keys:
            if self._actors[k] is actor and cell >= 0:
                return k, cell
        return None

    def pick_next_face(self, callback) -> None:
        """Let the next left click pick a face (:meth:`pick_face`): ``callback(result)``.

        That click neither drags nor turns the camera; a click on nothing gives None.
        """
        self._face_pick = callback
        self.widget.setCursor(QtCore.Qt.CrossCursor)

    # ----------------------------------------------------------------- dragging
    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        """Drag the proxy with the left mouse button when the press hits the moving part.

        While dragging, mouse moves and the release move the proxy and the wheel changes the drag
        depth. Returns True for events it used, which the 3D view then does not see (so the
        camera does not turn while a part is dragged).
        """
        et = event.type()
        if et == QtCore.QEvent.MouseButtonPress and event.button() == QtCore.Qt.LeftButton:
            if self._face_pick is not None:
                callback, self._face_pick = self._face_pick, None
                self.widget.unsetCursor()
                callback(self.pick_face(event.position()))
                return True
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

    def _drag_centre(self) -> np.ndarray:
        """(3,) world position of the proxy's pivot (what drags turn about)."""
        return posemath.pose_to_matrix(self._proxy_pose)[:3] @ np.append(self._centroid, 1.0)

    def _begin_drag(self, pos: QtCore.QPointF, mods) -> None:
        centre = self._drag_centre()
        disp = self._world_to_display(centre)
        x, y = self._display_xy(pos)
        self._drag = {
            "start_pos": QtCore.QPointF(pos),
            "start_xy": (x, y),
            "start_pose": self._proxy_pose.copy(),
            "centre": centre,
            "centre_disp": disp,
            "grab_world": self._display_to_world(x, y, disp[2]),  # on the view plane
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
        axis = self.constraint_axis()
        pose = d["start_pose"].copy()
        if mods & QtCore.Qt.ControlModifier:
            cx, cy = d["centre_disp"][0], d["centre_disp"][1]
            radius = 0.35 * min(self.plotter.width(), self.plotter.height())
            radius *= self.plotter.devicePixelRatioF()
            if axis is None:
                v0 = geometry.arcball_vector(*d["start_xy"], cx, cy, radius)
                v1 = geometry.arcball_vector(x, y, cx, cy, radius)
                rv = basis @ geometry.arcball_rotation(v0, v1)
            else:  # about the constraint axis: horizontal travel of a radius is a radian
                rv = np.asarray(axis) * (x - d["start_xy"][0]) / radius
            pose = posemath.rotate_about(pose, rv, d["centre"])
        elif axis is not None:
            if mods & QtCore.Qt.ShiftModifier:
                step = (y - d["start_xy"][1]) * self._world_per_pixel(d)
            else:
                step = self._along_axis(x, y, d, axis)
            pose[:3] += np.asarray(axis) * (step + d["depth"])
        elif mods & QtCore.Qt.ShiftModifier:
            world_per_px = self._world_per_pixel(d)
            pose[:3] += basis[:, 2] * (y - d["start_xy"][1]) * world_per_px
        else:
            now = self._display_to_world(x, y, d["centre_disp"][2])
            pose[:3] += now - d["grab_world"]
        if axis is None:
            pose[:3] += basis[:, 2] * d["depth"]
        self._proxy_pose = pose
        m = posemath.pose_to_matrix(pose)
        _set_matrix(self._actors["ghost"], m)
        for key in GHOST_LINES:
            _set_matrix(self._actors[key], m)
        self._update_axis_handle()
        self._dirty = True
        self.proxy_dragged.emit(pose.copy())

    def _along_axis(self, x: float, y: float, d, axis: np.ndarray) -> float:
        """How far along ``axis`` (from the grab point) the mouse ray at (x, y) passes nearest.

        When the axis points nearly at the camera the ray cannot pick a point on it; then
        the vertical mouse travel moves along the axis, as Shift does.
        """
        a = np.asarray(axis, float)
        near = self._display_to_world(x, y, 0.0)
        far = self._display_to_world(x, y, 1.0)
        ray = far - near
        ray /= np.linalg.norm(ray)
        w = d["grab_world"] - near
        b = float(a @ ray)
        denominator = 1.0 - b * b
        if denominator < 0.02:  # within about 8 degrees of the line of sight
            return (y - d["start_xy"][1]) * self._world_per_pixel(d)
        # closest points of the lines grab + s a and near + u ray
        return float((b * (w @ ray) - (w @ a)) / denominator)

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
