"""The masonry hull as a penalty: every vertex within ±t/2 of the reference mid-surface."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from formulations.equilibrium import to_dm
from formulations.terms.base import OnPoints, Term, TermContext, normal_rows, points_array
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import closest_points
from selfsupport.core.geometry import vertex_normals
from selfsupport.core.lazy import lazy_module

ca = lazy_module("casadi")  # (imported when first used: a plain staggered solve never is)


@dataclass(frozen=True, eq=False)
class HullPenalty(OnPoints, Term):
    """``Σ_i max(0, |⟨n_i, v_i − p_i⟩| − h)²``: zero inside the slab of half-thickness ``h``
    around the tangent plane at ``p_i`` (the reference vertex, normal ``n_i``), quadratic outside.

    A ``constraint`` term: methods keep its weight when they relax the objective. The hard form
    ``|⟨n_i, v_i − p_i⟩| ≤ h`` is :meth:`signed_distance` with bounds. Registered as ``"hull"``
    (needs the problem's thickness: ``h = t/2``).

    The slab is the hull's linearization at ``p_i``: a vertex that slides along it by ``δ``
    leaves the curved shell by about ``κ δ² / 2`` (a 100-vertex dome in a 2 cm hull: vertices
    slid 0.9 m and ended 10 cm outside). With the ``reference`` surface given, :meth:`at`
    re-anchors each slab at the current vertex's closest point on it, with the distance's own
    gradient as normal, so an iteration that re-anchors holds the true distance.
    """

    points: np.ndarray
    normals: np.ndarray
    half_thickness: float
    mask: np.ndarray | None = None
    weight: float = 1.0
    reference: Any = None  # the mid-surface (a PolyMesh in the term's units), for :meth:`at`
    name: ClassVar[str] = "hull"
    vertex_local: ClassVar[bool] = True
    constraint: ClassVar[bool] = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", points_array(self.points, "points"))
        object.__setattr__(self, "normals", points_array(self.normals, "normals"))
        if not (np.isfinite(self.half_thickness) and self.half_thickness >= 0):
            raise InputError(f"the hull's half thickness must be finite and >= 0, got {self.half_thickness}")

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "HullPenalty":

        t = params.pop("thickness", ctx.thickness)
        if t is None:
            raise InputError("the hull term needs the shell thickness (--thickness)")
        return cls(points=ctx.reference.vertices, normals=vertex_normals(ctx.reference), half_thickness=0.5 * t,
                   mask=ctx.free, weight=weight, reference=ctx.reference, **params)

    def at(self, V: np.ndarray, projection: tuple | None = None) -> "HullPenalty":
        """The slabs anchored at the closest points of ``V`` on the reference: the normal there
        is the direction from the surface to the vertex where the vertex is off it by more than
        ``h/2`` (the distance's gradient, so ``|⟨n, v − p⟩|`` is the true distance), else the
        surface's interpolated normal (the direction is ill-defined near the surface)."""
        if self.reference is None:
            return self

        V = np.asarray(V, float)
        p, d, nrm = projection if projection is not None else closest_points(V, self.reference)
        off = V - p
        side = np.sign(np.einsum("ij,ij->i", off, nrm))
        side[side == 0] = 1.0
        far = np.isfinite(d) & (d > 0.5 * self.half_thickness)
        n = np.array(nrm, float)
        n[far] = side[far, None] * off[far] / d[far, None]
        ok = np.all(np.isfinite(p), axis=1)  # (a non-finite vertex keeps its old anchor)
        return dataclasses.replace(self, points=np.where(ok[:, None], p, self.points),
                                   normals=np.where(ok[:, None], n, self.normals))

    @cached_property
    def _rows(self) -> sp.csr_matrix:
        return normal_rows(self.normals, self.idx, self.n_vertices)

    def signed_distance_expr(self, X_all):
        """``⟨n_i, v_i − p_i⟩`` of the selected vertices (CasADi): the hard constraint's body."""
        off = np.einsum("ij,ij->i", self.normals[self.idx], self.points[self.idx])
        return ca.mtimes(to_dm(self._rows), X_all) - off

    def signed_distance(self, V: np.ndarray) -> np.ndarray:
        """Signed normal distance of the selected vertices from their reference points."""
        idx = self.idx
        return np.einsum("ij,ij->i", self.normals[idx], np.asarray(V, float)[idx] - self.points[idx])

    def residual_expr(self, X_all):
        return ca.fmax(0, ca.fabs(self.signed_distance_expr(X_all)) - self.half_thickness)

    def vertex_blocks(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # rows outside the slab only: B = n nᵀ, b = n (n·v − sign(s) r) = n (n·p + sign(s) h)
        s = self.signed_distance(V)
        out = np.abs(s) > self.half_thickness
        idx, n = self.idx[out], self.normals[self.idx[out]]
        target = np.einsum("ij,ij->i", n, self.points[idx]) + np.sign(s[out]) * self.half_thickness
        return idx, n[:, :, None] * n[:, None, :], n * target[:, None]

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        s = self.signed_distance(V)
        r = np.maximum(np.abs(s) - self.half_thickness, 0.0)
        return r, (sp.diags(np.where(r > 0, np.sign(s), 0.0)) @ self._rows).tocsr()
