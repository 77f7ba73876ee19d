"""Scene-level checks run before a solve: what makes an input unusable, and what is unusual.

A design tool is fed meshes from modelling software. :func:`validate_scene` looks at a
:class:`~selfsupport.core.scene.Scene` once, up front, and

* **raises** a named exception (:class:`~selfsupport.core.errors.MeshError`,
  :class:`~selfsupport.core.errors.SupportError`, :class:`~selfsupport.core.errors.InputError`) for a
  problem no method can get past — the message says what is wrong, where, and what to do;
* **returns** :class:`Issue` warnings for inputs that are legal but deserve a word: the solve
  runs, the warning says what the result will look like and how to avoid it.

The checks live in :data:`CHECKS` (code -> function ``(scene, ctx) -> list[Issue]``); they run in
that order and stop at the first check that finds an error, because the later ones assume a
usable mesh. What each code means:

Errors (raised)
    ``mesh``          :meth:`PolyMesh.problems`: no faces, NaN/inf, index out of range,
                      non-manifold edge or vertex, inconsistent orientation; vertices that belong
                      to no face and are not supports.
    ``scale``         coordinates beyond ±1e100 m or all vertices in one point: areas and loads
                      would overflow or vanish. Below that the methods are scale-free (scenes
                      1e-6 m and 1e6 m across are tested).
    ``supports``      no supports, every vertex a support, a component without supports
                      (:meth:`Scene.check_supports`).
    ``extra_loads``   NaN/inf in the scene's extra masses or point loads.
    ``top_view``      the surface faces down on at least :data:`FOLD_FRACTION` of its top view:
                      not a roof over the ground plane, almost always a wrong vertical axis.

Every geometric test works on coordinates centred on the bounding box and divided by its
diagonal, so a scene 1e12 m from the origin is judged like the same scene at the origin.

Warnings (returned)
    ``isolated_vertices``   supports that belong to no face (the original tool's .sss files have
                            them): ignored by the solve (no edges, no load), kept in the output
                            so that vertex indices stay those of the input.
    ``duplicate_vertices``  vertices closer than :data:`COINCIDENT` × bbox diagonal (a crack, or a
                            zero-length edge). The methods cope (they move them apart) but the
                            mesh was probably meant to be welded.
    ``zero_area_faces``     faces of (almost) zero area; they carry no load and their edges add
                            weights that nothing determines.
    ``non_planar_faces``    polygons whose corners are off their best-fit plane; the network lives
                            on the edges and does not care, the loads use the centroid-fan area.
    ``overhang``            faces facing down in the top view, or a top view that covers itself
                            (layers); the staggered and IPOPT solves work in 3D, but the Airy stress
                            surface, the reciprocal diagram and the §2.5 construction need a height field.
    ``cannot_stand_as_is``  free vertices no compressive network can balance where they are (not
                            higher than any neighbour, or all neighbours on one side in the top view):
                            the solve has to move them, or they need a support.
    ``precision``           coordinates far from the origin compared with the object's size.

Example
-------
>>> from selfsupport.core.shapes import make_shape
>>> [i.code for i in validate_scene(make_shape("dome", n_vertices=100))]
[]
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from formulations.equilibrium import Topology, weight_matrix
from selfsupport.core.errors import InfeasibleDesign, InputError, MeshError, SelfSupportError, SupportError
from selfsupport.core.geometry import bbox_diagonal, face_areas, near_pairs
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene
from selfsupport.methods.weightfit_backends import make_backend

__all__ = ["Issue", "CHECKS", "ISSUE_CODES", "validate_scene", "scene_issues", "top_view_areas", "top_view_winding",
           "unbalanceable_vertices", "require_rise", "validate_problem", "COINCIDENT", "FOLD_FRACTION", "COORD_LIMIT", "FLAT"]

#: Vertices closer than this fraction of the bounding-box diagonal coincide.
COINCIDENT = 1e-10
#: Faces with less than this fraction of the median face area have zero area.
ZERO_AREA = 1e-10
#: Polygon corners further than this fraction of the face's size from its best-fit plane make
#: it non-planar (well above the 1e-15 round-off of CAD output, well below any visible warp).
NON_PLANAR = 1e-8
#: Share of the top-view area facing down from which a surface is no roof (error ``top_view``).
#: A masonry surface carrying its weight in compression faces up almost everywhere: the paper's
#: most overhanging scene (structural, Fig. 16) faces down on 1% of its top view, a mesh read
#: with the wrong vertical axis on ~50% (its front and back halves cancel).
FOLD_FRACTION = 0.25
#: Largest coordinate magnitude [m]: squares of lengths (areas) must stay far from overflow.
COORD_LIMIT = 1e100
#: Distance from the best-fit plane, as a fraction of the bounding-box diagonal, below which every
#: vertex lies in one plane: a flat reference (see :func:`require_rise`).
FLAT = 1e-9
#: |z-component| of a flat reference's unit normal below which its plane is vertical (it then
#: carries its load in the plane, and :func:`require_rise` does not apply).
VERTICAL = 1e-6
#: Size / coordinate magnitude below which too few significant digits describe the shape.
PRECISION_LIMIT = 1e-8
#: Top-view angular gap (radians) from which a vertex's neighbours all lie on one side.
HALF_TURN_TOL = 1e-9
#: At most this many indices are listed in a message.
LIST_MAX = 8


@dataclass(frozen=True)
class Issue:
    """One finding of :func:`scene_issues`.

    Attributes
    ----------
    code
        Key of :data:`CHECKS` that found it.
    severity
        ``"error"`` (the input is unusable; :func:`validate_scene` raises ``error``) or ``"warning"``.
    message
        What is wrong, where, and what to do.
    vertices, faces
        The vertices / faces concerned (all of them, not only those named in the message).
    error
        The exception class raised for an error; ``None`` for a warning.
    """

    code: str
    severity: str
    message: str
    vertices: tuple[int, ...] = ()
    faces: tuple[int, ...] = ()
    error: type[SelfSupportError] | None = field(default=None, compare=False)

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON types (for the network file's ``parameters``)."""
        return {"code": self.code, "severity": self.severity, "message": self.message,
                "vertices": list(self.vertices), "faces": list(self.faces)}

    def raise_(self) -> None:
        """Raise the error this issue stands for (only for ``severity == "error"``)."""
        raise (self.error or InputError)(self.message)


