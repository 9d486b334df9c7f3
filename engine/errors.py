"""Exceptions the engine raises for the user: each message names the problem and the fix."""

from __future__ import annotations


class Cancelled(Exception):
    """A long computation was cancelled through its ``cancel`` callback."""


class InputError(ValueError):
    """Bad input (file, mesh, value): the message says which and what to do."""


class ResourceError(RuntimeError):
    """A resource is too small or missing (memory for a grid, a device)."""


class Diverged(InputError):
    """The simulation's state left every physical bound; the message names the likely cause.

    A subclass of :class:`InputError`: a divergence comes from the parameters or the input
    (a gain too stiff for the time step, a proxy thrown far away), never from the part.
    """
