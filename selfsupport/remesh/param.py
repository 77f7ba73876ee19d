"""A global parametrization of a planar triangulation along a frame field (for :mod:`.remesh`).

Given two line fields per vertex (the relative principal directions: a *frame* field, the two
directions not orthogonal in general) and a spacing ``h``, find ``(u, v)`` per triangle corner
whose gradients follow the dual frame: with ``F = [d1 d2]`` (unit columns) the Jacobian of
``x ↦ (u, v)`` should be ``F⁻¹ / h``, so that ``u`` grows by one per ``h`` along ``d1`` and stays
put along ``d2`` (the iso-``u`` lines are lines of the ``d2`` family, ``h`` apart along ``d1``),
and likewise ``v``. The iso-lines ``u ∈ Z`` and ``v ∈ Z`` are then the mesh lines of a quad
mesh whose irregular vertices are the field's singularities only (no line ends in the middle
of the domain, so no T-junction), which is what :func:`.remesh.remesh` (``method="param"``)
feeds to its arrangement instead of streamlines.

Steps (the mixed-integer quadrangulation of Bommes, Zimmer & Kobbelt 2009, reduced to what a
fixed, given frame field needs):

1. per triangle, each family's direction from the mean of its corners' doubled-angle vectors;
2. the matching across every interior edge: the signed permutation ``R`` (of the 8 that map
   a line pair to itself) with ``F_t ≈ F_s R``; a vertex is singular when the matchings around
   it do not compose to the identity, or when they do and the frame turns a whole turn around
   it (a radial and circular pattern; its corners are kept apart, the seam's translation
   free to its end). On the generated dome the apex comes out as four singular vertices
   around it, each where the two directions swap;
3. a cut graph: the interior edges that a spanning tree of the dual graph does not cross,
   pruned of branches that end at a regular interior vertex; what remains joins the singular
   vertices and the holes to the boundary, and the cut mesh is a disk without singularities
   inside, on which the frames are made consistent along the tree;
4. least squares ``Σ_t area_t |∇(u, v)_t − F_t⁻¹ / h|²`` over the cut mesh's corners, with the
   seam conditions ``p_t = Rᵀ p_s + T_e`` across every cut edge as equations (KKT system,
   sparse LU), ``T_e`` unknown; boundary edges that run along a direction (within
   ALIGN_ANGLE) hold the other parameter constant (the boundary becomes a mesh line there:
   without it, the lines nearly parallel to a boundary cut it obliquely and leave slivers that
   the remesher's merge turns into triangles: on the paper's lilium at its mean edge length,
   112 triangles without, 69 with);
5. greedy rounding: the seam translation (or aligned boundary run) nearest an integer is
   fixed to it and the system is solved again, until all are integers (so that the integer
   iso-lines continue across the seams, and the aligned boundary is one of them).

Why a least squares on a fixed field rather than MIQ's smoothed cross field: the relative
principal directions are what the planar quads must follow (paper §5), so the field is not
ours to smooth (and smoothing does not simply remove singularities: averaging each family's
doubled-angle vectors over the one-ring once took the paper's vault from 2 singular vertices to
14, the lilium from 37 to 30); where the field is not integrable (e.g. the circles around a
dome's apex, whose circumference grows), the least squares spreads the error, and quads grow or
shrink instead of lines ending.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from selfsupport.core.errors import InputError

__all__ = ["Parametrization", "frame_parametrization", "density_ratio", "isolines", "SIGNED_PERMUTATIONS"]

#: The 8 signed permutations of two columns: the symmetries of a pair of line fields.
SIGNED_PERMUTATIONS = np.array([s @ P for P in (np.eye(2), np.array([[0.0, 1.0], [1.0, 0.0]]))
                                for s in (np.diag([1.0, 1.0]), np.diag([1.0, -1.0]),
                                          np.diag([-1.0, 1.0]), np.diag([-1.0, -1.0]))])
#: Two lines of a frame closer than this angle [degrees] are spread apart to it (``F`` would be
#: near-singular and ``F⁻¹`` ask for an unbounded gradient).
MIN_FRAME_ANGLE = 20.0
#: Seam translations within this of an integer count as rounded.
ROUND_TOL = 1e-6
#: A boundary edge within this angle [degrees] of one of its triangle's directions is held on an
#: iso-line of the other parameter (``align_boundary``).
ALIGN_ANGLE = 20.0


@dataclass(frozen=True, eq=False)
class Parametrization:
    """``uv``: ``(m, 3, 2)`` per triangle corner ``(u, v)`` in units of the spacing (continuous
    inside the cut mesh, related by a signed permutation and an integer translation across a
    seam); ``frames``: ``(m, 2, 2)`` the per-triangle frames made consistent on the cut mesh
    (columns ``d1, d2``); ``singular``: the singular vertices; ``seams``: the cut edges
    ``(k, 2)``; ``residual``: the root-mean-square of ``|∇(u, v) − s F⁻¹/h|`` (area weighted, in
    units of ``1/h``); ``rounded``: whether every seam translation is an integer; ``scale``: the
    factor ``s`` the target was scaled by (``keep_density``; else 1)."""

    uv: np.ndarray
    frames: np.ndarray
    singular: np.ndarray
    seams: np.ndarray
    residual: float
    rounded: bool
    scale: float = 1.0


def _triangle_frames(xy: np.ndarray, tris: np.ndarray, doubled: np.ndarray) -> np.ndarray:
    """``(m, 2, 2)`` per triangle the two directions (columns) from the mean of the corners'
    doubled-angle vectors ``doubled`` ``(n, 2, 2)`` (``[:, :, k]`` of family ``k``), spread apart
    to at least MIN_FRAME_ANGLE."""
    mean = doubled[tris].mean(axis=1)  # (m, 2, 2)
    ang = 0.5 * np.arctan2(mean[:, 1, :], mean[:, 0, :])  # (m, 2)
    return _spread_angles(ang)


def _spread(F: np.ndarray) -> np.ndarray:
    """Frames ``(m, 2, 2)`` (unit columns) with their two lines spread apart to at least MIN_FRAME_ANGLE."""
    return _spread_angles(np.arctan2(F[:, 1, :], F[:, 0, :]))


def _spread_angles(ang: np.ndarray) -> np.ndarray:
    """Frames ``(m, 2, 2)`` from two line angles ``(m, 2)`` each, spread apart to at least MIN_FRAME_ANGLE."""
    # the two line angles, brought within 90° of each other, then spread about their bisector
    diff = (ang[:, 1] - ang[:, 0] + 0.5 * np.pi) % np.pi - 0.5 * np.pi
    lo = np.radians(MIN_FRAME_ANGLE)
    wide = np.sign(diff + (diff == 0)) * np.maximum(np.abs(diff), lo)
    mid = ang[:, 0] + 0.5 * diff
    a0, a1 = mid - 0.5 * wide, mid + 0.5 * wide
    return np.stack([np.c_[np.cos(a0), np.sin(a0)], np.c_[np.cos(a1), np.sin(a1)]], axis=2)


def _gradients(xy: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per triangle the gradients ``(m, 3, 2)`` of its three hat functions and its area."""
    P = xy[tris]
    e = np.roll(P, 1, axis=1) - np.roll(P, -1, axis=1)  # edge opposite each corner (i+1 → i+2)
    a, b = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    area = 0.5 * cross
    safe = np.where(np.abs(cross) > 0, cross, 1.0)
    g = np.stack([-e[:, :, 1], e[:, :, 0]], axis=2) / safe[:, None, None]  # the opposite edge turned by 90°
    g[np.abs(cross) == 0] = 0.0
    return g, np.abs(area)


