"""§5 of the paper: Koenigs nets, Koebe meshes and the family Φ + αR (Fig. 15).

The setting
-----------
A thrust network S and its Airy surface Φ share their top view; a height field R over the same
top view keeps the loads of S when ``Δ_φ r = 0`` (R is *minimal relative to Φ*). For planar-quad
meshes the paper's condition is that the polar meshes R*, Φ* (polarity in the Maxwell paraboloid
``z = ½(x² + y²)``, :mod:`.reciprocal`) are **Christoffel duals**; a dual exists when Φ* is a
Koenigs net. The pieces, each a small numeric core:

* :func:`christoffel_dual` — the Christoffel dual of any planar-quad Koenigs net in ℝ³: same
  combinatorics, corresponding edges parallel, each dual quad's diagonals parallel to the
  primal's *other* diagonals. Per quad the dual's edge scalars are fixed up to one factor by the
  diagonal intersection (derivation at :func:`quad_dual_scalars`); the factors of neighbouring
  quads must agree on their common edge, a linear system in ``log |λ_f|`` whose residual is the
  **Koenigs defect** (0 exactly for a Koenigs net). Defined up to scale and translation.
* :func:`polar_mesh` — Φ*: one vertex per face of Φ (the pole ``(g, −c)`` of its plane
  ``z = g·x + c``), one face per interior vertex of Φ (the poles of the faces around it).
* :func:`minimal_partner` — R: the Christoffel dual R* of Φ*, polar again. Face ``f`` of R lies in
  the polar plane of R*'s vertex ``f``; R*'s faces are parallel to Φ*'s, so R has Φ's top view,
  and ``Δ_φ r = 0`` is the paper's zero mean curvature (parallel non-corresponding diagonals,
  its Fig. 4). (The caption of the paper's Fig. 15 calls R "Φ's Christoffel dual"; its text, and
  the shared top view, make it the polar of the dual of the polar.) A final Dirichlet solve from
  R's boundary heights removes the round-off of integrating R*.
* :func:`koebe_mesh` — explicit Φ: a square-grid circle pattern (optionally inverted, which gives
  the paper's Enneper example) turned into a PQ mesh either **tangent** to the paraboloid (a
  Koebe mesh: vertex ``v`` at the centre ``c`` of its circle, height ``½(|c|² − ρ²)``; adjacent
  circles touch, so each edge touches the paraboloid above the touching point, and the face
  circles are orthogonal to the vertex circles, which makes the faces planar) or **inscribed**
  in it (vertices on the paraboloid over a circular net; this is what the published
  ``enneper-koebe.obj`` is).
* :func:`family` — the thrust network of ``Φ + αR`` as a :class:`~selfsupport.core.result.Network`.

Which surface is which, and the loads
-------------------------------------
The paper measures heights along the load, so its "self-supporting Φ" is a *bowl*. With z up
(the project's convention) the thrust network of the family member α is the reflection
``s = −(φ + α r)`` and Φ (convex) is its Airy surface: the weights are Φ's creases
``w_ij = (jump of ∇φ across e_ij) / ‖e'_ij‖ ≥ 0`` (compression), halved and scaled by the load
density ``q``. Then ``Σ_j w_ij (s_j − s_i) = −(q/2) (Δ_φ φ + α Δ_φ r) = −q A*_i``, where
``A*_i = ½ Δ_φ φ(i)`` is the area of vertex i's cell in the reciprocal diagram (the paper's
``A_i(Φ, Φ)``), for every α. That is the paper's discrete balance ``2 K_Φ H^rel = F`` with
``H^rel = 1`` and ``K_Φ = A*_i / A_i``: a dead load of density ``q K_Φ`` per unit of top-view
area. (With Φ's full creases as weights the load density would be ``2 K_Φ`` — the paper's
"``2 K H^rel ≈ 1``" drops that factor; halving the weights, i.e. taking ½Φ as the Airy surface,
restores it.) "Unit load" means ``q = 1`` and ``K_Φ ≈ 1``, which holds because Φ approximates the
Maxwell paraboloid (``det ∇²φ = 1``): *exactly* for the inscribed meshes, whose reciprocal
cells are the circumcentre (Voronoi) cells of the top view, approximately for tangent ones
(:attr:`KoebeFamily.gauss_curvature` reports it). Supports are the boundary vertices; their
load is ``−q`` times their top-view area (:func:`centre_areas`; it goes straight into the ground).

Example
-------
>>> phi = koebe_mesh("enneper", n=8, hole=2)
>>> net = family(phi, alpha=1.0).network
>>> net.max_relative_error() < 1e-10, net.min_weight() > 0
(True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components

from selfsupport.analysis.airy import face_orientation, face_planes_through, freeze_arrays
from selfsupport.analysis.construction import lifting_weights
from selfsupport.analysis.reciprocal import cell_areas, vertex_face_rings
from selfsupport.analysis.stars import accumulate_along
from selfsupport.core.errors import InputError, MeshError, NotKoenigs
from selfsupport.core.evidence import stress_sums
from selfsupport.core.linalg import spd_factor
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network

__all__ = ["ChristoffelDual", "christoffel_dual", "quad_dual_scalars", "PolarMesh", "polar_mesh",
           "MinimalPartner", "minimal_partner", "KoebeFamily", "family", "koebe_mesh", "KOEBE_EXAMPLES",
           "MOBIUS_MAPS", "paraboloid_gaps", "centre_areas", "LOAD_RULES", "as_airy", "KINDS"]


# ------------------------------------------------------------------------------ Christoffel dual
def _quads(mesh: PolyMesh, what: str) -> np.ndarray:
    if mesh.n_faces == 0 or not np.all(mesh.face_sizes == 4):
        raise MeshError(f"{what} must be a quad mesh (every face 4 vertices); "
                        f"it has faces of sizes {sorted(set(mesh.face_sizes.tolist()))}")
    return mesh.face_vertices.reshape(-1, 4)


def quad_dual_scalars(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge scalars of the Christoffel dual of each quad, up to one factor per quad.

    For a planar quad ``x0 x1 x2 x3`` with diagonals meeting at ``x0 + a (x2 − x0) =
    x1 + b (x3 − x1)``, the quad with edges ``c_k (x_{k+1} − x_k)`` closes and has diagonals
    parallel to the primal's other ones exactly for ::

        c ∝ ((1 − a)(1 − b), −a (1 − b), a b, −b (1 − a))

    (put the dual's vertices on the two lines through the origin along ``x3 − x1`` and
    ``x2 − x0`` and require each edge parallel to its primal edge: four conditions, three
    unknowns, consistent; the signs alternate like ``dx* = x_u/|x_u|² du − x_v/|x_v|² dv``).
    Starting the quad at another corner only changes the factor.

    Parameters
    ----------
    P
        ``(F, 4, d)`` quad corners.

    Returns
    -------
    c, planarity
        ``(F, 4)`` scalars for the directed edges ``k → k + 1`` and ``(F,)`` the distance between the
        diagonals (0 for a planar quad).

    >>> c, gap = quad_dual_scalars(np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.]]]))
    >>> (c / c[0, 0]).tolist(), float(gap[0])
    ([[1.0, -1.0, 1.0, -1.0]], 0.0)
    """
    P = np.asarray(P, float)
    d1, d2, rhs = P[:, 2] - P[:, 0], P[:, 3] - P[:, 1], P[:, 1] - P[:, 0]
    # least squares [d1, −d2] (a, b) = x1 − x0 (exact for a planar quad)
    g11, g12, g22 = (d1 * d1).sum(1), -(d1 * d2).sum(1), (d2 * d2).sum(1)
    h1, h2 = (d1 * rhs).sum(1), -(d2 * rhs).sum(1)
    det = g11 * g22 - g12 * g12
    if np.any(det <= 1e-14 * g11 * g22):
        raise MeshError(f"quad {int(np.argmax(det <= 1e-14 * g11 * g22))} has parallel diagonals (degenerate)")
    a = (g22 * h1 - g12 * h2) / det
    b = (g11 * h2 - g12 * h1) / det
    gap = np.linalg.norm(a[:, None] * d1 - b[:, None] * d2 - rhs, axis=1)
    c = np.stack([(1 - a) * (1 - b), -a * (1 - b), a * b, -b * (1 - a)], axis=1)
    return c, gap


