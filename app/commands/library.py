"""`skelasm precompute PART PART ...`: the descriptors of a parts library, one task per part.

Each part is loaded, gridded and computed exactly as ``skelasm precompute PART`` does it, and
lands in the content-keyed cache (``engine.descriptor.store``), or with ``-o DIR`` also in
``DIR/<stem>.npz``. The parts run one after another in this process, or with ``--workers N``
on a local Dask cluster of N processes, or with ``--scheduler ADDRESS`` on a running one
(``engine.search.distributed.DaskWork``): a task per part. The numbers are the same either
way (each task computes its part on one thread, as a grid point's sum does not depend on
the thread it runs on).

A run is resumable: a part whose descriptor is cached loads in well under a second, and a
part whose ``DIR/<stem>.npz`` exists is kept as it is (``--force`` computes and replaces
it). A part that fails (a corrupt file) is reported on its own line and the others go on;
the exit status is then 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from engine.errors import InputError


@dataclass(frozen=True)
class PartJob:
    """What one task needs: the part's file and the grid and parameters to compute it on."""

    path: str
    tolerance: float | None
    samples: int | None
    spacing: float | None
    padding: float
    params: Any  # engine.params.DescriptorParams
    method: str
    backend: str | None
    use_cache: bool
    output: str | None


def compute_part(job: PartJob, cancelled=None) -> dict:
    """Load, grid and compute one part; returns its record (an ``error`` key on failure).

    ``cancelled`` is the work driver's callable (unused: a part runs to its end).
    """
    from engine.descriptor import descriptor_for_part, grid_for_part
    from engine.errors import ResourceError
    from engine.loading import load_part

    start = time.perf_counter()
    try:
        part = load_part(job.path, tolerance=job.tolerance)
        grid = grid_for_part(part, samples=job.samples, spacing=job.spacing,
                             padding=job.padding)
        descriptor = descriptor_for_part(part, grid, job.params, backend=job.backend,
                                         method=job.method, use_cache=job.use_cache)
        written = descriptor.save(Path(job.output)) if job.output else None
    except (ResourceError, OSError, ValueError, MemoryError) as exc:  # InputError too
        return {"part": job.path, "error": str(exc),
                "seconds": round(time.perf_counter() - start, 3)}
    from app.commands.precompute import _record

    return _record(descriptor, part, written, job.samples)


def _jobs(args: argparse.Namespace, paths: list[Path], params) -> tuple[list[PartJob], list]:
    """(jobs to run, records of outputs kept as they are)."""
    from app.commands.precompute import _output_folder, _samples_padding

    folder = _output_folder(args, "for several parts")
    stems = [p.stem for p in paths]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if folder is not None and twice:
        raise InputError(f"two parts would write {folder / (twice[0] + '.npz')}: give parts "
                         "with different names, or leave out -o (the cache keeps both)")
    samples, padding = _samples_padding(args)
    jobs, kept = [], []
    for path in paths:
        output = None if folder is None else folder / f"{path.stem}.npz"
        if output is not None and output.exists() and not args.force:
            kept.append({"part": str(path), "output": str(output.resolve()), "kept": True})
            continue
        jobs.append(PartJob(str(path), args.tolerance, samples, args.spacing, padding, params,
                            args.method, args.backend, not args.no_cache,
                            None if output is None else str(output)))
    return jobs, kept


def run_library(args: argparse.Namespace, paths: list[Path], params) -> int:
    """Compute every part of ``paths`` (see the module). Returns the exit status."""
    for path in paths:
        if path.suffix.lower() == ".toml":
            raise InputError(f"{path}: a scene among several parts; precompute a scene on "
                             "its own (skelasm precompute SCENE)")
        if not path.is_file():
            raise InputError(f"{path}: no such part file")
    if args.body is not None:
        raise InputError("--body picks a solid of one STEP file; give the parts one by one")
    if args.device is not None:
        raise InputError("--device applies to one part; a library runs on each worker's "
                         "backend (--backend)")
    jobs, records = _jobs(args, paths, params)
    work, where = None, "this process"
    if jobs and (args.workers is not None or args.scheduler is not None):
        from engine.search.distributed import DaskWork

        work = DaskWork.connect(args.scheduler, workers=args.workers or 2)
        where = (f"the Dask scheduler at {args.scheduler}" if args.scheduler
                 else f"a local Dask cluster of {args.workers} processes")
    if not args.json:
        print(f"{len(jobs)} of {len(paths)} parts to compute on {where}"
              + (f" ({len(records)} kept in {args.output})" if records else ""),
              file=sys.stderr)
    start = time.perf_counter()
    try:
        done = _run_jobs(jobs, work, args, start)
    finally:
        if work is not None:
            work.shutdown()
    records += done
    failed = [r for r in records if "error" in r]
    if args.json:
        print(json.dumps({"parts": records, "failed": len(failed),
                          "seconds": round(time.perf_counter() - start, 3)}))
    return 2 if failed else 0


def _run_jobs(jobs: list[PartJob], work, args: argparse.Namespace, start: float) -> list:
    records: list[dict] = []

    def report(rec: dict) -> None:
        records.append(rec)
        if args.json:
            return
        n, total = len(records), len(jobs)
        elapsed = time.perf_counter() - start
        left = elapsed / n * (total - n)
        if "error" in rec:
            print(f"error: {rec['error']}", file=sys.stderr)
        else:
            from app.commands.precompute import _describe

            print(_describe(rec))
        print(f"  {n} of {total} done, {elapsed:.0f} s, about {left:.0f} s left",
              file=sys.stderr)

    if work is None:
        for job in jobs:
            report(compute_part(job))
        return records
    for i, job in enumerate(jobs):
        work.submit(f"part-{i}", partial(compute_part, job))
    while len(records) < len(jobs):
        work.wait_until_idle(1.0)
        for rec in work.responses():
            report(rec)
    return records
