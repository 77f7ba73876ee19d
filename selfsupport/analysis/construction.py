"""§2.5 of the paper: self-supporting surfaces straight from a convex Airy function.

Given a convex function φ over the plane, a set of top-view points and a load:

1. lift the points onto φ; the **lower convex hull** of the lifted points (``scipy.spatial.
   ConvexHull``) is a convex polyhedral surface Φ whose projection is a *regular
   triangulation* of the points (for φ = ½(x² + y²) the Delaunay triangulation);
2. the creases of Φ are the weights: ``w_ij = (jump of ∇Φ across e_ij) / ‖e'_ij‖`` — the
   length ratio of the polar dual's edge to the primal edge (for the paraboloid: Voronoi
   edge / Delaunay edge). They are ≥ 0 because Φ is convex, and they satisfy the horizontal
   equilibrium (2) at every interior vertex identically (the dual polygons close);
3. the heights solve the Poisson problem ``Δ_φ s = A F`` (eq. 3) with the given heights on
   the supports — one sparse solve; the result is a network in equilibrium to round-off.

Where four or more lifted points are coplanar (co-circular points for the paraboloid) the
hull face is a polygon; qhull splits it into triangles whose diagonals are **zero-force
edges** (their weight is 0 up to round-off and is set to exactly 0; they are listed in
:attr:`Construction.zero_force_edges`).

Loads
-----
``load`` is either a load per unit **top-view** area ``F`` [N/m², negative = down] —
a number, one value per point, or a callable ``F(x, y)`` — turned into nodal loads
``A_i F_i`` with ``A_i`` from :data:`AREA_RULES` (default: the mixed-Voronoi top-view area,
which is the exact Voronoi area on non-obtuse triangulations), or a
:class:`~selfsupport.core.loads.LoadCase` (e.g. :class:`~selfsupport.core.loads.SelfWeight`), whose
nodal loads depend on the 3D geometry: then the Poisson problem is re-solved with loads
from the new heights until they agree to round-off (a fixed point; ``load_rounds``).

Example
-------
>>> from selfsupport.core.shapes import disk_points
>>> net = construct(disk_points(8), "paraboloid", load=-1.0)
>>> net.max_relative_error() < 1e-12, net.min_weight() >= 0
(True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence, Union

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from formulations.equilibrium import Topology, stress_laplacian
from selfsupport.analysis.airy import _J, face_orientation, face_planes_through, freeze_arrays
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import force_sums, stress_sums
from selfsupport.core.geometry import face_areas, vertex_areas
from selfsupport.core.linalg import spd_factor
from selfsupport.core.loads import LoadCase
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network

__all__ = ["PHI_FUNCTIONS", "AREA_RULES", "Construction", "construct", "construct_detailed", "lower_hull",
           "lifting_weights", "phi_function"]

PhiLike = Union[str, Callable[[np.ndarray, np.ndarray], np.ndarray], np.ndarray]

#: Named convex Airy functions φ(x, y) (vectorised); the CLI's ``--phi`` choices.
PHI_FUNCTIONS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    # the paper's example: Delaunay triangulation, Voronoi/Delaunay weights, Δ_φ = Laplacian
    "paraboloid": lambda x, y: 0.5 * (x * x + y * y),
    # anisotropic: stresses four times larger along y than along x
    "elliptic": lambda x, y: 0.5 * x * x + 2.0 * y * y,
    # stresses growing away from the centre (stiffer rim)
    "cosh": lambda x, y: np.cosh(x) + np.cosh(y),
    # ½|x|² + ¼|x|⁴: convex, growing faster than the paraboloid
    "quartic": lambda x, y: 0.5 * (x * x + y * y) + 0.25 * (x * x + y * y) ** 2,
}


def _voronoi_areas(mesh: PolyMesh) -> np.ndarray:
    return vertex_areas(mesh, np.c_[mesh.vertices[:, :2], np.zeros(mesh.n_vertices)])


def _barycentric_areas(mesh: PolyMesh) -> np.ndarray:
    v = np.c_[mesh.vertices[:, :2], np.zeros(mesh.n_vertices)]

    fa = face_areas(mesh, v)
    face_of, _, _ = mesh.corner_data
    return np.bincount(mesh.face_vertices, weights=(fa / mesh.face_sizes)[face_of], minlength=mesh.n_vertices)


#: Top-view vertex areas ``A_i`` that turn a load per unit area into nodal loads.
AREA_RULES: dict[str, Callable[[PolyMesh], np.ndarray]] = {
    "voronoi": _voronoi_areas,  # mixed Voronoi (Meyer et al.) of the top view
    "barycentric": _barycentric_areas,  # a third of each incident triangle
}


@dataclass(frozen=True, eq=False)
class Construction:
    """Outcome of the §2.5 construction."""

    network: Network
    phi: np.ndarray  # φ at the points (the Airy surface's vertex heights)
    face_gradients: np.ndarray  # (F, 2): ∇Φ per triangle — the reciprocal diagram's vertices
    zero_force_edges: np.ndarray  # mesh edge indices of diagonals of coplanar hull faces (weight 0)
    areas: np.ndarray  # top-view vertex areas A_i used for per-area loads (NaN for LoadCase loads)
    load_rounds: int  # Poisson solves (1 unless the load depends on the geometry)
    load_change: float  # last change of the nodal loads relative to the total load
    points_used: np.ndarray  # input point of each network vertex (all of them unless holes drop some)

    def __post_init__(self) -> None:
        freeze_arrays(self)


def phi_function(phi: PhiLike, points: np.ndarray) -> np.ndarray:
    """Evaluate ``phi`` (a name in :data:`PHI_FUNCTIONS`, a callable ``φ(x, y)`` or samples)
    at the points."""
    if isinstance(phi, str):
        try:
            phi = PHI_FUNCTIONS[phi]
        except KeyError:
            raise InputError(f"unknown Airy function {phi!r}; choose one of {', '.join(PHI_FUNCTIONS)} "
                             "or pass a callable / sampled values") from None
    if callable(phi):
        vals = np.asarray(phi(points[:, 0], points[:, 1]), float)
    else:
        vals = np.asarray(phi, float)
    if vals.shape != (len(points),):
        raise InputError(f"φ gives {vals.shape} values for {len(points)} points; give one value per point")
    if not np.all(np.isfinite(vals)):
        raise InputError(f"φ is not finite at point {int(np.argmin(np.isfinite(vals)))}")
    return vals


def lower_hull(points: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Regular triangulation of ``points`` weighted by ``values``: the projection of the lower
    convex hull of ``(x, y, value)``.

    Returns
    -------
    triangles
        ``(t, 3)`` vertex indices, counter-clockwise in the plane.
    unused
        Points that are not vertices of the lower hull (φ above the hull there: not convex,
        or duplicate points).
    """

    pts = np.c_[points, values]
    span = np.ptp(pts, axis=0)
    if np.any(span[:2] == 0):
        raise InputError("the top-view points are collinear; a triangulation needs a 2D point set")
    # qhull works best on well-scaled data; hull faces are invariant under axis scaling
    scaled = (pts - pts.min(axis=0)) / np.where(span > 0, span, 1.0)
    try:
        hull = ConvexHull(scaled, qhull_options="Qt Qbb Qc")
    except QhullError as e:
        raise InputError(f"qhull could not build the lower convex hull ({str(e).splitlines()[0]}); "
                         "check for duplicate or degenerate points") from None
    lower = hull.equations[:, 2] < -1e-12
    tri = hull.simplices[lower].astype(np.int64)
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    cr = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    tri = tri[np.abs(cr) > 1e-14 * float(np.max(np.abs(cr)))]  # sliver facets of vertical hull faces
    cr = cr[np.abs(cr) > 1e-14 * float(np.max(np.abs(cr)))]
    tri[cr < 0] = tri[cr < 0][:, [0, 2, 1]]
    used = np.zeros(len(points), dtype=bool)
    used[tri.ravel()] = True
    return tri, np.flatnonzero(~used)