def _error(code: str, message: str, cls: type[SelfSupportError], **kw: Any) -> Issue:
    return Issue(code, "error", message, error=cls, **kw)


def _warning(code: str, message: str, **kw: Any) -> Issue:
    return Issue(code, "warning", message, **kw)


def load_issues(loads: Any, supports: np.ndarray) -> list[Issue]:
    """Warnings about the loads of a problem (``loads``: its
    :class:`~formulations.loadcases.LoadCases`): a point load or extra mass on a support, which
    goes straight into the ground and changes nothing of the network.

    >>> from formulations.loadcases import LoadCases
    >>> from selfsupport.core.loads import PointLoad, SelfWeight
    >>> f = np.zeros(4); f[[0, 2]] = -500.0
    >>> [i.vertices for i in load_issues(LoadCases.of(SelfWeight() + PointLoad(f)), np.array([1, 0, 0, 1], bool))]
    [(0,)]
    """
    on = np.unique(np.concatenate([np.asarray(c.concentrated_at(), np.int64) for c in loads.models]))
    on = on[np.asarray(supports, bool)[on]]
    if not on.size:
        return []
    return [_warning("loads_on_supports", f"point loads or extra masses on supports ({_few(on)}) go straight into "
                     "the ground and change nothing of the network; load free vertices to load the shell",
                     vertices=tuple(int(v) for v in on))]


def _few(idx: np.ndarray) -> str:
    idx = np.asarray(idx).ravel()
    head = ", ".join(str(int(i)) for i in idx[:LIST_MAX])
    return head + (f", ... ({idx.size} in all)" if idx.size > LIST_MAX else "")


# ------------------------------------------------------------------------- geometry
def top_view_areas(mesh: PolyMesh, vertices: np.ndarray | None = None) -> np.ndarray:
    """Signed area of each face's projection onto the ground plane (positive: counter-clockwise
    seen from above, i.e. the face's normal points up). Shoelace formula, exact for polygons."""
    v = mesh.vertices if vertices is None else np.asarray(vertices, float)
    face_of, nxt, _ = mesh.corner_data
    a, b = v[mesh.face_vertices], v[nxt]
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    out = np.zeros(mesh.n_faces)
    np.add.at(out, face_of, 0.5 * cross)
    return out