@dataclass(frozen=True, eq=False)
class ChristoffelDual:
    """The Christoffel dual of a quad mesh.

    ``mesh`` has the primal's faces; ``edge_scale[k]`` is the scalar with
    ``x*_j − x*_i = edge_scale[k] (x_j − x_i)`` on ``edges[k] = (i, j)`` (signed). The
    ``koenigs_defect`` is the largest mismatch ``|log|λ_f c_e^f| − log|λ_g c_e^g||`` of the two
    faces' scalars on an interior edge after the least-squares fit (0 for a Koenigs net);
    ``closure_residual`` the largest ``‖x*_j − x*_i − c_e e_ij‖`` over the RMS dual edge length,
    ``nonplanarity`` the primal's largest diagonal gap over its RMS edge length.
    """

    mesh: PolyMesh
    edge_scale: np.ndarray
    koenigs_defect: float
    closure_residual: float
    nonplanarity: float

    def __post_init__(self) -> None:
        freeze_arrays(self)


def _pinned_laplacian_solve(n: int, i: np.ndarray, j: np.ndarray, rhs_edge: np.ndarray,
                            pinned_value: np.ndarray | None = None) -> np.ndarray:
    """Least squares ``u_j − u_i = rhs_edge`` over a graph of ``n`` nodes, one node per
    connected component pinned (to ``pinned_value`` there, default 0)."""
    rhs_edge = np.asarray(rhs_edge, float)
    cols = 1 if rhs_edge.ndim == 1 else rhs_edge.shape[1]
    R = rhs_edge.reshape(len(i), cols)
    B = sp.csr_matrix((np.r_[-np.ones(len(i)), np.ones(len(i))], (np.r_[np.arange(len(i)), np.arange(len(i))],
                                                                    np.r_[i, j])), shape=(len(i), n))
    _, comp = connected_components(B.T @ B, directed=False)
    _, pin = np.unique(comp, return_index=True)
    free = np.ones(n, dtype=bool)
    free[pin] = False
    base = np.zeros((n, cols)) if pinned_value is None else np.asarray(pinned_value, float).reshape(n, cols).copy()
    base[free] = 0.0
    out = base.copy()
    if free.any():
        Bf = B[:, free].tocsc()
        rhs = Bf.T @ (R - B @ base)
        out[free] = spd_factor((Bf.T @ Bf).tocsc()).solve(rhs).reshape(-1, cols)
    return out if rhs_edge.ndim > 1 else out[:, 0]


