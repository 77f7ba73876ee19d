"""The simultaneous problem with nlopt (SLSQP, or AUGLAG around L-BFGS) — small problems only.

Same problem, units, load rounds, polish and result as :class:`~selfsupport.methods.simultaneous.
Simultaneous`; only the NLP solver differs. nlopt's SLSQP works on dense matrices (O(n³) per
iteration in the number of unknowns), so scenes above :data:`MAX_FREE_VERTICES` free vertices are
refused: use the IPOPT backend there.
"""
from __future__ import annotations

import time
from typing import Any

import casadi as ca
import numpy as np

from formulations import ThrustNetworkProblem

from ..errors import BackendUnavailable, InputError
from ..loads import LoadCase
from ..result import SolveResult
from ..scene import Scene
from .simultaneous import Simultaneous

#: Largest number of free vertices accepted (dense SLSQP: ~(3·300 + edges)³ per iteration).
MAX_FREE_VERTICES = 300

#: nlopt result name -> our status (see selfsupport.result.STATUSES). Successful returns are
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

    ``algorithm``: ``"LD_SLSQP"`` (default) or ``"AUGLAG"`` (augmented Lagrangian around
    ``LD_LBFGS``, first-order: slow to reach tight tolerances).
    """

    name = "simultaneous"
    backend = "nlopt"
    ALGORITHMS = ("LD_SLSQP", "AUGLAG")
    defaults: dict[str, Any] = {"algorithm": "LD_SLSQP", "ftol_rel": 1e-14, "xtol_rel": 1e-12}

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

    def solve(self, scene: Scene, loads: LoadCase | None = None, **kw: Any) -> SolveResult:
        """Same arguments and result as :meth:`Simultaneous.solve` (``max_iter`` counts nlopt
        evaluations). Raises :class:`BackendUnavailable` above :data:`MAX_FREE_VERTICES`."""
        n_free = int(scene.free.sum())
        if n_free > MAX_FREE_VERTICES:
            raise BackendUnavailable(
                f"the nlopt simultaneous backend is for small problems ({n_free} free vertices > "
                f"{MAX_FREE_VERTICES}; dense SLSQP would take hours): use Simultaneous() with IPOPT instead")
        return super().solve(scene, loads, **kw)

    def _solve_round(self, problem: ThrustNetworkProblem, nlp: dict, x: np.ndarray, loads_scaled: np.ndarray,
                     warm: dict | None, *, tol: float, max_iter: int, remaining: float, verbose: bool) -> dict:
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
        except (RuntimeError, ValueError, MemoryError):
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
