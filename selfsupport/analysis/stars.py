"""Vertex stars: the corners around every vertex in counter-clockwise top-view order, with the
edge crossed between consecutive corners.

Per-vertex quantities of the Airy surface (``Δ_φ φ``, reciprocal cell areas) are sums over a
vertex's star. Around holes and interior supports Φ is multivalued, so these sums are taken
on the cover: the face planes of a star are continued from one face to the next across the
edges between them (see :attr:`selfsupport.analysis.airy.AiryResult.star_planes`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from selfsupport.core.mesh import PolyMesh

__all__ = ["Stars", "vertex_stars"]


@dataclass(frozen=True, eq=False)
class Stars:
    """Corner rings of all vertices (CSR): the star of ``v`` is
    ``corners[offsets[v]:offsets[v + 1]]``, counter-clockwise in the top view. Closed rings start
    at the vertex's first corner (its lowest-numbered face); open rings (boundary vertices) start
    at a boundary edge.

    ``after[c]`` is the edge between corner ``c``'s face and the next face counter-clockwise
    (for the last corner of an open ring: the boundary edge after it), ``before[c]`` the edge
    between it and the previous face; both are edge indices into ``mesh.edges`` and indexed by
    corner (``mesh.face_vertices`` order).
    """

    offsets: np.ndarray
    corners: np.ndarray
    after: np.ndarray
    before: np.ndarray
    closed: np.ndarray  # (n,) the ring closes (interior vertex)

    @property
    def vertex(self) -> np.ndarray:
        """``(C,)``: the vertex of every ring position."""
        return np.repeat(np.arange(len(self.offsets) - 1), np.diff(self.offsets))

    @property
    def first(self) -> np.ndarray:
        """``(C,)`` bool: the ring position starts its vertex's ring."""
        f = np.zeros(len(self.corners), dtype=bool)
        f[self.offsets[:-1][np.diff(self.offsets) > 0]] = True
        return f

    @property
    def last(self) -> np.ndarray:
        """``(C,)`` bool: the ring position ends its vertex's ring."""
        f = np.zeros(len(self.corners), dtype=bool)
        f[self.offsets[1:][np.diff(self.offsets) > 0] - 1] = True
        return f

    def next_position(self) -> np.ndarray:
        """``(C,)``: the following ring position (closed rings wrap around; ``-1`` after the
        last corner of an open ring)."""
        pos = np.arange(len(self.corners))
        nxt = pos + 1
        last = self.last
        start = np.repeat(self.offsets[:-1], np.diff(self.offsets))
        closed = self.closed[self.vertex]
        nxt[last] = np.where(closed[last], start[last], -1)
        return nxt


def vertex_stars(mesh: PolyMesh, orientation: int = 1) -> Stars:
    """The :class:`Stars` of a manifold mesh; ``orientation`` is the faces' top-view
    orientation (+1: counter-clockwise). Vectorised (pointer doubling), no Python loop over
    vertices."""
    n = mesh.n_vertices
    face_of, nxt, prv = mesh.corner_data
    fv = mesh.face_vertices
    fo = mesh.face_offsets
    C = len(fv)
    key = fv * n + nxt  # the half-edge leaving each corner
    order = np.argsort(key, kind="stable")
    skey = key[order]

    def corner_of(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        q = a * n + b
        pos = np.clip(np.searchsorted(skey, q), 0, C - 1)
        return np.where(skey[pos] == q, order[pos], -1)

    # for counter-clockwise faces the next face counter-clockwise around v holds the half-edge v -> prv
    succ = corner_of(fv, prv)
    pred = np.full(C, -1)
    pred[succ[succ >= 0]] = np.flatnonzero(succ >= 0)
    if orientation < 0:
        succ, pred = pred, succ
    # on a manifold mesh the corners of an interior vertex form one cycle, of a boundary vertex one
    # chain: break every cycle at the vertex's first corner
    verts, first = np.unique(fv, return_index=True)
    rep = first[~mesh.boundary_vertex_mask[verts]]
    succ = succ.copy()
    succ[pred[rep]] = -1
    # rank = distance to the chain's end (list ranking by pointer doubling)
    d = accumulate_along(succ, (succ >= 0).astype(np.int64))
    ring_order = np.lexsort((-d, fv))
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(fv, minlength=n), out=offsets[1:])
    he_edge = mesh.halfedge_data["halfedge_edge"]
    sizes = np.diff(fo)
    prev_corner = fo[face_of] + (np.arange(C) - fo[face_of] - 1) % sizes[face_of]
    to_nxt, to_prv = he_edge, he_edge[prev_corner]  # edges v–nxt and prv–v of each corner
    after, before = (to_prv, to_nxt) if orientation >= 0 else (to_nxt, to_prv)
    return Stars(offsets=offsets, corners=ring_order, after=np.asarray(after), before=np.asarray(before),
                 closed=~mesh.boundary_vertex_mask)


def accumulate_along(parent: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` summed along each element's chain of ``parent`` pointers (−1 ends a chain):
    ``out[i] = values[i] + values[parent[i]] + values[parent[parent[i]]] + …``, by pointer
    doubling (log₂ of the longest chain rounds, each vectorised). Chains must not cycle."""
    acc = np.array(values, copy=True)
    jump = np.asarray(parent).copy()
    while np.any(jump >= 0):
        ok = jump >= 0
        acc[ok] += acc[jump[ok]]
        nxt = np.full(len(jump), -1)
        nxt[ok] = jump[jump[ok]]
        jump = nxt
    return acc