def christoffel_dual(mesh: PolyMesh, *, tol: float = 1e-8) -> ChristoffelDual:
    """The Christoffel dual of a planar-quad mesh (see the module docstring).

    The dual is scaled so that its RMS edge length equals the primal's, signed so that most
    edge scalars are positive, and translated to the primal's centroid.

    Raises
    ------
    NotKoenigs
        When the per-face factors cannot agree: their signs contradict each other around a
        vertex, or the log-magnitudes miss by more than ``tol`` (then no dual exists).
    MeshError
        For a mesh that is not all quads, or a degenerate quad.

    >>> V = np.array([[x, y, 0.] for y in range(3) for x in range(3)])
    >>> quads = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]]
    >>> d = christoffel_dual(PolyMesh.from_faces(V, quads))
    >>> d.koenigs_defect < 1e-12, sorted(set(np.round(d.edge_scale, 12).tolist()))
    (True, [-1.0, 1.0])
    """
    Q = _quads(mesh, "a Christoffel dual's mesh")
    X = mesh.vertices
    c, gap = quad_dual_scalars(X[Q])
    ell = math.sqrt(float(np.mean(np.sum((X[mesh.edges[:, 1]] - X[mesh.edges[:, 0]]) ** 2, axis=1))))
    nonplanarity = float(gap.max()) / ell
    if not np.all(np.isfinite(c)) or np.any(np.abs(c) <= 1e-12 * np.abs(c).max(axis=1, keepdims=True)):
        raise MeshError("a quad's diagonals meet at one of its corners: the quad is degenerate and has no dual")
    he_edge = mesh.halfedge_data["halfedge_edge"]  # corner -> edge (corner k of face f runs k -> k+1)
    face_of = np.repeat(np.arange(mesh.n_faces), 4)
    c = c.ravel()
    m = mesh.n_edges
    # the two half-edges of every interior edge
    first = np.full(m, -1)
    second = np.full(m, -1)
    order = np.argsort(he_edge, kind="stable")
    starts = np.searchsorted(he_edge[order], np.arange(m))
    counts = np.bincount(he_edge, minlength=m)
    first[:] = order[starts]
    two = counts == 2
    second[two] = order[starts[two] + 1]
    h1, h2 = first[two], second[two]
    f1, f2 = face_of[h1], face_of[h2]
    F = mesh.n_faces
    # signs: λ_f1 c1 and λ_f2 c2 must have the same sign -> σ_f1 σ_f2 = sign(c1 c2); σ from the
    # parity of the sign flips along a breadth-first tree of each component of the face graph
    G = sp.csr_matrix((np.ones(len(f1)), (f1, f2)), shape=(F, F))
    G = G + G.T
    sgn_edge = np.sign(c[h1] * c[h2])
    _, comp = connected_components(G, directed=False)
    parent = np.full(F, -1)
    for root in np.unique(comp, return_index=True)[1]:
        nodes, pred = breadth_first_order(G, int(root), directed=False)
        parent[nodes[1:]] = pred[nodes[1:]]
    a, b = np.minimum(f1, f2), np.maximum(f1, f2)
    key = a * F + b
    order = np.argsort(key)
    child = np.flatnonzero(parent >= 0)
    tk = np.minimum(child, parent[child]) * F + np.maximum(child, parent[child])
    flip = np.zeros(F, dtype=np.int64)
    flip[child] = (sgn_edge[order[np.searchsorted(key[order], tk)]] < 0).astype(np.int64)
    sigma = np.where(accumulate_along(parent, flip) % 2 == 1, -1.0, 1.0)
    bad = sigma[f1] * sigma[f2] != sgn_edge
    if np.any(bad):
        k = int(np.argmax(bad))
        raise NotKoenigs(f"faces {int(f1[k])} and {int(f2[k])} need dual scale factors of opposite signs around a "
                         "vertex: this quad mesh has no Christoffel dual (it is not a Koenigs net)")
    # magnitudes: log|λ_f1| − log|λ_f2| = log|c2| − log|c1|
    t = np.log(np.abs(c[h2])) - np.log(np.abs(c[h1]))
    mu = _pinned_laplacian_solve(F, f2, f1, t)
    defect = float(np.abs(mu[f1] - mu[f2] - t).max()) if len(t) else 0.0
    if defect > tol:
        raise NotKoenigs(f"the quads' dual scale factors disagree by up to {defect:.2e} (log ratio) on shared edges: "
                         "the mesh is not a Koenigs net, so it has no Christoffel dual")
    lam = sigma * np.exp(mu - mu.mean())
    scale_he = lam[face_of] * c
    edge_scale = scale_he[first].copy()
    edge_scale[two] = 0.5 * (scale_he[h1] + scale_he[h2])
    # orientation of the edge vs. the half-edge: corner k runs fv -> next; edges are stored i < j,
    # and the scalar is symmetric under reversal, so no sign fix is needed
    if np.sum(edge_scale > 0) < np.sum(edge_scale < 0):
        edge_scale = -edge_scale
    e = mesh.edges
    ev = X[e[:, 1]] - X[e[:, 0]]
    edge_scale *= ell / math.sqrt(float(np.mean(np.sum((edge_scale[:, None] * ev) ** 2, axis=1))))
    target = edge_scale[:, None] * ev
    Xd = _pinned_laplacian_solve(mesh.n_vertices, e[:, 0], e[:, 1], target)
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[mesh.face_vertices] = True
    Xd[used] += X[used].mean(axis=0) - Xd[used].mean(axis=0)
    closure = float(np.linalg.norm(Xd[e[:, 1]] - Xd[e[:, 0]] - target, axis=1).max()) / ell
    return ChristoffelDual(mesh=mesh.with_vertices(Xd), edge_scale=edge_scale, koenigs_defect=defect,
                           closure_residual=closure, nonplanarity=nonplanarity)


