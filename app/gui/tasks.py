"""The engine's background tasks as the window tells them: what, how far, how long left.

Data: one :class:`Task` per engine task name (the ``task`` of ``engine.runtime.ProgressEvent``:
"correlator", "descriptors", "field", "landscape", "ladder"), labelled in words by the window
when it asks for the work (it knows why: a new K, a locked rotation, new descriptor
parameters), and advanced by the engine's progress events. No Qt here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from app.gui.quantities import ProgressClock, duration_text


@dataclass
class Task:
    """One running background task: its label in words and its clock."""

    label: str
    clock: ProgressClock = field(default_factory=ProgressClock)
    #: the engine reports fractions for it (False: only "done" comes; the elapsed time shows)
    reports_fraction: bool = True

    def text(self) -> str:
        """"preparing descriptors: 42 %, about 1 min 10 s left" or "...: 3 s so far"."""
        if not self.reports_fraction:
            return f"{self.label}: {duration_text(self.clock.elapsed)} so far"
        return f"{self.label}: {self.clock.text()}"


class TaskBoard:
    """The tasks running now, by engine task name."""

    #: What a task is called when the engine reports one the window did not start.
    LABELS = {
        "open": "opening the scene",
        "correlator": "preparing descriptors and correlation tables",
        "descriptors": "recomputing descriptors",
        "field": "building the correlation tables",
        "landscape": "computing the energy landscape",
        "ladder": "preparing live sigma",
    }

    def __init__(self) -> None:
        self.tasks: dict[str, Task] = {}

    def start(self, task: str, label: str | None = None, *, reports_fraction: bool = True) -> Task:
        """A task the window asked for; replaces one of the same name (it was superseded)."""
        entry = Task(label or self.LABELS.get(task, task), reports_fraction=reports_fraction)
        self.tasks[task] = entry
        return entry

    def progress(self, task: str, fraction: float) -> Task:
        """The engine reported ``fraction`` of ``task``."""
        entry = self.tasks.get(task)
        if entry is None:
            entry = self.start(task)
        entry.reports_fraction = True
        entry.clock.update(fraction)
        return entry

    def finish(self, task: str) -> None:
        """``task`` ended (done, cancelled or failed)."""
        self.tasks.pop(task, None)

    def clear(self) -> None:
        """Forget every task (a new scene)."""
        self.tasks.clear()

    def get(self, task: str) -> Task | None:
        """The running task of that name, or None."""
        return self.tasks.get(task)

    def summary(self, *, min_seconds: float = 1.0) -> str:
        """The running tasks older than ``min_seconds``, in words ("" when none)."""
        shown = [t.text() for t in self.tasks.values() if t.clock.elapsed >= min_seconds]
        return "; ".join(shown)
