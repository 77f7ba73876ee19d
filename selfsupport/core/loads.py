"""Load cases (paper Step 1). Each case maps a geometry to signed vertical nodal loads
``A_i F_i`` in newtons (negative = down); cases add up with ``+``. A case may also put
horizontal loads on the vertices (:meth:`LoadCase.horizontal`: a pseudo-static horizontal
acceleration, :class:`HorizontalAcceleration`); :func:`load_vectors_of` gives both as 3-vectors.

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
from typing import Sequence

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.geometry import vertex_areas
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene

G = 9.81


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

    def horizontal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        """``(n, 2)`` horizontal (x, y) nodal loads [N]; none for a vertical load."""
        return np.zeros((mesh.n_vertices, 2))

    @property
    def has_horizontal(self) -> bool:
        """Does the case put horizontal loads on the vertices?"""
        return False

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

    def horizontal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        out = np.zeros((mesh.n_vertices, 2))
        for c in self.cases:
            out = out + c.horizontal(mesh, vertices)
        return out

    @property
    def has_horizontal(self) -> bool:
        return any(c.has_horizontal for c in self.cases)

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


def plan_direction(spec: str | float) -> np.ndarray:
    """The unit plan vector of a direction: ``"x"``, ``"y"``, ``"-x"``, ``"-y"`` or an angle in
    degrees from the x axis towards the y axis (a number, or its text).

    >>> plan_direction("y").tolist(), plan_direction("-x").tolist(), np.round(plan_direction("45"), 6).tolist()
    ([0.0, 1.0], [-1.0, 0.0], [0.707107, 0.707107])
    """
    named = {"x": 0.0, "y": 90.0, "-x": 180.0, "-y": 270.0, "+x": 0.0, "+y": 90.0}
    text = str(spec).strip().lower()
    if text in named:
        deg = named[text]
    else:
        try:
            deg = float(text)
        except ValueError:
            raise InputError(f"direction {spec!r}: give x, y, -x, -y or an angle in degrees from the x axis") from None
        if not np.isfinite(deg):
            raise InputError(f"direction {spec!r}: give a finite angle in degrees")
    a = np.deg2rad(deg)
    d = np.array([np.cos(a), np.sin(a)])
    d[np.abs(d) < 1e-15] = 0.0  # (cos 90° is 6e-17: "y" is exactly y)
    return d


@dataclass(frozen=True)
class HorizontalAcceleration(LoadCase):
    """A pseudo-static horizontal acceleration ``a g`` in a plan direction (the seismic check of
    masonry): every vertex gets the horizontal load ``a`` × its weight under ``of`` (the vertical
    loads that are masses accelerated with the vault: its self-weight, extra masses), along
    ``direction``. It adds no vertical load; combine it with ``of`` for the whole case.

    >>> from selfsupport.core.mesh import PolyMesh
    >>> m = PolyMesh.from_faces(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.]]), [[0, 1, 2]])
    >>> sw = SelfWeight(density=1000.0, thickness=0.1)
    >>> h = HorizontalAcceleration(0.2, "x", sw).horizontal(m, m.vertices)
    >>> bool(np.allclose(h[:, 0], 0.2 * -sw.nodal(m, m.vertices)) and np.all(h[:, 1] == 0))
    True
    """

    acceleration: float  # in units of g
    direction: str | float = "x"
    of: LoadCase = SelfWeight()

    def __post_init__(self) -> None:
        if not (np.isfinite(self.acceleration) and self.acceleration >= 0):
            raise InputError(f"horizontal acceleration {self.acceleration}: give a finite number >= 0 (in g)")
        plan_direction(self.direction)

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        return np.zeros(mesh.n_vertices)

    def horizontal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        weight = np.maximum(-np.asarray(self.of.nodal(mesh, vertices), float), 0.0)  # (upward loads carry no mass)
        return self.acceleration * weight[:, None] * plan_direction(self.direction)[None, :]

    @property
    def has_horizontal(self) -> bool:
        return self.acceleration > 0

    @property
    def depends_on_geometry(self) -> bool:
        return self.of.depends_on_geometry


def load_vectors_of(case: LoadCase, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
    """``(n, 3)`` nodal load vectors [N] of a case: its horizontal loads and its vertical ones."""
    return np.column_stack([case.horizontal(mesh, vertices), case.nodal(mesh, vertices)])


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


def spread_mass(scene: Scene, at: Sequence[int] | None, kg: float) -> dict[int, float]:
    """``kg`` spread evenly over the vertices ``at`` (default: the scene's free handled vertices;
    a handled vertex that is also pinned carries nothing, lilium-pillar has one)."""
    if at is None or len(at) == 0:
        if scene.handles is None or not np.any(scene.handles):
            raise InputError("no vertices to load: give --load-at VERTEX[,VERTEX...] (the scene has no handled vertices)")
        at = np.flatnonzero(scene.handles & ~scene.supports).tolist()
        if not at:
            raise InputError("no vertices to load: the scene's handled vertices are all supports; give --load-at "
                             "VERTEX[,VERTEX...] (free vertices)")
    at = sorted({int(v) for v in at})
    n = scene.mesh.n_vertices
    bad = [v for v in at if not 0 <= v < n]
    if bad:
        raise InputError(f"--load-at vertex {bad[0]} is outside 0..{n - 1}")
    sup = [v for v in at if scene.supports[v]]
    if sup:
        raise InputError(f"--load-at vertex {sup[0]} is a support: its load goes straight into the ground; "
                         "load free vertices")
    if not (np.isfinite(kg) and kg >= 0):
        raise InputError(f"added mass must be a finite number >= 0 kg, got {kg}")
    return {v: float(kg) / len(at) for v in at}
