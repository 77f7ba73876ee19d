"""Planar faces in equilibrium (paper §5): one method's solve, and where it does not converge,
two finishes from the network in equilibrium without the planarity rows — the planar homotopy
(:mod:`selfsupport.methods.planar_homotopy`), and where that does not converge either, the
simultaneous solve (IPOPT) with the planarity rows as equations.

Why the finishes start there: the staggered method holds planarity as a penalty in Step 3 and on
some meshes stalls with the fit error and the penalty pulling against each other (the paper's
vault remeshed along its principal directions: max relative error 2.6e-2, non-planarity 1.2e-2;
lilium's remeshes: 0.3-1.1). A network in equilibrium on the same mesh is a 0.05-0.3 s staggered
solve without the rows. The homotopy lowers the non-planarity allowed in small cuts and restores
equilibrium after each by Newton steps (lilium's parametrization remesh: planar to 7e-4 in
equilibrium in about 20 s, where IPOPT from the same start ran into its time limit at max
relative error 28). IPOPT stays as the last resort: on the vault's principal remesh, started from
the network in equilibrium, it converged in 0.5 s. The best run is returned and
``parameters["planar_finish"]`` says how each ended.

Nearest, not just planar: the homotopy's minimum-norm steps end near its start, and the
staggered network in equilibrium it starts from can be far from the design (the paper's vault
remeshed along its principal directions: free edges lifted 0.24 of the diagonal, and without
the pull the planar network ends 3.3e-2 of it from the reference, mean). The homotopy therefore pulls its planar
end toward a reference surface while it stays planar and in equilibrium (and, where it does not
converge, its start before it runs again): with ``reference`` the design's surface, that vault
ends an order of magnitude closer to it (the pq study's table in the benchmarks page). With
``reference`` given, a first solve that converged alone is pulled the same way.

A barrel vault remeshed along its relative principal directions (the staggered method stalls
on it, the homotopy converges):

>>> from selfsupport import api
>>> from selfsupport.core.shapes import make_shape
>>> from selfsupport.remesh.streamlines import remesh
>>> from selfsupport.remesh.planar import solve_planar
>>> net = api.solve(make_shape("barrel_vault", nx=8, ny=10)).network
>>> r = solve_planar(remesh(net, field="principal", spacing=0.1, relative=True).scene, tol=1e-3)
>>> r.status, r.max_relative_error < 1e-8, r.parameters["planarity"]["met"]
('converged', True, True)
>>> r.parameters["planar_finish"]["first"]["status"], r.parameters["planar_finish"]["returned"]
('stalled', 'homotopy')
"""
from __future__ import annotations

import dataclasses
import inspect
import time
from typing import Any

from formulations import Planar
from selfsupport.core.mesh import PolyMesh
from selfsupport.io.problem import problem as stated_problem
from selfsupport.io.scenes import as_scene, design_of
from selfsupport.methods import capabilities, find_method
from selfsupport.methods.choice import AUTO
from selfsupport.methods.planar_homotopy import handles, planar_homotopy
from selfsupport.methods.solve import solve

__all__ = ["solve_planar", "finish_summary", "finish_method", "FIRST_SHARE"]

#: With the finish on and a time limit, the first solve's share of the limit; the rest is left to
#: the finish. The staggered method with the planarity penalty either converges early or crawls
#: to any limit without converging, while the homotopy from the network in equilibrium is what
#: makes stubborn meshes planar: the finish, not the first solve, needs the time.
FIRST_SHARE = 0.25


def finish_method() -> str:
    """The method of the finish: the first registered one whose planarity rows are equations,
    not a penalty, and that starts from a given network."""
    return find_method(planar_rows=True, warm_start=True)


def _better(a: Any, b: Any) -> bool:
    """Whether result ``a`` is better than ``b``: converged first, then the smaller max relative error."""
    if (a.status == "converged") != (b.status == "converged"):
        return a.status == "converged"
    return a.max_relative_error < b.max_relative_error


