"""Load cases (paper Step 1). Each case maps a geometry to signed vertical nodal loads
``A_i F_i`` in newtons (negative = down); cases add up with ``+``.

Example
-------
>>> import numpy as np
>>> from selfsupport.core.mesh import PolyMesh
>>> m = PolyMesh.from_faces(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.]]), [[0, 1, 2]])
>>> loads = SelfWeight(density=1000.0, thickness=0.1) + PointLoad(np.array([0.0, 0.0, -5.0]))
>>> round(float(loads.nodal(m, m.vertices).sum()), 3)  # -(1000*0.1*9.81*0.5) - 5
-495.5
>>> loads.concentrated, SelfWeight().concentrated  # (a load on single vertices: point loads, extra masses)
(True, False)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from selfsupport.core.geometry import vertex_areas
from selfsupport.core.mesh import PolyMesh

G = 9.81

#: Default material: stone-like density [kg/m³] and shell thickness [m] (the paper's examples).
DEFAULT_DENSITY = 2000.0
DEFAULT_THICKNESS = 0.1


class LoadCase:
    """Base class: ``nodal(mesh, vertices)`` returns an ``(n,)`` array of signed loads [N]."""

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    @property
    def depends_on_geometry(self) -> bool:
        return False

    @property
    def concentrated(self) -> bool:
        """Does the case put loads on single vertices (point loads, extra masses)?"""
        return bool(self.concentrated_at().size)

    def concentrated_at(self) -> np.ndarray:
        """The vertices that carry a point load or an extra mass (sorted indices)."""
        return np.zeros(0, dtype=np.int64)

    def __add__(self, other: "LoadCase") -> "CombinedLoad":
        return CombinedLoad((self, other))


@dataclass(frozen=True)
class CombinedLoad(LoadCase):
    cases: tuple[LoadCase, ...]

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        out = np.zeros(mesh.n_vertices)
        for c in self.cases:
            out = out + c.nodal(mesh, vertices)
        return out

    @property
    def depends_on_geometry(self) -> bool:
        return any(c.depends_on_geometry for c in self.cases)

    def concentrated_at(self) -> np.ndarray:
        return np.unique(np.concatenate([c.concentrated_at() for c in self.cases] + [np.zeros(0, np.int64)]))

    def __add__(self, other: LoadCase) -> "CombinedLoad":
        return CombinedLoad(self.cases + (other,))


@dataclass(frozen=True)
class SelfWeight(LoadCase):
    """Self-weight ρ·t·g × the vertex's area on its incident faces in 3D (re-estimated per call)."""

    density: float = 2000.0  # kg/m^3
    thickness: float = 0.1  # m
    g: float = G

    @property
    def unit_weight(self) -> float:
        """ρ t g: weight per unit surface area [N/m²]."""
        return self.density * self.thickness * self.g

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        return -self.unit_weight * vertex_areas(mesh, vertices)

    @property
    def depends_on_geometry(self) -> bool:
        return True


@dataclass(frozen=True, eq=False)
class PointLoad(LoadCase):
    """Fixed signed vertical forces per vertex [N] (negative = down)."""

    forces: np.ndarray

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        return np.asarray(self.forces, float)

    def concentrated_at(self) -> np.ndarray:
        return np.flatnonzero(np.asarray(self.forces, float) != 0)


@dataclass(frozen=True, eq=False)
class ExtraMass(LoadCase):
    """Extra mass per vertex [kg], pulled down by gravity."""

    mass: np.ndarray
    g: float = G

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        return -self.g * np.asarray(self.mass, float)

    def concentrated_at(self) -> np.ndarray:
        return np.flatnonzero(np.asarray(self.mass, float) != 0)


def with_scene_extras(loads: LoadCase, scene) -> LoadCase:
    """The load case plus the scene's own extra masses and point loads — unless ``loads``
    already holds them (e.g. built by ``api.scene_loads``), which must not count twice."""
    cases = loads.cases if isinstance(loads, CombinedLoad) else (loads,)

    def present(kind: type, attr: str, values: np.ndarray) -> bool:
        return any(isinstance(c, kind) and np.shape(getattr(c, attr)) == values.shape
                   and np.array_equal(np.asarray(getattr(c, attr), float), values) for c in cases)

    if scene.extra_mass is not None and np.any(scene.extra_mass) and not present(ExtraMass, "mass", scene.extra_mass):
        loads = loads + ExtraMass(scene.extra_mass)
    if (scene.point_loads is not None and np.any(scene.point_loads)
            and not present(PointLoad, "forces", scene.point_loads)):
        loads = loads + PointLoad(scene.point_loads)
    return loads