def _face_inner_points(mesh: PolyMesh, v: np.ndarray) -> np.ndarray:
    """A top-view point inside each face: the centroid of its largest centroid-fan triangle
    (inside the polygon whenever the polygon is star-shaped about its centroid, e.g. convex)."""
    face_of, nxt, _ = mesh.corner_data
    sizes = mesh.face_sizes
    c = np.zeros((mesh.n_faces, 2))
    np.add.at(c, face_of, v[mesh.face_vertices, :2])
    c /= sizes[:, None]
    p, q = v[mesh.face_vertices, :2], v[nxt, :2]
    cf = c[face_of]
    area = np.abs((p[:, 0] - cf[:, 0]) * (q[:, 1] - cf[:, 1]) - (p[:, 1] - cf[:, 1]) * (q[:, 0] - cf[:, 0]))
    # the corner with the largest fan triangle in each face (the first one of equal largest):
    # corners are stored face by face, so a segmented max finds it in O(corners) — the
    # lexsort it replaces (same corners) took 0.15 s at 200k vertices
    if np.isfinite(area).all():
        top = np.maximum.reduceat(area, mesh.face_offsets[:-1])
        cand = np.flatnonzero(area == top[face_of])
        first = cand[np.r_[True, face_of[cand[1:]] != face_of[cand[:-1]]]]
    else:  # (NaN would match no maximum; the sort puts it last)
        first = np.lexsort((-area, face_of))[mesh.face_offsets[:-1]]
    return (cf[first] + p[first] + q[first]) / 3.0


