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

from selfsupport.analysis.airy import AiryResult, _cross2, airy, freeze_arrays
from selfsupport.analysis.stars import vertex_stars
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network

__all__ = ["ReciprocalDiagram", "reciprocal", "vertex_face_rings", "cell_areas", "mixed_cell_areas", "CoverCells",
           "cover_cells"]


def vertex_face_rings(mesh: PolyMesh, orientation: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The faces around every vertex, in counter-clockwise top-view order.

    ``orientation`` is the faces' top-view orientation (+1: counter-clockwise). Open fans
    (boundary vertices) start at a boundary edge (see :func:`~selfsupport.analysis.stars.vertex_stars`).

    Returns
    -------
    offsets, faces
        CSR layout: the ring of vertex ``v`` is ``faces[offsets[v]:offsets[v + 1]]``.
    """
    st = vertex_stars(mesh, orientation)
    face_of, _, _ = mesh.corner_data
    return st.offsets, face_of[st.corners]


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
class CoverCells:
    """Per-vertex sums over the stars of Φ on the cover (see :func:`cover_cells`)."""

    laplacian_phi: np.ndarray  # (n,) Δ_φ φ = Σ_j w_ij (φ_j − φ_i), φ_j on vertex i's branch
    areas: np.ndarray  # (n,) signed reciprocal cell area A*_i (NaN at boundary supports)
    mixed_areas: np.ndarray | None  # (n,) A_i(Φ*, S*) at interior vertices (NaN on the boundary)

    def __post_init__(self) -> None:
        freeze_arrays(self)


def cover_cells(res: AiryResult, surface_gradients: np.ndarray | None = None) -> CoverCells:
    """``Δ_φ φ``, the reciprocal cell areas and mixed areas, computed on the cover of Φ.

    Around holes and interior supports Φ has a period, so a vertex next to a cut sees the
    faces beyond the cut on another branch. Each vertex's sums use its star's planes continued
    across the cut (:attr:`AiryResult.star_planes`): the cell around vertex ``i`` is the polygon
    of those gradients, and ``Δ_φ φ (v_i) = 2 A*_i`` holds at every vertex in horizontal
    equilibrium. At a free boundary vertex the cell is closed by the plane Φ continues with
    beyond the boundary (its gradient differs from the last face's by ``w J e'`` of the boundary
    edge; over a free hole in equilibrium this is one plane), so the identity and eq. (6) hold
    there too.

    Parameters
    ----------
    res
        The Airy result.
    surface_gradients
        ``(F, 2)`` face gradients of a second surface (e.g. the network's heights ``s``) for the
        mixed areas ``A_i(Φ*, S*)``; only at interior vertices (S has no plane beyond the boundary).
    """
    mesh = res.mesh
    n = mesh.n_vertices
    st = vertex_stars(mesh, res.orientation)
    face_of, _, _ = mesh.corner_data
    fv = mesh.face_vertices
    e = mesh.edges
    xy = mesh.vertices[:, :2]
    w = res.weights
    c = st.corners
    v = fv[c]
    nxt = st.next_position()
    inner = nxt >= 0
    start = np.repeat(st.offsets[:-1], np.diff(st.offsets))
    # each star in the gauge of its first face (Φ is defined up to an affine function): a
    # horizontal imbalance then perturbs the sums by |cell| × defect, not |∇Φ| × defect
    G = res.star_planes[c, :2]
    G = G - G[start]
    # consecutive pairs (a -> b) across an edge: inside the ring, then, for open rings, the last
    # face -> the plane beyond the boundary -> the first face
    k_in = np.flatnonzero(inner)
    k_open = np.flatnonzero(~inner)
    e_last = st.after[c[k_open]]
    e_first = st.before[c[start[k_open]]]

    def other(edges: np.ndarray, verts: np.ndarray) -> np.ndarray:
        return np.where(e[edges, 0] == verts, e[edges, 1], e[edges, 0])

    d_last = xy[other(e_last, v[k_open])] - xy[v[k_open]]
    G_ext = G[k_open] + w[e_last, None] * np.c_[-d_last[:, 1], d_last[:, 0]]
    pv = np.r_[v[k_in], v[k_open], v[k_open]]
    pe = np.r_[st.after[c[k_in]], e_last, e_first]
    Ga = np.r_[G[k_in], G[k_open], G_ext]
    Gb = np.r_[G[nxt[k_in]], G_ext, G[start[k_open]]]
    d = xy[other(pe, pv)] - xy[pv]
    lap = np.bincount(pv, weights=w[pe] * np.einsum("ki,ki->k", 0.5 * (Ga + Gb), d), minlength=n)
    area = 0.5 * np.bincount(pv, weights=_cross2(Ga, Gb), minlength=n)
    area[mesh.boundary_vertex_mask & res.supports] = np.nan
    mixed = None
    if surface_gradients is not None:
        H = np.asarray(surface_gradients, float)[face_of[c]]
        H = H - H[start]
        mixed = 0.25 * np.bincount(v[k_in], weights=_cross2(G[k_in], H[nxt[k_in]]) + _cross2(H[k_in], G[nxt[k_in]]),
                                   minlength=n)
        mixed[mesh.boundary_vertex_mask] = np.nan
    return CoverCells(laplacian_phi=lap, areas=area, mixed_areas=mixed)


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
    cell_areas: np.ndarray  # (n,) signed cell areas on the cover (cover_cells; NaN at boundary supports)
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
                             cell_offsets=cell_offsets, cell_faces=faces[keep], cell_areas=cover_cells(res).areas,
                             primal_edges=interior, dual_edges=dual, expected=expected, orientation=sigma)
