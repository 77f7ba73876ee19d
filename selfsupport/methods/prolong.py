"""Prolongation of a thrust network to a finer mesh of the same surface through its stress field.

A network interpolated to a finer mesh is not in equilibrium there: its heights are a C¹
interpolant whose second derivatives jump across the coarse edges, and a vertex load shrinks
with the area it carries (h²), so a 4× finer level's first weight fit is far from equilibrium
(max relative errors of order 1 to 10) and the fine level needs a dozen or more staggered
iterations to recover. What carries over
from level to level is the *stress*: the horizontal force per length, a smooth 2×2 tensor field
``σ`` (the cofactor of the Airy function's Hessian, docs/theory/airy.md), which the coarse weights
sample along the coarse edges. So:

1. the coarse network's stress per face, ``σ_F = Σ_{e ∈ F} s_e w_e e eᵀ / A_F`` (top-view edge
   vectors ``e``, face area ``A_F``; ``s_e`` = ½ for an edge between two faces, 1 on the
   boundary), averaged to the vertices by area, is interpolated linearly to each fine edge's
   midpoint. The boundary edges' weights are left out of it: the lifting of a smooth Airy
   function gives them none, so what they carry is a line force (an arch along a free edge),
   which step 2 carries as a force. Counted in the face stress as well, that force would be
   carried twice, smeared over the interior edges beside the boundary, where the polish would
   squash the strip beside the arch in plan (docs/theory/multilevel.md);
2. each interior fine edge takes the weight of the Airy function ``φ_e = ½ (p − m_e)ᵀ H_e (p − m_e)``
   with ``H_e = cof σ(m_e)`` lifted over its two faces (the jump of the faces' gradients across
   it, as :func:`selfsupport.analysis.construction.lifting_weights`); a boundary edge the
   horizontal force ``w ℓ`` (top-view length) of the nearest coarse *boundary* edge that carries
   any, over its own length (:func:`boundary_weights`: along a free boundary that force is what
   balances the interior's pull, ``H κ = σ``, and stays as the edges shorten; the nearest edge of
   any kind, often an interior one beside the boundary, would give neighbouring boundary edges
   weights orders of magnitude apart);
3. the smallest relative change that puts those weights in horizontal equilibrium on the fine
   top view (``δw = −DAᵀ(ADAᵀ)⁻¹Aw``, ``D = diag(w²)``, one vertex-sized factorization),
   clipped to the bounds;
4. the positions in equilibrium with them (the polish: x, y and the heights from the stress
   Laplacian, loads consistent with the new geometry; Anderson's fixed-point rounds first,
   Newton's steps where they do not settle, unless the rounds ended held above
   :data:`PROLONG_TOL` by rounding alone, ``Network.roundoff_limit``: no steps go below that
   floor). Where that fails, step 4 with the
   weights of step 2 as they are (clipped): the polish then moves the top view into horizontal
   equilibrium with them. Where neither comes within :data:`START_TOL`, the weights of steps
   1–2 with the boundary edges counted in the stress after all, as they are (a fallback for
   Catmull–Clark quads, where the boundary-free stress may not balance).
5. Where the fine scene is the coarse one refined by Catmull–Clark (a designer's subdivided
   design, :func:`~selfsupport.core.subdivision.subdivide_like`) and steps 1–4 fail: the
   network itself subdivided by the same step, its weights carried edge by edge
   (:func:`subdivided_weights`), its supports put back where the design has them, polished as in
   step 4. A quad network has about as many edges as horizontal equations (2 per free vertex),
   so its top view has to move with its weights: the projection of step 3 drives most weights to
   the lower bound there, and the stress of step 2 lifted over quads does not balance either.
   It comes last because where steps 1–4 work they land nearer the reference, and over
   triangles, whose subdivision is not a grid, it does not balance.

The result is a fine network in equilibrium to round-off, about as near the reference as the
coarse one was, in a fraction of the time that iterating from the interpolated network takes
(``python -m studies.scaling`` measures both).

Example
-------
A constant quadratic Airy function: the edge-by-edge lifting equals the global one.

>>> from selfsupport.core.shapes import make_shape
>>> from selfsupport.analysis.construction import lifting_weights
>>> m = make_shape("dome", n_vertices=200).mesh
>>> xy = m.vertices[:, :2]
>>> H = np.array([[2.0, 0.3], [0.3, 1.0]])
>>> w_global, _ = lifting_weights(m, 0.5 * np.einsum("pi,ij,pj->p", xy, H, xy))
>>> w_edge = quadratic_lifting_weights(m, xy, np.broadcast_to(H, (m.n_edges, 2, 2)))
>>> bool(np.allclose(w_edge, w_global, atol=1e-12 * np.abs(w_global).max()))
True
"""
from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from formulations import Problem, ScaledProblem
from selfsupport.analysis.airy import _J, face_orientation
from selfsupport.analysis.construction import restore_horizontal_equilibrium
from selfsupport.core.evidence import relative_errors
from selfsupport.core.geometry import edge_vectors
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.core.subdivision import Subdivision
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.polish import polish
from selfsupport.methods.warm import WarmStart, interpolate_over_top_view, transfer

