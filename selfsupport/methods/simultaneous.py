"""The simultaneous method: all free positions and active weights at once, with IPOPT.

    minimise    objective(V)                       (default: Σ ‖v_i − v_i^ref‖², free vertices)
    subject to  Σ_j w_ij (v_j − v_i) = (0, 0, L_i)  at every free vertex
                eps ≤ w ≤ w_max

stated once in :class:`formulations.problem.ThrustNetworkProblem` and solved by ``ca.nlpsol``
(IPOPT with MUMPS, adaptive μ) in scale-free units (:class:`~formulations.scaling.Scaling`:
lengths / bounding-box diagonal, forces / mean nodal load). Constraint rows are divided by
``|L_i|``, so IPOPT's ``tol`` bounds the paper's relative error directly.

Loads depend on the geometry (self-weight ∝ area). They are held fixed during one IPOPT run;
then re-estimated from the result (Anderson-accelerated) and the problem re-solved,
warm-started (1–20 IPOPT iterations each), until they change by less than :data:`LOAD_TOL`
(relative, max-norm). IPOPT's positions are only as accurate as its ``tol``, so once the change
is below :data:`POLISH_FROM` (or stops shrinking below :data:`POLISH_ACCEPT`) the weights are
frozen and the heights solved exactly from (3) with re-estimated loads (:func:`polish_heights`,
sparse LU). Either way the final loads are those of the final geometry and the network is in
equilibrium to round-off. On vault / vault-pillar: 8–14 rounds; domes: 2–4.

The objective ignores the weights, so their optimum is not unique; a tiny weight regulariser
(:data:`WEIGHT_REGULARIZATION`) keeps IPOPT off degenerate optima with huge weights.
The problem is non-convex: IPOPT returns a local optimum, and which one depends on the start.

Default lower bound: :func:`formulations.scaling.default_eps`, shared with the
staggered method: ``ε̂ = 1e-4 / ĥ²`` in scaled units (``ĥ`` the mean edge length / bbox
diagonal), i.e. ``ε = 1e-4 · F̄ · D / h̄²`` in N/m with ``F̄`` the mean nodal load. Equilibrium
weights are of order ``F̄ / h̄²`` times the inverse curvature, so this is 3–4 orders below
typical weights on any scene, and invariant under scaling lengths and loads.
"""
from __future__ import annotations

import time
from typing import Any, Callable

import casadi as ca
import numpy as np
from scipy.sparse.linalg import splu

from formulations import (PointDistance, ReferenceDistance, Scaled, Term, ThrustNetworkProblem, WeightBounds)

from ..errors import InputError
from ..loads import LoadCase, SelfWeight, with_scene_extras
from ..result import Network, SolveResult
from ..scene import Scene
from ..validate import require_rise
from formulations.equilibrium import Topology, position_blocks, residual
from formulations.scaling import Scaling, default_eps

#: Relative (max-norm) change of the loads between rounds below which they count as
#: consistent with the geometry.
LOAD_TOL = 1e-12
#: Load change below which the IPOPT rounds stop and the heights are solved with the weights
#: fixed (a sparse stress-Laplacian solve per load update, :func:`polish_heights`): IPOPT's
#: positions are only as accurate as its ``tol``, too coarse to make the loads consistent to
#: :data:`LOAD_TOL` by re-solving; the fixed-weight solve is exact.
POLISH_FROM = 1e-8
#: At most this many height solves in the polish, and the Anderson depth there.
POLISH_MAX_ITER = 100
POLISH_ANDERSON_DEPTH = 5
#: The polish also starts when the rounds stop contracting (IPOPT's accuracy limits them,
#: ~1e-7 at tol 1e-9 on 1,000+ vertices) below this load change; the objective is then optimal
#: for loads within this of the final ones. Above it the rounds go on (or give up: "stalled").
POLISH_ACCEPT = 1e-6
#: At most this many IPOPT runs with re-estimated loads.
MAX_LOAD_ROUNDS = 30
#: Depth of the Anderson acceleration of the load fixed point (0: plain re-estimation).
ANDERSON_DEPTH = 3
#: Natural weight scale in scaled units: ``1 / ĥ²`` (ĥ = mean edge length / bbox diagonal).
#: Cold-start weights, relative to it (IPOPT's path from larger starts is often long and ends
#: in worse local optima; 0.003–0.01 was consistently good on vault, vault-pillar and domes).
COLD_START_FACTOR = 0.01
#: ``mean((w / natural scale)²)`` is added to the objective with this factor. Without it the
#: objective ignores ``w``, the optimal weights are not unique, and IPOPT drifts towards
#: degenerate optima with weights 10³–10⁶ × typical (seen on vault, vault-pillar); at 1e-6
#: the change of the distance term is ~1e-6 relative.
WEIGHT_REGULARIZATION = 1e-6

