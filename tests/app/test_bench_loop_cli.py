"""`skelasm bench loop` from the command line: the table it prints, and bad flag combinations."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def bench(*args):
    return subprocess.run([sys.executable, "-m", "app", "bench", "loop", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


def test_bench_loop_prints_rate_and_periods():
    out = bench("--fake", "--seconds", "1", "--plot", "")
    assert out.returncode == 0, out.stderr
    row = [line for line in out.stdout.splitlines() if re.match(r"\| \d+ \|", line)]
    assert len(row) == 1
    steps, seconds, rate, median = (float(x) for x in row[0].strip("|").split("|")[:4])
    assert steps >= 200 and 0.9 < seconds < 2.0  # it ran in real time for about a second
    assert 200 < rate <= 1001 and abs(median - 1000.0) < 200  # periods near 1 ms
    assert "goal (rate >= 990 Hz, p99 <= 1200 us):" in out.stdout


def test_bench_loop_refuses_thread_and_process_together():
    out = bench("--gui", "--thread", "--process", "--seconds", "1", "--plot", "")
    assert out.returncode == 2
    assert "--thread and --process exclude each other" in out.stderr
