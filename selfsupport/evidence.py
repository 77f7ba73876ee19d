"""The evidence every result carries: equilibrium residuals (paper's Table 1 metric),
weight bounds, load consistency and distance to the reference surface."""
from __future__ import annotations

import numpy as np

from .geometry import bbox_diagonal
from .mesh import PolyMesh


def residuals(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray,
              loads: np.ndarray) -> np.ndarray:
    """``(n, 3)``: ``Σ_j w_ij (v_j − v_i) − (0, 0, A_i F_i)`` at every vertex (supports included)."""
    dv = vertices[edges[:, 1]] - vertices[edges[:, 0]]
    f = weights[:, None] * dv
    r = np.zeros_like(vertices)
    np.add.at(r, edges[:, 0], f)
    np.add.at(r, edges[:, 1], -f)
    r[:, 2] -= loads
    return r


def relative_errors(*, vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray,
                    loads: np.ndarray, supports: np.ndarray) -> np.ndarray:
    """Per non-support vertex: ``‖residual‖ / |A_i F_i|`` (paper's Table 1 definition)."""
    r = residuals(vertices=vertices, edges=edges, weights=weights, loads=loads)
    free = ~np.asarray(supports, bool)
    return np.linalg.norm(r[free], axis=1) / np.maximum(np.abs(loads[free]), 1e-300)


def max_relative_error(**kw) -> float:
    rel = relative_errors(**kw)
    return float(rel.max()) if rel.size else 0.0


def distance_to_surface(points: np.ndarray, reference: PolyMesh) -> np.ndarray:
    """Unsigned distance from each point to the (triangulated) reference surface."""
    return closest_points(points, reference)[1]


def closest_points(points: np.ndarray, reference: PolyMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points on the reference surface, distances and the unit normals there.

    Uses trimesh's proximity query (rtree) on a fan triangulation of the polygons. The normal
    is interpolated from the reference's vertex normals with the barycentric coordinates of
    the closest point, so that it varies continuously — a per-triangle normal would jump
    across edges, where round-off decides which triangle is "closest".
    """
    import trimesh

    from .geometry import vertex_normals

    tm = _trimesh_of(reference)
    closest, dist, tri = tm.nearest.on_surface(np.asarray(points, float))
    corners = tm.faces[tri]
    bary = trimesh.triangles.points_to_barycentric(tm.vertices[corners], closest)
    vn = vertex_normals(reference)
    normals = np.einsum("kc,kcj->kj", bary, vn[corners])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return closest, dist, normals


_TM_CACHE: dict[int, object] = {}


def _trimesh_of(mesh: PolyMesh):
    import trimesh

    key = id(mesh)
    hit = _TM_CACHE.get(key)
    if hit is not None and hit[0] is mesh:
        return hit[1]
    tris = triangulate(mesh)
    tm = trimesh.Trimesh(mesh.vertices, tris, process=False)
    if len(_TM_CACHE) > 16:
        _TM_CACHE.clear()
    _TM_CACHE[key] = (mesh, tm)
    return tm


def triangulate(mesh: PolyMesh) -> np.ndarray:
    """Fan triangulation ``(t, 3)`` of all faces (corner 0 as apex)."""
    fo, fv = mesh.face_offsets, mesh.face_vertices
    sizes = np.diff(fo)
    face_of = np.repeat(np.arange(mesh.n_faces), sizes - 2)
    k = np.arange(len(face_of)) - np.repeat(np.cumsum(sizes - 2) - (sizes - 2), sizes - 2)
    a = fv[fo[face_of]]
    b = fv[fo[face_of] + k + 1]
    c = fv[fo[face_of] + k + 2]
    return np.stack([a, b, c], axis=1)


def distance_stats(vertices: np.ndarray, reference: PolyMesh) -> tuple[float, float]:
    """Mean and max distance to the reference surface, relative to its bounding-box diagonal."""
    d = distance_to_surface(vertices, reference) / bbox_diagonal(reference.vertices)
    return float(d.mean()), float(d.max())
