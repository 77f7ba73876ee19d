"""Distance to the reference surface (paper §3, Step 3's α term)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from formulations.terms.base import PlaneDistance, TermContext
from selfsupport.core.evidence import closest_points
from selfsupport.core.geometry import vertex_normals
from selfsupport.core.mesh import PolyMesh

#: Default tangential hold τ: sliding along the reference costs this fraction of moving off it.
TANGENTIAL = 0.05


@dataclass(frozen=True, eq=False)
class ReferenceDistance(PlaneDistance):
    """Squared distance to the reference surface, linearised: ``p_i`` is the closest point of
    the reference to the current ``v_i`` and ``n_i`` the reference normal there; ``at(V)``
    re-projects (the closest points follow the vertices). ``tangential`` (τ) weakly holds the
    vertices against sliding along the surface.

    Registered as ``"reference"`` (free vertices, ``tangential`` default :data:`TANGENTIAL`).
    """

    reference: PolyMesh | None = None
    name: ClassVar[str] = "reference"

    @classmethod
    def from_reference(cls, vertices: np.ndarray, reference: PolyMesh, *, mask: np.ndarray | None = None,
                       weight: float = 1.0, tangential: float = 0.0) -> "ReferenceDistance":

        p, _, nrm = closest_points(np.asarray(vertices, float), reference)
        return cls(points=p, normals=nrm, mask=mask, weight=weight, tangential=tangential, reference=reference)

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "ReferenceDistance":

        params.setdefault("tangential", TANGENTIAL)
        if np.array_equal(ctx.vertices, ctx.reference.vertices):
            # at the reference itself the closest points are its vertices, the normals its vertex normals
            return cls(points=ctx.vertices, normals=vertex_normals(ctx.reference), mask=ctx.free, weight=weight,
                       reference=ctx.reference, **params)
        return cls.from_reference(ctx.vertices, ctx.reference, mask=ctx.free, weight=weight, **params)

    def at(self, V: np.ndarray, projection: tuple | None = None) -> "ReferenceDistance":
        if self.reference is None:
            return self

        p, _, nrm = projection if projection is not None else closest_points(np.asarray(V, float), self.reference)
        return dataclasses.replace(self, points=p, normals=nrm)