#: IPOPT ``return_status`` -> our status (selfsupport.result.STATUSES); unknown ones are "failed".
IPOPT_STATUS: dict[str, str] = {
    "Solve_Succeeded": "converged",
    "Solved_To_Acceptable_Level": "stalled",
    "Feasible_Point_Found": "stalled",
    "Search_Direction_Becomes_Too_Small": "stalled",
    "Maximum_Iterations_Exceeded": "iteration_limit",
    "Maximum_WallTime_Exceeded": "time_limit",
    "Maximum_CpuTime_Exceeded": "time_limit",
    "Infeasible_Problem_Detected": "infeasible",
    "Restoration_Failed": "failed",
    "Diverging_Iterates": "failed",
    "Error_In_Step_Computation": "failed",
    "Invalid_Number_Detected": "failed",
    "Invalid_Option": "failed",
    "Not_Enough_Degrees_Of_Freedom": "failed",
    "Invalid_Problem_Definition": "failed",
    "User_Requested_Stop": "interrupted",
    "Insufficient_Memory": "failed",
    "Internal_Error": "failed",
    "Unrecoverable_Exception": "failed",
    "NonIpopt_Exception_Thrown": "failed",
}
#: IPOPT statuses after which ``iter_count`` is meaningless.
_NO_ITERATIONS = {"Invalid_Option", "Invalid_Problem_Definition", "Not_Enough_Degrees_Of_Freedom",
                  "Insufficient_Memory", "Unrecoverable_Exception", "NonIpopt_Exception_Thrown"}


def _vertices_objective(scene: Scene, start: np.ndarray) -> Term:
    return PointDistance(targets=scene.mesh.vertices, mask=scene.free)


def _surface_objective(scene: Scene, start: np.ndarray) -> Term:
    return (ReferenceDistance.from_reference(start, scene.mesh, mask=scene.free)
            + PointDistance(targets=scene.mesh.vertices, mask=scene.free) * 0.1)


#: Named default objectives (stated in SI units): name -> factory(scene, start_vertices) -> Term.
#: ``"vertices"``: squared distance to the reference vertices. ``"surface"``: squared distance to
#: the reference surface, linearised at the start (closest points and normals), plus 0.1 × the
#: vertex term (the paper's α = 1, β = 0.1 regulariser).
OBJECTIVES: dict[str, Callable[[Scene, np.ndarray], Term]] = {
    "vertices": _vertices_objective,
    "surface": _surface_objective,
}


def _per_active_edge(value, scene: Scene, m: int, what: str) -> np.ndarray | float | None:
    """A bound given as a scalar, per active edge or per mesh edge -> scalar or (m,) array."""
    if value is None:
        return None
    a = np.asarray(value, float)
    if a.ndim == 0:
        return float(a)
    if a.shape == (scene.mesh.n_edges,):
        return a[scene.active_edges]
    if a.shape == (m,):
        return a
    raise InputError(f"{what} has {a.shape} entries; give a scalar, one per mesh edge ({scene.mesh.n_edges}) "
                     f"or one per active edge ({m})")


