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

Where the continuation stops short of ``t = 1`` the cases are measured at the last network that
carried ``t`` of them: each case's own weight fit there (Step 2, within the bounds) gives its
relative residual per vertex, and the fit's bound multipliers name the edges whose bound blocks
it (:func:`blocking`).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import scipy.sparse as sp

from formulations import Bounds, LoadCases, Problem
from formulations.equilibrium import load_vector, residual, weight_matrix
from selfsupport.core.linalg import spd_factor
from selfsupport.core.loads import LoadCase
from selfsupport.core.result import SolveResult
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.polish import max_rel_error
from selfsupport.methods.staggered.conclude import conclude, final_polish
from selfsupport.methods.staggered.options import StaggeredOptions
from selfsupport.methods.staggered.run import _Run
from selfsupport.methods.staggered.schedule import Schedule
from selfsupport.methods.staggered.state import FinishAttempt, IterState

if TYPE_CHECKING:
    from selfsupport.methods.staggered.method import StaggeredLinearization

#: Smallest continuation step in ``t``: a stage that does not converge at this step ends the
#: continuation (the cases are blocked at the last ``t`` reached).
MIN_STEP = 1.0 / 64
#: Max relative residual at which a stage counts as converged (the joint polish's target is
#: round-off, ~1e-12; the final network is checked against the solve's ``tol`` as any other).
STAGE_TOL = 1e-10
#: Share of the solve's time the continuation may take (the envelope's solve included).
SHARE = 0.5
#: Vertices and bound edges named in the report of a blocked continuation.
REPORTED = 5


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


def difference_fit(run: _Run, X: np.ndarray, L: np.ndarray) -> dict[str, dict[str, Any]]:
    """Per case ``c``: can the network at ``X`` carry the difference ``L_c − L_e`` of its loads
    from the cases' envelope by a change of its weights of either sign, with no bound? A network
    that carries both does (its two weight vectors' difference), and any network near one that
    carries ``t`` of the difference does to first order in ``t``; where it cannot, no
    continuation from ``X`` exists. The least-squares weight change's relative residual per
    vertex (over ``|L_c|``): its max and the vertices where it is largest."""
    top = run.top
    A = weight_matrix(top, X)
    out = {}
    Le = L.min(axis=0)
    for c, name in enumerate(run.loads.names):
        s = np.repeat(1.0 / np.abs(L[c, run.free]), 3)
        As = (sp.diags(s) @ A).tocsc()
        b = s * load_vector(top, L[c] - Le)
        N = (As.T @ As).tocsc()
        mu = 1e-12 * float(N.diagonal().max(initial=1.0))  # (A has a null space: the self-stresses)
        d = spd_factor(N + mu * sp.identity(N.shape[0], format="csc")).solve(As.T @ b)
        r = np.linalg.norm((As @ d - b).reshape(-1, 3), axis=1)
        order = np.argsort(r)[::-1][:REPORTED]
        out[name] = {"max_relative_residual": float(r.max(initial=0.0)),
                     "load_difference": float(np.abs(b).reshape(-1, 3).max(initial=0.0)),
                     "vertices": [int(v) for v in run.free_idx[order]], "vertex_residuals": [float(x) for x in r[order]]}
    return out


def blocking(run: _Run, X: np.ndarray, ws: list[np.ndarray]) -> dict[str, Any]:
    """What blocks the cases at positions ``X`` (scaled): each case's own weight fit within the
    bounds, from ``ws``: per case its max relative residual, the worst case, its vertices of
    largest residual, and the edges its fit holds at a bound with the largest multipliers (the
    fit's gradient on a weight at its bound: how much the residual would fall per unit the bound
    gave way); and :func:`difference_fit`."""
    fit = run.fit(X, ws)
    top = run.top
    out: dict[str, Any] = {"fit_errors": {}, "case": None}
    if fit is None:
        return out
    out["difference"] = difference_fit(run, X, fit.L)
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
    lo = np.broadcast_to(run.lower, w.shape)
    up = np.broadcast_to(run.upper, w.shape)
    tol = 1e-9 * np.maximum(np.abs(lo), np.finfo(float).tiny)
    mult = np.where(w <= lo + tol, np.maximum(g, 0.0), 0.0) + np.where(w >= up - tol, np.maximum(-g, 0.0), 0.0)
    edges = np.argsort(mult)[::-1][:REPORTED]
    edges = edges[mult[edges] > 0]
    out.update(case=run.loads.names[worst], max_relative_error=worst_err,
               vertices=[int(v) for v in run.free_idx[order]], vertex_errors=[float(x) for x in r[order]],
               bound_edges=[[int(i), int(j)] for i, j in top.edges[edges]],
               bound=["lower" if w[e] <= lo[e] + tol[e] else "upper" for e in edges])
    return out


