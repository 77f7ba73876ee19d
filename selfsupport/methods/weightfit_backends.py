"""Step-2 backends through CasADi and nlopt (thin adapters: lazy import, defaults, status map).

Each solves ``min ½‖A w − b‖² + ½ prox ‖w − w0‖²  s.t.  lower ≤ w ≤ upper``:

* :class:`IpoptFit` — IPOPT (MUMPS) on the lifted form ``min ½‖r‖² + ½ prox ‖w − w0‖²`` s.t.
  ``A w − r = b``: the KKT matrix keeps A's sparsity (no AᵀA). A's nonzeros, b, w0 and prox
  are NLP parameters, so one solver serves every fit with the same sparsity pattern.
* :class:`OsqpFit` — OSQP (ADMM) on the same lifted QP, through CasADi's ``conic`` plugin or,
  failing that, the ``osqp`` Python package.
* :class:`NloptFit` — nlopt's bound-constrained L-BFGS (or MMA) on the smooth objective with
  its analytic gradient. First-order: fine on small problems, slow to converge at thousands of
  edges (it reports ``"max_iter"`` then, never a false ``"optimal"``).

Statuses follow :class:`~selfsupport.methods.weightfit.WeightFit`: ``"optimal"``,
``"max_iter"`` (stopped before the tolerance), ``"failed"``.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from selfsupport.core.errors import BackendUnavailable, InputError
from selfsupport.methods import weightfit
from selfsupport.methods.deadline import ipopt_stop_callback, out_of_time, remaining
from selfsupport.methods.weightfit import (
    ActiveSetFit,
    CentredActiveSetFit,
    CentredAllActiveSetFit,
    WeightFit,
    WeightFitBackend,
    _objective,
    count_bounds,
)


def kkt_residual(*, A: sp.spmatrix, b: np.ndarray, w: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 w0: np.ndarray | None = None, prox: float = 0.0) -> float:
    """Relative projected-gradient norm ``‖w − clip(w − ∇f, lower, upper)‖∞ / scale``.

    Zero exactly at a minimiser of the box-constrained problem (first-order conditions);
    ``scale = max(‖Aᵀb‖∞, ‖AᵀA w‖∞, prox ‖w‖∞)`` makes it invariant to scaling A, b together.
    """
    w = np.asarray(w, float)
    Aw = A @ w
    g = A.T @ (Aw - b)
    if prox:
        g = g + prox * (w - (0.0 if w0 is None else w0))
    scale = max(float(np.abs(A.T @ b).max(initial=0.0)), float(np.abs(A.T @ Aw).max(initial=0.0)),
                prox * float(np.abs(w).max(initial=0.0)), 1e-300)
    return float(np.abs(w - np.clip(w - g, lower, upper)).max(initial=0.0) / scale)


def nlopt_failures(nlopt: Any) -> tuple[type[BaseException], ...]:
    """Every exception ``nlopt.opt.optimize`` raises for a run that stopped without success.

    Older wrappers raise the builtins (``RuntimeError`` for NLOPT_FAILURE, ``ValueError`` for
    invalid arguments, ``MemoryError``); the SWIG wrapper of nlopt ≥ 2.8 raises its own
    ``nlopt.runtime_error`` / ``nlopt.roundoff_limited`` …, which derive from ``nlopt.exception``
    and *not* from ``RuntimeError``, next to ``nlopt.RoundoffLimited`` and ``nlopt.ForcedStop``
    (plain ``Exception`` subclasses). Catch this tuple after the specific ones.
    """
    found = [RuntimeError, ValueError, MemoryError]
    for name in ("exception", "RoundoffLimited", "ForcedStop"):
        cls = getattr(nlopt, name, None)
        if isinstance(cls, type) and issubclass(cls, Exception) and cls not in found:
            found.append(cls)
    return tuple(found)


def _csc(A: sp.spmatrix) -> sp.csc_matrix:
    A = sp.csc_matrix(A, dtype=float, copy=True)
    A.sum_duplicates()
    A.sort_indices()
    return A


def _pattern_key(A: sp.csc_matrix) -> tuple:
    return (A.shape, A.nnz, hash(A.indptr.tobytes()), hash(A.indices.tobytes()))


def _finish(A, b, w, lower, upper, it, status, t0) -> WeightFit:
    w = np.clip(np.asarray(w, float), lower, upper)
    nl, nu = count_bounds(w, lower, upper)
    return WeightFit(w=w, objective=_objective(A, b, w), iterations=int(it), status=status,
                     seconds=time.perf_counter() - t0, n_lower=nl, n_upper=nu)


class IpoptFit(WeightFitBackend):
    """IPOPT on the lifted least-squares form (see the module docstring)."""

    name = "ipopt"
    defaults: dict[str, Any] = {"tol": 1e-10, "max_iter": 1000, "mu_strategy": "adaptive",
                                "max_wall_time": 600.0, "print_level": 0}
    #: IPOPT return_status -> WeightFit status (anything else: "failed").
    STATUS = {"Solve_Succeeded": "optimal", "Solved_To_Acceptable_Level": "max_iter",
              "Maximum_Iterations_Exceeded": "max_iter", "Maximum_WallTime_Exceeded": "max_iter",
              "Maximum_CpuTime_Exceeded": "max_iter", "User_Requested_Stop": "time_limit"}

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self._solvers: dict[tuple, Any] = {}
        self._stop = None  # the iteration callback of the cached solver (it carries the deadline)

    def reset(self) -> None:
        self._solvers.clear()

    def _solver(self, A: sp.csc_matrix):
        key = _pattern_key(A)
        if key not in self._solvers:
            import casadi as ca

            rows, m = A.shape
            Anz = ca.MX.sym("A_nz", A.nnz)
            Asym = ca.MX(ca.Sparsity(rows, m, A.indptr.tolist(), A.indices.tolist()), Anz)
            b = ca.MX.sym("b", rows)
            w0 = ca.MX.sym("w0", m)
            prox = ca.MX.sym("prox")
            w = ca.MX.sym("w", m)
            r = ca.MX.sym("r", rows)
            nlp = {"x": ca.vertcat(w, r), "p": ca.vertcat(Anz, b, w0, prox),
                   "f": 0.5 * ca.sumsqr(r) + 0.5 * prox * ca.sumsqr(w - w0),
                   "g": ca.mtimes(Asym, w) - r - b}
            opts = {k: v for k, v in self.options.items()}
            opts.update({"hessian_constant": "yes", "jac_c_constant": "yes", "sb": "yes"})
            self._solvers.clear()  # one pattern at a time: a new topology replaces the old
            # the solver is built once, so its max_wall_time cannot follow each fit's deadline:
            # a callback checks the deadline at every IPOPT iteration
            self._stop = ipopt_stop_callback(m + rows, rows, A.nnz + rows + m + 1)
            self._solvers[key] = ca.nlpsol("weightfit", "ipopt", nlp,
                                           {"ipopt": opts, "print_time": False, "error_on_fail": False,
                                            "iteration_callback": self._stop})
        return self._solvers[key]

    def _fit(self, *, A, b, lower, upper, w0, prox, rtol, deadline) -> WeightFit:  # rtol: own tol used
        t0 = time.perf_counter()
        A = _csc(A)
        b = np.asarray(b, float)
        lower = np.asarray(lower, float)
        upper = np.asarray(upper, float)
        rows, m = A.shape
        solver = self._solver(A)
        self._stop.deadline = deadline
        w_start = np.clip(np.asarray(w0, float), lower, upper)
        x0 = np.concatenate([w_start, A @ w_start - b])
        p = np.concatenate([A.data, b, np.asarray(w0, float), [float(prox)]])
        sol = solver(x0=x0, p=p, lbx=np.r_[lower, np.full(rows, -np.inf)], ubx=np.r_[upper, np.full(rows, np.inf)],
                     lbg=0.0, ubg=0.0)
        st = solver.stats()
        ret = str(st.get("return_status", "unknown"))
        status = self.STATUS.get(ret, "failed")
        it = int(st.get("iter_count", 0) or 0) if ret != "Invalid_Option" else 0
        return _finish(A, b, np.asarray(sol["x"]).ravel()[:m], lower, upper, it, status, t0)


class OsqpFit(WeightFitBackend):
    """OSQP on the lifted QP (CasADi ``conic('osqp')`` or the ``osqp`` package)."""

    name = "osqp"
    defaults: dict[str, Any] = {"eps_abs": 1e-8, "eps_rel": 1e-8, "max_iter": 200000, "polish": True,
                                "verbose": False}
    #: OSQP status -> WeightFit status (anything else: "failed").
    STATUS = {"solved": "optimal", "solved inaccurate": "max_iter", "maximum iterations reached": "max_iter",
              "max_iter_reached": "max_iter", "run time limit reached": "max_iter", "time_limit_reached": "max_iter"}

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self._impl = self._pick()
        self._solvers: dict[tuple, Any] = {}
        self._warm: dict[tuple, dict] = {}

    @staticmethod
    def _pick() -> str:
        try:
            import casadi as ca

            if ca.has_conic("osqp"):
                return "casadi"
        except ImportError:  # pragma: no cover
            pass
        try:
            import osqp  # noqa: F401

            return "python"
        except ImportError:
            raise BackendUnavailable(
                "the 'osqp' weight-fit backend needs OSQP: the installed CasADi has no osqp plugin and the "
                "'osqp' Python package is not installed; `pip install osqp`, or choose another backend "
                "(e.g. 'ipopt')") from None

    def reset(self) -> None:
        self._solvers.clear()
        self._warm.clear()

    @staticmethod
    def _lifted(A: sp.csc_matrix, prox: float) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        rows, m = A.shape
        H = sp.diags(np.r_[np.full(m, float(prox)), np.ones(rows)], format="csc")
        C = sp.hstack([A, -sp.identity(rows)], format="csc")
        return H, C

    def _fit(self, *, A, b, lower, upper, w0, prox, rtol, deadline) -> WeightFit:  # rtol: own tol used
        t0 = time.perf_counter()
        A = _csc(A)
        b = np.asarray(b, float)
        lower = np.asarray(lower, float)
        upper = np.asarray(upper, float)
        w0 = np.asarray(w0, float)
        rows, m = A.shape
        H, C = self._lifted(A, prox)
        q = np.r_[-float(prox) * w0, np.zeros(rows)]
        w_start = np.clip(w0, lower, upper)
        x0 = np.r_[w_start, A @ w_start - b]
        # the osqp package's own time_limit [s] (0: none) holds the deadline inside a run; CasADi's
        # OSQP interface does not accept that setting (3.8: "Not recognised"), so through CasADi
        # the deadline is only checked before the run
        limit = remaining(deadline, 0.0) if deadline is not None else 0.0
        if self._impl == "casadi":
            w, it, ret = self._fit_casadi(A, H, C, q, b, lower, upper, x0)
        else:
            w, it, ret = self._fit_python(H, C, q, b, lower, upper, x0, m, limit)
        status = self.STATUS.get(ret, "failed")
        if status != "optimal" and out_of_time(deadline):
            status = "time_limit"
        return _finish(A, b, w[:m], lower, upper, it, status, t0)

    def _fit_casadi(self, A, H, C, q, b, lower, upper, x0):
        import casadi as ca

        rows, m = A.shape
        key = _pattern_key(A)
        if key not in self._solvers:
            osqp_opts = {k: v for k, v in self.options.items()}
            # H's structure must not depend on prox (zeros are kept as structural entries)
            self._solvers.clear()
            self._warm.clear()
            self._solvers[key] = ca.conic("weightfit_osqp", "osqp",
                                          {"h": ca.Sparsity.diag(m + rows), "a": ca.DM(C).sparsity()},
                                          {"osqp": osqp_opts, "error_on_fail": False})
        solver = self._solvers[key]
        Hd = ca.DM(ca.Sparsity.diag(m + rows), H.diagonal())
        args = {"h": Hd, "g": q, "a": ca.DM(C), "lba": b, "uba": b,
                "lbx": np.r_[lower, np.full(rows, -np.inf)], "ubx": np.r_[upper, np.full(rows, np.inf)], "x0": x0}
        args.update(self._warm.get(key, {}))
        sol = solver(**args)
        self._warm[key] = {"lam_x0": sol["lam_x"], "lam_a0": sol["lam_a"]}
        st = solver.stats()
        ret = str(st.get("return_status", "unknown")).lower()
        it = max(int(st.get("iter_count", 0) or 0), 0)  # CasADi's OSQP interface reports -1 (unknown)
        return np.asarray(sol["x"]).ravel(), it, ret

    def _fit_python(self, H, C, q, b, lower, upper, x0, m, limit=0.0):  # pragma: no cover - casadi has osqp here
        import osqp

        n = H.shape[0]
        # OSQP has no variable bounds: add them as identity rows
        Aq = sp.vstack([C, sp.hstack([sp.identity(m), sp.csc_matrix((m, n - m))])], format="csc")
        l = np.r_[b, lower]
        u = np.r_[b, upper]
        prob = osqp.OSQP()
        opts = {k: v for k, v in self.options.items()}
        if limit:
            opts["time_limit"] = max(limit, 1e-3)
        prob.setup(sp.triu(H, format="csc"), q, Aq, l, u, **opts)
        prob.warm_start(x=x0)
        res = prob.solve()
        status = str(res.info.status).lower()
        return np.asarray(res.x, float), int(res.info.iter), status


class NloptFit(WeightFitBackend):
    """nlopt bound-constrained L-BFGS / MMA on the smooth objective (analytic gradient)."""

    name = "nlopt"
    defaults: dict[str, Any] = {"algorithm": "LD_LBFGS", "ftol_rel": 1e-16, "xtol_rel": 1e-14,
                                "maxeval": 20000, "maxtime": 600.0, "vector_storage": 20, "kkt_tol": 1e-8}
    #: algorithms accepted (bound constraints, gradient-based).
    ALGORITHMS = ("LD_LBFGS", "LD_MMA", "LD_CCSAQ", "LD_TNEWTON_PRECOND_RESTART", "LD_VAR2")

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        if self.options["algorithm"] not in self.ALGORITHMS:

            raise InputError(f"nlopt algorithm {self.options['algorithm']!r} is not supported here; "
                             f"choose one of {list(self.ALGORITHMS)}")
        try:
            import nlopt  # noqa: F401
        except ImportError:  # pragma: no cover
            raise BackendUnavailable("the 'nlopt' weight-fit backend needs the nlopt package: "
                                     "`pip install nlopt`") from None

    def _fit(self, *, A, b, lower, upper, w0, prox, rtol, deadline) -> WeightFit:  # rtol: own tol used
        import nlopt

        t0 = time.perf_counter()
        A = _csc(A)
        At = A.T.tocsr()
        b = np.asarray(b, float)
        lower = np.asarray(lower, float)
        upper = np.asarray(upper, float)
        w0 = np.asarray(w0, float)
        m = A.shape[1]
        best = {"f": np.inf, "w": np.clip(w0, lower, upper)}
        count = [0]

        def f(w, grad):
            count[0] += 1
            r = A @ w - b
            val = 0.5 * float(r @ r)
            if prox:
                d = w - w0
                val += 0.5 * prox * float(d @ d)
            if grad.size:
                grad[:] = At @ r + (prox * (w - w0) if prox else 0.0)
            if val < best["f"]:
                best["f"], best["w"] = val, w.copy()
            return val

        o = self.options
        opt = nlopt.opt(getattr(nlopt, o["algorithm"]), m)
        opt.set_lower_bounds(lower)
        opt.set_upper_bounds(upper)
        opt.set_min_objective(f)
        opt.set_ftol_rel(o["ftol_rel"])
        opt.set_xtol_rel(o["xtol_rel"])
        opt.set_maxeval(int(o["maxeval"]))
        opt.set_maxtime(float(max(min(o["maxtime"], remaining(deadline)), 1e-3)))
        if o["algorithm"] == "LD_LBFGS":
            opt.set_vector_storage(int(o["vector_storage"]))
        failed = False
        try:
            opt.optimize(best["w"].copy())
        except nlopt.RoundoffLimited:
            pass  # the best point so far is usually fine; the KKT check below decides
        except nlopt_failures(nlopt):
            # NLOPT_FAILURE (L-BFGS's line search gives up on an ill-conditioned fit: the
            # structural scene's Step 2 does), invalid arguments, out of memory, forced stop:
            # keep the best point evaluated; it is "optimal" only if it passes the KKT check
            failed = True
        w = np.clip(best["w"], lower, upper)
        if kkt_residual(A=A, b=b, w=w, lower=lower, upper=upper, w0=w0, prox=prox) <= o["kkt_tol"]:
            status = "optimal"
        else:
            status = "time_limit" if out_of_time(deadline) else "failed" if failed else "max_iter"
        return _finish(A, b, w, lower, upper, count[0], status, t0)


def _register() -> None:
    """Make sure the registry in weightfit lists these backends whichever module is imported
    first (weightfit imports this module while it initialises; if this module is imported first
    that import sees a half-initialised module and the registry would miss them)."""

    registry = getattr(weightfit, "WEIGHT_FIT_BACKENDS", None)
    if registry is not None:  # None: weightfit is importing us and will register us itself
        for cls in (IpoptFit, OsqpFit, NloptFit):
            registry.setdefault(cls.name, cls)


_register()


#: Step-2 backend name (``--backend``) -> class: the active-set fits of
#: :mod:`selfsupport.methods.weightfit` and the solver adapters of this module.
WEIGHT_FIT_BACKENDS: dict[str, type[WeightFitBackend]] = {
    c.name: c for c in (ActiveSetFit, CentredActiveSetFit, CentredAllActiveSetFit, IpoptFit, OsqpFit, NloptFit)}


def make_backend(name: str, **options: Any) -> WeightFitBackend:
    """Instantiate a Step-2 backend by name."""
    try:
        cls = WEIGHT_FIT_BACKENDS[name]
    except KeyError:
        raise InputError(f"unknown weight-fit backend {name!r}; choose one of {sorted(WEIGHT_FIT_BACKENDS)}") from None
    return cls(**options)
