"""Load cases from the command line and from TOML files.

``--point-load VERTEX:NEWTONS`` and ``--extra-mass VERTEX:KG`` (repeatable) add to every case;
``NEWTONS`` is a load, positive downward (``V:5000`` hangs 5 kN at vertex V; a negative value
pulls up). ``--load-cases FILE`` names several cases; each holds the self-weight unless it says
``self_weight = false``, plus its own loads::

    # cases.toml — one geometry must stand under each case
    [cases.empty]                      # self-weight only

    [cases.snow]
    uniform_mass = 80.0                # kg per m² of surface, on every vertex's area

    [cases.hoist]
    point_loads = { "40" = 5000.0 }    # N, positive down
    extra_mass = { "12" = 300.0 }      # kg

A case without ``self_weight`` cannot be checked by the paper's error metric (it divides by
each vertex's load), so a case must load every free vertex.

Example
-------
>>> spec = LoadSpec(density=2000.0, thickness=0.1, point_loads={3: 5000.0})
>>> cases = spec.cases(4)
>>> list(cases), round(float(cases["self-weight"].cases[1].forces[3]), 1)
(['self-weight'], -5000.0)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from selfsupport.core.defaults import DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.errors import InputError
from selfsupport.core.lazy import lazy_module
from selfsupport.core.loads import ExtraMass, G, LoadCase, PointLoad, SelfWeight

tomllib = lazy_module("tomllib")  # (its regexes compile on import: ~3 ms of every start; load-case files only)


def parse_vertex_value(text: str, what: str) -> tuple[int, float]:
    """``"VERTEX:VALUE"`` -> ``(vertex, value)`` (the CLI's ``--point-load`` / ``--extra-mass``)."""
    v, sep, x = str(text).partition(":")
    try:
        vertex, value = int(v), float(x)
    except ValueError:
        vertex, value = -1, float("nan")
    if not sep or vertex < 0 or not np.isfinite(value):
        raise InputError(f"{what} needs VERTEX:VALUE with a vertex index >= 0 and a finite number, got {text!r}")
    return vertex, value


def _vertex_map(d: Any, where: str) -> dict[int, float]:
    if not isinstance(d, Mapping):
        raise InputError(f"{where} must be a table of vertex = value, e.g. {{ \"12\" = 500.0 }}")
    out: dict[int, float] = {}
    for k, v in d.items():
        vertex, value = parse_vertex_value(f"{k}:{v}", where)
        out[vertex] = out.get(vertex, 0.0) + value
    return out


@dataclass(frozen=True)
class CaseSpec:
    """One named case: self-weight (or not), a uniform extra mass per area, point loads, masses."""

    name: str
    self_weight: bool = True
    uniform_mass: float = 0.0  # kg/m²
    point_loads: dict[int, float] = field(default_factory=dict)  # N, positive down
    extra_mass: dict[int, float] = field(default_factory=dict)  # kg


@dataclass(frozen=True)
class LoadSpec:
    """The load model of a solve as the user gave it: self-weight ρ, t; loads that apply to every
    case; and the named cases (none: one case, ``"self-weight"``). JSON-ready via :meth:`describe`."""

    density: float
    thickness: float
    point_loads: dict[int, float] = field(default_factory=dict)
    extra_mass: dict[int, float] = field(default_factory=dict)
    case_specs: tuple[CaseSpec, ...] = ()

    def __post_init__(self) -> None:
        for name, v in (("density", self.density), ("thickness", self.thickness)):
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a positive number, got {v}")

    def cases(self, n_vertices: int) -> dict[str, LoadCase]:
        """name -> load model on a mesh of ``n_vertices`` (the scene's own extras are added later)."""
        specs = self.case_specs or (CaseSpec("self-weight"),)
        out: dict[str, LoadCase] = {}
        for c in specs:
            parts: list[LoadCase] = []
            if c.self_weight:
                parts.append(SelfWeight(density=self.density, thickness=self.thickness))
            if c.uniform_mass:
                parts.append(SelfWeight(density=c.uniform_mass, thickness=1.0))  # kg/m² × g per area
            forces = {**self.point_loads}
            for k, v in c.point_loads.items():
                forces[k] = forces.get(k, 0.0) + v
            masses = {**self.extra_mass}
            for k, v in c.extra_mass.items():
                masses[k] = masses.get(k, 0.0) + v
            for d, what in ((forces, "point load"), (masses, "extra mass")):
                bad = [k for k in d if k >= n_vertices]
                if bad:
                    raise InputError(f"{what} on vertex {bad[0]}, but the mesh has vertices 0..{n_vertices - 1}")
            if forces:
                f = np.zeros(n_vertices)
                for k, v in forces.items():
                    f[k] -= v  # a load, positive down -> signed force, negative down
                parts.append(PointLoad(f))
            if masses:
                m = np.zeros(n_vertices)
                for k, v in masses.items():
                    m[k] += v
                parts.append(ExtraMass(m))
            if not parts:
                raise InputError(f"load case {c.name!r} has no load at all")
            total = parts[0]
            for p in parts[1:]:
                total = total + p
            out[c.name] = total
        return out

    def describe(self) -> dict[str, Any]:
        """For the network file (``parameters.load_model``): enough to rebuild every case."""
        return {"density": self.density, "thickness": self.thickness, "g": G,
                "point_loads": {str(k): v for k, v in self.point_loads.items()},
                "extra_mass": {str(k): v for k, v in self.extra_mass.items()},
                "cases": [{"name": c.name, "self_weight": c.self_weight, "uniform_mass": c.uniform_mass,
                           "point_loads": {str(k): v for k, v in c.point_loads.items()},
                           "extra_mass": {str(k): v for k, v in c.extra_mass.items()}} for c in self.case_specs]}

    @classmethod
    def from_description(cls, d: Mapping[str, Any]) -> "LoadSpec":
        """The inverse of :meth:`describe` (missing keys: defaults)."""
        return cls(density=float(d.get("density", DEFAULT_DENSITY)), thickness=float(d.get("thickness", DEFAULT_THICKNESS)),
                   point_loads=_vertex_map(d.get("point_loads", {}), "point_loads"),
                   extra_mass=_vertex_map(d.get("extra_mass", {}), "extra_mass"),
                   case_specs=tuple(_case(c.get("name", f"case{i}"), c, "cases")
                                    for i, c in enumerate(d.get("cases", []))))


_CASE_KEYS = {"self_weight", "uniform_mass", "point_loads", "extra_mass", "name"}


def _case(name: str, d: Any, where: str) -> CaseSpec:
    if not isinstance(d, Mapping):
        raise InputError(f"{where}: case {name!r} must be a table")
    unknown = set(d) - _CASE_KEYS
    if unknown:
        raise InputError(f"{where}: case {name!r} has unknown key(s) {sorted(unknown)}; "
                         f"use {sorted(_CASE_KEYS - {'name'})}")
    sw = d.get("self_weight", True)
    if not isinstance(sw, bool):
        raise InputError(f"{where}: case {name!r}: self_weight must be true or false")
    um = d.get("uniform_mass", 0.0)
    if not isinstance(um, (int, float)) or isinstance(um, bool) or not np.isfinite(um) or um < 0:
        raise InputError(f"{where}: case {name!r}: uniform_mass must be a number >= 0 (kg/m²)")
    return CaseSpec(name=str(name), self_weight=sw, uniform_mass=float(um),
                    point_loads=_vertex_map(d.get("point_loads", {}), f"{where}: case {name!r}: point_loads"),
                    extra_mass=_vertex_map(d.get("extra_mass", {}), f"{where}: case {name!r}: extra_mass"))


def read_load_cases(path: str | Path) -> tuple[CaseSpec, ...]:
    """The ``[cases.NAME]`` tables of a TOML file, in order."""
    p = Path(path)
    try:
        d = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise InputError(f"{p}: cannot read the load cases ({e.strerror or e})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: not a valid TOML file ({e}); see selfsupport solve --help for the format") from None
    except RecursionError:  # (tomllib recurses once per nested array or inline table)
        raise InputError(f"{p}: nests its values deeper than the TOML reader can follow; "
                         "a load-case file is flat [cases.NAME] tables") from None
    cases = d.get("cases")
    if not isinstance(cases, Mapping) or not cases:
        raise InputError(f"{p}: no [cases.NAME] tables; write e.g. [cases.empty] and [cases.snow] with their loads")
    extra = set(d) - {"cases"}
    if extra:
        raise InputError(f"{p}: unknown top-level key(s) {sorted(extra)}; only [cases.NAME] tables are read")
    return tuple(_case(name, c, str(p)) for name, c in cases.items())
