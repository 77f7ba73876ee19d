"""Several load cases that are not proportional: a continuation from the cases' envelope.

Why the staggered iteration stalls with such cases: Step 3 moves the positions with every case's
weights held and sums the cases' residuals, so a move that balances one case unbalances another;
where one case's weights sit at their bound, the only moves left trade the cases' errors against
each other, and the fit error stops falling although a geometry for every case may exist. The
coupled Step 3 moves the weights too, but from the reference, far from any such geometry.

The continuation starts where one load is solved: the cases' envelope ``L_e`` (at each vertex the
heaviest of the cases' loads, :class:`Envelope`) is solved alone by the staggered method, so the
geometry is shaped for the largest load each vertex sees. Every case's load is then moved from
the envelope towards its own, ``L_c(t) = L_e + t (L_c − L_e)``, ``t`` from 0 to 1; each stage is the joint
polish (:func:`~selfsupport.methods.polish.polish_joint`: Gauss–Newton with minimum-norm steps
on the positions and every case's weights off their bounds, loads of the geometry) from the
last stage's network, so the geometry moves no more than the cases require. ``t = 1`` is tried
first; a stage that does not converge halves the step, down to :data:`MIN_STEP`.

Before any stage, one least-squares solve per case decides whether a stage can succeed at all
(:func:`difference_fit`): at ``t = 0`` every case carries ``L_e`` with the envelope's weights, so
a path of networks leaving it moves every case's equilibrium alike through the positions and the
loads' dependence on them, and only the weights can carry the cases' differences: to first order
in ``t``, ``A(X) (ẇ_c − ẇ_mean) = L_c − L_mean``, with ``ẇ`` on the weights the joint polish moves
(those off their bounds). Where that system leaves a relative residual ``r``, a stage of step
``t`` leaves about ``t r`` to first order, and no stage converges: the stages (each a joint
polish, tens of seconds on a thousand vertices) are skipped and the block reported. It is made
first at the envelope's network as its iteration ends, then, if that passes, again after the
refinement towards the reference (most of the envelope's time with a point load). The test is
necessary, not sufficient: weights that a finite step pushes onto their bounds can still block
a stage. So each stage is started only when the last one's duration fits in the continuation's
share of the time (:data:`SHARE`), and the rest is the iteration's.

A case whose loads are another's times a factor ``k ≥ 1`` (snow on the self-weight) is left out
of all this and added at the end with that case's weights times ``k``
(:func:`~selfsupport.methods.base.proportional_members`, :func:`~selfsupport.methods.base.with_members`): it adds no condition on the geometry, but
left in, it adds equations the iteration must fit (on a quad mesh, three such cases make the
count square).

When neither the continuation nor the iteration over every case converges, the simultaneous
method (IPOPT over the positions and every case's weights at once) starts from the iteration's
network and each case's weights, in the time left, at least :data:`FINISH_SHARE` of the solve's
(:func:`ipopt_finish`), and seeks the network in equilibrium for every case nearest the
iteration's: where the iteration stalls because its Step 3 trades the cases' errors, IPOPT's
steps move the weights across their bounds and the positions together. Its answer is the
method's when it converges, else its status stands beside the staggered numbers in the report
("Infeasible_Problem_Detected" or a failed restoration: IPOPT's evidence of a local
infeasibility; "Feasible_Point_Found": the joint problem has as many equations as unknowns, see
:func:`joint_freedom`).

Why a plan can block every case at once, whatever their size: every case's weights balance
every free vertex in plan, ``H(x, y) w_c = 0``, so they lie in the plan's horizontal
self-stresses. A mesh with as many edges as horizontal equations (``m = 2 n_free``: a quad mesh
with free edges, such as the paper's vault-pillar) has none at a generic plan; a solve for one
load finds a plan with exactly one, and over such a plan every case's weights are multiples of
one vector and only proportional loads stand (:func:`top_view_self_stresses`, measured at the
envelope's network and reported with a block). Several cases need a plan with more, which a
step from the envelope's network does not reach; where the iteration finds none either, more
edges (quads split into triangles: ``selfsupport solve --triangulate``) or supports on the free edges give
the plan room.

More self-stresses are not enough over a fixed plan either: with ``k`` of them every case's
weights are ``S a_c`` and the cases share the heights, ``C n_free`` vertical equations for
``n_free + C k`` unknowns, so a generic plan carries ``C`` cases that are not proportional only
with ``k ≥ (C − 1) n_free / C`` (a quad mesh with free edges has ``m − 2 n_free`` plus its
mechanisms, far fewer: cas as quads 84 for 1,358 free vertices). Where the iteration over every
case stalls, this is measured at its network (:func:`fixed_plan`: the count, then a
least-squares solve over that plan with heights and weights of either sign free) and reported.
The count is generic, not a proof that no geometry stands: a plan the solve moves to can be a
special one where the vertical equations are dependent (the tests' 10 × 10 quad vault carries
two cases over a plan with two self-stresses); it says the plan must move, possibly far.

Where the continuation stops short of ``t = 1`` the cases are measured at the last network that
carried ``t`` of them: each case's own weight fit there (Step 2, within the bounds) gives its
relative residual per vertex, and the fit's bound multipliers name the edges whose bound blocks
it (:func:`blocking`; a weight counts as on its bound as the polish counts it). A linear program
then decides, for the case that fits worst, what the fit only suggests (:func:`least_tension`):
whether any weights within the bounds carry it exactly at that geometry, and if not, the least
tension they need. The first-order test above cannot see this: it asks whether the weights off
their bounds carry the differences with changes of *either sign*, and passes where those changes
would take many weights through their bound at any step the stages can take (triangulated cas
with 5% of its self-weight at its highest vertex: at the envelope's network the empty case,
blended by ``t``, is carried within the bounds up to ``t`` = 1/512 and not from 1/64 on), so its
stages' polish, whose steps hold every weight that would cross, finds no descent. Where the
program finds tension, the geometry must move, whatever is done with the weights.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import scipy.sparse as sp

from formulations import Bounds, LoadCases, Problem
from formulations.equilibrium import Topology, load_vector, position_blocks, residual, weight_matrix
from formulations.peel import difference_peel, loads_differ, star_degeneracy
from selfsupport.core.loads import LoadCase
from selfsupport.core.result import Network, SolveResult
from selfsupport.methods import find_method, method_class
from selfsupport.methods.deadline import out_of_time, remaining
from selfsupport.methods.polish import BOUND_ACTIVE_REL, max_rel_error, min_norm_step
from selfsupport.methods.staggered.conclude import conclude, final_polish, refinement_steps
from selfsupport.methods.staggered.options import StaggeredOptions
from selfsupport.methods.staggered.run import _Run
from selfsupport.methods.staggered.schedule import Schedule
from selfsupport.methods.staggered.state import FinishAttempt, FitState, IterState

if TYPE_CHECKING:
    from selfsupport.methods.staggered.method import StaggeredLinearization

#: Smallest continuation step in ``t``: a stage that does not converge at this step ends the
#: continuation (the cases are blocked at the last ``t`` reached).
MIN_STEP = 1.0 / 64
#: Max relative residual at which a stage counts as converged (the joint polish's target is
#: round-off, ~1e-12; the final network is checked against the solve's ``tol`` as any other).
STAGE_TOL = 1e-10
#: Share of the solve's time the continuation may take (the envelope's solve included); the rest
#: is the iteration's when the continuation does not reach every case.
SHARE = 0.25
#: Share of the solve's time kept for IPOPT's finish (:func:`ipopt_finish`) when the
#: continuation does not reach every case: the iteration over every case stops there. On
#: triangulated cas with a point load the iteration takes any time it is given and stalls at
#: ~4e-3, and the finish from there took 42 s (without it, the finish never started in 120 s).
FINISH_SHARE = 0.4
#: Max relative residual of :func:`difference_fit` above which the continuation is blocked at its
#: start: the smallest step's first-order error ``MIN_STEP · r`` a hundred times a stage's target
#: (the margin: the least-squares solve's round-off, 1e-14 on a dome, and the step's second-order terms).
BLOCKED_RESIDUAL = 100 * STAGE_TOL / MIN_STEP
#: Vertices and bound edges named in the report of a blocked continuation.
REPORTED = 5
#: A singular value of the horizontal equilibrium matrix at most this times its largest counts
#: as zero in :func:`top_view_self_stresses`: a network polished to round-off leaves ~2e-17
#: (vault-pillar, a 10 × 10 quad vault); the next ones there are 3.8e-5 and 1.4e-9. A network
#: further from equilibrium counts none (no note, not a wrong one).
SELF_STRESS_RTOL = 1e-12
#: A total tension of at most this share of the case's total load counts as none in
#: :func:`least_tension` (HiGHS's feasibility tolerance on the relative rows is 1e-7).
TENSION_RTOL = 1e-6
#: Most seconds :func:`least_tension` gives one case's LP (HiGHS on 4,240 edges, triangulated
#: cas: 3–6 s); never past the caller's deadline.
TENSION_LP_SECONDS = 60.0
#: Most active edges for which :func:`top_view_self_stresses` takes a dense SVD (0.01 s at 168
#: edges, 0.2 s at 1,500; 18–32 s at cas's 2,800 on a loaded machine); above it, the sparse count
#: (:func:`_plan_mechanisms`: 0.04 s there).
SELF_STRESS_MAX_EDGES = 1500
#: In the sparse count, a singular value of the horizontal equilibrium matrix at most this times
#: its largest counts as zero: its squares come from ``H Hᵀ``, whose round-off (~1e-16 of its
#: largest eigenvalue) hides singular values below ~1e-8 of the largest.
SELF_STRESS_SPARSE_RTOL = 1e-7
#: Most Gauss–Newton steps of :func:`fixed_plan` (each 0.1–0.3 s on cas's 1,358 free vertices).
FIXED_PLAN_STEPS = 20
#: Most share of the solve's time :func:`fixed_plan` takes, after the iteration over every case and
#: before IPOPT's finish.
FIXED_PLAN_SHARE = 0.05


@dataclass(frozen=True)
class Envelope(LoadCase):
    """At each vertex the heaviest load of the ``cases`` (the base of the continuation)."""

    cases: tuple[LoadCase, ...]

    def nodal(self, mesh: Any, vertices: np.ndarray) -> np.ndarray:
        return np.min([c.nodal(mesh, vertices) for c in self.cases], axis=0)  # (down is negative)

    @property
    def depends_on_geometry(self) -> bool:
        return any(c.depends_on_geometry for c in self.cases)

    def concentrated_at(self) -> np.ndarray:
        return np.unique(np.concatenate([c.concentrated_at() for c in self.cases]))


def _base_problem(problem: Problem, run: _Run) -> Problem:
    """The problem of the cases' envelope alone, with the full problem's bounds stated per edge
    (the default ε is relative to the first case's loads: the same edges keep the same bounds)."""
    sc = run.sc
    return replace(problem, loads=LoadCases((("envelope", Envelope(problem.loads.models)),)),
                   bounds=Bounds(sc.weight_back(np.broadcast_to(run.lower, (run.top.m,)).astype(float)),
                                 sc.weight_back(np.broadcast_to(run.upper, (run.top.m,)).astype(float))))


def _at_bounds(run: _Run, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the weights ``w`` on their lower and on their upper bound, as
    :func:`~selfsupport.methods.polish.polish_joint` counts them (within
    :data:`~selfsupport.methods.polish.BOUND_ACTIVE_REL` of the bound: the polish holds them)."""
    lo = np.broadcast_to(run.lower, (run.top.m,))
    up = np.broadcast_to(run.upper, (run.top.m,))
    below_up = up - BOUND_ACTIVE_REL * np.abs(np.nan_to_num(up, posinf=0.0))  # (∞ stays ∞)
    above_lo = lo + BOUND_ACTIVE_REL * np.maximum(lo, 1e-300)
    return w <= above_lo, w >= below_up


def _moved(run: _Run, ws: list[np.ndarray]) -> np.ndarray:
    """The weights the joint polish moves from any of ``ws``: those off their bounds (as
    :func:`~selfsupport.methods.polish.polish_joint` counts them)."""
    return np.any([~np.logical_or(*_at_bounds(run, w)) for w in ws], axis=0)


def difference_fit(run: _Run, X: np.ndarray, L: np.ndarray, ws: list[np.ndarray]) -> dict[str, dict[str, Any]]:
    """Per case ``c``: can the network at ``X`` carry the difference ``L_c − L_mean`` of its loads
    from the cases' mean by a change, of either sign, of the weights the joint polish moves (those
    off their bounds in any of ``ws``)? This is the first-order condition of a continuation from a
    network where every case has the same weights (see the module docstring): where it fails, the
    continuation's polish finds no path from ``X``, to first order. The minimum-norm weight change of the polish
    (:func:`~selfsupport.methods.polish.min_norm_step`); its relative residual per vertex (over
    ``|L_c|``): its max, the largest load difference, and the vertices where it is largest."""
    top = run.top
    A = weight_matrix(top, X).tocsc()[:, _moved(run, ws)]
    Lm = L.mean(axis=0)
    return {name: _carried(top, A, L[c] - Lm, L[c], run.free_idx) for c, name in enumerate(run.loads.names)}


def _carried(top: Topology, A: sp.spmatrix, diff: np.ndarray, scale: np.ndarray, free_idx: np.ndarray) -> dict[str, Any]:
    """How far a change of the weights of ``A``'s columns (the minimum-norm least-squares one)
    carries the nodal load difference ``diff``: its relative residual per free vertex (over
    ``|scale|``), its max, the largest relative load difference, and the vertices where it is largest."""
    s = np.repeat(1.0 / np.abs(scale[top.free]), 3)
    J = (sp.diags(s) @ A).tocsr()
    b = s * load_vector(top, diff)
    r = np.linalg.norm((J @ min_norm_step(J, [J.shape[0]], b) - b).reshape(-1, 3), axis=1)
    order = np.argsort(r)[::-1][:REPORTED]
    return {"max_relative_residual": float(r.max(initial=0.0)),
            "load_difference": float(np.abs(b).reshape(-1, 3).max(initial=0.0)),
            "vertices": [int(v) for v in free_idx[order]], "vertex_residuals": [float(x) for x in r[order]]}


def _active_topology(net: Network) -> Topology:
    """The topology of ``net``'s edges that carry a weight."""
    return Topology.build(net.mesh.n_vertices, net.edges[net.active_edges], net.supports)


def any_weights_carry(result: SolveResult) -> dict[str, dict[str, Any]]:
    """At the geometry of ``result`` (several cases): per case after the first, whether *any*
    change of the weights — either sign, no bound — carries the case's load difference from the
    first case there (:func:`_carried` over every active edge). The cases share the geometry, so
    ``A(X) (w_c − w_1) = L_c − L_1`` holds exactly in any network that carries both: a residual
    well above round-off says this geometry cannot carry them with any weights (the geometry
    blocks, not the bounds); near round-off, weights of some sign exist here, and the bounds or
    the iteration's reach are what is missing.

    Each case's entry also holds its ``peel`` (:func:`case_peel`): whether the mesh alone rules out
    every network whose stars are not degenerate."""
    (first_name, first), *rest = result.case_networks
    top = _active_topology(first)
    A = weight_matrix(top, first.vertices).tocsc()
    free_idx = np.flatnonzero(top.free)
    return {name: {"from": first_name, **_carried(top, A, other.loads - first.loads, other.loads, free_idx),
                   "peel": case_peel(top, first.vertices, first.loads, other.loads)}
            for name, other in rest}


def case_peel(top: Topology, X: np.ndarray, first: np.ndarray, other: np.ndarray) -> dict[str, Any]:
    """:func:`~formulations.peel.difference_peel` of two cases' nodal loads at the positions
    ``X``: the vertices where they differ, those the peel from the free edges reaches
    (``blocked_at``: then no network of this mesh carries both unless a star the peel passes is
    degenerate), its steps, and the smallest degeneracy of those stars at ``X`` and its vertex."""
    loaded = loads_differ(first, other, top.free)
    peel = difference_peel(top.n, top.edges, ~top.free, loaded)
    deg = star_degeneracy(peel, X)
    return {"loaded": [int(v) for v in loaded[:REPORTED]], "n_loaded": int(loaded.size),
            "blocked_at": [int(v) for v in peel.blocked_at[:REPORTED]], "steps": peel.steps,
            "forced_edges": int(peel.forced.sum()), "smallest_degeneracy": deg.smallest if peel.steps else None,
            "degenerate_vertex": deg.vertex}


def least_tension(top: Topology, X: np.ndarray, L: np.ndarray, lower: Any, upper: Any, *,
                  deadline: float | None = None) -> dict[str, Any]:
    """At the fixed positions ``X``: do weights within the bounds carry the loads ``L`` exactly,
    and if not, how much must the lower bound give way (tension, where it is the small default ε)?

    One linear program (HiGHS): minimise ``Σ_e q_e |e|`` over the weights ``w`` and ``q ≥ 0`` subject
    to ``A(X) w = b`` (every free vertex's rows over ``|L_i|``), ``w + q ≥ lower`` and ``w ≤ upper``:
    ``q_e |e|`` is the force by which edge ``e`` falls short of its lower bound. An optimum of zero
    certifies that this geometry carries the loads within the bounds; a positive one, that no
    weights within the bounds carry them here, whatever an iteration does with the weights alone
    (the geometry must move); an infeasible program, that no weights of either sign (below ``upper``) do.

    Parameters
    ----------
    top, X, L
        The topology, the positions ``(n, 3)`` and the nodal loads ``(n,)`` (any consistent units).
    lower, upper
        The weight bounds (scalars or one per edge; ``±inf`` for none).
    deadline
        ``time.perf_counter()`` value: HiGHS stops there (and at :data:`TENSION_LP_SECONDS`).

    Returns
    -------
    ``status``: "carried", "tension", "no weights" (no weights of either sign below ``upper`` carry ``L`` at ``X``; ``bounded_above``: whether any ``upper`` is finite)
    or "not measured" (out of time, or HiGHS failed: ``reason``); with "tension": ``tension_share``,
    the least total force short of the lower bound over the total load ``|Σ L|``; ``largest_share``,
    its largest edge's; ``edges``, how many edges fall short; ``tension_edges``, the
    :data:`REPORTED` edges (vertex pairs) with the largest; always ``seconds``.
    """
    # (scipy.optimize: 0.1 s to import, only for a report of a block)
    from scipy.optimize import linprog

    t0 = time.perf_counter()
    m, free = top.m, top.free
    budget = min(TENSION_LP_SECONDS, remaining(deadline))
    if budget <= 0.0 or m == 0:
        return {"status": "not measured", "reason": "no time left", "seconds": 0.0}
    lo = np.broadcast_to(np.asarray(lower, float), (m,))
    up = np.broadcast_to(np.asarray(upper, float), (m,))
    s = np.repeat(1.0 / np.abs(L[free]), 3)
    As = (sp.diags(s) @ weight_matrix(top, X)).tocsr()
    lens = np.linalg.norm(X[top.edges[:, 1]] - X[top.edges[:, 0]], axis=1)
    held = np.flatnonzero(np.isfinite(lo))  # (an edge without a lower bound needs no q)
    Iq = sp.csr_matrix((np.ones(held.size), (np.arange(held.size), held)), shape=(held.size, m))
    res = linprog(np.r_[np.zeros(m), lens[held]],
                  A_ub=sp.hstack([-Iq, -sp.identity(held.size)]).tocsr(), b_ub=-lo[held],
                  A_eq=sp.hstack([As, sp.csr_matrix((As.shape[0], held.size))]).tocsr(),
                  b_eq=s * load_vector(top, L),
                  bounds=[(None, u if np.isfinite(u) else None) for u in up] + [(0.0, None)] * held.size,
                  method="highs", options={"time_limit": budget})
    out: dict[str, Any] = {"seconds": time.perf_counter() - t0}
    if res.status == 2:
        return {**out, "status": "no weights", "bounded_above": bool(np.isfinite(up).any())}
    if res.status != 0:
        return {**out, "status": "not measured", "reason": res.message}
    total = float(np.abs(L[free].sum()))
    force = np.zeros(m)
    force[held] = res.x[m:] * lens[held] / total
    if force.sum() <= TENSION_RTOL:
        return {**out, "status": "carried"}
    order = np.argsort(force)[::-1][:REPORTED]
    order = order[force[order] > 0]
    return {**out, "status": "tension", "tension_share": float(force.sum()), "largest_share": float(force.max()),
            "edges": int(np.count_nonzero(force > TENSION_RTOL * force.max())),
            "tension_edges": [[int(i), int(j)] for i, j in top.edges[order]]}


def blocking(run: _Run, X: np.ndarray, ws: list[np.ndarray], fit: FitState | None = None) -> dict[str, Any]:
    """What blocks the cases at positions ``X`` (scaled): each case's own weight fit within the
    bounds, from ``ws`` (``fit``: that fit, when it is at hand): per case its max relative
    residual, the worst case, its vertices of largest residual, how many of its weights lie on a
    bound (as the polish counts them: :func:`_at_bounds`) and how many of those the fit pushes
    against it (``pushing``), and the edges with the largest multipliers (the fit's gradient on a
    weight at its bound: how much the residual would fall per unit the bound gave way); and
    :func:`difference_fit` (from ``ws`` and the fit's weights)."""
    fit = run.fit(X, ws) if fit is None else fit
    top = run.top
    out: dict[str, Any] = {"fit_errors": {}, "case": None}
    if fit is None:
        return out
    out["difference"] = difference_fit(run, X, fit.L, [*ws, *fit.w])
    worst, worst_err = 0, -1.0
    per_vertex = []
    for c, name in enumerate(run.loads.names):
        r = np.linalg.norm(residual(top, X, fit.w[c], fit.L[c]), axis=1) / np.abs(fit.L[c, run.free])
        per_vertex.append(r)
        out["fit_errors"][name] = float(r.max(initial=0.0))
        if r.max(initial=0.0) > worst_err:
            worst, worst_err = c, float(r.max(initial=0.0))
    r = per_vertex[worst]
    order = np.argsort(r)[::-1][:REPORTED]
    s = np.repeat(1.0 / np.abs(fit.L[worst, run.free]), 3)
    A = weight_matrix(top, X)
    g = (A.T @ (s * (s * (A @ fit.w[worst] - load_vector(top, fit.L[worst])))))  # ∇ ½‖S(Aw − b)‖²
    w = fit.w[worst]
    at_lo, at_up = _at_bounds(run, w)  # (the polish's measure: the fit's weights lie within its tolerance of a bound)
    mult = np.where(at_lo, np.maximum(g, 0.0), 0.0) + np.where(at_up, np.maximum(-g, 0.0), 0.0)
    edges = np.argsort(mult)[::-1][:REPORTED]
    edges = edges[mult[edges] > 0]
    out.update(case=run.loads.names[worst], max_relative_error=worst_err,
               vertices=[int(v) for v in run.free_idx[order]], vertex_errors=[float(x) for x in r[order]],
               at_bound=int(np.count_nonzero(at_lo | at_up)), pushing=int(np.count_nonzero(mult > 0)),
               bound_edges=[[int(i), int(j)] for i, j in top.edges[edges]],
               bound=["lower" if at_lo[e] else "upper" for e in edges])
    return out


def _message(rec: dict[str, Any]) -> str:
    """The continuation's report in one sentence (why it did not reach every case, with its
    measurements)."""
    b = rec.get("blocking") or {}
    if b.get("case") is None:
        return rec.get("message") or "the continuation from the cases' envelope failed at its start"
    edges = ", ".join(f"{i}-{j} ({k})" for (i, j), k in zip(b["bound_edges"], b["bound"])) or "none"
    diffs = b["difference"]
    worst = max(diffs, key=lambda k: diffs[k]["max_relative_residual"])
    diff = diffs[worst]
    carried = (f"the weights the polish moves (those off their bounds) carry the difference of case {worst!r} from "
               f"the cases' mean load only to relative residual {diff['max_relative_residual']:.2e} (of a "
               f"difference up to {diff['load_difference']:.2e}), largest at vertices {diff['vertices']}")
    if rec.get("blocked_at_start"):
        lead = (f"at the network of the cases' envelope (solved alone), {carried}: no continuation from it "
                f"exists to first order (a step t leaves about t times that), so its stages were skipped")
    elif rec.get("stopped") == "time":
        lead = (f"the continuation from the cases' envelope carried {rec['reached']:.0%} of the cases' difference "
                f"from it in equilibrium when its share of the time ({SHARE:.0%}) could not hold another stage "
                f"(the last took {rec['stages'][-1]['t_stage']:.1f} s); there, {carried}")
    else:
        lead = (f"the continuation from the cases' envelope carries {rec['reached']:.0%} of the cases' "
                f"difference from it in equilibrium, no more (a step of {MIN_STEP:g} failed); there, {carried}")
    held = (f"{b['at_bound']} of its weights on a bound, {b['pushing']} of them pushed against it; those with the "
            f"largest multipliers: {edges}")
    return (f"{lead}; case {b['case']!r}'s weight fit within the bounds at that geometry (least squares of the "
            f"relative residuals) leaves max relative error {b['max_relative_error']:.2e}, at vertices {b['vertices']} "
            f"({', '.join(f'{e:.1e}' for e in b['vertex_errors'])}), with {held}"
            + _tension_note(b) + _top_view_note(rec.get("top_view") or {}))


def _tension_note(b: dict[str, Any]) -> str:
    """:func:`least_tension` of the report's case (``b["tension"]``, where measured) in a clause."""
    t = b.get("tension")
    if not t or t["status"] == "not measured":
        return ""
    if t["status"] == "carried":
        return (f"; yet weights within the bounds carry case {b['case']!r} exactly at that geometry (a linear "
                f"program): the fit's residual is the iteration's, not the geometry's")
    if t["status"] == "no weights":
        below = " below their upper bounds" if t.get("bounded_above") else ""
        return f"; no weights of either sign{below} carry case {b['case']!r} at that geometry (a linear program)"
    return (f"; no weights within the bounds carry case {b['case']!r} at that geometry: the least that carry it "
            f"exactly fall short of the lower bound (tension, for the default ε) by a total force of "
            f"{t['tension_share']:.2g} times the case's total load over {t['edges']} edges (the largest "
            f"{t['largest_share']:.2g} times it; most at edges {', '.join(f'{i}-{j}' for i, j in t['tension_edges'])}; "
            f"a linear program), so the geometry must move")


def _with_tension(run: _Run, X: np.ndarray, b: dict[str, Any], deadline: float) -> dict[str, Any]:
    """``b`` (:func:`blocking` at ``X``) with :func:`least_tension` of its case at ``X`` (by ``deadline``)."""
    if b.get("case") is None:
        return b
    L = run.loads_at(X)[run.loads.names.index(b["case"])]
    return {**b, "tension": least_tension(run.top, X, L, run.lower, run.upper, deadline=deadline)}


def _top_view_note(tv: dict[str, Any]) -> str:
    """:func:`top_view_self_stresses` at the envelope's network in a clause, where it proves the
    block (one self-stress); empty otherwise."""
    if tv.get("self_stresses") != 1:
        return ""
    nxt = "" if tv["next_singular"] is None else f"; the next singular value is {tv['next_singular']:.1e} of the largest"
    return (f"; over the top view of the envelope's network the horizontal self-stresses (weights of either sign "
            f"balancing every free vertex in plan) are one-dimensional ({tv['edges']} edges for "
            f"{tv['horizontal_equations']} horizontal equations{nxt}): every case's weights there are multiples of "
            f"one vector, so no heights and no weights of either sign carry cases whose loads are not "
            f"proportional, however small their difference; every case needs a top view with two self-stresses "
            f"(a different plan): more edges than horizontal equations (quads split into triangles: solve "
            f"--triangulate) or supports on the free boundary give the plan that room")


def _start(run: _Run, envelope: Network, deadline: float) -> dict[str, Any] | None:
    """The continuation's start at the envelope's network: its scaled positions ``X`` and weights
    ``wb``, every case's own weight fit there ``W_full``, and :func:`blocking` with the max
    residual of its :func:`difference_fit` (whether any stage can converge); None when no case
    fits there. ``deadline``: the solve's (the measurement is the report of a block)."""
    X = run.sc.pos(envelope.vertices)
    wb = run.sc.weight(envelope.weights[run.scene.active_edges])
    full = run.fit(X, [wb] * run.C)
    if full is None:
        return None
    share, run.deadline = run.deadline, deadline
    b = blocking(run, X, [wb] * run.C, fit=full)
    run.deadline = share
    return {"X": X, "wb": wb, "W_full": np.array(full.w), "blocking": b,
            "difference_residual": max(d["max_relative_residual"] for d in b["difference"].values())}


def continuation(method: StaggeredLinearization, problem: Problem, opt: StaggeredOptions,
                 progress: Callable[[dict], None] | None, warm_start: Any, deadline: float
                 ) -> tuple[SolveResult | None, dict[str, Any]]:
    """The continuation over the load cases (see the module docstring).

    Returns
    -------
    The converged result (None when the envelope does not converge alone, or the cases are
    blocked, or its share :data:`SHARE` of the time ran out) and the continuation's record: the
    stages (``t``, polish steps, max relative error, seconds), the ``t`` reached and, when it is
    short of 1, why (``message``) with the measurement of :func:`blocking`; ``blocked_at_start``
    when :func:`difference_fit` at the envelope's network exceeded :data:`BLOCKED_RESIDUAL`.
    """
    t0 = time.perf_counter()
    whole = deadline
    # (its share of the time: a blocked continuation leaves the rest to the iteration over every case)
    deadline = t0 + SHARE * (deadline - t0)
    run = _Run(method, problem, replace(opt, coupled=False), progress, None, deadline)
    rec: dict[str, Any] = {"stages": [], "reached": 0.0}
    base = _base_problem(problem, run)
    # the envelope unrefined first: the refinement (most of its time with a point load) only
    # pays when the stages run
    single = method.solve(base, dataclasses.asdict(replace(opt, coupled=None, refine=0, refine_concentrated=0)),
                          progress=progress, warm_start=warm_start, deadline=deadline)
    rec.update(base_status=single.status, base_time=single.wall_time, base_iterations=single.iterations)
    if single.status != "converged":
        rec["message"] = (f"the continuation did not start: the cases' envelope alone ended {single.status} at max "
                          f"relative error {single.max_relative_error:.2e} within the continuation's share of the "
                          f"time ({SHARE:.0%})")
        return None, rec
    start = _start(run, single.network, whole)
    if start is not None and start["difference_residual"] <= BLOCKED_RESIDUAL:
        base_run = _Run(method, base, replace(opt, coupled=False), progress, None, deadline)
        steps = refinement_steps(base_run)
        if steps > 0:
            rec["difference_residual_unrefined"] = start["difference_residual"]
            net, _, _ = base_run.refine(single.network, single.case_networks, single.max_relative_error,
                                        rec.setdefault("base_refinement", []), steps)
            start = _start(run, net, whole)
    if start is not None:  # (what the envelope's plan allows: the report of a block)
        rec["top_view"] = top_view_self_stresses(run.top, start["X"])
    if start is None or start["difference_residual"] > BLOCKED_RESIDUAL:
        rec.update(blocked_at_start=start is not None, time=time.perf_counter() - t0)
        if start is not None:
            rec.update(difference_residual=start["difference_residual"],
                       blocking=_with_tension(run, start["X"], start["blocking"], whole))
            rec["message"] = _message(rec)
        else:
            rec["message"] = "the continuation did not start: no case has a weight fit at the envelope's network"
        return None, rec
    X, wb, W_full = start["X"], start["wb"], start["W_full"]
    rec["difference_residual"] = start["difference_residual"]
    X_ok, W_ok, t_ok, dt = X, np.array([wb] * run.C), 0.0, 1.0
    t_stage = 0.0  # (the last stage's duration: the next one's estimate)
    while t_ok < 1.0 and dt >= MIN_STEP:
        if out_of_time(deadline, t_stage):
            rec["stopped"] = "time"
            break
        t = min(1.0, t_ok + dt)
        # the weights' start: the last stage's, moved towards the full fit as far as t has gone
        frac = (t - t_ok) / (1.0 - t_ok)
        W0 = W_ok + frac * (W_full - W_ok)
        ts = time.perf_counter()
        Xp, W, L, steps = run.polish(X_ok, list(W0), blend=t)
        err = max_rel_error(run.top, Xp, np.array(W), L) if np.all(np.isfinite(Xp)) else np.inf
        ok = bool(err <= STAGE_TOL)
        t_stage = time.perf_counter() - ts
        rec["stages"].append({"t": t, "steps": steps, "max_rel_error": err, "ok": ok, "t_stage": t_stage})
        if progress:
            progress({"iteration": "load continuation", **rec["stages"][-1]})
        if ok:
            X_ok, W_ok, t_ok = Xp, np.array(W), t
            dt *= 2.0
        else:
            dt *= 0.5
    rec["reached"] = t_ok
    if t_ok < 1.0:
        run.deadline = whole
        rec["blocking"] = _with_tension(run, X_ok, blocking(run, X_ok, list(W_ok)), whole)
        rec["message"] = _message(rec)
        rec["time"] = time.perf_counter() - t0
        return None, rec
    rec["time"] = time.perf_counter() - t0
    return _conclude(run, X_ok, list(W_ok), single, rec), rec


def _conclude(run: _Run, X: np.ndarray, ws: list[np.ndarray], single: SolveResult, rec: dict) -> SolveResult:
    """The result of a continuation that reached every case: the staggered method's verdict
    (:func:`~.conclude.conclude`) on the last stage's network, with the envelope's history."""
    fit = run.fit(X, ws)
    err = max_rel_error(run.top, X, np.array(ws), run.loads_at(X))
    s = IterState(X=X, fit=fit, schedule=Schedule.start(run.opt), w_start=ws, polish_tol=run.opt.joint_polish_tol,
                  coupled=False, t_iteration=0.0, it=single.iterations, status="converged",
                  history=list(single.history) + [{"iteration": "load continuation", **rec}])
    s.finished = FinishAttempt(ok=True, X=X, w=ws, rounds=sum(st["steps"] for st in rec["stages"]), error=err)
    net, cases, final = final_polish(run, s)
    s.history.append(final)
    s.message = (f"the cases' envelope solved alone, then every case carried by a continuation in "
                 f"{len(rec['stages'])} stage(s)")
    res = conclude(run, s, net, cases)
    return dataclasses.replace(res, parameters={**res.parameters, "load_continuation": rec})


def joint_freedom(problem: Problem) -> dict[str, int]:
    """The count of the joint problem over the cases: unknowns (three coordinates per free
    vertex, one weight per active edge and case) less equations (three per free vertex and
    case). At zero or below the equations fix the network without any room for the objective
    (and the weights' bounds, inequalities, are not even counted): a network exists only where the
    loads happen to fit. A quad mesh has about two edges per vertex, so three cases leave it about
    nothing; a triangle mesh about three, room for any number of cases."""
    scene = problem.scene
    n_free, m, C = int(np.sum(~scene.supports)), int(np.count_nonzero(scene.active_edges)), len(problem.loads)
    return {"free_vertices": n_free, "edges": m, "cases": C, "unknowns": 3 * n_free + C * m,
            "equations": 3 * C * n_free, "freedom": 3 * n_free + C * m - 3 * C * n_free}


def plan_matrix(top: Topology, X: np.ndarray) -> sp.csr_matrix:
    """The horizontal rows of the equilibrium matrix at ``X`` (the x and y rows of (2), ``2 n_free × m``):
    its null space is the top view's horizontal self-stresses."""
    return weight_matrix(top, X).tocsr()[np.flatnonzero(np.arange(3 * top.n_free) % 3 != 2)]


def top_view_self_stresses(top: Topology, X: np.ndarray) -> dict[str, Any]:
    """The horizontal self-stresses of the top view of ``X``: weights of either sign that
    balance every free vertex in plan, ``H(x, y) w = 0`` (the x and y rows of (2)). Every case's
    weights over this top view are among them, and the heights enter only the vertical rows:
    where they form a one-dimensional space every case's weights are multiples of one vector
    ``u``, the vertical rows read ``D(u) z = L_c / λ_c`` with the same heights ``z``, and so no
    heights and no weights of either sign carry cases whose loads are not proportional (more
    self-stresses: :func:`fixed_plan`).

    Returns the count of edges ``m``, of horizontal equations ``2 n_free`` (a mesh with
    ``m ≤ 2 n_free``, such as a quad mesh with free edges, has no self-stress at a generic top
    view: a solve finds a special one with one), ``self_stresses``: the dimension of the space,
    ``m − rank H``, and ``next_singular``, the smallest singular value of ``H`` counted nonzero
    over the largest (how far the top view is from one more), and ``route``. Up to
    :data:`SELF_STRESS_MAX_EDGES` edges a dense SVD (singular values at most
    :data:`SELF_STRESS_RTOL` times the largest count as zero); above, ``m − 2 n_free`` plus the
    plan's mechanisms, the zero singular values of ``Hᵀ`` (:func:`_plan_mechanisms`, resolved to
    :data:`SELF_STRESS_SPARSE_RTOL`); ``self_stresses`` None where that count did not resolve."""
    H = plan_matrix(top, X)
    out: dict[str, Any] = {"edges": top.m, "horizontal_equations": 2 * top.n_free,
                           "self_stresses": None, "next_singular": None}
    if top.m == 0:
        return out
    if top.m > SELF_STRESS_MAX_EDGES:
        mech, nxt = _plan_mechanisms(H)
        out["route"] = "sparse"
        if mech is not None:
            out.update(self_stresses=top.m - 2 * top.n_free + mech, next_singular=nxt)
        return out
    s = np.linalg.svd(H.toarray(), compute_uv=False)
    s = np.r_[s, np.zeros(max(top.m - s.size, 0))] / max(float(s[0]), np.finfo(float).tiny)
    zero = s <= SELF_STRESS_RTOL
    out.update(self_stresses=int(zero.sum()), next_singular=float(s[~zero].min()) if (~zero).any() else None,
               route="dense")
    return out


def _plan_mechanisms(H: sp.spmatrix) -> tuple[int | None, float | None]:
    """The dimension of the null space of ``Hᵀ`` (the plan's infinitesimal mechanisms: ``rank H =
    2 n_free`` less it) and the smallest singular value of ``H`` above zero over its largest, from
    the smallest eigenvalues of ``H Hᵀ`` (shift-invert Lanczos, sparse LU). (None, None) where
    every eigenvalue asked for is zero (more mechanisms than asked for)."""
    from scipy.sparse.linalg import eigsh  # (only for the report of a block)

    G = (H @ H.T).tocsc()
    rows = G.shape[0]
    lmax = float(eigsh(G, k=1, which="LA", return_eigenvectors=False)[0]) if rows > 1 else float(G.toarray().max())
    nev = min(rows - 1, max(rows - H.shape[1], 0) + 8)
    if nev < 1 or lmax <= 0.0:
        return None, None
    vals = eigsh(G, k=nev, sigma=-1e-12 * lmax, which="LM", return_eigenvectors=False)
    s = np.sort(np.sqrt(np.abs(vals) / lmax))
    zero = s <= SELF_STRESS_SPARSE_RTOL
    if zero.all():
        return None, None
    return int(zero.sum()), float(s[~zero].min())


def self_stress_basis(top: Topology, X: np.ndarray, k: int | None = None, *, seed: int = 0) -> np.ndarray:
    """An orthonormal basis ``(m, k)`` of the horizontal self-stresses of the top view of ``X``,
    by the route :func:`top_view_self_stresses` counts them: up to
    :data:`SELF_STRESS_MAX_EDGES` edges the null space of the dense SVD (``k`` unused); above,
    ``k`` (their count) random vectors projected twice onto the null space of ``H`` (``w − Hᵀ
    (H Hᵀ + σ I)⁻¹ H w``, one sparse LU), then orthonormalised. ``σ`` is 1e-14 of ``H Hᵀ``'s
    largest diagonal entry, so singular values of ``H`` above ~1e-7 of its largest
    (:data:`SELF_STRESS_SPARSE_RTOL`) are projected out and those below kept."""
    from scipy.linalg import null_space  # (only for the report of a block)
    from scipy.sparse.linalg import splu

    H = plan_matrix(top, X).tocsr()
    if top.m <= SELF_STRESS_MAX_EDGES or k is None:
        return null_space(H.toarray(), rcond=SELF_STRESS_RTOL)
    G = (H @ H.T).tocsc()
    lu = splu((G + sp.identity(G.shape[0]) * 1e-14 * float(G.diagonal().max(initial=1.0))).tocsc())
    W = np.random.default_rng(seed).standard_normal((top.m, k))
    for _ in range(2):
        W = W - H.T @ lu.solve(H @ W)
    return np.linalg.qr(W)[0]


def _plan_fit(top: Topology, X: np.ndarray, L: np.ndarray, S: np.ndarray,
              deadline: float | None) -> tuple[np.ndarray, float, int] | None:
    """:func:`fixed_plan`'s least-squares solve over the plan of ``X`` with self-stress basis
    ``S``: the cases' loads ``L`` (one row per case), the first balanced exactly. Returns the
    other cases' stacked relative vertical residuals at its end, the largest at its start, and its
    steps; None where the first case's stress Laplacian is singular."""
    from scipy.linalg import cho_factor, cho_solve  # (only for the report of a block)
    from scipy.sparse.linalg import splu

    free, (C, k) = top.free, (len(L), S.shape[1])
    s = 1.0 / np.abs(L[:, free])
    z_s = X[~free, 2]
    pos = X.copy()

    def heights(a: np.ndarray) -> tuple[Any, np.ndarray] | None:
        """The first case's heights for coefficients ``a`` (into ``pos``): their factor and the
        vertical rows there."""
        w = S @ a
        K_ff, K_fs = position_blocks(top, w)
        try:
            lu = splu(K_ff.tocsc())
        except RuntimeError:  # (a singular stress Laplacian: no heights)
            return None
        pos[free, 2] = lu.solve(L[0, free] - K_fs @ z_s)
        return lu, weight_matrix(top, pos).tocsr()[2::3]

    def others(a: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None] | None:
        """The other cases' relative vertical residuals (stacked) at ``a``'s heights, and their
        Jacobian in ``a`` (Kaufman's: the projection of the coefficients' fit held)."""
        h = heights(a)
        if h is None:
            return None
        lu, Vz = h
        VS = Vz @ S
        dz = -lu.solve(VS) if jac else None  # (K_ff dz = −Vz S: the first case stays balanced)
        r, J = [], []
        for c in range(1, C):
            # (normal equations: LAPACK's least squares on a tall dense matrix is 50× slower than
            # its products where the cores are shared, and the floor sought is far above their round-off)
            M = s[c][:, None] * VS
            G = M.T @ M
            G += np.identity(k) * 1e-14 * float(G.diagonal().max(initial=1.0))
            cho = cho_factor(G)
            b = cho_solve(cho, M.T @ (s[c] * L[c, free]))
            r.append(M @ b - s[c] * L[c, free])
            if jac:
                D = s[c][:, None] * (position_blocks(top, S @ b)[0] @ dz)
                J.append(D - M @ cho_solve(cho, M.T @ D))
        return np.concatenate(r), (np.vstack(J) if jac else None)

    # (the first case's coefficients fitted at the network's heights: its heights then move least)
    M0 = s[0][:, None] * (weight_matrix(top, X).tocsr()[2::3] @ S)
    a = cho_solve(cho_factor(M0.T @ M0 + np.identity(k) * 1e-14 * float((M0 * M0).sum(axis=0).max())),
                  M0.T @ (s[0] * L[0, free]))
    got = others(a, True)
    if got is None:
        return None
    r, J = got
    start, lam, steps = np.abs(r).max(), 1e-3, 0
    while steps < FIXED_PLAN_STEPS and np.abs(r).max() > BLOCKED_RESIDUAL and not out_of_time(deadline):
        steps += 1
        JtJ = J.T @ J
        step = np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ) + 1e-300), -J.T @ r)
        trial = others(a + step, False)
        if trial is not None and trial[0] @ trial[0] < r @ r:
            a, lam = a + step, max(lam / 3.0, 1e-12)
            r, J = others(a, True)  # type: ignore[misc]
        else:
            lam *= 4.0
            if lam > 1e12:
                break
    return r, float(start), steps