# ------------------------------------------------------------------------------ polarity
@dataclass(frozen=True, eq=False)
class PolarMesh:
    """Φ* of a mesh Φ: ``mesh.vertices[f]`` is the pole of face ``f`` of Φ, ``mesh`` face ``k`` the
    ring of faces around Φ's interior vertex ``vertex_of_face[k]`` (counter-clockwise in the top
    view). Faces of Φ around no interior vertex are isolated vertices of Φ*. ``nonplanarity`` is
    the largest deviation of Φ's corners from their face's least-squares plane."""

    mesh: PolyMesh
    vertex_of_face: np.ndarray
    nonplanarity: float

    def __post_init__(self) -> None:
        freeze_arrays(self)


def _poles(mesh: PolyMesh, values: np.ndarray) -> tuple[np.ndarray, float]:
    g, c, res = face_planes_through(mesh, mesh.vertices[:, :2], values)
    return np.c_[g, -c], float(res.max())


def polar_mesh(mesh: PolyMesh) -> PolarMesh:
    """The polar mesh Φ* of a planar-faced height field Φ in the Maxwell paraboloid
    ``z = ½(x² + y²)``: the plane ``z = g·x + c`` ↦ the point ``(g, −c)`` (paper §2.2, Fig. 3).

    >>> V = np.array([[x, y, 0.5 * (x * x + y * y)] for y in range(3) for x in range(3)], float)
    >>> P = polar_mesh(PolyMesh.from_faces(V, [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]]))
    >>> P.vertex_of_face.tolist(), P.mesh.faces
    ([4], [[0, 1, 3, 2]])
    """
    poles, nonplanar = _poles(mesh, mesh.vertices[:, 2])
    sigma, _ = face_orientation(mesh)
    offsets, ring = vertex_face_rings(mesh, sigma)
    interior = np.flatnonzero(~mesh.boundary_vertex_mask & (np.diff(offsets) > 0))
    faces = [ring[offsets[v]:offsets[v + 1]].tolist() for v in interior]
    dual = PolyMesh.from_faces(poles, faces)
    return PolarMesh(mesh=dual, vertex_of_face=interior, nonplanarity=nonplanar)


# ------------------------------------------------------------------------------ the minimal partner R
@dataclass(frozen=True, eq=False)
class MinimalPartner:
    """R over Φ's top view with ``Δ_φ r = 0`` and planar faces (see :func:`minimal_partner`).

    ``heights`` are normalized: R's least-squares affine part removed (affine heights are the
    trivial minimal partners; they only tilt the family) and ``max |r| = `` Φ's height range.
    ``dual`` is the Christoffel dual R* of Φ*; ``vertex_spread`` the largest disagreement between
    the face planes of R at a vertex (0 up to round-off: at interior vertices by polarity, at
    boundary vertices because R*'s edges are parallel to Φ*'s), relative to max |r|.
    ``polish_change``: how far (over max |r|) the final Dirichlet solve moved the interior heights.
    """

    heights: np.ndarray
    polar: PolarMesh
    dual: ChristoffelDual
    vertex_spread: float
    polish_change: float

    def __post_init__(self) -> None:
        freeze_arrays(self)


def _check_height_field(mesh: PolyMesh, what: str) -> None:
    _quads(mesh, what)
    p = mesh.problems()
    if p:
        raise MeshError(f"{what}: {p[0]}")
    _, areas = face_orientation(mesh)
    if np.any(areas == 0) or np.any(np.sign(areas) != np.sign(areas[0])):
        raise MeshError(f"{what} is not a height field: its faces overlap or fold in the top view")


