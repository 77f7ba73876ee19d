"""One staggered solve: the problem in scaled units, the state of the iteration and its steps."""
from __future__ import annotations

import time
from dataclasses import asdict
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import scipy.sparse as sp

from formulations import Problem, TermContext, ThrustNetworkProblem, WeightBounds
from formulations.equilibrium import load_vector, position_blocks, weight_matrix
from formulations.scaling import Scaling
from formulations.terms import TERMS, HullPenalty, PlanarFaces, Sum, Term
from selfsupport.core.errors import InfeasibleDesign, InputError
from selfsupport.core.evidence import (
    FLOOR_CAP,
    FLOOR_MARGIN,
    closest_points,
    fit_floor_tolerance,
    roundoff_floors,
    roundoff_message,
)
from selfsupport.core.result import Network, SolveResult
from selfsupport.methods.base import (
    HULL_TOL,
    case_networks,
    cases_in_equilibrium,
    cases_max_error,
    hull_report,
    load_cases_note,
    planarity_report,
    short_of_tol,
    term_values,
)
from selfsupport.methods.deadline import DeadlineReached, out_of_time
from selfsupport.methods.polish import case_load_jacobians
from selfsupport.methods.polish import polish as _polish
from selfsupport.methods.polish import polish_joint as _polish_joint
from selfsupport.methods.refine import refine as _refine
from selfsupport.methods.staggered.finish import _try_finish
from selfsupport.methods.staggered.options import DEFAULT_OBJECTIVE, StaggeredOptions
from selfsupport.methods.staggered.schedule import DAMPING_MAX, _coupled_fits
from selfsupport.methods.staggered.step3 import _hull_faces, _into_hull, _position_step
from selfsupport.methods.validate import require_top_view_balance, validate_problem
from selfsupport.methods.warm import as_warm_start, transfer
from selfsupport.methods.weight_refit import edge_bounds, refit_weights

if TYPE_CHECKING:
    from selfsupport.methods.staggered.method import StaggeredLinearization


