"""Will it stand? The masonry hull, stability under added load and the maximum load (paper §4,
Figs. 9–10).

By the safe (lower-bound) theorem of limit analysis, a vault of no-tension masonry stands if
*some* compressive force network in equilibrium with its loads lies inside the masonry — here
the hull "reference mid-surface ± t/2" (:func:`~selfsupport.methods.base.hull_report` measures
it). A network found inside certifies the vault; failing to find one proves nothing by itself.

:func:`solve_in_hull` searches for such a network. With a method that holds the hull as hard
inequality rows (capability ``hull_as_rows``: IPOPT) one solve decides. The staggered method holds the hull as hard bounds
too (an active set in Step 3, :mod:`selfsupport.methods.staggered`), but its descent can stall
where a network exists; the search therefore first solves without the hull (the network nearest
to the reference — if it is already inside, that certifies the vault), then with it. Only when
both fail is the design reported ``infeasible``, with the vertices the closest equilibrium
network found leaves outside and by how much. That verdict is a strong hint, not a proof of
collapse.

:func:`stability_series` runs one search per added load. :func:`max_load` answers the largest
load that still admits a certified network with one limit program
(:mod:`selfsupport.structure.limit`: λ maximised by IPOPT over networks inside the hull), or, on request,
by bisecting over searches.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from formulations import Problem
from formulations.problem import Hull
from selfsupport.core.errors import InputError
from selfsupport.core.result import SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.problem import problem as stated_problem
from selfsupport.methods import capabilities
from selfsupport.methods.base import HULL_TOL, hull_report

__all__ = ["PENALTY_LADDER", "HULL_TOL", "solve_in_hull", "stands_line", "LoadStep", "stability_series",
           "max_load", "spread_mass", "MaxLoad"]

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
        from selfsupport.methods.staggered import StaggeredLinearization

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


@dataclass(frozen=True)
class LoadStep:
    """One added load: its mass [kg], the search's result and the verdict."""

    kg: float
    result: SolveResult
    at: tuple[int, ...]

    @property
    def certified(self) -> bool:
        return bool(self.result.parameters.get("hull", {}).get("certified"))

    def row(self) -> dict[str, Any]:
        """A table row: load, found, max relative error, max hull violation, outside count (beyond
        the hull's tolerance), time."""
        h = self.result.parameters.get("hull", {})
        return {"added_kg": self.kg, "found": self.certified, "status": self.result.status,
                "max_relative_error": self.result.max_relative_error, "max_hull_excess_m": h.get("max_excess"),
                "outside": h.get("outside"), "hull_tolerance_m": h.get("tolerance"), "penalty": h.get("penalty"),
                "distance_mean": self.result.distance_mean, "seconds": self.result.wall_time}


def _problem(scene: Scene, *, thickness: float, density: float, mass: Mapping[int, float],
             constraints_extra: Sequence[Any] = ()) -> Problem:
    return stated_problem(scene, density=density, thickness=thickness, extra_mass=dict(mass),
                       constraints=[Hull(thickness=thickness), *constraints_extra])


def stability_series(scene: Scene, *, thickness: float, loads_kg: Sequence[float], density: float = 2500.0,
                     at: Sequence[int] | None = None, method: Any = None, options: Mapping[str, Any] | None = None,
                     progress: Callable[[LoadStep], None] | None = None) -> list[LoadStep]:
    """One hull search (:func:`solve_in_hull`) per added mass in ``loads_kg`` (spread over ``at``,
    default the handled vertices), on top of the self-weight ρ t g. Each search after the first
    is warm-started from the previous network where the method allows it (IPOPT)."""
    at_ = tuple(sorted(spread_mass(scene, at, 1.0)))
    out: list[LoadStep] = []
    prev = None
    for kg in loads_kg:
        prob = _problem(scene, thickness=thickness, density=density, mass=spread_mass(scene, at_, kg))
        res = solve_in_hull(prob, method=method, options=options, warm_start=prev)
        step = LoadStep(kg=float(kg), result=res, at=at_)
        out.append(step)
        if res.max_relative_error <= CERTIFY_TOL:
            prev = res
        if progress:
            progress(step)
    return out