def minimal_partner(phi: PolyMesh, *, tol: float = 1e-8) -> MinimalPartner:
    """The planar-quad mesh R over Φ's top view that is minimal relative to Φ (``Δ_φ r = 0``):
    the polar of the Christoffel dual of Φ*'s polar mesh (paper §5, "Koenigs meshes").

    Raises :class:`NotKoenigs` when Φ* is not a Koenigs net (no such R exists).
    """
    _check_height_field(phi, "the Koebe mesh Φ")
    P = polar_mesh(phi)
    _quads(P.mesh, "Φ's polar mesh Φ* (every interior vertex of Φ needs 4 edges)")
    D = christoffel_dual(P.mesh, tol=tol)
    Rstar = D.mesh.vertices
    in_dual = np.zeros(phi.n_faces, dtype=bool)
    in_dual[P.mesh.face_vertices] = True
    # face f of R lies in the polar plane of R*'s vertex f: z = a·x − c for R*_f = (a, c)
    face_of, _, _ = phi.corner_data
    fv = phi.face_vertices
    xy = phi.vertices[:, :2]
    ok = in_dual[face_of]
    val = np.einsum("ij,ij->i", Rstar[face_of[ok], :2], xy[fv[ok]]) - Rstar[face_of[ok], 2]
    n = phi.n_vertices
    cnt = np.bincount(fv[ok], minlength=n)
    if np.any(cnt == 0):
        raise MeshError(f"vertex {int(np.argmax(cnt == 0))} of Φ lies only on faces without an interior vertex; "
                        "R is not defined there (trim the mesh's dangling faces)")
    r = np.bincount(fv[ok], weights=val, minlength=n) / cnt
    spread = np.zeros(n)
    np.maximum.at(spread, fv[ok], np.abs(val - r[fv[ok]]))
    r_dual = r
    r = _harmonic_extension(phi, r)
    change = float(np.abs(r - r_dual).max())
    A = np.c_[xy, np.ones(n)]
    r = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]
    size = float(np.ptp(phi.vertices[:, 2])) or 1.0
    rmax = float(np.abs(r).max())
    if rmax <= 1e-12 * size:
        raise NotKoenigs("the minimal partner R of this mesh is affine (a plane): the family Φ + αR only tilts Φ")
    r = r * (size / rmax) * _sign_convention(r, xy)
    return MinimalPartner(heights=r, polar=P, dual=D, vertex_spread=float(spread.max()) / rmax,
                          polish_change=change / rmax)


def _sign_convention(r: np.ndarray, xy: np.ndarray) -> float:
    """The sign that makes R positive at its largest |r|, ties broken by the top view.

    R and −R are equally minimal: the sign is a convention. Symmetric meshes (Enneper's is odd
    under x ↔ y) have several vertices with the same |r| and opposite signs, so "the largest"
    alone would follow round-off; among the vertices within 1e-6 of the largest |r| the one
    first in (x, y) order decides.
    """
    a = np.abs(r)
    near = np.flatnonzero(a >= (1.0 - 1e-6) * a.max())
    scale = float(np.ptp(xy, axis=0).max()) or 1.0
    key = np.round(xy[near] / (1e-6 * scale))  # positions equal to 1e-6 of the size count as equal
    first = near[np.lexsort((key[:, 1], key[:, 0]))[0]]
    return float(np.sign(r[first]))


def _harmonic_extension(phi: PolyMesh, r: np.ndarray) -> np.ndarray:
    """``r`` on the boundary, ``Δ_φ r = 0`` inside (one sparse SPD solve with Φ's creases).

    R from the dual is harmonic only up to the round-off of integrating R*'s edges, which the
    small reciprocal cells of a strongly graded mesh (the inverted grid: cell areas over six
    decades at 10k vertices) turn into 1e-7 relative load errors; the true R is the harmonic
    extension of its boundary values, so solving for it removes that round-off.
    """
    w, _ = lifting_weights(phi, phi.vertices[:, 2])
    e = phi.edges
    n = phi.n_vertices
    L = sp.csr_matrix((np.r_[w, w, -w, -w], (np.r_[e[:, 0], e[:, 1], e[:, 0], e[:, 1]],
                                             np.r_[e[:, 1], e[:, 0], e[:, 0], e[:, 1]])), shape=(n, n))
    inner = ~phi.boundary_vertex_mask
    if not inner.any():
        return r
    out = np.array(r, dtype=float)
    Lii = -L[inner][:, inner]
    out[inner] = spd_factor(Lii.tocsc()).solve(L[inner][:, ~inner] @ out[~inner])
    return out


