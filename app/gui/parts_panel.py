"""The parts list and the pose history.

:class:`PartsPanel` lists the open scene's parts (shown or hidden, name, file, unit,
triangles, whether the mesh is closed, which one moves); its check boxes show and hide the
parts in the 3D view. :class:`PoseHistory` keeps the poses the part and its ghost had before
each drag, typed pose or reset, for Undo and Redo.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtWidgets

#: Undo levels kept.
HISTORY_LEVELS = 30

COLUMNS = ("show", "name", "file", "unit", "triangles", "closed", "role")


def watertight(faces: np.ndarray) -> bool:
    """True when every edge of the triangles ``faces`` (m, 3) is shared by exactly two."""
    f = np.asarray(faces, np.int64)
    if f.size == 0:
        return False
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


class PartsPanel(QtWidgets.QTableWidget):
    """One row per part; the first column's check box shows or hides it.

    Signals
    -------
    visibility_changed(int, bool)
        The part's index in the scene and whether it is shown.
    """

    visibility_changed = QtCore.Signal(int, bool)

    def __init__(self, parent=None):
        super().__init__(0, len(COLUMNS), parent)
        self.setHorizontalHeaderLabels(list(COLUMNS))
        self.verticalHeader().setVisible(False)
        self.setEditTriggers(QtWidgets.QAbstractItemView.NoEditTriggers)
        self.setSelectionMode(QtWidgets.QAbstractItemView.NoSelection)
        self.horizontalHeader().setStretchLastSection(True)
        self.itemChanged.connect(self._item_changed)

    def set_parts(self, handle) -> None:
        """List ``handle``'s parts (an ``engine.runtime`` scene handle; None: none)."""
        self.blockSignals(True)
        self.setRowCount(0)
        if handle is not None:
            specs = handle.scene.parts
            for i, (part, spec) in enumerate(zip(handle.parts, specs, strict=True)):
                self.insertRow(i)
                moving = i == 1 and len(handle.parts) > 1
                show = QtWidgets.QTableWidgetItem()
                show.setFlags(QtCore.Qt.ItemIsUserCheckable | QtCore.Qt.ItemIsEnabled)
                show.setCheckState(QtCore.Qt.Checked)
                show.setToolTip("show or hide the part in the 3D view")
                cells = [show, QtWidgets.QTableWidgetItem(part.name),
                         QtWidgets.QTableWidgetItem(Path(spec.file).name),
                         QtWidgets.QTableWidgetItem(spec.unit or part.unit),
                         QtWidgets.QTableWidgetItem(f"{len(part.faces):,}"),
                         QtWidgets.QTableWidgetItem("yes" if watertight(part.faces) else "no"),
                         QtWidgets.QTableWidgetItem("moves" if moving else "fixed")]
                cells[2].setToolTip(str(spec.file))
                cells[5].setToolTip("closed: every edge joins exactly two triangles")
                for column, item in enumerate(cells):
                    self.setItem(i, column, item)
        self.blockSignals(False)
        self.resizeColumnsToContents()

    def shown(self, index: int) -> bool:
        """Whether part ``index`` is ticked as shown."""
        item = self.item(index, 0)
        return item is not None and item.checkState() == QtCore.Qt.Checked

    def set_shown(self, index: int, shown: bool) -> None:
        """Tick or untick part ``index`` (the view follows through the signal)."""
        self.item(index, 0).setCheckState(QtCore.Qt.Checked if shown else QtCore.Qt.Unchecked)

    def _item_changed(self, item: QtWidgets.QTableWidgetItem) -> None:
        if item.column() == 0:
            self.visibility_changed.emit(item.row(), item.checkState() == QtCore.Qt.Checked)


class PoseHistory:
    """Undo and redo of the moving part's pose: (part pose, proxy pose) pairs, part 1's frame.

    ``push`` before a change; ``undo(now)`` gives the state to go back to and keeps ``now``
    for ``redo``. A push clears the redo list.
    """

    def __init__(self, levels: int = HISTORY_LEVELS):
        self.levels = levels
        self._undo: list[tuple[np.ndarray, np.ndarray]] = []
        self._redo: list[tuple[np.ndarray, np.ndarray]] = []

    def push(self, part_pose, proxy_pose) -> None:
        """Remember the state before a change."""
        state = (np.array(part_pose, float), np.array(proxy_pose, float))
        if self._undo and all(np.array_equal(a, b) for a, b in zip(self._undo[-1], state,
                                                                   strict=True)):
            return  # the same state twice (a click without a move): one level
        self._undo.append(state)
        del self._undo[:-self.levels]
        self._redo.clear()

    def undo(self, part_pose, proxy_pose) -> tuple[np.ndarray, np.ndarray] | None:
        """The state before the last change (None: nothing to undo); ``now`` goes to redo."""
        if not self._undo:
            return None
        self._redo.append((np.array(part_pose, float), np.array(proxy_pose, float)))
        return self._undo.pop()

    def redo(self, part_pose, proxy_pose) -> tuple[np.ndarray, np.ndarray] | None:
        """The state the last undo left (None: nothing to redo)."""
        if not self._redo:
            return None
        self._undo.append((np.array(part_pose, float), np.array(proxy_pose, float)))
        return self._redo.pop()

    def clear(self) -> None:
        """Forget everything (a new scene)."""
        self._undo.clear()
        self._redo.clear()

    @property
    def depth(self) -> tuple[int, int]:
        """Levels to undo and to redo."""
        return len(self._undo), len(self._redo)
