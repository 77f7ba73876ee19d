"""One staggered solve: the problem in scaled units, and the iteration as named steps.

:meth:`_Run.solve` starts (:meth:`_Run.start`), iterates (:meth:`_Run.iterate`, one
:meth:`_Run.step` per iteration: finish try, release rules, Step 3, accept or reject), polishes
and concludes (:mod:`.conclude`). The loop's state is an :class:`~.state.IterState`; a fit is a
:class:`~.state.FitState`.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import scipy.sparse as sp

from formulations import Problem, TermContext, ThrustNetworkProblem, WeightBounds
from formulations.equilibrium import load_vector, position_blocks, weight_matrix
from formulations.terms import TERMS, HullPenalty, PlanarFaces, Sum, Term
from selfsupport.core.errors import InfeasibleDesign, InputError
from selfsupport.core.evidence import closest_points, fit_floor_tolerance, roundoff_floors
from selfsupport.core.result import Network, SolveResult
from selfsupport.methods.base import case_networks, cases_max_error
from selfsupport.methods.deadline import DeadlineReached, out_of_time
from selfsupport.methods.polish import case_load_jacobians
from selfsupport.methods.polish import polish as _polish
from selfsupport.methods.polish import polish_joint as _polish_joint
from selfsupport.methods.refine import refine as _refine
from selfsupport.methods.staggered.conclude import conclude, final_polish, retry_polish
from selfsupport.methods.staggered.finish import try_finish
from selfsupport.methods.staggered.options import DEFAULT_OBJECTIVE, StaggeredOptions
from selfsupport.methods.staggered.schedule import (
    Schedule,
    damping_after_coupled_step,
    damping_after_fallback,
    finish_due,
    fit_creeps,
    fit_stalls,
    retry_stopped,
    tightened_rtol,
    track_released,
)
from selfsupport.methods.staggered.state import FitState, IterState
from selfsupport.methods.staggered.step3 import Coupling, _hull_faces, _into_hull, _position_step
from selfsupport.methods.validate import require_top_view_balance, validate_problem
from selfsupport.methods.warm import as_warm_start, transfer
from selfsupport.methods.weight_refit import edge_bounds, refit_weights

if TYPE_CHECKING:
    from selfsupport.methods.staggered.method import StaggeredLinearization

#: Rounds of Step 3's hull active set (vertices a step carries out are pinned, the step solved again).
HULL_ROUNDS = 6

_NO_FIT = ("no weights can be fitted to the reference as it is (degenerate geometry, e.g. a flat network cannot "
           "carry vertical loads); give the surface some rise or check the mesh")


class _Run:
    """One solve: the problem in scaled units, the solve's workspaces, and the named steps."""

    def __init__(self, method: StaggeredLinearization, problem: Problem, opt: StaggeredOptions,
                 progress: Callable[[dict], None] | None, warm_start: Any = None,
                 deadline: float | None = None) -> None:
        self.t_start = time.perf_counter()
        # the one deadline every inner loop is given (see selfsupport.methods.deadline)
        self.deadline = self.t_start + opt.time_limit if deadline is None else deadline
        validate_problem(problem)  # mesh, supports; a flat reference needs w_max, else no nearest network exists
        self.method, self.problem, self.opt, self.progress = method, problem, opt, progress
        self.scene, self.loads = problem.scene, problem.loads
        self.mesh0 = self.scene.mesh
        self.C = len(self.loads)
        self.fixed_xy = problem.fixed_top_view
        if opt.coupled and self.fixed_xy:
            raise InputError("the coupled step (coupled=true) needs a free top view; drop coupled=true")
        sp_ = self.scaled = problem.scaled()
        self.top, self.sc = sp_.top, sp_.scaling
        self.lower, self.upper = sp_.lower, sp_.upper
        self.free = self.top.free
        self.free_idx = np.flatnonzero(self.free)
        self.X0 = sp_.X
        self.L0 = sp_.L
        self.reference = self.mesh0.with_vertices(sp_.X)
        self._terms(problem, opt)
        method.backend.reset()
        self._warm_start(warm_start, method)
        if self.fixed_xy:  # (the top view the solve keeps: the start's)
            require_top_view_balance(self.scene, self.sc.pos_back(self.X_start))
        # one backend per load case: each keeps its own warm start (active set, factor patterns)
        self.backends = [method.backend] + [type(method.backend)(**getattr(method.backend, "options", {}))
                                            for _ in range(self.C - 1)]
        self.step3: dict = {}  # Step 3's constant parts and its factor, kept across iterations
        self.polish_ws: dict = {}  # the polish's load-Jacobian colouring
        self.rtol_far = opt.fit_rtol  # the far-phase fits' KKT tolerance (tightened when it proves too loose)
        self.damping = opt.coupled_damping  # the coupled step's hold on the weights (raised when it over-promises)

    def _terms(self, problem: Problem, opt: StaggeredOptions) -> None:
        """The objective, the hull and planarity terms within it, and what Step 3 linearizes."""
        self.ctx = TermContext(vertices=self.X0, reference=self.reference, free=self.scene.free,
                               thickness=None if problem.hull_thickness() is None
                               else problem.hull_thickness() / self.sc.length)
        self.objective: Term | None = problem.terms(self.ctx, scaling=self.sc, default=DEFAULT_OBJECTIVE)
        parts = self.objective.parts() if self.objective is not None else ()
        # the hull's penalty term (if any): the joint polish holds its rows on the hull's face
        self.hull = next((t for t in parts if isinstance(t, HullPenalty)), None)
        # the planarity rows (if any): equations of the joint polish, a penalty in Step 3
        self.planar = next((t for t in parts if isinstance(t, PlanarFaces)), None)
        self.joint = self.C > 1 or self.fixed_xy or self.hull is not None or self.planar is not None
        # what Step 3 linearizes: the objective plus the method's own smoothing
        # (the hull is no penalty here but hard bounds, an active set: see position_step)
        smooth = TERMS["fairness"].build(self.ctx, weight=opt.smoothing) if opt.smoothing > 0 else None
        step3 = tuple(t for t in parts if not isinstance(t, HullPenalty)) + ((smooth,) if smooth else ())
        self.step3_terms: Term | None = (None if not step3 else step3[0] if len(step3) == 1 else Sum(step3))

    def _warm_start(self, warm_start: Any, method: StaggeredLinearization) -> None:
        """The starting iterate: the reference, or a previous network (methods/warm.py) whose
        weights are the first fit's warm start."""
        self.X_start, self.w_warm, self.warm_info = self.X0, None, None
        if warm_start is None:
            return
        V, w, same = transfer(as_warm_start(warm_start), self.scene)
        self.X_start = self.sc.pos(V)
        self.w_warm = [np.clip(self.sc.weight(w[self.scene.active_edges]), self.lower, self.upper)] * self.C
        self.warm_info = {"same_topology": same}
        if same:  # its active set seeds the first fit (PDAS then needs a few factorizations)
            method.backend.warm(self.w_warm[0], self.lower, self.upper)

    # ---------------------------------------------------------------- Steps 1-2
    def loads_at(self, X: np.ndarray) -> np.ndarray:
        """Step 1: scaled nodal loads of every case at positions ``X``, shape (n_cases, n)."""
        return self.sc.loads_at(self.loads, self.mesh0, X)

    def fit(self, X: np.ndarray, w0: list[np.ndarray], prox_rel: float | None = None, rtol: float | None = None, *,
            at_warm_start: bool = False) -> FitState | None:
        """Steps 1 and 2 at positions ``X``: loads, then one weight fit per load case, warm-started
        at ``w0``; None when the geometry admits no fit. ``at_warm_start``: ``w0`` is the warm
        start's, which fits already when it is in equilibrium to its round-off floor."""
        t0 = time.perf_counter()
        L = self.loads_at(X)
        t1 = time.perf_counter()
        free = self.free
        if not np.all(L[:, free] < 0) or not np.all(np.isfinite(X)):
            return None
        A = weight_matrix(self.top, X)
        prox_rel = self.opt.prox_w if prox_rel is None else prox_rel
        ws, As_all, rels, fits = [], [], [], []
        for c in range(self.C):
            s = np.repeat(1.0 / np.abs(L[c, free]), 3)
            # rows scaled in place: a product with diag(s) would drop A's stored zeros, the
            # structure the weight fit's factorizations are ordered by (linalg.structural_gram)
            As = sp.csc_matrix((A.data * s[A.indices], A.indices, A.indptr), shape=A.shape)
            b = s * load_vector(self.top, L[c])
            prox = prox_rel * float(np.asarray(As.multiply(As).sum(axis=0)).mean())
            floor = self._floor_tolerance(X, w0[c], L[c], b) if at_warm_start else None
            try:
                f = self.backends[c].fit(A=As, b=b, lower=self.lower, upper=self.upper, w0=w0[c], prox=prox,
                                         rtol=rtol, deadline=self.deadline, fits=floor)
            except (ValueError, RuntimeError, ArithmeticError):  # singular systems of a degenerate geometry
                return None
            if not np.all(np.isfinite(f.w)):
                return None
            ws.append(f.w)
            As_all.append(As)
            rels.append(np.linalg.norm((As @ f.w - b).reshape(-1, 3), axis=1))
            fits.append(f)
        t_weights = time.perf_counter() - t1
        worst_case = int(np.argmax([r.max() if r.size else 0.0 for r in rels]))
        worst = np.argsort(rels[worst_case])[::-1][:10]
        status = next((s for s in ("time_limit", "inexact") if any(f.status == s for f in fits)), fits[-1].status)
        E = float(sum(r @ r for r in rels))
        merit, rows = self._merit(X, ws, L, E)
        return FitState(X=X, L=L, w=ws, As=As_all, E=E, merit=merit, max_rel_error=float(max(r.max() for r in rels)),
                        worst_vertices=[int(v) for v in self.free_idx[worst]],
                        fit_iterations=int(sum(f.iterations for f in fits)), fit_status=status,
                        n_at_lower=int(sum(f.n_lower for f in fits)), n_at_upper=int(sum(f.n_upper for f in fits)),
                        t_loads=t1 - t0, t_weights=t_weights, cpu_s=time.process_time(), planar_rows=rows)

    def _floor_tolerance(self, X: np.ndarray, w: np.ndarray, L: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Per-row fit tolerance at which a warm start in equilibrium to its round-off floor
        fits already (:func:`~selfsupport.core.evidence.fit_floor_tolerance`), relative to ``|b|``."""
        at_floor = roundoff_floors(vertices=X, edges=self.top.edges, weights=w, loads=L, supports=~self.free)
        floor = np.repeat(fit_floor_tolerance(at_floor, L[self.free]), 3)
        floor /= max(float(np.abs(b).max(initial=0.0)), 1e-300)
        return floor

    def _merit(self, X: np.ndarray, ws: list[np.ndarray], L: np.ndarray, E: float) -> tuple[float, np.ndarray | None]:
        """What a step must lower: the fit error ``E``, plus, with planar faces required, their
        rows' squares weighted as in Step 3's model (``c`` × the penalty, ``c`` the mean squared
        relative diagonal of the stress Laplacian; see :func:`~.step3._position_step`) — else a
        step towards planar faces, which raises ``E`` a little, is never taken. Also the rows."""
        if self.planar is None:
            return E, None
        Kff, _ = position_blocks(self.top, ws[0])
        c = float(np.mean((Kff.diagonal() / np.abs(L[0][self.free])) ** 2))
        rows = self.planar.linearize(X)[0]
        return E + c * self.planar.weight * float(rows @ rows), rows

    def judge(self, Xt: np.ndarray, cur: FitState, rec: dict) -> tuple[FitState | None, bool]:
        """Steps 1-2 at the trial positions and whether they lower the merit. Far from
        equilibrium (fit error above finish_try) the fit only steers the iteration and stops at
        ``rtol_far``; such a fit overstates min_w E, so a rejection is confirmed by an exact fit,
        and when that overturns it the tolerance is tightened (:func:`~.schedule.tightened_rtol`)."""
        opt = self.opt
        rtol = self.rtol_far if cur.max_rel_error > opt.finish_try else None
        trial = self.fit(Xt, cur.w, rtol=rtol)
        accepted = trial is not None and trial.merit < cur.merit
        if not accepted and trial is not None and trial.fit_status == "inexact":
            trial = self.fit(Xt, cur.w)
            accepted = trial is not None and trial.merit < cur.merit
            rec["confirmed"] = True
            if accepted:
                self.rtol_far = tightened_rtol(self.rtol_far, opt)
        rec["fit_rtol"] = rtol
        rec["trial_fit_status"] = trial.fit_status if trial is not None else None
        return trial, accepted

    # ---------------------------------------------------------------- Step 3
    def position_step(self, X: np.ndarray, cur: FitState, alpha: float, beta: float,
                      coupled: bool = False) -> np.ndarray:
        """Step 3 at the current fit (see the package docstring), the masonry hull as hard bounds
        by an active set: vertices a step carries out of the hull are pinned to its face (normal
        part only) and the step solved again; what a last round still leaves outside is projected
        (a penalty of any weight either lets vertices out or, stiff, stalls the descent)."""
        coupling = None
        if coupled:  # each case's own scaled A at X, restricted to its weights off their bounds
            movable = [(w > self.lower) & (w < self.upper) for w in cur.w]
            coupling = Coupling(G=[As[:, m] for As, m in zip(cur.As, movable)],
                                gap=[(w - self.lower)[m] for w, m in zip(cur.w, movable)], prox=beta,
                                damping=self.damping)
        active = np.zeros(0, dtype=np.int64)
        for _ in range(HULL_ROUNDS):
            pinned = _hull_faces(self.hull, X, active) if active.size else None
            Xt = _position_step(self.top, X, weights=cur.w, loads=cur.L, objective=self.step3_terms, alpha=alpha,
                                beta=beta, coupling=coupling, workspace=self.step3, fixed_xy=self.fixed_xy,
                                pinned=pinned, deadline=self.deadline, rtol=self.opt.step_rtol)
            if self.hull is None:
                return Xt
            s = self.hull.signed_distance(Xt)
            out = self.hull.idx[np.abs(s) > self.hull.half_thickness]
            grown = np.union1d(active, out)
            if grown.size == active.size:
                break
            active = grown
        return _into_hull(self.hull, Xt, fixed_xy=self.fixed_xy)

    def time_message(self) -> str:
        """The message of a solve stopped by its deadline."""
        return f"time limit {self.opt.time_limit:g} s reached"

    # ---------------------------------------------------------------- results
    def networks(self, X: np.ndarray, ws: list[np.ndarray]) -> tuple[Network, tuple[tuple[str, Network], ...]]:
        """The network (first case) and every case's network at scaled positions and weights."""
        return case_networks(self.problem, self.sc, X, ws)

    def refit(self, cases) -> tuple[tuple[str, Network], ...] | None:
        """Every case's weights refit to its stored positions within the weight bounds
        (:func:`~selfsupport.methods.weight_refit.refit_weights`) when that puts every case in
        equilibrium, else None."""
        lo, up = edge_bounds(self.problem, self.scaled)
        out = []
        for name, n in cases:
            r = refit_weights(n, self.opt.tol, lower=lo, upper=up)
            if r is None:
                return None
            out.append((name, r))
        return tuple(out)

    def roundoff_limit(self, cases) -> dict | None:
        """The worst case's report when every case out of equilibrium is held there by rounding
        alone (:meth:`Network.roundoff_limit`), else ``None``."""
        reports = [n.roundoff_limit(self.opt.tol) for _, n in cases if not n.in_equilibrium(self.opt.tol)]
        if not reports or any(r is None for r in reports):
            return None
        return max(reports, key=lambda r: r["max_relative_error"])

    def blended(self, t: float) -> tuple[Callable, Callable]:
        """Loads ``L_e + t (L_c − L_e)`` of every case ``c``, ``L_e`` their envelope (at each vertex
        the heaviest of the cases' loads), and their Jacobians: the load path of the continuation
        over the cases (:mod:`.cases`)."""
        if "load_jacobians" not in self.polish_ws:
            self.polish_ws["load_jacobians"] = case_load_jacobians(self.loads.models, self.mesh0, self.sc, self.free)
        jacobians = self.polish_ws["load_jacobians"]

        def loads_at(X: np.ndarray) -> np.ndarray:
            L = self.loads_at(X)
            Le = L.min(axis=0)[None]  # (loads are negative: the heaviest is the least)
            return Le + t * (L - Le)

        def load_jacobian(X: np.ndarray, Lt: np.ndarray, deadline: float | None = None) -> list | None:
            L = self.loads_at(X)
            J = jacobians(X, L, deadline=deadline)
            if J is None:
                return None
            heaviest = L[:, self.free].argmin(axis=0)  # the envelope's rows: each from its heaviest case
            Je = None
            for c, Jc in enumerate(J):
                if Jc is not None:
                    rows = sp.diags(np.repeat((heaviest == c).astype(float), 3)) @ Jc
                    Je = rows if Je is None else Je + rows
            out = []
            for Jc in J:  # (None: no term depends on the geometry)
                terms = [f * M for f, M in ((1.0 - t, Je), (t, Jc)) if M is not None and f != 0.0]
                out.append(None if not terms else terms[0] if len(terms) == 1 else terms[0] + terms[1])
            return out

        return loads_at, load_jacobian

    def polish(self, X: np.ndarray, ws: list[np.ndarray], *, fallbacks: bool = True, stop: bool = False,
               blend: float | None = None):
        """Positions (and, with several cases, a fixed top view, a hull or planar faces, weights)
        in exact equilibrium: (X, ws, L, rounds). ``stop``: what the polishes return past their
        deadline (``X`` as it is, with its loads), without their set-up. ``blend``: ``t``, the
        loads of :meth:`blended` instead of the cases' own."""
        if stop:
            return X.copy(), ws, self.loads_at(X), 0
        if blend is not None:
            loads_at, load_jacobian = self.blended(blend)
        elif not self.joint:
            Xp, L, rounds = _polish(self.top, X, ws[0], self.loads.primary, self.mesh0, self.sc,
                                    workspace=self.polish_ws, fallbacks=fallbacks, deadline=self.deadline)
            return Xp, ws, L[None], rounds
        else:
            loads_at, load_jacobian = self.loads_at, None
        top = self.top
        h = float(np.linalg.norm(X[top.edges[:, 1]] - X[top.edges[:, 0]], axis=1).mean())
        form = ThrustNetworkProblem(top, X, loads_at(X), WeightBounds(self.lower, self.upper),
                                    weight_scale=1.0 / h ** 2, hull=self.hull, planar=self.planar,
                                    fixed_xy=self.X0[self.free, :2] if self.fixed_xy else None)
        if "load_jacobians" not in self.polish_ws:
            self.polish_ws["load_jacobians"] = case_load_jacobians(self.loads.models, self.mesh0, self.sc, self.free)
        Xp, W, rounds, _, _ = _polish_joint(form, X, np.array(ws), loads_at=loads_at,
                                            load_jacobian=load_jacobian or self.polish_ws["load_jacobians"],
                                            deadline=self.deadline)
        return Xp, list(W), loads_at(Xp), rounds

    def refine(self, net: Network, cases, err: float, history: list, steps: int) -> tuple[Network, Any, float]:
        """The optional refinement phase (:mod:`~selfsupport.methods.refine`), one load case, at
        most ``steps`` SQP steps."""
        opt, sc = self.opt, self.sc
        rec: dict[str, Any] = {"iteration": "refine"}
        if self.joint or self.objective is None:
            rec.update(applied=False, skipped="the refinement handles one load case, a free top view, no hull, and "
                                              "an objective")
            history.append(rec)
            return net, cases, err
        t0 = time.perf_counter()
        Xn = sc.pos(net.vertices)
        Xn[self.scene.supports] = self.X0[self.scene.supports]
        wn = sc.weight(net.weights[self.scene.active_edges])
        ref = _refine(self.top, Xn, wn, self.loads.primary, self.mesh0, sc, self.objective, self.lower, self.upper,
                      max_steps=steps, tol=opt.tol, min_gain=opt.refine_gain, deadline=self.deadline,
                      workspace=self.polish_ws, progress=self.progress)
        applied = False
        if ref.steps:
            refined, rcases = self.networks(ref.X, [ref.w])
            applied = cases_max_error(rcases) <= opt.tol  # (never trade equilibrium)
            if applied:
                net, cases, err = refined, rcases, cases_max_error(rcases)
        rec.update(steps=ref.steps, tried=ref.tried, applied=applied, t_refine=time.perf_counter() - t0,
                   max_rel_error=err, objective=[h["objective"] for h in ref.history if h["accepted"]],
                   rho=[h["rho"] for h in ref.history])
        history.append(rec)
        if self.progress:
            self.progress(rec)
        return net, cases, err

    # ---------------------------------------------------------------- the iteration
    def solve(self) -> SolveResult:
        """Iterate to the polish, polish (again from a tighter fit when the polish missed
        equilibrium), and conclude."""
        s = self.start()
        while True:
            self.iterate(s)
            net, cases, final = final_polish(self, s)
            if not retry_polish(self, s, cases, final):
                break
        s.history.append(final)
        if self.progress:
            self.progress(final)
        return conclude(self, s, net, cases)

    def start(self) -> IterState:
        """The first fit: at the warm start when it is near equilibrium (or ``warm_iterate``),
        else at the reference, centred at the best uniform weight (scale-free, deterministic)."""
        opt, top = self.opt, self.top
        X = self.X_start.copy()
        A0 = weight_matrix(top, X) @ np.ones(top.m)
        w_start = []
        for c in range(self.C):
            b0 = load_vector(top, self.L0[c])
            w_uniform = float(A0 @ b0 / max(float(A0 @ A0), 1e-300))
            w_start.append(np.clip(np.full(top.m, w_uniform), self.lower, self.upper))
        cur = self.fit(X, self.w_warm, at_warm_start=True) if self.w_warm is not None else None
        warm_fit = cur  # (when it fitted already and the loop ends on it, the final refit is skipped)
        warm_try = False
        if cur is not None and cur.max_rel_error <= opt.finish_try:
            self.warm_info["used"] = True
        elif cur is not None and cur.max_rel_error <= opt.warm_accept:
            self.warm_info["used"] = warm_try = True
        elif cur is not None and opt.warm_iterate:
            self.warm_info["used"] = True
        else:  # (a warm start this far from equilibrium is slower than a cold one)
            if self.w_warm is not None:
                self.warm_info.update(used=False, first_error=cur.max_rel_error if cur else None)
                X = self.X0.copy()
            cur = self.fit(X, w_start)
        if cur is None:
            raise InfeasibleDesign(_NO_FIT)
        # before the first iteration, the first fit stands in for an iteration's duration
        return IterState(X=X, fit=cur, schedule=Schedule.start(opt), w_start=w_start, warm_fit=warm_fit,
                         warm_try=warm_try, polish_tol=opt.joint_polish_tol if self.joint else opt.polish_tol,
                         coupled=bool(opt.coupled), t_iteration=cur.t_loads + cur.t_weights)

    def iterate(self, s: IterState) -> None:
        """Iterations from ``s.it + 1`` until a step ends the loop or ``max_iter``; Ctrl-C and a
        deadline inside a step stop it with the current iterate."""
        try:
            for it in range(s.it + 1, self.opt.max_iter + 1):
                s.it = it
                if self.step(s):
                    break
        except KeyboardInterrupt:  # Ctrl-C: stop cleanly with the best network so far
            s.status, s.message = "interrupted", "interrupted by the user; the network is the best one so far"
        except DeadlineReached:  # inside Step 3: the current iterate is the best network
            s.status, s.message = "time_limit", self.time_message()

    def step(self, s: IterState) -> bool:
        """One iteration: hand over to the polish, or try the finish, apply the release rules,
        then Step 3 and Step 4. True when the iteration ends here."""
        s.proj = None
        rec: dict[str, Any] = {"iteration": s.it, "alpha": s.schedule.alpha, "beta": s.schedule.beta,
                               **s.fit.record()}
        if s.retry_errors is not None:
            s.retry_errors.append(s.fit.max_rel_error)
        gap = self.gap(s.fit, rec)
        if gap <= s.polish_tol or retry_stopped(s.retry_errors):  # (a retry polishes once the fit stops improving)
            s.status = "converged"
            s.history.append(rec)
            return True
        if finish_due(gap, fresh=s.fresh, last_try=s.last_try, warm_try=s.warm_try, fit_status=s.fit.fit_status,
                      opt=self.opt):
            if self.finish(s, rec, s.schedule.finish_slack(self.opt)):
                return True
            if s.warm_try:  # the warm start does not finish as it is: start cold
                self.restart_cold(s, rec)
                return False
            s.last_try = gap  # try again once the fit error has halved
        s.fresh = False
        if self.release_rules(s, rec):
            return True
        if out_of_time(self.deadline, s.t_iteration):
            # (an iteration the deadline would cut is wasted: its Step 3 is no step, its fit too
            # loose to accept; and its factorizations cannot stop early)
            s.status, s.message = "time_limit", self.time_message()
            s.history.append(rec)
            return True
        Xt, trial, accepted = self.trial_step(s, rec)
        s.history.append(rec)
        if self.progress:
            self.progress(rec)
        return self.advance(s, Xt, trial, accepted)

    def gap(self, fit: FitState, rec: dict) -> float:
        """How far the fit is from the polish: its max relative error, or, with planar faces
        required, the larger of it and the planarity rows (the faces must be as near planar as
        the fit is near equilibrium before the joint polish makes both exact)."""
        if self.planar is None:
            return fit.max_rel_error
        rec["planarity_row"] = float(np.abs(fit.planar_rows).max(initial=0.0))
        return max(fit.max_rel_error, rec["planarity_row"])

    def projection(self, s: IterState) -> tuple:
        """Closest points of the iterate on the reference (computed at most once per iterate)."""
        if s.proj is None:
            s.proj = closest_points(s.X, self.reference)
        return s.proj

    def finish(self, s: IterState, rec: dict, slack: float) -> bool:
        """A finish try (:func:`~.finish.try_finish`), recorded in ``rec``; True when it ends the
        iteration: "converged", or "stalled" at its round-off floor (``s.at_floor``)."""
        attempt = try_finish(self, s.X, s.fit, d_it=self.projection(s)[1], slack=slack)
        rec["finish_try"] = attempt.record() if attempt is not None else None
        if attempt is None or attempt.ending is None:
            return False
        s.finished, s.status, s.at_floor = attempt, attempt.ending, attempt.ending == "stalled"
        s.history.append(rec)
        return True

    def restart_cold(self, s: IterState, rec: dict) -> None:
        """The warm start's one finish try failed: start again from the reference."""
        s.warm_try = False
        self.warm_info.update(used=False, first_error=s.fit.max_rel_error)
        s.X = self.X0.copy()
        cur = self.fit(s.X, s.w_start)
        if cur is None:
            raise InfeasibleDesign("no weights can be fitted to the reference as it is (degenerate geometry); "
                                   "check the mesh")
        s.fit = cur
        s.history.append(rec)

    def release_rules(self, s: IterState, rec: dict) -> bool:
        """Once α is at its minimum: a creeping fit turns Step 3 coupled (:func:`~.schedule.fit_creeps`);
        a stalled one (:func:`~.schedule.fit_stalls`) gets a last finish try and otherwise ends the
        run "stalled". True when the iteration ends here."""
        opt = self.opt
        s.released = track_released(s.released, s.fit.max_rel_error, s.schedule, opt)
        if fit_creeps(s.released, opt, coupled=s.coupled, fixed_xy=self.fixed_xy, n_vertices=self.mesh0.n_vertices,
                      n_cases=self.C):
            s.coupled, s.released = True, s.released[-1:]
            rec["coupled_from_here"] = True
        if not fit_stalls(s.released, opt):
            return False
        # (or Step 3 creeps with the weights held, and the polish of these weights finishes)
        if self.finish(s, rec, opt.finish_slack_released):
            return True
        s.stalled_at = float(self.projection(s)[1].mean())
        s.status, s.message = "stalled", (
            f"the fit error stopped falling (max relative error {s.fit.max_rel_error:.2e}) although "
            f"the pull towards the reference is fully released (α at its minimum for "
            f"{len(s.released) - 1} iterations)")
        s.history.append(rec)
        return True

    def trial_step(self, s: IterState, rec: dict) -> tuple[np.ndarray, FitState | None, bool]:
        """Step 3 with the weights of the current fit, and Steps 1-2 at the trial (:meth:`judge`).
        A rejected coupled step falls back to the plain one; the hold on the weights follows."""
        t0 = time.perf_counter()
        if self.opt.reproject_every and s.it > 1 and s.it % self.opt.reproject_every == 0 and self.step3_terms:
            self.step3_terms = self.step3_terms.at(s.X, projection=self.projection(s))
        if self.hull is not None and s.it > 1:  # the hull's slabs at X's closest points, every iteration
            # (fixed slabs let vertices slide out of the curved shell)
            self.hull = self.hull.at(s.X, projection=self.projection(s))
        alpha, beta = s.schedule.alpha, s.schedule.beta
        Xt = self.position_step(s.X, s.fit, alpha, beta, coupled=s.coupled)
        rec["t_positions"] = time.perf_counter() - t0
        trial, accepted = self.judge(Xt, s.fit, rec)
        if s.coupled and not accepted:
            # the coupled model over-promised (weights it moved were clamped by the refit): the
            # plain step; when that is taken the weights' moves failed, so hold them harder
            Xt = self.position_step(s.X, s.fit, alpha, beta)
            trial, accepted = self.judge(Xt, s.fit, rec)
            rec["fallback"] = True
            if accepted:
                self.damping = damping_after_fallback(self.damping)
        elif s.coupled:
            self.damping = damping_after_coupled_step(self.damping, self.opt)
        rec["coupled_damping"] = self.damping if s.coupled else None
        rec["cg_iterations"] = self.step3.get("cg_iterations", 0)  # of the step taken
        rec["accepted"] = accepted
        s.t_iteration = time.perf_counter() - t0
        return Xt, trial, accepted

    def advance(self, s: IterState, Xt: np.ndarray, trial: FitState | None, accepted: bool) -> bool:
        """Step 4: take an accepted trial and shrink α, β, or reject it and widen the trust
        region (:class:`~.schedule.Schedule`). True when too many rejections end the run."""
        if accepted:
            ratio = trial.merit / s.fit.merit
            s.X, s.fit, s.fresh = Xt, trial, True
            s.schedule.accept(ratio, self.opt)
            return False
        s.schedule.reject(self.opt)
        if s.schedule.out_of_steps(self.opt):
            s.status, s.message = "stalled", (f"no position step reduces the fit error any more "
                                              f"(max relative error {s.fit.max_rel_error:.2e})")
            return True
        return False