def _homotopy_problem(scene: Any, planar: list, solve_kw: dict[str, Any]) -> Any:
    """The stated problem with planar faces, when the planar homotopy takes it (one load case, a
    free top view, no hull); else ``None``."""
    problem_kw = {k: v for k, v in solve_kw.items() if k in inspect.signature(stated_problem).parameters}
    problem = stated_problem(scene, constraints=planar, **problem_kw)
    return problem if handles(problem) else None


def _pulled(result: Any, scene: Any, planar: list, reference: PolyMesh | None, deadline: float | None,
            solve_kw: dict[str, Any]) -> Any:
    """``result`` (planar, in equilibrium) drawn toward ``reference`` by the planar homotopy's
    pull, when it converged, has one load case, a free top view and no hull, and ``reference``
    is given; the pulled network when it is converged and closer, else ``result``. The time and
    ``parameters["planar_pull"]`` (the pull's record, ``None`` when it did not run) say so."""
    problem = _homotopy_problem(scene, planar, solve_kw) if reference is not None else None
    if problem is None or result.status != "converged":
        return dataclasses.replace(result, parameters={**result.parameters, "planar_pull": None})
    pulled = planar_homotopy(problem, result, deadline=deadline, reference=reference)
    record = pulled.parameters["homotopy"]["pull"]
    better = (pulled.status == "converged" and record.get("planar") is not None
              and record["planar"]["distance_after"] < record["planar"]["distance_before"])
    kept = pulled if better else result
    return dataclasses.replace(kept, wall_time=result.wall_time + pulled.wall_time,
                               parameters={**kept.parameters, "planar_finish": None,
                                           "planar_pull": {**record, "applied": better}})


