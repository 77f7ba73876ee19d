"""The simultaneous problem with nlopt — small problems only.

Same problem (a :class:`formulations.Problem` or the short form), units, load rounds, polish and
result as :class:`~selfsupport.methods.simultaneous.Simultaneous`; only the solver differs. One
load case, no hull, free top view: other problems are refused with an :class:`InputError` naming
the feature. Two formulations:

* ``algorithm="LD_LBFGS"`` (default) — the *reduced* problem in the weights alone: for given
  weights the positions follow from (2)-(3) by one sparse solve per coordinate (the force
  density method), so equilibrium holds exactly and only the bounds ``eps ≤ w ≤ w_max``
  remain; the gradient is the adjoint ``∇_w f − A(X)ᵀ (K_ff ⊗ I)⁻¹ ∇_X f``. First-order:
  thousands of evaluations, ~20 s at 100 free vertices; refused above
  ``MAX_FREE_VERTICES["reduced"]``.
* ``algorithm="LD_SLSQP"`` or ``"AUGLAG"`` — the full problem (positions and weights, equilibrium
  as equality constraints). nlopt's SLSQP is dense, O(n³) per iteration: ~5 s at 9 free
  vertices, > 60 s at 70; refused above ``MAX_FREE_VERTICES["full"]``.

Use :class:`~selfsupport.methods.simultaneous.Simultaneous` (IPOPT) for anything larger.
"""
from __future__ import annotations

import time
from typing import Any

import casadi as ca
import numpy as np
from scipy.sparse.linalg import splu

from formulations import Hull, Planar, Problem, ThrustNetworkProblem
from formulations.equilibrium import position_blocks, weight_matrix
from selfsupport.core.errors import BackendUnavailable, InputError
from selfsupport.methods import METHODS
from selfsupport.methods.simultaneous import Simultaneous
from selfsupport.methods.weightfit_backends import nlopt_failures

#: Largest number of free vertices accepted, per formulation (see the module docstring).
MAX_FREE_VERTICES = {"reduced": 300, "full": 50}

#: nlopt result name -> our status (see selfsupport.core.result.STATUSES). Successful returns are
#: only "converged" when the constraints really hold to ``tol`` (checked separately).
NLOPT_STATUS: dict[str, str] = {
    "SUCCESS": "converged",
    "STOPVAL_REACHED": "converged",
    "FTOL_REACHED": "converged",
    "XTOL_REACHED": "converged",
    "MAXEVAL_REACHED": "iteration_limit",
    "MAXTIME_REACHED": "time_limit",
    "ROUNDOFF_LIMITED": "stalled",
    "FORCED_STOP": "interrupted",
    "FAILURE": "failed",
    "INVALID_ARGS": "failed",
    "OUT_OF_MEMORY": "failed",
}