__all__ = ["face_stress", "vertex_stress", "cofactor", "quadratic_lifting_weights", "stress_weights",
           "subdivided_weights", "Prolongation", "prolong", "PROLONG_TOL"]

#: A prolonged network is used when its max relative error is at most this (the polish reaches
#: 1e-11–1e-10; a polish that did not converge is far above).
PROLONG_TOL = 1e-8
#: A coarser level's network starts the next one when its max relative error is at most this (a
#: start needs to be near equilibrium, not at round-off: a level polished only to 1e-9 is a
#: network near the reference all the same). Below it a
#: candidate's polish has come near; above it, the next candidate is tried (:func:`prolong`).
START_TOL = 1e-6
#: The candidate tried only when none before it came within START_TOL: the stress with the
#: coarse boundary edges counted (module docstring, step 4).
FALLBACK = "as carried, boundary in the stress"


def cofactor(S: np.ndarray) -> np.ndarray:
    """The cofactor of symmetric 2×2 tensors ``(..., 2, 2)``: stress ↔ Airy Hessian."""
    out = np.empty_like(S)
    out[..., 0, 0], out[..., 1, 1] = S[..., 1, 1], S[..., 0, 0]
    out[..., 0, 1], out[..., 1, 0] = -S[..., 1, 0], -S[..., 0, 1]
    return out


def _face_areas(mesh: PolyMesh, xy: np.ndarray) -> np.ndarray:
    return np.abs(face_orientation(mesh, xy)[1])


