"""The paper's staggered linearization (§3, Steps 0–4), in scale-free units.

Step 1  loads from the current geometry.
Step 2  weights with positions fixed: a box-constrained sparse least-squares fit of the
        relative residual ``(A w − b)_i / |A_i F_i|`` (pluggable backend, warm-started). While
        the fit error is above ``finish_try`` the backend may stop at a KKT tolerance of
        ``fit_rtol`` = 1e-3: those fits only steer the iteration. A loose fit overstates
        min_w E, so it may reject a step that lowers it; a rejection is therefore confirmed by an
        exact fit (without that, a 4k concave disk stalled at its first step), and when the exact
        fit overturns it the tolerance is tightened tenfold for the rest of the solve (a 64k
        disk, whose E falls by ~0.1% per step, otherwise paid an exact fit on every step).
        Measured against 1e-6 on 37 solves (paper scenes, rotated/scaled and jittered variants,
        generated shapes): all converge, 7 end closer to the reference (up to 30%), 4 farther
        (up to 6%); lilium takes 0.71-0.83x the time (two alternating measurements). The fits
        the finish and the polish use are exact (a loosely fitted iterate waits one step for
        its exact fit before the finish is tried).
Step 3  positions with weights fixed: a sparse SPD linear least-squares problem

            Σ_i ‖r_i / d_i‖² + α Σ_i ( ⟨n_i, v_i − p_i⟩² + τ ‖T_i (v_i − p_i)‖² ) + β Σ_i ‖v_i − v_i^k‖²

        (+ γ ‖U (v − v_ref)‖², U the umbrella Laplacian: the displacement must be smooth, which
        keeps vertices whose weights sit at ε from being thrown far away — the original tool
        smoothed the same way) where the residual rows are scaled by ``1 / |A_i F_i|`` (the error
        the fit measures) and the penalties by the mean ``(d_i / |A_i F_i|)²``, ``d_i = Σ_j w_ij``,
        which turns that relative residual into a length. ``p_i`` and ``n_i``
        are a point of the reference surface and its normal (tangent-plane linearization of
        the distance to the reference, re-projected as the vertex slides), ``T_i`` the tangent
        projector (a weak hold against sliding) and the β term a proximal step. All terms
        are lengths relative to the bounding-box diagonal, so α, β, τ are dimensionless.
Step 4  repeat. A trial position is accepted only if Steps 1-2 there give a smaller fit error
        (the merit is E(X) = min_w E(X, w), so the iteration is a descent method); otherwise β is
        multiplied by 4 and the step retried (a trust region). After an accepted step α and β
        shrink, α in proportion to the square root of the error reduction, so the iteration goes
        from "stay on the reference" towards "satisfy equilibrium" as fast as the error allows.
        From the third rejection in a row α shrinks too: by then the steps are short, and what
        stops the descent is the anchor itself (the positions sit at a stationary point of the
        Step-3 objective for this α). A flat disk with ``w_max`` stalled this way (w_max 3e3 and
        1e4 of 1e2...1e5; 1e2 fails in IPOPT too); on the paper's scenes no step is rejected.
        Once α is at ``alpha_min`` the reference no longer holds the network; if the fit error
        then does not halve within ``stall_window`` iterations the design is taken as
        infeasible and the solve stops "stalled" (the paper's scenes spend at most 2 iterations
        at ``alpha_min``; without the rule a 1200-vertex vault with one pillar base freed ran on
        to the 200-iteration limit, the network drifting further all the while).
Coupled (option ``coupled``) Step 3 may also move the weights that are not at a bound, with a
        damping ∝ 1/(w − ε)² so that weights near ε hardly move: a Gauss-Newton step on the
        reduced error min_w E(X, w) instead of on E(X, w_k). It follows the penalty path more
        faithfully (measured: up to 1.65× closer to the reference on the paper's scenes) but costs a
        (3n + m)-sized factorization per step; a rejected coupled step falls back to the plain
        one. Not the default: slower, and its weights are less reproducible under rotations and
        scalings of the input (up to ~1.5% of the weight moves, against < 1% for the plain step).
Finish  once the fit's max relative error is below ``finish_try``, every accepted step tries the
        polish below with the current weights and keeps it when the polished network is in
        equilibrium and its mean distance to the reference exceeds the iterate's by at most
        ``finish_slack``: finishing then costs (almost) no closeness, and iterating on could only
        drift. A try is screened first: positions in equilibrium with the weights and the
        iterate's loads (one stress-Laplacian solve) predict the polished distance, and a try
        predicted far beyond the slack is not polished (twocirc-3: 4 tries of 20–33 ms skipped,
        0.83× the time, the same network). A try uses Newton only: one that Newton cannot
        finish fails cheaply (the fixed-point fallbacks took 0.7 s of 1.9 s on a 1k concave
        disk for a try that failed anyway). The linear systems are factored by CHOLMOD (:mod:`selfsupport.linalg`).
Polish  once the fit's max relative error is below ``polish_tol``, the weights are frozen and
        the positions solved exactly from (2)-(3) — a stress-Laplacian system — with the loads
        re-estimated from the new geometry until they are consistent to round-off (Newton with
        a coloured finite-difference load Jacobian; :mod:`~selfsupport.methods.polish`). The
        result is in equilibrium to machine precision with loads of its own geometry.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from ..errors import InfeasibleDesign, InputError
from ..evidence import closest_points
from ..geometry import vertex_normals
from ..loads import LoadCase, SelfWeight, with_scene_extras
from ..result import Network, SolveResult
from ..scene import Scene
from ..validate import require_rise
from .assembly import Topology, block_diagonal, load_vector, position_blocks, residual, weight_matrix
from .scaling import Scaling, ScaledProblem
from ..linalg import spd_factor
from .polish import polish as _polish
from .refine import refine as _refine
from .weightfit import WeightFitBackend, make_backend


@dataclass(frozen=True)
class StaggeredOptions:
    """Settings of the staggered method (general: no per-scene tuning)."""

    alpha0: float = field(default=1.0, metadata={"range": "(0, inf)"})  # distance-to-reference penalty at the start
    beta0: float = field(default=0.01, metadata={"range": "(0, inf)"})  # proximal penalty at the start
    shrink: float = field(default=0.5, metadata={"range": "(0, 1)"})  # factor applied to α, β after an iteration that reduced the error
    # (and to α from the third rejected step in a row)
    alpha_min: float = field(default=1e-8, metadata={"range": "(0, inf)"})
    beta_min: float = field(default=1e-8, metadata={"range": "(0, inf)"})
    max_rejections: int = field(default=12, metadata={"range": "[1, inf)"})  # consecutive rejected position steps before "stalled"
    stall_window: int = field(default=30, metadata={"range": "[1, inf)"})  # iterations at alpha_min in which the fit error must halve, else "stalled"
    # (on the paper's scenes and their variants at most 2 iterations are spent at alpha_min)
    tangential: float = field(default=0.05, metadata={"range": "[0, inf)"})  # τ: tangential hold relative to the normal one
    fairness: float = field(default=100.0, metadata={"range": "[0, inf)"})  # γ/α: umbrella-Laplacian smoothness of the displacement (the original tool's smoothing)
    reproject_every: int = field(default=1, metadata={"range": "[0, inf)"})  # closest-point re-projection onto the reference (0: never)
    prox_w: float = field(default=1e-8, metadata={"range": "(0, inf)"})  # proximal weight of the Step-2 fit relative to its diagonal: makes the
    # weights unique (A has more columns than rows) and reproducible during the iteration
    prox_w_final: float = field(default=1e-12, metadata={"range": "(0, inf)"})  # ... and for the last fit before the polish
    polish_tol: float = field(default=1e-3, metadata={"range": "(0, inf)"})  # fit error below which the weights are frozen and positions solved
    coupled: bool = False  # Step 3 moves the free weights with the positions (Gauss-Newton on min_w E):
    # up to 1.65x closer to the reference on the paper's scenes, 1.5-4x slower, and less reproducible
    # under rotation/scaling of the input (weights shift by up to ~1.5%); hence opt-in
    coupled_damping: float = field(default=1e-4, metadata={"range": "[0, inf)"})  # coupled step: how strongly weights near ε are held (∝ 1/gap²)
    finish_try: float = field(default=0.1, metadata={"range": "[0, inf)"})  # fit error below which the polish is tried after every accepted step
    finish_slack: float = field(default=0.05, metadata={"range": "[0, inf)"})  # ... and kept if its mean distance to the reference grows by at most this
    finish_screen: float = field(default=0.25, metadata={"range": "[0, inf)"})  # ... and not even polished when one stress-Laplacian solve with the
    # iterate's loads already moves the mean distance up by more than this (see _try_finish)
    try_fallbacks: bool = False  # ... with Newton only (no Anderson / Newton-Krylov rounds after it)
    fit_rtol: float = field(default=1e-3, metadata={"range": "(0, inf)"})  # KKT tolerance a Step-2 backend may stop at while the fit error is above
    # finish_try (those fits only steer the iteration; the fits the finish uses are exact)
    refine: int = field(default=0, metadata={"range": "[0, inf)"})  # at most this many SQP steps towards the reference after convergence (refine.py;
    # 0: the paper's method as it is)
    tol: float = field(default=1e-9, metadata={"range": "(0, inf)"})  # required max relative error of the final network
    max_iter: int = field(default=200, metadata={"range": "[1, inf)"})
    time_limit: float = field(default=600.0, metadata={"range": "(0, inf)"})


def parse_option(text: str) -> tuple[str, Any]:
    """``"KEY=VALUE"`` → a typed :class:`StaggeredOptions` setting (the CLI's ``--option``).

    >>> parse_option("coupled=true"), parse_option("shrink=0.25")
    (('coupled', True), ('shrink', 0.25))

    Values outside the interval in the field's ``metadata["range"]`` are refused
    (:func:`selfsupport.options.check_range`).
    """
    key, sep, value = text.partition("=")
    key, value = key.strip().replace("-", "_"), value.strip()
    fields = StaggeredOptions.__dataclass_fields__
    if not sep or key not in fields:
        raise InputError(f"--option needs KEY=VALUE with KEY one of {sorted(fields)}, got {text!r}")
    kind = str(fields[key].type)
    try:
        if kind == "bool":
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(value)
            return key, value.lower() in ("true", "1", "yes")
        number = int(value) if kind == "int" else float(value)
    except ValueError:
        raise InputError(f"--option {key} needs a {kind} value, got {value!r}") from None
    if not np.isfinite(number):
        raise InputError(f"--option {key} must be finite, got {value!r}")
    from ..options import check_range

    check_range(key, number, fields[key].metadata.get("range"))  # the interval next to the field
    return key, number


class StaggeredLinearization:
    """The paper's method. ``backend`` names the Step-2 solver (see ``WEIGHT_FIT_BACKENDS``).

    Example
    -------
    >>> from selfsupport.shapes import make_shape
    >>> res = StaggeredLinearization().solve(make_shape("dome", n_vertices=300), SelfWeight())
    >>> res.status, res.max_relative_error < 1e-9
    ('converged', True)
    """

    name = "staggered"

    def __init__(self, backend: str | WeightFitBackend = "active-set", **options: Any) -> None:
        self.backend = make_backend(backend) if isinstance(backend, str) else backend
        unknown = set(options) - set(StaggeredOptions.__dataclass_fields__)
        if unknown:
            raise InputError(f"unknown staggered option(s) {sorted(unknown)}; known: {sorted(StaggeredOptions.__dataclass_fields__)}")
        self.options = StaggeredOptions(**options)

    def solve(self, scene: Scene, loads: LoadCase | None = None, *, eps: float | None = None,
              w_max: float | None = None, progress: Callable[[dict], None] | None = None,
              **overrides: Any) -> SolveResult:
        """Solve for the thrust network nearest to ``scene.mesh``.

        Parameters
        ----------
        scene
            Reference mesh and supports.
        loads
            Load case (default: :class:`SelfWeight` with its defaults), plus the scene's extras.
        eps, w_max
            Weight bounds in SI units [N/m]; ``eps`` defaults to a scale-free bound
            (:func:`~selfsupport.methods.scaling.default_eps`).
        progress
            Called with the history record of each iteration.
        overrides
            Any :class:`StaggeredOptions` field, for this solve only.
        """
        unknown = set(overrides) - set(StaggeredOptions.__dataclass_fields__)
        if unknown:
            raise InputError(f"unknown staggered option(s) {sorted(unknown)}; known: {sorted(StaggeredOptions.__dataclass_fields__)}")
        opt = replace(self.options, **overrides) if overrides else self.options
        t_start = time.perf_counter()
        scene.mesh.validate()
        scene.check_supports()
        require_rise(scene, w_max)  # a flat reference needs w_max, else no nearest network exists
        loads = with_scene_extras(loads if loads is not None else SelfWeight(), scene)
        mesh0 = scene.mesh
        L0 = loads.nodal(mesh0, mesh0.vertices)
        prob = ScaledProblem.build(scene, L0, eps=eps, w_max=w_max)
        top, sc, X, lower, upper = prob.top, prob.scaling, prob.X, prob.lower, prob.upper
        free = top.free
        eps_s, wmax_s = float(lower[0]), float(upper[0])  # scalar bounds (every scene has active edges)
        Xref_mesh = mesh0.with_vertices(X)
        self.backend.reset()

        X0 = X.copy()
        U = _umbrella(top, mesh0)
        step3: dict = {}  # Step 3's constant parts and its factor, kept across iterations
        polish_ws: dict = {}  # the polish's load-Jacobian colouring
        P = X.copy()  # anchor points on the reference surface
        Nrm = vertex_normals(Xref_mesh)  # and the normals there
        alpha, beta = opt.alpha0, opt.beta0
        history: list[dict[str, Any]] = []
        status, message = "iteration_limit", ""

        def refit(Xc: np.ndarray, w0: np.ndarray, prox_rel: float = opt.prox_w, rtol: float | None = None):
            """Steps 1 and 2 at positions Xc: loads, then the weight fit."""
            t0 = time.perf_counter()
            Lc = sc.load(loads.nodal(mesh0, sc.pos_back(Xc)))
            t1 = time.perf_counter()
            if not np.all(Lc[free] < 0) or not np.all(np.isfinite(Xc)):
                return None
            A = weight_matrix(top, Xc)
            b = load_vector(top, Lc)
            s = np.repeat(1.0 / np.abs(Lc[free]), 3)
            As = sp.diags(s) @ A
            prox = prox_rel * float(np.asarray(As.multiply(As).sum(axis=0)).mean())
            try:
                fit = self.backend.fit(A=As, b=s * b, lower=lower, upper=upper, w0=w0, prox=prox, rtol=rtol)
            except (ValueError, RuntimeError, ArithmeticError):  # singular systems of a degenerate geometry
                return None
            if not np.all(np.isfinite(fit.w)):
                return None
            rel = np.linalg.norm((As @ fit.w - s * b).reshape(-1, 3), axis=1)
            worst = np.argsort(rel)[::-1][:10]
            return {"L": Lc, "w": fit.w, "As": As, "E": float(rel @ rel), "max_rel_error": float(rel.max()),
                    "worst_vertices": [int(v) for v in free_idx[worst]],
                    "fit_iterations": fit.iterations, "fit_status": fit.status, "n_at_lower": fit.n_lower,
                    "n_at_upper": fit.n_upper, "t_loads": t1 - t0, "t_weights": time.perf_counter() - t1}

        rtol_far = opt.fit_rtol  # the far-phase fits' KKT tolerance (tightened when it proves too loose)

        def judge(Xt: np.ndarray, rec: dict):
            """Steps 1-2 at the trial positions and whether they lower the recorded fit error.
            Far from equilibrium (fit error above finish_try) the fit only steers the iteration
            and stops at ``rtol_far``. Such a fit overstates min_w E (its proximal term aside),
            so it may reject a step that lowers it: a rejection is confirmed by an exact fit.
            When the exact fit overturns it, the steps' gains are smaller than the loose fits'
            overstatement (large meshes: E falls by ~0.1% per step), and the tolerance is
            tightened tenfold for the rest of the solve."""
            nonlocal rtol_far
            rtol = rtol_far if cur["max_rel_error"] > opt.finish_try else None
            trial = refit(Xt, cur["w"], rtol=rtol)
            accepted = trial is not None and trial["E"] < cur["E"]
            if not accepted and trial is not None and trial["fit_status"] == "inexact":
                trial = refit(Xt, cur["w"])
                accepted = trial is not None and trial["E"] < cur["E"]
                rec["confirmed"] = True
                if accepted:
                    rtol_far = max(0.1 * rtol_far, min(opt.fit_rtol, 1e-6))
            rec["fit_rtol"] = rtol
            rec["trial_fit_status"] = trial["fit_status"] if trial is not None else None
            return trial, accepted

        # proximal centre of the first fit: the best uniform weight (scale-free, deterministic)
        A0 = weight_matrix(top, X) @ np.ones(top.m)
        b0 = load_vector(top, sc.load(L0))
        w_uniform = float(np.clip(A0 @ b0 / max(float(A0 @ A0), 1e-300), eps_s, wmax_s))
        free_idx = np.flatnonzero(free)
        cur = refit(X, np.full(top.m, w_uniform))
        if cur is None:
            raise InfeasibleDesign("no weights can be fitted to the reference as it is (degenerate geometry, e.g. a flat "
                                   "network cannot carry vertical loads); give the surface some rise or check the mesh")
        it = 0
        rejected = 0
        released: list[float] = []  # fit errors of the iterations since α reached alpha_min
        fresh, early, last_try = True, None, np.inf
        polish_tol = opt.polish_tol
        retry_errors: list[float] | None = None  # fit errors since a retry began
        while True:
            try:
                for it in range(it + 1, opt.max_iter + 1):
                    proj = None  # closest points of X on the reference: computed at most once per iterate
                    rec: dict[str, Any] = {"iteration": it, "alpha": alpha, "beta": beta,
                                           **{k: v for k, v in cur.items() if k not in ("L", "w", "As")}}
                    if retry_errors is not None:
                        retry_errors.append(cur["max_rel_error"])
                    if cur["max_rel_error"] <= polish_tol or (
                            retry_errors is not None and len(retry_errors) > 5
                            and retry_errors[-1] > 0.5 * retry_errors[-6]):
                        # (during a retry: polish again once the fit stops improving)
                        status = "converged"
                        history.append(rec)
                        break
                    if (fresh and cur["max_rel_error"] <= min(opt.finish_try, 0.5 * last_try)
                            and cur["fit_status"] != "inexact"):
                        # (a trial fitted loosely that landed below finish_try waits one step: the
                        # next fit is exact, and the finish polishes exact weights only)
                        proj = proj if proj is not None else closest_points(X, Xref_mesh)
                        early = _try_finish(top, X, cur["w"], cur["L"], loads, mesh0, sc, Xref_mesh, proj[1], opt,
                                            polish_ws)
                        rec["finish_try"] = early[3] if early is not None else None
                        if early is not None and early[3]["ok"]:
                            status = "converged"
                            history.append(rec)
                            break
                        early = None
                        last_try = cur["max_rel_error"]  # try again once the fit error has halved
                    fresh = False
                    released = released + [cur["max_rel_error"]] if alpha <= opt.alpha_min else []
                    if len(released) > opt.stall_window and released[-1] > 0.5 * released[-1 - opt.stall_window]:
                        # the reference no longer holds the positions, yet the fit does not improve:
                        # more iterations only move the network further (an infeasible design)
                        status, message = "stalled", (
                            f"the fit error stopped falling (max relative error {cur['max_rel_error']:.2e}) although "
                            f"the pull towards the reference is fully released (α at its minimum for "
                            f"{len(released) - 1} iterations)")
                        history.append(rec)
                        break
                    if time.perf_counter() - t_start > opt.time_limit:
                        status, message = "time_limit", f"time limit {opt.time_limit:g} s reached"
                        history.append(rec)
                        break
                    # Step 3: positions, with the weights of the current fit
                    t0 = time.perf_counter()
                    if opt.reproject_every and it > 1 and it % opt.reproject_every == 0:
                        P, _, Nrm = proj if proj is not None else closest_points(X, Xref_mesh)
                    G = gap = None
                    if opt.coupled:  # the fit's own scaled A at X, restricted to the weights off their bounds
                        movable = (cur["w"] > lower) & (cur["w"] < upper)
                        G, gap = cur["As"][:, movable], (cur["w"] - lower)[movable]
                    Xt = _position_step(top, X, cur["w"], cur["L"], P, Nrm, alpha, beta, opt.tangential,
                                        opt.fairness * alpha, Xref=X0, umbrella=U, G=G, prox_dw=beta,
                                        gap=gap, damping=opt.coupled_damping, workspace=step3)
                    rec["t_positions"] = time.perf_counter() - t0
                    # Steps 1-2 at the trial positions; far from equilibrium the fit only steers the
                    # iteration, so it may stop at a looser tolerance
                    trial, accepted = judge(Xt, rec)
                    if G is not None and not accepted:
                        # the coupled model over-promised (weights it moved were clamped by the
                        # refit): fall back to the plain position step before shrinking the region
                        Xt = _position_step(top, X, cur["w"], cur["L"], P, Nrm, alpha, beta, opt.tangential,
                                            opt.fairness * alpha, Xref=X0, umbrella=U, workspace=step3)
                        trial, accepted = judge(Xt, rec)
                        rec["fallback"] = True
                    rec["cg_iterations"] = step3.get("cg_iterations", 0)  # of the step taken
                    rec["accepted"] = accepted
                    history.append(rec)
                    if progress:
                        progress(rec)
                    # Step 4: trust-region style schedule
                    if accepted:
                        ratio = trial["E"] / cur["E"]
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

            if status not in ("converged", "interrupted"):
                message = (f"{message or status}; vertices hardest to balance: {cur['worst_vertices'][:5]} "
                           f"(max relative fit error {cur['max_rel_error']:.2e}); try more supports there, a larger "
                           "w_max, a pillar, or more iterations").lstrip("; ")
            # final fit with (almost) no proximal pull, so that the polish moves the geometry as
            # little as the data allow (an input already in equilibrium comes back unchanged)
            t0 = time.perf_counter()
            if early is not None:  # the polish of the current weights was already accepted
                Xp, L, load_rounds, _ = early
                w = cur["w"]
            else:
                last = refit(X, cur["w"], opt.prox_w_final)
                w = last["w"] if last is not None and last["E"] <= cur["E"] else cur["w"]
                # Polish: weights frozen, positions exact, loads consistent
                t0 = time.perf_counter()
                Xp, L, load_rounds = _polish(top, X, w, loads, mesh0, sc, workspace=polish_ws)
            polish_move = float(np.linalg.norm(Xp - X, axis=1).max()) if np.all(np.isfinite(Xp)) else np.inf
            net = self._network(scene, sc, Xp, w, loads) if np.isfinite(polish_move) else None
            err = net.max_relative_error() if net is not None else np.inf
            final = {"iteration": "polish", "t_polish": time.perf_counter() - t0, "load_rounds": load_rounds,
                     "polish_max_move": polish_move, "max_rel_error": err, "kept": True}
            if status != "converged" and not (np.isfinite(err) and err <= min(cur["max_rel_error"], 1.0)):
                # from a poor fit the exact solve can land anywhere (even collapse): keep the last
                # iterate, labelled by its status, rather than a "polished" network that is worse
                final["kept"] = False
                net = self._network(scene, sc, X, w, loads)
                if w is not cur["w"]:  # the final fit minimises the sum of squares, not the max error
                    net = min(net, self._network(scene, sc, X, cur["w"], loads), key=Network.max_relative_error)
                message += "; the final polish did not improve the network, so the last iterate is returned (not in equilibrium)"
            elif status != "converged" and polish_move > opt.polish_tol:
                message += (f"; to reach equilibrium the final polish moved vertices by up to {polish_move:.2e} "
                            "of the bounding-box diagonal, so this network may be far from the design")
            if (status == "converged" and early is None and not err <= opt.tol and polish_tol > 1e-9
                    and it < opt.max_iter and time.perf_counter() - t_start < opt.time_limit):
                # the polish did not reach equilibrium (the load fixed point stalled, e.g. on a
                # kink of the area model): iterate on to a much tighter fit and polish again
                history.append({**final, "kept": False, "retry": True})
                polish_tol *= 1e-2
                retry_errors = []
                status = "iteration_limit"
                continue
            break
        history.append(final)
        if progress:
            progress(final)
        if opt.refine > 0 and status == "converged" and err <= opt.tol:
            # walk back towards the reference along the equilibrium manifold (SQP, refine.py)
            t0 = time.perf_counter()
            Xn = sc.pos(net.vertices)
            Xn[scene.supports] = X0[scene.supports]
            wn = sc.weight(net.weights[scene.active_edges])
            ref = _refine(top, Xn, wn, loads, mesh0, sc, Xref_mesh, lower, upper, max_steps=opt.refine,
                          tau=opt.tangential, tol=opt.tol, deadline=t_start + opt.time_limit, workspace=polish_ws)
            refined = self._network(scene, sc, ref.X, ref.w, loads) if ref.steps else None
            applied = refined is not None and refined.max_relative_error() <= opt.tol  # (never trade equilibrium)
            if applied:
                net, err = refined, refined.max_relative_error()
            rec = {"iteration": "refine", "steps": ref.steps, "tried": ref.tried, "applied": applied,
                   "t_refine": time.perf_counter() - t0, "max_rel_error": err,
                   "dist_mean": [h["dist_mean"] for h in ref.history if h["accepted"]],
                   "rho": [h["rho"] for h in ref.history]}
            history.append(rec)
            if progress:
                progress(rec)
        if status == "converged" and not err <= opt.tol:
            worst = np.argsort(net.relative_errors())[::-1][:5]
            status, message = "stalled", (
                f"the polished network has max relative error {err:.2e} > tol {opt.tol:g}; vertices hardest to "
                f"balance: {[int(v) for v in free_idx[worst]]}; try more supports there, a larger w_max, or a pillar")
        return SolveResult.build(
            net, status=status, method=self.name, backend=self.backend.name, iterations=it,
            wall_time=time.perf_counter() - t_start, history=tuple(history), message=message,
            parameters={**asdict(opt), "eps": sc.weight_back(eps_s), "w_max": w_max,
                        "scaling": asdict(sc)})


    @staticmethod
    def _network(scene: Scene, sc: Scaling, X: np.ndarray, w: np.ndarray, loads: LoadCase) -> Network:
        """The network in SI units: supports exactly where the design put them, loads of its geometry."""
        mesh0 = scene.mesh
        V = sc.pos_back(X)
        V[scene.supports] = mesh0.vertices[scene.supports]  # exactly, not through the scaling round trip
        weights = np.zeros(mesh0.n_edges)
        weights[scene.active_edges] = sc.weight_back(w)
        return Network(mesh=mesh0.with_vertices(V), weights=weights, loads=loads.nodal(mesh0, V),
                       supports=scene.supports, reference=mesh0, handles=scene.handles)


def _umbrella(top: Topology, mesh) -> sp.csr_matrix:
    """Umbrella Laplacian rows ``u_i − mean_j u_j`` at free interior vertices, over all vertices."""
    n = top.n
    e = mesh.edges
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    deg = np.asarray(A.sum(axis=1)).ravel()
    Lu = (sp.identity(n) - sp.diags(1.0 / deg) @ A).tocsr()
    rows = top.free & ~mesh.boundary_vertex_mask
    return Lu[rows]


def _position_step(top: Topology, X: np.ndarray, w: np.ndarray, L: np.ndarray, P: np.ndarray,
                   Nrm: np.ndarray, alpha: float, beta: float, tau: float, gamma: float = 0.0,
                   Xref: np.ndarray | None = None, umbrella: sp.csr_matrix | None = None,
                   G: sp.spmatrix | None = None, prox_dw: float = 0.0, gap: np.ndarray | None = None,
                   damping: float = 0.0, workspace: dict | None = None) -> np.ndarray:
    """Step 3: the SPD least-squares update of the free positions (see the module docstring).

    The residual rows are scaled by ``1 / |A_i F_i|`` as in the fit (so the step decreases the
    very error the fit measures); the penalties are multiplied by the mean of
    ``(d_i / |A_i F_i|)²``, which converts that relative residual into a length, so that
    α and β compare lengths with lengths whatever the mesh resolution.

    The system is ``(H ⊗ I₃ + b₀ I + b₁ ⊕ n_i n_iᵀ) x = rhs`` with H the (n_free × n_free)
    Gram matrix of the scaled stress Laplacian (+ fairness): only the anchor's normal part
    couples x, y and z. It is solved by conjugate gradients preconditioned with one n×n
    factorization of ``H + b₀ I`` applied to the three coordinates — a 3n×3n factorization
    costs ~27× the flops, and the preconditioned system's condition number is at most
    ``1 + b₁/b₀ = 1 + (1 − τ)/(τ + β/α)`` (measured: 2–27 iterations to 1e-10 on the paper's
    scenes). The direct 3n×3n factorization remains for the coupled step and as a fallback.
    ``workspace`` (a dict kept by the caller across steps) holds what does not change between
    steps — ``UfᵀUf`` and the factor objects, whose symbolic analyses are reused.
    """
    ws = workspace if workspace is not None else {}
    ws["cg_iterations"] = 0  # stays 0 unless conjugate gradients solve the step
    free = top.free
    Kff, Kfs = position_blocks(top, w)
    d = -Kff.diagonal()
    s = 1.0 / np.abs(L[free])
    c = float(np.mean((d * s) ** 2))
    S = sp.diags(s)
    Kt = (S @ Kff).tocsr()
    nf = top.n_free
    B = np.zeros((nf, 3))
    B[:, 2] = L[free]
    target = S @ (B - Kfs @ X[~free])  # (nf, 3): target of Kt X_free
    H = (Kt.T @ Kt).tocsr()
    n = Nrm[free]
    # anchor + proximal term per vertex: b0 I + b1 n nᵀ
    b0, b1 = c * (alpha * tau + beta), c * alpha * (1 - tau)
    rhs = Kt.T @ target
    if gamma > 0 and umbrella is not None and umbrella.shape[0]:
        # smooth displacement: γ ‖U (X − X_ref)‖², U the umbrella Laplacian (supports as data)
        if "Uf" not in ws:
            ws["Uf"], ws["Us"] = umbrella[:, free].tocsr(), umbrella[:, ~free].tocsr()
            ws["UtU"] = (ws["Uf"].T @ ws["Uf"]).tocsr()
        Uf, Us = ws["Uf"], ws["Us"]
        H = (H + (c * gamma) * ws["UtU"]).tocsr()
        rhs += (c * gamma) * (Uf.T @ (Uf @ Xref[free] + Us @ (Xref[~free] - X[~free])))
    Pf = P[free]
    rhs += (c * alpha) * (tau * Pf + (1 - tau) * n * np.einsum("ki,ki->k", n, Pf)[:, None]) + (c * beta) * X[free]
    Xn = X.copy()
    if G is None or G.shape[1] == 0:  # (with every weight at a bound the coupled step is the plain one)
        sol = _solve_anchored(H, b0, b1, n, rhs, ws)
        if sol is not None:
            Xn[free] = sol
            return Xn
    M = (sp.kron(H, sp.identity(3), format="csr")
         + block_diagonal(b0 * np.eye(3)[None] + b1 * n[:, :, None] * n[:, None, :])).tocsc()
    if G is not None and G.shape[1] > 0:
        # coupled step: the weights not at a bound move with the positions (Gauss-Newton on
        # the reduced error min_w E(X, w) rather than on E(X, w_k)); dw is only used to shape
        # the position step: the trial is refitted exactly
        J = sp.kron(Kt, sp.identity(3), format="csr")
        GtG = (G.T @ G).tocsr()
        pw = prox_dw * float(GtG.diagonal().mean()) if GtG.shape[0] else 0.0
        # weights near their bound may hardly move (an interior-point-like scaling), since the
        # refit will clamp them there
        gap = np.asarray(gap, float)
        pw = pw + damping * float(GtG.diagonal().mean()) * (np.median(gap) / gap) ** 2
        N = sp.bmat([[M, J.T @ G], [G.T @ J, GtG + sp.diags(pw)]], format="csc")
        # the target of J x + G dw is the scaled target t (the current residual is J x_k − t)
        rhs_w = G.T @ target.ravel()
        sol = spd_factor(N).solve(np.r_[rhs.ravel(), rhs_w])
        Xn[free] = sol[:M.shape[0]].reshape(-1, 3)
        return Xn
    ws["factor"] = spd_factor(M, reuse=ws.get("factor"))
    Xn[free] = ws["factor"].solve(rhs.ravel()).reshape(-1, 3)
    return Xn


def _solve_anchored(H: sp.csr_matrix, b0: float, b1: float, n: np.ndarray, rhs: np.ndarray, ws: dict,
                    rtol: float = 1e-10, maxiter: int = 200) -> np.ndarray | None:
    """``(H ⊗ I₃ + b0 I + b1 ⊕ n_i n_iᵀ) x = rhs`` for ``(k, 3)`` arrays by preconditioned CG
    (scipy), the preconditioner ``(H + b0 I)⁻¹`` per coordinate; None if CG does not converge."""
    from scipy.sparse.linalg import LinearOperator, cg

    k = H.shape[0]
    pre = ws["pre"] = spd_factor((H + b0 * sp.identity(k, format="csr")).tocsc(), reuse=ws.get("pre"))

    def matvec(x: np.ndarray) -> np.ndarray:
        X = x.reshape(k, 3)
        return (H @ X + b0 * X + (b1 * np.einsum("ki,ki->k", n, X))[:, None] * n).ravel()

    op = LinearOperator((3 * k, 3 * k), matvec=matvec, dtype=float)
    prec = LinearOperator((3 * k, 3 * k), matvec=lambda r: pre.solve(r.reshape(k, 3)).ravel(), dtype=float)
    count = [0]
    x, info = cg(op, rhs.ravel(), x0=pre.solve(rhs).ravel(), rtol=rtol, atol=0.0, maxiter=maxiter, M=prec,
                 callback=lambda _: count.__setitem__(0, count[0] + 1))
    ok = info == 0 and np.all(np.isfinite(x))
    ws["cg_iterations"] = count[0] if ok else 0  # 0: the caller falls back to the direct solve
    return x.reshape(k, 3) if ok else None


def _try_finish(top: Topology, X: np.ndarray, w: np.ndarray, L_it: np.ndarray, loads: LoadCase, mesh0,
                sc: Scaling, reference, d_it: np.ndarray, opt: StaggeredOptions, workspace: dict | None = None):
    """Polish with the current weights and keep the result if it is in equilibrium and no
    farther from the reference than the iterate itself (mean within ``finish_slack``, max
    within 4× that): finishing then costs no closeness, further iterations could only drift.
    ``L_it`` are the iterate's loads, ``d_it`` its distances to the reference.

    A screen comes first: the positions in equilibrium with ``w`` and the iterate's loads
    (one stress-Laplacian solve; the polish then only makes the loads consistent) predict the
    polished distance — measured on the paper's scenes within 25% of the polished ratio where it
    was far off (82 / 6.0 / 2.1 / 1.40 against 109 / 7.4 / 2.5 / 1.42 on twocirc-3) and within
    7% where the polish was kept. A try whose screened mean distance exceeds the iterate's by
    more than ``finish_screen`` is not polished (a Newton polish costs 20–70 ms there, the
    screen a few).
    Returns (positions, loads, rounds, info) — positions and loads None when screened out —
    or None when the polish breaks down."""
    free = top.free
    slack = opt.finish_slack
    Kff, Kfs = position_blocks(top, w)
    B = np.zeros((top.n_free, 3))
    B[:, 2] = L_it[free]
    Xs = X.copy()
    Xs[free] = spd_factor((-Kff).tocsc()).solve(Kfs @ X[~free] - B)  # −K_ff X_f = K_fs X_s − B
    if not np.all(np.isfinite(Xs)):
        return None
    screen = float(closest_points(Xs, reference)[1].mean() / max(float(d_it.mean()), 1e-300))
    if screen > 1 + opt.finish_screen:
        return None, None, 0, {"ok": False, "screened": screen}
    # Newton only: a try that Newton cannot finish is retried later, or left to the final polish
    Xp, L, rounds = _polish(top, X, w, loads, mesh0, sc, workspace=workspace, fallbacks=bool(opt.try_fallbacks))
    if not np.all(np.isfinite(Xp)):
        return None
    err = float((np.linalg.norm(residual(top, Xp, w, L), axis=1) / np.abs(L[free])).max())
    d_p = closest_points(Xp, reference)[1]
    ok = (err <= opt.tol and float(d_p.mean()) <= (1 + slack) * float(d_it.mean())
          and float(d_p.max()) <= (1 + 4 * slack) * float(d_it.max()))
    info = {"ok": bool(ok), "error": err, "screened": screen,
            "dist_mean_ratio": float(d_p.mean() / max(d_it.mean(), 1e-300)),
            "dist_max_ratio": float(d_p.max() / max(d_it.max(), 1e-300))}
    return Xp, L, rounds, info
