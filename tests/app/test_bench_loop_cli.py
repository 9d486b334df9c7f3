"""`skelasm bench loop` from the command line: the table it prints, and bad flag combinations."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
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
    # the thread engine as start_engine runs it: 0.5 ms, not Python's 5 ms
    assert "mode: thread, load: none, switch interval: 0.0005 s" in out.stdout
    # a thread engine's loop at ordinary priority gives its refresh lane none either
    assert ("loop thread scheduling: normal (not asked for), waiting by spinning (yielding "
            "the CPU); refresh lane: ordinary priority") in out.stdout


def test_bench_loop_gives_each_engine_its_own_switch_interval():
    import argparse

    from bench.loop import switch_interval
    from engine.runtime import DEFAULT_SWITCH_INTERVAL

    def args(**kw):
        base = dict(switch_interval=None, process=False, gui=False, thread=False)
        return argparse.Namespace(**{**base, **kw})

    assert switch_interval(args()) == DEFAULT_SWITCH_INTERVAL  # start_engine's thread engine
    assert switch_interval(args(gui=True, thread=True)) == DEFAULT_SWITCH_INTERVAL
    assert switch_interval(args(process=True)) is None  # Python's, shortened during jobs
    assert switch_interval(args(gui=True)) is None  # the window's engine process
    assert switch_interval(args(switch_interval=0.005)) == 0.005
    assert switch_interval(args(process=True, switch_interval=1e-3)) == 1e-3


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


def test_after_changes_counts_the_periods_that_follow_each_change():
    # 1 ms periods; a 5 ms period 50 ms after the second change, a 3 ms one 300 ms after
    # it (between changes), a 4 ms one before the first change (not counted at all)
    from bench.loop import after_changes

    periods = np.full(2000, 1e-3)
    periods[[100, 1250, 1500]] = (4e-3, 5e-3, 3e-3)
    ends = 10.0 + np.cumsum(periods)
    sent = [float(ends[500]), float(ends[1200])]
    c = after_changes(periods, ends, [9.0, *sent, 13.0])  # outside the periods: left out
    after = ((ends > sent[0]) & (ends <= sent[0] + 0.1)) | ((ends > sent[1])
                                                            & (ends <= sent[1] + 0.1))
    between = ~after & (ends > sent[0])
    assert c["changes"] == 2 and c["changes_late"] == 1
    assert (c["after_n"], c["after_late"]) == (after.sum(), 1)
    assert c["after_max_us"] == pytest.approx(5000.0)
    assert (c["between_n"], c["between_late"]) == (between.sum(), 1)
    assert c["between_max_us"] == pytest.approx(3000.0)


def test_collections_report_places_long_collections_after_changes():
    # collections at 1.0 s (gen 0, 0.1 ms), 2.05 s (gen 1, 1.5 ms: 50 ms after the change at
    # 2.0 s), 2.5 s (gen 2, 80 ms: 500 ms after it), and one at 0.5 s before the measured
    # periods begin (left out, however long)
    from bench.loop import collections_report

    table = np.array([[0.5, 0.2, 2], [1.0, 1e-4, 0], [2.05, 1.5e-3, 1], [2.5, 0.08, 2]])
    g = collections_report(table, begin=0.9, sent=[2.0])
    assert (g["n"], g["full"], g["long"], g["long_after"]) == (3, 1, 2, 1)
    assert g["longest_ms"] == pytest.approx(80.0) and g["longest_generation"] == 2
    none = collections_report(np.zeros((0, 3)), begin=0.0, sent=[])
    assert (none["n"], none["long"], none["longest_generation"]) == (0, 0, -1)


@pytest.mark.parametrize("where", [[], ["--process"]])
def test_bench_loop_counts_the_periods_after_k_changes(where):
    # the process engine's periods come back with their end times on the parent's clock
    out = bench("--fake", "--seconds", "2", "--modes-sweep", "12,8", "--sweep-period",
                "0.4", "--plot", "", *where)
    assert out.returncode == 0, out.stderr
    rows = [line for line in out.stdout.splitlines() if re.match(r"\| \d+ \|", line)]
    assert len(rows) == 2, out.stdout
    seconds = float(rows[0].strip("|").split("|")[1])  # measured, longer on a busy machine
    changes, late, after_n, *_ = (float(x) for x in rows[1].strip("|").split("|"))
    # sends outside the periods' times are left out: a clock not shared, or end times
    # placed wrongly by seconds, leave none (a K change here builds a real field in the
    # worker, which can stall this analytic loop, so the periods after each vary)
    assert 2 <= changes <= seconds / 0.4 + 1  # a loaded machine may delay the sends
    assert 0 <= late <= changes
    assert changes <= after_n <= 101 * changes
    # the loop's process reports its garbage collections (both transports)
    gc_line = re.search(r"garbage collections in the loop's process: (\d+) \((\d+) full\), "
                        r"(\d+) over 1 ms \((\d+) within 100 ms after a change\)", out.stdout)
    assert gc_line is not None, out.stdout
    n, full, long, long_after = (int(x) for x in gc_line.groups())
    assert full <= n and long_after <= long <= n
    # the thread engine reports its hand-overs (the process engine's stay in its process)
    held = re.search(r"held back until a cache served the part: held (\d+), served (\d+), "
                     r"gave_up (\d+), dropped (\d+)", out.stdout)
    assert (held is not None) == (not where), out.stdout
    if held:
        # each field held was handed over one way or the other, or dropped for a newer
        # one (on a busy machine a build can outlast the time between changes); one may
        # be held at the end
        assert int(held[1]) - int(held[2]) - int(held[3]) - int(held[4]) in (0, 1)


def test_bench_loop_refuses_thread_and_process_together():
    out = bench("--gui", "--thread", "--process", "--seconds", "1", "--plot", "")
    assert out.returncode == 2
    assert "--thread and --process exclude each other" in out.stderr


@pytest.mark.parametrize("control", [False, True])
def test_the_sweep_control_marks_the_same_times_and_sends_nothing(control):
    import argparse
    import threading
    import time

    from bench.loop import _sweeper
    from engine.runtime import SetModes

    args = argparse.Namespace(modes_sweep="12,8", sweep_period=0.02, sweep_control=control)
    sent, commands, stop = [], [], threading.Event()
    thread = _sweeper(args, commands.append, stop, sent)
    thread.start()
    deadline = time.monotonic() + 10.0
    while len(sent) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    thread.join(5.0)
    assert len(sent) >= 3 and sent == sorted(sent)
    if control:
        assert commands == []
    else:
        assert commands[:3] == [SetModes(12), SetModes(8), SetModes(12)]


def test_bench_loop_says_where_a_k_changes_jobs_run():
    import argparse

    from bench.loop import add_arguments, job_process

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert job_process(parser.parse_args([])) is None  # the engine decides
    assert job_process(parser.parse_args(["--jobs", "here"])) is False
    assert job_process(parser.parse_args(["--jobs", "process"])) is True
    with pytest.raises(SystemExit):
        parser.parse_args(["--jobs", "elsewhere"])
