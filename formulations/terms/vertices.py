"""Squared distance to target vertices (the simultaneous method's default objective)."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from formulations.terms.base import Term, TermContext, points_array, selection, vertex_indices


@dataclass(frozen=True, eq=False)
class PointDistance(Term):
    """``Σ_i ‖v_i − t_i‖²`` over the selected vertices (``mask``; all by default).

    Registered as ``"vertices"``: targets are the reference vertices, free vertices only.
    """

    targets: np.ndarray
    mask: np.ndarray | None = None
    weight: float = 1.0
    name: ClassVar[str] = "vertices"
    couples_xyz: ClassVar[bool] = False
    vertex_local: ClassVar[bool] = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "targets", points_array(self.targets, "targets"))

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "PointDistance":
        return cls(targets=ctx.reference.vertices, mask=ctx.free, weight=weight, **params)

    @property
    def n_vertices(self) -> int:
        return self.targets.shape[0]

    @cached_property
    def idx(self) -> np.ndarray:
        return vertex_indices(self.mask, self.n_vertices)

    def residual_expr(self, X_all):
        rows = (3 * self.idx[:, None] + np.arange(3)).ravel()
        return X_all[rows.tolist()] - self.targets[self.idx].ravel()

    def per_coordinate(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        idx = self.idx
        return np.asarray(V, float)[idx] - self.targets[idx], selection(idx, self.n_vertices)
