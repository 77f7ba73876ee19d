"""Motion along the fixed starting normals (the paper's Step-3 α term as printed)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from formulations.terms.base import PlaneDistance, TermContext
from selfsupport.core.geometry import vertex_normals
from selfsupport.core.mesh import PolyMesh


@dataclass(frozen=True, eq=False)
class NormalDrift(PlaneDistance):
    """``Σ_i ⟨n_i, v_i − v_i⁰⟩²``: the paper's ``α Σ ⟨n_i, v_i − v_i⁰⟩²`` with the starting
    normals ``n_i`` held fixed. Registered as ``"normal_drift"`` (free vertices)."""

    name: ClassVar[str] = "normal_drift"

    @classmethod
    def from_mesh(cls, mesh: PolyMesh, vertices: np.ndarray | None = None, *, mask: np.ndarray | None = None,
                  weight: float = 1.0) -> "NormalDrift":

        v = mesh.vertices if vertices is None else np.asarray(vertices, float)
        return cls(points=v, normals=vertex_normals(mesh, v), mask=mask, weight=weight)

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "NormalDrift":
        return cls.from_mesh(ctx.reference, ctx.vertices, mask=ctx.free, weight=weight, **params)