def top_view_winding(mesh: PolyMesh, points: np.ndarray, vertices: np.ndarray | None = None,
                     chunk: int = 2_000_000) -> np.ndarray:
    """Winding number of the mesh's oriented boundary around each top-view point.

    For a consistently oriented surface this is, at each point, the number of faces above it
    facing up minus the number facing down (Stokes): 1 on a height field, 2 or more where the
    top view covers itself. Sunday's crossing rule over the boundary half-edges, evaluated as a
    sweep in y so the cost is (points × boundary edges crossing a horizontal line), not
    points × boundary edges.
    """
    v = mesh.vertices if vertices is None else np.asarray(vertices, float)
    pts = np.asarray(points, float).reshape(-1, 2)
    face_of, nxt, _ = mesh.corner_data
    on_b = mesh.boundary_edge_mask[mesh.halfedge_data["halfedge_edge"]]
    A, B = v[mesh.face_vertices[on_b], :2], v[nxt[on_b], :2]
    order = np.argsort(pts[:, 1], kind="stable")
    ys = pts[order, 1]
    lo = np.searchsorted(ys, np.minimum(A[:, 1], B[:, 1]), side="left")
    hi = np.searchsorted(ys, np.maximum(A[:, 1], B[:, 1]), side="left")
    counts = hi - lo
    wind = np.zeros(len(pts), dtype=np.int64)
    ends = np.cumsum(counts)
    start = 0
    while start < len(A):
        # edges [start, stop) whose point pairs fit into one chunk (at least one edge)
        stop = max(start + 1, int(np.searchsorted(ends, (ends[start - 1] if start else 0) + chunk, side="right")))
        c = counts[start:stop]
        e = np.repeat(np.arange(start, stop), c)
        offs = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        k = order[lo[e] + offs]
        a, b, p = A[e], B[e], pts[k]
        left = (b[:, 0] - a[:, 0]) * (p[:, 1] - a[:, 1]) - (p[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        up = a[:, 1] < b[:, 1]
        contrib = np.where(up & (left > 0), 1, 0) - np.where(~up & (left < 0), 1, 0)
        np.add.at(wind, k, contrib)
        start = stop
    return wind


def unbalanceable_vertices(scene: Scene, vertices: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Free vertices that no compressive network (all weights > 0) can balance where they are.

    Returns two index arrays:

    * ``low``: not higher than any neighbour. Equation (3), Σ_j w_ij (z_j − z_i) = A_i F_i < 0,
      needs a lower neighbour when every w_ij > 0.
    * ``one_sided``: the top-view directions to the neighbours (vertical edges left out) leave an
      angular gap of at least π, so they lie in a closed half-plane and equation (2),
      Σ_j w_ij (x_j − x_i) = 0, has no solution with every w_ij > 0 — a free vertex on a straight
      or outward-bent free boundary, a free corner.
    """
    mesh = scene.mesh
    v = mesh.vertices if vertices is None else np.asarray(vertices, float)
    n = mesh.n_vertices
    e = mesh.edges
    i = np.r_[e[:, 0], e[:, 1]]
    j = np.r_[e[:, 1], e[:, 0]]
    free = ~scene.supports
    zmin = np.full(n, np.inf)
    np.minimum.at(zmin, i, v[j, 2])
    low = np.flatnonzero(free & (v[:, 2] <= zmin))

    d = v[j, :2] - v[i, :2]
    diag = bbox_diagonal(v)
    horiz = np.hypot(d[:, 0], d[:, 1]) > COINCIDENT * diag
    i, d = i[horiz], d[horiz]
    ang = np.arctan2(d[:, 1], d[:, 0])
    has = np.zeros(n, bool)
    has[i] = True
    gap = np.zeros(n)
    if ang.size:
        gap = _largest_angular_gap(i, ang, n)
    one_sided = np.flatnonzero(free & has & (gap >= np.pi - HALF_TURN_TOL))
    return low, one_sided


def require_top_view_balance(scene: Scene, vertices: np.ndarray) -> None:
    """Raise :class:`~selfsupport.core.errors.InfeasibleDesign` when the top view is to stay as it is
    (:class:`~formulations.FixedTopView`) and a free vertex has all its neighbours on one side of
    it there: equation (2) then has no solution with every weight ≥ ε > 0, whatever the heights
    (the ``one_sided`` vertices of :func:`unbalanceable_vertices`). Without this the methods
    iterate to their limits (a vault with free edges: 30 iterations, then "stalled" at 0.1).

    >>> from selfsupport.core.shapes import make_shape
    >>> dome = make_shape("dome", n_vertices=100)  # supported along its whole rim: balanced
    >>> require_top_view_balance(dome, dome.mesh.vertices)
    """
    one_sided = unbalanceable_vertices(scene, vertices)[1]
    if one_sided.size:

        raise InfeasibleDesign(
            f"with the top view fixed, {one_sided.size} free vertices have all their neighbours on one side of them "
            f"in the top view (a free straight or convex boundary, a free corner: {_few(one_sided)}), so no "
            "compressive network balances them horizontally; support them, or let the top view move (drop "
            "--fixed-top-view)")


def _largest_angular_gap(i: np.ndarray, ang: np.ndarray, n: int) -> np.ndarray:
    """Per vertex, the largest gap between the directions ``ang`` (radians in [-π, π]) of the
    half-edges leaving it (``i``), the wrap-around gap included; 0 where none leaves.

    The directions are sorted within each vertex's row of a padded (n, max degree) array: one
    stable grouping by vertex, O(half-edges), and a short sort per row — a lexsort over all
    half-edges took 0.16-0.3 s at 200k vertices, this 0.05 s. Any order of equal directions
    gives the same gaps, so the result is that of the lexsort bit for bit. A vertex of huge
    degree (a fan of thousands of triangles) would make the array large: then the lexsort.
    """
    count = np.bincount(i, minlength=n)
    k = int(count.max())
    if k * n <= 4 * i.size + 1024:
        order = np.argsort(i, kind="stable")
        rows = i[order]
        first = np.cumsum(count) - count
        P = np.full((n, k), np.inf)
        P[rows, np.arange(i.size) - first[rows]] = ang[order]
        P.sort(axis=1)
        with np.errstate(invalid="ignore"):
            inner = P[:, 1:] - P[:, :-1]  # (inf - inf, inf - x past a row's end are masked)
        valid = np.arange(1, k)[None, :] < count[:, None]
        big = np.where(valid, inner, 0.0).max(axis=1, initial=0.0)
        has = count > 0
        wrap = np.zeros(n)
        wrap[has] = 2 * np.pi - (P[has, count[has] - 1] - P[has, 0])
        return np.maximum(big, wrap)
    order = np.lexsort((ang, i))
    i, ang = i[order], ang[order]
    has = np.zeros(n, bool)
    has[i] = True
    starts = np.searchsorted(i, np.arange(n), side="left")
    stops = np.searchsorted(i, np.arange(n), side="right")
    same = i[1:] == i[:-1]
    g = np.where(same, np.diff(ang), 0.0)
    # largest gap between consecutive directions, and the wrap-around gap
    big = np.zeros(n)
    np.maximum.at(big, i[1:][same], g[same])
    wrap = np.zeros(n)
    wrap[has] = 2 * np.pi - (ang[stops[has] - 1] - ang[starts[has]])
    return np.maximum(big, wrap)


# ------------------------------------------------------------------------- checks
@dataclass
class _Context:
    """Quantities several checks share, computed once."""

    scene: Scene
    diag: float = 0.0
    #: the vertices centred on the bounding box and divided by its diagonal (set by the scale
    #: check): every geometric test uses these, so far-off coordinates lose nothing more
    V: np.ndarray | None = None

    #: the faces' areas at :meth:`vertices` (the top-view and zero-area checks both need them)
    _areas: np.ndarray | None = None

    def vertices(self) -> np.ndarray:
        return self.scene.mesh.vertices if self.V is None else self.V

    def face_areas(self) -> np.ndarray:
        if self._areas is None:
            self._areas = face_areas(self.scene.mesh, self.vertices())
        return self._areas


def _check_mesh(scene: Scene, ctx: _Context) -> list[Issue]:
    problems = scene.mesh.problems()
    if problems:
        return [_error("mesh", p + ("" if "; " in p else "; fix the mesh in your modelling tool"), MeshError)
                for p in problems]
    iso = scene.mesh.isolated_vertices
    free = iso[~scene.supports[iso]]
    if free.size:
        return [_error("mesh", f"{free.size} vertices belong to no face and are not supports (vertices {_few(free)}); "
                       "remove them, or pin them (a support that belongs to no face is ignored)", MeshError,
                       vertices=tuple(free.tolist()))]
    if iso.size:
        return [_warning("isolated_vertices", f"{iso.size} vertices belong to no face (vertices {_few(iso)}): "
                         "ignored by the solve (supports with no edges and no load), kept in the output with "
                         "their indices", vertices=tuple(iso.tolist()))]
    return []


def _check_scale(scene: Scene, ctx: _Context) -> list[Issue]:
    v = scene.mesh.vertices
    big = float(np.abs(v).max())
    if big > COORD_LIMIT:
        k = int(np.argmax(np.abs(v).max(axis=1)))
        return [_error("scale", f"vertex {k} has a coordinate of {big:.3g} m, beyond ±{COORD_LIMIT:.0e} m where "
                       "areas and loads overflow; check the units and the file", InputError, vertices=(k,))]
    ctx.diag = bbox_diagonal(v)
    if not ctx.diag > 0:
        return [_error("scale", "all vertices lie in one point; check the units and the file", InputError)]
    ctx.V = (v - 0.5 * (v.min(axis=0) + v.max(axis=0))) / ctx.diag
    out = []
    if ctx.diag < PRECISION_LIMIT * big:
        out.append(_warning("precision", f"the object is {ctx.diag:.3g} m across but {big:.3g} m from the origin: "
                            f"only ~{16 + np.log10(ctx.diag / big):.0f} significant digits describe its shape; "
                            "translate the mesh near the origin"))
    return out


def _check_supports(scene: Scene, ctx: _Context) -> list[Issue]:
    try:
        scene.check_supports()
    except SupportError as e:
        return [_error("supports", str(e), SupportError)]
    return []


def _check_extra_loads(scene: Scene, ctx: _Context) -> list[Issue]:
    out = []
    for name in ("extra_mass", "point_loads"):
        a = getattr(scene, name)
        if a is not None and not np.isfinite(a).all():
            k = np.flatnonzero(~np.isfinite(a))
            out.append(_error("extra_loads", f"{name} of vertices {_few(k)} is NaN or infinite; give finite values",
                              InputError, vertices=tuple(k.tolist())))
    return out


def _check_top_view(scene: Scene, ctx: _Context) -> list[Issue]:
    mesh = scene.mesh
    V = ctx.vertices()
    a = top_view_areas(mesh, V)
    total = float(np.abs(a).sum())
    area3d = float(ctx.face_areas().sum())
    if not total > 1e-12 * area3d:
        return []  # a vertical surface (a wall in one plane): no top view to speak of
    up = 1.0 if a.sum() >= 0 else -1.0
    a = up * a
    down = a < -ZERO_AREA * float(np.median(np.abs(a)))
    frac = float(-a[down].sum()) / total
    if frac >= FOLD_FRACTION:
        f = np.flatnonzero(down)
        return [_error("top_view", f"the surface is not a roof over the ground plane: {100 * frac:.0f}% of its top "
                       f"view faces down (faces {_few(f)}); check the vertical axis (--up z|-z|y|-y|x|-x; the "
                       "paper's files are -y up) or cut the surface into parts that face up", MeshError,
                       faces=tuple(f.tolist()))]
    out = []
    layered = np.zeros(mesh.n_faces, bool)
    if mesh.boundary_edge_mask.any():
        wind = top_view_winding(mesh, _face_inner_points(mesh, V), V) * int(up)
        layered = (wind >= 2) & ~down
    if down.any() or layered.any():
        f = np.flatnonzero(down | layered)
        what = []
        if down.any():
            what.append(f"{int(down.sum())} faces face down ({100 * frac:.1f}% of the top view)")
        if layered.any():
            what.append(f"{int(layered.sum())} faces lie above or below other parts of the surface")
        out.append(_warning("overhang", f"the top view is not one-to-one: {' and '.join(what)} (faces {_few(f)}); "
                            "the solve works in 3D, but the Airy stress surface, the reciprocal diagram and the "
                            "§2.5 construction need a height field", faces=tuple(f.tolist())))
    return out


def _check_duplicates(scene: Scene, ctx: _Context) -> list[Issue]:

    pairs = near_pairs(ctx.vertices(), COINCIDENT * (1.0 if ctx.V is not None else ctx.diag))  # (in order)
    free = ~scene.supports
    pairs = pairs[free[pairs[:, 0]] | free[pairs[:, 1]]]  # two coincident supports hold each other: harmless
    if not len(pairs):
        return []
    a, b = (int(x) for x in pairs[0])
    verts = np.unique(pairs)
    return [_warning("duplicate_vertices", f"{len(pairs)} pairs of vertices coincide (first: {a} and {b}); they are "
                     "separate vertices (a crack, or a zero-length edge) which the solve will pull apart; weld them "
                     "in your modelling tool if the surface should be continuous", vertices=tuple(verts.tolist()))]


def _check_zero_area(scene: Scene, ctx: _Context) -> list[Issue]:
    ar = ctx.face_areas()
    bad = np.flatnonzero(ar <= ZERO_AREA * float(np.median(ar)))
    if not bad.size:
        return []
    return [_warning("zero_area_faces", f"{bad.size} faces have (almost) zero area (faces {_few(bad)}): they carry "
                     "no load and their edges' weights are not determined; remove them or fix their corners",
                     faces=tuple(bad.tolist()))]


def _check_planarity(scene: Scene, ctx: _Context) -> list[Issue]:
    mesh = scene.mesh
    v = ctx.vertices()
    sizes = mesh.face_sizes
    worst = np.zeros(mesh.n_faces)
    for k in np.unique(sizes[sizes > 3]):
        f = np.flatnonzero(sizes == k)
        idx = mesh.face_vertices[mesh.face_offsets[f][:, None] + np.arange(k)]
        P = v[idx] - v[idx].mean(axis=1, keepdims=True)
        s = np.linalg.svd(P, compute_uv=False)  # smallest singular value: RMS distance to the plane × √k
        size = np.linalg.norm(P, axis=2).max(axis=1)
        worst[f] = s[:, -1] / np.maximum(size, 1e-300)
    bad = np.flatnonzero(worst > NON_PLANAR)
    if not bad.size:
        return []
    k = int(bad[np.argmax(worst[bad])])
    return [_warning("non_planar_faces", f"{bad.size} polygons are not planar (worst: face {k}, corners "
                     f"{worst[k]:.1e} of its size off its plane): fine for the thrust network, which lives on the "
                     "edges; loads use the centroid-fan area; planar panels need a planarity step",
                     faces=tuple(bad.tolist()))]


def _check_stand(scene: Scene, ctx: _Context) -> list[Issue]:
    low, one_sided = unbalanceable_vertices(scene, ctx.vertices())
    if not (low.size or one_sided.size):
        return []
    what = []
    if low.size:
        what.append(f"not higher than any neighbour: {_few(low)}")
    if one_sided.size:
        what.append(f"with all neighbours on one side in the top view (a free straight or convex boundary, a "
                    f"free corner): {_few(one_sided)}")
    verts = np.union1d(low, one_sided)
    return [_warning("cannot_stand_as_is", "no compressive network balances these free vertices where they are, "
                     f"so the solve must move them: {'; '.join(what)}; to keep them, support them or add a pillar",
                     vertices=tuple(verts.tolist()))]


#: Checks in the order they run; a check that finds an error stops the rest.
CHECKS: dict[str, Callable[[Scene, _Context], list[Issue]]] = {
    "mesh": _check_mesh,
    "scale": _check_scale,
    "supports": _check_supports,
    "extra_loads": _check_extra_loads,
    "top_view": _check_top_view,
    "duplicate_vertices": _check_duplicates,
    "zero_area_faces": _check_zero_area,
    "non_planar_faces": _check_planarity,
    "cannot_stand_as_is": _check_stand,
}


#: Every code an :class:`Issue` may carry (a check may report under more than one code).
ISSUE_CODES = frozenset({"mesh", "isolated_vertices", "scale", "precision", "supports", "extra_loads", "top_view", "overhang",
                         "duplicate_vertices", "zero_area_faces", "non_planar_faces", "cannot_stand_as_is"})


def scene_issues(scene: Scene) -> list[Issue]:
    """Every issue :data:`CHECKS` finds, errors first in check order; never raises for the input.

    Stops after the first check that reports an error: later checks assume what earlier ones
    establish (a valid mesh, a finite size, supports).
    """
    ctx = _Context(scene)
    out: list[Issue] = []
    for check in CHECKS.values():
        found = check(scene, ctx)
        out += found
        if any(i.severity == "error" for i in found):
            break
    return out


def require_rise(scene: Scene, w_max: float | None) -> None:
    """Raise :class:`~selfsupport.core.errors.InfeasibleDesign` for a flat reference without ``w_max``.

    A network in a non-vertical plane carries no vertical load (equation (3) reduces to a
    combination of equation (2)), so it must rise into a shallow dome. When its top view can
    be balanced by positive weights (equation (2) alone), any rise, however small, is balanced
    by large enough weights: with no upper weight bound the distance tends to 0 as the weights
    grow and the nearest network does not exist, and the methods would iterate on towards it
    until their limits. ``w_max`` chooses the rise. A vertical plane carries its load in the
    plane, and a top view that no positive weights balance must move by a finite amount
    anyway: neither is refused.

    >>> from selfsupport.core.shapes import make_shape
    >>> require_rise(make_shape("disk", n_vertices=50), w_max=1e3)  # bounded weights: a definite rise
    >>> require_rise(make_shape("disk", n_vertices=50), w_max=None)
    Traceback (most recent call last):
    ...
    selfsupport.core.errors.InfeasibleDesign: the reference is flat (all vertices within 1e-09 of the bounding-box diagonal of one plane) and no upper weight bound is set: a flat network carries no vertical load, and any rise, however small, is balanced by large enough weights, so no nearest network exists; give the surface some rise, or set w_max (--wmax) to choose it
    """
    if w_max is not None and not (np.ndim(w_max) == 0 and np.isinf(w_max)):
        return  # a bound (its value is the method's to check)
    V = scene.mesh.vertices
    diag = bbox_diagonal(V)
    d = (V - V.mean(axis=0)) / (diag if diag > 0 else 1.0)  # centred and scaled: far-off or huge coordinates lose nothing
    normal = np.linalg.svd(d, full_matrices=False)[2][-1]  # of the best-fit (least-squares) plane
    diag = 1.0
    if (float(np.abs(d @ normal).max()) <= FLAT * diag and abs(float(normal[2])) > VERTICAL
            and _top_view_balanceable(scene)):

        raise InfeasibleDesign(
            f"the reference is flat (all vertices within {FLAT:g} of the bounding-box diagonal of one plane) and no "
            "upper weight bound is set: a flat network carries no vertical load, and any rise, however small, is "
            "balanced by large enough weights, so no nearest network exists; give the surface some rise, or set "
            "w_max (--wmax) to choose it")


#: Largest number of weights for which :func:`_top_view_balanceable` runs a weight fit when no
#: candidate weights balance the top view (the fit of this homogeneous problem needs ~100
#: interior-point iterations: 0.7 s at 6,000 weights, 10 s at 60,000).
BALANCE_FIT_LIMIT = 10_000


def _top_view_balanceable(scene: Scene, rtol: float = 1e-8) -> bool:
    """Whether positive weights satisfy equation (2) at every free vertex of the top view (to
    ``rtol`` of the vertex's largest edge force).

    Candidates first: uniform weights (a regular grid) and, on a triangle mesh, the cotangent
    weights of the top view, which balance every interior vertex of a Delaunay triangulation.
    Failing those, one Step-2 fit of the horizontal rows (weights ≥ 1, zero right-hand side)
    up to :data:`BALANCE_FIT_LIMIT` weights; above it ``False`` (not proven balanceable)."""

    mesh = scene.mesh
    active = scene.active_edges
    top = Topology.build(mesh.n_vertices, mesh.edges[active], scene.supports)
    X = (mesh.vertices - mesh.vertices.mean(axis=0)) / bbox_diagonal(mesh.vertices)
    A = weight_matrix(top, X)
    Axy = A[np.flatnonzero(np.arange(A.shape[0]) % 3 != 2)]  # x and y of every free vertex

    Ax, Ay = Axy[0::2], Axy[1::2]
    length = (Ax.multiply(Ax) + Ay.multiply(Ay)).sqrt()  # |x_j − x_i| per free vertex and edge

    def balances(w: np.ndarray) -> bool:
        if not np.all(w > 0):
            return False
        scale = np.asarray(length.multiply(w[None, :]).max(axis=1).todense()).ravel()
        r = (Axy @ w).reshape(-1, 2)
        return bool(np.all(np.hypot(r[:, 0], r[:, 1]) <= rtol * np.maximum(scale, 1e-300)))

    candidates = [np.ones(top.m)]
    if np.all(np.diff(mesh.face_offsets) == 3):
        candidates.append(_cotangent_weights(mesh, X)[active])
    if any(balances(w) for w in candidates):
        return True
    if top.m > BALANCE_FIT_LIMIT:
        return False
    ones = np.ones(top.m)
    # (a proximal term leaves a residual in proportion to it: 1e-12 gave ~1e-8, at rtol)
    prox = 1e-16 * float(np.asarray(Axy.multiply(Axy).sum(axis=0)).mean())
    fit = make_backend("active-set").fit(A=Axy, b=np.zeros(Axy.shape[0]), lower=ones,
                                         upper=np.full(top.m, np.inf), w0=ones, prox=prox)
    return balances(fit.w)


def _cotangent_weights(mesh: PolyMesh, X: np.ndarray) -> np.ndarray:
    """Per mesh edge, ½ Σ cot of the top-view angles opposite it (triangle meshes). The
    half-edge leaving corner k of a triangle runs to corner k+1, opposite corner k+2; the mesh
    maps every half-edge to its edge."""
    F = mesh.face_vertices.reshape(-1, 3)
    he_edge = mesh.halfedge_data["halfedge_edge"].reshape(-1, 3)
    P = X[:, :2]
    w = np.zeros(mesh.n_edges)
    for k in range(3):
        i, j, o = F[:, k], F[:, (k + 1) % 3], F[:, (k + 2) % 3]
        u, v = P[i] - P[o], P[j] - P[o]
        cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
        cot = (u * v).sum(axis=1) / np.where(np.abs(cross) > 0, np.abs(cross), np.nan)
        np.add.at(w, he_edge[:, k], 0.5 * np.nan_to_num(cot, nan=-np.inf))
    return w


def validate_problem(problem: Any) -> None:
    """What every method checks before it solves ``problem`` (a :class:`~formulations.Problem`): its
    mesh and supports, and that a flat reference has an upper weight bound (:func:`require_rise`);
    raises named errors."""
    problem.validate()
    require_rise(problem.scene, 1.0 if problem.bounds.has_upper else None)


def validate_scene(scene: Scene) -> list[Issue]:
    """Raise for the first fatal problem of ``scene``; return the warnings.

    Raises
    ------
    MeshError, SupportError, InputError
        The first error :func:`scene_issues` finds (message: what, where, what to do).
    """
    issues = scene_issues(scene)
    for i in issues:
        if i.severity == "error":
            i.raise_()
    return issues
