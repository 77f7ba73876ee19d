"""A design problem: reference mesh, supports and loads, before any solve."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from selfsupport.core.errors import SupportError
from selfsupport.core.mesh import PolyMesh


@dataclass(frozen=True, eq=False)
class Scene:
    """The input of a solve.

    Parameters
    ----------
    mesh
        The reference mesh (z up, SI units). It is also the starting geometry.
    supports
        Boolean mask: vertices held by the ground (no equilibrium required, kept in place).
    handles
        Boolean mask of handle vertices (the original tool's editing handles; kept for I/O).
    extra_mass
        Extra mass per vertex [kg] (adds ``-g * extra_mass`` to the load).
    point_loads
        Extra signed vertical force per vertex [N] (negative = down).
    name
        For reports.
    """

    mesh: PolyMesh
    supports: np.ndarray
    handles: np.ndarray | None = None
    extra_mass: np.ndarray | None = None
    point_loads: np.ndarray | None = None
    name: str = "scene"
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = self.mesh.n_vertices
        sup = np.asarray(self.supports)
        if sup.dtype != bool:
            idx = sup.astype(np.int64).ravel()
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise SupportError(f"support index {int(idx.max() if idx.max() >= n else idx.min())} is outside 0..{n - 1}")
            sup = np.zeros(n, dtype=bool)
            sup[idx] = True
        if sup.shape != (n,):
            raise SupportError(f"supports mask has {sup.shape[0]} entries for {n} vertices")
        sup = sup.copy()
        sup.setflags(write=False)
        object.__setattr__(self, "supports", sup)
        for name in ("handles", "extra_mass", "point_loads"):
            a = getattr(self, name)
            if a is not None:
                a = np.array(a, dtype=bool if name == "handles" else float).copy()
                if a.shape != (n,):
                    raise SupportError(f"{name} has {a.shape} entries for {n} vertices")
                a.setflags(write=False)
                object.__setattr__(self, name, a)

    @property
    def free(self) -> np.ndarray:
        """Vertices that must be in equilibrium (interior and free boundary)."""
        return ~self.supports

    @property
    def vertex_roles(self) -> np.ndarray:
        """Per vertex: ``"support"``, ``"boundary"`` (free boundary) or ``"interior"``."""
        roles = np.where(self.mesh.boundary_vertex_mask, "boundary", "interior").astype(object)
        roles[self.supports] = "support"
        return roles

    @property
    def active_edges(self) -> np.ndarray:
        """Mask of edges that carry an unknown weight (not both ends supported)."""
        e = self.mesh.edges
        return ~(self.supports[e[:, 0]] & self.supports[e[:, 1]])

    def check_supports(self) -> None:
        """Raise :class:`SupportError` unless every component has a support and a free vertex."""
        if not self.supports.any():
            raise SupportError("the scene has no supports; mark the ground-contact vertices (e.g. --supports boundary or a supports file)")
        if self.supports.all():
            raise SupportError("every vertex is a support, so there is nothing to solve; free some vertices")
        labels = self.mesh.connected_components
        has = np.zeros(labels.max() + 1, dtype=bool)
        has[labels[self.supports]] = True
        if not has.all():
            c = int(np.argmin(has))
            v = int(np.argmax(labels == c))
            raise SupportError(
                f"mesh component containing vertex {v} ({int((labels == c).sum())} vertices) has no support and would fall; "
                "add supports to it or remove it")
