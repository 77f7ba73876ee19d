"""The evidence every result carries: equilibrium residuals (paper's Table 1 metric),
weight bounds, load consistency and distance to the reference surface."""
from __future__ import annotations

import atexit

import numpy as np

from selfsupport.core.geometry import bbox_diagonal, diagonal_distance, vertex_normals
from selfsupport.core.mesh import PolyMesh


def stress_sums(*, edges: np.ndarray, weights: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``Σ_j w_ij (f_j − f_i)`` at every vertex: the stress Laplacian Δ_φ applied to ``values``
    (``(n,)`` or ``(n, k)``, e.g. heights, top-view or 3D positions). With the positions it is the
    left side of eqs. (2)–(3); :func:`residuals` subtracts the loads.

    >>> stress_sums(edges=np.array([[0, 1], [1, 2]]), weights=np.array([2.0, 1.0]), values=np.array([0.0, 1.0, 3.0]))
    array([ 2.,  0., -2.])
    """
    values = np.asarray(values, float)
    f = np.asarray(weights, float).reshape((-1,) + (1,) * (values.ndim - 1)) * (values[edges[:, 1]] - values[edges[:, 0]])
    return _sum_at_ends(edges, f, -f, len(values))


def force_sums(*, edges: np.ndarray, weights: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``Σ_j |w_ij| ‖f_j − f_i‖`` at every vertex: the size of the forces a vertex balances, the
    scale its residual is judged against (``values`` ``(n, k)``: top-view or 3D positions)."""
    values = np.asarray(values, float)
    m = np.abs(np.asarray(weights, float)) * np.linalg.norm(values[edges[:, 1]] - values[edges[:, 0]], axis=1)
    return _sum_at_ends(edges, m, m, len(values))


def load_vectors(loads: np.ndarray) -> np.ndarray:
    """``(n, 3)`` nodal load vectors [N] of ``loads``: signed vertical loads ``(n,)`` become
    ``(0, 0, A_i F_i)``; ``(n, 3)`` loads (with horizontal components) are returned as they are.

    >>> load_vectors(np.array([-2.0, 0.0])).tolist()
    [[0.0, 0.0, -2.0], [0.0, 0.0, 0.0]]
    """
    L = np.asarray(loads, float)
    if L.ndim == 2:
        return L
    out = np.zeros((len(L), 3))
    out[:, 2] = L
    return out


def load_magnitudes(loads: np.ndarray) -> np.ndarray:
    """``|L_i|`` per vertex of vertical ``(n,)`` or 3D ``(n, 3)`` loads (the scale of a relative error)."""
    L = np.asarray(loads, float)
    return np.linalg.norm(L, axis=1) if L.ndim == 2 else np.abs(L)


def residuals(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray,
              loads: np.ndarray) -> np.ndarray:
    """``(n, 3)``: ``Σ_j w_ij (v_j − v_i) − L_i`` at every vertex (supports included); ``L_i`` is
    ``(0, 0, A_i F_i)`` for vertical loads ``(n,)``, or the rows of 3D loads ``(n, 3)``."""
    r = stress_sums(edges=edges, weights=weights, values=vertices)
    L = np.asarray(loads, float)
    if L.ndim == 2:
        return r - L
    r[:, 2] -= L
    return r


def support_reactions(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray, loads: np.ndarray,
                      supports: np.ndarray) -> np.ndarray:
    """``(k, 3)`` force [N] the ground exerts on each support (in vertex order), from the network:
    ``R_i = Σ_j w_ij (v_j − v_i) − L_i``, the :func:`residuals` at the support, so that the
    support is in equilibrium under its edges' forces, its own load and ``R_i``.

    Summed over the supports, ``Σ R_i = −Σ_i L_i`` over every vertex (the edge terms cancel
    pairwise) up to the free vertices' residuals. With compression (w ≥ 0) the network pushes
    its supports outward and down; the reaction is the ground pushing back, inward and up.

    >>> V = np.array([[-2.0, 0, 0], [0.0, 0, 1], [2.0, 0, 0]])   # two bars, apex load 10 N
    >>> R = support_reactions(vertices=V, edges=np.array([[0, 1], [1, 2]]), weights=np.array([5.0, 5.0]),
    ...                       loads=np.array([0.0, -10.0, 0.0]), supports=np.array([True, False, True]))
    >>> R.tolist()   # thrust H = P L / (4 f) = 10 * 4 / 4 = 10 N, each side carries 5 N up
    [[10.0, 0.0, 5.0], [-10.0, 0.0, 5.0]]
    """
    sup = np.asarray(supports, bool)
    return residuals(vertices=vertices, edges=edges, weights=weights, loads=loads)[sup]


def reaction_summary(reactions: np.ndarray, loads: np.ndarray, support_vertices: np.ndarray) -> dict:
    """What foundations are designed from, in N: the total reaction (a 3-vector), its vertical
    part beside the total load, the largest horizontal reaction at one support (its vertex) and
    the thrust (the sum of the supports' horizontal reaction magnitudes)."""
    R = np.asarray(reactions, float).reshape(-1, 3)
    h = np.linalg.norm(R[:, :2], axis=1)
    k = int(np.argmax(h)) if h.size else -1
    L = load_vectors(loads)
    return {"total": R.sum(axis=0), "vertical": float(R[:, 2].sum()), "total_load": L.sum(axis=0),
            "max_horizontal": float(h[k]) if h.size else 0.0,
            "max_horizontal_vertex": int(np.asarray(support_vertices)[k]) if h.size else None,
            "thrust": float(h.sum())}


def reaction_line(summary: dict) -> str:
    """One summary line on :func:`reaction_summary`, in kN: the vertical reactions beside the load
    they carry, the largest horizontal reaction and its support vertex, and the thrust (the sum
    of the horizontal reaction magnitudes).

    >>> reaction_line(reaction_summary(np.array([[1e3, 0, 2e3], [-1e3, 0, 2e3]]), np.array([0, -4e3, 0]), [0, 2]))
    'vertical 4 kN (load 4 kN), max horizontal 1 kN at 0, thrust 2 kN'
    """
    if summary["max_horizontal_vertex"] is None:
        return "no supports"
    return (f"vertical {summary['vertical'] / 1e3:.6g} kN (load {-summary['total_load'][2] / 1e3:.6g} kN), max "
            f"horizontal {summary['max_horizontal'] / 1e3:.4g} kN at {summary['max_horizontal_vertex']}, thrust "
            f"{summary['thrust'] / 1e3:.4g} kN")


def _sum_at_ends(edges: np.ndarray, at_first: np.ndarray, at_second: np.ndarray, n: int) -> np.ndarray:
    """Per vertex, the sum of ``at_first`` over the edges that start there and of ``at_second``
    over those that end there (``(m,)`` or ``(m, k)`` arrays). One bincount per column over both
    ends: the same sums in the same order as ``np.add.at(r, e0, a); np.add.at(r, e1, b)`` (bit
    for bit), 3-5x faster on (n, 3) arrays."""
    shape = (n,) + at_first.shape[1:]
    if not len(edges):
        return np.zeros(shape)
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    both = np.concatenate([at_first, at_second]).reshape(2 * len(edges), -1)
    return np.stack([np.bincount(ends, weights=both[:, k], minlength=n) for k in range(both.shape[1])],
                    axis=1).reshape(shape)


def relative_errors(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray,
                    loads: np.ndarray, supports: np.ndarray) -> np.ndarray:
    """Per non-support vertex: ``‖residual‖ / |A_i F_i|`` (paper's Table 1 definition)."""
    r = residuals(vertices=vertices, edges=edges, weights=weights, loads=loads)
    free = ~np.asarray(supports, bool)
    return np.linalg.norm(r[free], axis=1) / np.maximum(load_magnitudes(loads)[free], 1e-300)


#: A vertex whose relative error is at most this many times its round-off floor
#: (:func:`roundoff_floors`) is in equilibrium as far as double precision can tell: the floor
#: bounds the coordinates' rounding, and a polished solve adds a little (about twice the floor).
FLOOR_MARGIN = 4.0
#: ... but never a relative error above this: the floor grows without bound where a vertex's load
#: vanishes (vertices slid together), and such a network is degenerate, not in equilibrium.
FLOOR_CAP = 1e-8
#: A vertex whose load is below this fraction of the median free vertex's load has (nearly) no
#: area of its own: it slid onto its neighbours. Its floor is then large because the network is
#: degenerate, so :func:`roundoff_limit` does not blame rounding (vertices held by rounding alone
#: carry a few hundredths of the median load or more).
DEGENERATE_LOAD = 1e-3
#: ... and one whose load is below this fraction (but above DEGENERATE_LOAD) sits in squashed
#: faces: on an unsquashed mesh even a free corner carries about a quarter of a typical load.
#: :func:`roundoff_message` then names it, since the small load raises the floor as much as the
#: forces do.
SQUASHED_LOAD = 0.1


def floor_tolerance(floors: np.ndarray) -> np.ndarray:
    """Per vertex, the relative error that counts as equilibrium at its round-off floor:
    :data:`FLOOR_MARGIN` × the floor, never above :data:`FLOOR_CAP` (the equilibrium test's
    rule; a warm start's weight fit uses :func:`fit_floor_tolerance`)."""
    return np.minimum(FLOOR_MARGIN * np.asarray(floors, float), FLOOR_CAP)


def degenerate(loads: np.ndarray) -> np.ndarray:
    """Per free vertex (``loads``: theirs): a load below :data:`DEGENERATE_LOAD` × the median
    |load|, i.e. a vertex that slid onto its neighbours.

    >>> degenerate(np.array([-1.0, -2.0, -1.5, -1e-4]))
    array([False, False, False,  True])
    """
    load = np.abs(np.asarray(loads, float))
    return load < DEGENERATE_LOAD * float(np.median(load)) if load.size else np.zeros(0, bool)


def fit_floor_tolerance(floors: np.ndarray, loads: np.ndarray) -> np.ndarray:
    """Per free vertex, the relative residual below which a warm start's weights fit already:
    :data:`FLOOR_MARGIN` × its round-off floor, without :data:`FLOOR_CAP` (a fit cannot
    balance such a vertex better in doubles), except at a :func:`degenerate` vertex, where
    the cap stays (its floor is large because it slid onto its neighbours, which a fit may
    still mend)."""
    floors = np.asarray(floors, float)
    return np.where(degenerate(loads), floor_tolerance(floors), FLOOR_MARGIN * floors)


def roundoff_floors(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray,
                    loads: np.ndarray, supports: np.ndarray) -> np.ndarray:
    """Per non-support vertex: the relative error that rounding the coordinates to doubles can
    leave alone, ``eps ‖Σ_j |w_ij| (|v_i| + |v_j|)‖ / |A_i F_i|`` (absolute values taken per
    coordinate). Where an edge's force is many times the vertex's load (next to a pillar of a
    fine mesh, on a free boundary arch) no positions, however solved, balance that vertex better:
    a 64k pillar vault's floor reached 1.05e-8 at vertices whose polished error was 4.8e-9.

    >>> V = np.array([[0.0, 0, 0], [1.0, 0, 1], [2.0, 0, 0]])
    >>> E = np.array([[0, 1], [1, 2]])
    >>> f = roundoff_floors(vertices=V, edges=E, weights=np.array([1.0, 1.0]), loads=np.array([0, -2.0, 0]),
    ...                     supports=np.array([True, False, True]))
    >>> bool(np.isclose(f[0], np.finfo(float).eps * np.linalg.norm([4.0, 0, 2.0]) / 2))
    True
    """
    V = np.abs(np.asarray(vertices, float))
    a = np.abs(np.asarray(weights, float))[:, None] * (V[edges[:, 0]] + V[edges[:, 1]])
    S = _sum_at_ends(edges, a, a, len(V))
    free = ~np.asarray(supports, bool)
    return np.finfo(float).eps * np.linalg.norm(S[free], axis=1) / np.maximum(load_magnitudes(loads)[free], 1e-300)


def roundoff_limit(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray, loads: np.ndarray,
                   supports: np.ndarray, tol: float, rel: np.ndarray | None = None,
                   floors: np.ndarray | None = None) -> dict | None:
    """Why a network misses ``tol`` when rounding alone is the reason, else ``None``.

    Such a network has vertices above ``tol``, and each one is within :data:`FLOOR_MARGIN` ×
    its round-off floor (:func:`roundoff_floors`). Some of them are above :data:`FLOOR_CAP`,
    so it is not in equilibrium. No positions in doubles balance these vertices better, so
    iterating on is wasted. None of them may be a degenerate vertex (:data:`DEGENERATE_LOAD`).

    The floor is ``eps Σ|w_ij|(|v_i| + |v_j|)``. It grows with the distance from the origin: a
    design in site coordinates 10⁶ m away has a floor 10⁵ times that at the origin. It also grows
    with the edge force over the vertex's load: a fine mesh's free-boundary arches carry 10⁶
    times it. The report gives both: ``floor`` (the largest floor among the vertices above
    ``tol``), ``centred_floor`` (the same with the bounding-box centre moved to the origin),
    ``offset`` (that centre's distance from the origin), ``force_ratio`` (the largest edge
    force at those vertices over their load) and ``load_ratio`` (the smallest load among them over
    the median free vertex's load). ``rel`` and ``floors``, when given, are the
    network's :func:`relative_errors` and :func:`roundoff_floors` (a network keeps them; at 443k
    vertices they cost 0.24 and 0.05 s).

    >>> V = np.array([[0.0, 0, 0], [1.0, 0, 1], [2.0, 0, 0]])
    >>> E, S = np.array([[0, 1], [1, 2]]), np.array([True, False, True])
    >>> kw = dict(edges=E, weights=np.array([1.0, 1.0]), loads=np.array([0, -2.0, 0]), supports=S, tol=1e-9)
    >>> roundoff_limit(vertices=V, **kw) is None  # in equilibrium
    True
    >>> far = V + [1e9, 0, 0]
    >>> far[1, 0] = np.nextafter(far[1, 0], 2e9)   # one spacing of doubles (1.2e-7) off
    >>> rep = roundoff_limit(vertices=far, **kw)
    >>> rep["n_vertices"], rep["offset"] > 1e9 - 2, rep["centred_floor"] < 1e-15
    (1, True, True)
    """
    if rel is None:
        rel = relative_errors(vertices=vertices, edges=edges, weights=weights, loads=loads, supports=supports)
    over = rel > tol
    if not over.any() or not np.all(np.isfinite(rel)):
        return None
    if floors is None:
        floors = roundoff_floors(vertices=vertices, edges=edges, weights=weights, loads=loads, supports=supports)
    if np.all(rel[over] <= floor_tolerance(floors[over])) or np.any(rel[over] > FLOOR_MARGIN * floors[over]):
        return None  # in equilibrium (at the floor, within the cap), or off it for other reasons
    free = ~np.asarray(supports, bool)
    load = load_magnitudes(loads)[free]
    if np.any(degenerate(load)[over]):
        return None  # a vertex with next to no load: slid onto its neighbours, a degenerate network
    V = np.asarray(vertices, float)
    centre = 0.5 * (V.min(axis=0) + V.max(axis=0))
    centred = roundoff_floors(vertices=V - centre, edges=edges, weights=weights, loads=loads, supports=supports)
    force = np.abs(weights) * np.linalg.norm(V[edges[:, 1]] - V[edges[:, 0]], axis=1)
    at_vertex = np.zeros(len(V))
    np.maximum.at(at_vertex, edges[:, 0], force)
    np.maximum.at(at_vertex, edges[:, 1], force)
    ratio = at_vertex[free][over] / np.maximum(load[over], 1e-300)
    return {"max_relative_error": float(rel.max()), "n_vertices": int(over.sum()), "floor": float(floors[over].max()),
            "centred_floor": float(centred[over].max()), "offset": float(np.linalg.norm(centre)),
            "force_ratio": float(ratio.max()),
            "load_ratio": float(load[over].min() / max(float(np.median(load)), 1e-300))}


def roundoff_message(report: dict, tol: float) -> str:
    """One sentence on a :func:`roundoff_limit` report: what limits the network, and what to change."""
    head = (f"max relative error {report['max_relative_error']:.2e} > tol {tol:g}, but each of the "
            f"{report['n_vertices']} vertices above tol is within {FLOOR_MARGIN:g}× its round-off floor (largest "
            f"{report['floor']:.2e}): rounding the coordinates to doubles leaves that much, and no positions "
            "balance those vertices better")
    if FLOOR_MARGIN * report["centred_floor"] <= tol:
        return (f"{head}; the design lies {report['offset']:.3g} m from the origin, so translate it near the "
                f"origin (its floor there: {report['centred_floor']:.1e})")
    squashed = (f", and some of those vertices carry only {report['load_ratio']:.2g} of the median vertex load "
                "(the faces beside them are squashed in plan)"
                if report["load_ratio"] < SQUASHED_LOAD else "")
    return (f"{head}; edge forces there reach {report['force_ratio']:.2g}× those vertices' loads (e.g. the "
            f"free-boundary arches of a fine mesh){squashed}: use a coarser mesh, support that boundary, or a tol "
            f"of at least {FLOOR_MARGIN * report['floor']:.1e}")


def max_relative_error(**kw) -> float:
    rel = relative_errors(**kw)
    return float(rel.max()) if rel.size else 0.0


def distance_to_surface(points: np.ndarray, reference: PolyMesh) -> np.ndarray:
    """Unsigned distance from each point to the (triangulated) reference surface, exact.

    libigl's AABB-tree query (shared with :func:`closest_points`): exact at any distance and
    light on memory — 64k points in 0.2 s near the surface, 1.2 s far from it. trimesh's rtree
    query, used before, built candidate lists for all points at once (3.9 GiB at 16k
    vertices; the OOM killer at 64k). ``tests/test_evidence.py`` checks it against trimesh.
    """
    P = np.asarray(points, float)
    d = np.full(len(P), np.inf)
    ok = np.all(np.isfinite(P), axis=1)
    if ok.any():
        d[ok] = _reference_index(reference).query(P[ok])[0]
    return d


def closest_points(points: np.ndarray, reference: PolyMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points on the reference surface, distances and the unit normals there.

    Exact at any distance: libigl's AABB tree over the fan-triangulated reference, built
    once per reference mesh and kept (the solver queries it every outer iteration; ~1 ms
    per 1,000 points). Coordinates are centred and in units of the bounding-box diagonal, so
    scenes far from the origin lose no digits. ``tests/test_evidence.py`` checks it against
    trimesh.

    The normal is interpolated from the reference's vertex normals with the barycentric
    coordinates of the closest point, so it varies continuously — a per-triangle normal would
    jump across edges, where round-off decides which triangle is "closest". A non-finite
    point gets NaN for its closest point and normal and an infinite distance.
    """
    P = np.asarray(points, float)
    closest, dist, normals = np.full(P.shape, np.nan), np.full(len(P), np.inf), np.full(P.shape, np.nan)
    ok = np.all(np.isfinite(P), axis=1)  # (igl returns an arbitrary triangle for a NaN point)
    if not ok.any():
        return closest, dist, normals
    idx = _reference_index(reference)
    dist[ok], tri, C = idx.query(P[ok])
    corners = idx.F[tri]
    bc = _barycentric(C, *(idx.V[corners[:, j]] for j in range(3)))
    nrm = np.einsum("kc,kcj->kj", bc, idx.normals[corners])
    normals[ok] = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    closest[ok] = C * idx.scale + idx.centre
    return closest, dist, normals


def _barycentric(Q: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(k, 3)`` of points Q lying on triangles ABC (clipped to the
    triangle against round-off; a degenerate triangle gives its first corner)."""
    ab, ac, aq = B - A, C - A, Q - A
    d00, d01, d11 = (ab * ab).sum(1), (ab * ac).sum(1), (ac * ac).sum(1)
    d20, d21 = (aq * ab).sum(1), (aq * ac).sum(1)
    den = d00 * d11 - d01 * d01
    ok = den > 1e-30 * np.maximum(d00 * d11, 1e-300)
    den = np.where(ok, den, 1.0)
    v = np.where(ok, (d11 * d20 - d01 * d21) / den, 0.0)
    w = np.where(ok, (d00 * d21 - d01 * d20) / den, 0.0)
    bc = np.clip(np.stack([1 - v - w, v, w], axis=1), 0.0, None)
    return bc / np.maximum(bc.sum(axis=1, keepdims=True), 1e-300)


class _ReferenceIndex:
    """A reference mesh prepared for closest-point queries (normalised coordinates)."""

    def __init__(self, mesh: PolyMesh) -> None:
        import igl


        V = mesh.vertices
        self.centre, self.scale = V.mean(axis=0), max(bbox_diagonal(V), 1e-300)
        self.V = np.ascontiguousarray((V - self.centre) / self.scale, dtype=float)
        self.F = np.ascontiguousarray(triangulate(mesh), dtype=np.int64)
        self.normals = vertex_normals(mesh)
        self.tree = igl.AABB()
        self.tree.init(self.V, self.F)
        self._last: tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None

    def query(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For finite points P (world units): distances (world units), the closest triangle
        and the closest points in the normalised coordinates (centred, in units of the
        diagonal: no cancellation for scenes far from the origin).

        The answer for the last points asked is kept (read-only): a result's evidence, its
        objective terms and its hull record all ask about the same final vertices, and one
        query takes 0.3 s at 200k vertices. Each point's answer depends on that point alone,
        so a repeated query returns exactly what a new one would."""
        last = self._last
        if last is not None and last[0].shape == P.shape and np.array_equal(last[0], P):
            return last[1]
        sq, tri, C = self.tree.squared_distance(self.V, self.F, np.ascontiguousarray((P - self.centre) / self.scale))
        out = (np.sqrt(np.maximum(np.asarray(sq, float).ravel(), 0.0)) * self.scale, np.asarray(tri), np.asarray(C))
        for a in out:
            a.setflags(write=False)
        self._last = (np.array(P, dtype=float), out)
        return out


_INDEX_CACHE: dict[int, tuple[PolyMesh, _ReferenceIndex]] = {}
# (emptied at exit: libigl's AABB trees still alive when its nanobind module is torn down are
# reported as "leaked" on stderr, a screenful after every study)
atexit.register(_INDEX_CACHE.clear)


def _reference_index(mesh: PolyMesh) -> _ReferenceIndex:
    """The query structure of a mesh, cached per mesh object (meshes are immutable)."""
    hit = _INDEX_CACHE.get(id(mesh))
    if hit is not None and hit[0] is mesh:
        return hit[1]
    if len(_INDEX_CACHE) > 16:
        _INDEX_CACHE.clear()
    idx = _ReferenceIndex(mesh)
    _INDEX_CACHE[id(mesh)] = (mesh, idx)
    return idx


def triangulate(mesh: PolyMesh) -> np.ndarray:
    """Fan triangulation ``(t, 3)`` of all faces (corner 0 as apex): cheap and total, for closest
    points, drawing and interpolation, where any triangulation of the surface will do. Splitting a
    design into triangles to solve is :func:`selfsupport.core.triangulation.split_faces`."""
    fo, fv = mesh.face_offsets, mesh.face_vertices
    sizes = np.diff(fo)
    face_of = np.repeat(np.arange(mesh.n_faces), sizes - 2)
    k = np.arange(len(face_of)) - np.repeat(np.cumsum(sizes - 2) - (sizes - 2), sizes - 2)
    a = fv[fo[face_of]]
    b = fv[fo[face_of] + k + 1]
    c = fv[fo[face_of] + k + 2]
    return np.stack([a, b, c], axis=1)


def distance_stats(vertices: np.ndarray, reference: PolyMesh) -> tuple[float, float]:
    """Mean and max distance to the reference surface, relative to its bounding-box diagonal.

    Vertices that belong to no face of the reference (supports that carry nothing, see
    :mod:`selfsupport.methods.validate`) are not part of the surface and are left out."""
    vertices = np.asarray(vertices, float)
    # the distances of all vertices, then those of the isolated ones dropped: the same query as
    # the result's objective terms ask (answered once, see _ReferenceIndex.query)
    d = distance_to_surface(vertices, reference) / bbox_diagonal(reference.vertices)
    if len(vertices) == reference.n_vertices:
        iso = reference.isolated_vertices
        if iso.size:
            d = np.delete(d, iso)
    return float(d.mean()), float(d.max())


def face_nonplanarity(mesh: PolyMesh) -> np.ndarray:
    """Per quad face: the distance between its two diagonals over its mean edge length (0 for a
    planar quad; the fabrication measure of the paper's §5). Other faces get NaN.

    >>> import numpy as np
    >>> V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.1], [0, 1, 0.]])
    >>> m = PolyMesh.from_faces(V, [[0, 1, 2, 3]])
    >>> round(float(face_nonplanarity(m)[0]), 4)  # diagonals 0.0499 apart, edges 1.0025 long
    0.0498
    """
    out = np.full(mesh.n_faces, np.nan)
    quads = np.flatnonzero(mesh.face_sizes == 4)
    if quads.size:
        faces = mesh.faces  # (once: the property builds every face's list)
        out[quads] = np.abs(diagonal_distance(mesh.vertices, np.array([faces[f] for f in quads]))[0])
    return out