# ------------------------------------------------------------------------------ the family Φ + αR
def centre_areas(mesh: PolyMesh, centres: np.ndarray) -> np.ndarray:
    """Top-view vertex areas: each face split at its centre ``centres[f]`` into one quadrilateral
    per corner (corner, midpoint of the next edge, centre, midpoint of the previous edge), signed.
    They sum to the top-view area of the mesh for any centres; with the circumcentres of circular
    faces they are the Voronoi (circumcentric) areas.

    >>> m = PolyMesh.from_faces(np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0.]]), [[0, 1, 2, 3]])
    >>> centre_areas(m, np.array([[1.0, 1.0]])).tolist()
    [1.0, 1.0, 1.0, 1.0]
    """
    face_of, nxt, prv = mesh.corner_data
    xy = mesh.vertices[:, :2]
    p = xy[mesh.face_vertices]
    pts = [p, 0.5 * (p + xy[nxt]), np.asarray(centres, float)[face_of], 0.5 * (p + xy[prv])]
    a = 0.5 * sum(pts[k][:, 0] * pts[(k + 1) % 4][:, 1] - pts[(k + 1) % 4][:, 0] * pts[k][:, 1] for k in range(4))
    sigma, _ = face_orientation(mesh)
    return sigma * np.bincount(mesh.face_vertices, weights=a, minlength=mesh.n_vertices)


#: How the loads of the family are taken (both times ``−q``): ``reciprocal`` — the reciprocal
#: cell areas ``A*_i = ½ Δ_φ φ(i)``, in equilibrium for every Φ (the default); ``top-view`` — the
#: top-view areas ``A_i`` (:func:`centre_areas` at the face planes' centres), the literal unit load
#: per top-view area, in equilibrium only where ``K_Φ = A*_i / A_i = 1`` (inscribed meshes).
LOAD_RULES = ("reciprocal", "top-view")


@dataclass(frozen=True, eq=False)
class KoebeFamily:
    """One member ``S_α = −(Φ + αR)`` (z up) of the family, as a thrust network, and its evidence.

    ``gauss_curvature`` is ``K_Φ(v_i) = A*_i / A_i`` per interior vertex (reciprocal-cell area over
    the top-view area of :func:`centre_areas` at each face plane's centre — the centre of the circle
    in which the plane cuts the paraboloid; NaN on the boundary): 1 means unit load per unit
    top-view area. ``harmonic_residual`` is ``max |Δ_φ r| / max Δ_φ φ`` over the interior vertices.
    """

    network: Network
    phi: np.ndarray
    r: np.ndarray
    alpha: float
    load_density: float
    loads: str
    gauss_curvature: np.ndarray
    harmonic_residual: float
    partner: MinimalPartner
    #: the input was a dome and was reflected into Φ (set by :func:`selfsupport.api.koebe`)
    flipped: bool = False

    def __post_init__(self) -> None:
        freeze_arrays(self)


def as_airy(mesh: PolyMesh) -> tuple[PolyMesh, bool]:
    """The convex orientation of a Koebe mesh: ``(Φ, flipped)``. A dome (every interior crease
    ≤ 0: the thrust network ``−Φ`` of α = 0, e.g. the paper's OBJ files read with ``up=-y``) is
    reflected in the plane z = 0; a bowl is returned as it is."""
    crease, _ = lifting_weights(mesh, mesh.vertices[:, 2])
    inner = crease[~mesh.boundary_edge_mask]
    if inner.size and np.all(inner <= 0) and np.any(inner < 0):
        return mesh.with_vertices(mesh.vertices * np.array([1.0, 1.0, -1.0])), True
    return mesh, False


def family(phi: PolyMesh, alpha: float, *, partner: MinimalPartner | None = None,
           load_density: float = 1.0, loads: str = "reciprocal") -> KoebeFamily:
    """The thrust network of ``Φ + αR`` for unit (or ``load_density``) load.

    Parameters
    ----------
    phi
        The Airy surface Φ: a convex planar-quad height field whose polar mesh is Koenigs
        (a Koebe mesh of the Maxwell paraboloid, :func:`koebe_mesh`).
    alpha
        The family parameter; R is normalized as in :class:`MinimalPartner`.
    partner
        R, when already computed (:func:`minimal_partner`).
    load_density
        ``q`` [N/m² of top view, > 0]: weights ``(q/2)·`` Φ's creases.
    loads
        One of :data:`LOAD_RULES`.

    Returns
    -------
    KoebeFamily
        with ``network``: vertices ``(x, y, −(φ + α r))``, the boundary as supports, whose loads
        are ``−q A_i`` (top-view areas) in either rule.
    """
    alpha = float(alpha)
    q = float(load_density)
    if not (math.isfinite(alpha) and math.isfinite(q) and q > 0):
        raise InputError(f"alpha must be finite and load_density positive, got alpha={alpha!r}, "
                         f"load_density={load_density!r}")
    if loads not in LOAD_RULES:
        raise InputError(f"unknown load rule {loads!r}; use one of {', '.join(LOAD_RULES)}")
    R = minimal_partner(phi) if partner is None else partner
    phi_h = phi.vertices[:, 2]
    crease, g = lifting_weights(phi, phi_h)
    sup = phi.boundary_vertex_mask.copy()
    e = phi.edges
    inner = ~phi.boundary_edge_mask
    if np.any(crease[inner] < 0):
        k = int(np.flatnonzero(inner)[np.argmin(crease[inner])])
        raise MeshError(f"Φ is not convex across edge {tuple(e[k].tolist())} (crease {crease[k]:.3e} < 0): "
                        "its weights would be tensile; give a convex Koebe mesh")
    w = 0.5 * q * crease
    w[sup[e[:, 0]] & sup[e[:, 1]]] = 0.0
    sigma, _ = face_orientation(phi)
    cell = cell_areas(phi, g, sigma)
    area = centre_areas(phi, g)
    nodal = -q * area
    if loads == "reciprocal":
        nodal[~sup] = -q * cell[~sup]
    s = -(phi_h + alpha * R.heights)
    net = Network(mesh=phi.with_vertices(np.c_[phi.vertices[:, :2], s]), weights=w, loads=nodal, supports=sup)
    lap_phi = stress_sums(edges=e, weights=crease, values=phi_h)
    lap_r = stress_sums(edges=e, weights=crease, values=R.heights)
    harm = float(np.abs(lap_r[~sup]).max() / np.abs(lap_phi[~sup]).max()) if (~sup).any() else 0.0
    K = np.full(phi.n_vertices, np.nan)
    K[~sup] = cell[~sup] / area[~sup]
    return KoebeFamily(network=net, phi=phi_h, r=R.heights, alpha=alpha, load_density=q, loads=loads,
                       gauss_curvature=K, harmonic_residual=harm, partner=R)


