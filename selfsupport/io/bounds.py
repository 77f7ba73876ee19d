"""Per-edge weight bounds a designer states in a file (``solve --bounds FILE``).

Two forms, chosen by suffix:

* ``.csv`` — one edge a row, ``i,j,w_min,w_max`` [N/m]: the edge by its two vertices (0-based,
  either order), then its bounds; either bound may be left empty (the default: ε, or the
  ``--eps`` / ``--w-min`` value, below; unbounded, or ``--wmax`` / ``--max-stress``, above).
  A first row ``i,j,w_min,w_max`` is a header; ``#`` starts a comment::

      i,j,w_min,w_max
      0,1,,2500        # at most 2.5 kN/m on edge (0, 1)
      4,7,-300,        # tension down to -300 N/m allowed there

* ``.json`` — a JSON object with ``edges`` (``[[i, j], ...]``) and ``w_min`` and/or ``w_max``
  arrays in the order of its ``edges`` (``null``: the default); a network file with these two
  keys added is one.

Edges missing from the file take the defaults. ``w_min`` may be negative (tension allowed down to
it); ``w_max`` must be positive (``inf`` in a CSV: unbounded). The bounds are per mesh edge of the
mesh being solved, as a :class:`~formulations.problem.Bounds` whose NaN entries are not stated.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from formulations.problem import Bounds
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.meshfiles import Source, strip_comment
from selfsupport.io.network_json import load_json

__all__ = ["BOUNDS_SUFFIXES", "read_bounds", "write_bounds"]

#: The suffixes of a bounds file.
BOUNDS_SUFFIXES = (".csv", ".json")
_HEADER = ["i", "j", "w_min", "w_max"]
_FORMAT = "write one edge a row as i,j,w_min,w_max (N/m; leave a bound empty for the default)"


def read_bounds(path: str | Path, mesh: PolyMesh) -> Bounds:
    """The per-edge bounds of a ``.csv`` or ``.json`` bounds file (module docstring) for ``mesh``.

    Parameters
    ----------
    path
        The bounds file.
    mesh
        The mesh being solved: the file's vertex pairs are its edges.

    Returns
    -------
    Bounds
        ``lower`` and ``upper`` with one entry per mesh edge, NaN where the file states none.

    Raises
    ------
    InputError
        One line naming the file (and line): an unknown suffix, an edge the mesh does not have or
        one listed twice, a value that is not a number, NaN, an infinite ``w_min``, a ``w_max``
        not above zero, ``w_min`` not below ``w_max``, or a file that states no bound.
    """
    src = Source(path)
    suffix = src.path.suffix.lower()
    if suffix not in BOUNDS_SUFFIXES:
        raise src.error(f"unknown bounds file type {suffix or '(no suffix)'!r}",
                        f"give a {' or '.join(BOUNDS_SUFFIXES)} file")
    lower = np.full(mesh.n_edges, np.nan)
    upper = np.full(mesh.n_edges, np.nan)
    rows = _csv_rows(src) if suffix == ".csv" else _json_rows(src)
    seen: dict[int, int | None] = {}
    for line, i, j, lo, up in rows:
        k = _edge_index(src, mesh, i, j, line)
        if k in seen:
            first = seen[k]
            raise src.error(f"edge ({i}, {j}) is listed twice" + (f" (first on line {first})" if first else ""),
                            "state each edge once", line)
        seen[k] = line
        _check_pair(src, i, j, lo, up, line)
        lower[k], upper[k] = lo, up
    if np.isnan(lower).all() and np.isnan(upper).all():
        raise src.error("states no bound", _FORMAT)
    return Bounds(lower, upper)


def write_bounds(path: str | Path, mesh: PolyMesh, bounds: Bounds) -> None:
    """Write per-edge ``bounds`` (scalars or one per mesh edge, NaN: not stated) of ``mesh`` as a
    ``.csv`` or ``.json`` bounds file that :func:`read_bounds` reads back; edges with neither
    bound stated are left out."""
    p = Path(path)
    if p.suffix.lower() not in BOUNDS_SUFFIXES:
        raise InputError(f"{p}: unknown bounds file type {p.suffix or '(no suffix)'!r}; "
                         f"give a {' or '.join(BOUNDS_SUFFIXES)} file")
    m = mesh.n_edges
    lo = np.broadcast_to(np.nan if bounds.lower is None else np.asarray(bounds.lower, float), (m,))
    up = np.broadcast_to(np.nan if bounds.upper is None else np.asarray(bounds.upper, float), (m,))
    keep = ~(np.isnan(lo) & np.isnan(up))
    if p.suffix.lower() == ".json":
        def col(a: np.ndarray) -> list:
            return [None if math.isnan(x) else x for x in a[keep].tolist()]

        doc = {"edges": mesh.edges[keep].tolist(), "w_min": col(lo), "w_max": col(up)}
        if np.isinf(up[keep]).any():
            raise InputError(f"{p}: JSON has no infinity; leave an unbounded w_max as null (the default)")
        atomic_write_text(p, json.dumps(doc, allow_nan=False) + "\n")
        return
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(_HEADER)
    for (i, j), a, b in zip(mesh.edges[keep].tolist(), lo[keep].tolist(), up[keep].tolist()):
        w.writerow([i, j, "" if math.isnan(a) else repr(a), "" if math.isnan(b) else repr(b)])
    atomic_write_text(p, out.getvalue())


# ------------------------------------------------------------------------------ helpers
def _number(src: Source, text: str, what: str, line: int | None) -> float:
    """A bound from its text: empty is NaN (not stated); NaN itself is refused."""
    text = text.strip()
    if not text:
        return math.nan
    try:
        x = float(text)
    except ValueError:
        raise src.error(f"{what} {text!r} is not a number", _FORMAT, line) from None
    if math.isnan(x):
        raise src.error(f"{what} is NaN", "leave it empty for the default, or give a number", line)
    return x


def _csv_rows(src: Source):
    text = src.read_text()
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = strip_comment(raw).strip()
        if not line:
            continue
        cells = next(csv.reader([line]))
        if [c.strip().lower() for c in cells] == _HEADER:
            continue
        if len(cells) != 4:
            raise src.error(f"has {len(cells)} columns, not 4", _FORMAT, lineno)
        i, j = (_vertex(src, c, lineno) for c in cells[:2])
        yield (lineno, i, j, _number(src, cells[2], "w_min", lineno), _number(src, cells[3], "w_max", lineno))


def _vertex(src: Source, text: str, line: int) -> int:
    try:
        return int(text.strip())
    except ValueError:
        raise src.error(f"{text.strip()!r} is not a vertex index", "name each edge by its two 0-based vertex indices",
                        line) from None


def _json_rows(src: Source):

    d = load_json(src)
    edges = d.get("edges")
    if not isinstance(edges, list) or not all(isinstance(e, list) and len(e) == 2 for e in edges):
        raise src.error("has no 'edges' list of [i, j] pairs", "a JSON bounds file holds edges and w_min / w_max "
                        "arrays in the order of its edges")
    cols = {}
    for key in ("w_min", "w_max"):
        v = d.get(key)
        if v is None:
            cols[key] = [None] * len(edges)
            continue
        if not isinstance(v, list) or len(v) != len(edges):
            n = len(v) if isinstance(v, list) else type(v).__name__
            raise src.error(f"key {key!r} has {n} entries for {len(edges)} edges",
                            "give one per edge, in the order of 'edges' (null: the default)")
        cols[key] = v
    if "w_min" not in d and "w_max" not in d:
        raise src.error("has neither 'w_min' nor 'w_max'", "add per-edge arrays in the order of 'edges'")
    for k, (e, lo, up) in enumerate(zip(edges, cols["w_min"], cols["w_max"])):
        if not all(isinstance(x, int) and not isinstance(x, bool) for x in e):
            raise src.error(f"edge {k} is {e!r}, not two vertex indices", "write edges as [i, j] integer pairs")
        vals = []
        for key, x in (("w_min", lo), ("w_max", up)):
            if x is not None and (isinstance(x, bool) or not isinstance(x, (int, float))):
                raise src.error(f"{key}[{k}] is {x!r}, not a number", "give numbers, or null for the default")
            vals.append(math.nan if x is None else float(x))
        yield (None, e[0], e[1], *vals)


def _edge_index(src: Source, mesh: PolyMesh, i: int, j: int, line: int | None) -> int:
    n = mesh.n_vertices
    if not (0 <= i < n and 0 <= j < n):
        raise src.error(f"edge ({i}, {j}) names a vertex outside 0..{n - 1} (the mesh has {n} vertices)",
                        "name edges by the 0-based vertex indices of the mesh being solved", line)
    a, b = min(i, j), max(i, j)
    e = mesh.edges
    key = e[:, 0] * (n + 1) + e[:, 1]  # (mesh.edges is sorted by this key)
    k = int(np.searchsorted(key, a * (n + 1) + b))
    if k >= len(key) or key[k] != a * (n + 1) + b:
        raise src.error(f"({i}, {j}) is not an edge of the mesh", "name edges by the two vertices they join", line)
    return k


def _check_pair(src: Source, i: int, j: int, lo: float, up: float, line: int | None) -> None:
    at = f"edge ({i}, {j})"
    if math.isinf(lo):
        raise src.error(f"w_min of {at} is {lo:g}", "give a finite number (negative: tension allowed down to it)",
                        line)
    if not math.isnan(up) and not up > 0:
        raise src.error(f"w_max of {at} is {up:g}", "w_max must be positive (the most force density the edge may "
                        "carry); allow tension with a negative w_min instead", line)
    if not (math.isnan(lo) or math.isnan(up)) and not lo < up:
        raise src.error(f"w_min ({lo:g}) of {at} is not below its w_max ({up:g})", "swap or fix them", line)
