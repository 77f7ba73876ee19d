"""Vertical-axis conventions of mesh files.

The project works with z up. Files name their vertical axis with ``up``: ``"z"`` (the
default for OBJ/PLY/OFF), ``"-z"``, ``"y"``, ``"-y"``, ``"x"``, ``"-x"``. Each name maps to a
*proper* rotation ``R`` (orthogonal, ``det R = +1``) taking file coordinates to ours::

    ours = file @ R.T        file = ours @ R

A proper rotation (never a reflection) keeps face orientation, so normals computed from the
face order keep pointing the same way relative to the surface.

The original tool's ``.sss`` files and the paper's OBJ files have height = −y, i.e.
``up="-y"``: (X, Y, Z) ↦ (X, Z, −Y).

Every matrix is a signed permutation, so the mapping is exact in floating point.
"""
from __future__ import annotations

import numpy as np

from selfsupport.core.errors import InputError


def _rotation(rows: list[list[int]]) -> np.ndarray:
    r = np.array(rows, dtype=float)
    r.setflags(write=False)
    return r


#: ``up`` name -> rotation ``R`` with ``ours = file @ R.T`` (z up).
UP_AXES: dict[str, np.ndarray] = {
    "z": _rotation([[1, 0, 0], [0, 1, 0], [0, 0, 1]]),     # identity
    "-z": _rotation([[1, 0, 0], [0, -1, 0], [0, 0, -1]]),  # half turn about x
    "y": _rotation([[1, 0, 0], [0, 0, -1], [0, 1, 0]]),    # (X, Y, Z) -> (X, -Z, Y)
    "-y": _rotation([[1, 0, 0], [0, 0, 1], [0, -1, 0]]),   # (X, Y, Z) -> (X, Z, -Y): .sss and the paper's OBJ
    "x": _rotation([[0, 1, 0], [0, 0, 1], [1, 0, 0]]),     # (X, Y, Z) -> (Y, Z, X)
    "-x": _rotation([[0, 1, 0], [0, 0, -1], [-1, 0, 0]]),  # (X, Y, Z) -> (Y, -Z, -X)
}


def rotation(up: str, *, what: str = "up") -> np.ndarray:
    """The rotation for an ``up`` name; :class:`InputError` listing the valid names otherwise."""
    try:
        return UP_AXES[up]
    except (KeyError, TypeError):
        names = ", ".join(repr(k) for k in UP_AXES)
        raise InputError(f"unknown vertical axis {what}={up!r}; use one of {names}") from None


def to_ours(points: np.ndarray, up: str) -> np.ndarray:
    """File coordinates -> project coordinates (z up)."""
    return np.asarray(points, dtype=float).reshape(-1, 3) @ rotation(up).T


def to_file(points: np.ndarray, up: str) -> np.ndarray:
    """Project coordinates (z up) -> file coordinates (the inverse of :func:`to_ours`)."""
    return np.asarray(points, dtype=float).reshape(-1, 3) @ rotation(up)