def face_stress(mesh: PolyMesh, xy: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face ``σ_F = Σ_{e ∈ F} s_e w_e e eᵀ / A_F`` (see the module docstring) and the
    face areas. Summed with the areas it is ``Σ_e w_e e eᵀ``, the integral of the stress of a
    piecewise-linear Airy function (edges inside the mesh counted in both their faces by half).

    >>> from selfsupport.core.shapes import make_shape
    >>> m = make_shape("dome", n_vertices=100).mesh
    >>> xy, w = m.vertices[:, :2], np.ones(m.n_edges)
    >>> S, A = face_stress(m, xy, w)
    >>> e = xy[m.edges[:, 1]] - xy[m.edges[:, 0]]
    >>> bool(np.allclose((S * A[:, None, None]).sum(axis=0), e.T @ e))
    True
    """
    e, ef = mesh.edges, mesh.edge_faces
    ev = xy[e[:, 1]] - xy[e[:, 0]]
    W = np.asarray(weights, float)[:, None, None] * ev[:, :, None] * ev[:, None, :]
    share = np.where((ef >= 0).all(axis=1), 0.5, 1.0)
    S = np.zeros((mesh.n_faces, 2, 2))
    for side in range(2):
        on = ef[:, side] >= 0
        np.add.at(S, ef[on, side], share[on, None, None] * W[on])
    A = _face_areas(mesh, xy)
    return S / np.maximum(A, 1e-300)[:, None, None], A


def vertex_stress(mesh: PolyMesh, xy: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(n, 2, 2)``: the face stresses averaged over each vertex's faces, weighted by area."""
    S, A = face_stress(mesh, xy, weights)
    face_of = mesh.corner_data[0]
    fv = mesh.face_vertices
    Sv = np.zeros((mesh.n_vertices, 2, 2))
    Av = np.zeros(mesh.n_vertices)
    np.add.at(Sv, fv, (S * A[:, None, None])[face_of])
    np.add.at(Av, fv, A[face_of])
    return Sv / np.maximum(Av, 1e-300)[:, None, None]


def _face_gradients(mesh: PolyMesh, xy: np.ndarray, faces: np.ndarray, centre: np.ndarray,
                    H: np.ndarray) -> np.ndarray:
    """Gradient of the least-squares plane through ``½ (p − centre)ᵀ H (p − centre)`` at the
    corners of each face in ``faces`` (exact for triangles); one row per entry."""
    fo, fv = mesh.face_offsets, mesh.face_vertices
    sizes = fo[faces + 1] - fo[faces]
    row = np.repeat(np.arange(len(faces)), sizes)
    corner = fo[faces][row] + (np.arange(len(row)) - np.repeat(np.cumsum(sizes) - sizes, sizes))
    P = xy[fv[corner]] - centre[row]
    v = 0.5 * np.einsum("ki,kij,kj->k", P, H[row], P)
    n = sizes.astype(float)
    Pm = np.zeros((len(faces), 2))
    vm = np.zeros(len(faces))
    np.add.at(Pm, row, P)
    np.add.at(vm, row, v)
    Pm /= n[:, None]
    vm /= n
    D = P - Pm[row]
    M = np.zeros((len(faces), 2, 2))
    r = np.zeros((len(faces), 2))
    np.add.at(M, row, D[:, :, None] * D[:, None, :])
    np.add.at(r, row, D * (v - vm[row])[:, None])
    return np.linalg.solve(M, r[..., None])[..., 0]


def quadratic_lifting_weights(mesh: PolyMesh, xy: np.ndarray, H_edge: np.ndarray) -> np.ndarray:
    """Per interior edge the weight of the Airy function ``½ (p − m_e)ᵀ H_e (p − m_e)`` (``m_e``
    the edge's midpoint) over its two faces: ``(∇Φ_L − ∇Φ_R) · σ J e / ‖e‖²`` as in
    :func:`~selfsupport.analysis.construction.lifting_weights`; 0 on the boundary."""
    sigma, _ = face_orientation(mesh, xy)
    e, ef = mesh.edges, mesh.edge_faces
    w = np.zeros(mesh.n_edges)
    inner = np.flatnonzero((ef >= 0).all(axis=1))
    if not inner.size:
        return w
    m = 0.5 * (xy[e[inner, 0]] + xy[e[inner, 1]])
    H = np.asarray(H_edge, float)[inner]
    jump = _face_gradients(mesh, xy, ef[inner, 0], m, H) - _face_gradients(mesh, xy, ef[inner, 1], m, H)
    ev = xy[e[inner, 1]] - xy[e[inner, 0]]
    w[inner] = (jump * (sigma * _J(ev))).sum(axis=1) / (ev ** 2).sum(axis=1)
    return w


def boundary_weights(coarse: PolyMesh, coarse_xy: np.ndarray, coarse_weights: np.ndarray, fine: PolyMesh,
                     fine_xy: np.ndarray, at: np.ndarray | None = None) -> np.ndarray:
    """Weights of ``fine``'s boundary edges (``at``, default all of them; others 0) carrying the
    horizontal force ``w ℓ`` of the nearest coarse boundary edge with a positive weight, divided
    by the fine edge's top-view length (step 2 of the module docstring). NaN where the coarse
    boundary carries nothing.

    >>> from selfsupport.core.shapes import make_shape
    >>> m = make_shape("dome", n_vertices=200).mesh
    >>> xy = m.vertices[:, :2]
    >>> b = m.boundary_edge_mask
    >>> w = np.where(b, 3.0 / np.linalg.norm(xy[m.edges[:, 1]] - xy[m.edges[:, 0]], axis=1), 7.0)
    >>> bool(np.allclose(boundary_weights(m, xy, w, m, xy)[b], w[b]))  # the same mesh: the same weights
    True
    """

    def mids(mesh: PolyMesh, xy: np.ndarray) -> np.ndarray:
        return 0.5 * (xy[mesh.edges[:, 0]] + xy[mesh.edges[:, 1]])

    at = fine.boundary_edge_mask if at is None else np.asarray(at, bool)
    w = np.zeros(fine.n_edges)
    cw = np.asarray(coarse_weights, float)
    src = np.flatnonzero(coarse.boundary_edge_mask & (cw > 0))
    if not src.size:
        w[at] = np.nan
        return w
    force = cw[src] * _plan_lengths(coarse.edges[src], coarse_xy)
    _, k = cKDTree(mids(coarse, coarse_xy)[src]).query(mids(fine, fine_xy)[at])
    w[at] = force[k] / np.maximum(_plan_lengths(fine.edges[at], fine_xy), 1e-300)
    return w


def stress_weights(coarse: PolyMesh, coarse_xy: np.ndarray, coarse_weights: np.ndarray, fine: PolyMesh,
                   fine_xy: np.ndarray, with_boundary: bool = False) -> np.ndarray:
    """Weights of the interior edges of ``fine`` carrying the coarse network's stress field
    (steps 1–2 of the module docstring); boundary edges get 0. The coarse boundary edges are
    left out of the stress: their weights are a line force (an arch along a free edge), which
    :func:`boundary_weights` carries; in the face stress it would be carried twice, smeared over
    the interior edges beside the boundary as well. ``with_boundary``: counted all the same (the
    fallback candidate of :func:`prolong`)."""
    Sv = vertex_stress(coarse, coarse_xy,
                       coarse_weights if with_boundary else np.where(coarse.boundary_edge_mask, 0.0, coarse_weights))
    e = fine.edges
    mid = 0.5 * (fine_xy[e[:, 0]] + fine_xy[e[:, 1]])
    s = interpolate_over_top_view(coarse, Sv.reshape(-1, 4)[:, [0, 1, 3]], mid, xy=coarse_xy, cubic=False)
    S = np.stack([np.stack([s[:, 0], s[:, 1]], axis=-1), np.stack([s[:, 1], s[:, 2]], axis=-1)], axis=1)
    return quadratic_lifting_weights(fine, fine_xy, cofactor(S))


def subdivided_weights(coarse: PolyMesh, sub: Subdivision, weights: np.ndarray) -> np.ndarray:
    """Weights of the edges of ``sub.mesh``, one Catmull–Clark step of ``coarse`` (step 5 of the
    module docstring): each half of a coarse edge keeps its weight, and the edge from a face
    point to an edge point takes the mean of the face's two edges beside that edge (parallel to
    it in a quad). On a grid refined twice as finely each line of edges carries half the force over
    half the length, so a weight, force per top-view length, stays. A boundary arch stays one line:
    the halves of a boundary edge keep its *force* w ℓ (top-view lengths of ``coarse`` and
    ``sub.mesh``), as in :func:`boundary_weights`.

    >>> from selfsupport.core.subdivision import catmull_clark
    >>> from selfsupport.core.shapes import make_shape
    >>> m = make_shape("barrel_vault", n_vertices=100).mesh
    >>> w = np.arange(m.n_edges, dtype=float)
    >>> sub = catmull_clark(m)
    >>> wf = subdivided_weights(m, sub, w)
    >>> e = m.edges[7]  # both halves of coarse edge 7 (an interior edge) keep its weight
    >>> halves = [np.flatnonzero((sub.mesh.edges == sorted(p)).all(axis=1))[0]
    ...           for p in ((e[0], sub.edge_point(7)), (e[1], sub.edge_point(7)))]
    >>> wf[halves].tolist()
    [7.0, 7.0]
    """
    w = np.asarray(weights, float)
    fo = coarse.face_offsets
    sizes = np.diff(fo)
    face_of, _, _ = coarse.corner_data
    pos = np.arange(fo[-1]) - fo[face_of]
    prev = fo[face_of] + (pos - 1) % sizes[face_of]
    nxt = fo[face_of] + (pos + 1) % sizes[face_of]
    he = coarse.halfedge_data["halfedge_edge"]  # coarse corner c -> its edge (v_c, v_next)
    # fine face c (one per coarse corner) is (v_c, e_c, f, e_prev): its edges in corner order are
    # half of edge c, the face edge at e_c, the face edge at e_prev, half of edge prev(c)
    fine = sub.mesh.halfedge_data["halfedge_edge"].reshape(-1, 4)
    out = np.empty(sub.mesh.n_edges)
    out[fine[:, 0]] = w[he]
    out[fine[:, 3]] = w[he[prev]]
    out[fine[:, 1]] = 0.5 * (w[he[prev]] + w[he[nxt]])
    # a boundary arch stays one line: its halves carry the whole force w ℓ (boundary_weights)
    bf = sub.mesh.boundary_edge_mask
    ef = sub.mesh.edges[bf]
    parent = np.where(ef[:, 0] < sub.n_old, ef[:, 1], ef[:, 0]) - sub.n_old  # the edge point's edge
    force = w[parent] * _plan_lengths(coarse.edges[parent], coarse.vertices)
    out[bf] = force / np.maximum(_plan_lengths(ef, sub.mesh.vertices), 1e-300)
    return out


def _plan_lengths(edges: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Top-view lengths of ``edges`` (``xy``: positions, their first two columns used)."""
    return np.linalg.norm(edge_vectors(np.asarray(xy)[:, :2], edges), axis=1)


@dataclass(frozen=True)
class Prolongation:
    """A coarse network carried to a finer scene: ``network`` (None when it failed) and why."""

    network: Network | None
    max_relative_error: float
    seconds: float
    info: dict[str, Any]
    #: where no candidate reached PROLONG_TOL: the one whose polish came nearest (lowest max
    #: relative error; ``max_relative_error`` is its error), or None when none polished to finite values
    nearest: Network | None = None


class _Candidate(NamedTuple):
    """A start for the polish of step 4."""

    name: str
    #: scaled positions
    X: np.ndarray
    #: scaled active weights, or a function making them when first tried (the fallback's stress
    #: carry is seconds at 256k vertices)
    weights: np.ndarray | Callable[[], np.ndarray]


def _failed(t0: float, why: str, err: float = float("inf")) -> Prolongation:
    """A prolongation that returns no network, begun at ``t0`` (``time.perf_counter()``)."""
    return Prolongation(None, err, time.perf_counter() - t0, {"why": why})


def _stress_candidates(problem: Problem, sp_: ScaledProblem, network: Network, reference: PolyMesh
                       ) -> tuple[list[_Candidate], list[str]]:
    """Steps 1–3: the projected stress weights, the weights as carried and the fallback (the
    coarse boundary edges counted in the stress), all on the interpolated positions; and why
    there are none (the stress weights are not finite)."""
    scene = problem.scene
    top, sc = sp_.top, sp_.scaling
    # positions: the coarse network's offsets interpolated (methods/warm.py)
    V, w_near, _ = transfer(WarmStart(network, reference=reference), scene)
    X = sc.pos(V)
    Xc = sc.pos(network.vertices)[:, :2]
    wc_ = sc.weight(np.asarray(network.weights, float))
    boundary = scene.mesh.boundary_edge_mask
    wb = boundary_weights(network.mesh, Xc, wc_, scene.mesh, X[:, :2], at=boundary)[boundary]

    def carried(with_boundary: bool) -> np.ndarray:
        w = stress_weights(network.mesh, Xc, wc_, scene.mesh, X[:, :2], with_boundary=with_boundary)
        # (a coarse boundary that carries nothing: the nearest coarse edge's weight)
        w[boundary] = np.where(np.isfinite(wb), wb, sc.weight(w_near[boundary]))
        return w[scene.active_edges]

    w = carried(False)
    if not np.all(np.isfinite(w)):
        return [], ["the stress weights are not finite"]
    # step 3 with relative changes (small weights stay small rather than being pushed across
    # zero by the large ones' corrections); where the polish cannot balance those, the weights
    # as carried, the polish moving the top view into equilibrium with them. Where neither comes
    # within START_TOL, the stress with the boundary edges counted (FALLBACK)
    projected = restore_horizontal_equilibrium(X[:, :2], top.edges, w, top.free,
                                               metric=np.maximum(w, sp_.lower) ** 2)
    # (the fallback's weights made only when it is tried: a stress carry is seconds at 256k)
    return [_Candidate("projected", X, projected), _Candidate("as carried", X, w),
            _Candidate(FALLBACK, X, functools.cache(lambda: carried(True)))], []


def _subdivided_candidate(problem: Problem, sp_: ScaledProblem, network: Network, subdivision: Subdivision | None
                          ) -> _Candidate | None:
    """Step 5: the network itself subdivided, its weights along, where ``subdivision`` made the
    fine scene (a quad network's top view must move with its weights, which the interpolated
    top view and the projection cannot: cyl2); None otherwise."""
    scene, sc = problem.scene, sp_.scaling
    if subdivision is None or subdivision.mesh.n_vertices != scene.mesh.n_vertices \
            or not np.array_equal(subdivision.mesh.face_vertices, scene.mesh.face_vertices):
        return None
    ws = sc.weight(subdivided_weights(network.mesh, subdivision, np.asarray(network.weights, float)))
    Vs = subdivision.mesh.vertices.copy()
    sup = np.asarray(scene.supports, bool)
    Vs[sup] = scene.mesh.vertices[sup]  # (a support beside a free vertex would follow it: stays put)
    return _Candidate("subdivided", sc.pos(Vs), ws[scene.active_edges])


def _balanced(problem: Problem, sp_: ScaledProblem, X: np.ndarray, wc: np.ndarray, *, newton: bool,
              deadline: float | None) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, int]:
    """Step 4 for one candidate: the polish (Anderson's rounds, or Newton's steps) of the positions
    ``X`` with the scaled weights ``wc``. Returns its max relative error (∞ where it broke down),
    positions, mesh-edge weights and loads (SI), and the polish's rounds."""
    scene, top, sc = problem.scene, sp_.top, sp_.scaling
    Xp, _, rounds = polish(top, X, wc, problem.loads.primary, scene.mesh, sc, newton=newton,
                           fallbacks=not newton, krylov=False, deadline=deadline)
    V = sc.pos_back(Xp)
    L_phys = problem.loads.primary.nodal(scene.mesh, V)
    weights = np.zeros(scene.mesh.n_edges)
    weights[scene.active_edges] = sc.weight_back(wc)
    if not np.all(np.isfinite(Xp)) or not np.all(np.isfinite(L_phys)):
        return float("inf"), V, weights, L_phys, rounds
    rel = relative_errors(vertices=V, edges=scene.mesh.edges, weights=weights, loads=L_phys,
                          supports=scene.supports)
    return (float(rel.max()) if rel.size else 0.0), V, weights, L_phys, rounds


def _polish_order(candidates: list[_Candidate]) -> list[tuple[_Candidate, bool]]:
    """(candidate, Newton?) in the order tried: per candidate Anderson's rounds (cheap), then
    Newton's steps; with a subdivided candidate, Anderson's rounds for every candidate first (the
    stress candidates' Newton steps, when they fail, cost most of a large level's time)."""
    subdivided = candidates[-1].name == "subdivided" if candidates else False
    return [(c, nw) for nw in (False, True) for c in candidates] if subdivided else \
        [(c, nw) for c in candidates for nw in (False, True)]


def _polish_candidates(problem: Problem, sp_: ScaledProblem, candidates: list[_Candidate], *, deadline: float | None
                       ) -> tuple[tuple[Network, float, dict[str, Any]] | None, tuple[float, Network | None, str],
                                  dict[str, float]]:
    """Step 4 for the candidates in turn until one polishes to :data:`PROLONG_TOL`.

    Returns that one (network, max relative error, info) or None; the nearest so far
    (error, network, name); and each candidate's lowest error."""
    scene = problem.scene
    best: tuple[float, Network | None, str] = (float("inf"), None, "")
    ended: dict[str, float] = {}
    floored: set[str] = set()  # candidates whose Anderson rounds ended at their round-off floor
    for (name, Xs, cand), newton in _polish_order(candidates):
        if out_of_time(deadline):
            break
        if name == FALLBACK and best[0] <= START_TOL:
            continue  # (a fallback: a candidate before it came near equilibrium)
        if newton and name in floored:
            continue  # (no positions balance it better: 30 s of Newton's steps at 256k, for nothing)
        wc = np.clip(cand() if callable(cand) else cand, sp_.lower, sp_.upper)
        err, V, weights, L_phys, rounds = _balanced(problem, sp_, Xs, wc, newton=newton, deadline=deadline)
        ended[name] = min(err, ended.get(name, np.inf))
        near = not newton and PROLONG_TOL < err <= START_TOL
        if err <= PROLONG_TOL or err < best[0] or near:
            net = Network(mesh=scene.mesh.with_vertices(V), weights=weights, loads=L_phys,
                          supports=scene.supports, reference=scene.mesh)
            if err <= PROLONG_TOL or err < best[0]:
                best = (err, net, name)
            if near and net.roundoff_limit(PROLONG_TOL) is not None:
                floored.add(name)
        if err <= PROLONG_TOL:
            return (net, err, {"weights": name, "polish": "newton" if newton else "anderson",
                               "polish_rounds": int(rounds), "at_lower": int(np.sum(wc <= sp_.lower))}), best, ended
    return None, best, ended


def prolong(problem: Problem, network: Network, reference: PolyMesh, deadline: float | None = None,
            subdivision: Subdivision | None = None) -> Prolongation:
    """Carry ``network`` (solved for ``reference``, a coarser mesh of the same surface) to the
    scene of ``problem`` through its stress field (see the module docstring); ``subdivision``:
    the Catmull–Clark step that made the fine scene, applied to the network (its positions and
    :func:`subdivided_weights` are the last candidate, step 5). The returned
    network is in equilibrium on the fine mesh with loads of its own geometry when
    ``max_relative_error`` ≤ :data:`PROLONG_TOL`; otherwise ``network`` is None, ``nearest`` the
    candidate whose polish came nearest (its error in ``max_relative_error``) and ``info``
    says why (a problem with several load cases, a fixed top view or a hull is not prolonged:
    its frozen weights cannot balance every case or hold the constraint)."""
    t0 = time.perf_counter()
    if len(problem.loads) != 1 or problem.constraints:
        return _failed(t0, "several load cases or a constraint: the prolongation balances one case, unconstrained")
    if out_of_time(deadline):
        return _failed(t0, "the time limit was reached")
    sp_ = problem.scaled()
    candidates, tried = _stress_candidates(problem, sp_, network, reference)
    sub = _subdivided_candidate(problem, sp_, network, subdivision)
    if sub is not None:
        candidates.append(sub)
    found, best, ended = _polish_candidates(problem, sp_, candidates, deadline=deadline)
    if found is not None:
        net, err, info = found
        return Prolongation(net, err, time.perf_counter() - t0, info)
    tried += [f"{name}: the polish ended at {err:.2e}" if np.isfinite(err) else f"{name}: the polish broke down"
              for name, err in ended.items()]
    out = _failed(t0, "; ".join(tried) or "the time limit was reached", best[0])
    if best[1] is None:
        return out
    return dataclasses.replace(out, nearest=best[1], info={**out.info, "nearest": best[2]})