class Simultaneous:
    """Method object: positions and weights at once with IPOPT (backend ``"ipopt"``).

    Example
    -------
    >>> from selfsupport.shapes import make_shape
    >>> res = Simultaneous().solve(make_shape("dome", n_vertices=100), SelfWeight())
    >>> res.status, res.max_relative_error < 1e-9
    ('converged', True)
    """

    name = "simultaneous"
    backend = "ipopt"
    #: IPOPT options (``ipopt.`` prefix added); ``tol``, ``max_iter``, ``max_wall_time`` and
    #: ``print_level`` come from :meth:`solve`'s arguments.
    defaults: dict[str, Any] = {
        "mu_strategy": "adaptive",
        "linear_solver": "mumps",
        "sb": "yes",
    }
    #: Extra IPOPT options for the re-solves with updated loads (warm start).
    warm_defaults: dict[str, Any] = {
        "warm_start_init_point": "yes",
        "warm_start_bound_push": 1e-9,
        "warm_start_bound_frac": 1e-9,
        "warm_start_slack_bound_push": 1e-9,
        "warm_start_slack_bound_frac": 1e-9,
        "warm_start_mult_bound_push": 1e-9,
        "mu_strategy": "monotone",
        "mu_init": 1e-11,  # capped at 0.01 × tol
    }

    def __init__(self, **ipopt_options: Any) -> None:
        self.options = {**self.defaults, **ipopt_options}

    # ------------------------------------------------------------------ public
    def solve(self, scene: Scene, loads: LoadCase | None = None, *, eps: float | None = None,
              w_max=None, tol: float = 1e-9, max_iter: int = 3000, time_limit: float = 120.0,
              warm_start: Network | None = None, objective: str | Term | None = None,
              progress: Callable[[dict], None] | None = None, verbose: bool = False) -> SolveResult:
        """Solve for the thrust network nearest to the reference.

        Parameters
        ----------
        scene
            Reference mesh (also the start unless ``warm_start``) and supports (held fixed).
        loads
            Load case (default :class:`~selfsupport.loads.SelfWeight`), plus the scene's extra
            masses and point loads. Re-estimated from the geometry between IPOPT rounds.
        eps, w_max
            Weight bounds in N/m (scalar, per mesh edge or per active edge). ``eps`` defaults
            to :func:`~formulations.scaling.default_eps` (see the module docstring).
        tol
            IPOPT's ``tol`` (the constraint rows are relative residuals).
        max_iter
            IPOPT iteration limit per round.
        time_limit
            Wall-clock limit [s] of the whole solve (IPOPT's ``max_wall_time`` gets what is left).
        warm_start
            A previous network on the same mesh: its free positions and active weights start IPOPT.
        objective
            ``None`` / a name in :data:`OBJECTIVES` / a :class:`~formulations.objectives.Term` of all
            vertex positions stated in SI units (it is rescaled internally; minimisers are kept).
        progress
            Called with the history record of every round (``stage`` "ipopt" or "polish").
        verbose
            Print IPOPT's log.
        """
        t_start = time.perf_counter()
        scene.mesh.validate()
        scene.check_supports()
        require_rise(scene, w_max)  # a flat reference needs w_max, else no nearest network exists
        loads = with_scene_extras(loads if loads is not None else SelfWeight(), scene)
        mesh0 = scene.mesh
        n = mesh0.n_vertices
        active = scene.active_edges
        top = Topology.build(n, mesh0.edges[active], scene.supports)
        free = top.free

        V = mesh0.vertices.copy()
        if warm_start is not None:
            if warm_start.mesh.n_vertices != n or warm_start.weights.shape != (mesh0.n_edges,):
                raise InputError(f"warm_start network has {warm_start.mesh.n_vertices} vertices / "
                                 f"{warm_start.weights.shape[0]} edges, the scene {n} / {mesh0.n_edges}; "
                                 "warm-start only from a network on the same mesh")
            V[free] = warm_start.vertices[free]
        L = loads.nodal(mesh0, V)
        if np.any(L[free] >= 0):
            k = int(np.flatnonzero(free & (L >= 0))[0])
            raise InputError(f"vertex {k} carries no downward load (zero area?); remove degenerate faces "
                             "or add a load there")

        sc = Scaling.of(mesh0.vertices, L, free)
        Xref = sc.pos(mesh0.vertices)
        if eps is None:
            eps_s = default_eps(Xref, top.edges)
        else:
            eps_s = sc.weight(np.asarray(_per_active_edge(eps, scene, top.m, "eps")))
        wmax = _per_active_edge(w_max, scene, top.m, "w_max")
        wmax_s = None if wmax is None else sc.weight(np.asarray(wmax))
        term = self._objective(objective, scene, V)
        h = float(np.linalg.norm(Xref[top.edges[:, 1]] - Xref[top.edges[:, 0]], axis=1).mean())
        problem = ThrustNetworkProblem(top, sc.pos(V), sc.load(L), WeightBounds(eps_s, wmax_s),
                                       objective=Scaled(term, length=sc.length, center=sc.center),
                                       weight_regularization=WEIGHT_REGULARIZATION, weight_scale=1.0 / h ** 2)

        if warm_start is not None:
            w0 = sc.weight(warm_start.weights[active])
        else:
            w0 = np.full(top.m, COLD_START_FACTOR / h ** 2)
        w0 = np.clip(w0, problem.lower, problem.upper)
        x = problem.pack(sc.pos(V), w0)

        nlp = problem.nlp()
        history: list[dict[str, Any]] = []
        warm = None
        status, message, iterations = "failed", "", 0
        L_cur = L
        mixer = _Anderson(ANDERSON_DEPTH, accept=lambda Lm: bool(np.all(Lm[free] < 0)))
        polish = False
        x_ok = None  # last iterate of a converged round
        best = (np.inf, x)  # (load change, iterate) of the most load-consistent converged round
        for rnd in range(1, MAX_LOAD_ROUNDS + 1):
            remaining = time_limit - (time.perf_counter() - t_start)
            if remaining <= 0:
                status, message = "time_limit", f"time limit {time_limit:g} s reached before load round {rnd}"
                polish = x_ok is not None
                break
            out = self._solve_round(problem, nlp, x, sc.load(L_cur), warm, tol=tol, max_iter=max_iter,
                                    remaining=remaining, verbose=verbose)
            iterations += out["iterations"]
            x, warm = out["x"], out["warm"]
            Vs, ws = problem.unpack(x)
            L_new = loads.nodal(mesh0, sc.pos_back(Vs))
            change = _relative_change(L_new, L_cur)
            rec = {"round": rnd, "stage": self.backend, "solver_status": out["raw"], "iterations": out["iterations"],
                   "seconds": out["seconds"], "objective": out["objective"], "load_change": change,
                   "max_relative_error": _max_rel_error(top, Vs, ws, sc.load(L_new))}
            history.append(rec)
            if progress is not None:
                progress(rec)
            status = out["status"]
            if status != "converged":
                message = f"{self.backend} returned {out['raw']} in load round {rnd}"
                if x_ok is not None:
                    x, polish = x_ok, True
                    message += "; the last converged round's result is returned, heights solved with its weights"
                break
            x_ok = x
            if change < best[0]:
                best = (change, x)
            if change < LOAD_TOL:
                message = f"{self.backend} converged; loads consistent with the geometry after {rnd} round(s)"
                break
            stagnating = len(history) > 1 and change > 0.5 * history[-2]["load_change"]
            if change < POLISH_FROM or (stagnating and change < POLISH_ACCEPT):
                polish = True
                break
            if rnd == MAX_LOAD_ROUNDS or (len(history) > 3 and change >= history[-4]["load_change"]):
                status = "stalled"
                x = best[1]
                message = (f"the loads do not settle: the geometry changes them by {change:.2e} (relative) "
                           f"after {rnd} {self.backend} round(s); the most consistent round (change "
                           f"{best[0]:.2e}) is returned with loads of its own geometry (tight w_max, or a design "
                           "that cannot carry its own weight?)")
                break
            L_cur = mixer.next(L_cur, L_new)

        if polish:
            t0 = time.perf_counter()
            Vp, wp = problem.unpack(x)
            Vp, k, pchange, ok = polish_heights(top, Vp, wp, loads=loads, mesh=mesh0, scaling=sc)
            switch = history[-1]["load_change"] if status == "converged" else float("nan")
            if ok:
                x = problem.pack(Vp, wp)
            Lp = sc.load(loads.nodal(mesh0, sc.pos_back(Vp)))
            rec = {"round": len(history) + 1, "stage": "polish", "solver_status": "converged" if ok else "not converged",
                   "iterations": k, "seconds": time.perf_counter() - t0, "objective": None, "load_change": pchange,
                   "max_relative_error": _max_rel_error(top, Vp, wp, Lp)}
            history.append(rec)
            if progress is not None:
                progress(rec)
            if status != "converged":
                pass  # keep the solver's status and message
            elif not ok:
                status = "stalled"
                message = (f"height solve with fixed weights did not make the loads consistent (still "
                           f"{pchange:.2e} relative after {k} solves); the last {self.backend} round's network "
                           "is returned with loads of its own geometry")
            else:
                message = (f"{self.backend} converged in {len(history) - 1} load round(s) (last load change "
                           f"{switch:.1e}); heights solved with fixed weights until the loads changed < {LOAD_TOL:g}")

        Vs, ws = problem.unpack(x)
        V_final = sc.pos_back(Vs)
        V_final[~free] = mesh0.vertices[~free]  # exactly, not through the scaling round trip
        weights = np.zeros(mesh0.n_edges)
        weights[active] = sc.weight_back(ws)
        final_mesh = mesh0.with_vertices(V_final)
        network = Network(mesh=final_mesh, weights=weights, loads=loads.nodal(final_mesh, V_final),
                          supports=scene.supports, reference=mesh0, handles=scene.handles)
        return SolveResult.build(
            network, status=status, method=self.name, backend=self.backend, iterations=iterations,
            wall_time=time.perf_counter() - t_start, history=tuple(history), message=message,
            parameters={"eps": float(np.min(sc.weight_back(np.asarray(eps_s)))), "w_max": w_max, "tol": tol,
                        "max_iter": max_iter, "time_limit": time_limit,
                        "objective": objective if objective is None or isinstance(objective, str)
                        else type(objective).__name__,
                        "warm_start": warm_start is not None, "load_rounds": len(history),
                        "solver_options": dict(self.options)})

    # ------------------------------------------------------------------ backend
    def _solve_round(self, problem: ThrustNetworkProblem, nlp: dict, x: np.ndarray, loads_scaled: np.ndarray,
                     warm: dict | None, *, tol: float, max_iter: int, remaining: float, verbose: bool) -> dict:
        """One IPOPT run with the loads fixed. Returns ``x``, ``warm`` (multipliers for the next
        round), ``raw`` (IPOPT's status), ``status``, ``iterations``, ``objective``, ``seconds``."""
        opts = dict(self.options)
        if warm is not None:
            opts.update(self.warm_defaults)
            opts["mu_init"] = min(opts.get("mu_init", 1.0), 0.01 * tol)
        opts.update({"tol": tol, "max_iter": int(max_iter), "max_wall_time": float(max(remaining, 1e-3)),
                     "print_level": 5 if verbose else 0})
        solver = ca.nlpsol("simultaneous", "ipopt", nlp,
                           {"ipopt": opts, "print_time": bool(verbose), "error_on_fail": False})
        args = problem.solver_args(x, loads_scaled)
        if warm is not None:
            args.update(warm)
        t0 = time.perf_counter()
        sol = solver(**args)
        seconds = time.perf_counter() - t0
        st = solver.stats()
        ret = str(st.get("return_status", "unknown"))
        return {"x": np.asarray(sol["x"]).ravel(), "warm": {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]},
                "raw": ret, "status": IPOPT_STATUS.get(ret, "failed"),
                "iterations": 0 if ret in _NO_ITERATIONS else int(st.get("iter_count", 0) or 0),
                "objective": float(sol["f"]), "seconds": seconds}

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _objective(objective: str | Term | None, scene: Scene, start: np.ndarray) -> Term:
        if objective is None:
            objective = "vertices"
        if isinstance(objective, str):
            try:
                return OBJECTIVES[objective](scene, start)
            except KeyError:
                raise InputError(f"unknown objective {objective!r}; choose one of {sorted(OBJECTIVES)} "
                                 "or pass a formulations.objectives.Term") from None
        if isinstance(objective, Term):
            if objective.n_vertices != scene.mesh.n_vertices:
                raise InputError(f"the objective is defined on {objective.n_vertices} vertices, the scene has "
                                 f"{scene.mesh.n_vertices}")
            return objective
        raise InputError(f"objective must be a name in {sorted(OBJECTIVES)} or a Term, got {type(objective).__name__}")