def fixed_plan(result: SolveResult, deadline: float | None = None) -> dict[str, Any]:
    """Whether, over the top view of ``result``'s network (several cases), any heights and any
    weights of either sign carry every case (loads held at the network's).

    Over a fixed plan every case's weights lie among its ``k`` horizontal self-stresses
    (:func:`top_view_self_stresses`), ``w_c = S a_c``, and the cases share the heights: ``C n_free``
    vertical equations for ``n_free + C k`` unknowns. Where ``k < (C − 1) n_free / C`` they
    outnumber the unknowns and generically no heights carry the cases (``needed``: the least
    ``k`` that does not); this is then measured by a least-squares solve (variable projection,
    Gauss–Newton, at most :data:`FIXED_PLAN_STEPS` steps): the first case exactly balanced (its
    heights solved for its coefficients ``a_1``), every other case's coefficients the linear least
    squares of its vertical rows at those heights, ``a_1`` moved to lower the others' relative
    residuals. A floor well above round-off (:data:`BLOCKED_RESIDUAL`) is the local evidence that
    the plan must move; the count is the generic one.

    Returns
    -------
    :func:`top_view_self_stresses` with ``cases``, ``needed``, ``unknowns``, ``equations`` and
    ``verdict``: "blocked" (with ``case``, the worst case, ``residual`` and ``start_residual``,
    its max relative residual per vertex after and before the solve, ``steps``, ``seconds``),
    "carried" (the solve reached the threshold), "not blocked by the count" or "not measured"
    (the count did not resolve, or no time).
    """
    t0 = time.perf_counter()
    (_, first), *_ = result.case_networks
    top = _active_topology(first)
    X = first.vertices
    n, C = top.n_free, len(result.case_networks)
    out = top_view_self_stresses(top, X)
    k = out["self_stresses"]
    out.update(cases=C, needed=-(-(C - 1) * n // C), unknowns=None if k is None else n + C * k, equations=C * n)
    if k is None or out_of_time(deadline):
        return {**out, "verdict": "not measured"}
    if k >= out["needed"]:
        return {**out, "verdict": "not blocked by the count"}
    names = [name for name, _ in result.case_networks]
    if k == 0:  # (no weights balance the plan: every case's vertical rows are its loads alone)
        return {**out, "verdict": "blocked", "case": names[0], "balanced": None, "residual": 1.0,
                "start_residual": 1.0, "steps": 0, "seconds": time.perf_counter() - t0}
    got = _plan_fit(top, X, np.array([net.loads for _, net in result.case_networks]),
                    self_stress_basis(top, X, k), deadline)
    if got is None:
        return {**out, "verdict": "not measured", "reason": "the first case's stress Laplacian is singular"}
    r, start, steps = got
    per_case = np.abs(r).reshape(C - 1, n).max(axis=1)
    worst = int(np.argmax(per_case))
    verdict = "carried" if per_case.max() <= BLOCKED_RESIDUAL else "blocked"
    return {**out, "verdict": verdict, "case": names[1 + worst], "balanced": names[0],
            "residual": float(per_case.max()), "start_residual": float(start), "steps": steps,
            "seconds": time.perf_counter() - t0}


def fixed_plan_note(fp: dict[str, Any]) -> str:
    """:func:`fixed_plan` in one sentence, where it measured a block (empty otherwise)."""
    if fp.get("verdict") != "blocked":
        return ""
    if fp["self_stresses"] == 0:
        return (f"this network's plan has no horizontal self-stress ({fp['edges']} edges for "
                f"{fp['horizontal_equations']} horizontal equations, full rank): no weights of either sign balance "
                f"its free vertices in plan, so over it no case stands, let alone {fp['cases']}; the plan must move "
                f"to a special one")
    return (f"over this network's plan the horizontal self-stresses (weights of either sign balancing every free "
            f"vertex in plan) are {fp['self_stresses']}-dimensional ({fp['edges']} edges for "
            f"{fp['horizontal_equations']} horizontal equations), so the {fp['cases']} cases' vertical equations "
            f"({fp['equations']}) outnumber the heights and the self-stresses' coefficients ({fp['unknowns']}): "
            f"generically no heights carry the cases over a plan with fewer than {fp['needed']} self-stresses; "
            f"a least-squares solve over this plan (case {fp['balanced']!r} balanced exactly, heights and every "
            f"case's weights of either sign free, loads held) leaves case {fp['case']!r} at max relative residual "
            f"{fp['residual']:.2e} (from {fp['start_residual']:.2e}, {fp['steps']} Gauss–Newton steps): the plan "
            f"must move to a special one, where the vertical equations are dependent, and the nearest network in "
            f"equilibrium may be far; more edges (quads split into triangles: solve --triangulate) or supports on "
            f"the free edges give every plan room")


def ipopt_finish(problem: Problem, stalled: SolveResult, deadline: float,
                 progress: Callable[[dict], None] | None) -> tuple[SolveResult, dict[str, Any]]:
    """IPOPT over every case jointly (the simultaneous method), started from the staggered
    network ``stalled`` (its positions and each case's weights), until ``deadline`` (each IPOPT
    run's ``max_wall_time``, the polish's deadline). Without a masonry hull it seeks the network
    in equilibrium for every case *nearest the staggered one* (``nearest_to_start``): the
    iteration has already traded the distance to the reference against the cases' errors, and
    IPOPT asked for the distance to the reference from there travels far with the loads held per
    round, which then change by percents and the rounds do not settle (a triangulated 16 × 16
    free-edged vault, two cases, from 5.8e-3: still 0.19 after 200 s; nearest the start:
    converged in 30 s, vertices moved by 0.2% of the span). Returns its result and a record: its status
    and IPOPT's last one, every case's max relative error, the mean distance to the reference
    against the start's, the seconds, and :func:`joint_freedom`."""
    t0 = time.perf_counter()
    # the registry's simultaneous method, imported only now (CasADi is not for every solve)
    simultaneous = method_class(find_method(simultaneous=True, load_cases=True, warm_start=True))
    nearest = problem.hull_thickness() is None
    res = simultaneous().solve(problem, {"warm_start": stalled, "time_limit": remaining(deadline),
                                         "nearest_to_start": nearest}, progress=progress, deadline=deadline)
    raw = [h["solver_status"] for h in res.history if h.get("stage") == simultaneous.backend]
    rec = {"status": res.status, "ipopt_status": raw[-1] if raw else None, "rounds": len(raw),
           "max_relative_error": res.max_relative_error,
           "case_errors": {name: net.max_relative_error() for name, net in res.case_networks},
           "distance_mean": res.distance_mean, "start_distance_mean": stalled.distance_mean,
           "nearest_to_start": nearest,
           "moved": float(np.abs(res.network.vertices - stalled.network.vertices).max()),
           "seconds": time.perf_counter() - t0, **joint_freedom(problem)}
    return res, rec


def finish_note(stalled: SolveResult, rec: dict[str, Any]) -> str:
    """One sentence: IPOPT's finish from the staggered network, beside the staggered numbers."""
    errs = ", ".join(f"{k} {v:.2e}" for k, v in rec["case_errors"].items())
    count = (f"; the joint problem has {rec['unknowns']} unknowns for {rec['equations']} equations "
             f"({rec['free_vertices']} free vertices, {rec['edges']} edges, {rec['cases']} cases)")
    seeking = " for the network nearest it" if rec.get("nearest_to_start") else ""
    return (f"IPOPT over every case jointly, started from this network (max relative error "
            f"{stalled.max_relative_error:.2e}){seeking}, ended {rec['status']} (IPOPT: {rec['ipopt_status']}) in "
            f"{rec['seconds']:.1f} s at max relative error per case {errs}, its vertices up to "
            f"{rec['moved']:.3g} m from it" + count)


def carry_note(carry: dict[str, dict[str, Any]]) -> str:
    """:func:`any_weights_carry` in one sentence: the case whose difference is carried worst, and
    whether the geometry (residual above :data:`BLOCKED_RESIDUAL`) or the bounds block."""
    name = max(carry, key=lambda k: carry[k]["max_relative_residual"])
    c = carry[name]
    if c["max_relative_residual"] > BLOCKED_RESIDUAL:
        return (f"at this network no change of the weights, of either sign and unbounded, carries case {name!r}'s "
                f"load difference from case {c['from']!r} (relative residual {c['max_relative_residual']:.2e}, at "
                f"vertices {c['vertices']}): the geometry blocks, not the weights' bounds" + peel_note(name, c))
    return (f"at this network weights of either sign carry every case's load difference from case {c['from']!r} "
            f"(relative residual at most {c['max_relative_residual']:.1e}): the weights' bounds, or the "
            "iteration's reach, block it")


def peel_note(name: str, c: dict[str, Any]) -> str:
    """:func:`case_peel` of ``any_weights_carry``'s case ``c`` in a clause, where the peel blocks it."""
    p = c.get("peel") or {}
    if not p.get("blocked_at"):
        return ""
    deg = p["smallest_degeneracy"]
    return (f"; nor does any network of this mesh without a degenerate vertex star: case {name!r} differs from "
            f"{c['from']!r} only at vertices {p['loaded']}, and from the free vertices with three edges or fewer, "
            f"{p['steps']} vertices in turn force the weights' difference to zero on {p['forced_edges']} edges, "
            f"every edge at vertex {p['blocked_at'][0]} among them (formulations.peel); only where some of "
            f"those stars degenerate (two edges on a line or three in a plane; here the smallest singular value "
            f"of their directions is {deg:.1e}, at vertex {p['degenerate_vertex']}) can one geometry carry both: "
            f"split the quads into triangles (solve --triangulate) or support the free edges")
