"""Load cases of a problem: a named set of load models for which one geometry must stand.

Each case maps a geometry to signed vertical nodal loads ``A_i F_i`` [N] (the load models of
:mod:`selfsupport.core.loads`: self-weight re-estimated from the geometry, extra mass, point loads;
they add up with ``+``). With several cases a network has one weight vector per case, and every
case must be in equilibrium with compressive weights: the shell stands empty *and* under snow.
The scene's own extra masses and point loads (``.sss`` handled vertices) belong to every case.

Example
-------
>>> from selfsupport.core.shapes import make_shape
>>> from selfsupport.core.loads import SelfWeight, PointLoad
>>> import numpy as np
>>> scene = make_shape("dome", n_vertices=60)
>>> f = np.zeros(scene.mesh.n_vertices); f[30] = -5000.0
>>> cases = LoadCases.of({"empty": SelfWeight(), "point": SelfWeight() + PointLoad(f)}, scene)
>>> cases.names, len(cases)
(('empty', 'point'), 2)
>>> L = cases.nodal(scene.mesh, scene.mesh.vertices)
>>> round(float(L[1].sum() - L[0].sum()), 6)
-5000.0
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Mapping

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.loads import LoadCase, SelfWeight, with_scene_extras
from selfsupport.core.mesh import PolyMesh

#: Name of the case when a problem has a single one.
DEFAULT_CASE = "self-weight"


@dataclass(frozen=True, eq=False)
class LoadCases:
    """An ordered, named, non-empty set of load cases."""

    cases: tuple[tuple[str, LoadCase], ...]

    def __post_init__(self) -> None:
        if not self.cases:
            raise InputError("a problem needs at least one load case")
        names = [n for n, _ in self.cases]
        if len(set(names)) != len(names):
            raise InputError(f"load case names must be unique, got {names}")
        for n, c in self.cases:
            if not isinstance(c, LoadCase):
                raise InputError(f"load case {n!r} is a {type(c).__name__}, not a load model")
            if c.has_horizontal:  # (nodal() is the vertical part: a method would drop the rest unseen)
                raise InputError(f"load case {n!r} has horizontal loads: the form-finding methods balance vertical "
                                 "loads only; assess a horizontal acceleration with 'selfsupport stability "
                                 "--max-horizontal' (selfsupport.structure.limit.max_horizontal)")

    @classmethod
    def of(cls, loads: "LoadCase | LoadCases | Mapping[str, LoadCase] | None", scene=None) -> "LoadCases":
        """From one load model (``None``: default self-weight), a mapping name -> model, or a set;
        the scene's extra masses and point loads are added to every case (once)."""
        if isinstance(loads, LoadCases):
            cases = loads.cases
        elif loads is None or isinstance(loads, LoadCase):
            cases = ((DEFAULT_CASE, loads if loads is not None else SelfWeight()),)
        elif isinstance(loads, Mapping):
            cases = tuple((str(k), v) for k, v in loads.items())
        else:
            raise InputError(f"loads must be a load model or a mapping name -> load model, got {type(loads).__name__}")
        if scene is not None:
            cases = tuple((n, with_scene_extras(c, scene)) for n, c in cases)
        return cls(cases)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.cases)

    @property
    def models(self) -> tuple[LoadCase, ...]:
        return tuple(c for _, c in self.cases)

    @property
    def primary(self) -> LoadCase:
        """The first case (it sets the force unit of the scaling)."""
        return self.cases[0][1]

    def __len__(self) -> int:
        return len(self.cases)

    def __iter__(self) -> Iterator[tuple[str, LoadCase]]:
        return iter(self.cases)

    @property
    def depends_on_geometry(self) -> bool:
        return any(c.depends_on_geometry for c in self.models)

    def nodal(self, mesh: PolyMesh, vertices: np.ndarray) -> np.ndarray:
        """``(n_cases, n)`` signed nodal loads [N] at the given positions."""
        return np.stack([c.nodal(mesh, vertices) for c in self.models])
