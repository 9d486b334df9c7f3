"""The accuracy indicator's worker: the truncation profile of the descriptors in use.

The engine sends the descriptors it correlates (``ReadyEvent`` and ``DescriptorsSwapped``
carry them for the slice views); from them a background worker (the engine's one
interface for background work, :class:`engine.runtime.JobWorker`) computes, once per pair,
:func:`engine.correlation.truncation.truncation_profile` for the energy and the force: for
every K the share of the correlation spectrum's weight outside the kept cube. The
parameter panel then reads the values at any K without asking anyone. A newer pair
supersedes an older one: the worker cancels it, and an answer for an older request id is
dropped.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore

from engine.runtime import JobWorker


def profile_of(descriptors) -> np.ndarray | None:
    """(2, N + 1) float64: energy and force truncation profiles, None without a pair.

    ``N`` is the pair's padded FFT size as the engine picks it
    (:func:`engine.correlation.required_fft_size` of the first and last grid).
    """
    from engine.correlation import required_fft_size
    from engine.correlation.truncation import truncation_profile

    if len(descriptors) < 2:
        return None
    fixed, moving = descriptors[0], descriptors[-1]
    size = required_fft_size(fixed.rho.shape, moving.rho.shape)
    return np.stack([truncation_profile(fixed, moving, size, quantity=q)
                     for q in ("energy", "force")])


class AccuracyIndicator(QtCore.QObject):
    """Computes truncation profiles off the GUI thread, one pair at a time.

    Signals
    -------
    profile_ready(object)
        The newest pair's profiles ((2, N + 1) float64: energy, force), or None when there
        is no pair or it failed (the panel then shows no estimate).
    """

    profile_ready = QtCore.Signal(object)
    _answered = QtCore.Signal(int, object)

    #: Pairs whose FFT has at most this many points are done at once on the calling
    #: thread (a few milliseconds): a worker thread would then only add GIL hand-offs
    #: that stretch a trivial job across the first live frames.
    inline_points = 64**3

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self._worker = JobWorker(name="skelasm-accuracy")
        self._request = 0
        # emitted from the worker, delivered on this object's (the GUI's) thread
        self._answered.connect(self._deliver, QtCore.Qt.QueuedConnection)

    def submit(self, descriptors) -> None:
        """Compute the profile of ``descriptors`` (part 1 first, part 2 last)."""
        from engine.correlation import required_fft_size

        self._request += 1
        request = self._request
        pair = tuple(descriptors)
        if len(pair) < 2 or required_fft_size(pair[0].rho.shape,
                                              pair[-1].rho.shape) ** 3 <= self.inline_points:
            self._worker.cancel("profile")  # superseded
            self._deliver(request, _profile_or_none(pair))
            return

        def work(cancelled) -> None:
            profile = _profile_or_none(pair)
            if not cancelled():
                self._answered.emit(request, profile)

        self._worker.submit("profile", work)  # cancels the superseded one

    def wait_until_idle(self, timeout: float = 60.0) -> bool:
        """Wait until the last request has been computed (tests); True when it has."""
        return self._worker.wait_until_idle(timeout)

    def shutdown(self) -> None:
        """Drop what is queued and stop the worker (the window closes)."""
        self._request += 1
        self._worker.shutdown(timeout=0.0)

    def _deliver(self, request: int, profile) -> None:
        if request == self._request:
            self.profile_ready.emit(profile)


def _profile_or_none(pair: tuple) -> np.ndarray | None:
    try:
        return profile_of(pair)
    except (ValueError, MemoryError):
        return None
