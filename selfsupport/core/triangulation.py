"""A design's polygons split into triangles (``selfsupport solve --triangulate``).

A quad mesh with free edges has as many edges as horizontal equations, so over a generic plan
its weights are fixed by one load and several load cases that are not proportional cannot all
stand (:mod:`selfsupport.methods.staggered.cases`). Splitting every face into triangles adds an
edge per extra triangle, with the vertices (and so the supports, loads and vertex data) unchanged
and every original edge kept.

The rule: greedy ear clipping, each step cutting off the corner whose closing diagonal is the
shortest. On a quad that is the shorter diagonal; on an n-gon short diagonals keep the triangles
away from slivers. A face must be strictly convex in its best-fit plane (the plane of its vector
area), where every corner is an ear, with one exception: a quad with one reflex or straight corner
(a dart, or a triangle with a vertex on one side, as meshes of panels have) is split from that
corner, by its one diagonal that stays inside and makes no zero-area triangle. Any other face that
is not convex is refused. Diagonals equal to round-off go to the fan from corner 0
(:func:`selfsupport.core.evidence.triangulate`), so a symmetric face splits as the fan does.

Example
-------
>>> import numpy as np
>>> quad = PolyMesh.from_faces(np.array([[0, 0, 0], [2., 0, 0], [3, 1, 0], [1, 1, 0]]), [[0, 1, 2, 3]])
>>> split_faces(quad).faces   # diagonal 1-3 (length sqrt 2) is shorter than 0-2 (sqrt 10)
[[1, 2, 3], [0, 1, 3]]
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from selfsupport.core.errors import MeshError
from selfsupport.core.geometry import face_normals
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene

__all__ = ["split_faces", "split_scene", "SPLIT_RULE"]

#: The rule in words, for reports.
SPLIT_RULE = "shortest diagonals (quads: the shorter one)"

#: A corner counts as convex when the sine of its turn in the face's plane exceeds this: below it
#: the corner is straight and an ear there would be a zero-area triangle.
_MIN_TURN_SINE = 1e-9
#: Diagonals within this relative difference of the shortest are a tie (broken toward the fan).
_TIE = 1e-9


def split_faces(mesh: PolyMesh) -> PolyMesh:
    """Every face of ``mesh`` with more than three corners split into triangles along its
    shortest diagonals (module docstring); triangles are kept as they are.

    Parameters
    ----------
    mesh
        A polygon mesh whose faces are strictly convex in their best-fit planes, quads with one
        reflex or straight corner aside (module docstring).

    Returns
    -------
    PolyMesh
        The same vertices; an n-gon becomes ``n − 2`` triangles in its place (face order kept)
        with the face's orientation, every original edge kept and ``n − 3`` diagonals added.

    Raises
    ------
    MeshError
        A face that is not strictly convex in its plane (a reflex or straight corner; on a quad,
        two of them), naming the face and the corner.

    Examples
    --------
    >>> hexagon = PolyMesh.from_faces(np.c_[np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3),
    ...                                     np.zeros(6)], [list(range(6))])
    >>> split_faces(hexagon).faces   # three ears and the triangle between them
    [[0, 1, 2], [2, 3, 4], [0, 2, 4], [0, 4, 5]]
    """
    fv, fo = mesh.face_vertices, mesh.face_offsets
    sizes = np.diff(fo)
    if sizes.size and sizes.min() < 3:
        f = int(np.argmin(sizes))
        raise MeshError(f"face {f} has {int(sizes[f])} corners; every face needs at least 3: remove it and try again")
    n_tri = sizes - 2
    first = np.r_[0, np.cumsum(n_tri)[:-1]]  # each face's first triangle in the output
    tris = np.empty((int(n_tri.sum()), 3), dtype=np.int64)
    V, normals = mesh.vertices, face_normals(mesh)
    for n in np.unique(sizes):
        faces = np.flatnonzero(sizes == n)
        F = fv[fo[faces][:, None] + np.arange(n)]  # (k, n) vertex indices
        if n == 3:
            tris[first[faces]] = F
            continue
        P = V[F]
        sines = _corner_sines(P, normals[faces])
        bad = sines <= _MIN_TURN_SINE  # (k, n): corners not strictly convex
        one = (bad.sum(axis=1) == 1) if n == 4 else np.zeros(len(faces), bool)
        if (bad.any(axis=1) & ~one).any():
            _refuse(sines, faces, F, bad & ~one[:, None])
        if one.any():  # a quad's one reflex or straight corner k: the diagonal from it, k to k + 2
            k = np.argmax(bad[one], axis=1)[:, None]
            G = np.take_along_axis(F[one], (k + np.arange(4)) % 4, axis=1)
            tris[first[faces[one]]], tris[first[faces[one]] + 1] = G[:, [0, 1, 2]], G[:, [0, 2, 3]]
            faces, F, P = faces[~one], F[~one], P[~one]
        left = np.broadcast_to(np.arange(n), F.shape).copy()  # corners still on each face, by position
        rows = np.arange(len(faces))[:, None]
        for step in range(n - 2):
            r = left.shape[1]
            if r == 3:
                pick = np.ones(len(faces), dtype=np.int64)
            else:
                prv, nxt = np.roll(left, 1, axis=1), np.roll(left, -1, axis=1)
                d = np.linalg.norm(P[rows, prv] - P[rows, nxt], axis=2)  # (k, r): each ear's diagonal
                # ties go to the first ear from position 1 on (position 0 last): the fan from corner 0
                order = np.r_[1:r, 0]
                near = d[:, order] <= d.min(axis=1, keepdims=True) * (1 + _TIE)
                pick = order[np.argmax(near, axis=1)]
            i = np.arange(len(faces))
            ear = np.stack([left[i, (pick - 1) % r], left[i, pick], left[i, (pick + 1) % r]], axis=1)
            tris[first[faces] + step] = F[rows, ear]
            keep = np.ones(left.shape, bool)
            keep[i, pick] = False
            left = left[keep].reshape(len(faces), r - 1)
    return PolyMesh(V, tris.ravel(), np.arange(0, 3 * len(tris) + 1, 3))


def _corner_sines(P: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """``(k, n)``: the sine of the turn at every corner of faces ``P`` (k, n, 3), in the plane of
    the face's vector area (its unit normal ``unit``, k × 3) and signed by it: positive at a convex
    corner."""
    a = P - np.roll(P, 1, axis=1)  # edge into each corner
    b = np.roll(P, -1, axis=1) - P  # edge out of it
    sine = np.einsum("kij,kj->ki", np.cross(a, b), unit)
    return sine / np.maximum(np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2), 1e-300)


def _refuse(sines: np.ndarray, faces: np.ndarray, F: np.ndarray, bad: np.ndarray) -> None:
    """Raise :class:`MeshError` for the first face with a ``bad`` corner (``sines``: its corners'
    :func:`_corner_sines`; see :func:`split_faces`)."""
    k, j = np.argwhere(bad)[0]
    kind = "reflex" if sines[k, j] < -_MIN_TURN_SINE else "straight"
    raise MeshError(f"face {int(faces[k])} (vertices {' '.join(map(str, F[k].tolist()))}) is not convex in its "
                    f"plane: its corner at vertex {int(F[k, j])} is {kind}, so it cannot be split into triangles "
                    "by its shortest diagonals; split that face by hand (or make it convex) first")


def split_scene(scene: Scene) -> Scene:
    """``scene`` with its mesh split by :func:`split_faces`.

    Supports, handles, extra masses and point loads index the vertices, which are unchanged, and
    carry over as they are; so does ``meta`` (its ``.sss`` edge weights name edges by their two
    vertices: the kept edges keep theirs, and a diagonal, named by none, is written with weight 0).
    A network file's stored reference and network are not split here: pass the design
    (:func:`selfsupport.io.scenes.design_of`).

    >>> from selfsupport.core.shapes import make_shape
    >>> s = make_shape("barrel_vault", nx=4, ny=3)
    >>> t = split_scene(s)
    >>> (s.mesh.n_faces, t.mesh.n_faces), (s.mesh.n_edges, t.mesh.n_edges), bool((t.supports == s.supports).all())
    ((12, 24), (31, 43), True)
    """
    return replace(scene, mesh=split_faces(scene.mesh))
