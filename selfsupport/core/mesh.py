"""Polygon mesh with lazily computed topology.

Faces are kept as polygons (triangles, quads, mixed); they are stored flat, CSR style
(``face_vertices`` + ``face_offsets``) so that geometry kernels can stay vectorised.
Topology (unique edges, edge-face incidence, boundary loops) is computed on first use and
cached: the mesh itself is immutable.

Example
-------
>>> import numpy as np
>>> m = PolyMesh.from_faces(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.]]), [[0, 1, 2, 3]])
>>> m.n_vertices, m.n_faces, m.n_edges, len(m.boundary_loops)
(4, 1, 4, 1)
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Iterable, Sequence

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from selfsupport.core.errors import MeshError


@dataclass(frozen=True, eq=False)
class PolyMesh:
    """An immutable polygon mesh.

    Parameters
    ----------
    vertices
        ``(n, 3)`` float array, z up.
    face_vertices
        Concatenated vertex indices of all faces.
    face_offsets
        ``(n_faces + 1,)``; face ``f`` is ``face_vertices[face_offsets[f]:face_offsets[f+1]]``.
    """

    vertices: np.ndarray
    face_vertices: np.ndarray
    face_offsets: np.ndarray

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=float)
        fv = np.ascontiguousarray(self.face_vertices, dtype=np.int64)
        fo = np.ascontiguousarray(self.face_offsets, dtype=np.int64)
        for a in (v, fv, fo):
            a.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "face_vertices", fv)
        object.__setattr__(self, "face_offsets", fo)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_faces(cls, vertices: np.ndarray, faces: Iterable[Sequence[int]]) -> "PolyMesh":
        """Build from a vertex array and a list of polygons (lists of vertex indices)."""
        faces = [list(map(int, f)) for f in faces]
        sizes = np.array([len(f) for f in faces], dtype=np.int64)
        offsets = np.zeros(len(faces) + 1, dtype=np.int64)
        np.cumsum(sizes, out=offsets[1:])
        flat = np.fromiter((i for f in faces for i in f), dtype=np.int64, count=int(sizes.sum()))
        return cls(np.asarray(vertices, dtype=float).reshape(-1, 3), flat, offsets)

    def with_vertices(self, vertices: np.ndarray) -> "PolyMesh":
        """Same connectivity, new positions; the cached topology is shared, not recomputed."""
        new = PolyMesh(vertices, self.face_vertices, self.face_offsets)
        for name in ("edges", "halfedge_data", "boundary_loops", "corner_data", "triangle_corners"):
            if name in self.__dict__:
                new.__dict__[name] = self.__dict__[name]
        return new

    # ------------------------------------------------------------------ sizes
    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.face_offsets.shape[0] - 1)

    @property
    def n_edges(self) -> int:
        return int(self.edges.shape[0])

    @property
    def face_sizes(self) -> np.ndarray:
        return np.diff(self.face_offsets)

    @property
    def faces(self) -> list[list[int]]:
        """Faces as Python lists (for I/O; kernels use the flat arrays)."""
        fv, fo = self.face_vertices, self.face_offsets
        sizes = np.diff(fo)
        if sizes.size and np.all(sizes == sizes[0]):  # one size (all triangles): one tolist, 10x faster at 200k
            return fv.reshape(-1, int(sizes[0])).tolist()
        return [fv[fo[f]:fo[f + 1]].tolist() for f in range(self.n_faces)]

    @property
    def is_triangular(self) -> bool:
        return bool(np.all(self.face_sizes == 3))

    # ------------------------------------------------------------------ topology
    @cached_property
    def corner_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per corner: face index, next corner's vertex, previous corner's vertex."""
        fo = self.face_offsets
        sizes = np.diff(fo)
        face_of = np.repeat(np.arange(self.n_faces), sizes)
        pos = np.arange(fo[-1]) - fo[face_of]
        nxt = fo[face_of] + (pos + 1) % sizes[face_of]
        prv = fo[face_of] + (pos - 1) % sizes[face_of]
        return face_of, self.face_vertices[nxt], self.face_vertices[prv]

    @cached_property
    def triangle_corners(self) -> np.ndarray:
        """``(t, 3)``: the three corners of each triangular face, in face order (the self-weight's
        mixed areas gather them at every load evaluation)."""
        start = self.face_offsets[:-1][self.face_sizes == 3]
        return np.stack([self.face_vertices[start], self.face_vertices[start + 1], self.face_vertices[start + 2]],
                        axis=1)

    @cached_property
    def halfedge_data(self) -> dict[str, np.ndarray]:
        face_of, nxt, _ = self.corner_data
        a, b = self.face_vertices, nxt
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = lo * (self.n_vertices + 1) + hi
        uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        edges = np.stack([uniq // (self.n_vertices + 1), uniq % (self.n_vertices + 1)], axis=1)
        # edge -> up to two faces; slot 0 for the half-edge running lo->hi, slot 1 for hi->lo
        m = len(uniq)
        edge_faces = -np.ones((m, 2), dtype=np.int64)
        slot = (a > b).astype(np.int64)
        taken = np.zeros((m, 2), dtype=np.int64)
        np.add.at(taken, (inverse, slot), 1)
        edge_faces[inverse, slot] = face_of
        return {
            "edges": edges,
            "edge_faces": edge_faces,
            "halfedge_edge": inverse,
            "edge_counts": counts,
            "edge_slot_counts": taken,
        }

    @cached_property
    def edges(self) -> np.ndarray:
        """``(m, 2)`` unique undirected edges, ``i < j``, sorted lexicographically."""
        e = self.halfedge_data["edges"]
        e.setflags(write=False)
        return e

    @property
    def edge_faces(self) -> np.ndarray:
        """``(m, 2)`` the faces on either side of each edge (``-1`` on the boundary)."""
        return self.halfedge_data["edge_faces"]

    @property
    def boundary_edge_mask(self) -> np.ndarray:
        return self.halfedge_data["edge_counts"] == 1

    @cached_property
    def boundary_vertex_mask(self) -> np.ndarray:
        mask = np.zeros(self.n_vertices, dtype=bool)
        mask[self.edges[self.boundary_edge_mask].ravel()] = True
        return mask

    @cached_property
    def boundary_loops(self) -> list[np.ndarray]:
        """Closed boundary loops, each a vertex index array following the boundary half-edges."""
        face_of, nxt, _ = self.corner_data
        he_edge = self.halfedge_data["halfedge_edge"]
        is_b = self.boundary_edge_mask[he_edge]
        succ: dict[int, int] = {}
        for a, b in zip(self.face_vertices[is_b].tolist(), nxt[is_b].tolist()):
            # boundary half-edges of the faces; walking them backwards follows the boundary
            succ[b] = a
        loops: list[np.ndarray] = []
        seen: set[int] = set()
        for start in succ:
            if start in seen:
                continue
            loop = [start]
            seen.add(start)
            cur = succ[start]
            while cur != start and cur not in seen and cur in succ:
                loop.append(cur)
                seen.add(cur)
                cur = succ[cur]
            loops.append(np.array(loop, dtype=np.int64))
        return loops

    @cached_property
    def vertex_neighbors(self) -> list[np.ndarray]:
        """For each vertex, the indices of its edge neighbours."""
        e = self.edges
        nb: list[list[int]] = [[] for _ in range(self.n_vertices)]
        for i, j in e.tolist():
            nb[i].append(j)
            nb[j].append(i)
        return [np.array(x, dtype=np.int64) for x in nb]

    @cached_property
    def connected_components(self) -> np.ndarray:
        """Component label per vertex (edge connectivity)."""

        e = self.edges
        n = self.n_vertices
        g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        _, labels = connected_components(g, directed=False)
        return labels

    # ------------------------------------------------------------------ validity
    def problems(self) -> list[str]:
        """Everything that makes this mesh unusable, as messages (empty when valid)."""
        out: list[str] = []
        v = self.vertices
        n = self.n_vertices
        if n == 0 or self.n_faces == 0:
            return ["mesh has no vertices or no faces"]
        if v.ndim != 2 or v.shape[1] != 3:
            return [f"vertex array has shape {v.shape}, expected (n, 3)"]
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any():
            out.append(f"{int(bad.sum())} vertices have NaN/inf coordinates (first: vertex {int(np.argmax(bad))})")
        fv = self.face_vertices
        if fv.size and (fv.min() < 0 or fv.max() >= n):
            f = int(np.searchsorted(self.face_offsets, int(np.argmax((fv < 0) | (fv >= n))), side="right") - 1)
            out.append(f"face {f} refers to a vertex index outside 0..{n - 1}")
            return out
        if np.any(self.face_sizes < 3):
            out.append(f"face {int(np.argmax(self.face_sizes < 3))} has fewer than 3 vertices")
            return out
        face_of, nxt, _ = self.corner_data
        if np.any(fv == nxt):
            out.append(f"face {int(face_of[np.argmax(fv == nxt)])} repeats a vertex")
            return out
        he = self.halfedge_data
        if np.any(he["edge_counts"] > 2):
            k = int(np.argmax(he["edge_counts"] > 2))
            i, j = he["edges"][k]
            out.append(f"non-manifold edge ({i}, {j}) is shared by {he['edge_counts'][k]} faces")
        elif np.any(he["edge_slot_counts"] > 1):
            k = int(np.argmax((he["edge_slot_counts"] > 1).any(axis=1)))
            i, j = he["edges"][k]
            out.append(f"faces on both sides of edge ({i}, {j}) have opposite orientation; orient the mesh consistently")
        else:
            _, nxt2, _ = self.corner_data
            is_b = self.boundary_edge_mask[he["halfedge_edge"]]
            starts = np.bincount(self.face_vertices[is_b], minlength=n)
            if np.any(starts > 1):
                out.append(f"vertex {int(np.argmax(starts > 1))} joins several boundary fans (non-manifold vertex); split it")
        # Vertices that belong to no face are not a mesh problem: they have no edges, and a scene
        # may keep them as supports that carry nothing (validate.py refuses them when free).
        return out

    @property
    def isolated_vertices(self) -> np.ndarray:
        """Indices of the vertices that belong to no face (no edges, no area)."""
        used = np.zeros(self.n_vertices, dtype=bool)
        used[self.face_vertices] = True
        return np.flatnonzero(~used)

    def is_valid(self) -> bool:
        return not self.problems()

    def validate(self) -> "PolyMesh":
        """Raise :class:`MeshError` naming the first problem; return self when fine."""
        p = self.problems()
        if p:
            raise MeshError(p[0])
        return self
