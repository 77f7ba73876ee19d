"""The Airy stress surface Φ of a thrust network (paper §2.1–2.2).

Over the top view of a network in horizontal equilibrium (eq. 2) there is a polyhedral
surface Φ — one plane per face, vertices ``(x_i, y_i, φ_i)`` — whose gradient jumps across
every edge by ``w_ij ‖e'_ij‖`` in the direction normal to the edge's top view ``e'_ij``.
Equivalently, with ``J`` the rotation by +90° and faces ``L``/``R`` to the left/right of
the directed edge ``i → j`` (faces counter-clockwise in the top view)::

    ∇Φ|_L − ∇Φ|_R = w_ij J (x_j − x_i)                          (jump condition)

so Φ is convex exactly where the weights are non-negative (compression).

How it is computed
------------------
* Each face gets an affine function ``P_f(x) = g_f · x + c_f``. Across every interior edge
  the jump condition and continuity along the edge prescribe ``P_L − P_R`` exactly. The
  planes are the **least-squares solution over the dual graph** (one pinned face per
  component). They are first integrated along a breadth-first spanning tree (linear time);
  when that already fits every dual edge to round-off — integrable input, the usual case —
  it *is* the least-squares solution. Otherwise (a slightly non-integrable network:
  horizontal residuals) the dual-graph Laplacian is solved, so that the misfit is spread and
  reported rather than accumulated along the tree (``integration`` says which).
* Integrability is local: around an interior vertex the jumps close exactly when eq. (2)
  holds there (``closure_residual``). Around a **hole**, an **interior support** (its
  reaction is an external force) or a support patch, Φ exists only locally and has a
  *period*: after a turn around the hole, the plane has changed by an affine function
  (gradient part ``J ×`` the net horizontal force the network exerts on the hole, constant
  part its moment). Each such source is joined to the outer boundary by a cut — a
  shortest path that prefers support–support edges, which carry no force — whose dual
  edges are left out of the least squares; the periods are read off across the cuts and
  reported per source (:class:`Period`). A free hole in equilibrium has zero period.
* **Φ on the cover.** Every corner takes its value from its own face's plane, so every face
  of Φ is planar (``corner_phi``). The corners of a vertex form one vertex of Φ unless a cut with a
  non-zero period separates them: there Φ is cut open and the vertex gets one copy per side
  (``cover_vertex``, ``cover_phi``, ``cover_parent``; :meth:`AiryResult.stress_mesh`).
  ``phi`` per vertex is the branch of its lowest-numbered face; ``vertex_spread`` says how
  far the planes meeting at one vertex of Φ disagree (zero on exact input). The gauge (Φ is
  defined up to an affine function per component) is fixed by removing the best-fit plane,
  as the original tool did.
* **Per-vertex quantities** (``Δ_φ φ``, reciprocal cells, eq. (6)) are sums over a vertex's
  star; ``star_planes`` holds each corner's plane continued around its vertex from the
  vertex's first face, the period applied across cut edges, so the star sums see one branch
  (:func:`~selfsupport.analysis.reciprocal.cover_cells`).
* Faces whose vertices are all supports carry nothing; they simply continue their
  neighbours' planes (the support–support edges between them have zero weight).
* Polygon faces (quads …) get one plane each. When the values at the vertices of Φ of a
  polygon are not coplanar (only possible on non-integrable input) the face is listed in
  ``nonplanar_faces`` and split by a fan of diagonals — edges the network does not have,
  i.e. zero-force edges of S — whose Φ-creases (the weights Φ would need there) are
  reported in ``split_edges`` / ``split_edge_weights``.

Orientation: the top-view orientation ``σ = ±1`` of the faces (counter-clockwise: +1) is
detected, so meshes with downward normals give the same Φ.

Example
-------
>>> import numpy as np
>>> from selfsupport.analysis import construct, airy
>>> from selfsupport.core.shapes import disk_points
>>> net = construct(disk_points(6), "paraboloid", load=-1.0)
>>> res = airy(net)
>>> bool(res.convex), res.max_closure_residual < 1e-12
(True, True)
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components, dijkstra

from selfsupport.analysis.stars import Stars, accumulate_along, vertex_stars
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import force_sums, load_vectors, stress_sums
from selfsupport.core.linalg import spd_factor
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network

__all__ = ["AiryResult", "Period", "airy", "INTEGRATIONS", "face_orientation", "top_view_jumps", "face_planes_through"]

#: Dijkstra cost of a support–support edge when cutting from a hole to the boundary
#: (cheap: such edges carry no force, so a period across them disturbs nothing).
SUPPORT_EDGE_COST = 1e-3


# ---------------------------------------------------------------------------------- results
def freeze_arrays(obj: Any) -> None:
    """Make every numpy array field of a (frozen) dataclass read-only: results are immutable."""

    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, np.ndarray):
            v.setflags(write=False)


@dataclass(frozen=True, eq=False)
class Period:
    """The period of Φ around one source (a hole or an interior support).

    Across the source's cut, Φ's two branches differ by the affine function
    ``x ↦ gradient · x + offset`` (network coordinates). With
    ``T = Σ_{i ∈ source} Σ_j w_ij (x_i − x_j)`` the horizontal thrust the network exerts on
    the source (compression pushes) and ``M = Σ_i x_i × T_i`` its moment about the origin,
    ``gradient = J T`` and ``offset = M``: zero for a free hole in equilibrium, the support's
    horizontal reaction (rotated) for a support.
    """

    kind: str  # "hole" or "support"
    vertices: np.ndarray  # the hole's boundary loop, or the interior support vertex
    gradient: np.ndarray  # (2,)
    offset: float
    cut_edges: np.ndarray  # the first edge of the cut from this source towards the outer boundary
    thrust: np.ndarray  # (2,) T, from the weights directly (no Φ involved)
    moment: float  # M, from the weights directly

    def __post_init__(self) -> None:
        freeze_arrays(self)

    def value_at(self, point: np.ndarray) -> float:
        """The jump of Φ at a top-view point (e.g. the hole's centre)."""
        return float(np.dot(self.gradient, np.asarray(point, float)[:2]) + self.offset)


@dataclass(frozen=True, eq=False)
class AiryResult:
    """The Airy stress surface of a network (see the module docstring).

    Arrays are indexed like the network: ``phi`` per vertex, ``face_*`` per face (mesh
    order), edge arrays per ``mesh.edges`` row (``NaN`` on boundary edges).
    """

    mesh: PolyMesh
    weights: np.ndarray
    supports: np.ndarray
    phi: np.ndarray  # (n,)
    face_gradients: np.ndarray  # (F, 2): the reciprocal diagram's vertices
    face_offsets: np.ndarray  # (F,): face plane φ = g·x + c
    orientation: int  # +1 when faces run counter-clockwise in the top view
    jumps: np.ndarray  # (m, 2): prescribed ∇Φ_L − ∇Φ_R = σ w J e' (0 on boundary edges)
    crease_weights: np.ndarray  # (m,): the weights Φ's creases stand for (NaN: boundary, cut)
    edge_residual: np.ndarray  # (m,): |∇Φ_L − ∇Φ_R − jump| (NaN: boundary)
    closure_residual: np.ndarray  # (n,): |Σ_j w_ij (x_j − x_i)| / Σ_j |w_ij| |x_j − x_i| at free vertices (NaN: supports)
    vertex_spread: np.ndarray  # (n,): max − min of the face planes meeting at one vertex of Φ (cover)
    planarity_residual: np.ndarray  # (F,): max |φ_i − P_f(x_i)| over the face's corners
    cut_edges: np.ndarray  # mesh edge indices whose dual edges were left out
    periods: tuple[Period, ...]
    nonplanar_faces: np.ndarray
    split_edges: np.ndarray  # (k, 2) fan diagonals of the non-planar faces
    split_edge_weights: np.ndarray  # (k,) Φ-creases there
    convex: bool
    face_component: np.ndarray  # (F,) dual component label (gauge per component)
    integration: str  # "tree" (integrable input, spanning-tree integration) or "least-squares"
    cover_vertex: np.ndarray  # (C,): per corner (mesh.face_vertices order), its vertex of Φ
    cover_phi: np.ndarray  # (n + k,): φ at the vertices of Φ; the first n are ``phi``
    cover_parent: np.ndarray  # (n + k,): the network vertex of each vertex of Φ
    star_planes: np.ndarray  # (C, 3): per corner (g, c), its face plane continued around the vertex
    scale: dict[str, float]
    seconds: float

    def __post_init__(self) -> None:
        freeze_arrays(self)

    @property
    def reciprocal_vertices(self) -> np.ndarray:
        """``(F, 2)``: one vertex of the reciprocal diagram per face, the gradient of Φ there."""
        return self.face_gradients

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @property
    def max_closure_residual(self) -> float:
        """Worst relative horizontal imbalance (integrability defect) over vertices that must close."""
        c = self.closure_residual[np.isfinite(self.closure_residual)]
        return float(c.max()) if c.size else 0.0

    @property
    def max_edge_residual(self) -> float:
        """Worst misfit of the jump condition over interior edges off the cuts, relative to the
        mean jump ``mean |w_ij| ‖e'_ij‖``."""
        live = np.isfinite(self.edge_residual)
        live[self.cut_edges] = False
        r = self.edge_residual[live]
        return float(r.max() / self.scale["jump"]) if r.size else 0.0

    @property
    def min_crease_weight(self) -> float:
        c = self.crease_weights[np.isfinite(self.crease_weights)]
        return float(c.min()) if c.size else 0.0

    @property
    def corner_phi(self) -> np.ndarray:
        """``(C,)``: φ at every corner (``mesh.face_vertices`` order), from the corner's vertex of Φ."""
        return self.cover_phi[self.cover_vertex]

    @property
    def n_cover_copies(self) -> int:
        """Vertices of Φ beyond the network's: second (third …) copies of vertices on cuts."""
        return len(self.cover_parent) - self.mesh.n_vertices

    def stress_mesh(self) -> PolyMesh:
        """Φ as a mesh over the top view: vertices ``(x_i, y_i, φ_i)`` and the network's faces.

        Where a cut with a non-zero period passes, Φ is cut open: the vertices there appear
        once per side (``cover_parent`` says whose copy), so every face keeps its own plane.
        The first ``n`` vertices are the network's, in order, with ``phi``.
        """
        v = np.c_[self.mesh.vertices[self.cover_parent, :2], self.cover_phi]
        return PolyMesh(v, self.cover_vertex, self.mesh.face_offsets)

    def summary(self) -> dict[str, Any]:
        return {"convex": bool(self.convex), "orientation": self.orientation,
                "max_closure_residual": self.max_closure_residual, "max_edge_residual": self.max_edge_residual,
                "max_vertex_spread": float(np.nanmax(self.vertex_spread)) if self.vertex_spread.size else 0.0,
                "min_crease_weight": self.min_crease_weight, "n_cut_edges": int(self.cut_edges.size),
                "n_cover_copies": self.n_cover_copies,
                "n_periods": len(self.periods), "n_nonplanar_faces": int(self.nonplanar_faces.size),
                "integration": self.integration,
                "seconds": self.seconds}


# ---------------------------------------------------------------------------------- kernels
def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _J(v: np.ndarray) -> np.ndarray:
    """Rotation by +90° of 2D vectors."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def face_orientation(mesh: PolyMesh, xy: np.ndarray | None = None) -> tuple[int, np.ndarray]:
    """Top-view orientation: ``(σ, signed_areas)`` with σ = +1 when the faces run
    counter-clockwise seen from above (by total signed area)."""
    xy = mesh.vertices[:, :2] if xy is None else xy
    face_of, nxt, _ = mesh.corner_data
    a = np.zeros(mesh.n_faces)
    np.add.at(a, face_of, 0.5 * _cross2(xy[mesh.face_vertices], xy[nxt]))
    return (1 if a.sum() >= 0 else -1), a


def top_view_jumps(mesh: PolyMesh, weights: np.ndarray, sigma: int, xy: np.ndarray) -> np.ndarray:
    """``(m, 2)``: ``∇Φ_L − ∇Φ_R = σ w J e'`` per edge (L = ``edge_faces[:, 0]``)."""
    e = mesh.edges
    return sigma * np.asarray(weights, float)[:, None] * _J(xy[e[:, 1]] - xy[e[:, 0]])


def face_planes_through(mesh: PolyMesh, xy: np.ndarray, values: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane ``z = g·x + c`` through each face's ``(x_i, values_i)``.

    Returns ``(g (F, 2), c (F,), residual (F,))`` with the residual the max deviation over the
    corners (zero for triangles). Batched 3 × 3 normal equations around each face centroid.
    """
    return _planes_through_corners(mesh, xy, np.asarray(values, float)[mesh.face_vertices])


def _planes_through_corners(mesh: PolyMesh, xy: np.ndarray, corner_values: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`face_planes_through` with one value per corner (``mesh.face_vertices`` order)."""
    face_of, _, _ = mesh.corner_data
    sizes = mesh.face_sizes
    fv = mesh.face_vertices
    cen = np.zeros((mesh.n_faces, 2))
    np.add.at(cen, face_of, xy[fv])
    cen /= sizes[:, None]
    d = xy[fv] - cen[face_of]
    vmean = np.bincount(face_of, weights=corner_values, minlength=mesh.n_faces) / sizes
    dv = corner_values - vmean[face_of]
    M = np.zeros((mesh.n_faces, 2, 2))
    r = np.zeros((mesh.n_faces, 2))
    for a in range(2):
        np.add.at(r[:, a], face_of, d[:, a] * dv)
        for b in range(2):
            np.add.at(M[:, a, b], face_of, d[:, a] * d[:, b])
    g = np.linalg.solve(M, r[..., None])[..., 0]
    c = vmean - np.einsum("fi,fi->f", g, cen)
    res = np.zeros(mesh.n_faces)
    np.maximum.at(res, face_of, np.abs(corner_values - (np.einsum("ci,ci->c", g[face_of], xy[fv]) + c[face_of])))
    return g, c, res


def _split_fans(mesh: PolyMesh, faces: np.ndarray, xy: np.ndarray, phi_c: np.ndarray, sigma: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """Fan-split the given polygon faces at their first corner; return the diagonals
    ``(k, 2)`` and the crease weights Φ (through the corner values ``phi_c``) has across them."""
    if faces.size == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    fo, fv = mesh.face_offsets, mesh.face_vertices
    sizes = fo[faces + 1] - fo[faces]
    ntri = sizes - 2
    owner = np.repeat(np.arange(len(faces)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1  # 1 .. size-2
    start = fo[faces][owner]
    tc = np.stack([start, start + k, start + k + 1], axis=1)  # corners
    t = fv[tc]
    Mt = np.stack([xy[t[:, 1]] - xy[t[:, 0]], xy[t[:, 2]] - xy[t[:, 0]]], axis=1)
    rt = np.stack([phi_c[tc[:, 1]] - phi_c[tc[:, 0]], phi_c[tc[:, 2]] - phi_c[tc[:, 0]]], axis=1)
    g = np.linalg.solve(Mt, rt[..., None])[..., 0]
    # diagonal v0 -> v_k+1 between fan triangle k (right of it) and k+1 (left of it)
    nxt = np.r_[owner[1:] == owner[:-1], False]
    i = np.flatnonzero(nxt)
    diag = np.stack([t[i, 0], t[i, 2]], axis=1)
    ed = xy[diag[:, 1]] - xy[diag[:, 0]]
    jump = g[i + 1] - g[i]
    w = (jump * (sigma * _J(ed))).sum(axis=1) / (ed * ed).sum(axis=1)
    return diag.astype(np.int64), w


def _loop_area(xy: np.ndarray, loop: np.ndarray) -> float:
    p = xy[loop]
    return 0.5 * float(_cross2(p, np.roll(p, -1, axis=0)).sum())


# ---------------------------------------------------------------------------------- cover
def _segment_exclusive_sum(values: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per position, the sum of ``values`` at the earlier positions of the same segment."""
    cs = np.cumsum(values, axis=0) - values
    start = np.repeat(offsets[:-1], np.diff(offsets))
    return cs - cs[start]


def _star_shifts(mesh: PolyMesh, stars: Stars, mismatch: np.ndarray, xy: np.ndarray, tol: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Continue the face planes around every vertex across cut edges.

    ``mismatch[e] = P_L − P_R − (prescribed jump)`` on cut edges (zero elsewhere). Returns
    ``shift`` ``(C, 3)`` per corner — added to the corner's face plane, it gives the plane as
    continued from the vertex's first ring face — and ``sector`` ``(C,)``: corners of one vertex
    with the same sector share a vertex of Φ; a new sector starts where a crossed cut changes
    the value at the vertex by more than ``tol``.
    """
    face_of, _, _ = mesh.corner_data
    ef = mesh.edge_faces
    fv = mesh.face_vertices
    corners = stars.corners
    nxt = stars.next_position()
    has_next = nxt >= 0
    e = stars.after[corners]
    m = mismatch[e]
    # crossing R -> L continues with +jump: P_L + shift = P_R + rhs  =>  shift grows by −mismatch
    into_left = ef[e, 0] == face_of[corners[np.where(has_next, nxt, 0)]]
    step = np.where(into_left[:, None], -m, m) * has_next[:, None]
    v = fv[corners]
    jump_at_v = np.abs(np.einsum("ci,ci->c", m[:, :2], xy[v]) + m[:, 2])
    split = has_next & (jump_at_v > tol)
    shift_pos = _segment_exclusive_sum(step, stars.offsets)
    label = _segment_exclusive_sum(split.astype(np.int64), stars.offsets)
    # a closed ring whose wrap-around crossing is no split: its last sector is its first
    last = stars.last
    lv = v[last]
    wrap_joins = np.zeros(mesh.n_vertices, dtype=bool)
    wrap_joins[lv] = stars.closed[lv] & ~split[last]
    last_label = np.zeros(mesh.n_vertices, dtype=np.int64)
    last_label[lv] = label[last]
    label = np.where(wrap_joins[v] & (label == last_label[v]), 0, label)
    shift = np.empty_like(shift_pos)
    shift[corners] = shift_pos
    sector = np.empty_like(label)
    sector[corners] = label
    return shift, sector


def _cover_vertices(n: int, fv: np.ndarray, sector: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertex of Φ per corner: sector 0 keeps the vertex's index, other sectors get copies
    numbered from ``n``. Returns ``(cover_vertex (C,), parent (n + copies,))``."""
    cover = fv.copy()
    extra = sector > 0
    if extra.any():
        key = fv[extra] * (int(sector.max()) + 1) + sector[extra]
        uniq, inv = np.unique(key, return_inverse=True)
        cover[extra] = n + inv
        parent = np.r_[np.arange(n), uniq // (int(sector.max()) + 1)]
    else:
        parent = np.arange(n)
    return cover, parent


# ---------------------------------------------------------------------------------- cuts
@dataclass
class _CutTree:
    cut: np.ndarray  # bool (m,)
    sources: list[tuple[str, np.ndarray, int]]  # (kind, vertices, node id)
    parent_edge: dict[int, tuple[int, int]]  # node -> (edge index, +1 if edge runs lo->hi from child side)
    children: dict[int, list[int]]


def _cut_tree(mesh: PolyMesh, supports: np.ndarray, xy: np.ndarray) -> _CutTree:
    """Cuts from every hole and interior support to the outer boundary of its component.

    Nodes: each boundary loop is one node (id ``n + k``), every other vertex its own node.
    A Dijkstra tree from the outer loops (support–support edges cheap) gives each source a
    path to the root; the union of those paths is a forest, so cutting along it leaves
    every component a topological disk in which Φ is single valued.
    """
    n, m = mesh.n_vertices, mesh.n_edges
    loops = mesh.boundary_loops
    node = np.arange(n)
    for k, loop in enumerate(loops):
        node[loop] = n + k
    comp = mesh.connected_components
    # outer loop per component: largest |top-view area|
    outer: dict[int, int] = {}
    for k, loop in enumerate(loops):
        c = int(comp[loop[0]])
        a = abs(_loop_area(xy, loop))
        if c not in outer or a > outer[c][1]:
            outer[c] = (k, a)
    roots = [n + k for k, _ in outer.values()]
    outer_ids = {k for k, _ in outer.values()}
    sources: list[tuple[str, np.ndarray, int]] = [("hole", loops[k], n + k) for k in range(len(loops))
                                                 if k not in outer_ids]
    interior_support = np.flatnonzero(supports & ~mesh.boundary_vertex_mask)
    sources += [("support", np.array([v]), int(v)) for v in interior_support]
    cut = np.zeros(m, dtype=bool)
    tree = _CutTree(cut=cut, sources=sources, parent_edge={}, children={})
    if not sources or not roots:
        return tree
    e = mesh.edges
    a, b = node[e[:, 0]], node[e[:, 1]]
    keep = a != b
    cost = np.where(supports[e[:, 0]] & supports[e[:, 1]], SUPPORT_EDGE_COST, 1.0)
    ea, eb, ec, ei = a[keep], b[keep], cost[keep], np.flatnonzero(keep)
    lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
    N = n + len(loops)
    # one representative (cheapest) primal edge per node pair: csgraph would add duplicates
    order = np.lexsort((ec, hi, lo))
    lo, hi, ec, ei = lo[order], hi[order], ec[order], ei[order]
    first = np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])]
    lo, hi, ec, ei = lo[first], hi[first], ec[first], ei[first]
    G = sp.coo_matrix((ec, (lo, hi)), shape=(N, N)).tocsr()
    rep = {(int(p), int(q)): int(k) for p, q, k in zip(lo, hi, ei)}
    _, pred, _ = dijkstra(G, directed=False, indices=roots, min_only=True, return_predecessors=True)
    visited: set[int] = set(roots)
    for _, _, u in sources:
        cur = u
        while cur not in visited:
            p = int(pred[cur])
            if p < 0:  # a component without an outer boundary: nothing to cut to
                break
            k = rep[(min(cur, p), max(cur, p))]
            cut[k] = True
            child_is_lo = node[e[k, 0]] == cur
            tree.parent_edge[cur] = (k, 1 if child_is_lo else -1)
            tree.children.setdefault(p, []).append(cur)
            visited.add(cur)
            cur = p
    return tree


# ---------------------------------------------------------------------------------- solve
def _tree_integrate(F: int, L: np.ndarray, R: np.ndarray, rhs: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """Integrate ``P[L] − P[R] = rhs`` along a breadth-first spanning tree of every dual
    component (root: its pinned face, ``P = 0``). Exact on exact data, O(F log depth):
    path sums by pointer doubling, no Python loop over faces."""
    k = len(L)
    root = F  # a virtual root joined to every component's pinned face (with a zero jump)
    pin = np.flatnonzero(pinned)
    G = sp.coo_matrix((np.ones(k + len(pin)), (np.r_[L, np.full(len(pin), root)], np.r_[R, pin])),
                      shape=(F + 1, F + 1)).tocsr()
    _, pred = breadth_first_order(G, root, directed=False, return_predecessors=True)
    pred = pred[:F]
    # jump from the parent to each face along the tree edge
    key = np.r_[L * (F + 1) + R, R * (F + 1) + L]
    val = np.r_[rhs, -rhs]  # child L of parent R: P_L = P_R + rhs; child R of parent L: P_R = P_L − rhs
    order = np.argsort(key)
    key, val = key[order], val[order]
    child = np.flatnonzero((pred >= 0) & (pred < F))
    step = np.zeros((F, rhs.shape[1]))
    step[child] = val[np.searchsorted(key, child * (F + 1) + pred[child])]
    return accumulate_along(np.where((pred >= 0) & (pred < F), pred, -1), step)


#: How the face planes are obtained from the jumps (``airy(..., integration=NAME)``): each
#: entry decides, from the spanning-tree solution's worst misfit relative to the largest jump
#: and the number of faces, whether to go on to the least-squares solve.
INTEGRATIONS: dict[str, Callable[[float, int], bool]] = {
    # exact input (misfit at round-off): the tree solution is the least-squares one; otherwise
    # least squares, except on very large networks whose misfit is still tiny (the solve would
    # cost seconds to move errors of 1e-12 around)
    "auto": lambda misfit, F: misfit > 1e-15 and (F <= 40_000 or misfit > 1e-12),
    "tree": lambda misfit, F: False,
    "least-squares": lambda misfit, F: True,
}


def _dual_least_squares(F: int, L: np.ndarray, R: np.ndarray, rhs: np.ndarray, rule: Callable[[float, int], bool]
                        ) -> tuple[np.ndarray, np.ndarray, str]:
    """Minimise ``Σ_k ‖P[L_k] − P[R_k] − rhs_k‖²`` over per-face vectors ``P``; one face pinned
    to zero per component of the dual graph.

    The data are first integrated along a spanning tree; on integrable input that already
    fits every dual edge and *is* the least-squares solution. ``rule(misfit, F)`` (see
    :data:`INTEGRATIONS`) decides whether to solve the normal equations (the dual-graph
    Laplacian, one step of iterative refinement) instead, which spreads a misfit over all
    edges rather than leaving it on the few that close the tree's cycles.
    Returns ``(P, component labels, method)``.
    """
    k = len(L)
    adj = sp.coo_matrix((np.ones(k), (L, R)), shape=(F, F))
    _, label = connected_components(adj, directed=False)
    pinned = np.zeros(F, dtype=bool)
    pinned[np.unique(label, return_index=True)[1]] = True
    P = np.zeros((F, rhs.shape[1]))
    if k == 0:
        return P, label, "none"
    P = _tree_integrate(F, L, R, rhs, pinned)
    scale = np.maximum(np.abs(rhs).max(axis=0), 1e-300)
    misfit = float((np.abs(P[L] - P[R] - rhs) / scale).max())
    if not rule(misfit, F):
        return P, label, "tree"
    free = ~pinned
    rows = np.r_[np.arange(k), np.arange(k)]
    B = sp.csr_matrix((np.r_[np.ones(k), -np.ones(k)], (rows, np.r_[L, R])), shape=(k, F))
    Bf = B[:, free].tocsc()
    lu = spd_factor(Bf.T @ Bf)
    x = lu.solve(np.asarray(Bf.T @ rhs))
    # one step of iterative refinement: the dual Laplacian's condition number grows with F
    x += lu.solve(np.asarray(Bf.T @ (rhs - Bf @ x)))
    P[:] = 0.0
    P[free] = x
    return P, label, "least-squares"


def airy(network: Network, *, tol: float = 1e-9, planarity_tol: float = 1e-8, integration: str = "auto") -> AiryResult:
    """The Airy stress surface Φ of a network (see the module docstring).

    Parameters
    ----------
    network
        A :class:`~selfsupport.core.result.Network` (or anything with a ``.network``, e.g. a
        :class:`~selfsupport.core.result.SolveResult`). Its weights are used as they are; the
        network need not be exactly in equilibrium (the defect is reported).
    tol
        Relative tolerance of the convexity verdict: Φ counts as convex when every crease
        weight is ``>= -tol * max|w|``.
    integration
        ``"auto"`` (default), ``"tree"`` or ``"least-squares"`` (:data:`INTEGRATIONS`): the
        spanning-tree integration is exact and linear-time on integrable input; least squares
        spreads the misfit of slightly non-integrable input (a dual-Laplacian solve, ~0.4 s at
        10k vertices). ``"auto"`` uses least squares unless the input is integrable to
        round-off, or very large (> 40k faces) and integrable to 1e-12.
    planarity_tol
        Polygon faces whose vertex values deviate from their plane by more than this, relative
        to ``mean jump × mean edge length``, are reported as non-planar and split.

    Returns
    -------
    AiryResult

    Raises
    ------
    InputError
        Wrong weight count, non-finite weights, or a degenerate top view (faces of zero area).
    """
    t0 = time.perf_counter()
    network = getattr(network, "network", network)
    horizontal = float(np.abs(load_vectors(network.loads)[:, :2]).max(initial=0.0))
    if horizontal > 0:
        raise InputError(f"the Airy stress function and the reciprocal diagram apply to vertical loads only, and this "
                         f"network carries horizontal loads (up to {horizontal:.3g} N at a vertex); analyse a network "
                         "under vertical loads")
    mesh = network.mesh
    n, m, F = mesh.n_vertices, mesh.n_edges, mesh.n_faces
    w = np.asarray(network.weights, float)
    if w.shape != (m,) or not np.all(np.isfinite(w)):
        raise InputError(f"the network needs one finite weight per edge ({m}); got shape {w.shape}")
    supports = np.asarray(network.supports, bool)
    xy0 = mesh.vertices[:, :2]
    center = 0.5 * (xy0.min(axis=0) + xy0.max(axis=0))
    xy = xy0 - center  # centred: keeps the plane offsets well conditioned
    sigma, signed_area = face_orientation(mesh, xy)
    diag = float(np.linalg.norm(xy.max(axis=0) - xy.min(axis=0)))
    if diag == 0 or np.any(np.abs(signed_area) <= 1e-14 * diag ** 2):
        k = int(np.argmin(np.abs(signed_area)))
        raise InputError(f"face {k} has (almost) zero area in the top view, so Φ has no plane there; "
                         "the Airy surface needs a top view without vertical faces")

    e = mesh.edges
    ef = mesh.edge_faces
    interior = (ef >= 0).all(axis=1)
    ev = xy[e[:, 1]] - xy[e[:, 0]]
    elen2 = (ev * ev).sum(axis=1)
    D = top_view_jumps(mesh, w, sigma, xy)
    D[~interior] = 0.0
    mid = 0.5 * (xy[e[:, 0]] + xy[e[:, 1]])
    Dc = -(D * mid).sum(axis=1)  # continuity along the edge: c_L − c_R = −D · x on the edge
    rhs_all = np.c_[D, Dc]

    tree = _cut_tree(mesh, supports, xy)
    dual = interior & ~tree.cut
    try:
        rule = INTEGRATIONS[integration]
    except KeyError:
        raise InputError(f"unknown integration {integration!r}; choose one of {', '.join(INTEGRATIONS)}") from None
    P, label, integration = _dual_least_squares(F, ef[dual, 0], ef[dual, 1], rhs_all[dual], rule)

    # faces of components that touch no free vertex carry nothing: refit them afterwards
    face_of, _, _ = mesh.corner_data
    fv = mesh.face_vertices
    has_free = np.zeros(F, dtype=bool)
    np.logical_or.at(has_free, face_of, ~supports[fv])
    live_comp = np.zeros(label.max() + 1, dtype=bool)
    live_comp[label[has_free]] = True
    live_face = live_comp[label]

    def corner_values(P: np.ndarray) -> np.ndarray:
        return np.einsum("ci,ci->c", P[face_of, :2], xy[fv]) + P[face_of, 2]

    # gauge: remove the best-fit plane of each live component's corner values
    cv = corner_values(P)
    comp_c = label[face_of]
    A = np.c_[xy[fv], np.ones(len(fv))]
    nc = label.max() + 1
    M = np.zeros((nc, 3, 3))
    r = np.zeros((nc, 3))
    for a in range(3):
        np.add.at(r[:, a], comp_c, A[:, a] * cv)
        for b in range(3):
            np.add.at(M[:, a, b], comp_c, A[:, a] * A[:, b])
    ok = np.linalg.matrix_rank(M) == 3
    gauge = np.zeros((nc, 3))
    gauge[ok] = np.linalg.solve(M[ok], r[ok][..., None])[..., 0]
    P = P - gauge[label]

    jump_scale = float(np.mean(np.sqrt(elen2[interior]) * np.abs(w[interior]))) if interior.any() else 1.0
    jump_scale = jump_scale if jump_scale > 0 else 1.0
    h_mean = float(np.sqrt(elen2).mean())
    value_tol = planarity_tol * jump_scale * h_mean

    # Φ on the cover: every corner keeps its face's plane; around each vertex the planes are
    # continued across cut edges (the period applied), and the corners of a vertex are one
    # vertex of Φ unless a cut with a non-zero period separates them
    stars = vertex_stars(mesh, sigma)
    cut_mismatch = np.zeros((m, 3))
    on_cut = tree.cut & interior
    cut_mismatch[on_cut] = P[ef[on_cut, 0]] - P[ef[on_cut, 1]] - rhs_all[on_cut]
    shift, sector = _star_shifts(mesh, stars, cut_mismatch, xy, value_tol)
    cover_vertex, cover_parent = _cover_vertices(n, fv, sector)
    ncov = len(cover_parent)

    # φ per cover vertex: mean of the live incident planes (all planes where none is live)
    cv = corner_values(P)
    live_c = live_face[face_of]
    has_live = np.zeros(ncov, dtype=bool)
    np.logical_or.at(has_live, cover_vertex, live_c)
    use = live_c | ~has_live[cover_vertex]
    cnt = np.bincount(cover_vertex[use], minlength=ncov)
    cover_phi = np.bincount(cover_vertex[use], weights=cv[use], minlength=ncov) / np.maximum(cnt, 1)
    hi_v = np.full(ncov, -np.inf)
    lo_v = np.full(ncov, np.inf)
    np.maximum.at(hi_v, cover_vertex[use], cv[use])
    np.minimum.at(lo_v, cover_vertex[use], cv[use])
    spread = np.zeros(n)
    np.maximum.at(spread, cover_parent, np.where(cnt > 0, hi_v - lo_v, 0.0))
    phi = cover_phi[:n]
    phi_c = cover_phi[cover_vertex]

    if not live_face.all():
        g_d, c_d, _ = _planes_through_corners(mesh, xy, phi_c)
        dead = ~live_face
        P[dead, :2], P[dead, 2] = g_d[dead], c_d[dead]

    g = P[:, :2]
    c = P[:, 2]
    planar = np.zeros(F)
    np.maximum.at(planar, face_of, np.abs(phi_c - corner_values(P)))
    star = P[face_of] + shift
    star_planes = np.c_[star[:, :2], star[:, 2] - star[:, :2] @ center]  # network coordinates

    # the jump condition as achieved, and the weights Φ's creases stand for
    diff = np.full((m, 2), np.nan)
    diff[interior] = g[ef[interior, 0]] - g[ef[interior, 1]]
    edge_res = np.linalg.norm(diff - D, axis=1)
    crease = (diff * (sigma * _J(ev))).sum(axis=1) / np.where(elen2 > 0, elen2, np.nan)
    crease[tree.cut] = np.nan

    # closure: horizontal equilibrium (2) wherever it is required (free vertices); at interior ones
    # it is exactly the integrability of Φ around the vertex
    hsum = stress_sums(edges=e, weights=w, values=xy)
    mag = force_sums(edges=e, weights=w, values=xy)
    needs = ~supports
    closure = np.full(n, np.nan)
    closure[needs] = np.linalg.norm(hsum[needs], axis=1) / np.maximum(mag[needs], 1e-300)

    # periods: mismatch across each cut edge, minus what the sources beyond it contribute
    periods: list[Period] = []
    if tree.sources:
        mismatch: dict[int, np.ndarray] = {}
        for node_id, (k, s) in tree.parent_edge.items():
            if interior[k]:
                mismatch[node_id] = s * (P[ef[k, 0]] - P[ef[k, 1]] - rhs_all[k])
            else:
                mismatch[node_id] = np.zeros(3)
        for kind, verts, node_id in tree.sources:
            if node_id not in tree.parent_edge:
                continue
            own = mismatch[node_id] - sum((mismatch[ch] for ch in tree.children.get(node_id, [])), np.zeros(3))
            own_g = own[:2] * sigma
            own_c = own[2] * sigma - float(own_g @ center)  # back to network coordinates
            T = -hsum[verts].sum(axis=0)
            Mt = float(np.sum(_cross2(xy0[verts], -hsum[verts])))
            periods.append(Period(kind=kind, vertices=np.asarray(verts), gradient=own_g, offset=float(own_c),
                                  cut_edges=np.array([tree.parent_edge[node_id][0]]), thrust=T, moment=Mt))

    # non-planar polygons: split by fan diagonals (zero-force edges of S), report their creases
    sizes = mesh.face_sizes
    bad = np.flatnonzero((sizes > 3) & (planar > value_tol))
    split_e, split_w = _split_fans(mesh, bad, xy, phi_c, sigma)

    wmax = float(np.abs(w).max()) if w.size else 0.0
    judged = interior & ~tree.cut & np.isfinite(crease) & ~(supports[e[:, 0]] & supports[e[:, 1]])
    convex = bool(np.all(crease[judged] >= -tol * max(wmax, 1e-300)))

    c_out = c - g @ center  # planes in network coordinates
    return AiryResult(
        mesh=mesh, weights=w, supports=supports, phi=phi, face_gradients=g, face_offsets=c_out, orientation=sigma,
        jumps=D, crease_weights=crease, edge_residual=np.where(interior, edge_res, np.nan),
        closure_residual=closure, vertex_spread=spread, planarity_residual=planar,
        cut_edges=np.flatnonzero(tree.cut), periods=tuple(periods), nonplanar_faces=bad,
        split_edges=split_e, split_edge_weights=split_w,
        convex=convex, face_component=label, integration=integration,
        cover_vertex=cover_vertex, cover_phi=cover_phi, cover_parent=cover_parent, star_planes=star_planes,
        scale={"center_x": float(center[0]), "center_y": float(center[1]), "diagonal": diag,
               "jump": jump_scale, "edge_length": h_mean},
        seconds=time.perf_counter() - t0)
