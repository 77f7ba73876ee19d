"""The reciprocal force diagram S'* and the polar dual Φ* (paper §2.2).

* **Reciprocal diagram**: one vertex per face of the network — the gradient ``∇Φ|_f`` of the
  Airy surface there — and one edge per interior edge of the network, ``w_ij J e'_ij``
  (``J`` the rotation by 90°): the edge is perpendicular to the primal edge and its length
  is the horizontal force in it. The faces of the diagram ("cells") are the closed polygons
  around the interior vertices; the cell of vertex ``i`` closes exactly when (2) holds at
  ``i``, and its signed area ``A*_i`` satisfies ``Σ_j w_ij (φ_j − φ_i) = 2 A*_i``.
* **Polar dual** Φ* with respect to the paraboloid ``z = ½(x² + y²)``: the plane
  ``z = g·x + c`` of a face of Φ has the pole ``(g, −c)``; the poles of the faces around a
  vertex ``(x_i, φ_i)`` lie on its polar plane ``z = x_i·y − φ_i``, so Φ* is again a polyhedral
  surface with planar faces; its top view is the reciprocal diagram.

Cells run counter-clockwise around their vertex's top view, so on a convex Φ (all
``w ≥ 0``) every cell has positive area.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh import PolyMesh
from ..result import Network
from .airy import AiryResult, _cross2, airy, freeze_arrays

__all__ = ["ReciprocalDiagram", "reciprocal", "vertex_face_rings", "cell_areas", "mixed_cell_areas"]


def vertex_face_rings(mesh: PolyMesh, orientation: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The faces around every vertex, in counter-clockwise top-view order.

    ``orientation`` is the faces' top-view orientation (+1: counter-clockwise). Open fans
    (boundary vertices) start at a boundary edge. Vectorised (pointer doubling), no Python
    loop over vertices.

    Returns
    -------
    offsets, faces
        CSR layout: the ring of vertex ``v`` is ``faces[offsets[v]:offsets[v + 1]]``.
    """
    n = mesh.n_vertices
    face_of, nxt, prv = mesh.corner_data
    fv = mesh.face_vertices
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
    d = (succ >= 0).astype(np.int64)
    jump = succ.copy()
    while np.any(jump >= 0):
        ok = jump >= 0
        d[ok] += d[jump[ok]]
        jnext = np.full(C, -1)
        jnext[ok] = jump[jump[ok]]
        jump = jnext
    ring_order = np.lexsort((-d, fv))
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(fv, minlength=n), out=offsets[1:])
    return offsets, face_of[ring_order]


def cell_areas(mesh: PolyMesh, gradients: np.ndarray, orientation: int) -> np.ndarray:
    """Signed area of each vertex's reciprocal cell (polygon of the gradients of the faces
    around it, counter-clockwise), summed over the dual edges: ``½ Σ g_R × g_L``. Only
    meaningful at interior vertices (``NaN`` on the boundary)."""
    return mixed_cell_areas(mesh, gradients, gradients, orientation)


def mixed_cell_areas(mesh: PolyMesh, g: np.ndarray, h: np.ndarray, orientation: int) -> np.ndarray:
    """Mixed areas ``A_i(G, H)`` of the cells of two face-gradient fields with the same
    combinatorics: ``¼ Σ (g_R × h_L + h_R × g_L)`` (``A(G, G)`` is the area). ``NaN`` on the
    boundary."""
    e, ef = mesh.edges, mesh.edge_faces
    interior = (ef >= 0).all(axis=1)
    L, R = ef[interior, 0], ef[interior, 1]
    contrib = 0.25 * orientation * (_cross2(g[R], h[L]) + _cross2(h[R], g[L]))
    out = np.zeros(mesh.n_vertices)
    np.add.at(out, e[interior, 0], contrib)
    np.add.at(out, e[interior, 1], -contrib)
    out[mesh.boundary_vertex_mask] = np.nan
    return out