def solve_planar(scene: Any, *, tol: float = 1e-3, method: str = "staggered", finish: bool = True,
                 time_limit: float | None = None, equilibrium_tol: float | None = None,
                 reference: PolyMesh | None = None, **solve_kw: Any) -> Any:
    """Solve ``scene`` with planar faces (:class:`formulations.Planar`) by ``method``; when that does
    not converge and ``finish``, by :func:`finish_method` warm-started from the network in
    equilibrium without the planarity rows (module docstring).

    Parameters
    ----------
    scene
        A scene, or anything :func:`selfsupport.methods.solve.solve` takes.
    tol
        Largest quad non-planarity accepted (distance of the diagonals / mean edge length).
    method
        The first solve's method (a name of :data:`selfsupport.methods.METHODS`, or ``"auto"``).
    finish
        Run the finish when the first solve does not converge.
    time_limit
        Wall-clock limit of the whole call [s]; with ``finish``, the first solve gets
        :data:`FIRST_SHARE` of it and the finish what is left, unless ``method`` holds planar faces
        as equations (then there is no finish) (``None``: each solve its method's own default).
    equilibrium_tol
        The solves' required max relative error (their ``tol``; ``None``: each method's default).
    reference
        The surface the homotopy's planar network is pulled toward once it is planar and in
        equilibrium (:func:`~selfsupport.methods.planar_homotopy.planar_homotopy`; ``None``: the
        scene's own reference). For a remesh, whose reference is the network it was lifted to,
        the design's surface (the network's ``reference``).
    **solve_kw
        Passed to every :func:`selfsupport.methods.solve.solve` (loads, bounds, objective, ...).

    Returns
    -------
    SolveResult
        The better run (converged first, then the smaller max relative error) with the time and
        iterations of all runs, its status ``time_limit`` when it did not converge and the limit
        has passed (a run was cut or skipped for want of time); ``parameters["planar_finish"]``
        describes the finish (``None`` when it did not run).
    """


    t0 = time.perf_counter()
    if equilibrium_tol is not None:
        solve_kw["tol"] = equilibrium_tol
    planar = list(solve_kw.pop("constraints", ()) or ()) + [Planar(tol=tol)]
    # the scene once, with the caller's supports and up-axis: every run below solves this one
    # (a network file: its stored design, and the first solve starts from its stored network)
    scene, stored = design_of(as_scene(scene, supports=solve_kw.pop("supports", None), up=solve_kw.pop("up", None)))
    start = solve_kw.pop("warm_start", None)
    start = {"warm_start": stored if start is None else start} if start is not None or stored is not None else {}

    def left(share: float = 1.0) -> dict[str, float]:
        if time_limit is None:
            return {}
        return {"time_limit": max(share * time_limit - (time.perf_counter() - t0), 1e-3)}

    def out_of_time() -> bool:
        return time_limit is not None and time.perf_counter() - t0 >= time_limit

    # (a method with planarity rows as equations has no finish: its solve gets the whole limit)
    rows = method != AUTO and capabilities(method).planar_rows
    first = solve(scene, method=method, constraints=planar, **left(FIRST_SHARE if finish and not rows else 1.0),
                  **start, **solve_kw)
    if (first.status in ("converged", "interrupted") or not finish or out_of_time()
            or capabilities(first.method if method == AUTO else method).planar_rows):
        # (a method with planarity rows as equations: the finish would solve the same rows again)
        return _pulled(dataclasses.replace(first, parameters={**first.parameters, "planar_finish": None}),
                       scene, planar, reference if finish and not out_of_time() else None,
                       None if time_limit is None else t0 + time_limit, solve_kw)
    free = [c for c in planar if not isinstance(c, Planar)]
    eq = solve(scene, method="staggered", constraints=free, **left(), **start, **solve_kw)
    if eq.status != "converged":
        note = f"no finish: the mesh has no network in equilibrium without planar faces either ({eq.status})"
        return dataclasses.replace(first, wall_time=time.perf_counter() - t0, message=f"{first.message}; {note}",
                                   parameters={**first.parameters, "planar_finish": {"status": "not run", "why": note}})
    runs = [("first", first)]
    problem = _homotopy_problem(scene, planar, solve_kw)
    if problem is not None:
        runs.append(("homotopy", planar_homotopy(problem, eq, deadline=None if time_limit is None
                                                 else t0 + time_limit, reference=reference)))
    if runs[-1][1].status != "converged" and not out_of_time():
        fm = finish_method()  # (the first method's options are not its own unless it takes options)
        kw = {k: v for k, v in solve_kw.items() if k != "options" or capabilities(fm).options_type is not None}
        runs.append(("finish", solve(scene, method=fm, constraints=planar, warm_start=eq, **left(), **kw)))
    name, chosen = runs[0]
    for n_, r in runs[1:]:
        if _better(r, chosen):
            name, chosen = n_, r
    note = f"{method} with planar faces ended {first.status} at max relative error {first.max_relative_error:.2e}; " + \
        "; ".join(f"{r.method} from the network in equilibrium without them ({eq.iterations} iterations) ended "
                  f"{r.status} at {r.max_relative_error:.2e}" for _, r in runs[1:])
    summary = {n_: {"method": r.method, "status": r.status, "max_relative_error": r.max_relative_error,
                    "iterations": r.iterations, "wall_time": r.wall_time} for n_, r in runs}
    # (a call past its limit that did not converge ended by the limit: a run skipped or cut for want of time)
    status = chosen.status if chosen.status == "converged" or not out_of_time() else "time_limit"
    return dataclasses.replace(
        chosen, status=status, wall_time=time.perf_counter() - t0,
        iterations=eq.iterations + sum(r.iterations for _, r in runs),
        message="; ".join(m for m in (chosen.message, note) if m),
        parameters={**chosen.parameters, "planar_finish": {
            **summary, "equilibrium": {"status": eq.status, "iterations": eq.iterations, "wall_time": eq.wall_time},
            "returned": name}})


def finish_summary(result: Any) -> str:
    """One line on how :func:`solve_planar` ended: the first method alone, or it and the finish."""
    f = result.parameters.get("planar_finish")
    if f is None:
        pull = result.parameters.get("planar_pull")
        return "the first method alone" + (", then pulled toward the reference" if pull and pull["applied"] else "")
    if "why" in f:
        return f["why"]
    then = ", then ".join(f"{f[k]['method']} {f[k]['status']} ({f[k]['max_relative_error']:.1e})"
                          for k in ("homotopy", "finish") if k in f)
    return f"{f['first']['method']} {f['first']['status']}, then {then}; returned: the {f['returned']} run"
