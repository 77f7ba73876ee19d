"""Where two load cases on one geometry can differ in their weights: the peel from the free edges.

Two cases carried by one network share its positions ``X``, so their weights differ by a
``d = w_c − w_1`` with ``A(X) d = L_c − L_1`` (eq. 2 and 3 of both cases, subtracted): at every
free vertex where the cases' loads agree, the differences balance in space, with no load.

A free vertex with at most three edges on which ``d`` may still be nonzero, their directions
linearly independent, balances only ``d = 0`` on them. Starting at the free vertices that have three
edges or fewer (a quad mesh's free edges) and repeating on the vertices this leaves with three
or fewer, the *peel* marks the edges ``d`` must vanish on. The set of marked (*forced*) edges
depends on the mesh alone, not on the order the vertices are taken in: a vertex one maximal
order peels has at most three edges outside another's forced set, so that one has forced them too.

**If the peel forces every edge of a vertex where the loads differ, no network carries both
cases, with weights of either sign and any bounds, unless a star the peel passes is degenerate**:
its remaining edges at that step two on one line or three in one plane. (Induction along the
peel, in any one order: at a step whose edges of nonzero length are independent, the edges peeled
before carry no difference of force, so these carry none either; at the loaded vertex no edge
then does, against its load difference. An edge of zero length carries no force whatever its
weight, so it is no way out.) Quad meshes with free edges are often such meshes (``python -m
studies.peel``); on a triangle mesh the peel stops where vertices have six edges, a band along its
free edges at most.

:func:`star_degeneracy` measures the exception at given positions: the smallest singular value of
each step's unit edge directions, in the peel's own order (0: degenerate). Since the proof holds
in any order, a positive smallest value certifies that those positions carry no such difference;
near zero, the weights that would carry it grow like its inverse. The value itself depends on
the order the vertices are numbered in.

Example
-------
A 4 × 4 quad grid supported at its four corners, the cases differing at vertex 5:

>>> import numpy as np
>>> from selfsupport.core.mesh import PolyMesh
>>> t = np.arange(4.0)
>>> x, y = np.meshgrid(t, t)
>>> V = np.column_stack([x.ravel(), y.ravel(), 3.0 - (x.ravel() - 1.5) ** 2 / 3 - (y.ravel() - 1.5) ** 2 / 2])
>>> quads = [[4 * r + c, 4 * r + c + 1, 4 * r + c + 5, 4 * r + c + 4] for r in range(3) for c in range(3)]
>>> mesh = PolyMesh.from_faces(V, quads)
>>> supports = np.isin(np.arange(16), [0, 3, 12, 15])
>>> p = difference_peel(mesh.n_vertices, mesh.edges, supports, [5])
>>> p.blocked_at.tolist(), int(p.forced.sum()), mesh.n_edges
([5], 24, 24)
>>> bool(star_degeneracy(p, V).smallest > 0.1)
True
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["DifferencePeel", "StarDegeneracy", "difference_peel", "star_degeneracy", "loads_differ"]

#: A peeled star has at most this many edges: three independent directions in space balance only zero.
MAX_PEELED = 3


@dataclass(frozen=True, eq=False)
class DifferencePeel:
    """The peel of :func:`difference_peel`.

    ``forced[e]``: edge ``e`` carries no difference of force at any network whose peeled stars
    are not degenerate. ``vertices[k]`` is the free vertex of step ``k``, its edges
    ``step_edges[step_offsets[k]:step_offsets[k + 1]]`` (at most three: those not forced before).
    ``loaded`` are the vertices where the cases' loads differ (not peeled), ``blocked_at`` those of
    them whose every edge is forced (an edgeless one too: it carries no difference). Edges between
    two supports enter no equation and are never forced (their ends are never peeled). ``edges``
    are the edges the peel was built on."""

    edges: np.ndarray
    forced: np.ndarray
    vertices: np.ndarray
    step_offsets: np.ndarray
    step_edges: np.ndarray
    loaded: np.ndarray
    blocked_at: np.ndarray

    @property
    def blocked(self) -> bool:
        """Whether only a network with a degenerate peeled star can carry both cases (whatever the
        order of the peel)."""
        return self.blocked_at.size > 0

    @property
    def steps(self) -> int:
        return int(self.vertices.size)


@dataclass(frozen=True, eq=False)
class StarDegeneracy:
    """:func:`star_degeneracy`: per step of the peel the smallest singular value of its unit edge
    directions (``sigma``), the smallest of all and its vertex (``None`` for a peel of no step)."""

    sigma: np.ndarray
    smallest: float
    vertex: int | None


def difference_peel(n_vertices: int, edges: np.ndarray, supports: np.ndarray,
                    loaded: Sequence[int] | np.ndarray) -> DifferencePeel:
    """The peel from the free vertices with at most three edges (module docstring).

    Parameters
    ----------
    n_vertices : int
    edges : (m, 2) int array
        The edges that carry a weight.
    supports : (n,) bool array
    loaded : sequence of int
        The free vertices where the cases' loads differ (:func:`loads_differ`); they are not peeled.

    Returns
    -------
    DifferencePeel
        The forced edges and the steps; the set of forced edges does not depend on the order in
        which the vertices are taken (module docstring), the steps do.

    Examples
    --------
    A chain of two free vertices between two supports, loaded at its second vertex: the first
    has two edges, so both are forced, and the loaded vertex keeps only its edge to a support.

    >>> import numpy as np
    >>> p = difference_peel(4, np.array([[0, 1], [1, 2], [2, 3]]), np.array([True, False, False, True]), [2])
    >>> p.forced.tolist(), p.vertices.tolist(), p.blocked
    ([True, True, False], [1], False)
    """
    E = np.asarray(edges, np.int64).reshape(-1, 2)
    sup = np.asarray(supports, bool)
    loaded = np.unique(np.asarray(loaded, np.int64))
    ends = E.ravel()
    count = np.bincount(ends, minlength=n_vertices)
    offsets = np.r_[0, np.cumsum(count)]
    incident = np.argsort(ends, kind="stable") // 2
    peelable = ~sup
    peelable[loaded] = False
    alive = np.ones(E.shape[0], bool)
    queue = deque(np.flatnonzero(peelable & (count > 0) & (count <= MAX_PEELED)).tolist())
    vertices, step_edges, step_offsets = [], [], [0]
    while queue:
        v = queue.popleft()
        if not peelable[v] or not 0 < count[v] <= MAX_PEELED:
            continue
        es = incident[offsets[v]:offsets[v + 1]]
        es = es[alive[es]]
        alive[es] = False
        peelable[v] = False
        vertices.append(v)
        step_edges.extend(es.tolist())
        step_offsets.append(len(step_edges))
        for u in E[es].ravel():
            count[u] -= 1
            if peelable[u] and 0 < count[u] <= MAX_PEELED:
                queue.append(int(u))
    blocked = np.array([v for v in loaded if count[v] == 0], np.int64)
    return DifferencePeel(edges=E, forced=~alive, vertices=np.asarray(vertices, np.int64),
                          step_offsets=np.asarray(step_offsets, np.int64), step_edges=np.asarray(step_edges, np.int64),
                          loaded=loaded, blocked_at=blocked)


def star_degeneracy(peel: DifferencePeel, vertices: np.ndarray) -> StarDegeneracy:
    """How far the peel's stars are from degenerate at the positions ``vertices``.

    Parameters
    ----------
    peel : DifferencePeel
    vertices : (n, 3) array

    Returns
    -------
    StarDegeneracy
        Per step the smallest singular value of the ``r × 3`` matrix of the unit directions of its
        ``r ≤ 3`` edges of nonzero length (an edge of zero length carries no force and is left
        out; a step with none counts 1): 1 for one edge or orthogonal edges, 0 for a degenerate
        star.
    """
    E = peel.edges
    X = np.asarray(vertices, float)
    k = peel.steps
    if k == 0:
        return StarDegeneracy(sigma=np.zeros(0), smallest=float("inf"), vertex=None)
    r = np.diff(peel.step_offsets)
    step = np.repeat(np.arange(k), r)
    slot = np.arange(peel.step_edges.size) - peel.step_offsets[step]
    d = X[E[peel.step_edges, 1]] - X[E[peel.step_edges, 0]]
    length = np.linalg.norm(d, axis=1)
    unit = np.divide(d, length[:, None], out=np.zeros_like(d), where=length[:, None] > 0)
    M = np.zeros((k, MAX_PEELED, 3))
    M[step, slot] = unit
    s = np.linalg.svd(M, compute_uv=False)
    nonzero = np.bincount(step, weights=length > 0, minlength=k).astype(np.int64)
    sigma = np.where(nonzero > 0, s[np.arange(k), np.maximum(nonzero, 1) - 1], 1.0)
    i = int(np.argmin(sigma))
    return StarDegeneracy(sigma=sigma, smallest=float(sigma[i]), vertex=int(peel.vertices[i]))


def loads_differ(first: np.ndarray, other: np.ndarray, free: np.ndarray, rtol: float = 1e-12) -> np.ndarray:
    """The free vertices where two cases' nodal loads (at one geometry) differ by more than
    ``rtol`` of the largest difference: the ``loaded`` of :func:`difference_peel`.

    >>> import numpy as np
    >>> loads_differ(np.array([-1.0, -2.0, -2.0]), np.array([-1.0, -2.0, -2.5]), np.array([False, True, True])).tolist()
    [2]
    """
    diff = np.abs(np.asarray(other, float) - np.asarray(first, float))
    diff = np.where(np.asarray(free, bool), diff, 0.0)
    top = float(diff.max(initial=0.0))
    return np.flatnonzero(diff > rtol * top) if top > 0 else np.zeros(0, np.int64)