class _Run:
    """One solve: the problem in scaled units, the state of the iteration, and the named steps."""

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
        self.ctx = TermContext(vertices=sp_.X, reference=self.reference, free=self.scene.free,
                               thickness=None if problem.hull_thickness() is None
                               else problem.hull_thickness() / self.sc.length)
        self.objective: Term | None = problem.terms(self.ctx, scaling=self.sc, default=DEFAULT_OBJECTIVE)
        # the hull's penalty term (if any): the joint polish holds its rows on the hull's face
        self.hull = next((t for t in (self.objective.parts() if self.objective is not None else ())
                          if isinstance(t, HullPenalty)), None)
        # the planarity rows (if any): equations of the joint polish, a penalty in Step 3
        self.planar = next((t for t in (self.objective.parts() if self.objective is not None else ())
                            if isinstance(t, PlanarFaces)), None)
        self.joint = self.C > 1 or self.fixed_xy or self.hull is not None or self.planar is not None
        # what Step 3 linearizes: the objective plus the method's own smoothing
        # (the hull is no penalty here but hard bounds, an active set: see position_step)
        smooth = TERMS["fairness"].build(self.ctx, weight=opt.smoothing) if opt.smoothing > 0 else None
        parts = tuple(t for t in (self.objective.parts() if self.objective is not None else ())
                      if not isinstance(t, HullPenalty)) + ((smooth,) if smooth else ())
        self.step3_terms: Term | None = (None if not parts else parts[0] if len(parts) == 1 else Sum(parts))
        method.backend.reset()
        self.X_start, self.w_warm, self.warm_info = self.X0, None, None
        if warm_start is not None:  # a previous network as the starting iterate (methods/warm.py)
            V, w, same = transfer(as_warm_start(warm_start), self.scene)
            self.X_start = self.sc.pos(V)
            self.w_warm = [np.clip(self.sc.weight(w[self.scene.active_edges]), self.lower, self.upper)] * self.C
            self.warm_info = {"same_topology": same}
            if same:  # its active set seeds the first fit (PDAS then needs a few factorizations)
                method.backend.warm(self.w_warm[0], self.lower, self.upper)
        if self.fixed_xy:  # (the top view the solve keeps: the start's)
            require_top_view_balance(self.scene, self.sc.pos_back(self.X_start))
        # one backend per load case: each keeps its own warm start (active set, factor patterns)
        self.backends = [method.backend] + [type(method.backend)(**getattr(method.backend, "options", {}))
                                            for _ in range(self.C - 1)]
        self.step3: dict = {}  # Step 3's constant parts and its factor, kept across iterations
        self.polish_ws: dict = {}  # the polish's load-Jacobian colouring
        self.rtol_far = opt.fit_rtol  # the far-phase fits' KKT tolerance (tightened when it proves too loose)
        self.damping = opt.coupled_damping  # the coupled step's hold on the weights (raised when it over-promises)

    # ---------------------------------------------------------------- Steps 1-2
    def loads_at(self, X: np.ndarray) -> np.ndarray:
        """Step 1: scaled nodal loads of every case at positions ``X``, shape (n_cases, n)."""
        return self.sc.loads_at(self.loads, self.mesh0, X)

    def fit(self, X: np.ndarray, w0: list[np.ndarray], prox_rel: float | None = None,
            rtol: float | None = None) -> dict | None:
        """Steps 1 and 2 at positions ``X``: loads, then one weight fit per load case."""
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
            floor = None
            if w0 is self.w_warm:  # a warm start in equilibrium to its round-off floor fits already
                # (evidence.fit_floor_tolerance: with the equilibrium test's cap, a 256k pillar
                # vault's start at 1.06e-7, floor 1.6e-7, ran the interior point 150 s for nothing)
                at_floor = roundoff_floors(vertices=X, edges=self.top.edges, weights=w0[c], loads=L[c], supports=~free)
                floor = np.repeat(fit_floor_tolerance(at_floor, L[c, free]), 3)
                floor /= max(float(np.abs(b).max(initial=0.0)), 1e-300)
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
        worst_case = int(np.argmax([r.max() if r.size else 0.0 for r in rels]))
        worst = np.argsort(rels[worst_case])[::-1][:10]
        status = next((s for s in ("time_limit", "inexact") if any(f.status == s for f in fits)), fits[-1].status)
        return {"L": L, "w": ws, "As": As_all, "X": X, "E": float(sum(r @ r for r in rels)),
                "max_rel_error": float(max(r.max() for r in rels)),
                "worst_vertices": [int(v) for v in self.free_idx[worst]],
                "fit_iterations": int(sum(f.iterations for f in fits)), "fit_status": status,
                "n_at_lower": int(sum(f.n_lower for f in fits)), "n_at_upper": int(sum(f.n_upper for f in fits)),
                "t_loads": t1 - t0, "t_weights": time.perf_counter() - t1,
                "cpu_s": time.process_time()}  # (process CPU when this error was known: studies.peers)

    def judge(self, Xt: np.ndarray, cur: dict, rec: dict) -> tuple[dict | None, bool]:
        """Steps 1-2 at the trial positions and whether they lower the recorded fit error.
        Far from equilibrium (fit error above finish_try) the fit only steers the iteration
        and stops at ``rtol_far``. Such a fit overstates min_w E (its proximal term aside),
        so it may reject a step that lowers it: a rejection is confirmed by an exact fit.
        When the exact fit overturns it, the steps' gains are smaller than the loose fits'
        overstatement (large meshes: E falls by ~0.1% per step), and the tolerance is
        tightened tenfold for the rest of the solve."""
        opt = self.opt
        rtol = self.rtol_far if cur["max_rel_error"] > opt.finish_try else None
        trial = self.fit(Xt, cur["w"], rtol=rtol)
        accepted = trial is not None and self.merit(trial) < self.merit(cur)
        if not accepted and trial is not None and trial["fit_status"] == "inexact":
            trial = self.fit(Xt, cur["w"])
            accepted = trial is not None and self.merit(trial) < self.merit(cur)
            rec["confirmed"] = True
            if accepted:
                self.rtol_far = max(0.1 * self.rtol_far, min(opt.fit_rtol, 1e-6))
        rec["fit_rtol"] = rtol
        rec["trial_fit_status"] = trial["fit_status"] if trial is not None else None
        return trial, accepted

    def merit(self, fit: dict) -> float:
        """What a step must lower: the fit error ``E``, plus, with planar faces required, their
        rows' squares weighted as in Step 3's model (``c`` × the penalty, ``c`` the mean squared
        relative diagonal of the stress Laplacian; see :func:`_position_step`) — else a step
        towards planar faces, which raises ``E`` a little, is never taken."""
        if self.planar is None:
            return fit["E"]
        if "merit" not in fit:
            Kff, _ = position_blocks(self.top, fit["w"][0])
            c = float(np.mean((Kff.diagonal() / np.abs(fit["L"][0][self.free])) ** 2))
            r = self.planar_rows(fit)
            fit["merit"] = fit["E"] + c * self.planar.weight * float(r @ r)
        return fit["merit"]

    def planar_rows(self, fit: dict) -> np.ndarray:
        """The planarity rows at the fit's positions (computed once per fit)."""
        if "planar_rows" not in fit:
            fit["planar_rows"] = self.planar.linearize(fit["X"])[0]
        return fit["planar_rows"]

    # ---------------------------------------------------------------- Step 3
    def position_step(self, X: np.ndarray, cur: dict, alpha: float, beta: float, coupled: bool = False) -> np.ndarray:
        """Step 3 at the current fit (see the module docstring)."""
        G = gap = None
        if coupled:  # each case's own scaled A at X, restricted to its weights off their bounds
            movable = [(w > self.lower) & (w < self.upper) for w in cur["w"]]
            G = [As[:, m] for As, m in zip(cur["As"], movable)]
            gap = [(w - self.lower)[m] for w, m in zip(cur["w"], movable)]
        active = np.zeros(0, dtype=np.int64)
        for _ in range(6):
            # the masonry hull as hard bounds, by an active set: vertices a step carries out of the
            # hull are pinned to its face (normal part only) and the step solved again; what a
            # last round still leaves outside is projected (a penalty of any weight either lets
            # vertices out or, stiff, stalls the descent: a dome with an apex load in a 2 cm hull
            # stalled at fit error 0.78; projection alone stalled there too)
            pinned = _hull_faces(self.hull, X, active) if active.size else None
            Xt = _position_step(self.top, X, cur["w"], cur["L"], self.step3_terms, alpha, beta, G=G, prox_dw=beta,
                                gap=gap, damping=self.damping, workspace=self.step3,
                                fixed_xy=self.fixed_xy, pinned=pinned, deadline=self.deadline)
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
        return case_networks(self.problem, self.sc, X, ws)

    def refit(self, cases) -> tuple[tuple[str, Network], ...] | None:
        """Every case's weights refit to its stored positions within the weight bounds
        (:func:`~.weight_refit.refit_weights`) when that puts every case in equilibrium, else None."""
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

    def polish(self, X: np.ndarray, ws: list[np.ndarray], *, fallbacks: bool = True, stop: bool = False):
        """Positions (and, with several cases or a fixed top view, weights) in exact equilibrium:
        (X, ws, L, rounds). ``stop``: what the polishes return past their deadline (``X`` as it
        is, with its loads), without their set-up."""
        if stop:
            return X.copy(), ws, self.loads_at(X), 0
        if not self.joint:
            Xp, L, rounds = _polish(self.top, X, ws[0], self.loads.primary, self.mesh0, self.sc,
                                    workspace=self.polish_ws, fallbacks=fallbacks, deadline=self.deadline)
            return Xp, ws, L[None], rounds
        top = self.top
        h = float(np.linalg.norm(X[top.edges[:, 1]] - X[top.edges[:, 0]], axis=1).mean())
        form = ThrustNetworkProblem(top, X, self.loads_at(X), WeightBounds(self.lower, self.upper),
                                    weight_scale=1.0 / h ** 2, hull=self.hull, planar=self.planar,
                                    fixed_xy=self.X0[self.free, :2] if self.fixed_xy else None)
        if "load_jacobians" not in self.polish_ws:
            self.polish_ws["load_jacobians"] = case_load_jacobians(self.loads.models, self.mesh0, self.sc, self.free)
        Xp, W, rounds, _, _ = _polish_joint(form, X, np.array(ws), loads_at=self.loads_at,
                                            load_jacobian=self.polish_ws["load_jacobians"], deadline=self.deadline)
        return Xp, list(W), self.loads_at(Xp), rounds

    def try_finish(self, X: np.ndarray, cur: dict, d_it: np.ndarray, slack: float) -> tuple | None:
        """Polish the iterate now and keep it if it is in equilibrium, inside the hull and no
        farther from the reference than the iterate (mean within ``slack``, max within 4× that;
        ``finish_slack``, or ``finish_slack_released`` once α is at its minimum): finishing then
        costs no closeness, further iterations could only drift.
        Returns (positions, weights, rounds, info), or None when the polish breaks down.

        With one case and a free top view the current weights are polished (:func:`_try_finish`).
        With several cases, a fixed top view or a hull it is the joint polish, which moves the
        weights with the positions: near equilibrium its Newton steps converge where Step 3, with
        the weights held, creeps (a dome with an apex load in a 5 cm hull: the fit error fell by
        half in 30 iterations at α's minimum; the joint polish, tried there, moved vertices by
        7e-4 of the diagonal to 1e-14).

        A polish that meets everything but ``tol``, and is held above it by rounding alone
        (:meth:`roundoff_limit`), says so in ``info["roundoff_limit"]``: the iteration stops there
        (a 256k pillar vault's prolonged start, 1.06e-7 at its floor, iterated 640 s to 5.6e-6)."""
        early = self._polish_try(X, cur, d_it, slack)
        if early is None or early[3]["ok"] or early[0] is None:
            return early
        Xp, ws, _, info = early
        if (info["error"] > self.opt.tol and info.get("inside_hull", True) and info.get("planar", True)
                and info["dist_mean_ratio"] <= 1 + slack and info["dist_max_ratio"] <= 1 + 4 * slack):
            limit = self.roundoff_limit(self.networks(Xp, ws)[1])
            if limit is not None:
                info["roundoff_limit"] = limit
        return early

    def finish_attempt(self, X: np.ndarray, cur: dict, d_it: np.ndarray, slack: float,
                       rec: dict) -> tuple[tuple | None, tuple[str, bool] | None]:
        """One finish try (:meth:`try_finish`), recorded in ``rec``: the try when it ends the
        iteration, and how — ("converged", False), or ("stalled", True) when it is in equilibrium
        as far as doubles can tell but above tol (its round-off floor: stop there) — else
        (None, None)."""
        early = self.try_finish(X, cur, d_it, slack)
        rec["finish_try"] = early[3] if early is not None else None
        if early is not None and early[3]["ok"]:
            return early, ("converged", False)
        if early is not None and "roundoff_limit" in early[3]:
            return early, ("stalled", True)
        return None, None

    def _polish_try(self, X: np.ndarray, cur: dict, d_it: np.ndarray, slack: float) -> tuple | None:
        opt = self.opt
        if not self.joint:
            early = _try_finish(self.top, X, cur["w"][0], cur["L"][0], self.loads.primary, self.mesh0, self.sc,
                                self.reference, d_it, opt, slack, self.polish_ws, deadline=self.deadline)
            return None if early is None else (early[0], cur["w"], early[2], early[3])
        Xp, ws, _, rounds = self.polish(X, cur["w"])
        if not np.all(np.isfinite(Xp)):
            return None
        net, cases = self.networks(Xp, ws)
        err = cases_max_error(cases)
        d_p = closest_points(Xp, self.reference)[1]
        # (the true distance: the slabs re-anchored at the polished positions)
        inside = self.hull is None or bool(np.all(
            np.abs(self.hull.at(Xp).signed_distance(Xp)) <= self.hull.half_thickness * (1 + HULL_TOL)))
        planar = self.planar is None or planarity_report(self.problem, net)["met"]
        ok = (err <= opt.tol and inside and planar and float(d_p.mean()) <= (1 + slack) * float(d_it.mean())
              and float(d_p.max()) <= (1 + 4 * slack) * float(d_it.max()))
        info = {"ok": bool(ok), "error": err, "inside_hull": inside, "planar": planar,
                "dist_mean_ratio": float(d_p.mean() / max(d_it.mean(), 1e-300)),
                "dist_max_ratio": float(d_p.max() / max(d_it.max(), 1e-300))}
        return Xp, ws, rounds, info

    # ---------------------------------------------------------------- the iteration
    def solve(self) -> SolveResult:
        opt, top, sc = self.opt, self.top, self.sc
        X = self.X_start.copy()
        alpha, beta = opt.alpha0, opt.beta0
        history: list[dict[str, Any]] = []
        status, message = "iteration_limit", ""
        at_floor = False  # stopped by a finish try held above tol by rounding alone
        stalled_at = None  # the mean distance of the iterate at which the stall rule stopped the run
        # proximal centre of the first fit: the best uniform weight (scale-free, deterministic)
        A0 = weight_matrix(top, X) @ np.ones(top.m)
        w_start = []
        for c in range(self.C):
            b0 = load_vector(top, self.L0[c])
            w_uniform = float(A0 @ b0 / max(float(A0 @ A0), 1e-300))
            w_start.append(np.clip(np.full(top.m, w_uniform), self.lower, self.upper))
        cur = self.fit(X, self.w_warm) if self.w_warm is not None else None
        warm_fit = cur  # (the warm start's own fit: when it fitted already and the loop ends on it,
        # the final refit below is skipped — it cannot balance the start better than its floor)
        warm_try = False  # one finish try from the warm start, else a cold start
        if cur is not None and cur["max_rel_error"] <= opt.finish_try:
            self.warm_info["used"] = True
        elif cur is not None and cur["max_rel_error"] <= opt.warm_accept:
            self.warm_info["used"] = warm_try = True
        elif cur is not None and opt.warm_iterate:
            self.warm_info["used"] = True
        else:  # (a warm start this far from equilibrium measured slower than a cold one: 1.0-1.9x on lilium)
            if self.w_warm is not None:
                self.warm_info.update(used=False, first_error=cur["max_rel_error"] if cur else None)
                X = self.X0.copy()
            cur = self.fit(X, w_start)
        if cur is None:
            raise InfeasibleDesign("no weights can be fitted to the reference as it is (degenerate geometry, e.g. a flat "
                                   "network cannot carry vertical loads); give the surface some rise or check the mesh")
        it = 0
        rejected = 0
        released: list[float] = []  # fit errors of the iterations since α reached alpha_min
        fresh, early, last_try = True, None, np.inf
        polish_tol = opt.joint_polish_tol if self.joint else opt.polish_tol
        coupled = bool(opt.coupled)  # (turned on when the fit creeps at α's minimum: creep_window)
        retry_errors: list[float] | None = None  # fit errors since a retry began
        # duration of the last iteration (Step 3 and its fits): the next one is started only if it
        # can end before the deadline; before the first, the first fit stands in for it
        t_iteration = cur["t_loads"] + cur["t_weights"]
        while True:
            try:
                for it in range(it + 1, opt.max_iter + 1):
                    proj = None  # closest points of X on the reference: computed at most once per iterate
                    rec: dict[str, Any] = {"iteration": it, "alpha": alpha, "beta": beta,
                                           **{k: v for k, v in cur.items() if k not in ("L", "w", "As", "X", "planar_rows")}}
                    if retry_errors is not None:
                        retry_errors.append(cur["max_rel_error"])
                    # (with planar faces required, the faces must be as near planar as the fit is
                    # near equilibrium before the joint polish makes both exact)
                    gap = cur["max_rel_error"]
                    if self.planar is not None:
                        rec["planarity_row"] = float(np.abs(self.planar_rows(cur)).max(initial=0.0))
                        gap = max(gap, rec["planarity_row"])
                    if gap <= polish_tol or (
                            retry_errors is not None and len(retry_errors) > 5
                            and retry_errors[-1] > 0.5 * retry_errors[-6]):
                        # (during a retry: polish again once the fit stops improving)
                        status = "converged"
                        history.append(rec)
                        break
                    if (fresh and (gap <= min(opt.finish_try, 0.5 * last_try) or warm_try)
                            and cur["fit_status"] not in ("inexact", "time_limit")):
                        # (a trial fitted loosely that landed below finish_try waits one step: the
                        # next fit is exact, and the finish polishes exact weights only)
                        proj = proj if proj is not None else closest_points(X, self.reference)
                        slack = opt.finish_slack if alpha > opt.alpha_min else opt.finish_slack_released
                        early, ended = self.finish_attempt(X, cur, proj[1], slack, rec)
                        if ended:
                            status, at_floor = ended
                            history.append(rec)
                            break
                        if warm_try:  # the warm start does not finish as it is: start cold
                            warm_try = False
                            self.warm_info.update(used=False, first_error=cur["max_rel_error"])
                            X = self.X0.copy()
                            cur = self.fit(X, w_start)
                            if cur is None:
                                raise InfeasibleDesign("no weights can be fitted to the reference as it is "
                                                       "(degenerate geometry); check the mesh")
                            history.append(rec)
                            continue
                        last_try = gap  # try again once the fit error has halved
                    fresh = False
                    released = released + [cur["max_rel_error"]] if alpha <= opt.alpha_min else []
                    if (not coupled and not self.fixed_xy and opt.creep_window
                            and _coupled_fits(self.mesh0.n_vertices, self.C)
                            and len(released) > opt.creep_window
                            and released[-1] > 0.5 * released[-1 - opt.creep_window]):
                        # Step 3 creeps with the weights held (a point load: the cone under it needs
                        # the weights and the positions to move together): move them together
                        coupled, released = True, released[-1:]
                        rec["coupled_from_here"] = True
                    if len(released) > opt.stall_window and released[-1] > 0.5 * released[-1 - opt.stall_window]:
                        # the reference no longer holds the positions, yet the fit does not improve:
                        # more iterations only move the network further (an infeasible design) — or
                        # Step 3 creeps with the weights held (a point load: the fit error fell 0.39 ->
                        # 0.25 in 30 iterations on lilium), and the polish of these weights finishes
                        proj = proj if proj is not None else closest_points(X, self.reference)
                        early, ended = self.finish_attempt(X, cur, proj[1], opt.finish_slack_released, rec)
                        if ended:
                            status, at_floor = ended
                            history.append(rec)
                            break
                        stalled_at = float(proj[1].mean())
                        status, message = "stalled", (
                            f"the fit error stopped falling (max relative error {cur['max_rel_error']:.2e}) although "
                            f"the pull towards the reference is fully released (α at its minimum for "
                            f"{len(released) - 1} iterations)")
                        history.append(rec)
                        break
                    if out_of_time(self.deadline, t_iteration):
                        # (an iteration the deadline would cut is wasted: its Step 3 is no step,
                        # its fit too loose to accept; and its factorizations cannot stop early)
                        status, message = "time_limit", self.time_message()
                        history.append(rec)
                        break
                    # Step 3: positions, with the weights of the current fit
                    t0 = time.perf_counter()
                    if opt.reproject_every and it > 1 and it % opt.reproject_every == 0 and self.step3_terms:
                        proj = proj if proj is not None else closest_points(X, self.reference)
                        self.step3_terms = self.step3_terms.at(X, projection=proj)
                    if self.hull is not None and it > 1:  # the hull's slabs at X's closest points, every
                        # iteration (fixed slabs let vertices slide out of the curved shell)
                        proj = proj if proj is not None else closest_points(X, self.reference)
                        self.hull = self.hull.at(X, projection=proj)
                    Xt = self.position_step(X, cur, alpha, beta, coupled=coupled)
                    rec["t_positions"] = time.perf_counter() - t0
                    # Steps 1-2 at the trial positions; far from equilibrium the fit only steers the
                    # iteration, so it may stop at a looser tolerance
                    trial, accepted = self.judge(Xt, cur, rec)
                    if coupled and not accepted:
                        # the coupled model over-promised (weights it moved were clamped by the
                        # refit): fall back to the plain position step before shrinking the region.
                        # When the plain step is taken, the weights' moves were what failed: hold
                        # them harder in the next coupled step (a concave disk with two load cases,
                        # one a point load: every coupled step at the default hold was rejected, and
                        # the plain steps crept until "stalled"). When both fail, the region is too
                        # large, which β answers.
                        Xt = self.position_step(X, cur, alpha, beta)
                        trial, accepted = self.judge(Xt, cur, rec)
                        rec["fallback"] = True
                        if accepted:
                            self.damping = min(10.0 * self.damping, DAMPING_MAX)
                    elif coupled:
                        self.damping = max(0.5 * self.damping, opt.coupled_damping)
                    rec["coupled_damping"] = self.damping if coupled else None
                    rec["cg_iterations"] = self.step3.get("cg_iterations", 0)  # of the step taken
                    rec["accepted"] = accepted
                    t_iteration = time.perf_counter() - t0
                    history.append(rec)
                    if self.progress:
                        self.progress(rec)
                    # Step 4: trust-region style schedule
                    if accepted:
                        ratio = self.merit(trial) / self.merit(cur)
                        X, cur = Xt, trial
                        fresh = True
                        beta = max(beta * opt.shrink, opt.beta_min)
                        alpha = max(alpha * min(1.0, ratio ** 0.5) * opt.shrink, opt.alpha_min)
                        rejected = 0
                    else:
                        beta *= 4.0
                        rejected += 1
                        if rejected >= 3:  # short steps still fail: the anchor holds X, loosen it
                            alpha = max(alpha * opt.shrink, opt.alpha_min)
                        if rejected > opt.max_rejections:
                            status, message = "stalled", (f"no position step reduces the fit error any more "
                                                          f"(max relative error {cur['max_rel_error']:.2e})")
                            break
            except KeyboardInterrupt:  # Ctrl-C: stop cleanly with the best network so far
                status, message = "interrupted", "interrupted by the user; the network is the best one so far"
            except DeadlineReached:  # inside Step 3: the current iterate is the best network
                status, message = "time_limit", self.time_message()

            if status not in ("converged", "interrupted") and not at_floor:
                message = (f"{message or status}; vertices hardest to balance: {cur['worst_vertices'][:5]} "
                           f"(max relative fit error {cur['max_rel_error']:.2e}); try more supports there, a larger "
                           "w_max, a pillar, or more iterations").lstrip("; ")
            # final fit with (almost) no proximal pull, so that the polish moves the geometry as
            # little as the data allow (an input already in equilibrium comes back unchanged)
            t0 = time.perf_counter()
            if early is not None:  # the polish of the current weights was already accepted
                Xp, ws, load_rounds, _ = early
            else:
                # (when the deadline would cut it — a fit's factorizations cannot stop early, and
                # one at 200k vertices takes seconds — keep the current weights)
                t_fit = cur["t_loads"] + cur["t_weights"]
                as_warm = cur is warm_fit and cur["fit_iterations"] == 0 and retry_errors is None
                last = None if out_of_time(self.deadline, t_fit) or as_warm else self.fit(X, cur["w"], opt.prox_w_final)
                ws = last["w"] if last is not None and last["E"] <= cur["E"] else cur["w"]
                # Polish: weights frozen (or, with several cases, moved least), positions exact.
                # It factors a system of the mesh's size before it can check the deadline (2.3 s
                # at 200k vertices): a run the deadline stopped skips it when it would end past
                # the deadline (a fit's time stands in for it), as the polish does past it
                t0 = time.perf_counter()
                Xp, ws, _, load_rounds = self.polish(
                    X, ws, stop=status != "converged" and out_of_time(self.deadline, t_fit))
            polish_move = float(np.linalg.norm(Xp - X, axis=1).max()) if np.all(np.isfinite(Xp)) else np.inf
            net, cases = self.networks(Xp, ws) if np.isfinite(polish_move) else (None, ())
            err = max(n.max_relative_error() for _, n in cases) if net is not None else np.inf
            final = {"iteration": "polish", "t_polish": time.perf_counter() - t0, "load_rounds": load_rounds,
                     "polish_max_move": polish_move, "max_rel_error": err, "kept": True, "cpu_s": time.process_time()}
            if status != "converged" and not (np.isfinite(err) and err <= min(cur["max_rel_error"], 1.0)):
                # from a poor fit the exact solve can land anywhere (even collapse): keep the last
                # iterate, labelled by its status, rather than a "polished" network that is worse
                final["kept"] = False
                net, cases = self.networks(X, ws)
                if ws is not cur["w"]:  # the final fit minimises the sum of squares, not the max error
                    alt = self.networks(X, cur["w"])
                    if cases_max_error(alt[1]) < cases_max_error(cases):
                        net, cases = alt
                message += "; the final polish did not improve the network, so the last iterate is returned (not in equilibrium)"
            elif status != "converged" and polish_move > opt.polish_tol:
                message += (f"; to reach equilibrium the final polish moved vertices by up to {polish_move:.2e} "
                            "of the bounding-box diagonal, so this network may be far from the design")
            if (status == "converged" and early is None and not cases_in_equilibrium(cases, opt.tol) and polish_tol > 1e-9
                    and it < opt.max_iter and not out_of_time(self.deadline) and self.roundoff_limit(cases) is None):
                # the polish did not reach equilibrium (the load fixed point stalled, e.g. on a
                # kink of the area model): iterate on to a much tighter fit and polish again
                history.append({**final, "kept": False, "retry": True})
                polish_tol *= 1e-2
                retry_errors = []
                status = "iteration_limit"
                continue
            break
        history.append(final)
        if self.progress:
            self.progress(final)
        err = cases_max_error(cases)
        # (a load on a support goes into the ground: it concentrates nothing on the network)
        concentrated = any(self.free[c.concentrated_at()].any() for c in self.loads.models)
        steps = opt.refine or (opt.refine_concentrated if concentrated else 0)
        if steps > 0 and status == "converged" and err <= opt.tol:
            net, cases, err = self.refine(net, cases, err, history, steps)
            if not history[-1].get("applied") and history[-1].get("tried"):
                # (say so: with a point load the unrefined network may be the spike under it)
                message = "; ".join(m for m in (message, (
                    f"the refinement towards the reference kept none of its {history[-1]['tried']} trial steps "
                    "(none stayed in equilibrium and came closer): the network is the unrefined one")) if m)
        elif steps > 0 and status == "stalled" and stalled_at is not None and err <= opt.tol and not self.joint:
            # (the stall rule stopped a creeping fit and the final polish moved the network away, 1.9x
            # the iterate's distance on a 4k pillar vault under a point load: the refinement walks it
            # back in equilibrium; as near the reference as the iterate, it is the method's answer)
            net, cases, err = self.refine(net, cases, err, history, steps)
            d = float(closest_points(sc.pos(net.vertices), self.reference)[1].mean())
            history[-1]["stalled_at"], history[-1]["refined_to"] = stalled_at, d
            if err <= opt.tol and d <= (1 + opt.finish_slack_released) * stalled_at:
                status, message = "converged", (
                    f"the fit stopped falling at α's minimum; its polish, refined in equilibrium, is as near the "
                    f"reference as the last iterate ({d / stalled_at:.2f}× its mean distance)")
        if (status == "converged" or at_floor) and not cases_in_equilibrium(cases, opt.tol) \
                and not out_of_time(self.deadline) and self.roundoff_limit(cases) is not None:
            # held above tol by rounding the positions alone: the weights, refit to the positions as
            # stored, absorb what the framework allows (weight_refit.py; a 256k pillar vault's free
            # arches: 2.1e-8 -> 8.4e-9, weights moved by 2e-7 of themselves)
            t0 = time.perf_counter()
            refit = self.refit(cases)
            history.append({"iteration": "weight refit", "applied": refit is not None, "max_rel_error_before": err,
                            "t_refit": time.perf_counter() - t0})
            if refit is not None:
                net, cases = refit[0][1], refit
                err = history[-1]["max_rel_error"] = cases_max_error(cases)
                status, at_floor = "converged", False
                message = "; ".join(m for m in (message, (
                    f"the polish was held at {history[-1]['max_rel_error_before']:.2e} by the rounding of its "
                    "positions; its weights, refit to the positions as stored, put it in equilibrium")) if m)
        floor, balanced = None, cases_in_equilibrium(cases, opt.tol)
        if status == "converged" and err > opt.tol and balanced:
            # (forces many times the loads: no positions balance those vertices better in doubles)
            floor = max(float(n.roundoff_floors().max(initial=0.0)) for _, n in cases)
            message = (f"max relative error {err:.2e} is above tol {opt.tol:g} but within {FLOOR_MARGIN:g}× the "
                       f"round-off floor of the vertices above it (max floor {floor:.2e}: forces far larger than "
                       f"those vertices' loads) and {FLOOR_CAP:g}; " + message).rstrip("; ")
        limit = self.roundoff_limit(cases) if (status == "converged" or at_floor) and not balanced else None
        if limit is not None:  # (held above tol by rounding alone: more supports or iterations cannot help)
            status, message = "stalled", "; ".join(m for m in (roundoff_message(limit, opt.tol), message) if m)
        elif at_floor:  # (the last iterate was returned instead, and it is off the floor)
            message = "; ".join(m for m in (message, "the iteration stopped at a polish held above tol by "
                                            "rounding alone") if m)
        if status == "converged" and not balanced:
            status, message = "stalled", short_of_tol(net, opt.tol, err)
        params: dict[str, Any] = {**asdict(opt), "eps": _si_bound(sc, self.lower), "w_max": _si_bound(sc, self.upper),
                                  "scaling": asdict(sc), "problem": self.problem.describe(),
                                  "load_cases": list(self.loads.names), "warm_start": self.warm_info}
        if floor is not None:  # (converged at the round-off floor, above tol)
            params["roundoff_floor"] = floor
        if limit is not None:  # (stalled: held above tol by rounding alone)
            params["roundoff_limit"] = limit
        hull = hull_report(self.problem, net)
        if hull is not None:
            params["hull"] = hull
        planarity = planarity_report(self.problem, net)
        if planarity is not None:
            params["planarity"] = planarity
            if status == "converged" and not planarity["met"]:
                status, message = "stalled", (
                    f"in equilibrium, but faces are not planar: max non-planarity {planarity['max_nonplanarity']:.2e} "
                    f"> {planarity['tol']:g} (diagonal distance over mean edge length); try a larger planarity "
                    "penalty, or a quad mesh along the relative principal directions (selfsupport pq)")
        if status != "converged":
            message = "; ".join(m for m in (message, load_cases_note(self.problem)) if m)
        return SolveResult.build(
            net, cases=cases, status=status, method=self.method.name, backend=self.method.backend.name,
            iterations=it, wall_time=time.perf_counter() - self.t_start, history=tuple(history), message=message,
            parameters=params, terms=term_values(self.problem, net, default=DEFAULT_OBJECTIVE))

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
                      max_steps=steps, tol=opt.tol, min_gain=opt.refine_gain,
                      deadline=self.deadline,
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


def _si_bound(sc: Scaling, b: np.ndarray) -> Any:
    """A bound in N/m for the record: a number when it is the same on every edge."""
    v = sc.weight_back(np.asarray(b, float))
    if v.size and np.all(v == v[0]):
        return None if np.isinf(v[0]) else float(v[0])
    return v.tolist()
