"""Named exceptions. Every message says what is wrong and what to do about it.

The CLI prints ``str(exc)`` as one line and exits with ``exc.exit_code``.
"""
from __future__ import annotations


class SelfSupportError(Exception):
    """Base class of every error the project raises on purpose."""

    exit_code: int = 2


class InputError(SelfSupportError):
    """A file or argument cannot be read or makes no sense (broken file, NaN, bad index)."""

    exit_code = 2


class MeshError(InputError):
    """The mesh is unusable as a thrust network (non-manifold, degenerate, ...)."""


class SupportError(InputError):
    """Supports are missing or inconsistent (none at all, a component without any, ...)."""


class BackendUnavailable(SelfSupportError):
    """A requested solver backend is not installed or cannot run this problem."""

    exit_code = 3


class InfeasibleDesign(SelfSupportError):
    """No compressive network exists near the design with the given bounds."""

    exit_code = 4


class TooLarge(InputError):
    """The problem would need more memory than the machine (or ``--max-memory``) allows."""


class NotKoenigs(MeshError):
    """A quad mesh has no Christoffel dual (it is not a Koenigs net), so §5's family Φ + αR
    does not exist for it."""
