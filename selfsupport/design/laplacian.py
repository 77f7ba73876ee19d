"""Handle-based deformation with Laplacian coordinates (Sorkine et al. 2004, Lipman et al. 2004).

The reference is edited by moving *handle* vertices; the other vertices of a *region of
interest* (ROI) follow so that their Laplacian coordinates ``δ = L V₀`` are kept in the least
squares sense, and everything outside the ROI stays (the anchors)::

    min_{V_free}  Σ_{i ∈ ROI} ‖(L V)_i − δ_i‖²     V_handles, V_anchors given

``L = I − Λ`` with ``Λ`` the **mean-value** weights of each vertex's edge neighbours (Floater
2003), computed per face corner so that they work on polygon meshes: they reproduce affine
functions on a planar mesh (so an affine move of the handles and anchors is reproduced
exactly, and a plane stays a plane), unlike the uniform umbrella weights, and unlike libigl's
cotangent matrix they need no triangulation. Boundary vertices use the curve rule (their two
boundary neighbours, inverse-length weights) so that a free boundary keeps its shape.

The normal equations ``L_RFᵀ L_RF`` are the same for x, y and z: one sparse Cholesky factor
per ROI serves the full edit, the height-only edit (z solved, x, y kept) and the top-view-only
edit (x, y solved, z kept), and every later position of the handles — only the right-hand
side changes (:class:`LaplacianEditor`). Rotations of the handles are not compensated (plain
Laplacian coordinates are not rotation invariant): the edits of §4 are translations.

Example
-------
>>> import numpy as np
>>> from selfsupport.core.shapes import make_shape
>>> mesh = make_shape("dome", n_vertices=200).mesh
>>> top = np.argmax(mesh.vertices[:, 2])
>>> handles = np.zeros(mesh.n_vertices, bool); handles[top] = True
>>> ed = LaplacianEditor(mesh, handles, roi=ring_region(mesh, handles, 4))
>>> V = ed.deform(mesh.vertices[handles] + [0, 0, 0.5], mode="height")
>>> bool(np.allclose(V[top], mesh.vertices[top] + [0, 0, 0.5])), bool(np.allclose(V[:, :2], mesh.vertices[:, :2]))
(True, True)
"""
from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp

from selfsupport.core.errors import InputError
from selfsupport.core.linalg import spd_factor
from selfsupport.core.mesh import PolyMesh

__all__ = ["MODES", "laplacian_matrix", "ring_region", "LaplacianEditor"]

#: Which coordinates an edit moves.
MODES: dict[str, tuple[int, ...]] = {"full": (0, 1, 2), "height": (2,), "top_view": (0, 1)}
Mode = Literal["full", "height", "top_view"]


def laplacian_matrix(mesh: PolyMesh, vertices: np.ndarray | None = None) -> sp.csr_matrix:
    """``L = I − Λ`` (n × n): mean-value weights at interior vertices, the boundary curve rule at
    boundary vertices, a zero row at vertices in no face.

    Parameters
    ----------
    mesh
        Any polygon mesh.
    vertices
        Positions to measure the weights at (default: the mesh's).
    """
    V = mesh.vertices if vertices is None else np.asarray(vertices, float)
    n = mesh.n_vertices
    i = mesh.face_vertices
    _, a, b = mesh.corner_data  # next and previous vertex of every corner
    e1, e2 = V[a] - V[i], V[b] - V[i]
    l1, l2 = np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)
    cross = np.linalg.norm(np.cross(e1, e2), axis=1)
    # tan(θ/2) = |e1 × e2| / (|e1||e2| + e1·e2): stable for every angle below π
    den = l1 * l2 + np.einsum("ij,ij->i", e1, e2)
    t = cross / np.maximum(den, 1e-12 * l1 * l2)
    tiny = 1e-300
    rows = np.r_[i, i]
    cols = np.r_[a, b]
    vals = np.r_[t / np.maximum(l1, tiny), t / np.maximum(l2, tiny)]
    bmask = mesh.boundary_vertex_mask
    keep = ~bmask[rows]
    rows, cols, vals = rows[keep], cols[keep], vals[keep]
    # boundary vertices: the curve through their boundary neighbours (inverse-length weights)
    eb = mesh.edges[mesh.boundary_edge_mask]
    lb = np.linalg.norm(V[eb[:, 1]] - V[eb[:, 0]], axis=1)
    rows = np.r_[rows, eb[:, 0], eb[:, 1]]
    cols = np.r_[cols, eb[:, 1], eb[:, 0]]
    vals = np.r_[vals, 1.0 / np.maximum(lb, tiny), 1.0 / np.maximum(lb, tiny)]
    W = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    s = np.asarray(W.sum(axis=1)).ravel()
    has = s > 0
    inv = np.where(has, 1.0 / np.where(has, s, 1.0), 0.0)
    return (sp.diags(has.astype(float)) - sp.diags(inv) @ W).tocsr()


