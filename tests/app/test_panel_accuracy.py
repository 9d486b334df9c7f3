"""What the accuracy setting costs, in the parameter panel: the measured microseconds per
pose, the truncation estimate at K (and at the K a held slider would apply), the last
recompute's seconds; the indicator's worker; the window showing them on a real scene.
"""

from __future__ import annotations

import gc
import types

import numpy as np
import pytest

from app.gui.accuracy import AccuracyIndicator, profile_of
from app.gui.params_panel import ParamsPanel
from engine.correlation import required_fft_size
from engine.correlation.truncation import truncation_profile


@pytest.fixture(autouse=True)
def _collect_after():
    """Free these tests' panels and windows here, not during a later test's measurement
    (tests/app/test_binding.py counts references to None over a live window).
    """
    yield
    gc.collect()


def _descriptor(shape, seed):
    rng = np.random.default_rng(seed)
    rho = (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(np.complex64)
    return types.SimpleNamespace(rho=rho)


def test_panel_shows_the_truncation_share_at_k_and_at_a_previewed_k(qtbot):
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    assert panel.truncation.text() == "-"  # nothing known yet: no number made up
    energy = np.linspace(1.0, 0.0, 49)  # share outside at K = 0 .. 48
    force = np.sqrt(energy)
    panel.modes.setValueSilently(16)
    panel.set_truncation_profile(np.stack([energy, force]))
    assert panel.truncation_at(16) == pytest.approx((energy[16], force[16]))
    assert panel.truncation.text().startswith(
        f"energy ≤ {100 * energy[16]:.2g} %, force ≤ {100 * force[16]:.2g} % at K = 16")
    panel.modes.previewed.emit(32.0)  # the slider held at 32, not yet let go
    text = panel.truncation.text()
    assert text.startswith(f"at K = 32 if applied: energy ≤ {100 * energy[32]:.2g} %, "
                           f"force ≤ {100 * force[32]:.2g} %")
    assert f"(now {100 * energy[16]:.2g} %, {100 * force[16]:.2g} %)" in text
    panel.set_truncation_profile(None)
    assert panel.truncation.text() == "-"


def test_panel_shows_the_median_pose_cost_and_restarts_it_at_a_new_k(qtbot):
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    for us in (10.0, 500.0, 12.0, 11.0, 13.0):  # one slow step does not move the median
        panel.show_pose_cost(us, 16)
    assert panel.pose_cost.text() == "12 µs per pose at K = 16"
    panel.show_pose_cost(90.0, 32)
    assert panel.pose_cost.text() == "90 µs per pose at K = 32"
    panel.show_pose_cost(float("nan"), 32)
    assert panel.pose_cost.text() == "90 µs per pose at K = 32"
    panel.show_descriptor_cost(12.34)
    assert panel.recompute_cost.text() == "last recompute 12.3 s; per pose unchanged"


def test_indicator_computes_off_the_gui_thread_and_keeps_only_the_newest(qtbot):
    indicator = AccuracyIndicator()
    indicator.inline_points = 0  # these small pairs would be done at once
    first = (_descriptor((6, 6, 6), 0), _descriptor((4, 4, 4), 1))
    second = (_descriptor((8, 7, 6), 2), _descriptor((5, 4, 3), 3))
    got = []
    indicator.profile_ready.connect(got.append)
    with qtbot.waitSignal(indicator.profile_ready, timeout=10000):
        indicator.submit(first)
        indicator.submit(second)
    qtbot.wait(200)  # an answer for the first request would have arrived by now
    size = required_fft_size((8, 7, 6), (5, 4, 3))
    assert len(got) == 1
    np.testing.assert_allclose(got[0][0], truncation_profile(*second, size))
    np.testing.assert_allclose(got[0][1], truncation_profile(*second, size, quantity="force"))
    assert profile_of(second[:1]) is None  # guidance off: no pair, no estimate
    indicator.shutdown()


def test_indicator_does_a_small_pair_at_once(qtbot):
    indicator = AccuracyIndicator()
    got = []
    indicator.profile_ready.connect(got.append)
    pair = (_descriptor((6, 6, 6), 0), _descriptor((4, 4, 4), 1))
    indicator.submit(pair)  # no event loop turn needed
    assert len(got) == 1 and got[0].shape == (2, required_fft_size((6, 6, 6), (4, 4, 4)) + 1)
    indicator.submit(())  # guidance off
    assert got[-1] is None
    indicator.shutdown()


def test_window_shows_what_the_accuracy_setting_costs(make_window, small_scene, wait_until,
                                                       tmp_path):
    win = make_window(small_scene)
    panel = win.params
    wait_until(lambda: "µs per pose" in panel.pose_cost.text(), 15000, "the pose cost")
    wait_until(lambda: "%" in panel.truncation.text(), 15000, "the truncation estimate")
    k = int(panel.modes.value())
    assert f"at K = {k}" in panel.pose_cost.text()
    shares = panel.truncation_at(k)
    assert shares is not None and 0.0 <= shares[0] < 1.0 and 0.0 <= shares[1] < 1.0
    # the indicator agrees with the bound computed from the engine's own descriptors
    descriptors = win.slice_view._descriptors
    assert len(descriptors) == 2
    assert shares == pytest.approx(tuple(profile_of(descriptors)[:, k]))
    path = win.save_screenshot(tmp_path / "panel.png", panel)
    assert path.stat().st_size > 1000
