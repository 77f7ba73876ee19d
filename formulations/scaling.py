"""Scale-free units: lengths relative to the diagonal of the smallest upright box around the
scene (:func:`~selfsupport.core.geometry.plan_box_diagonal`: unchanged by turning the scene about the
vertical axis, and equal to the axis-aligned box's diagonal wherever that box is the smallest),
forces relative to the mean nodal load. Every solver works in these units so one set of defaults serves scenes
from 2 m to 30 m and any density or thickness; a scaled scene gives the scaled network.

In scaled units ``v̂ = (v − c) / D``, ``L̂ = L / F`` and, from ``Σ w (v_j − v_i) = L``,
``ŵ = w D / F``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from selfsupport.core.geometry import plan_box_diagonal


@dataclass(frozen=True)
class Scaling:
    center: tuple[float, float, float]
    length: float
    force: float

    @classmethod
    def of(cls, vertices: np.ndarray, loads: np.ndarray, free: np.ndarray) -> "Scaling":
        c = vertices.min(axis=0) * 0.5 + vertices.max(axis=0) * 0.5
        f = float(np.abs(loads[free]).mean()) if free.any() else 1.0
        return cls(tuple(map(float, c)), plan_box_diagonal(vertices), f if f > 0 else 1.0)

    def pos(self, v: np.ndarray) -> np.ndarray:
        return (v - np.asarray(self.center)) / self.length

    def pos_back(self, v: np.ndarray) -> np.ndarray:
        return v * self.length + np.asarray(self.center)

    def load(self, L: np.ndarray) -> np.ndarray:
        return L / self.force

    def load_back(self, L: np.ndarray) -> np.ndarray:
        return L * self.force

    def loads_at(self, model: Any, mesh: Any, X: np.ndarray) -> np.ndarray:
        """Scaled nodal loads of ``model`` (anything with ``nodal(mesh, vertices)``: a load case
        or a set of cases) at scaled positions ``X``: the load models work in SI units."""
        return self.load(model.nodal(mesh, self.pos_back(X)))

    def weight(self, w: np.ndarray) -> np.ndarray:
        return w * self.length / self.force

    def weight_back(self, w: np.ndarray) -> np.ndarray:
        return w * self.force / self.length


#: Lower weight bound relative to the natural weight scale 1 / h² (h = mean edge length in
#: scaled units): weights of a network in equilibrium are of order 1 / (valence · κ h²), so
#: this keeps ε three to four orders below typical weights on any mesh and scene size.
EPS_FACTOR = 1e-4


def default_eps(scaled_vertices: np.ndarray, edges: np.ndarray) -> float:
    """The default lower weight bound ε in scaled units (see :data:`EPS_FACTOR`)."""
    d = scaled_vertices[edges[:, 1]] - scaled_vertices[edges[:, 0]]
    h = float(np.linalg.norm(d, axis=1).mean())
    return EPS_FACTOR / h ** 2