def lifting_weights(mesh: PolyMesh, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weights of the Airy surface through ``(x_i, y_i, values_i)`` on a top-view mesh.

    ``w_e = (∇Φ_L − ∇Φ_R) · σ J e' / ‖e'‖²`` on interior edges (0 on the boundary), with the
    face gradients of the planes through each face's values (least squares for polygons).
    By construction the weights are in horizontal equilibrium at every interior vertex.

    Returns ``(weights (m,), face_gradients (F, 2))``.
    """
    xy = mesh.vertices[:, :2] - mesh.vertices[:, :2].mean(axis=0)
    sigma, _ = face_orientation(mesh, xy)
    g, _, _ = face_planes_through(mesh, xy, np.asarray(values, float))
    e, ef = mesh.edges, mesh.edge_faces
    interior = (ef >= 0).all(axis=1)
    ev = xy[e[:, 1]] - xy[e[:, 0]]
    w = np.zeros(mesh.n_edges)
    jump = g[ef[interior, 0]] - g[ef[interior, 1]]
    w[interior] = (jump * (sigma * _J(ev[interior]))).sum(axis=1) / (ev[interior] ** 2).sum(axis=1)
    return w, g


def _per_point(value, points: np.ndarray, what: str) -> np.ndarray:
    if callable(value) and not isinstance(value, LoadCase):
        out = np.asarray(value(points[:, 0], points[:, 1]), float)
    else:
        out = np.asarray(value, float)
    out = np.broadcast_to(out, (len(points),)).astype(float) if out.ndim == 0 else out
    if out.shape != (len(points),) or not np.all(np.isfinite(out)):
        raise InputError(f"{what} must be a finite number, one per point ({len(points)}) or a callable f(x, y)")
    return out


def restore_horizontal_equilibrium(xy: np.ndarray, edges: np.ndarray, w: np.ndarray, free: np.ndarray,
                                   tol: float = 1e-17, metric: np.ndarray | None = None) -> np.ndarray:
    """The smallest change of the non-zero weights that puts them in horizontal equilibrium (2).

    The minimum-norm correction ``δw = −D Aᵀ (A D Aᵀ)⁻¹ A w`` (``A`` the horizontal rows of (2) at
    free vertices, restricted to edges that carry force; ``D = diag(metric)``, default I: the
    change minimises ``Σ δw_e² / metric_e``; one refinement step). Here it removes round-off:
    weights from creases inherit the precision of the φ values, ``eps |φ|``, which on steep or
    irregular inputs leaves horizontal residuals of ~1e-10 of the loads, and ``|δw|`` is of the
    same tiny size, so signs and zero-force edges are kept. The multilevel prolongation
    (:mod:`selfsupport.methods.prolong`) uses it on weights that are only near equilibrium, with
    ``metric = w²`` (relative changes; the caller clips what leaves the bounds).
    """
    n = len(xy)
    hsum = stress_sums(edges=edges, weights=w, values=xy)
    mag = force_sums(edges=edges, weights=w, values=xy)
    if not np.any(free) or np.all(np.linalg.norm(hsum[free], axis=1) <= tol * np.maximum(mag[free], 1e-300)):
        return w

    ev = xy[edges[:, 1]] - xy[edges[:, 0]]
    cols = np.flatnonzero(w != 0)
    fi = -np.ones(n, dtype=np.int64)
    fi[free] = np.arange(int(free.sum()))
    rows, cc, vals = [], [], []
    for end, sign in ((0, 1.0), (1, -1.0)):
        f = fi[edges[cols, end]]
        ok = f >= 0
        for c in range(2):
            rows.append(2 * f[ok] + c)
            cc.append(np.flatnonzero(ok))
            vals.append(sign * ev[cols[ok], c])
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cc))),
                      shape=(2 * int(free.sum()), len(cols)))
    # (a free vertex with collinear edges makes A Aᵀ singular; spd_factor then factors it with a
    # tiny diagonal shift, and Aᵀ removes the null-space part of the multipliers again)
    DAt = (A.T if metric is None else sp.diags(np.asarray(metric, float)[cols]) @ A.T).tocsc()
    lu = spd_factor(A @ DAt)
    r = A @ w[cols]
    lam = lu.solve(r)
    lam += lu.solve(r - A @ (DAt @ lam))
    out = w.copy()
    out[cols] -= DAt @ lam
    return out


def _inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test, vectorised over points."""
    poly = np.asarray(polygon, float).reshape(-1, 2)
    x, y = points[:, 0], points[:, 1]
    inside = np.zeros(len(points), dtype=bool)
    for (x0, y0), (x1, y1) in zip(poly, np.roll(poly, -1, axis=0)):
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < xc)
    return inside


