"""Exceptions the engine raises for the user: each message names the problem and the fix."""

from __future__ import annotations


class Cancelled(Exception):
    """A long computation was cancelled through its ``cancel`` callback."""


class InputError(ValueError):
    """Bad input (file, mesh, value): the message says which and what to do."""


class ResourceError(RuntimeError):
    """A resource is too small or missing (memory for a grid, a device)."""