def _interior_edges(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interior edges: ``(k, 2)`` vertex pairs and ``(k, 2)`` the two triangles, and a boolean
    per vertex that it lies on the boundary."""
    m = len(tris)
    a = tris[:, [1, 2, 0]].ravel()
    b = tris[:, [2, 0, 1]].ravel()
    t = np.repeat(np.arange(m), 3)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    lo, hi, t = lo[order], hi[order], t[order]
    same = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    i = np.flatnonzero(same)
    if np.any(same[1:] & same[:-1]):
        raise InputError("the top-view triangulation is not a manifold (an edge with three triangles)")
    on_bnd = np.ones(len(lo), bool)
    on_bnd[i] = on_bnd[i + 1] = False
    n = int(tris.max()) + 1
    bnd = np.zeros(n, bool)
    bnd[lo[on_bnd]] = bnd[hi[on_bnd]] = True
    return np.c_[lo[i], hi[i]], np.c_[t[i], t[i + 1]], bnd


def _best_matching(Fs: np.ndarray, Ft: np.ndarray) -> np.ndarray:
    """Index into SIGNED_PERMUTATIONS of the ``R`` minimising ``|F_s R − F_t|`` per row."""
    cand = np.einsum("kij,rjl->kril", Fs, SIGNED_PERMUTATIONS)  # (k, 8, 2, 2)
    return np.argmin(((cand - Ft[:, None]) ** 2).sum(axis=(2, 3)), axis=1)


def _dual_tree(m: int, edge_tris: np.ndarray, root: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Breadth-first spanning tree of the dual graph: visiting order, parent triangle and the
    interior edge to it (``-1`` at the root and in components not reached), and per interior
    edge whether the tree crosses it."""
    adj = sp.coo_matrix((np.r_[np.arange(len(edge_tris)), np.arange(len(edge_tris))] + 1,
                         (edge_tris[:, 0].tolist() + edge_tris[:, 1].tolist(),
                          edge_tris[:, 1].tolist() + edge_tris[:, 0].tolist())), shape=(m, m)).tocsr()
    order, pred = sp.csgraph.breadth_first_order(adj, root, directed=False, return_predecessors=True)
    if len(order) < m:
        raise InputError("the network's top view is not one connected region; remesh each part on its own")
    parent_edge = -np.ones(m, np.int64)
    has = pred >= 0
    parent_edge[has] = np.asarray(adj[np.flatnonzero(has), pred[has]]).ravel() - 1
    in_tree = np.zeros(len(edge_tris), bool)
    in_tree[parent_edge[has]] = True
    return order, pred, in_tree


def _vertex_fans(n: int, xy: np.ndarray, tris: np.ndarray) -> list[np.ndarray]:
    """Per vertex its triangles sorted by angle around it (a planar triangulation's stars are
    star-shaped, so the angle of the centroid orders them)."""
    v = tris.ravel()
    t = np.repeat(np.arange(len(tris)), 3)
    c = xy[tris].mean(axis=1)[t] - xy[v]
    order = np.lexsort((np.arctan2(c[:, 1], c[:, 0]), v))
    v, t = v[order], t[order]
    cuts = np.searchsorted(v, np.arange(n + 1))
    return [t[cuts[i]:cuts[i + 1]] for i in range(n)]


def _singular_vertices(xy: np.ndarray, tris: np.ndarray, frames: np.ndarray, bnd: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Interior vertices around which a family's direction turns (nonzero index) or the
    matchings do not compose to the identity; and, of those, the ones whose matchings do compose
    to the identity (a whole turn, e.g. a dome's apex)."""
    n = len(xy)
    fans = _vertex_fans(n, xy, tris)
    out, whole = [], []
    for i in np.flatnonzero(~bnd):
        f = fans[i]
        if len(f) < 3:
            continue
        # carry the frame around the vertex, each triangle's representative the one closest to
        # the last: the frame it comes back as (the holonomy) and how far its first line turned
        cur = frames[f[0]]
        turn = 0.0
        for t in np.r_[f[1:], f[:1]]:
            nxt = frames[t] @ SIGNED_PERMUTATIONS[_best_matching(frames[[t]], cur[None])[0]]
            turn += np.arctan2(cur[0, 0] * nxt[1, 0] - cur[1, 0] * nxt[0, 0], cur[:, 0] @ nxt[:, 0])
            cur = nxt
        R = np.linalg.solve(frames[f[0]], cur)
        wind = np.round(turn / (2 * np.pi)) if np.allclose(R, np.eye(2), atol=1e-6) else 0.0
        ident = np.allclose(R, np.eye(2), atol=1e-6)
        if wind != 0 or not ident:
            out.append(i)
            if ident:
                whole.append(i)
    return np.array(out, np.int64), np.array(whole, np.int64)


def _cut_graph(edges: np.ndarray, in_tree: np.ndarray, bnd: np.ndarray, singular: np.ndarray) -> np.ndarray:
    """Boolean per interior edge: on the cut (not crossed by the dual tree, and not on a branch
    that ends at a regular interior vertex)."""
    n = len(bnd)
    cut = ~in_tree
    keep = bnd.copy()
    keep[singular] = True
    while True:
        deg = np.bincount(edges[cut].ravel(), minlength=n)
        leaf = (deg == 1) & ~keep
        drop = cut & (leaf[edges[:, 0]] | leaf[edges[:, 1]])
        if not drop.any():
            return cut
        cut = cut & ~drop


def _wedges(tris: np.ndarray, edges: np.ndarray, edge_tris: np.ndarray, glued: np.ndarray,
            apart: np.ndarray) -> np.ndarray:
    """``(m, 3)`` per triangle corner its wedge: corners of a vertex joined across glued edges,
    except at the vertices ``apart`` (each corner its own wedge)."""
    m = len(tris)
    parent = np.arange(3 * m)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for k in np.flatnonzero(glued):
        s, t = edge_tris[k]
        for v in edges[k]:
            if apart[v]:
                continue
            a = 3 * s + int(np.flatnonzero(tris[s] == v)[0])
            b = 3 * t + int(np.flatnonzero(tris[t] == v)[0])
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[ra] = rb
    roots = np.array([find(x) for x in range(3 * m)])
    return np.unique(roots, return_inverse=True)[1].reshape(m, 3)


def _boundary_alignment(xy: np.ndarray, tris: np.ndarray, frames: np.ndarray, wedge: np.ndarray
                        ) -> list[tuple[int, int]]:
    """Pairs of unknowns (``2 wedge + coordinate``) to be equal: the two ends of each boundary
    edge within ALIGN_ANGLE of a direction of its triangle, in the parameter that stays put along
    that direction (``v`` along ``d1``, ``u`` along ``d2``); a pair already joined through others
    is left out (a boundary loop that is all one iso-line would give one equation too many)."""
    m = len(tris)
    a = tris[:, [0, 1, 2]].ravel()
    b = tris[:, [1, 2, 0]].ravel()
    ia = np.tile([0, 1, 2], m)
    ib = np.tile([1, 2, 0], m)
    t = np.repeat(np.arange(m), 3)
    key = np.minimum(a, b) * (int(tris.max()) + 1) + np.maximum(a, b)
    uniq, cnt = np.unique(key, return_counts=True)
    once = np.isin(key, uniq[cnt == 1])
    parent: dict[int, int] = {}

    def find(x: int) -> int:
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    out = []
    lim = np.sin(np.radians(ALIGN_ANGLE))
    for j in np.flatnonzero(once):
        e = xy[b[j]] - xy[a[j]]
        L = np.linalg.norm(e)
        if L == 0:
            continue
        F = frames[t[j]]
        sines = np.abs(e[0] * F[1] - e[1] * F[0]) / L  # |sin| to d1, d2
        k = int(np.argmin(sines))
        if sines[k] > lim:
            continue
        c = 1 - k
        x, y = 2 * wedge[t[j], ia[j]] + c, 2 * wedge[t[j], ib[j]] + c
        rx, ry = find(int(x)), find(int(y))
        if rx != ry:
            parent[rx] = ry
            out.append((int(x), int(y)))
    return out


def frame_parametrization(xy: np.ndarray, tris: np.ndarray, directions: np.ndarray, spacing: float,
                          *, round_seams: bool = True, max_rounds: int | None = None,
                          align_boundary: bool = True, frames: np.ndarray | None = None,
                          integer_singularities: bool = False, batch: int = 1,
                          align_weight: float | None = None, keep_density: bool = False) -> Parametrization:
    """A parametrization ``(u, v)`` of the triangulation ``(xy, tris)`` whose gradients are the
    dual frame of ``directions`` over ``spacing`` (module docstring).

    Parameters
    ----------
    xy
        ``(n, 2)`` vertex positions.
    tris
        ``(m, 3)`` triangles (a manifold, connected top view; holes allowed).
    directions
        ``(n, 2, 2)`` per vertex two unit directions (columns), finite everywhere (fill the
        undefined ones first); their signs do not matter.
    spacing
        Length ``h`` of a quad edge along each direction.
    round_seams
        Round the seam translations to integers (greedy, one per solve).
    max_rounds
        Most solves in the rounding (default: as many as there are seam translations).
    align_boundary
        Hold boundary edges that run along a direction of the field on an iso-line of the
        other parameter, rounded to an integer with the seams (so that the boundary is a mesh
        line there, not cut obliquely by lines that end on it in slivers).
    frames
        ``(m, 2, 2)`` per triangle the frame (unit columns), instead of the mean of
        ``directions`` over its corners (e.g. a smoothed field, :mod:`.quadmesh`).
    integer_singularities
        Round the ``(u, v)`` of every singular vertex of index ±1/4 (the matchings around it a
        quarter turn) to integers as well: the vertex is then a crossing of integer iso-lines,
        a quad mesh vertex of valence 3 or 5, not a point inside a face (which the iso-lines
        would leave as a face of three or five corners). Whole-turn singularities stay slits.
    align_weight
        Weigh the least squares along the frame: the terms that turn the iso-lines away from
        the directions (``∇u·d2``, ``∇v·d1``) ``align_weight`` times the ones that change their
        spacing (``∇u·d1 − 1/h``, ``∇v·d2 − 1/h``); where the field is not integrable, the
        lines then keep to the directions and give way in spacing. ``None``: the plain
        ``|∇(u, v) − F⁻¹/h|²``.
    batch
        Values fixed per solve in the rounding: ``1``, one at a time (the plain greedy
        rounding); ``k > 1``, the ``1/k`` of the remaining ones nearest an integer (about ``k``
        solves for ``k`` times fewer; the seamless remesh uses 8).
    keep_density
        Scale the target gradients, before the rounding, so that the unrounded parametrization
        covers as many unit squares (``∫|det ∇(u, v)|``) as the target asks for
        (``∫|det F⁻¹| / h²``, :func:`density_ratio`). Where the field is not integrable the
        least squares keeps only the target's gradient part, which is shorter: the lines then
        come out farther apart than ``spacing`` (the paper's vault at its mean edge: 57% of the
        target's quads).

    Returns
    -------
    Parametrization
    """
    xy = np.asarray(xy, float)
    tris = np.asarray(tris, np.int64)
    n, m = len(xy), len(tris)
    if frames is None:
        D = np.asarray(directions, float)
        if not np.all(np.isfinite(D)):
            raise InputError("the frame field has undefined directions; fill them before parametrizing")
        doubled = np.stack([D[:, 0, :] ** 2 - D[:, 1, :] ** 2, 2 * D[:, 0, :] * D[:, 1, :]], axis=1)
        F = _triangle_frames(xy, tris, doubled)
    else:
        F = _spread(np.asarray(frames, float).copy())
    G, area = _gradients(xy, tris)
    edges, edge_tris, bnd = _interior_edges(tris)
    singular, whole = _singular_vertices(xy, tris, F, bnd)
    # the root of the dual tree (and the gauge): the largest triangle off the boundary
    root = int(np.argmax(np.where(bnd[tris].any(axis=1), -1.0, 1.0) * area))
    order, pred, in_tree = _dual_tree(m, edge_tris, root)
    # frames made consistent along the tree: each triangle takes the representative closest to
    # its parent's
    for t in order[1:]:
        F[t] = F[t] @ SIGNED_PERMUTATIONS[_best_matching(F[[t]], F[[pred[t]]])[0]]
    cut = _cut_graph(edges, in_tree, bnd, singular)
    match = _best_matching(F[edge_tris[:, 0]], F[edge_tris[:, 1]])
    # an uncut edge whose matching is not the identity (the pruning's assumption failed, e.g. a
    # frame turning fast next to a singularity) becomes a seam as well: its equations hold either way
    seam = cut | (match != 0)
    # at a whole-turn singularity the seam's translation cannot vanish at its end (the lines
    # that circle it grow with the radius): its corners are not joined, the point is a slit's end
    apart = np.zeros(n, bool)
    apart[whole] = True
    wedge = _wedges(tris, edges, edge_tris, ~seam, apart)
    W = int(wedge.max()) + 1
    # least squares rows: sqrt(area) (∇u − J_t[0], ∇v − J_t[1]) per triangle, unknowns (u_w, v_w)
    J = np.linalg.inv(F) / spacing  # rows: target ∇u, ∇v
    sw = np.sqrt(area)
    rows, cols, vals, rhs = [], [], [], []
    # align_weight: rows along the frame, ∇u·d_j − δ_0j / h and ∇v·d_j − δ_1j / h, the ones that
    # turn the lines (∇u·d2, ∇v·d1) weighted; else rows along x and y, ∇(u, v) − F⁻¹ / h
    GF = np.einsum("mkd,mdj->mkj", G, F) if align_weight is not None else G
    for c in range(2):  # u, v
        for d in range(2):  # x, y (or d1, d2)
            r = (2 * c + d) * m + np.arange(m)
            wr = sw * (np.sqrt(align_weight) if align_weight is not None and c != d else 1.0)
            for k in range(3):
                rows.append(r)
                cols.append(2 * wedge[:, k] + c)
                vals.append(wr * GF[:, k, d])
            rhs.append(wr * (J[:, c, d] if align_weight is None else np.full(m, float(c == d) / spacing)))
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(4 * m, 2 * W))
    b = np.concatenate(rhs) * spacing  # in units where the lines are 1 apart: ∇ scaled by h
    A = A * spacing
    # seam equations: p_t(a) − Rᵀ p_s(a) − T_e = 0 for both ends a of each seam edge
    sk = np.flatnonzero(seam)
    nT = 2 * len(sk)
    crow, ccol, cval = [], [], []
    row = 0
    for j, k in enumerate(sk):
        s, t = edge_tris[k]
        Rt = SIGNED_PERMUTATIONS[match[k]].T
        for v in edges[k]:
            ws = wedge[s, int(np.flatnonzero(tris[s] == v)[0])]
            wt = wedge[t, int(np.flatnonzero(tris[t] == v)[0])]
            for c in range(2):
                crow += [row, row]
                ccol += [2 * wt + c, 2 * W + 2 * j + c]
                cval += [1.0, -1.0]
                for c2 in range(2):
                    if Rt[c, c2] != 0:
                        crow.append(row)
                        ccol.append(2 * ws + c2)
                        cval.append(-Rt[c, c2])
                row += 1
    # boundary runs along the field: equal values of the parameter that stays put along them
    pairs = _boundary_alignment(xy, tris, F, wedge) if align_boundary else []
    for x0, x1 in pairs:
        crow += [row, row]
        ccol += [x0, x1]
        cval += [1.0, -1.0]
        row += 1
    N = 2 * W + nT
    C = sp.csr_matrix((cval, (crow, ccol)), shape=(row, N))
    d0 = np.zeros(row)
    A = sp.hstack([A, sp.csr_matrix((A.shape[0], nT))]).tocsr()
    H = (A.T @ A).tocsr()
    g_fit = A.T @ b
    g = g_fit
    # the gauge (a common translation of all values is free): a faint pull of the root
    # triangle's first corner to (½, ½), weak enough to give way to the rounding
    w0 = wedge[root, 0]
    eps = 1e-8 * float(H.diagonal()[:2 * W].mean())
    H = H + sp.csr_matrix(([eps, eps], ([2 * w0, 2 * w0 + 1], [2 * w0, 2 * w0 + 1])), shape=(N, N))
    g = g + np.bincount([2 * w0, 2 * w0 + 1], weights=[0.5 * eps, 0.5 * eps], minlength=N)
    # a tiny Tikhonov term on the translations keeps the KKT matrix regular where two seam
    # edges share both wedges on each side (their translations are equal, one equation too many)
    reg = sp.diags(np.r_[np.zeros(2 * W), np.full(nT, 1e-12)])
    fixed: dict[int, float] = {}

    def solve() -> np.ndarray:
        fi = np.array(sorted(fixed), np.int64)
        E = sp.csr_matrix((np.ones(len(fi)), (np.arange(len(fi)), fi)), shape=(len(fi), N))
        CC = sp.vstack([C, E]).tocsr()
        dd = np.r_[d0, [fixed[i] for i in fi]]
        K = sp.bmat([[H + reg, CC.T], [CC, -1e-12 * sp.identity(CC.shape[0])]], format="csc")
        return spla.splu(K).solve(np.r_[g, dd])[:N]

    x = solve()
    scale = 1.0
    if keep_density:
        # the solve is linear in the target (the gauge's pull aside): scaling the target by s
        # scales the unrounded solution by s and its quad count by s²
        ratio = density_ratio(G, area, x[:2 * W].reshape(W, 2)[wedge], J)
        if np.isfinite(ratio) and ratio > 0:
            scale = float(1.0 / np.sqrt(ratio))
            g = g - g_fit + scale * g_fit
            x = solve()
    # what must be an integer: the seam translations, and one value of each aligned boundary run
    runs: dict[int, int] = {}
    parent = {a: b for a, b in pairs}
    for a, _ in pairs:
        r = a
        while r in parent:
            r = parent[r]
        runs.setdefault(r, r)
    sing_vals = np.zeros(0, np.int64)
    if integer_singularities:
        quarter = np.setdiff1d(singular, whole)
        corner = np.isin(tris, quarter)
        sing_vals = np.unique(np.r_[2 * wedge[corner], 2 * wedge[corner] + 1]).astype(np.int64)
    cand = np.r_[2 * W + np.arange(nT), np.array(sorted(runs), np.int64), sing_vals].astype(np.int64)
    rounded = cand.size == 0
    if round_seams and cand.size:
        # greedy: the values nearest an integer are fixed to it, then solve again; the singular
        # vertices first (a seam's translation T = (I − R) p at its singular end is an integer
        # when p is, not the other way round)
        rounds = max_rounds if max_rounds is not None else cand.size
        for _ in range(rounds):
            free = np.zeros(0, np.int64)
            for todo in (sing_vals, cand):
                free = np.array([i for i in todo if i not in fixed], np.int64)
                free = free[np.abs(x[free] - np.round(x[free])) > ROUND_TOL] if free.size else free
                if free.size:
                    break
            if not free.size:
                break
            near = free[np.argsort(np.abs(x[free] - np.round(x[free])), kind="stable")]
            for i in near[:1 if batch <= 1 else -(-len(near) // int(batch))]:
                fixed[int(i)] = float(np.round(x[i]))
            x = solve()
        off = np.abs(x[cand] - np.round(x[cand]))
        rounded = bool(np.all(off <= 1e2 * ROUND_TOL))
    P = x[:2 * W].reshape(W, 2)
    uv = P[wedge]  # (m, 3, 2)
    grad = np.einsum("mkd,mkc->mcd", G, uv) * spacing
    res = float(np.sqrt((area * ((grad - scale * J * spacing) ** 2).sum(axis=(1, 2))).sum() / area.sum()))
    return Parametrization(uv=uv, frames=F, singular=singular, seams=edges[sk], residual=res, rounded=rounded,
                           scale=scale)


def density_ratio(G: np.ndarray, area: np.ndarray, uv: np.ndarray, target: np.ndarray) -> float:
    """How many unit squares of the parametrization ``uv`` ``(m, 3, 2)`` cover the triangulation
    (``Σ_t A_t |det ∇(u, v)_t|``) over how many its target gradients ``(m, 2, 2)`` (rows ``∇u``,
    ``∇v``) ask for; ``G`` and ``area`` as from :func:`_gradients`, all in the same length unit."""
    grad = np.einsum("mkd,mkc->mcd", G, uv)
    want = float((area * np.abs(np.linalg.det(target))).sum())
    return float((area * np.abs(np.linalg.det(grad))).sum()) / want if want > 0 else float("nan")


def isolines(xy: np.ndarray, tris: np.ndarray, uv: np.ndarray, *, snap: float = 1e-9
             ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The iso-lines ``u ∈ Z`` and ``v ∈ Z`` of a per-corner parametrization as polylines, in
    two lists: the lines that are mostly iso-``u``, and the rest. Pieces are joined where they
    meet across triangles (within ``snap`` × the mean edge length), across seams too, where an
    iso-``u`` line may go on as an iso-``v`` line."""

    xy = np.asarray(xy, float)
    P = xy[tris]
    ell = float(np.linalg.norm(P[:, 1] - P[:, 0], axis=1).mean())
    segs, label = [], []
    for c in range(2):
        f = uv[:, :, c]
        lo, hi = np.ceil(f.min(axis=1)), np.floor(f.max(axis=1))
        for t in np.flatnonzero(hi >= lo):
            for k in np.arange(lo[t], hi[t] + 1):
                above = f[t] >= k
                if above.all() or not above.any():
                    continue
                if (np.abs(f[t] - k) <= 1e-9).sum() >= 2:  # along an edge: a boundary held on the level
                    continue
                pts = []
                for i, j in ((0, 1), (1, 2), (2, 0)):
                    if above[i] != above[j]:
                        s = (k - f[t, i]) / (f[t, j] - f[t, i])
                        pts.append(P[t, i] + s * (P[t, j] - P[t, i]))
                if len(pts) == 2 and np.linalg.norm(pts[1] - pts[0]) > snap * ell:
                    segs.append(pts)
                    label.append(c)
    if not segs:
        return [], []
    S = np.asarray(segs).reshape(-1, 2)
    rep = np.arange(len(S))
    for i, j in sorted(cKDTree(S).query_pairs(10 * snap * ell)):
        rep[j] = rep[i] if rep[i] < j else rep[j]
    node = np.unique(rep, return_inverse=True)[1]
    E = node.reshape(-1, 2)
    keep = E[:, 0] != E[:, 1]
    XY = np.zeros((int(node.max()) + 1, 2))
    XY[node] = S
    out: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
    for path, segs_on in _chain(E[keep], XY):
        out[int(np.round(np.asarray(label)[keep][segs_on].mean()))].append(XY[path])
    return out


def _chain(E: np.ndarray, XY: np.ndarray) -> list[tuple[list[int], list[int]]]:
    """Polylines from segments ``E`` (node pairs): maximal paths through nodes of degree two, as
    their nodes and their segments."""
    n = len(XY)
    nb: list[list[int]] = [[] for _ in range(n)]
    for k, (a, b) in enumerate(E):
        nb[a].append(k)
        nb[b].append(k)
    used = np.zeros(len(E), bool)
    lines = []

    def walk(start: int, k: int) -> tuple[list[int], list[int]]:
        path, on = [start], []
        cur = start
        while True:
            used[k] = True
            on.append(k)
            a, b = E[k]
            cur = b if a == cur else a
            path.append(cur)
            nxt = [j for j in nb[cur] if not used[j]]
            if len(nb[cur]) != 2 or not nxt:
                return path, on
            k = nxt[0]

    for v in range(n):  # open lines first (from their ends and branch points), then loops
        if len(nb[v]) != 2:
            for k in nb[v]:
                if not used[k]:
                    lines.append(walk(v, k))
    for k in range(len(E)):
        if not used[k]:
            lines.append(walk(int(E[k, 0]), k))
    return lines
