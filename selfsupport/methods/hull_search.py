"""The masonry hull search: a network in equilibrium whose every free vertex lies inside the hull
(reference ± t/2 along its normal), found by the method's own hard rows where it has them, else by
a penalty ladder."""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Callable, Mapping, Sequence

from formulations import Problem
from formulations.problem import Hull
from selfsupport.core.errors import InputError
from selfsupport.core.result import SolveResult
from selfsupport.methods import capabilities
from selfsupport.methods.base import hull_report
from selfsupport.methods.staggered import StaggeredLinearization

#: What the staggered search tries, in order: 0, no hull (the nearest network); then the hull
#: (the value is :class:`~formulations.problem.Hull`'s penalty, which only penalty-based methods use).
PENALTY_LADDER: tuple[float, ...] = (0.0, Hull.penalty)
#: Max relative equilibrium error of a certifying network.
CERTIFY_TOL = 1e-6


# --------------------------------------------------------------------------------- the hull
def _with_penalty(problem: Problem, thickness: float, penalty: float) -> Problem:
    """The problem with its hull replaced: none (``penalty == 0``) or ``Hull(thickness, penalty)``."""
    kept = tuple(c for c in problem.constraints if not isinstance(c, Hull))
    extra = () if penalty == 0 else (Hull(thickness=thickness, penalty=penalty),)
    return replace(problem, constraints=kept + extra)


def _in_equilibrium(res: SolveResult, tol: float) -> bool:
    # the evidence of the network itself, not the method's label: a run that "stalled" but whose
    # final polish reached equilibrium is as good a certificate as any (the safe theorem asks
    # for a compressive network in equilibrium, not for the way it was found)
    return bool(res.max_relative_error <= tol and res.min_weight >= 0)


def solve_in_hull(problem: Problem, *, method: Any = None, options: Mapping[str, Any] | None = None,
                  penalties: Sequence[float] = PENALTY_LADDER, tol: float = CERTIFY_TOL,
                  warm_start: Any = None, progress: Callable[[dict], None] | None = None) -> SolveResult:
    """A compressive network in equilibrium inside the masonry hull of ``problem`` (which must
    have a :class:`~formulations.problem.Hull` constraint), or the verdict ``infeasible``.

    Parameters
    ----------
    problem
        The design problem with its hull.
    method
        A method instance (default: the staggered method). A method whose capabilities say
        ``hull_as_rows`` (IPOPT) treats the hull as hard rows, warm-started from ``warm_start``
        where it takes a start: one solve decides; any other method climbs ``penalties``.
    options
        The method's options for every solve.
    penalties
        The hull penalties tried in turn (0: no hull); the first network in equilibrium inside
        the hull ends the search.
    tol
        Max relative equilibrium error of a certifying network.
    warm_start
        A previous network on the same mesh, passed to a method that holds the hull as rows and
        takes a start (IPOPT); the penalty search starts from the reference.
    progress
        Called with each solve's history records.

    Returns
    -------
    SolveResult
        ``status`` ``"converged"`` with a certified network, or ``"infeasible"`` with the closest
        network in equilibrium found (or, if none was, the one nearest to equilibrium).
        ``parameters["hull"]`` is :func:`~selfsupport.methods.base.hull_report` plus
        ``certified`` and ``stands``; ``parameters["hull_search"]`` lists every rung.
    """
    t = problem.hull_thickness()
    if t is None:
        raise InputError("solve_in_hull needs a problem with the masonry hull (constraints=['hull'])")
    if method is None:

        method = StaggeredLinearization()
    t0 = time.perf_counter()
    opts = dict(options or {})
    caps = capabilities(method)
    hard = caps.hull_as_rows
    if hard and caps.warm_start and warm_start is not None:
        opts["warm_start"] = warm_start
    ladder = [None] if hard else list(penalties)
    tried: list[tuple[dict, SolveResult, dict]] = []
    for pen in ladder:
        prob = problem if pen is None else _with_penalty(problem, t, float(pen))
        res = method.solve(prob, opts, progress=progress)
        hull = hull_report(problem, res.network)
        ok = _in_equilibrium(res, tol) and hull["inside_all"]
        rung = {"penalty": pen if pen is not None else "hard", "status": res.status,
                "max_relative_error": res.max_relative_error, "outside": hull["outside"],
                "max_excess": hull["max_excess"], "iterations": res.iterations, "wall_time": res.wall_time}
        tried.append((rung, res, hull))
        if ok:
            break
    rung, res, hull = tried[-1]
    certified = _in_equilibrium(res, tol) and hull["inside_all"]
    if not certified:
        # the diagnosis: the equilibrium network that leaves the hull least, else the least unbalanced
        eq = [x for x in tried if _in_equilibrium(x[1], tol)]
        rung, res, hull = (min(eq, key=lambda x: (x[2]["max_excess"], x[2]["outside"])) if eq
                           else min(tried, key=lambda x: x[1].max_relative_error))
    hull = {**hull, "certified": certified, "penalty": rung["penalty"]}
    search = [r for r, _, _ in tried]
    if certified:
        status = "converged"
        message = res.message if res.status == "converged" else (
            f"certified: the network is compressive and in equilibrium inside the hull (the method itself "
            f"reported {res.status!r}: {res.message})")
    else:
        where = ", ".join(f"{v} ({e:.3g} m)" for v, e in zip(hull["outside_vertices"][:8], hull["outside_excess"][:8]))
        how = f"hard hull rows ({getattr(method, 'name', type(method).__name__)})" if hard else f"hull penalties {', '.join(f'{p:g}' for p in ladder)}"
        if _in_equilibrium(res, tol):
            message = (f"no compressive network in equilibrium inside the masonry hull (t = {t:g} m) was found with "
                       f"{how}; the closest one found leaves {hull['outside']} free vertices outside by up to "
                       f"{hull['max_excess']:.3g} m: {where}")
        else:
            message = (f"no compressive network in equilibrium was found with {how} (best max relative error "
                       f"{res.max_relative_error:.2e}; {hull['outside']} free vertices outside the hull of t = {t:g} m"
                       f"{': ' + where if where else ''}); the written network is NOT in equilibrium")
        status = "infeasible"
    hull["stands"] = stands_line({"hull": hull})
    params = {**res.parameters, "hull": hull, "hull_search": search}
    return replace(res, status=status, message=message, parameters=params,
                   wall_time=time.perf_counter() - t0)


def stands_line(parameters: Mapping[str, Any]) -> str:
    """The verdict of the safe theorem for a result's ``parameters`` (with a ``hull`` entry)."""
    hull = parameters.get("hull") or {}
    if not hull:
        return "stands: not assessed (no masonry hull; give --hull and --thickness)"
    if hull.get("certified"):
        return (f"stands: yes, certified by a network inside the hull (a compressive network in equilibrium within "
                f"the reference ± {0.5 * hull['thickness']:g} m; safe theorem)")
    if hull.get("certified") is None:  # a report without the search (a bare method result)
        if hull.get("inside_all"):
            return "stands: inside the hull, but the network's equilibrium was not assessed here"
    return (f"stands: not certified ({hull.get('outside', '?')} free vertices outside the hull of t = "
            f"{hull['thickness']:g} m by up to {hull.get('max_excess', float('nan')):.3g} m in the closest network "
            "found; failing to find a network is not a proof of collapse)")


# ------------------------------------------------------------------------ added loads