def ring_region(mesh: PolyMesh, seeds: np.ndarray, rings: int) -> np.ndarray:
    """Mask of the vertices within ``rings`` edge steps of the ``seeds`` mask. The growth stops
    once a ring adds no vertex, so any ``rings`` (``1e9``: everything connected to the seeds)
    takes at most as many steps as the mesh has vertices."""
    e = mesh.edges
    n = mesh.n_vertices
    adj = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    mask = np.asarray(seeds, bool).copy()
    for _ in range(min(int(rings), n)):
        grown = mask | (adj @ mask.astype(float) > 0)
        if np.array_equal(grown, mask):
            break
        mask = grown
    return mask


class LaplacianEditor:
    """Laplacian-coordinate deformation of one region of interest, factored once.

    Parameters
    ----------
    mesh
        The reference before the edit (its positions define the Laplacian coordinates).
    handles
        Boolean mask (or indices) of the handle vertices; their new positions go to :meth:`deform`.
    roi
        Mask of the vertices allowed to move (handles included; default: every vertex).
        Vertices outside it are anchors and stay.
    fixed
        Mask of further vertices that stay even inside the ROI (e.g. supports).

    Raises
    ------
    InputError
        A part of the ROI is connected to no handle or anchor (its position would be undetermined).
    """

    def __init__(self, mesh: PolyMesh, handles: np.ndarray, roi: np.ndarray | None = None,
                 fixed: np.ndarray | None = None) -> None:
        n = mesh.n_vertices
        self.mesh = mesh
        self.handles = _mask(handles, n)
        roi_m = np.ones(n, bool) if roi is None else _mask(roi, n)
        fixed_m = np.zeros(n, bool) if fixed is None else _mask(fixed, n)
        L = laplacian_matrix(mesh)
        has_row = np.diff(L.indptr) > 0
        self.free = roi_m & ~self.handles & ~fixed_m & has_row
        if not self.handles.any():
            raise InputError("a Laplacian edit needs at least one handle vertex")
        rows = (roi_m | self.handles) & has_row
        self.delta = L @ mesh.vertices  # the Laplacian coordinates to keep
        Lr = L[rows]
        self._Lrf = Lr[:, self.free].tocsc()
        self._Lrc = Lr[:, ~self.free].tocsc()
        self._delta_r = self.delta[rows]
        M = (self._Lrf.T @ self._Lrf).tocsc()
        # the ROI's free part must touch a constrained vertex, else L_RF is rank deficient
        d = M.diagonal()
        if self.free.any() and not np.all(d > 0):
            raise InputError("part of the region of interest has no Laplacian row; enlarge the region")
        self.factor = spd_factor(M) if self.free.any() else None
        if self.factor is not None:
            probe = self.factor.solve(M @ np.ones(M.shape[0]))
            if not np.allclose(probe, 1.0, atol=1e-6):
                raise InputError("part of the region of interest is connected to no handle or anchor; add handles or "
                                 "shrink the region so that its border is anchored")
        self.solves = 0  # deform calls served by this factor (the factor is never recomputed)

    def deform(self, handle_positions: np.ndarray, mode: Mode = "full") -> np.ndarray:
        """New vertex positions with the handles at ``handle_positions`` ((k, 3), handles in index
        order). ``mode``: ``"full"``, ``"height"`` (only z moves; the handles' x, y are ignored)
        or ``"top_view"`` (only x, y move; the handles' z is ignored)."""
        if mode not in MODES:
            raise InputError(f"unknown edit mode {mode!r}; choose one of {', '.join(MODES)}")
        V0 = self.mesh.vertices
        P = np.asarray(handle_positions, float).reshape(-1, 3)
        if P.shape[0] != int(self.handles.sum()):
            raise InputError(f"{P.shape[0]} handle positions for {int(self.handles.sum())} handles")
        axes = list(MODES[mode])
        V = V0.copy()
        V[np.ix_(self.handles, axes)] = P[:, axes]
        if self.factor is not None:
            rhs = self._Lrf.T @ (self._delta_r[:, axes] - self._Lrc @ V[~self.free][:, axes])
            V[np.ix_(self.free, axes)] = self.factor.solve(rhs).reshape(-1, len(axes))
        self.solves += 1
        return V


def _mask(a: np.ndarray, n: int) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype == bool:
        if a.shape != (n,):
            raise InputError(f"vertex mask has shape {a.shape} for {n} vertices")
        return a.copy()
    idx = a.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise InputError(f"vertex index outside 0..{n - 1}")
    m = np.zeros(n, bool)
    m[idx] = True
    return m
