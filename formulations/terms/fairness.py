"""Smoothness: the umbrella Laplacian of the positions, or of their displacement."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from formulations.equilibrium import to_dm
from formulations.terms.base import Term, TermContext, points_array, vertex_indices
from selfsupport.core.lazy import lazy_module
from selfsupport.core.mesh import PolyMesh

ca = lazy_module("casadi")  # (imported when first used: a plain staggered solve never is)


@dataclass(frozen=True, eq=False)
class Fairness(Term):
    """``Σ_i ‖Σ_j (u_j − u_i) / deg_i‖²`` over the rows ``free`` (all vertices by default), with
    ``u = v − targets`` (``targets=None``: ``u = v``, plain fairness).

    Registered as ``"fairness"``: the displacement from the reference must be smooth, at the
    free interior vertices — which keeps vertices whose weights sit at ε from being thrown far
    away (the original tool smoothed the same way).
    """

    mesh: PolyMesh
    free: np.ndarray | None = None
    targets: np.ndarray | None = None
    weight: float = 1.0
    name: ClassVar[str] = "fairness"
    couples_xyz: ClassVar[bool] = False

    def __post_init__(self) -> None:
        if self.targets is not None:
            object.__setattr__(self, "targets", points_array(self.targets, "targets"))

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "Fairness":
        return cls(mesh=ctx.reference, free=ctx.interior_free, targets=ctx.reference.vertices, weight=weight,
                   **params)

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @cached_property
    def umbrella(self) -> sp.csr_matrix:
        """Rows ``u_i − mean_j u_j`` of the selected vertices over all vertices."""
        m = self.mesh
        n = m.n_vertices
        e = m.edges
        A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                          shape=(n, n)).tocsr()
        deg = np.asarray(A.sum(axis=1)).ravel()
        U = (sp.identity(n) - sp.diags(1.0 / np.maximum(deg, 1)) @ A).tocsr()
        return U[vertex_indices(self.free, n)]

    def residual_expr(self, X_all):
        U = to_dm(sp.kron(self.umbrella, sp.identity(3)))
        shift = 0 if self.targets is None else ca.DM(self.targets.ravel())
        return ca.mtimes(U, X_all - shift)

    def per_coordinate(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        u = np.asarray(V, float) if self.targets is None else np.asarray(V, float) - self.targets
        return self.umbrella @ u, self.umbrella