# ------------------------------------------------------------------------------ explicit Koebe meshes
def _identity(c: np.ndarray, rho: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    return c, rho


def _inversion(c: np.ndarray, rho: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Inversion in the unit circle, ``z ↦ z / |z|²``: points, or circles (centre, radius) that do
    not pass through the origin (the image circle of (c, ρ) has centre ``c / (|c|² − ρ²)``)."""
    if rho is None:
        return c / np.sum(c * c, axis=1, keepdims=True), None
    k = np.sum(c * c, axis=1) - rho * rho
    if np.any(k <= 0):
        raise InputError("a circle of the pattern contains the inversion centre; enlarge the hole")
    return c / k[:, None], rho / k


#: Möbius maps of the top view applied to the square-grid pattern: ``(centres, radii|None) ->`` same.
MOBIUS_MAPS: dict[str, Callable[[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]]] = {
    "identity": _identity,
    "inversion": _inversion,
}

#: Named examples: keyword arguments of :func:`koebe_mesh`. ``enneper`` is the layout of the
#: paper's Fig. 15 / ``published/enneper-koebe.obj`` (an 18 × 18 grid without its central 4 × 4,
#: inverted); ``grid`` a plain square grid (R = x² − y² up to scale: the isotropic Enneper
#: surface's analogue).
KOEBE_EXAMPLES: dict[str, dict] = {
    "enneper": {"n": 18, "hole": 4, "mobius": "inversion", "spacing": 0.33069},
    "grid": {"n": 12, "hole": 0, "mobius": "identity", "spacing": 0.2},
}

#: how a vertex of the pattern becomes a point of Φ: "tangent" (edges touch the paraboloid:
#: the Koebe mesh proper) or "inscribed" (vertices on the paraboloid).
KINDS = ("tangent", "inscribed")


def koebe_mesh(example: str | None = None, *, kind: str = "tangent", n: int | None = None, hole: int | None = None,
               mobius: str | None = None, spacing: float | None = None,
               region: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> PolyMesh:
    """A planar-quad mesh Φ tangent to (or inscribed in) the Maxwell paraboloid, from a square
    grid of circles.

    The grid has ``n × n`` vertices at ``((i + ½ − n/2) h, (j + ½ − n/2) h)`` with circles of radius
    ``h/2`` (neighbours touch); the central ``hole × hole`` vertices are left out (needed for the
    inversion, whose centre is the grid's centre). A Möbius map of the plane (:data:`MOBIUS_MAPS`)
    keeps the pattern's touching and orthogonality. Then each vertex becomes

    * ``kind="tangent"``: the centre ``c`` of its mapped circle at height ``½(|c|² − ρ²)`` — the
      apex of the cone tangent to the paraboloid along the lifted circle; adjacent apexes span
      a line touching the paraboloid over the touching point, and the four apexes of a face lie
      in the plane that cuts the paraboloid over the face circle (orthogonal to the vertex circles);
    * ``kind="inscribed"``: the mapped grid point, lifted onto the paraboloid (the four mapped
      corners of a square are concyclic, so the face is planar).

    ``region(x, y) -> bool`` (vectorised, on the grid points *before* the Möbius map) keeps a
    sub-region: the quads whose four corners it keeps (and then the vertices they use).

    Faces run counter-clockwise seen from above (the inversion reverses orientation; the faces are
    flipped back).

    >>> m = koebe_mesh(n=4, hole=0, mobius="identity", spacing=1.0, kind="inscribed")
    >>> m.n_vertices, m.n_faces, float(m.vertices[0, 2])
    (16, 9, 2.25)
    >>> koebe_mesh(n=12, region=lambda x, y: x * x + y * y <= 1.0).n_faces  # a disk of radius 1
    61
    """
    kw = dict(KOEBE_EXAMPLES[_example(example)]) if example is not None else dict(n=12, hole=0, mobius="identity",
                                                                                    spacing=0.2)
    for key, val in (("n", n), ("hole", hole), ("mobius", mobius), ("spacing", spacing)):
        if val is not None:
            kw[key] = val
    if kind not in KINDS:
        raise InputError(f"unknown kind {kind!r}; use one of {', '.join(KINDS)}")
    n, hole, h = int(kw["n"]), int(kw["hole"]), float(kw["spacing"])
    if n < 3 or hole < 0 or hole > n - 4 or (n - hole) % 2:
        raise InputError(f"need n >= 3, 0 <= hole <= n - 4 and n - hole even (a centred hole); got n={n}, hole={hole}")
    if not (math.isfinite(h) and h > 0):
        raise InputError(f"spacing must be a positive number, got {h!r}")
    try:
        mob = MOBIUS_MAPS[kw["mobius"]]
    except KeyError:
        raise InputError(f"unknown Möbius map {kw['mobius']!r}; use one of {', '.join(MOBIUS_MAPS)}") from None
    if kw["mobius"] == "inversion" and hole < 2:
        raise InputError("the inversion needs a hole of at least 2 × 2 grid vertices around its centre")
    ij = np.arange(n) + 0.5 - n / 2.0
    I, J = np.meshgrid(ij, ij, indexing="xy")
    centres = np.c_[I.ravel(), J.ravel()] * h
    lo, hi = (n - hole) // 2, (n + hole) // 2
    idx = np.arange(n * n).reshape(n, n)  # idx[j, i]
    keep = np.ones((n, n), dtype=bool)
    keep[lo:hi, lo:hi] = False
    if region is not None:
        inside = np.asarray(region(centres[:, 0], centres[:, 1]), dtype=bool)
        if inside.shape != (n * n,):
            raise InputError(f"region must return one bool per grid point ({n * n}), got shape {inside.shape}")
        keep &= inside.reshape(n, n)
    k = keep.ravel()
    quads = [[idx[j, i], idx[j, i + 1], idx[j + 1, i + 1], idx[j + 1, i]]
             for j in range(n - 1) for i in range(n - 1)
             if k[idx[j, i]] and k[idx[j, i + 1]] and k[idx[j + 1, i + 1]] and k[idx[j + 1, i]]]
    if not quads:
        raise InputError("the region keeps no quad of the grid; enlarge it or refine the grid (n, spacing)")
    used = np.zeros(n * n, dtype=bool)
    used[np.ravel(quads)] = True
    new = -np.ones(n * n, dtype=np.int64)
    new[used] = np.arange(int(used.sum()))
    quads = new[np.array(quads, dtype=np.int64)]
    c = centres[used]
    if kind == "tangent":
        cm, rho = mob(c, np.full(len(c), h / 2.0))
        z = 0.5 * (np.sum(cm * cm, axis=1) - rho * rho)
    else:
        cm, _ = mob(c, None)
        z = 0.5 * np.sum(cm * cm, axis=1)
    V = np.c_[cm, z]
    mesh = PolyMesh.from_faces(V, quads)
    sigma, _ = face_orientation(mesh)
    if sigma < 0:
        mesh = PolyMesh.from_faces(V, quads[:, ::-1])
    return mesh.validate()


def _example(name: str) -> str:
    if name not in KOEBE_EXAMPLES:
        raise InputError(f"unknown Koebe example {name!r}; use one of {', '.join(KOEBE_EXAMPLES)}")
    return name


# ------------------------------------------------------------------------------ diagnostics
def paraboloid_gaps(mesh: PolyMesh) -> tuple[np.ndarray, np.ndarray]:
    """How a mesh sits on the Maxwell paraboloid ``z = ½(x² + y²)``.

    Returns ``(vertex_gap, edge_gap)``: per vertex ``½|x'|² − z`` (0 on the paraboloid, > 0 below
    it), per edge the minimum of ``½|x'|² − z`` along the edge's whole *line*: 0 when the line
    touches the paraboloid, < 0 for a secant (a chord of an inscribed mesh), > 0 for a line that
    misses it.

    >>> m = koebe_mesh(n=4, hole=0, mobius="identity", spacing=1.0, kind="tangent")
    >>> vg, eg = paraboloid_gaps(m)
    >>> float(np.abs(eg).max()) < 1e-12, float(vg.min()) > 0
    (True, True)
    """
    V = mesh.vertices
    vg = 0.5 * np.sum(V[:, :2] ** 2, axis=1) - V[:, 2]
    e = mesh.edges
    p, d = V[e[:, 0]], V[e[:, 1]] - V[e[:, 0]]
    # along p + t d: ½|p' + t d'|² − (p_z + t d_z) = A t² + B t + C, minimum C − B²/(4A)
    A = 0.5 * np.sum(d[:, :2] ** 2, axis=1)
    B = np.sum(p[:, :2] * d[:, :2], axis=1) - d[:, 2]
    C = 0.5 * np.sum(p[:, :2] ** 2, axis=1) - p[:, 2]
    return vg, C - B * B / (4 * A)
