"""What every method is: ``solve(problem, options) -> SolveResult`` on a
:class:`formulations.Problem`, plus the helpers they share to honour that contract.

Methods also accept the short form ``solve(scene, loads, eps=..., w_max=..., objective=...)``,
which builds the problem with :func:`as_problem` — nothing more.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Protocol, runtime_checkable

import numpy as np

from formulations import Problem, TermContext
from formulations.scaling import Scaling

from ..result import Network, SolveResult
from ..scene import Scene


@runtime_checkable
class Method(Protocol):
    """A solution method: any object with a ``name`` and this ``solve``."""

    name: str

    def solve(self, problem: Problem, options: Mapping[str, Any] | None = None, *,
              progress: Callable[[dict], None] | None = None) -> SolveResult:
        """Solve ``problem``; ``options`` are the method's settings for this solve only."""
        ...  # pragma: no cover - protocol


def as_problem(problem: Problem | Scene, loads: Any = None, *, eps: Any = None, w_max: Any = None,
               objective: Any = None, constraints: Any = ()) -> Problem:
    """``problem`` itself, or the problem built from a scene and the short form's arguments
    (which must then not contradict a given problem)."""
    if isinstance(problem, Problem):
        extra = {k: v for k, v in (("loads", loads), ("eps", eps), ("w_max", w_max), ("objective", objective))
                 if v is not None}
        if extra or constraints:
            from ..errors import InputError

            raise InputError(f"{sorted(extra) + (['constraints'] if constraints else [])} are part of the problem; "
                             "pass them to Problem.build instead")
        return problem
    return Problem.build(problem, loads, eps=eps, w_max=w_max, objective=objective, constraints=constraints)


def term_values(problem: Problem, network: Network, default: Any = None) -> dict[str, float]:
    """Each objective term's value at ``network`` in SI units (the reference term re-projected
    there), by name — for the summary and the JSON."""
    scene = problem.scene
    V = np.asarray(network.vertices, float)
    ctx = TermContext(vertices=scene.mesh.vertices, reference=scene.mesh, free=scene.free,
                      thickness=problem.hull_thickness())
    total = problem.terms(ctx, default=default)
    if total is None:
        return {}
    out: dict[str, float] = {}
    for t in total.parts():
        out[t.name] = out.get(t.name, 0.0) + t.at(V).numeric_value(V)
    return out


def hull_report(problem: Problem, network: Network, thickness: float | None = None) -> dict[str, Any] | None:
    """Where the network sits in the masonry hull (see :func:`hull_excess`) of the problem's hull
    constraint, else of ``thickness`` (for a diagnosis of a problem without the constraint);
    ``None`` without either."""
    t = problem.hull_thickness() if problem.hull_thickness() is not None else thickness
    return None if t is None else hull_excess(problem.scene, network, t)


def hull_excess(scene: Scene, network: Network, thickness: float) -> dict[str, Any]:
    """Where the network sits in the masonry hull (reference ± t/2 along the reference vertex
    normals): thickness, max excess beyond t/2 [m], free vertices outside (count, the first 20)
    and free vertices in all. The one computation behind the ``hull`` record of a solve and
    the warning of :mod:`selfsupport.diagnostics`."""
    from formulations.terms import HullPenalty

    t = float(thickness)
    ctx = TermContext(vertices=scene.mesh.vertices, reference=scene.mesh, free=scene.free, thickness=t)
    term = HullPenalty.build(ctx)
    excess = np.abs(term.signed_distance(network.vertices)) - 0.5 * t
    outside = term.idx[excess > 1e-9 * t]
    return {"thickness": t, "max_excess": float(max(excess.max(initial=-np.inf), 0.0)),
            "outside": int(outside.size), "outside_vertices": outside[:20].tolist(), "free": int(term.idx.size)}


def case_networks(problem: Problem, scaling: Scaling, X: np.ndarray, ws: list[np.ndarray]
                  ) -> tuple[Network, tuple[tuple[str, Network], ...]]:
    """Networks in SI units for scaled positions ``X`` and one scaled weight vector per case:
    supports exactly where the design put them, each case's loads of this geometry."""
    scene = problem.scene
    mesh0 = scene.mesh
    V = scaling.pos_back(X)
    V[scene.supports] = mesh0.vertices[scene.supports]  # exactly, not through the scaling round trip
    mesh = mesh0.with_vertices(V)
    nets = []
    for (name, model), w in zip(problem.loads, ws):
        weights = np.zeros(mesh0.n_edges)
        weights[scene.active_edges] = scaling.weight_back(w)
        nets.append((name, Network(mesh=mesh, weights=weights, loads=model.nodal(mesh0, V), supports=scene.supports,
                                   reference=mesh0, handles=scene.handles)))
    return nets[0][1], tuple(nets)
