"""Catmull–Clark subdivision of polygon meshes with boundaries and creases (paper §4: upsample a
coarse design, then polish it with the solver).

One step turns every n-gon into n quads. New points (Catmull & Clark 1978, with the usual
boundary and crease rules, DeRose et al. 1998):

* face point   ``f = `` centroid of the face's vertices;
* edge point   ``(a + b + f₁ + f₂) / 4`` for a smooth interior edge, the midpoint ``(a + b)/2``
  for a boundary or crease edge;
* vertex point ``(Q + 2R + (n − 3) S) / n`` for a smooth vertex of valence n (Q the mean of the
  adjacent face points, R the mean of the incident edges' midpoints, S the vertex);
  ``(a + 6 S + b) / 8`` on a boundary or crease curve through exactly two crease edges (the
  cubic B-spline rule; a ``corner`` vertex and one with more than two crease edges stays put).

Boundary vertices in only one face (the corners of a quad grid) are corners by default, so
the outline keeps its corners. Crease edges default to the edges between two supports: a
support curve is refined as a curve, not smoothed into the surface. Supports carry over: old
supports, edge points of support–support edges and face points of all-support faces.

Written here: libigl's Python bindings have Loop and midpoint upsampling for triangles only,
trimesh's subdivision triangulates, and neither keeps polygon faces, creases or attributes.

Example
-------
>>> import numpy as np
>>> from selfsupport.core.mesh import PolyMesh
>>> quad = PolyMesh.from_faces(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.]]), [[0, 1, 2, 3]])
>>> sub = catmull_clark(quad)
>>> sub.mesh.n_vertices, sub.mesh.n_faces, sub.mesh.vertices[-1].tolist()
(9, 4, [0.5, 0.5, 0.0])
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace

import numpy as np

from selfsupport.core.errors import InputError, TooLarge
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene

__all__ = ["Subdivision", "catmull_clark", "subdivide_like", "subdivide_scene", "subdivision_parents",
           "subdivided_vertex_count"]


@dataclass(frozen=True, eq=False)
class Subdivision:
    """One Catmull–Clark step: the new mesh (old vertices first, in their order, then one point
    per old edge in ``mesh.edges`` order, then one per face) and what carries over.

    Attributes
    ----------
    mesh
        The refined mesh.
    crease
        Mask of the refined mesh's crease edges (children of crease edges), for the next level.
    corner
        Mask of the refined mesh's corner vertices.
    n_old, n_edges, n_faces
        Sizes of the coarse mesh (the index blocks of the new vertices).
    """

    mesh: PolyMesh
    crease: np.ndarray
    corner: np.ndarray
    n_old: int
    n_edges: int
    n_faces: int

    def edge_point(self, k: np.ndarray | int) -> np.ndarray | int:
        """Index of the point of coarse edge ``k``."""
        return self.n_old + np.asarray(k)

    def face_point(self, f: np.ndarray | int) -> np.ndarray | int:
        """Index of the point of coarse face ``f``."""
        return self.n_old + self.n_edges + np.asarray(f)


def catmull_clark(mesh: PolyMesh, *, crease: np.ndarray | None = None, corner: np.ndarray | None = None,
                  grid_corners: bool = True) -> Subdivision:
    """One Catmull–Clark step (see the module docstring).

    Parameters
    ----------
    mesh
        A valid polygon mesh (triangles, quads, mixed).
    crease
        Mask over ``mesh.edges`` of interior edges to keep sharp (boundary edges always are).
    corner
        Mask of vertices that stay where they are.
    grid_corners
        Also keep boundary vertices that belong to a single face.
    """
    mesh.validate()
    V = mesh.vertices
    n, m, F = mesh.n_vertices, mesh.n_edges, mesh.n_faces
    E = mesh.edges
    crease_m = mesh.boundary_edge_mask.copy()
    if crease is not None:
        c = np.asarray(crease, bool)
        if c.shape != (m,):
            raise InputError(f"crease mask has {c.shape} entries for {m} edges")
        crease_m |= c
    corner_m = np.zeros(n, bool) if corner is None else np.asarray(corner, bool).copy()
    if corner_m.shape != (n,):
        raise InputError(f"corner mask has {corner_m.shape} entries for {n} vertices")
    fv, fo = mesh.face_vertices, mesh.face_offsets
    sizes = np.diff(fo)
    face_of, _, _ = mesh.corner_data
    he_edge = mesh.halfedge_data["halfedge_edge"]  # corner c -> edge (v_c, v_next)
    pos = np.arange(fo[-1]) - fo[face_of]
    prev_corner = fo[face_of] + (pos - 1) % sizes[face_of]

    # face points
    FP = np.add.reduceat(V[fv], fo[:-1], axis=0) / sizes[:, None]
    # edge points
    mid = 0.5 * (V[E[:, 0]] + V[E[:, 1]])
    ef = mesh.edge_faces
    smooth_e = ~crease_m & (ef >= 0).all(axis=1)
    EP = mid.copy()
    EP[smooth_e] = 0.5 * mid[smooth_e] + 0.25 * (FP[ef[smooth_e, 0]] + FP[ef[smooth_e, 1]])
    # vertex points: the smooth rule everywhere first
    valence = np.bincount(E.ravel(), minlength=n).astype(float)
    nfaces = np.bincount(fv, minlength=n).astype(float)
    Q = np.zeros((n, 3))
    np.add.at(Q, fv, FP[face_of])
    R = np.zeros((n, 3))
    np.add.at(R, E[:, 0], mid)
    np.add.at(R, E[:, 1], mid)
    with np.errstate(invalid="ignore", divide="ignore"):
        Q /= nfaces[:, None]
        R /= valence[:, None]
        k = valence[:, None]
        VP = (Q + 2.0 * R + (k - 3.0) * V) / k
    # crease curves: exactly two crease edges -> cubic B-spline; more -> corner
    ncrease = np.bincount(E[crease_m].ravel(), minlength=n)
    nbsum = np.zeros((n, 3))
    ce = E[crease_m]
    np.add.at(nbsum, ce[:, 0], V[ce[:, 1]])
    np.add.at(nbsum, ce[:, 1], V[ce[:, 0]])
    curve = ncrease == 2
    VP[curve] = (6.0 * V[curve] + nbsum[curve]) / 8.0
    fixed = corner_m | (ncrease > 2) | (nfaces == 0)
    if grid_corners:
        fixed |= mesh.boundary_vertex_mask & (nfaces == 1)
    VP[fixed] = V[fixed]

    # new faces: corner c of face f -> (v_c, edge point of (v_c, next), face point, edge point of (prev, v_c))
    quads = np.stack([fv, n + he_edge, n + m + face_of, n + he_edge[prev_corner]], axis=1)
    new = PolyMesh(np.vstack([VP, EP, FP]), quads.ravel(), np.arange(0, 4 * len(quads) + 1, 4))
    # crease children: (a, e_k) and (e_k, b) for every crease edge k
    ks = np.flatnonzero(crease_m)
    child = np.r_[np.stack([E[ks, 0], n + ks], 1), np.stack([n + ks, E[ks, 1]], 1)]
    keys = np.sort(child, axis=1)
    NE = new.edges
    nk = new.n_vertices + 1
    crease_new = np.isin(NE[:, 0] * nk + NE[:, 1], keys[:, 0] * nk + keys[:, 1])
    corner_new = np.r_[fixed, np.zeros(m + F, bool)]
    return Subdivision(mesh=new, crease=crease_new, corner=corner_new, n_old=n, n_edges=m, n_faces=F)


def subdivide_scene(scene: Scene, levels: int = 1, *, crease_supports: bool = True) -> Scene:
    """``levels`` Catmull–Clark steps of a scene's mesh, carrying supports and creases.

    Edges between two supports are creases (``crease_supports``); support vertices that do not
    lie on exactly two such edges (isolated pins, ends of support chains) are corners and stay
    put. Supports carry over as in the module docstring; handles, extra masses and point loads
    stay on the old vertices (new vertices get none), so a total extra load is unchanged.

    The result remembers the scenes it was refined from, coarsest first (:func:`subdivision_parents`):
    the multilevel method solves them first, the paper's upsample-then-polish.

    >>> from selfsupport.core.shapes import make_shape
    >>> fine = subdivide_scene(make_shape("dome", n_vertices=200), 2)
    >>> [p.mesh.n_vertices for p in subdivision_parents(fine)] + [fine.mesh.n_vertices]
    [217, 1201, 4705]

    Each step quadruples the mesh: callers that solve the result check its size first
    (:func:`~selfsupport.methods.memory.check_subdivision`); a count no machine holds
    (:data:`COUNT_CAP`) raises :class:`~selfsupport.core.errors.TooLarge` here, before any step.
    """
    if int(levels) < 0:
        raise InputError(f"subdivision levels must be >= 0, got {levels}")
    if subdivided_vertex_count(scene.mesh, levels) > COUNT_CAP:  # (no machine holds it: refused at once)
        raise TooLarge(f"subdividing {levels} times gives more than {COUNT_CAP:.0e} vertices; subdivide fewer times")
    mesh, sup = scene.mesh, np.asarray(scene.supports, bool)
    extras = {k: getattr(scene, k) for k in ("handles", "extra_mass", "point_loads")}
    crease = corner = None
    parents = [*subdivision_parents(scene), scene]
    out = scene
    for k in range(int(levels)):
        E = mesh.edges
        ss = sup[E[:, 0]] & sup[E[:, 1]]
        crease = (ss if crease is None else (crease | ss)) if crease_supports else crease
        nc = np.bincount(E[ss].ravel(), minlength=mesh.n_vertices)
        pin_corner = sup & (nc != 2) & ~mesh.boundary_vertex_mask
        corner = pin_corner if corner is None else (corner | pin_corner)
        s = catmull_clark(mesh, crease=crease, corner=corner)
        step = (_fingerprint(mesh, sup), crease.copy() if crease is not None else None, corner.copy())
        fv, fo = mesh.face_vertices, mesh.face_offsets
        face_sup = np.logical_and.reduceat(sup[fv], fo[:-1])
        sup = np.r_[sup, ss, face_sup]
        extra_n = s.mesh.n_vertices - mesh.n_vertices
        for key, a in extras.items():
            if a is not None:
                extras[key] = np.r_[a, np.zeros(extra_n, dtype=a.dtype)]
        mesh, crease, corner = s.mesh, s.crease, s.corner
        out = replace(scene, mesh=mesh, supports=sup, name=f"{scene.name}+cc{k + 1}", **extras,
                      meta={**scene.meta, _PARENTS: (tuple(parents), _fingerprint(mesh, sup)), _STEP: step})
        parents.append(out)
    return replace(out, name=f"{scene.name}+cc{levels}")


#: :func:`subdivided_vertex_count` stops counting past this many vertices.
COUNT_CAP = 10 ** 15


def subdivided_vertex_count(mesh: PolyMesh, levels: int) -> int:
    """Vertices after ``levels`` Catmull–Clark steps, counted without subdividing (a size check
    before the work): each step adds a point per edge and per face; an n-gon becomes n quads
    with n new edges.

    >>> from selfsupport.core.shapes import make_shape
    >>> m = make_shape("dome", n_vertices=200).mesh
    >>> subdivided_vertex_count(m, 2) == catmull_clark(catmull_clark(m).mesh).mesh.n_vertices
    True
    """
    v, e, f, corners = mesh.n_vertices, mesh.n_edges, mesh.n_faces, int(mesh.face_sizes.sum())
    for _ in range(int(levels)):
        if v > COUNT_CAP:  # (far beyond any machine already: a count of 1e9 levels ends here)
            break
        v, e, f, corners = v + e + f, 2 * e + corners, corners, 4 * corners
    return int(v)


#: ``scene.meta`` key of the coarser scenes a subdivided scene came from (and its fingerprint then)
_PARENTS = "subdivided_from"
#: ``scene.meta`` key of the last step: the parent's fingerprint and the crease and corner masks
_STEP = "subdivision_step"


def _fingerprint(mesh: PolyMesh, supports: np.ndarray) -> str:
    """A digest of what the coarser scenes must still describe: positions, faces and supports."""
    h = hashlib.blake2b(digest_size=16)
    for a in (mesh.vertices, mesh.face_vertices, mesh.face_offsets, np.asarray(supports, bool)):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def subdivision_parents(scene: Scene) -> tuple[Scene, ...]:
    """The scenes ``scene`` was refined from by :func:`subdivide_scene`, coarsest first; empty when
    it was not, or when its mesh or supports changed since (an edit after the subdivision: the
    coarser scenes are then no longer the same design)."""
    stored = scene.meta.get(_PARENTS)
    if not stored:
        return ()
    parents, key = stored
    return tuple(parents) if key == _fingerprint(scene.mesh, scene.supports) else ()


def subdivide_like(child: Scene, parent: Scene, vertices: np.ndarray) -> Subdivision | None:
    """The Catmull–Clark step that made ``child`` from ``parent`` (:func:`subdivide_scene`, same
    creases and corners), applied to other positions of the parent's mesh, e.g. a thrust network
    solved on it. None when ``child`` was not made from ``parent`` by one step, or either changed
    since.

    >>> from selfsupport.core.shapes import make_shape
    >>> coarse = make_shape("pillar_vault", n_vertices=200)
    >>> fine = subdivide_scene(coarse, 1)
    >>> bool(np.allclose(subdivide_like(fine, coarse, coarse.mesh.vertices).mesh.vertices, fine.mesh.vertices))
    True
    >>> subdivide_like(fine, fine, fine.mesh.vertices) is None
    True
    """
    step = child.meta.get(_STEP)
    if step is None or not subdivision_parents(child) or step[0] != _fingerprint(parent.mesh, parent.supports):
        return None
    V = np.asarray(vertices, float)
    if V.shape != parent.mesh.vertices.shape:
        raise InputError(f"{V.shape[0]} positions for a mesh of {parent.mesh.n_vertices} vertices")
    return catmull_clark(parent.mesh.with_vertices(V), crease=step[1], corner=step[2])
