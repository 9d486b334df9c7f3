"""`skelasm bench accuracy`: the tables' structure, errors shrinking toward the reference,
and the truncation indicator against a direct sum (tiny settings: grid 16, K 8).
"""

from __future__ import annotations

import argparse
import types
from pathlib import Path

import numpy as np
import pytest

from bench import accuracy
from engine.correlation.spectrum import cube_weights, kept_indices
from engine.correlation.truncation import truncation_profile

PEG = str(Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml")


def _args(*extra: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    accuracy.add_arguments(parser)
    return parser.parse_args(["--grid", "16", "--modes", "8", "--poses", "10", *extra])


def _field(shape, seed):
    rng = np.random.default_rng(seed)
    rho = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    return types.SimpleNamespace(rho=rho.astype(np.complex64))


def test_truncation_profile_matches_a_direct_sum_over_the_kept_cube():
    fixed, moving = _field((7, 6, 5), 1), _field((4, 5, 6), 2)
    size = 12
    a = np.abs(np.fft.fftn(fixed.rho, s=(size,) * 3, axes=(0, 1, 2)))
    b = np.abs(np.fft.fftn(moving.rho, s=(size,) * 3, axes=(0, 1, 2)))
    total = np.sum(a * b)
    profile = truncation_profile(fixed, moving, size)
    assert profile.shape == (size + 1,)
    assert profile[0] == pytest.approx(1.0) and profile[size] == pytest.approx(0.0, abs=1e-12)
    for k in (1, 2, 3, 4, 7, 8, 11):
        kept = np.mod(kept_indices(k, size), size)
        inside = np.sum((a * b)[np.ix_(kept, kept, kept)] * cube_weights(k, size))
        assert profile[k] == pytest.approx(1.0 - inside / total, rel=1e-6, abs=1e-9)  # float32 FFT
    assert np.all(np.diff(profile) <= 1e-12)
    # the force's weight is |k| times the energy's: the zero frequency counts for nothing
    force = truncation_profile(fixed, moving, size, quantity="force")
    signed = np.fft.fftfreq(size, 1.0 / size)
    norm = np.sqrt(signed[:, None, None] ** 2 + signed[None, :, None] ** 2
                   + signed[None, None, :] ** 2)
    kept = np.mod(kept_indices(4, size), size)
    weight = a * b * norm
    inside = np.sum(weight[np.ix_(kept, kept, kept)] * cube_weights(4, size))
    expected = 1.0 - inside / np.sum(weight)
    assert force[4] == pytest.approx(expected, rel=1e-6)
    assert force[1] == pytest.approx(1.0)  # K = 1 keeps only k = 0, whose |k| is 0
    with pytest.raises(ValueError, match="valid: energy, force"):
        truncation_profile(fixed, moving, size, quantity="torque")


def test_truncation_profile_refuses_a_grid_larger_than_the_fft():
    with pytest.raises(ValueError, match="fit the FFT size"):
        truncation_profile(_field((13, 4, 4), 0), _field((4, 4, 4), 0), 12)


@pytest.fixture(scope="module")
def peg_rows():
    args = _args("--dials", "modes", "quadrature", "interpolation",
                 "--mode-sweep", "4", "8", "--theta-sweep", "0.7", "0.5", "0.35",
                 "--adaptive-tolerances", "--interpolation-sweep", "1:1", "2:2", "4:2")
    return accuracy.measure(PEG, args)


def _dial(rows, dial):
    return [r for r in rows if r.dial == dial]


def test_every_dial_has_one_reference_row_with_zero_error(peg_rows):
    for dial in ("modes", "quadrature", "interpolation"):
        rows = _dial(peg_rows, dial)
        refs = [r for r in rows if r.reference]
        assert len(refs) == 1, dial
        assert refs[0].energy == 0.0 and refs[0].force == 0.0 and refs[0].torque == 0.0
        for r in rows:
            if not r.reference:
                assert r.energy > 0 and r.force > 0, (dial, r.setting)


def test_errors_shrink_toward_the_reference(peg_rows):
    modes = {r.setting: r for r in _dial(peg_rows, "modes")}
    assert modes["K = 8"].force < modes["K = 4"].force
    assert modes["K = 8"].energy < modes["K = 4"].energy
    # the indicator falls with K, and bounds the measured energy error from above here
    assert 0 < modes["K = 8"].outside < modes["K = 4"].outside < 1
    assert modes["K = 8"].outside_force < modes["K = 4"].outside_force < 1
    # the force reads higher frequencies: more of its weight lies outside a cube
    assert modes["K = 8"].outside_force > modes["K = 8"].outside
    quad = {r.setting: r for r in _dial(peg_rows, "quadrature")}
    assert quad["tree, THETA = 0.5"].rho_l2 < quad["tree, THETA = 0.7"].rho_l2
    # (the force at four poses is not monotone in THETA at the 1e-3 level: the descriptor is)
    interp = [r for r in _dial(peg_rows, "interpolation") if not r.reference]
    assert interp[1].force < interp[0].force  # refine 2 beats the plain lattice


def test_times_are_filled_where_the_dial_costs_them(peg_rows):
    for r in _dial(peg_rows, "modes") + _dial(peg_rows, "interpolation"):
        assert r.pose_us is not None and r.pose_us > 0
        assert r.spectra_s is not None
    # the peg's insertion axis is not free: the seat line is sampled for every truncated K
    assert all(r.seat_cells is not None for r in _dial(peg_rows, "modes") if not r.reference)
    for r in _dial(peg_rows, "quadrature"):
        assert r.descriptor_s is not None and r.descriptor_s > 0 and r.pose_us is None


def test_table_has_a_header_and_one_line_per_row(peg_rows):
    rows = _dial(peg_rows, "modes")
    lines = accuracy.table(rows).splitlines()
    assert lines[0].startswith("| setting | descriptor s | spectra s | per pose us |")
    assert len(lines) == 2 + len(rows)
    assert all(line.count("|") == len(accuracy.COLUMNS) + 1 for line in lines)
    assert "(ref)" in lines[-1] and "full lattice" in lines[-1]


def test_plot_is_written(peg_rows, tmp_path):
    path = tmp_path / "accuracy.png"
    accuracy.plot(peg_rows, str(path))
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_command_line_prints_the_tables_and_refuses_a_missing_folder(tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "a.png"
    status = main(["bench", "accuracy", "--scenes", PEG, "--dials", "interpolation",
                   "--grid", "16", "--modes", "8", "--interpolation-sweep", "1:1", "2:2",
                   "--poses", "5", "-o", str(out)])
    text = capsys.readouterr().out
    assert status == 0 and out.exists()
    assert "### peg_in_hole: interpolation" in text
    assert "| refine 2, oversample 2 (q = 1) (ref) |" in text
    assert main(["bench", "accuracy", "--scenes", PEG, "-o",
                 str(tmp_path / "missing" / "a.png")]) == 2


def test_progress_shows_the_task_and_the_time_left_on_a_terminal_only():
    import io

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    screen = Terminal()
    progress = accuracy.Progress(2, screen)
    progress.begin("pin: modes")
    assert "[0/2] pin: modes" in screen.getvalue() and "left" not in screen.getvalue()
    progress.end()
    progress.begin("pin: grid")
    assert "[1/2] pin: grid" in screen.getvalue() and "s left)" in screen.getvalue()
    piped = io.StringIO()
    quiet = accuracy.Progress(2, piped)
    quiet.begin("pin: modes")
    quiet.end()
    assert piped.getvalue() == ""
