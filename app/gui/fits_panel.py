"""The Fits dock: where part 2 goes and what joint it makes, found by the search.

"Find fits" runs :func:`engine.search.search_scene` on the open scene off the GUI thread (the
engine's :class:`engine.runtime.JobWorker`; the window's engine keeps running), with its
progress, the time left and Cancel. The fits come as a list, lowest energy first: the joint
kind and its confidence, the free axes, where part 2 sits; the chosen one is drawn in the 3D
view (part 2's edges there, green, and its free axes as lines). "Place the part there" puts
part 2 and its ghost at the fit, at rest; "Use as the seat…" opens Edit > Set up the fit with
the fit's pose and free axes filled in, to be saved with the scene.
"""

from __future__ import annotations

import math

import numpy as np
from PySide6 import QtCore, QtWidgets

from engine.runtime import JobWorker


def fit_pose(fit) -> np.ndarray:
    """(6,) origin pose of a found fit (translation, rotation vector in radians)."""
    from engine.pose import rotation_vector

    return np.concatenate([np.asarray(fit.translation, float), rotation_vector(fit.rotation)])


class FitsPanel(QtWidgets.QWidget):
    """The search's fits (see the module docstring).

    Signals
    -------
    chosen(object)
        The fit chosen in the list (an ``engine.search.Fit``), or None.
    place(object)
        (6,) origin pose to put part 2 at, at rest.
    use_as_seat(object)
        The fit to set up as the scene's seat.
    """

    chosen = QtCore.Signal(object)
    place = QtCore.Signal(object)
    use_as_seat = QtCore.Signal(object)
    _progressed = QtCore.Signal(int, float, object)
    _answered = QtCore.Signal(int, object, str)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self._worker = JobWorker(name="skelasm-find-fits")
        self._request = 0
        self.fits: tuple = ()
        self.unit = "mm"
        lay = QtWidgets.QVBoxLayout(self)
        row = QtWidgets.QHBoxLayout()
        self.find = QtWidgets.QPushButton("Find fits")
        self.find.setObjectName("find_fits")
        self.find.setToolTip("Search every rotation of part 2 (576, 30 degrees apart) and "
                             "every translation for the poses of lowest energy, and tell "
                             "each fit's joint (docs/search.md)")
        self.cancel = QtWidgets.QPushButton("Cancel")
        self.cancel.setEnabled(False)
        row.addWidget(self.find)
        row.addWidget(self.cancel)
        lay.addLayout(row)
        self.progress = QtWidgets.QProgressBar()
        self.progress.setRange(0, 1000)
        self.progress.setFormat("no search yet")
        self.progress.setTextVisible(True)
        lay.addWidget(self.progress)
        self.list = QtWidgets.QListWidget()
        self.list.setObjectName("fits_list")
        lay.addWidget(self.list, 1)
        row = QtWidgets.QHBoxLayout()
        self.place_button = QtWidgets.QPushButton("Place the part there")
        self.seat_button = QtWidgets.QPushButton("Use as the seat…")
        for b in (self.place_button, self.seat_button):
            b.setEnabled(False)
            row.addWidget(b)
        lay.addLayout(row)
        self.cancel.clicked.connect(self.stop)
        self.list.currentRowChanged.connect(self._row)
        self.place_button.clicked.connect(lambda: self._with_fit(
            lambda f: self.place.emit(fit_pose(f))))
        self.seat_button.clicked.connect(lambda: self._with_fit(self.use_as_seat.emit))
        # emitted from the worker, delivered on the GUI's thread
        self._progressed.connect(self._show_progress, QtCore.Qt.QueuedConnection)
        self._answered.connect(self._deliver, QtCore.Qt.QueuedConnection)

    # ------------------------------------------------------------------ the search
    def start(self, scene, unit: str) -> None:
        """Search ``scene`` (an ``engine.scene.Scene``) in the background."""
        from engine.search import search_scene

        self._request += 1
        request = self._request
        self.unit = unit
        self.set_fits(())
        self.find.setEnabled(False)
        self.cancel.setEnabled(True)
        self.progress.setValue(0)
        self.progress.setFormat("finding fits: preparing the descriptors %p%")

        def work(cancelled) -> None:
            def progress(fraction: float, left: float | None) -> None:
                self._progressed.emit(request, float(fraction), left)

            try:
                result = search_scene(scene, progress=progress, cancel=cancelled)
            except Exception as exc:  # noqa: BLE001 - said in the panel, never raised here
                if not cancelled():
                    self._answered.emit(request, None, f"{type(exc).__name__}: {exc}")
                return
            self._answered.emit(request, result, "")

        self._worker.submit("search", work)

    def stop(self) -> None:
        """Cancel the search running."""
        self._request += 1
        self._worker.cancel("search")
        self._idle("cancelled")

    def shutdown(self) -> None:
        """Drop the search (the window closes)."""
        self._request += 1
        self._worker.shutdown(timeout=0.0)

    def wait_until_idle(self, timeout: float = 120.0) -> bool:
        """Wait until the search has finished (tests); True when it has."""
        return self._worker.wait_until_idle(timeout)

    def _idle(self, text: str) -> None:
        self.find.setEnabled(True)
        self.cancel.setEnabled(False)
        self.progress.setFormat(text)

    def _show_progress(self, request: int, fraction: float, left) -> None:
        if request != self._request:
            return
        self.progress.setValue(int(round(1000 * min(max(fraction, 0.0), 1.0))))
        suffix = f", about {left:.0f} s left" if left is not None else ""
        self.progress.setFormat(f"finding fits %p%{suffix}")

    def _deliver(self, request: int, result, message: str) -> None:
        if request != self._request:
            return
        if result is None:
            self._idle(f"the search failed: {message}")
            return
        self.progress.setValue(1000)
        count = len(result.fits)
        self._idle(f"{count} fit{'s' if count != 1 else ''} in {result.seconds:.0f} s "
                   f"({result.settings.rotations} rotations)")
        self.set_fits(result.fits)

    # ------------------------------------------------------------------ the list
    def set_fits(self, fits) -> None:
        """Show ``fits`` (``engine.search.Fit``, best first); the first is chosen."""
        from engine.search.joint import axis_names

        self.fits = tuple(fits)
        self.list.blockSignals(True)
        self.list.clear()
        for f in self.fits:
            names, others = axis_names(f.joint)
            free = ", ".join(names) + (f" +{len(others)}" if others else "")
            t = np.asarray(f.translation, float)
            turned = math.degrees(float(np.linalg.norm(fit_pose(f)[3:])))
            item = QtWidgets.QListWidgetItem(
                f"{f.rank}. {f.joint.kind} ({f.joint.confidence:.2f}), free {free or 'none'}")
            item.setToolTip(f"part 2 at ({t[0]:.4g}, {t[1]:.4g}, {t[2]:.4g}) {self.unit}, "
                            f"turned {turned:.1f}° (part 1's frame); energy {f.energy:.4g} "
                            f"per unit kappa; {f.cluster_size} of the scan's candidates")
            self.list.addItem(item)
        self.list.blockSignals(False)
        has = bool(self.fits)
        self.place_button.setEnabled(has)
        self.seat_button.setEnabled(has)
        self.list.setCurrentRow(0 if has else -1)
        if not has:
            self.chosen.emit(None)

    def current(self):
        """The fit chosen, or None."""
        row = self.list.currentRow()
        return self.fits[row] if 0 <= row < len(self.fits) else None

    def _row(self, _row: int) -> None:
        self.chosen.emit(self.current())

    def _with_fit(self, act) -> None:
        fit = self.current()
        if fit is not None:
            act(fit)
