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

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

from formulations import Problem
from formulations.problem import Hull
from selfsupport.core.errors import InputError
from selfsupport.core.loads import spread_mass
from selfsupport.core.result import SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.problem import problem as stated_problem
from selfsupport.methods.base import HULL_TOL
from selfsupport.methods.hull_search import (
    CERTIFY_TOL,
    PENALTY_LADDER,
    solve_in_hull,
    stands_line,
)
from selfsupport.structure.limit import limit_load

__all__ = ["CERTIFY_TOL", "PENALTY_LADDER", "HULL_TOL", "solve_in_hull", "stands_line", "LoadStep", "stability_series",
           "max_load", "spread_mass", "MaxLoad"]

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
             time_limit: float = 600.0, slide: bool = False) -> MaxLoad:
    """The largest added mass (kg, spread over ``at``) that still admits a certified network.

    ``search="nlp"`` (default): one limit program (:func:`selfsupport.structure.limit.limit_load`: maximise
    λ over networks inside the hull, IPOPT, warm-started from the staggered network), the answer
    certified by its network; ``progress`` gets each IPOPT round's record, ``time_limit`` [s]
    bounds the whole analysis; ``start_kg``, ``rel_tol``, ``abs_tol``, ``cap_kg`` and ``method``
    are the bisection's. ``options`` go to the staggered start; ``slide`` lets the vertices
    slide along the reference too (:func:`~selfsupport.structure.limit.limit_load`).

    ``search="bisection"``: brackets by doubling from ``start_kg`` (up to ``cap_kg``), then
    bisects until the bracket ``[lo, hi]`` satisfies ``hi - lo <= max(rel_tol * hi, abs_tol)``,
    one :func:`solve_in_hull` per probe (``progress`` gets each :class:`LoadStep`). The answer
    is ``lo``, with its certifying network. The search is a heuristic, so the certified set need
    not be an interval; the bisection assumes it is, and every probe is kept. The design tool's
    probe uses it: it reports a verdict per probe and is cancelled between probes.
    """
    if search == "nlp":

        r = limit_load(scene, thickness=thickness, density=density, at=at, options=options, time_limit=time_limit,
                       progress=progress, slide=slide)
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
