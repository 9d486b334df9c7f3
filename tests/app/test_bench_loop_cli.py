"""`skelasm bench loop` from the command line: the table it prints, and bad flag combinations."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def bench(*args):
    return subprocess.run([sys.executable, "-m", "app", "bench", "loop", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


def table_row(out):
    row = [line for line in out.stdout.splitlines() if re.match(r"\| \d+ \|", line)]
    assert len(row) == 1
    return [float(x) for x in row[0].strip("|").split("|")[:4]]


def test_bench_loop_prints_rate_and_periods():
    out = bench("--fake", "--seconds", "1", "--plot", "")
    assert out.returncode == 0, out.stderr
    steps, seconds, rate, median = table_row(out)
    assert steps >= 990 and seconds > 0 and rate > 0 and median > 0  # 1 s of 1 kHz steps
    assert "goal (rate >= 990 Hz, p99 <= 1200 us):" in out.stdout


@pytest.mark.slow
def test_bench_loop_runs_in_real_time_on_a_quiet_machine():
    # a timing check: slow-marked and skipped under load (a loaded machine stretches the
    # second, which says nothing about the loop)
    load, cpus = os.getloadavg()[0], os.cpu_count() or 1
    if load > 0.5 * cpus:
        pytest.skip(f"load average {load:.1f} on {cpus} CPUs")
    steps, seconds, rate, median = table_row(bench("--fake", "--seconds", "1", "--plot", ""))
    assert 0.9 < seconds < 2.0  # it ran in real time for about a second
    assert 200 < rate <= 1001 and abs(median - 1000.0) < 200  # periods near 1 ms


def test_bench_loop_refuses_thread_and_process_together():
    out = bench("--gui", "--thread", "--process", "--seconds", "1", "--plot", "")
    assert out.returncode == 2
    assert "--thread and --process exclude each other" in out.stderr
