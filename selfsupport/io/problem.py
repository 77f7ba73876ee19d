"""The problem a user states: self-weight and extra loads, load cases, weight bounds, objective
and constraints of a scene, as a :class:`~formulations.Problem`."""
from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from formulations import Bounds, Problem
from formulations.problem import stress_w_max
from selfsupport.core.defaults import DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.errors import InputError
from selfsupport.core.loads import LoadCase, SelfWeight, with_scene_extras
from selfsupport.core.scene import Scene
from selfsupport.io.bounds import read_bounds
from selfsupport.io.loadcases import LoadSpec, read_load_cases

__all__ = ["load_spec", "problem", "scene_loads", "weight_bounds"]


def scene_loads(scene: Scene, *, density: float = DEFAULT_DENSITY, thickness: float = DEFAULT_THICKNESS) -> LoadCase:
    """Self-weight ρ·t·g plus the scene's extra masses and point loads."""
    for name, v in (("density", density), ("thickness", thickness)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v}")
    return with_scene_extras(SelfWeight(density=float(density), thickness=float(thickness)), scene)


def load_spec(*, density: float = DEFAULT_DENSITY, thickness: float = DEFAULT_THICKNESS,
              point_loads: Mapping[int, float] | None = None, extra_mass: Mapping[int, float] | None = None,
              load_cases: Any = None) -> Any:
    """The load model: self-weight ρ [kg/m³], t [m]; ``point_loads`` {vertex: N, positive down}
    and ``extra_mass`` {vertex: kg} on every case; ``load_cases`` a TOML file or a sequence of
    :class:`~selfsupport.io.loadcases.CaseSpec` (see :mod:`selfsupport.io.loadcases`)."""
    cases = ()
    if load_cases is not None:
        cases = read_load_cases(load_cases) if isinstance(load_cases, (str, os.PathLike)) else tuple(load_cases)
    return LoadSpec(density=float(density), thickness=float(thickness), point_loads=dict(point_loads or {}),
                    extra_mass=dict(extra_mass or {}), case_specs=cases)


def problem(scene: Scene, *, density: float = DEFAULT_DENSITY, thickness: float = DEFAULT_THICKNESS,
            point_loads: Mapping[int, float] | None = None, extra_mass: Mapping[int, float] | None = None,
            load_cases: Any = None, w_max: Any = None, eps: Any = None, objective: Any = None,
            constraints: Any = (), bounds: Any = None, max_stress: float | None = None) -> Problem:
    """The :class:`~formulations.Problem` of a scene: load cases from :func:`load_spec` (plus the
    scene's own extras), bounds [N/m, scalar or per edge; see :func:`weight_bounds` for
    ``bounds`` and ``max_stress``], objective (``{"name": weight}``, ``"name=weight"`` strings,
    terms; ``None``: the method's default) and constraints (``"hull"``, ``"fixed_top_view"`` or
    instances)."""
    spec = load_spec(density=density, thickness=thickness, point_loads=point_loads, extra_mass=extra_mass,
                     load_cases=load_cases)
    return Problem.build(scene, spec.cases(scene.mesh.n_vertices), objective=objective, constraints=constraints,
                         bounds=weight_bounds(scene, eps=eps, w_max=w_max, bounds=bounds, max_stress=max_stress,
                                              thickness=thickness))


def weight_bounds(scene: Scene, *, eps: Any = None, w_max: Any = None, bounds: Any = None,
                  max_stress: float | None = None, thickness: float = DEFAULT_THICKNESS) -> Bounds:
    """The weight bounds a designer states, per edge of ``scene``'s mesh.

    Parameters
    ----------
    scene
        The scene being solved (the bounds file names edges of its mesh).
    eps, w_max
        Lower and upper bounds [N/m], scalars or one per edge (``None``: the scale-free default
        ε / unbounded). A lower bound of zero or below allows tension down to it.
    bounds
        Per-edge bounds over ``eps`` / ``w_max``: a bounds file (``.csv`` / ``.json``,
        :func:`~selfsupport.io.bounds.read_bounds`) or a :class:`~formulations.problem.Bounds`
        (NaN entries: not stated).
    max_stress
        Allowable stress σ_max [Pa]: ``w_max`` per edge from the shell ``thickness`` and each
        edge's tributary width (:func:`~formulations.problem.stress_w_max`); not with ``w_max``.

    Returns
    -------
    Bounds
        What :meth:`~formulations.Problem.build` states over its scalar bounds.
    """
    if max_stress is not None:
        if w_max is not None:
            raise InputError("give either w_max (--wmax) or a maximum stress (--max-stress), not both: each "
                             "states the upper weight bound")
        w_max = stress_w_max(scene.mesh, max_stress, thickness)
    base = Bounds(eps, w_max)
    if bounds is None:
        return base
    if isinstance(bounds, (str, os.PathLike)):
        bounds = read_bounds(bounds, scene.mesh)
    if not isinstance(bounds, Bounds):
        raise InputError(f"bounds must be a bounds file or a Bounds, not a {type(bounds).__name__}")
    return bounds.over(base)
