"""Choosing the supports of a mesh that carries no pins of its own (OBJ, PLY, OFF).

``--supports boundary`` pins every boundary vertex; ``--supports FILE`` reads a supports file:
0-based vertex indices separated by white space, ``#`` starts a comment::

    # ground contact of structural.obj
    0 2 5
    17   # the corner
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from selfsupport.core.errors import SupportError
from selfsupport.core.mesh import PolyMesh
from selfsupport.io.meshfiles import Source, strip_comment

__all__ = ["SUPPORT_RULES", "read_supports_file", "resolve_supports"]


def _boundary(mesh: PolyMesh) -> np.ndarray:
    return mesh.boundary_vertex_mask.copy()


#: named support choices; anything else given as ``supports`` is a supports file path
SUPPORT_RULES: dict[str, Callable[[PolyMesh], np.ndarray]] = {"boundary": _boundary}


def read_supports_file(path: str | Path, n_vertices: int) -> np.ndarray:
    """Read a supports file into a boolean mask of length ``n_vertices``.

    Raises
    ------
    InputError
        Missing or empty file, a token that is not an integer, an index outside
        ``0..n_vertices-1`` (the message names the file and line).
    """
    src = Source(path)
    text = src.read_text()
    mask = np.zeros(n_vertices, dtype=bool)
    count = 0
    for lineno, line in enumerate(text.splitlines(), 1):
        for t in strip_comment(line).split():
            try:
                i = int(t)
            except ValueError:
                raise src.error(f"{t!r} is not a vertex index", "list 0-based integer vertex indices; "
                                "'#' starts a comment", lineno) from None
            if not 0 <= i < n_vertices:
                raise src.error(f"vertex index {i} is outside 0..{n_vertices - 1} (the mesh has {n_vertices} vertices)",
                                "supports files use 0-based indices of the mesh they belong to", lineno)
            mask[i] = True
            count += 1
    if count == 0:
        raise src.error("lists no vertex indices", "list the 0-based indices of the supported vertices")
    return mask


def resolve_supports(spec: str | Path | None, mesh: PolyMesh, *, source: str | Path) -> np.ndarray:
    """Supports mask for a mesh file without pins.

    Parameters
    ----------
    spec
        ``None`` (an error: the file has no supports), a rule name from
        :data:`SUPPORT_RULES` (``"boundary"``), or a supports file path.
    mesh
        The mesh the supports belong to.
    source
        The mesh file (for the message).
    """
    if spec is None:
        raise SupportError(f"{source} has no supports: pass --supports boundary or --supports FILE "
                           "(a file of 0-based vertex indices) to say which vertices rest on the ground")
    rule = SUPPORT_RULES.get(str(spec)) if isinstance(spec, str) else None
    if rule is not None:
        return rule(mesh)
    return read_supports_file(spec, mesh.n_vertices)