@dataclass(frozen=True)
class MaxLoad:
    """The largest certified load and its network. From the limit program (``search="nlp"``):
    ``upper_kg`` is the program's own optimum (a local one), ``limit`` its full answer; from the
    bisection: the smallest load found not certified, and every probe."""

    kg: float | None  # None: nothing certified (not even the unloaded vault, for the bisection)
    upper_kg: float | None  # the bisection: the smallest load found not certified (None: none up to the cap)
    tolerance_kg: float
    certificate: SolveResult | None
    probes: tuple[LoadStep, ...] = field(default_factory=tuple)
    limit: Any = None  # the limit program's LimitResult (search="nlp")
    message: str = ""


def max_load(scene: Scene, *, thickness: float, density: float = 2500.0, at: Sequence[int] | None = None,
             start_kg: float = 1000.0, rel_tol: float = 0.05, abs_tol: float = 1.0, cap_kg: float = 1e8,
             method: Any = None, options: Mapping[str, Any] | None = None,
             progress: Callable[[Any], None] | None = None, search: str = "nlp",
             time_limit: float = 600.0) -> MaxLoad:
    """The largest added mass (kg, spread over ``at``) that still admits a certified network.

    ``search="nlp"`` (default): one limit program (:func:`selfsupport.structure.limit.limit_load`: maximise
    λ over networks inside the hull, IPOPT, warm-started from the staggered network), the answer
    certified by its network; ``progress`` gets each IPOPT round's record, ``time_limit`` [s]
    bounds the whole analysis; ``start_kg``, ``rel_tol``, ``abs_tol``, ``cap_kg`` and ``method``
    are the bisection's. ``options`` go to the staggered start.

    ``search="bisection"``: brackets by doubling from ``start_kg`` (up to ``cap_kg``), then
    bisects until the bracket ``[lo, hi]`` satisfies ``hi - lo <= max(rel_tol * hi, abs_tol)``,
    one :func:`solve_in_hull` per probe (``progress`` gets each :class:`LoadStep`). The answer
    is ``lo``, with its certifying network. The search is a heuristic, so the certified set need
    not be an interval; the bisection assumes it is, and every probe is kept. The design tool's
    probe uses it: it reports a verdict per probe and is cancelled between probes.
    """
    if search == "nlp":
        from selfsupport.structure.limit import limit_load

        r = limit_load(scene, thickness=thickness, density=density, at=at, options=options, time_limit=time_limit,
                       progress=progress)
        return MaxLoad(r.value, r.optimum, 0.0, r.certificate, (), r, r.message)
    if search != "bisection":
        raise InputError(f"unknown max-load search {search!r}; choose 'nlp' or 'bisection'")
    at_ = tuple(sorted(spread_mass(scene, at, 1.0)))
    probes: list[LoadStep] = []

    def probe(kg: float) -> LoadStep:
        prob = _problem(scene, thickness=thickness, density=density, mass=spread_mass(scene, at_, kg))
        step = LoadStep(kg=float(kg), result=solve_in_hull(prob, method=method, options=options), at=at_)
        probes.append(step)
        if progress:
            progress(step)
        return step

    base = probe(0.0)
    if not base.certified:
        return MaxLoad(None, 0.0, 0.0, None, tuple(probes), message=base.result.message)
    lo, best, hi = 0.0, base, None
    kg = float(start_kg)
    while kg <= cap_kg:
        s = probe(kg)
        if not s.certified:
            hi = kg
            break
        lo, best = kg, s
        kg *= 2.0
    if hi is None:
        return MaxLoad(lo, None, 0.0, best.result, tuple(probes))
    while hi - lo > max(rel_tol * hi, abs_tol):
        mid = 0.5 * (lo + hi)
        s = probe(mid)
        if s.certified:
            lo, best = mid, s
        else:
            hi = mid
    return MaxLoad(lo, hi, hi - lo, best.result, tuple(probes))