class NloptSimultaneous(Simultaneous):
    """Method object: the simultaneous problem solved by nlopt (backend ``"nlopt"``).

    Options: ``algorithm`` (``"LD_LBFGS"``: reduced problem, default; ``"LD_SLSQP"`` /
    ``"AUGLAG"``: full problem), ``ftol_rel``, ``xtol_rel``, ``gtol`` (projected-gradient
    tolerance of the reduced problem, scale-free units: below it a stop counts as converged).
    """

    name = "nlopt"
    backend = "nlopt"
    #: one load case, no hull, no planar rows (refused by :meth:`_check_problem`); starts from the reference
    capabilities = METHODS["nlopt"].capabilities
    #: bound-constrained algorithms for the reduced (weights-only) problem (LD_MMA was tried:
    #: it does not converge on a 5×5 grid in 13,000 evaluations)
    REDUCED = ("LD_LBFGS",)
    ALGORITHMS = REDUCED + ("LD_SLSQP", "AUGLAG")
    defaults: dict[str, Any] = {"algorithm": "LD_LBFGS", "ftol_rel": 1e-15, "xtol_rel": 1e-13, "gtol": 1e-8}

    def __init__(self, **options: Any) -> None:
        unknown = set(options) - set(self.defaults)
        if unknown:
            raise InputError(f"unknown nlopt option(s) {sorted(unknown)}; known: {sorted(self.defaults)}")
        self.options = {**self.defaults, **options}
        if self.options["algorithm"] not in self.ALGORITHMS:
            raise InputError(f"nlopt algorithm {self.options['algorithm']!r} not supported; use one of "
                             f"{list(self.ALGORITHMS)}")
        try:
            import nlopt  # noqa: F401
        except ImportError:  # pragma: no cover
            raise BackendUnavailable("the nlopt backend needs the nlopt package: `pip install nlopt`") from None

    def _check_problem(self, problem: Problem) -> None:
        """Refuse what this backend cannot state: several load cases, the hull's inequality rows,
        planar faces, a fixed top view (the reduced formulation computes x, y from the weights); and problems
        above :data:`MAX_FREE_VERTICES` (:class:`BackendUnavailable`)."""
        several = len(problem.loads) > 1 and not self.capabilities.load_cases
        for unsupported, what in ((several, f"{len(problem.loads)} load cases"),
                                  (problem.constraint(Hull) is not None, "the masonry-hull constraint"),
                                  (problem.constraint(Planar) is not None, "the planar-faces constraint"),
                                  (problem.fixed_top_view, "a fixed top view")):
            if unsupported:
                raise InputError(f"the nlopt backend does not support {what}; use the IPOPT method "
                                 "(Simultaneous, --method ipopt)")
        n_free = int(problem.scene.free.sum())
        kind = "reduced" if self.options["algorithm"] in self.REDUCED else "full"
        if n_free > MAX_FREE_VERTICES[kind]:
            raise BackendUnavailable(
                f"the nlopt simultaneous backend ({self.options['algorithm']}) is for small problems: "
                f"{n_free} free vertices > {MAX_FREE_VERTICES[kind]}; use the IPOPT method "
                "(Simultaneous, --method ipopt) instead")

    def _solve_round(self, problem: ThrustNetworkProblem, nlp: dict, x: np.ndarray, loads_scaled: np.ndarray,
                     warm: dict | None, *, tol: float, max_iter: int, remaining: float, verbose: bool,
                     extra: Any = None) -> dict:
        # (``extra``: IPOPT's options of a cold round, which nlopt has no use for)
        if self.options["algorithm"] in self.REDUCED:
            return self._solve_round_reduced(problem, nlp, x, loads_scaled, tol=tol, max_iter=max_iter,
                                             remaining=remaining)
        return self._solve_round_full(problem, nlp, x, loads_scaled, tol=tol, max_iter=max_iter, remaining=remaining)

    def _solve_round_reduced(self, problem: ThrustNetworkProblem, nlp: dict, x: np.ndarray,
                             loads_scaled: np.ndarray, *, tol: float, max_iter: int, remaining: float) -> dict:
        """Weights only: positions follow from (2)-(3) by a sparse solve per coordinate (force
        density method), so equilibrium holds exactly and only the bounds remain; the gradient
        of f(X(w), w) is the adjoint ``∇_w f − A(X)ᵀ (K_ff ⊗ I)⁻¹ ∇_X f``."""
        import nlopt

        top = problem.topology
        free = top.free
        nf3 = 3 * top.n_free
        p = problem.parameters(loads_scaled)
        F = self._functions(problem, nlp)["f"]
        Vs = problem.vertices[~free]
        Lf = np.atleast_2d(np.asarray(loads_scaled, float))[0, free]  # one case (see _check_problem)
        lower, upper = problem.lower, problem.upper
        scale = problem.weight_scale
        count = [0]
        state: dict[str, Any] = {}

        def positions(w):
            Kff, Kfs = position_blocks(top, w)
            lu = splu(Kff.tocsc())
            X = np.empty((top.n_free, 3))
            for c in range(3):
                rhs = -(Kfs @ Vs[:, c]) + (Lf if c == 2 else 0.0)
                X[:, c] = lu.solve(rhs)
            return X, lu

        def objective(u, grad):
            count[0] += 1
            w = u * scale
            X, lu = positions(w)
            xv = np.concatenate([X.ravel(), w])
            f, g = F(xv, p)
            g = np.asarray(g).ravel()
            if grad.size:
                V = problem.vertices.copy()
                V[free] = X
                lam = np.column_stack([lu.solve(g[:nf3].reshape(-1, 3)[:, c]) for c in range(3)]).ravel()
                grad[:] = (g[nf3:] - weight_matrix(top, V).T @ lam) * scale
                state["pg"] = float(np.abs(u - np.clip(u - grad, lower / scale, upper / scale)).max())
            state["x"] = xv
            return float(f)

        o = self.options
        opt = nlopt.opt(getattr(nlopt, o["algorithm"]), top.m)
        opt.set_lower_bounds(lower / scale)
        opt.set_upper_bounds(upper / scale)
        opt.set_min_objective(objective)
        opt.set_ftol_rel(o["ftol_rel"])
        opt.set_xtol_rel(o["xtol_rel"])
        opt.set_maxeval(int(max_iter))
        opt.set_maxtime(float(max(remaining, 1e-3)))
        u0 = np.clip(x[nf3:], lower, upper) / scale
        t0 = time.perf_counter()
        try:
            us = opt.optimize(u0)
            raw = _result_name(opt.last_optimize_result())
        except nlopt.RoundoffLimited:
            us, raw = None, "ROUNDOFF_LIMITED"
        except nlopt.ForcedStop:
            us, raw = None, "FORCED_STOP"
        except nlopt_failures(nlopt):  # NLOPT_FAILURE etc. (nlopt ≥ 2.8: not RuntimeError)
            us, raw = None, "FAILURE"
        seconds = time.perf_counter() - t0
        if us is not None:
            objective(np.clip(us, lower / scale, upper / scale), np.zeros(top.m))
        xs = state.get("x", x)
        status = NLOPT_STATUS.get(raw, "failed")
        pg = state.get("pg", np.inf)
        if status in ("converged", "stalled"):
            status = "converged" if pg <= o["gtol"] else "stalled"
        return {"x": xs, "warm": None, "raw": f"{raw} (projected gradient {pg:.1e})", "status": status,
                "iterations": int(count[0]), "objective": float(F(xs, p)[0]), "seconds": seconds}

    def _solve_round_full(self, problem: ThrustNetworkProblem, nlp: dict, x: np.ndarray, loads_scaled: np.ndarray,
                          *, tol: float, max_iter: int, remaining: float) -> dict:
        import nlopt

        p = problem.parameters(loads_scaled)
        fun = self._functions(problem, nlp)
        F = fun["f"]
        G = fun["g"]
        b = problem.bounds_args()
        n = x.size
        # variable scaling x = D u: weights in units of their natural scale (SLSQP's quasi-Newton
        # start is the identity; unscaled weights ~1/ĥ² cost it hundreds of extra iterations)
        D = np.ones(n)
        D[3 * problem.topology.n_free:] = problem.weight_scale
        count = [0]
        last = {"u": np.clip(x, b["lbx"], b["ubx"]) / D}

        def objective(u, grad):
            count[0] += 1
            f, gf = F(D * u, p)
            if grad.size:
                grad[:] = np.asarray(gf).ravel() * D
            last["u"] = u.copy()
            return float(f)

        def constraints(result, u, grad):
            g, J = G(D * u, p)
            result[:] = np.asarray(g).ravel()
            if grad.size:
                grad[:, :] = np.asarray(J) * D

        o = self.options
        if o["algorithm"] == "AUGLAG":
            opt = nlopt.opt(nlopt.AUGLAG_EQ, n)
            local = nlopt.opt(nlopt.LD_LBFGS, n)
            local.set_ftol_rel(o["ftol_rel"])
            local.set_xtol_rel(o["xtol_rel"])
            opt.set_local_optimizer(local)
        else:
            opt = nlopt.opt(nlopt.LD_SLSQP, n)
        lb, ub = b["lbx"], b["ubx"]
        opt.set_lower_bounds(lb / D)
        opt.set_upper_bounds(ub / D)
        opt.set_min_objective(objective)
        opt.add_equality_mconstraint(constraints, np.full(b["lbg"].size, 0.1 * tol))
        opt.set_ftol_rel(o["ftol_rel"])
        opt.set_xtol_rel(o["xtol_rel"])
        opt.set_maxeval(int(max_iter))
        opt.set_maxtime(float(max(remaining, 1e-3)))
        t0 = time.perf_counter()
        try:
            us = opt.optimize(last["u"].copy())
            raw = _result_name(opt.last_optimize_result())
        except nlopt.RoundoffLimited:
            us, raw = last["u"], "ROUNDOFF_LIMITED"
        except nlopt.ForcedStop:
            us, raw = last["u"], "FORCED_STOP"
        except nlopt_failures(nlopt):  # NLOPT_FAILURE etc. (nlopt ≥ 2.8: not RuntimeError)
            us, raw = last["u"], "FAILURE"
        seconds = time.perf_counter() - t0
        xs = np.clip(D * np.asarray(us, float), lb, ub)
        g = np.asarray(G(xs, p)[0]).ravel()
        viol = float(np.abs(g).max(initial=0.0))
        status = NLOPT_STATUS.get(raw, "failed")
        if status in ("converged", "stalled"):
            status = "converged" if viol <= tol else "stalled"
        return {"x": xs, "warm": None, "raw": f"{raw} (max |relative residual| {viol:.1e})", "status": status,
                "iterations": int(count[0]), "objective": float(F(xs, p)[0]), "seconds": seconds}

    @staticmethod
    def _functions(problem: ThrustNetworkProblem, nlp: dict) -> dict[str, ca.Function]:
        cache = problem.__dict__.setdefault("_nlopt_functions", {})
        if not cache:
            x, pp = nlp["x"], nlp["p"]
            cache["f"] = ca.Function("f", [x, pp], [nlp["f"], ca.gradient(nlp["f"], x)])
            cache["g"] = ca.Function("g", [x, pp], [nlp["g"], ca.densify(ca.jacobian(nlp["g"], x))])
        return cache


def _result_name(code: int) -> str:
    import nlopt

    for name in NLOPT_STATUS:
        if getattr(nlopt, name, None) == code:
            return name
    return f"nlopt code {code}"