class _Anderson:
    """Anderson acceleration of a fixed point ``u = G(u)``: ``next(u, G(u))`` returns the next
    iterate, mixing the last ``depth`` steps (type II, least squares). It turns the linear
    convergence of load re-estimation (rates 0.1–0.5 on the paper's vaults) into a faster one,
    and makes mildly unstable ones (rate slightly above 1, seen in the fixed-weight height solve
    on vault) converge. ``accept(u)`` vetoes a mixed iterate (then the plain ``G(u)`` is used);
    ``limit_step`` also vetoes mixed steps longer than the plain one (against runaway when the
    map is far from contractive, e.g. load rounds under a tight ``w_max``)."""

    def __init__(self, depth: int, accept: Callable[[np.ndarray], bool] | None = None,
                 limit_step: bool = True) -> None:
        self.depth = depth
        self.accept = accept
        self.limit_step = limit_step
        self.f: list[np.ndarray] = []
        self.g: list[np.ndarray] = []

    def next(self, u: np.ndarray, Gu: np.ndarray) -> np.ndarray:
        self.f.append(Gu - u)
        self.g.append(Gu)
        del self.f[:-(self.depth + 1)], self.g[:-(self.depth + 1)]
        if self.depth == 0 or len(self.f) < 2:
            return Gu
        dF = np.diff(np.array(self.f), axis=0).T
        dG = np.diff(np.array(self.g), axis=0).T
        gamma = np.linalg.lstsq(dF, self.f[-1], rcond=None)[0]
        out = Gu - dG @ gamma
        too_far = self.limit_step and np.abs(out - Gu).max() > np.abs(self.f[-1]).max()
        if too_far or not np.all(np.isfinite(out)) or (self.accept is not None and not self.accept(out)):
            return Gu  # safeguards: finite, accepted, and (limit_step) no farther than the plain step
        return out


