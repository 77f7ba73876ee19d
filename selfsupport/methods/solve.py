"""One solve from what a user states: the scene (a file, a shape, a network), its loads and bounds,
the method (or ``"auto"``), limits on time and memory. Input is validated and the memory checked
before any work; the result records the loads, the input's warnings and the method chosen.
:func:`selfsupport.api.solve` is this function."""
from __future__ import annotations

import os
import time
from dataclasses import replace
from typing import Any, Callable, Mapping

from formulations import Problem
from selfsupport.core.defaults import DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.errors import InputError, TooLarge
from selfsupport.core.loads import G
from selfsupport.core.options import check_options
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.problem import load_spec, weight_bounds
from selfsupport.io.scenes import as_scene, design_of
from selfsupport.methods import METHODS, capabilities, make_method
from selfsupport.methods.choice import AUTO, choose_method
from selfsupport.methods.deadline import finish_reserve
from selfsupport.methods.hull_search import solve_in_hull
from selfsupport.methods.memory import check_memory, dense_row_bytes
from selfsupport.methods.validate import load_issues, validate_scene

__all__ = ["solve"]


def solve(scene_or_path: Scene | str | os.PathLike, *, method: str = AUTO, backend: str | None = None,
          density: float = DEFAULT_DENSITY, thickness: float = DEFAULT_THICKNESS, w_max: Any = None,
          eps: Any = None, tol: float | None = None, max_iter: int | None = None,
          time_limit: float | None = None, supports: Any = None, up: str | None = None,
          progress: Callable[[dict], None] | None = None, options: Mapping[str, Any] | None = None,
          objective: Any = None, point_loads: Mapping[int, float] | None = None,
          extra_mass: Mapping[int, float] | None = None, load_cases: Any = None, constraints: Any = (),
          max_memory: float | None = None, warm_start: Network | SolveResult | None = None,
          started: float | None = None, bounds: Any = None, max_stress: float | None = None) -> SolveResult:
    """Find the thrust network nearest to a reference surface.

    Parameters
    ----------
    scene_or_path
        A :class:`~selfsupport.core.scene.Scene` or a scene/mesh file (see :func:`~selfsupport.io.scenes.as_scene`). A network file (``.json``)
        that stores its reference is solved for that reference, starting from the stored
        network (:func:`~selfsupport.io.scenes.design_of`).
    method
        A name in :data:`~selfsupport.methods.METHODS` (``"staggered"``, ``"multilevel"``, ``"ipopt"``, ``"nlopt"``) or
        ``"auto"`` (default): the multilevel method where it pays, else the staggered method
        (:func:`~selfsupport.methods.choice.choose_method`; ``parameters["method_choice"]`` says
        which and why).
    backend
        The method's inner solver, where it has a choice (staggered: Step-2 backend,
        default ``"active-set"``).
    density, thickness
        Self-weight ρ [kg/m³] and t [m]; the load is ρ·t·g per unit surface area.
    w_max, eps
        Upper and lower weight bounds [N/m], scalars or one per edge (``None``: no upper bound /
        the scale-free default). A lower bound of zero or below allows tension down to it: the
        result's ``parameters["tension"]`` counts the edges in tension.
    bounds, max_stress
        Per-edge bounds from a file (or a :class:`~formulations.problem.Bounds`) over ``eps`` /
        ``w_max``, and w_max from an allowable stress [Pa] and ``thickness`` (see
        :func:`~selfsupport.io.problem.weight_bounds`).
    tol, max_iter, time_limit
        Stopping rules; ``None`` keeps the method's defaults (staggered: ``tol`` is the required
        max relative error, ``max_iter`` counts outer iterations; IPOPT: its ``tol`` and its
        iteration limit per load round).
    supports, up
        See :func:`~selfsupport.io.scenes.as_scene`.
    progress
        Called with each iteration's history record.
    options
        Further settings of the method (staggered: fields of
        :class:`~selfsupport.methods.staggered.StaggeredOptions`, e.g. ``{"coupled": True}``).
    objective, point_loads, extra_mass, load_cases, constraints
        The rest of the problem (see :func:`~selfsupport.io.problem.problem`).
    max_memory
        Memory the solve may use [GiB] (default: what the machine has available now); a mesh
        whose estimated need exceeds it is refused before any work
        (:func:`~selfsupport.methods.memory.check_memory`).
    warm_start
        A network to start from instead of the reference (default: the stored network of a
        network file, else none). Used by the staggered method (its offset from its own
        reference and its weights, :mod:`~selfsupport.methods.warm`) and by IPOPT (same mesh);
        the nlopt method, and the staggered method under the masonry hull, start from the
        reference. ``parameters["design"]`` records what was used.
    started
        The ``time.perf_counter()`` value ``time_limit`` counts from (default: the call): the
        command line passes its own start, so that reading the input counts too.

    Returns
    -------
    SolveResult
        Its ``parameters`` gain ``"loads"`` (the self-weight ρ, t), ``"load_model"`` (every load,
        so the file can be re-checked case by case), ``"input_issues"``: the warnings of
        :func:`~selfsupport.methods.validate.validate_scene` and :func:`~selfsupport.methods.validate.load_issues`
        as dicts, ``"cpu"``: the process's CPU seconds at the call (``at_entry``, the origin of
        the staggered history records' ``cpu_s``) and spent in it (``solve``), and with
        ``method="auto"`` ``"method_choice"``: the method chosen and why (one line).

    Raises
    ------
    MeshError, SupportError, InputError
        Unusable input (see :func:`~selfsupport.methods.validate.validate_scene`), before any solving.
    TooLarge
        The solve would need more memory than ``max_memory`` / the machine has.
    """
    # the time limit covers the validation too (1 s at 200k vertices)
    t_entry = time.perf_counter() if started is None else float(started)
    cpu_entry = time.process_time()  # (the origin of the history records' "cpu_s" stamps)
    scene, stored = design_of(as_scene(scene_or_path, supports=supports, up=up))
    start = warm_start if warm_start is not None else stored
    spec = load_spec(density=density, thickness=thickness, point_loads=point_loads, extra_mass=extra_mass,
                     load_cases=load_cases)
    # before the solve allocates its matrices
    check_memory(scene.mesh.n_vertices, method, max_memory, n_cases=max(len(spec.case_specs), 1),
                 extra_bytes=dense_row_bytes(scene.mesh.edges, scene.mesh.n_vertices))
    issues = validate_scene(scene)  # raises for unusable input before any work; warnings go into the result
    prob = Problem.build(scene, spec.cases(scene.mesh.n_vertices), objective=objective, constraints=constraints,
                         bounds=weight_bounds(scene, eps=eps, w_max=w_max, bounds=bounds, max_stress=max_stress,
                                              thickness=thickness))
    issues = [*issues, *load_issues(prob.loads, scene.supports)]
    choice, settings = None, {}
    if method == AUTO:  # (the rule, from the problem: selfsupport.methods.choice)
        choice = choose_method(prob, warm_start=start)
        method, settings = choice.method, dict(choice.settings)
    stops = {k: v for k, v in (("tol", tol), ("max_iter", max_iter), ("time_limit", time_limit)) if v is not None}
    caps = capabilities(method)
    if options:
        if caps.options_type is None:
            takes = [n for n in METHODS if capabilities(n).options_type is not None]
            raise InputError(f"method options {sorted(options)} apply to the {' and '.join(takes)} methods "
                             f"only, not {method!r}")
        check_options(caps.options_class(), options)  # before the work, with the allowed interval
    if len(prob.loads) > 1 and caps.options_type is not None and "ipopt_finish" not in (options or {}):
        # the staggered method may hand several cases to IPOPT (methods/staggered/cases.py): only
        # where IPOPT's estimate fits the same memory
        try:
            check_memory(scene.mesh.n_vertices, "ipopt", max_memory, n_cases=len(prob.loads))
        except TooLarge:
            options = {**dict(options or {}), "ipopt_finish": False}
    solver = make_method(method, backend, **settings)
    # one deadline for the whole solve, handed to the method's every inner loop; it keeps back the
    # time that building and writing the result will take, so that the whole run ends near its limit
    until = {} if time_limit is None else {
        "deadline": t_entry + float(time_limit) - finish_reserve(scene.mesh.n_vertices, len(spec.case_specs))}
    design = dict(scene.meta.get("design", {}))
    start_kw, started = _start_keywords(method, caps, start, hull=prob.hull_thickness() is not None,
                                        name="stored network" if start is stored else "warm_start network")
    if start is not None:
        design["start"] = started
    if prob.hull_thickness() is not None:
        # the masonry hull: search for a certifying network, or the verdict "infeasible"
        result = solve_in_hull(prob, method=solver, options={**dict(options or {}), **stops}, progress=progress,
                               **start_kw)
    else:
        result = solver.solve(prob, {**dict(options or {}), **stops}, progress=progress, **start_kw, **until)
    load_model = {"type": "self_weight", "density": float(density), "thickness": float(thickness), "g": G}
    extra = {"design": design} if design else {}
    tension = result.tension()
    if tension["edges"] or prob.bounds.allows_tension:  # (reported whenever tension was allowed)
        extra["tension"] = tension
    if choice is not None:
        extra["method_choice"] = choice.as_dict()
    cpu = {"at_entry": cpu_entry, "solve": time.process_time() - cpu_entry}  # process CPU seconds
    return replace(result, parameters={**result.parameters, "loads": load_model, "load_model": spec.describe(),
                                       "input_issues": [i.as_dict() for i in issues], "cpu": cpu, **extra})


def _start_keywords(method: str, caps: Any, start: Any, *, hull: bool, name: str) -> tuple[dict[str, Any], str]:
    """How ``method`` (with capabilities ``caps``) is handed the starting network ``start``
    (``warm_start=``), and what the solve then starts from, in words for ``parameters["design"]``
    (``name``: what ``start`` is). Under the hull only a method that holds it as hard rows keeps
    the start (the penalty search starts from the reference)."""
    if start is None:
        return {}, "reference"
    if caps.warm_start and (caps.hull_as_rows or not hull):
        return {"warm_start": start}, name
    why = f"the {method} hull search starts there" if caps.warm_start else f"{method} takes no start"
    return {}, f"reference ({why})"
