"""Quad-dominant remeshing of a network's top view along two line fields (paper §5, Fig. 12).

A planar-quad thrust network follows the *relative principal directions* of its surface
(eigenvectors of ``(∇²φ)⁻¹ ∇²s``, :func:`~selfsupport.analysis.curvature.curvatures`): they are
conjugate for both the surface and its Airy surface, and only quads along conjugate directions
can be planar on both. This module draws the quad mesh in the top view:

1. the two line fields are interpolated linearly over the network's top-view triangulation
   (``matplotlib.tri``: point location and interpolation on a non-convex domain with holes), as
   doubled-angle vectors so that ``d`` and ``−d`` agree; vertices without directions (supports,
   where Φ is not strictly convex) are filled harmonically from their neighbours;
2. the lines of each family, drawn by one of :data:`METHODS` (``method=``):

   * ``"seamless"`` (the default): the integer iso-lines of a seamless integer-grid
     parametrization (MIQ-style) of the field smoothed by :mod:`.quadmesh` (few singularities,
     each on an integer point; the boundary held on iso-lines): quads only, but at the
     singularities and where the boundary is not along the field;
   * ``"streamlines"``: evenly spaced streamlines (Jobard & Lefer 1997), traced
     with midpoint steps from seeds at distance ``spacing`` beside the lines already drawn,
     ended at the domain's boundary or closer than ``spacing / 2`` to a line of the same family
     (singularities of the field are where lines end: their faces get five or three corners,
     not a hole);
   * ``"param"``: the integer iso-lines of a global parametrization whose gradients are the
     dual frame of the two directions over the spacing (:mod:`.param`: cut graph through the
     field's singularities, least squares, seam translations rounded to integers, boundary
     edges along the field held on an iso-line);

3. the lines and the boundary loops are noded and polygonised (``shapely``); the corners of a
   face are the arrangement's nodes (crossings, ends on the boundary, sharp boundary corners);
   nodes closer than ``merge`` × ``spacing`` are merged; a quad with a corner angle below
   :data:`DEGENERATE_ANGLE` or above its supplement is split into two triangles;
4. heights are interpolated from the network; boundary vertices next to supported boundary
   are supports; each interior support (a pillar) becomes a vertex where it was, joined to the
   corners of the face that holds it.

Streamlines or a parametrization. Streamlines need neither a cut graph nor integer rounding
and follow two non-orthogonal families as they are; but where the lines of a family spread
apart a new one starts, and where they crowd one ends: a T-junction, its pentagon split into a
quad and a triangle (:func:`_split_polygon`). On the paper's lilium at its mean edge length that
leaves 158 triangles and 124 interior vertices of valence other than four (the paper's own quad
mesh: no triangle, and 25 such vertices: a 12-valent pole ringed by 12 of valence 3, four of
valence 6, and a pair of valence 3 in each lobe). The parametrization's lines end only at the
boundary (no T-junction): the spacing varies instead (a family crowds or spreads where the
field is not integrable, so the same ``spacing`` does not give the same number of faces), and
the irregular vertices sit at the field's singularities and where lines meet the boundary. The
same lilium: 69 triangles, 51 such vertices (and its planar polish stalls as well). libigl's
MIQ, which does this for cross fields, is not in its Python bindings, and the relative principal
directions are a frame field (not orthogonal), hence :mod:`.param`. The unsmoothed field has many
singularities (lilium: 37) not on integer points; ``"seamless"`` smooths the field first
(:mod:`.quadmesh`) and rounds the singular vertices to integer points, which leaves (next to) no
triangle (measured by ``python -m studies.pq``).

Example
-------
>>> from selfsupport import api
>>> from selfsupport.core.shapes import make_shape
>>> net = api.solve(make_shape("dome", n_vertices=300)).network
>>> q = remesh(net, spacing=0.12, relative=True)
>>> q.scene.mesh.is_valid(), q.face_size_counts == {4: q.scene.mesh.n_faces}, q.info["singular_indices"]
(True, True, [0.25, 0.25, 0.25, 0.25])

Along a parametrization of the unsmoothed field the lines end only at the boundary: nearly all
faces are quads (48 of 55 here; two of the triangles are a near-triangular quad split,
:data:`DEGENERATE_ANGLE`), and the only irregular vertices are next to the apex's singularities:

>>> p = remesh(net, spacing=0.06, relative=True, method="param")
>>> p.scene.mesh.is_valid(), bool((p.scene.mesh.face_sizes == 4).mean() > 0.85), p.irregular_vertices <= 4
(True, True, True)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from selfsupport.analysis.curvature import curvatures
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import triangulate
from selfsupport.core.geometry import turning_angles
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.core.scene import Scene
from selfsupport.remesh.param import frame_parametrization, isolines
from selfsupport.remesh.quadmesh import SMOOTHING, cross_indices, cross_to_frame, frame_to_cross, smooth_frames

#: Nodes closer than this fraction of the spacing are merged (slivers where lines meet the boundary).
MERGE = 0.25
#: A boundary vertex of the network whose turning angle exceeds this (degrees) stays a corner.
CORNER_ANGLE = 30.0
#: A quad with a top-view corner angle below this or above 180° minus this (degrees) is split
#: into two triangles: it is all but a triangle with a straight corner, and holding it planar in
#: equilibrium (its diagonals' distance over its size) pulls it into a sliver. On lilium's
#: parametrization remesh at 1.3 × its mean edge (57 such quads of 573, corner angles down to
#: 0.7°) the planar homotopy crushed them to angles of 0.1° without and reached planar
#: equilibrium with the split (methods/planar_homotopy.py).
DEGENERATE_ANGLE = 20.0
#: Integration step of the streamlines, as a fraction of the spacing.
STEP = 0.2
#: The seamless remesh's weight of the terms that turn its lines away from the field over the ones
#: that change their spacing (:func:`.param.frame_parametrization`, ``align_weight``): the planar
#: faces need the directions; the spacing may give.
ALIGN_WEIGHT = 10.0
#: Parameter values within this of an integer (in units of the spacing) are snapped to it (seamless remesh).
SNAP = 1e-6
#: Fields the remesher can follow.
FIELDS = ("principal", "grid")


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the cross product of top-view vectors."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


@dataclass(frozen=True, eq=False)
class Remesh:
    """A remeshed design: the new scene (heights on the network, supports carried), the lines
    drawn (per family; ``method="param"``: the iso-lines of ``u`` and of ``v``, which trade
    families across a seam where the field's two directions swap), and counts for reports
    (``info``: the parametrization's singular vertices, residual and rounding; for either
    method ``degenerate_quads_split``, the near-triangular quads split, :data:`DEGENERATE_ANGLE`)."""

    scene: Scene
    lines: tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]
    spacing: float
    field: str
    method: str = "streamlines"
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def irregular_vertices(self) -> int:
        """Interior vertices whose valence is not four (pillars included)."""
        m = self.scene.mesh
        val = np.bincount(m.edges.ravel(), minlength=m.n_vertices)
        return int(((val != 4) & ~m.boundary_vertex_mask).sum())

    @property
    def face_size_counts(self) -> dict[int, int]:
        k, c = np.unique(self.scene.mesh.face_sizes, return_counts=True)
        return {int(a): int(b) for a, b in zip(k, c)}


# ---------------------------------------------------------------------------- fields
def principal_line_fields(network: Network) -> np.ndarray:
    """``(n, 2, 2)`` per vertex the two relative principal directions of the top view (``[:, :, k]``
    the k-th, unit; NaN where undefined: supports, Φ not strictly convex)."""
    return _principal_field(network)[0]


def _principal_field(network: Network) -> tuple[np.ndarray, np.ndarray]:
    """The relative principal directions (:func:`principal_line_fields`) and per vertex how
    distinct they are, ``|κ₂ − κ₁| / (|κ₁| + |κ₂|)`` in ``[0, 1]`` (0 at an umbilic, where every
    direction is principal, and where undefined)."""
    c = curvatures(network)
    k = np.asarray(c.principal_curvatures, float)
    conf = np.abs(k[:, 1] - k[:, 0]) / np.maximum(np.abs(k).sum(axis=1), 1e-300)
    return np.asarray(c.principal_directions, float), np.nan_to_num(conf, nan=0.0)


def _fill_doubled(mesh: PolyMesh, D: np.ndarray) -> np.ndarray:
    """Doubled-angle vectors ``(n, 2)`` with the NaN rows filled harmonically (graph Laplacian)."""
    ok = np.all(np.isfinite(D), axis=1)
    if not ok.any():
        raise InputError("the network has no relative principal directions anywhere (its Airy surface is "
                         "nowhere strictly convex); solve it with a positive lower weight bound first")
    if ok.all():
        return D
    e = mesh.edges
    n = mesh.n_vertices
    A = sp.coo_matrix((np.ones(2 * len(e)), (e.ravel(), e[:, ::-1].ravel())), shape=(n, n)).tocsr()
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    u = np.flatnonzero(~ok)
    Luu = L[u][:, u].tocsc()
    rhs = -(L[u][:, np.flatnonzero(ok)] @ D[ok])
    out = D.copy()
    out[u] = np.column_stack([spla.spsolve(Luu + 1e-12 * sp.identity(len(u), format="csc"), rhs[:, k])
                              for k in range(2)])
    return out


class _Field:
    """Line field of one family over the top view: ``direction(p, prev)`` the unit direction at
    ``p`` (the sign closest to ``prev``), ``None`` outside the domain."""

    def __init__(self, tri, doubled: np.ndarray) -> None:
        import matplotlib.tri as mtri

        self.interp = [mtri.LinearTriInterpolator(tri, doubled[:, k]) for k in range(2)]

    def direction(self, p: np.ndarray, prev: np.ndarray | None) -> np.ndarray | None:
        c = self.interp[0](p[0], p[1])
        s = self.interp[1](p[0], p[1])
        if np.ma.is_masked(c) or np.ma.is_masked(s):
            return None
        ang = 0.5 * np.arctan2(float(s), float(c))
        d = np.array([np.cos(ang), np.sin(ang)])
        if prev is not None and d @ prev < 0:
            d = -d
        return d


# ---------------------------------------------------------------------------- streamlines
class _Family:
    """The samples of one family's lines (for the separation test): a KD-tree rebuilt lazily."""

    def __init__(self) -> None:
        self.lines: list[np.ndarray] = []
        self._tree: cKDTree | None = None

    def add(self, line: np.ndarray) -> None:
        self.lines.append(line)
        self._tree = None

    def near(self, p: np.ndarray, r: float) -> bool:
        if not self.lines:
            return False
        if self._tree is None:
            self._tree = cKDTree(np.vstack(self.lines))
        return bool(self._tree.query_ball_point(p, r, return_length=True) > 0)


def _trace(field: _Field, seed: np.ndarray, h: float, family: _Family, d_test: float,
           max_steps: int, inside: Callable[[np.ndarray], bool]) -> np.ndarray | None:
    """A streamline through ``seed`` both ways (midpoint rule, step ``h``), ended outside the
    domain, closer than ``d_test`` to ``family``'s lines, on closing onto itself, or after
    ``max_steps``. The last point outside the domain is kept so the line reaches the boundary."""
    halves: list[np.ndarray] = []
    d0 = field.direction(seed, None)
    if d0 is None:
        return None
    closed = False
    for sign in (1.0, -1.0):
        if closed:  # the first half came round to the seed: the line is a loop
            halves.append(np.array([seed]))
            break
        pts = [seed]
        back = int(d_test / h) + 3  # points this close along the line are not "near" it
        other = halves[0][back:] if halves else np.zeros((0, 2))  # the first half, for the self test
        prev = sign * d0
        p = seed
        for _ in range(max_steps):
            d1 = field.direction(p, prev)
            if d1 is None:
                break
            mid = p + 0.5 * h * d1
            d2 = field.direction(mid, d1)
            if d2 is None:
                d2 = d1
            q = p + h * d2
            if not inside(q):
                pts.append(q + h * d2)  # a little past the boundary: the arrangement clips it there
                break
            if family.near(q, d_test):
                break
            if len(pts) > 10 and np.linalg.norm(q - seed) < 0.5 * h:  # closed loop
                pts.append(seed)
                closed = True
                break
            own = np.vstack([other, np.asarray(pts[:-back])]) if len(pts) > back else other
            if len(own):
                dist = np.linalg.norm(own - q, axis=1)
                if dist.min() < d_test:  # coming round to itself (a loop that does not quite close, a
                    pts.append(own[int(np.argmin(dist))])  # spiral at a singularity): joined there
                    break
            pts.append(q)
            prev, p = d2, q
        halves.append(np.array(pts))
    line = np.vstack([halves[1][::-1], halves[0][1:]])
    return line if len(line) >= 3 else None


def _streamlines(field: _Field, seeds0: np.ndarray, spacing: float, inside, max_steps: int,
                 deadline_lines: int, boundary: _Family | None = None) -> list[np.ndarray]:
    """Evenly spaced streamlines of one family (Jobard & Lefer): new seeds at ``±spacing`` across
    every line drawn, kept when no line of the family is within ``0.99 spacing``. ``seeds0``: the
    first seed, then fallbacks tried in order when the queue runs dry (a seed at a singularity
    gives no line; a region may be cut off by the lines' ends)."""
    fam = _Family()
    h = STEP * spacing
    queue = [np.asarray(s, float) for s in seeds0[:1]]
    fallback = [np.asarray(s, float) for s in seeds0[1:]][::-1]  # regions the lines do not reach
    while (queue or fallback) and len(fam.lines) < deadline_lines:
        s = queue.pop(0) if queue else fallback.pop()
        if not inside(s) or fam.near(s, 0.99 * spacing) or (boundary is not None and boundary.near(s, 0.5 * spacing)):
            continue  # (a line seeded along the boundary would make a strip of slivers)
        line = _trace(field, s, h, fam, 0.5 * spacing, max_steps, inside)
        if line is None or np.linalg.norm(np.diff(line, axis=0), axis=1).sum() < spacing:
            continue
        fam.add(line)
        t = np.gradient(line, axis=0)
        t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
        nrm = np.c_[-t[:, 1], t[:, 0]]
        every = max(1, int(round(1.0 / STEP)))  # a seed per spacing along the line
        for k in range(0, len(line), every):
            queue.append(line[k] + spacing * nrm[k])
            queue.append(line[k] - spacing * nrm[k])
    return fam.lines


# ---------------------------------------------------------------------------- arrangement
def _arrangement(lines: list[np.ndarray], domain, corners: np.ndarray, spacing: float
                 ) -> tuple[np.ndarray, list[list[int]]]:
    """Faces of the arrangement of ``lines`` clipped to ``domain`` (a shapely polygon), with the
    arrangement's nodes as corners."""
    from shapely.geometry import LineString
    from shapely.ops import polygonize, unary_union

    # (not clipped first: a clipped end a round-off short of the boundary would be a dangle;
    # lines cross the boundary and the pieces outside bound no face inside the domain)
    noded = unary_union([domain.boundary] + [LineString(l) for l in lines])
    polys = [p for p in polygonize(noded) if p.area > 1e-12 * domain.area]
    polys = [p for p in polys if domain.contains(p.representative_point())]
    if not polys:
        raise InputError("the remeshing found no faces; choose a smaller --spacing")
    # points of the polygons' rings and how many distinct neighbours each has
    key = lambda xy: (round(xy[0] / spacing * 1e7), round(xy[1] / spacing * 1e7))  # noqa: E731
    nbrs: dict[tuple, set] = {}
    coords: dict[tuple, tuple] = {}
    rings = []
    for p in polys:
        ring = [tuple(c) for c in list(p.exterior.coords)[:-1]]
        if not p.exterior.is_ccw:
            ring = ring[::-1]
        ks = [key(c) for c in ring]
        rings.append(ks)
        for i, k in enumerate(ks):
            coords.setdefault(k, ring[i])
            s = nbrs.setdefault(k, set())
            s.add(ks[i - 1])
            s.add(ks[(i + 1) % len(ks)])
    corner_keys = {key(c) for c in corners}
    # a corner of the old boundary survives only when it lies on the new boundary ring
    is_node = {k: (len(v) != 2 or k in corner_keys) for k, v in nbrs.items()}
    keys = [k for k, v in is_node.items() if v]
    P = np.array([coords[k] for k in keys])
    # merge nodes closer than MERGE × spacing to a kept node (greedy, not transitive: a chain of
    # close nodes along the boundary must not collapse into one); nodes of higher degree are kept first
    from shapely import distance, points

    on_ring = distance(points(P), domain.boundary) <= 1e-9 * spacing
    # boundary nodes first (an interior node merged into one moves onto the boundary, never the
    # other way: a boundary vertex moved inside would be a free vertex on the ground), then by degree
    order = sorted(range(len(keys)), key=lambda i: (not on_ring[i], -len(nbrs[keys[i]])))
    tree = cKDTree(P)
    rep = -np.ones(len(keys), np.int64)
    for i in order:
        if rep[i] >= 0:
            continue
        rep[i] = i
        for j in tree.query_ball_point(P[i], MERGE * spacing):
            if rep[j] < 0:
                rep[j] = i
    uniq, new_id = np.unique(rep, return_inverse=True)
    V2 = P[uniq]
    index = {k: int(new_id[i]) for i, k in enumerate(keys)}
    faces = []
    for ks in rings:
        f = [index[k] for k in ks if is_node[k]]
        g = [v for i, v in enumerate(f) if v != f[i - 1]] if len(f) > 1 else f
        if len(g) >= 3 and len(set(g)) == len(g):
            faces.append(g)
    # interior vertices left with two edges (merges, a line's end on another line's corner) are
    # no corners: dropped from their faces (a free vertex with two edges cannot be balanced)
    bnd = set(np.flatnonzero(on_ring[uniq]).tolist())
    while True:
        nb: dict[int, set] = {}
        for f in faces:
            for i, v in enumerate(f):
                nb.setdefault(v, set()).update((f[i - 1], f[(i + 1) % len(f)]))
        two = {v for v, s in nb.items() if len(s) == 2 and v not in bnd}
        if not two:
            break
        faces = [g for g in ([v for v in f if v not in two] for f in faces) if len(g) >= 3]
    return V2, [q for f in faces for q in _split_polygon(V2, f)]


def _insert_points(V2: np.ndarray, faces: list[list[int]], points: np.ndarray, tol: float
                   ) -> tuple[np.ndarray, list[list[int]], list[int]]:
    """Make each of ``points`` (pillars) a vertex: a vertex within ``tol`` of it, or a new vertex
    joined to every corner of the face that contains it (a fan of triangles: the forces gather
    radially into a pillar, and the lines of a field rarely cross exactly there — a pillar is a
    singularity of the relative principal directions). Returns the vertices, faces and the
    points' vertex indices."""
    from matplotlib.path import Path as _Path

    V2 = np.asarray(V2, float)
    faces = [list(f) for f in faces]
    ids: list[int] = []
    for p in np.asarray(points, float).reshape(-1, 2):
        d = np.linalg.norm(V2 - p, axis=1)
        if d.size and d.min() <= tol:
            ids.append(int(np.argmin(d)))
            continue
        hit = next((i for i, f in enumerate(faces) if _Path(V2[f]).contains_point(p)), None)
        if hit is None:
            raise InputError(f"the pillar at ({p[0]:g}, {p[1]:g}) lies in no face of the remesh; try another --spacing")
        V2 = np.vstack([V2, p])
        c = len(V2) - 1
        f = faces.pop(hit)
        faces += [[c, f[k], f[(k + 1) % len(f)]] for k in range(len(f))]
        ids.append(c)
    return V2, faces, ids


def _corner_angles(P: np.ndarray) -> np.ndarray:
    """Interior angles [rad] at the corners of the top-view polygon ``P`` (k, 2), in [0, π]."""
    u, w = np.roll(P, 1, axis=0) - P, np.roll(P, -1, axis=0) - P
    return np.arctan2(np.abs(_cross2(u, w)), np.einsum("ij,ij->i", u, w))


def _min_angle(T: np.ndarray) -> float:
    """Smallest angle of the top-view triangle ``T`` (3, 2)."""
    return float(_corner_angles(T).min())


def _split_polygon(P: np.ndarray, face: list[int]) -> list[list[int]]:
    """A face with more than four corners as quads and triangles: triangles cut off next to its
    straightest corner (a T-junction, where a line ended) until a quad remains. A pentagon with
    three corners on one curved line cannot be planar unless the line is straight there; a
    triangle always is."""
    f = list(face)
    out = []
    while len(f) > 4:
        k = len(f)
        Q = P[f]
        a, b = Q - np.roll(Q, 1, axis=0), np.roll(Q, -1, axis=0) - Q
        turn = np.abs(np.arctan2(_cross2(a, b), np.einsum("ij,ij->i", a, b)))
        v = int(np.argmin(turn))  # the straightest corner
        ahead = [f[v], f[(v + 1) % k], f[(v + 2) % k]]
        behind = [f[(v - 2) % k], f[(v - 1) % k], f[v]]
        tri = ahead if _min_angle(P[ahead]) >= _min_angle(P[behind]) else behind
        out.append(tri)
        f = [x for x in f if x != tri[1]]
    return out + [f]


def _split_degenerate(V2: np.ndarray, faces: list[list[int]]) -> tuple[list[list[int]], int]:
    """Quads with a corner angle outside ``[DEGENERATE_ANGLE, 180 − DEGENERATE_ANGLE]`` split into
    two triangles by the diagonal from their widest corner; (faces, how many were split)."""
    out: list[list[int]] = []
    split = 0
    for f in faces:
        if len(f) == 4:
            ang = np.degrees(_corner_angles(V2[f]))
            if ang.min() < DEGENERATE_ANGLE or ang.max() > 180.0 - DEGENERATE_ANGLE:
                i = int(np.argmax(ang))
                out += [[f[i], f[(i + 1) % 4], f[(i + 2) % 4]], [f[i], f[(i + 2) % 4], f[(i + 3) % 4]]]
                split += 1
                continue
        out.append(f)
    return out, split


def _domain(mesh: PolyMesh):
    """The network's top view as a shapely polygon (outer loop and holes)."""
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    xy = mesh.vertices[:, :2]
    tris = triangulate(mesh)
    dom = unary_union([Polygon(xy[t]) for t in tris if abs(_cross2(xy[t[1]] - xy[t[0]], xy[t[2]] - xy[t[0]])) > 0])
    if dom.geom_type != "Polygon":
        raise InputError("the network's top view is not one connected region; remesh each part on its own")
    return dom


def _corners(mesh: PolyMesh) -> np.ndarray:
    """Top-view positions of boundary vertices where the boundary turns by more than CORNER_ANGLE."""
    xy = mesh.vertices[:, :2]
    out = []
    for loop in mesh.boundary_loops:
        P = xy[loop]
        out.append(P[turning_angles(P) > CORNER_ANGLE])
    return np.vstack(out) if out else np.zeros((0, 2))


# ---------------------------------------------------------------------------- line builders
@dataclass(frozen=True, eq=False)
class _Setting:
    """What a line builder gets: the network's mesh, its top-view triangulation, each family's
    unit doubled-angle vectors per vertex (filled where undefined), the spacing, the domain."""

    mesh: PolyMesh
    tri: object  # matplotlib.tri.Triangulation
    doubled: tuple[np.ndarray, np.ndarray]
    spacing: float
    domain: object  # shapely Polygon
    max_lines: int
    confidence: np.ndarray | None = None  # per vertex, in [0, 1] (None: 1 everywhere)
    smooth: bool = True  # the seamless remesh smooths the field (not a fixed grid's: it stays unaligned)
    smoothing: float = SMOOTHING  # the seamless remesh's smoothing length / the bbox diagonal


def _streamline_lines(st: _Setting) -> tuple[list[list[np.ndarray]], dict]:
    """Evenly spaced streamlines of each family (module docstring, step 2)."""
    xy = st.mesh.vertices[:, :2]
    finder = st.tri.get_trifinder()
    inside = lambda p: bool(finder(p[0], p[1]) >= 0)  # noqa: E731
    diag = float(np.linalg.norm(np.ptp(xy, axis=0)))
    max_steps = int(4 * diag / (STEP * st.spacing)) + 10
    c = np.asarray(st.domain.representative_point().coords[0])
    inner = np.flatnonzero(~st.mesh.boundary_vertex_mask)  # fallback seeds, nearest the centre first
    seeds = [c] + list(xy[inner[np.argsort(np.linalg.norm(xy[inner] - c, axis=1))]])
    border = _Family()  # the boundary, sampled at a tenth of the spacing
    for ring in [st.domain.exterior, *st.domain.interiors]:
        border.add(np.asarray([ring.interpolate(t).coords[0] for t in np.arange(0, ring.length, 0.1 * st.spacing)]))
    lines: list[list[np.ndarray]] = []
    for k in range(2):
        fam_lines = _streamlines(_Field(st.tri, st.doubled[k]), seeds, st.spacing, inside, max_steps, st.max_lines,
                                 border)
        if len(fam_lines) >= st.max_lines:
            raise InputError(f"more than {st.max_lines} lines per direction at spacing {st.spacing:g}; "
                             "choose a larger --spacing")
        lines.append(fam_lines)
    return lines, {}


def _param_lines(st: _Setting) -> tuple[list[list[np.ndarray]], dict]:
    """Integer iso-lines of a global parametrization along the two fields (:mod:`.param`),
    each end extended a little past the boundary (the arrangement clips it there; an end a
    round-off short of the boundary would be a dangle)."""

    ang = np.stack([0.5 * np.arctan2(d[:, 1], d[:, 0]) for d in st.doubled], axis=1)  # (n, 2)
    D = np.stack([np.cos(ang), np.sin(ang)], axis=1)  # (n, 2, 2), columns the two directions
    xy = st.mesh.vertices[:, :2]
    tris = np.asarray(st.tri.triangles)
    return _isoline_lines(st, frame_parametrization(xy, tris, D, st.spacing))


def _seamless_lines(st: _Setting) -> tuple[list[list[np.ndarray]], dict]:
    """Integer iso-lines of a seamless integer-grid parametrization (MIQ-style) along the
    smoothed field (:mod:`.quadmesh`): few singularities, each on an integer point, the
    boundary on iso-lines."""
    xy = st.mesh.vertices[:, :2]
    tris = np.asarray(st.tri.triangles)
    # per triangle the mean of its corners' cross and stretch (which, unlike each family's
    # direction, do not depend on which line of a frame is called the first)
    ang = np.stack([0.5 * np.arctan2(d[:, 1], d[:, 0]) for d in st.doubled], axis=1)
    z, S = frame_to_cross(np.stack([np.cos(ang), np.sin(ang)], axis=1))
    F0 = cross_to_frame(z[tris].mean(axis=1), S[tris].mean(axis=1))
    conf = None if st.confidence is None else st.confidence[tris].mean(axis=1)
    diag = float(np.linalg.norm(np.ptp(xy, axis=0)))
    F = smooth_frames(xy, tris, F0, length=st.smoothing * diag, confidence=conf) if st.smooth else F0
    index = cross_indices(xy, tris, F)
    p = frame_parametrization(xy, tris, None, st.spacing, frames=F, integer_singularities=True, batch=8,
                              align_weight=ALIGN_WEIGHT, keep_density=True)
    # values an integer to the solve's round-off (the gauge's faint pull, the KKT regularisation)
    # are that integer: a boundary held on an iso-line is then skipped as one, not traced beside itself
    near = np.abs(p.uv - np.round(p.uv)) < SNAP
    lines, info = _isoline_lines(st, dataclasses.replace(p, uv=np.where(near, np.round(p.uv), p.uv)))
    return lines, {**info, "singular_indices": sorted(float(i) for i in index[index != 0])}


def _isoline_lines(st: _Setting, p) -> tuple[list[list[np.ndarray]], dict]:
    """The integer iso-lines of the parametrization ``p`` (:class:`.param.Parametrization`) as
    the two families' lines, each end extended a little past the boundary."""
    xy = st.mesh.vertices[:, :2]
    tris = np.asarray(st.tri.triangles)
    lines: list[list[np.ndarray]] = [[], []]
    for k, fam in enumerate(isolines(xy, tris, p.uv)):
        if sum(len(x) for x in fam) > st.max_lines / STEP:
            raise InputError(f"too many iso-lines at spacing {st.spacing:g}; choose a larger --spacing")
        for line in fam:
            # a piece shorter than half the spacing (an iso-line grazing the boundary) bounds
            # only slivers: the merge would fold them into triangles
            if len(line) < 2 or np.linalg.norm(np.diff(line, axis=0), axis=1).sum() < 2 * MERGE * st.spacing:
                continue
            a = line[0] - line[1]
            b = line[-1] - line[-2]
            ext = 0.05 * st.spacing
            lines[k].append(np.vstack([line[0] + ext * a / max(np.linalg.norm(a), 1e-300), line,
                                       line[-1] + ext * b / max(np.linalg.norm(b), 1e-300)]))
    return lines, {"singularities": int(len(p.singular)), "residual": p.residual, "rounded": p.rounded,
                   "density_scale": p.scale}


#: Line builders by name (``remesh(method=...)``).
METHODS: dict[str, Callable[[_Setting], tuple[list[list[np.ndarray]], dict]]] = {
    "seamless": _seamless_lines,
    "streamlines": _streamline_lines,
    "param": _param_lines,
}


# ---------------------------------------------------------------------------- main
def remesh(network: Network, *, spacing: float | None = None, relative: bool = False, field: str = "principal",
           angle: float = 0.0, max_lines: int = 20000, method: str = "seamless",
           smoothing: float = SMOOTHING, directions: np.ndarray | None = None) -> Remesh:
    """Quad-dominant remesh of ``network``'s top view along a line field, lifted to its heights.

    Parameters
    ----------
    network
        A thrust network (in equilibrium: its Airy surface gives the relative principal directions).
    spacing
        Distance between neighbouring lines of a family [m] (``relative=True``: a fraction of the
        top view's bounding-box diagonal); default: the network's mean top-view edge length.
    field
        ``"principal"``: the relative principal directions; ``"grid"``: two constant orthogonal
        directions at ``angle`` degrees to the x axis (the naive, unaligned quad mesh of Fig. 12).
    max_lines
        Most lines per family (a guard against a spacing far below the mesh's resolution).
    smoothing
        ``method="seamless"``: the smoothing length of the field over the top view's diagonal
        (:func:`.quadmesh.smooth_frames`).
    directions
        ``(n, 2, 2)`` per vertex of the network two top-view directions (columns) to follow
        instead of ``field``'s (``field`` is then only the name in the report).
    method
        How the lines are drawn (:data:`METHODS`): ``"streamlines"``, evenly spaced streamlines
        of each family (lines end where the field spreads: T-junctions); ``"param"``, the integer
        iso-lines of a global parametrization along both fields (:mod:`.param`: lines end only at
        the boundary, quads grow or shrink instead; irregular vertices at the field's singularities).

    Returns
    -------
    Remesh
        The new scene: heights interpolated from the network, supports on the boundary where the
        network's boundary is supported, and at each interior support (pillar): a vertex there,
        fanned to the corners of the face that holds it; handles dropped.
    """
    import matplotlib.tri as mtri

    network = getattr(network, "network", network)
    mesh = network.mesh
    if field not in FIELDS:
        raise InputError(f"unknown field {field!r}; choose one of {', '.join(FIELDS)}")
    if method not in METHODS:
        raise InputError(f"unknown remesh method {method!r}; choose one of {', '.join(METHODS)}")
    sup = np.asarray(network.supports, bool)
    pillars = np.flatnonzero(sup & ~mesh.boundary_vertex_mask)
    xy = mesh.vertices[:, :2]
    diag = float(np.linalg.norm(np.ptp(xy, axis=0)))
    e = mesh.edges
    mean_edge = float(np.linalg.norm(xy[e[:, 1]] - xy[e[:, 0]], axis=1).mean())
    if spacing is None:
        spacing = mean_edge
    elif relative:
        spacing = float(spacing) * diag
    if not (np.isfinite(spacing) and spacing > 0):
        raise InputError(f"--spacing must be a positive number, got {spacing!r}")
    if spacing < 1e-3 * diag:
        raise InputError(f"--spacing {spacing:g} is below 1/1000 of the top view's size ({diag:g}); choose a larger one")
    tri = mtri.Triangulation(xy[:, 0], xy[:, 1], triangulate(mesh))
    n = mesh.n_vertices
    conf = None
    if directions is not None:
        D = np.asarray(directions, float)
        if D.shape != (n, 2, 2):
            raise InputError(f"directions must be (n_vertices, 2, 2) = ({n}, 2, 2), got {D.shape}")
    elif field == "principal":
        D, conf = _principal_field(network)
    else:
        a = np.radians(angle)
        D = np.broadcast_to(np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]), (n, 2, 2)).copy()
    doubled = []
    for k in range(2):
        dk = D[:, :, k]
        dbl = _fill_doubled(mesh, np.c_[dk[:, 0] ** 2 - dk[:, 1] ** 2, 2 * dk[:, 0] * dk[:, 1]])
        nrm = np.linalg.norm(dbl, axis=1, keepdims=True)
        doubled.append(dbl / np.where(nrm > 0, nrm, 1.0))
    domain = _domain(mesh)
    if not (np.isfinite(smoothing) and smoothing > 0):
        raise InputError(f"--smoothing must be a positive number, got {smoothing!r}")
    lines, info = METHODS[method](_Setting(mesh=mesh, tri=tri, doubled=(doubled[0], doubled[1]), spacing=spacing,
                                           domain=domain, max_lines=max_lines, confidence=conf,
                                           smoothing=float(smoothing), smooth=directions is not None or field != "grid"))
    # (a spacing near the top view's size draws a line or two, whose faces merge away: no mesh)
    too_coarse = InputError(f"--spacing {spacing:g} m draws too few lines for a mesh of this top view "
                            f"({np.ptp(xy[:, 0]):.3g} x {np.ptp(xy[:, 1]):.3g} m); choose a smaller --spacing (the "
                            f"default, the network's mean top-view edge length, is {mean_edge:.3g} m)")
    if not (lines[0] and lines[1]):
        raise too_coarse
    V2, faces = _arrangement(lines[0] + lines[1], domain, _corners(mesh), spacing)
    V2, faces, pillar_ids = _insert_points(V2, faces, xy[pillars], MERGE * spacing)
    if not any(len(f) == 4 for f in faces):  # (none, or a few triangles round singularities rounded onto one point)
        raise too_coarse
    used = np.unique(np.concatenate([np.asarray(f) for f in faces]))
    remap = -np.ones(len(V2), np.int64)
    remap[used] = np.arange(len(used))
    V2 = V2[used]
    faces = [remap[f].tolist() for f in faces]
    faces, info["degenerate_quads_split"] = _split_degenerate(V2, faces)
    z = mtri.LinearTriInterpolator(tri, mesh.vertices[:, 2])(V2[:, 0], V2[:, 1])
    zf = np.asarray(np.ma.filled(z, np.nan), float)
    if np.isnan(zf).any():  # nodes on the boundary a round-off outside: the nearest network vertex's height
        miss = np.isnan(zf)
        zf[miss] = mesh.vertices[cKDTree(xy).query(V2[miss])[1], 2]
    new = PolyMesh.from_faces(np.c_[V2, zf], faces)
    if not new.is_valid():
        raise InputError("the remeshed top view is not a valid manifold mesh (lines too close near a singularity "
                         "of the field?); try another --spacing")
    # supports: new boundary vertices whose nearest old boundary vertex is a support
    bmask = new.boundary_vertex_mask
    old_b = np.flatnonzero(mesh.boundary_vertex_mask)
    near = old_b[cKDTree(xy[old_b]).query(V2[bmask])[1]]
    supports = np.zeros(new.n_vertices, bool)
    supports[np.flatnonzero(bmask)] = sup[near]
    supports[remap[pillar_ids]] = True  # the pillars, where they were
    scene = Scene(mesh=new, supports=supports, name=f"{getattr(network, 'name', 'network')}-pq")
    return Remesh(scene=scene, lines=(tuple(lines[0]), tuple(lines[1])), spacing=spacing, field=field, method=method,
                  info=info)