def _mask(spec, n: int, what: str) -> np.ndarray:
    a = np.asarray(spec)
    if a.dtype == bool:
        if a.shape != (n,):
            raise InputError(f"{what} mask has {a.shape} entries for {n} points")
        return a.copy()
    idx = a.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise InputError(f"{what} index outside 0..{n - 1}")
    m = np.zeros(n, dtype=bool)
    m[idx] = True
    return m


def _ungrounded(edges: np.ndarray, w: np.ndarray, supports: np.ndarray) -> np.ndarray:
    """Free vertices that reach no support through edges of positive weight. −K_ff is SPD
    exactly when there are none (checked before factoring: spd_factor would factor a singular
    matrix with a tiny shift, not fail).

    >>> _ungrounded(np.array([[0, 1], [1, 2], [2, 3]]), np.array([1.0, 0.0, 1.0]), np.array([True, False, False, False]))
    array([2, 3])
    """
    n = supports.size
    pos = w > 0
    graph = sp.csr_matrix((np.ones(int(pos.sum())), (edges[pos, 0], edges[pos, 1])), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    grounded = np.zeros(comp.max() + 1, dtype=bool)
    grounded[comp[supports]] = True
    return np.flatnonzero(~supports & ~grounded[comp])


def construct_detailed(points: np.ndarray, phi: PhiLike, *, load: float | np.ndarray | Callable | LoadCase = -1.0,
                       boundary_heights: float | np.ndarray | Callable = 0.0, supports: np.ndarray | None = None,
                       holes: Sequence[np.ndarray] = (), support_holes: bool = False, areas: str = "voronoi",
                       zero_tol: float = 1e-9, max_load_rounds: int = 200, load_tol: float = 1e-15,
                       rise: float | None = None) -> Construction:
    """The §2.5 construction with everything it found (see the module docstring).

    Parameters
    ----------
    points
        ``(n, 2)`` top-view points (extra columns are ignored).
    phi
        The convex Airy function: a name in :data:`PHI_FUNCTIONS`, a callable ``φ(x, y)``, or
        one sampled value per point.
    load
        Load per unit top-view area ``F`` [N/m², negative = down] (number, array or callable),
        or a :class:`~selfsupport.core.loads.LoadCase` (nodal loads from the 3D geometry, iterated).
    boundary_heights
        Heights of the supports (number, one per point, or callable ``h(x, y)``).
    supports
        Extra supports (boolean mask or indices of ``points``); the outer boundary of the
        triangulation is always supported (its vertices cannot balance horizontal forces).
    holes
        Polygons (``(k, 2)`` arrays); triangles whose centroid lies inside one are removed
        and points left without a triangle are dropped (``points_used`` maps the network's
        vertices back to ``points``). A hole's rim can stand **free** only where the removed
        part of Φ is one plane (e.g. a hole whose rim points are co-circular, for the
        paraboloid): the removed edges then carry no force. Otherwise set ``support_holes``.
    support_holes
        Support the rims of the holes.
    rise
        Scale φ (and so all weights) so that the highest free vertex stands ``rise`` above the
        highest support: heights go as 1/scale for a given load, so one rescaling is exact for
        per-area loads; geometry-dependent loads take a few rounds. ``None``: φ as given.
    areas
        Rule for the top-view vertex areas ``A_i`` (:data:`AREA_RULES`).
    zero_tol
        Weights below ``zero_tol × max w`` are diagonals of coplanar hull faces: set to 0.
    max_load_rounds, load_tol
        Fixed-point iteration for geometry-dependent loads: stop when the nodal loads change
        by less than ``load_tol`` × total load.

    Raises
    ------
    InputError
        Bad input, φ not convex at some points (they are not vertices of the lower hull), a
        free hole rim that cannot be balanced, or a free vertex no positive weight holds.
    """
    if rise is not None:
        rise = float(rise)
        if not (math.isfinite(rise) and rise > 0):
            raise InputError(f"rise must be a positive number, got {rise!r}")
        vals0 = phi_function(phi, np.asarray(points, float)[:, :2])
        kw = dict(load=load, boundary_heights=boundary_heights, supports=supports, holes=holes,
                  support_holes=support_holes, areas=areas, zero_tol=zero_tol, max_load_rounds=max_load_rounds,
                  load_tol=load_tol)
        scale, c = 1.0, None
        if isinstance(load, LoadCase) and load.depends_on_geometry:
            # first scale with the loads of the flat top view (as fixed per-area loads): starting
            # the geometric iteration from an arbitrarily tall surface could make it diverge
            c0 = construct_detailed(points, vals0, **{**kw, "load": -1.0})
            m0 = c0.network.mesh
            flat_nodal = np.asarray(load.nodal(m0, np.c_[m0.vertices[:, :2], np.zeros(m0.n_vertices)]), float)
            proxy = np.zeros(len(vals0))
            proxy[c0.points_used] = flat_nodal / c0.areas
            c1 = construct_detailed(points, vals0, **{**kw, "load": proxy})
            z = c1.network.vertices[:, 2]
            sup1 = c1.network.supports
            now = float(z[~sup1].max() - z[sup1].max()) if (~sup1).any() else 0.0
            if now > 0:
                scale = now / rise
        slope, last = -1.0, None  # d log(rise) / d log(scale): exactly −1 for fixed loads
        for _ in range(30):
            c = construct_detailed(points, vals0 * scale, **kw)
            z = c.network.vertices[:, 2]
            now = float(z[~c.network.supports].max() - z[c.network.supports].max()) if (~c.network.supports).any() else 0.0
            if now <= 0:
                raise InputError("the construction gives no free vertex above the supports (the load points up?); "
                                 "cannot scale it to a rise")
            if abs(now - rise) <= 1e-12 * rise:
                break
            if last is not None and abs(math.log(scale) - last[0]) > 1e-14:
                # secant in log-log: geometry-dependent loads make the rise a little steeper than 1/scale
                slope = min((math.log(now) - last[1]) / (math.log(scale) - last[0]), -0.1)
            last = (math.log(scale), math.log(now))
            scale *= math.exp((math.log(rise) - math.log(now)) / slope)
        return c
    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] < 2 or len(pts) < 3:
        raise InputError(f"points must be an (n, 2) array with n >= 3, got shape {pts.shape}")
    pts = pts[:, :2]
    if not np.all(np.isfinite(pts)):
        raise InputError(f"point {int(np.argmin(np.isfinite(pts).all(axis=1)))} is not finite")
    n0 = len(pts)
    vals = phi_function(phi, pts)
    heights = _per_point(boundary_heights, pts, "boundary_heights")
    user_sup = np.zeros(n0, dtype=bool) if supports is None else _mask(supports, n0, "supports")
    F_in = None if isinstance(load, LoadCase) else _per_point(load, pts, "load")
    tri, unused = lower_hull(pts, vals)
    if unused.size:
        raise InputError(f"{unused.size} point(s) are not vertices of the lower convex hull of the lifted points "
                         f"(first: point {int(unused[0])}): φ is not strictly convex there, or points repeat; "
                         "remove them or use a strictly convex φ")
    full = PolyMesh(np.c_[pts, np.zeros(n0)], tri.ravel(), np.arange(0, 3 * len(tri) + 1, 3))
    w_full, grads = lifting_weights(full, vals)
    wmax = float(w_full.max()) if w_full.size else 0.0
    if wmax <= 0:
        raise InputError("φ is affine on the points: all weights vanish; use a strictly convex φ")
    if np.any(w_full < -zero_tol * wmax):
        k = int(np.argmin(w_full))
        raise InputError(f"edge {tuple(full.edges[k])} has negative weight {w_full[k]:.3g}: the lower hull is not "
                         "convex there (round-off on nearly coplanar points?)")
    w_full[np.abs(w_full) <= zero_tol * wmax] = 0.0

    keep_pts = np.arange(n0)
    flat, w = full, w_full
    if len(holes):
        cen = pts[tri].mean(axis=1)
        drop = np.zeros(len(tri), dtype=bool)
        for hole in holes:
            drop |= _inside(cen, hole)
        tri, grads = tri[~drop], grads[~drop]
        used = np.zeros(n0, dtype=bool)
        used[tri.ravel()] = True
        keep_pts = np.flatnonzero(used)
        new_id = -np.ones(n0, dtype=np.int64)
        new_id[keep_pts] = np.arange(len(keep_pts))
        flat = PolyMesh(np.c_[pts[keep_pts], np.zeros(len(keep_pts))], new_id[tri].ravel(),
                        np.arange(0, 3 * len(tri) + 1, 3)).validate()
        # carry the weights over by vertex pair
        fe = full.edges
        key_full = new_id[fe[:, 0]] * (n0 + 1) + new_id[fe[:, 1]]
        ok = (new_id[fe[:, 0]] >= 0) & (new_id[fe[:, 1]] >= 0)
        kf, wf = key_full[ok], w_full[ok]
        order = np.argsort(kf)
        ne = flat.edges
        # new_id is increasing, so every kept edge keeps its (lo, hi) order
        w = wf[order][np.searchsorted(kf[order], ne[:, 0] * (n0 + 1) + ne[:, 1])]
    n = flat.n_vertices
    P = pts[keep_pts]
    zero = np.flatnonzero((flat.edge_faces.min(axis=1) >= 0) & (w == 0.0))

    # supports: the outer boundary loop (largest top-view area), the hole rims if asked, the user's
    sup = user_sup[keep_pts].copy()
    loops = flat.boundary_loops
    areas_l = [abs(float(np.sum(P[lp, 0] * np.roll(P[lp, 1], -1) - P[lp, 1] * np.roll(P[lp, 0], -1)))) for lp in loops]
    outer = int(np.argmax(areas_l))
    for k, lp in enumerate(loops):
        if k == outer or support_holes:
            sup[lp] = True
    free = ~sup
    e = flat.edges
    hsum = stress_sums(edges=e, weights=w, values=P[:, :2])
    mag = force_sums(edges=e, weights=w, values=P[:, :2])
    bad = free & (np.linalg.norm(hsum, axis=1) > 1e-9 * np.maximum(mag, 1e-300))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"point {int(keep_pts[k])} on a hole's rim cannot stand free: φ is not one plane over the "
                         "hole, so the removed edges carried force; support the rims (support_holes=True) or make "
                         "the rim points lie where φ is affine (co-circular rims for the paraboloid)")
    w[sup[e[:, 0]] & sup[e[:, 1]]] = 0.0  # the network convention: no unknown between two supports
    w = restore_horizontal_equilibrium(P, e, w, free)
    heights = heights[keep_pts]

    top = Topology.build(n, e, sup)
    Lw = stress_laplacian(top, w)
    Kff = Lw[free][:, free].tocsc()
    Kfs = Lw[free][:, sup].tocsr()
    held = np.bincount(e.ravel(), weights=np.repeat((w > 0).astype(float), 2), minlength=n)
    if np.any(free & (held == 0)):
        k = int(np.flatnonzero(free & (held == 0))[0])
        raise InputError(f"free point {int(keep_pts[k])} has no edge with positive weight (φ is flat around it); "
                         "use a strictly convex φ or make it a support")
    ungrounded = _ungrounded(e, w, sup)
    if ungrounded.size:
        raise InputError(f"free point {int(keep_pts[ungrounded[0]])} is not connected to a support through positive "
                         "weights, so its height is undetermined; use a strictly convex φ or add supports")
    lu = spd_factor(-Kff)  # −K_ff is SPD (positive weights, every free point grounded)

    def solve_heights(nodal: np.ndarray) -> np.ndarray:
        s = heights.copy()
        rhs = nodal[free] - Kfs @ heights[sup]
        x = -lu.solve(rhs)
        x -= lu.solve(rhs - Kff @ x)  # iterative refinement: equilibrium to round-off
        s[free] = x
        return s

    if isinstance(load, LoadCase):
        A = np.full(n, np.nan)
        s = heights.copy()
        s[free] = float(np.mean(heights[sup]))
        mesh3 = flat.with_vertices(np.c_[P, s])
        nodal = np.asarray(load.nodal(mesh3, mesh3.vertices), float)
        rounds, change = 0, np.inf
        total = max(float(np.abs(nodal).sum()), 1e-300)
        while rounds < max_load_rounds:
            s = solve_heights(nodal)
            rounds += 1
            new = np.asarray(load.nodal(mesh3, np.c_[P, s]), float)
            change = float(np.abs(new - nodal).max()) / total
            nodal = new
            if not math.isfinite(change) or not np.all(np.isfinite(s)):
                break
            if change <= load_tol or not load.depends_on_geometry:
                break
        if not (math.isfinite(change) and change <= 1e-9):
            raise InputError(f"the geometry-dependent loads did not settle (last change {change:.2e} of the total "
                             f"after {rounds} rounds): the surface is too steep for this φ and load; scale φ up "
                             "(or use rise=) or lower the load")
    else:
        try:
            A = AREA_RULES[areas](flat)
        except KeyError:
            raise InputError(f"unknown area rule {areas!r}; choose one of {', '.join(AREA_RULES)}") from None
        nodal = A * F_in[keep_pts]
        s = solve_heights(nodal)
        rounds, change = 1, 0.0
    net = Network(mesh=flat.with_vertices(np.c_[P, s]), weights=w, loads=nodal, supports=sup)
    return Construction(network=net, phi=vals[keep_pts], face_gradients=grads, zero_force_edges=zero, areas=A,
                        load_rounds=rounds, load_change=float(change) if math.isfinite(change) else float("nan"),
                        points_used=keep_pts)


def construct(points: np.ndarray, phi: PhiLike, **kwargs) -> Network:
    """A self-supporting network from a convex Airy function (§2.5); see
    :func:`construct_detailed` for the parameters and for what else the construction finds."""
    return construct_detailed(points, phi, **kwargs).network