def polish_heights(top: Topology, V: np.ndarray, w: np.ndarray, *, loads: LoadCase, mesh, scaling: Scaling,
                   tol: float = LOAD_TOL, max_iter: int = POLISH_MAX_ITER) -> tuple[np.ndarray, int, float, bool]:
    """Exact equilibrium for fixed weights, with loads consistent with the geometry.

    In scaled units: the x, y rows of (2) do not involve loads, ``K_ff X_f = −K_fs X_s``;
    the z rows give ``K_ff z_f = L_f(V) − K_fs z_s``, iterated with the loads re-estimated until
    they change by less than ``tol`` (relative). ``K_ff`` (stress Laplacian at free vertices,
    supports eliminated) is positive definite for positive weights.
    Returns ``(V, solves, last load change, converged)``.
    """
    Kff, Kfs = position_blocks(top, w)
    lu = splu(Kff.tocsc())
    free = top.free
    V = np.array(V, float)
    Vs = V[~free]
    for c in (0, 1):
        V[free, c] = lu.solve(-(Kfs @ Vs[:, c]))
    rhs_s = Kfs @ Vs[:, 2]
    mixer = _Anderson(POLISH_ANDERSON_DEPTH, limit_step=False)  # must cure mildly unstable modes
    L = scaling.load(loads.nodal(mesh, scaling.pos_back(V)))
    change = np.inf
    z = V[free, 2].copy()
    for k in range(1, max_iter + 1):
        Gz = lu.solve(L[free] - rhs_s)
        z = mixer.next(z, Gz)
        V[free, 2] = z
        L_new = scaling.load(loads.nodal(mesh, scaling.pos_back(V)))
        change = _relative_change(L_new, L)
        L = L_new
        if change < tol:
            return V, k, change, True
    return V, max_iter, change, False


def _relative_change(new: np.ndarray, old: np.ndarray) -> float:
    return float(np.abs(new - old).max() / max(np.abs(new).max(), 1e-300))


def _max_rel_error(top: Topology, V: np.ndarray, w: np.ndarray, L: np.ndarray) -> float:
    """Max relative residual at free vertices (scaled units; for the history only)."""
    r = residual(top, V, w, L)
    Lf = np.abs(L[top.free])
    return float((np.linalg.norm(r, axis=1) / np.maximum(Lf, 1e-300)).max()) if Lf.size else 0.0