@dataclass(frozen=True, eq=False)
class ReciprocalDiagram:
    """The reciprocal diagram and the polar dual of a network's Airy surface.

    ``vertices[f]`` is the gradient of Φ on face ``f`` (network face order). For every interior
    edge ``k``, ``dual_edges[k] = (R, L)`` are the faces right and left of
    ``mesh.edges[k]`` in the top view, and ``vertices[L] − vertices[R] = w_k J e'_k`` (exactly
    on exact input; see :attr:`edge_residual`).
    """

    vertices: np.ndarray  # (F, 2)
    polar_vertices: np.ndarray  # (F, 3): (g, −c), the pole of each face plane
    cell_vertex: np.ndarray  # primal vertex of each cell (interior vertices)
    cell_offsets: np.ndarray  # CSR offsets of cells into cell_faces
    cell_faces: np.ndarray  # faces (= diagram vertices) of each cell, counter-clockwise
    cell_areas: np.ndarray  # (n,) signed area of each vertex's cell (NaN on the boundary)
    primal_edges: np.ndarray  # interior edge indices
    dual_edges: np.ndarray  # (k, 2): (R, L) per interior edge
    expected: np.ndarray  # (k, 2): w J e'
    orientation: int

    def __post_init__(self) -> None:
        freeze_arrays(self)

    @property
    def edge_vectors(self) -> np.ndarray:
        """``vertices[L] − vertices[R]`` per interior edge."""
        return self.vertices[self.dual_edges[:, 1]] - self.vertices[self.dual_edges[:, 0]]

    @property
    def edge_residual(self) -> np.ndarray:
        """``‖(vertices[L] − vertices[R]) − w J e'‖`` per interior edge."""
        return np.linalg.norm(self.edge_vectors - self.expected, axis=1)

    @property
    def cells(self) -> list[np.ndarray]:
        o = self.cell_offsets
        return [self.cell_faces[o[k]:o[k + 1]] for k in range(len(self.cell_vertex))]

    def mesh(self, height: str = "flat") -> PolyMesh:
        """The diagram as a polygon mesh: ``height="flat"`` (z = 0, the force diagram) or
        ``"polar"`` (the polar dual Φ*, planar faces)."""
        v = self.polar_vertices if height == "polar" else np.c_[self.vertices, np.zeros(len(self.vertices))]
        return PolyMesh(v, self.cell_faces, self.cell_offsets)


def reciprocal(source: AiryResult | Network) -> ReciprocalDiagram:
    """The reciprocal diagram (and polar dual) of a network or of its :class:`AiryResult`."""
    res = source if isinstance(source, AiryResult) else airy(source)
    mesh = res.mesh
    sigma = res.orientation
    g = res.face_gradients
    offsets, faces = vertex_face_rings(mesh, sigma)
    closed = ~mesh.boundary_vertex_mask
    verts = np.flatnonzero(closed)
    sizes = offsets[verts + 1] - offsets[verts]
    keep = np.repeat(closed, np.diff(offsets))  # rings are stored vertex by vertex
    cell_offsets = np.zeros(len(verts) + 1, dtype=np.int64)
    np.cumsum(sizes, out=cell_offsets[1:])
    e, ef = mesh.edges, mesh.edge_faces
    interior = np.flatnonzero((ef >= 0).all(axis=1))
    # (R, L) in the top view: edge_faces[:, 0] is left of lo -> hi for counter-clockwise faces
    dual = ef[interior][:, ::-1] if sigma > 0 else ef[interior]
    ev = mesh.vertices[e[interior, 1], :2] - mesh.vertices[e[interior, 0], :2]
    expected = res.weights[interior, None] * np.stack([-ev[:, 1], ev[:, 0]], axis=1)
    return ReciprocalDiagram(vertices=g, polar_vertices=np.c_[g, -res.face_offsets], cell_vertex=verts,
                             cell_offsets=cell_offsets, cell_faces=faces[keep], cell_areas=cell_areas(mesh, g, sigma),
                             primal_edges=interior, dual_edges=dual, expected=expected, orientation=sigma)
