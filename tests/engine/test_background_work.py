"""One interface for background work: JobWorker, which the engine and the window submit to.

A newer job of a kind supersedes the older one (cancelled if queued, told to stop if
running); the window makes no thread or pool of its own.
"""

from __future__ import annotations

import ast
import threading
from pathlib import Path

import pytest

from engine.errors import Cancelled
from engine.runtime import BackgroundWork, JobWorker

ROOT = Path(__file__).resolve().parents[2]


def test_the_job_worker_is_the_background_work_interface():
    worker = JobWorker(name="skelasm-test")
    try:
        assert isinstance(worker, BackgroundWork)
    finally:
        worker.shutdown(0.0)


def test_a_newer_job_of_a_kind_supersedes_the_older_one():
    worker = JobWorker(name="skelasm-test")
    started, release = threading.Event(), threading.Event()
    seen: list[str] = []

    def first(cancelled):
        started.set()
        release.wait(5.0)
        if cancelled():
            seen.append("first told to stop")
            raise Cancelled("superseded")
        seen.append("first finished")

    def queued(cancelled):
        seen.append("queued ran")

    def newest(cancelled):
        seen.append("newest ran")

    try:
        worker.submit("profile", first)
        assert started.wait(5.0)
        worker.submit("other", queued)  # another kind is not touched...
        worker.submit("profile", newest)  # ...the same kind is
        release.set()
        assert worker.wait_until_idle(5.0)
    finally:
        worker.shutdown(1.0)
    assert seen == ["first told to stop", "queued ran", "newest ran"]


def test_a_queued_job_is_dropped_when_superseded():
    worker = JobWorker(name="skelasm-test")
    gate = threading.Event()
    ran: list[int] = []
    try:
        worker.submit("block", lambda cancelled: gate.wait(5.0) and None)
        worker.submit("profile", lambda cancelled: ran.append(1))
        worker.submit("profile", lambda cancelled: ran.append(2))  # 1 never starts
        gate.set()
        assert worker.wait_until_idle(5.0)
    finally:
        worker.shutdown(1.0)
    assert ran == [2]


@pytest.mark.parametrize("source", sorted((ROOT / "app").rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_the_window_makes_no_thread_or_pool_of_its_own(source):
    """app/ submits its background work through engine.runtime.JobWorker."""
    own = []
    for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Call):
            name = getattr(node.func, "attr", None) or getattr(node.func, "id", None)
            if name in ("Thread", "ThreadPoolExecutor", "ProcessPoolExecutor", "QThread",
                        "QThreadPool"):
                own.append(f"{source.name}:{node.lineno} {name}")
    assert not own, own