def _message(rec: dict[str, Any]) -> str:
    """The continuation's report in one sentence (blocked, with its measurements)."""
    b = rec["blocking"]
    if b.get("case") is None:
        return "the continuation from the cases' envelope failed at its start"
    edges = ", ".join(f"{i}-{j} ({k})" for (i, j), k in zip(b["bound_edges"], b["bound"])) or "none"
    diff = b["difference"].get(b["case"])
    unbounded = "" if diff is None else (
        "; no change of the weights of either sign carries that case's difference from the envelope on this "
        f"geometry (least-squares relative residual {diff['max_relative_residual']:.2e} of a difference up to "
        f"{diff['load_difference']:.2e}, largest at vertices {diff['vertices']}), so no network near it carries "
        "both")
    return (f"the continuation from the cases' envelope carries {rec['reached']:.0%} of the cases' "
            f"difference from it in equilibrium, no more (a step of {MIN_STEP:g} failed); there, case {b['case']!r} "
            f"fits at best to max relative error {b['max_relative_error']:.2e} within the bounds, at vertices "
            f"{b['vertices']} ({', '.join(f'{e:.1e}' for e in b['vertex_errors'])}); the edges its fit holds at a "
            f"bound with the largest multipliers: {edges}{unbounded}")


def continuation(method: StaggeredLinearization, problem: Problem, opt: StaggeredOptions,
                 progress: Callable[[dict], None] | None, warm_start: Any, deadline: float
                 ) -> tuple[SolveResult | None, dict[str, Any]]:
    """The continuation over the load cases (see the module docstring).

    Returns
    -------
    The converged result (None when the envelope does not converge alone, or the cases are
    blocked, or its share :data:`SHARE` of the time ran out) and the continuation's record: the stages
    (``t``, polish steps, max relative error), the ``t`` reached and, when blocked, the
    measurement of :func:`blocking`.
    """
    t0 = time.perf_counter()
    # (its share of the time: a blocked continuation leaves the rest to the iteration over every case)
    deadline = t0 + SHARE * (deadline - t0)
    run = _Run(method, problem, replace(opt, coupled=False), progress, None, deadline)
    rec: dict[str, Any] = {"stages": [], "reached": 0.0}
    single = method.solve(_base_problem(problem, run), dataclasses.asdict(replace(opt, coupled=None)),
                          progress=progress, warm_start=warm_start, deadline=deadline)
    rec.update(base_status=single.status, base_time=single.wall_time, base_iterations=single.iterations)
    if single.status != "converged":
        return None, rec
    X = run.sc.pos(single.network.vertices)
    wb = run.sc.weight(single.network.weights[run.scene.active_edges])
    full = run.fit(X, [wb] * run.C)  # every case's own weights at the envelope's network
    if full is None:
        return None, rec
    W_full = np.array(full.w)
    X_ok, W_ok, t_ok, dt = X, np.array([wb] * run.C), 0.0, 1.0
    while t_ok < 1.0 and dt >= MIN_STEP and not out_of_time(deadline):
        t = min(1.0, t_ok + dt)
        # the weights' start: the last stage's, moved towards the full fit as far as t has gone
        frac = (t - t_ok) / (1.0 - t_ok)
        W0 = W_ok + frac * (W_full - W_ok)
        ts = time.perf_counter()
        Xp, W, L, steps = run.polish(X_ok, list(W0), blend=t)
        err = max_rel_error(run.top, Xp, np.array(W), L) if np.all(np.isfinite(Xp)) else np.inf
        ok = bool(err <= STAGE_TOL)
        rec["stages"].append({"t": t, "steps": steps, "max_rel_error": err, "ok": ok,
                              "t_stage": time.perf_counter() - ts})
        if progress:
            progress({"iteration": "load continuation", **rec["stages"][-1]})
        if ok:
            X_ok, W_ok, t_ok = Xp, np.array(W), t
            dt *= 2.0
        else:
            dt *= 0.5
    rec["reached"] = t_ok
    rec["time"] = time.perf_counter() - t0
    if t_ok < 1.0:
        if not out_of_time(deadline):
            rec["blocking"] = blocking(run, X_ok, list(W_ok))
            rec["message"] = _message(rec)
        return None, rec
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
