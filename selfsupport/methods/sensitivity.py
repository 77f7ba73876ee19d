"""Sensitivities of the simultaneous optimum: how the network moves when one scalar parameter
of the problem changes, from the KKT system of the NLP (no re-solve).

At a converged solve of :class:`~selfsupport.methods.simultaneous.Simultaneous` the NLP (in its
scale-free units, :mod:`formulations.nlp`) sits at a KKT point z* = (x*, λ*) with an active set
A: weights on their lower / upper bound, x and y of the free vertices under a fixed top view,
hull rows on the hull's face. Holding A (each active bound an equality, each inactive inequality
dropped), the optimum is the root of

    F(z, θ) = [ ∇ₓf(x; θ) + J_E(x, p)ᵀ λ_E + P_Aᵀ λ_A ;      stationarity
                g_E(x, p(x, θ)) − rhs_E(θ) ;                 equilibrium rows (+ active hull rows)
                P_A x − b_A(θ) ]                             active bounds

and the implicit function theorem gives dz/dθ = −(∂F/∂z)⁻¹ ∂F/∂θ, one sparse LU solve. CasADi
gives the derivatives of f and g (Hessian of the Lagrangian, Jacobians in x and in the
parameters p). The loads are NLP *parameters*, but at the optimum they are the load model at the
optimum's own geometry (self-weight ∝ area), so they enter through the chain rule:
``p = p(x, θ)``, ``∂F/∂x ← ∂F/∂x + ∂F/∂p · ∂p/∂x``; ``∂L/∂X`` is taken by central finite
differences of the load model on a coloured pattern (a vertex's load depends on the faces around
it). The result is the *total* derivative — the same fixed point (optimal for the loads of its
own geometry) that the simultaneous method computes, which is what a re-solve at θ ± h returns.

Units. The NLP's force unit F̄ is the mean nodal load of the first case at the solve's start;
the default lower weight bound ε and the weight regulariser are stated relative to it, so they
scale with the loads (a design choice of the method: ``ε ∝ load``, which makes pure self-weight
scale exactly: ``w ∝ ρ``). The derivative follows that: ``d ln F̄ / dθ`` is taken at the
optimum's geometry (what a re-solve warm-started from this optimum uses). Positions convert to
SI with the bounding-box diagonal D (fixed by the reference), weights with ``F̄ / D``.

The row scaling of the equilibrium rows (``1 / |L_i|``) is held: it changes λ, never x.

Parameters (:data:`PARAMETERS`, parsed by :func:`parse_parameter`):

* ``density``, ``thickness`` — ρ, t of the material self-weight (every :class:`SelfWeight`
  with the first one's ρ and t; a uniform mass, stated as a self-weight with other ρ, t, is
  not the material). ``thickness`` also moves a hull whose thickness is the self-weight's.
* ``point_load:V`` — magnitude [N, downward] of the point load at vertex V, in the cases that
  carry one there (every case if none does: the effect of adding one); ``point_load:V@CASE``
  one named case.
* ``w_max`` — the scalar upper weight bound [N/m] (only weights on it feel it).
* ``objective:NAME`` — the weight of the objective term NAME.

Example
-------
>>> from formulations import Problem
>>> from selfsupport.core.loads import SelfWeight
>>> from selfsupport.methods.simultaneous import Simultaneous
>>> from selfsupport.core.shapes import make_shape
>>> problem = Problem.build(make_shape("dome", n_vertices=60), SelfWeight(density=2000.0))
>>> run = Simultaneous().run(problem)
>>> s = sensitivity(run, "density", problem=problem)
>>> w = run.result.network.weights
>>> float(np.abs(s.d_weights[0] - w / 2000.0).max() / np.abs(w / 2000.0).max()) < 1e-8  # w ∝ ρ
True
>>> float(np.abs(s.d_vertices).max()) < 1e-9  # the shape does not depend on ρ
True
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, onenormest, splu

from formulations import FixedTopView, Hull, ObjectiveTerm, Problem
from formulations.nlp import ThrustNetworkProblem
from formulations.scaling import Scaling
from selfsupport.core.errors import InputError
from selfsupport.core.loads import CombinedLoad, LoadCase, PointLoad, SelfWeight
from selfsupport.core.result import SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.loadcases import LoadSpec
from selfsupport.methods import METHODS, capabilities
from selfsupport.methods.base import load_factor, proportional_members, without_members
from selfsupport.methods.polish import BOUND_ACTIVE_REL, HULL_ACTIVE_REL, load_colouring
from selfsupport.methods.simultaneous import DEFAULT_OBJECTIVE, Simultaneous, SimultaneousRun, kept_cases

#: Relative stationarity residual (with least-squares multipliers on the active set) above which
#: the point is not a KKT point of the NLP and no sensitivity is given (a staggered result: O(1)).
#: Loose, because with the method's small default weight regulariser IPOPT's final barrier terms
#: (~μ / (w − ε)) are as large as the regulariser's gradient, which alone fixes the weights in the
#: null space of the equilibrium Jacobian: a correct optimum can show a residual of 1e-4. Such
#: results are accepted; their ``kkt_residual`` and ``condition`` say how far to trust the derivative.
KKT_ACCEPT = 1e-2
#: Relative step of the central differences of the load model (in scaled lengths, i.e. of the
#: bounding-box diagonal): truncation error ~ step² ≈ 1e-12, round-off ~ 1e-16 / step ≈ 1e-10.
LOAD_FD_STEP = 1e-6


# ------------------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class Sensitivity:
    """Derivative of an optimal network with respect to one parameter θ (SI units, per unit θ).

    Attributes
    ----------
    parameter, value
        The parameter's name (``"density"``, ``"point_load:12"``, …) and its value θ at the optimum.
    d_vertices
        ``(n, 3)`` dV/dθ [m per unit θ]; support rows are zero.
    d_weights
        One ``(m,)`` array per load case (mesh-edge order): dw/dθ [N/m per unit θ]; edges
        between two supports are zero.
    case_names
        Names of the load cases, in the order of ``d_weights``.
    active
        The active set that was held: ``"lower"``, ``"upper"`` (per case: mesh edges on the
        bound), ``"fixed_xy"`` (free vertices whose x, y are held), ``"hull"`` (vertices on the
        hull's face).
    kkt_residual
        Relative stationarity residual at the optimum with least-squares multipliers on that
        active set (small: the active set and the point are a KKT point).
    weakly_active
        Active bounds whose multiplier is below 1e-8 of the largest: there the derivative is
        one-sided (a bound could be left or joined by an arbitrarily small change of θ).
    condition
        1-norm condition estimate of the KKT matrix ∂F/∂z (scaled units).
    solve_residual
        Relative residual of the linear solve.
    """

    parameter: str
    value: float
    d_vertices: np.ndarray
    d_weights: tuple[np.ndarray, ...]
    case_names: tuple[str, ...]
    active: dict[str, Any]
    kkt_residual: float
    weakly_active: int
    condition: float
    solve_residual: float


# --------------------------------------------------------------------------- parameters
def _leaves(model: LoadCase) -> list[LoadCase]:
    return [x for c in model.cases for x in _leaves(c)] if isinstance(model, CombinedLoad) else [model]


class Parameter:
    """A scalar parameter of a :class:`Problem`: its value and the partial derivatives of the
    problem's data (loads at fixed geometry, bounds, hull thickness, objective) with respect to it."""

    name: ClassVar[str] = "parameter"

    @classmethod
    def parse(cls, arg: str) -> "Parameter":
        if arg:
            raise InputError(f"parameter {cls.name!r} takes no argument, got {cls.name}:{arg}")
        return cls()

    @property
    def label(self) -> str:
        return self.name

    def value(self, problem: Problem) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def d_loads(self, problem: Problem, V: np.ndarray) -> np.ndarray:
        """``(n_cases, n)`` ∂L/∂θ [N per unit θ] at the fixed positions ``V``."""
        return np.zeros((len(problem.loads), problem.scene.mesh.n_vertices))

    def d_upper(self, problem: Problem) -> float:
        """d w_max / dθ [N/m per unit θ] (a scalar bound)."""
        return 0.0

    def d_thickness(self, problem: Problem) -> float:
        """d (hull thickness) / dθ [m per unit θ]."""
        return 0.0

    objective_name: str | None = None


class _Material(Parameter):
    attr: ClassVar[str]

    def _self_weights(self, problem: Problem) -> list[list[SelfWeight]]:
        """Per case, its material self-weight loads (those with the first one's ρ and t)."""
        per_case = [[x for x in _leaves(m) if isinstance(x, SelfWeight)] for m in problem.loads.models]
        first = next((x for xs in per_case for x in xs), None)
        if first is None:
            raise InputError(f"the problem has no self-weight, so no {self.name} to vary")
        return [[x for x in xs if (x.density, x.thickness) == (first.density, first.thickness)] for xs in per_case]

    def value(self, problem: Problem) -> float:
        return float(getattr(next(x for xs in self._self_weights(problem) for x in xs), self.attr))

    def d_loads(self, problem: Problem, V: np.ndarray) -> np.ndarray:
        # self-weight is −ρ t g · area: linear in ρ and in t
        mesh = problem.scene.mesh
        return np.stack([sum((x.nodal(mesh, V) / getattr(x, self.attr) for x in xs), np.zeros(mesh.n_vertices))
                         for xs in self._self_weights(problem)])


class Density(_Material):
    name = "density"
    attr = "density"


class Thickness(_Material):
    name = "thickness"
    attr = "thickness"

    def d_thickness(self, problem: Problem) -> float:
        h = problem.constraint(Hull)
        return 1.0 if h is not None and h.thickness is None else 0.0  # the hull takes the self-weight's t


@dataclass(frozen=True)
class PointLoadMagnitude(Parameter):
    vertex: int
    case: str | None = None
    name: ClassVar[str] = "point_load"

    @classmethod
    def parse(cls, arg: str) -> "PointLoadMagnitude":
        v, _, case = arg.partition("@")
        try:
            return cls(int(v), case or None)
        except ValueError:
            raise InputError(f"write point_load:VERTEX or point_load:VERTEX@CASE, got point_load:{arg}") from None

    @property
    def label(self) -> str:
        return f"point_load:{self.vertex}" + (f"@{self.case}" if self.case else "")

    def _magnitudes(self, problem: Problem) -> np.ndarray:
        """Per case, the downward point load at the vertex [N]."""
        n = problem.scene.mesh.n_vertices
        if not 0 <= self.vertex < n:
            raise InputError(f"point_load:{self.vertex}: the mesh has vertices 0..{n - 1}")
        return np.array([-sum(float(np.asarray(x.forces, float)[self.vertex]) for x in _leaves(m)
                              if isinstance(x, PointLoad)) for m in problem.loads.models])

    def cases(self, problem: Problem) -> np.ndarray:
        """Mask of the cases the parameter acts on."""
        names = problem.loads.names
        if self.case is not None:
            if self.case not in names:
                raise InputError(f"{self.label}: no load case {self.case!r}; the problem has {', '.join(names)}")
            return np.array([c == self.case for c in names])
        has = self._magnitudes(problem) != 0
        return has if has.any() else np.ones(len(names), bool)

    def value(self, problem: Problem) -> float:
        mags = self._magnitudes(problem)[self.cases(problem)]
        if np.ptp(mags) > 0:
            raise InputError(f"{self.label}: the cases carry different point loads there ({mags.tolist()} N); "
                             "name one case: point_load:VERTEX@CASE")
        return float(mags[0])

    def d_loads(self, problem: Problem, V: np.ndarray) -> np.ndarray:
        out = np.zeros((len(problem.loads), problem.scene.mesh.n_vertices))
        out[self.cases(problem), self.vertex] = -1.0  # a larger downward load: more negative L
        return out


class UpperBound(Parameter):
    name = "w_max"

    def value(self, problem: Problem) -> float:
        up = problem.bounds.upper
        if not problem.bounds.has_upper:
            raise InputError("the problem has no w_max to vary")
        if np.ndim(up) != 0:
            raise InputError("w_max is given per edge; the w_max sensitivity is of a scalar bound")
        return float(up)

    def d_upper(self, problem: Problem) -> float:
        return 1.0


@dataclass(frozen=True)
class ObjectiveWeight(Parameter):
    term: str
    name: ClassVar[str] = "objective"

    @classmethod
    def parse(cls, arg: str) -> "ObjectiveWeight":
        if not arg:
            raise InputError("write objective:NAME with the name of an objective term")
        return cls(arg)

    @property
    def label(self) -> str:
        return f"objective:{self.term}"

    @property
    def objective_name(self) -> str:  # type: ignore[override]
        return self.term

    def value(self, problem: Problem) -> float:

        spec = problem.objective if problem.objective is not None else (ObjectiveTerm(DEFAULT_OBJECTIVE),)
        hits = [o for o in spec if isinstance(o, ObjectiveTerm) and o.name == self.term]
        if len(hits) != 1:
            have = [getattr(o, "name", type(o).__name__) for o in spec]
            raise InputError(f"objective:{self.term}: the objective has {len(hits)} terms of that name "
                             f"(terms: {', '.join(have)}); name a term that occurs once")
        return float(hits[0].weight)


#: Parameter kinds by name (``NAME`` or ``NAME:ARG``).
PARAMETERS: dict[str, type[Parameter]] = {c.name: c for c in (Density, Thickness, PointLoadMagnitude, UpperBound,
                                                               ObjectiveWeight)}


def parse_parameter(spec: str | Parameter) -> Parameter:
    """``"density"``, ``"thickness"``, ``"w_max"``, ``"point_load:V"``, ``"point_load:V@CASE"``,
    ``"objective:NAME"`` (or a :class:`Parameter`) -> a :class:`Parameter`."""
    if isinstance(spec, Parameter):
        return spec
    name, _, arg = str(spec).partition(":")
    if name not in PARAMETERS:
        raise InputError(f"unknown parameter {spec!r}; choose from density, thickness, w_max, point_load:VERTEX, "
                         "objective:NAME")
    return PARAMETERS[name].parse(arg)


# ------------------------------------------------------------------------------ helpers
def _scipy(dm: ca.DM) -> sp.csc_matrix:
    """A sparse CasADi DM as a scipy CSC matrix (structural zeros kept out)."""
    colind, row = dm.sparsity().get_ccs()
    return sp.csc_matrix((np.asarray(dm.nonzeros(), float), row, colind), shape=dm.shape)


def _load_jacobians(problem: Problem, sc: Scaling, X: np.ndarray, free: np.ndarray) -> list[sp.csr_matrix | None]:
    """Per case ``∂L̂_free / ∂X̂_free`` (n_free × 3 n_free, column ``3 k + c``) in scaled units, by
    central differences on the face-neighbour pattern (one pair of load evaluations per colour
    and coordinate); ``None`` for a case whose loads do not depend on the geometry."""
    mesh0 = problem.scene.mesh
    rows, cols, colour, n_colours = load_colouring(mesh0, free)
    fidx = np.flatnonzero(free)
    nf = fidx.size
    out: list[sp.csr_matrix | None] = []
    for model in problem.loads.models:
        if not model.depends_on_geometry:
            out.append(None)
            continue
        R, C, D = [], [], []
        for c in range(3):
            diff = np.empty((n_colours, nf))
            for k in range(n_colours):
                Xp, Xm = X.copy(), X.copy()
                Xp[fidx[colour == k], c] += LOAD_FD_STEP
                Xm[fidx[colour == k], c] -= LOAD_FD_STEP
                diff[k] = (model.nodal(mesh0, sc.pos_back(Xp)) - model.nodal(mesh0, sc.pos_back(Xm)))[fidx]
            R.append(rows)
            C.append(3 * cols + c)
            D.append(diff[colour[cols], rows] / (2 * LOAD_FD_STEP * sc.force))
        out.append(sp.csr_matrix((np.concatenate(D), (np.concatenate(R), np.concatenate(C))), shape=(nf, 3 * nf)))
    return out


def _kkt_functions(form: ThrustNetworkProblem, nlp: dict) -> ca.Function:
    """``(x, p, λ_g) -> (∇f, J_g, ∇²ₓₓℒ, ∂(∇ₓℒ)/∂p, ∂g/∂p)`` with ℒ = f + λ_gᵀ g."""
    x, p, f, g = nlp["x"], nlp["p"], nlp["f"], nlp["g"]
    lam = ca.MX.sym("lam_g", g.shape[0]) if isinstance(x, ca.MX) else ca.SX.sym("lam_g", g.shape[0])
    grad_L = ca.gradient(f + ca.dot(lam, g), x)
    return ca.Function("kkt", [x, p, lam], [ca.gradient(f, x), ca.jacobian(g, x), ca.jacobian(grad_L, x),
                                            ca.jacobian(grad_L, p), ca.jacobian(g, p)])


def _objective_gradient(form: ThrustNetworkProblem, name: str, x_sym, x: np.ndarray, p_sym, p: np.ndarray
                        ) -> np.ndarray:
    """∇ₓ of the unweighted objective term(s) called ``name`` (∂(∇f)/∂weight)."""
    parts = [t for t in (form.objective.parts() if form.objective is not None else ()) if t.name == name]
    if not parts:
        raise InputError(f"objective:{name}: the solved NLP has no term {name!r}")
    X_all = form.equilibrium.all_positions()
    raw = sum((t.raw(X_all) for t in parts), 0)
    fn = ca.Function("d_obj", [x_sym, p_sym], [ca.gradient(raw, x_sym)])
    return np.asarray(fn(x, p)).ravel()


# ----------------------------------------------------------------------------- problem
def problem_of(result: SolveResult) -> Problem:
    """The :class:`Problem` of a result written by :func:`selfsupport.api.solve` (its
    ``parameters``: load model, bounds, objective, constraints), checked against the result: the
    rebuilt load model must give the stored loads of every case at the result's geometry."""

    params = result.parameters
    desc, model = params.get("problem"), params.get("load_model")
    if not isinstance(desc, dict) or not isinstance(model, dict):
        raise InputError("the result does not describe its problem (solved outside selfsupport.api.solve?); "
                         "pass problem=")
    net = result.network
    scene = Scene(mesh=net.reference if net.reference is not None else net.mesh, supports=net.supports,
                  handles=net.handles, name="result")
    objective = desc.get("objective")
    if objective is not None:
        if any(o.get("user_term") for o in objective):
            raise InputError("the result's objective has user terms that cannot be rebuilt; pass problem=")
        objective = tuple(ObjectiveTerm(o["name"], o["weight"], o.get("params", {})) for o in objective)
    cons = [Hull(c.get("thickness")) if c["name"] == "hull" else FixedTopView() for c in desc.get("constraints", [])]
    bounds = desc.get("bounds", {})
    prob = Problem.build(scene, LoadSpec.from_description(model).cases(scene.mesh.n_vertices), eps=bounds.get("eps"),
                         w_max=bounds.get("w_max"), objective=objective, constraints=cons)
    for (_, m), (_, n) in zip(prob.loads, result.case_networks):
        L = m.nodal(scene.mesh, n.vertices)
        if not np.allclose(L, n.loads, rtol=1e-10, atol=1e-10 * np.abs(n.loads).max()):
            raise InputError("the load model rebuilt from the result does not give its stored loads "
                             "(scene extras not recorded?); pass problem=")
    return prob


# ------------------------------------------------------------------------- the KKT steps
@dataclass(frozen=True, eq=False)
class _Optimum:
    """The optimum in the NLP's scaled units, with the loads of its own geometry."""

    problem: Problem
    form: ThrustNetworkProblem
    sc: Scaling
    #: ``(n, 3)`` positions [m] and scaled
    V: np.ndarray
    X: np.ndarray
    #: ``(n_cases, m)`` scaled weights of the active edges
    W: np.ndarray
    #: the NLP's variables and parameters at the optimum, and the NLP itself
    x: np.ndarray
    p: np.ndarray
    nlp: dict
    #: ``(n_cases, n)`` loads [N] and scaled
    L_si: np.ndarray
    Lh: np.ndarray

    @property
    def load_offset(self) -> int:
        """Where the first case's free loads sit in ``p`` (after the supports' positions)."""
        return 3 * int((~self.form.topology.free).sum())


@dataclass(frozen=True, eq=False)
class _ActiveSet:
    """The active set held: bounds as equalities (``A``: entries of x), rows of g held (``E``)."""

    #: the bounds tiled over the cases (scaled), and the weights on them
    lo: np.ndarray
    up: np.ndarray
    on_lo: np.ndarray
    on_up: np.ndarray
    #: entries of x held: the fixed top view's x, y, the weights on their lower, upper bound
    fixed: np.ndarray
    A_lo: np.ndarray
    A_up: np.ndarray
    A: np.ndarray
    #: the equilibrium rows (``n_eq``), then the active hull rows
    n_eq: int
    E: np.ndarray
    #: mask of the hull's vertices on its face (None: no hull) and the side of each
    hull_on: np.ndarray | None
    hull_sign: np.ndarray
    #: ``(|A|, n_x)`` selection of the held entries of x
    PA: sp.csr_matrix


def _converged_result(result_or_run: Any) -> tuple[SolveResult, Any]:
    """The result (and the run's answer, or None) of a converged simultaneous solve; else InputError."""
    answer = None
    if isinstance(result_or_run, SimultaneousRun):
        result, answer = result_or_run.result, result_or_run.answer
    elif isinstance(result_or_run, SolveResult):
        result = result_or_run
    else:
        raise InputError(f"sensitivity needs a SolveResult or a SimultaneousRun, got {type(result_or_run).__name__}")
    simultaneous = result.method in METHODS and capabilities(result.method).simultaneous
    if not simultaneous or result.status != "converged":
        raise InputError(f"sensitivities are of a converged simultaneous (IPOPT) optimum; this result is "
                         f"{result.method} / {result.status}: solve with method='ipopt'")
    return result, answer


def _formulation(result: SolveResult, answer: Any, problem: Problem) -> tuple[ThrustNetworkProblem, Scaling]:
    """The solved NLP and its scaling: the run's own, or rebuilt for a cold start (which starts
    at the reference); a warm start's NLP depends on its start, so it cannot be rebuilt."""
    if answer is not None:
        return answer.formulation, answer.scaling
    if not result.parameters.get("warm_start", False):
        return Simultaneous.formulation(
            problem, problem.scene.mesh.vertices, weight_regularization=result.parameters.get("weight_regularization"))
    raise InputError("a warm-started solve's NLP depends on its start; pass the SimultaneousRun")


def _optimum(result: SolveResult, problem: Problem, form: ThrustNetworkProblem, sc: Scaling) -> _Optimum:
    """The optimum in scaled units, its loads those of its own geometry."""
    act = problem.scene.active_edges
    V = result.network.vertices
    X = sc.pos(V)
    W = np.stack([sc.weight(n.weights[act]) for _, n in result.case_networks])
    L_si = problem.loads.nodal(problem.scene.mesh, V)
    Lh = sc.load(L_si)
    return _Optimum(problem=problem, form=form, sc=sc, V=V, X=X, W=W, x=form.pack(X, W), p=form.parameters(Lh),
                    nlp=form.nlp(), L_si=L_si, Lh=Lh)


def _active_set(opt: _Optimum) -> _ActiveSet:
    """Weights on a bound (the polish's criterion), the fixed top view's x, y, hull rows on the face."""
    form, x = opt.form, opt.x
    C, nf = form.n_cases, form.topology.n_free
    lo, up = np.tile(form.lower, C), np.tile(form.upper, C)
    wx = x[3 * nf:]
    on_lo = wx <= lo + BOUND_ACTIVE_REL * np.maximum(np.abs(lo), 1e-300)  # (a tension bound is negative)
    on_up = wx >= up - BOUND_ACTIVE_REL * np.abs(np.nan_to_num(up, posinf=0.0))
    bnd = form.bounds_args()
    fixed = np.flatnonzero(bnd["lbx"] == bnd["ubx"])  # the fixed top view's x, y
    A_lo, A_up = 3 * nf + np.flatnonzero(on_lo), 3 * nf + np.flatnonzero(on_up & ~on_lo)
    A = np.concatenate([fixed, A_lo, A_up])
    n_eq = 3 * nf * C
    E = np.arange(n_eq)
    hull_on, hull_sign = None, np.zeros(0)
    if form.hull is not None:
        sd = form.hull.signed_distance(opt.X)
        hull_on = np.abs(sd) >= form.hull.half_thickness * (1 - HULL_ACTIVE_REL)
        E = np.concatenate([E, n_eq + np.flatnonzero(hull_on)])
        hull_sign = np.sign(sd[hull_on])
    PA = sp.csr_matrix((np.ones(A.size), (np.arange(A.size), A)), shape=(A.size, x.size))
    return _ActiveSet(lo=lo, up=up, on_lo=on_lo, on_up=on_up, fixed=fixed, A_lo=A_lo, A_up=A_up, A=A, n_eq=n_eq,
                      E=E, hull_on=hull_on, hull_sign=hull_sign, PA=PA)


def _multipliers(kkt: ca.Function, opt: _Optimum, act: _ActiveSet) -> tuple[np.ndarray, float, int, sp.csr_matrix]:
    """Least-squares multipliers on the active set, ``[J_Eᵀ P_Aᵀ] μ ≈ −∇f``.

    Returns λ_g (zero off ``E``), the relative stationarity residual, the number of weakly
    active bounds and the constraint Jacobian J; InputError where the point is no KKT point."""
    x, p, form, E = opt.x, opt.p, opt.form, act.E
    n_x = x.size
    gf = np.asarray(kkt(x, p, np.zeros(form.n_g))[0]).ravel()
    J = _scipy(kkt(x, p, np.zeros(form.n_g))[1]).tocsr()
    B = sp.hstack([J[E].T, act.PA.T]).tocsc()
    k = B.shape[1]
    aug = sp.bmat([[sp.identity(n_x), B], [B.T, None]], format="csc")
    sol = splu(aug).solve(np.concatenate([-gf, np.zeros(k)]))
    mu = sol[n_x:]
    stationarity = float(np.abs(gf + B @ mu).max() / max(np.abs(gf).max(), np.abs(B @ mu).max(), 1e-300))
    if not stationarity <= KKT_ACCEPT:
        raise InputError(f"the result is not a KKT point of the simultaneous NLP (relative stationarity residual "
                         f"{stationarity:.1e} with its active set); sensitivities need IPOPT's optimum")
    lam_g = np.zeros(form.n_g)
    lam_g[E] = mu[:E.size]
    lam_A = mu[E.size:]
    weak = int(np.sum(np.abs(lam_A[act.fixed.size:]) <= 1e-8 * max(np.abs(lam_A).max(initial=0.0), 1e-300)))
    return lam_g, stationarity, weak, J


def _kkt_matrix(kkt: ca.Function, opt: _Optimum, act: _ActiveSet, *, lam_g: np.ndarray, J: sp.csr_matrix
                ) -> tuple[sp.csc_matrix, sp.csr_matrix, sp.csr_matrix]:
    """∂F/∂z with the loads' dependence on the geometry (chain rule through p), and the
    parameter Jacobians ``∂(∇ₓℒ)/∂p``, ``∂g/∂p`` (for ∂F/∂θ)."""
    form, E, PA = opt.form, act.E, act.PA
    top = form.topology
    C, m, nf = form.n_cases, top.m, top.n_free
    n_x, n_p = opt.x.size, opt.p.size
    _, _, H, Mp, Gp = (o for o in kkt(opt.x, opt.p, lam_g))
    H, Mp, Gp = _scipy(H), _scipy(Mp).tocsr(), _scipy(Gp).tocsr()
    n_sup = opt.load_offset
    DL = _load_jacobians(opt.problem, opt.sc, opt.X, top.free)
    blocks = [sp.csr_matrix((n_sup, n_x))]
    for c in range(C):
        Jc = DL[c] if DL[c] is not None else sp.csr_matrix((nf, 3 * nf))
        blocks.append(sp.hstack([Jc, sp.csr_matrix((nf, C * m))]))
    blocks.append(sp.csr_matrix((n_p - n_sup - C * nf, n_x)))
    dp_dx = sp.vstack(blocks).tocsr()
    K11 = (H + Mp @ dp_dx).tocsr()
    K21 = (J[E] + Gp[E] @ dp_dx).tocsr()
    if act.A.size:
        K = sp.bmat([[K11, J[E].T, PA.T], [K21, None, None], [PA, None, None]], format="csc")
    else:
        K = sp.bmat([[K11, J[E].T], [K21, None]], format="csc")
    return K, Mp, Gp


def _parameter_rhs(par: Parameter, opt: _Optimum, act: _ActiveSet, *, Mp: sp.csr_matrix, Gp: sp.csr_matrix
                   ) -> tuple[np.ndarray, float]:
    """``−∂F/∂θ`` and ``d ln F̄ / dθ`` (the force unit's change, taken at the optimum's geometry)."""
    form, sc, problem = opt.form, opt.sc, opt.problem
    free, C, m, nf = form.topology.free, form.n_cases, form.topology.m, form.topology.n_free
    dL = par.d_loads(problem, opt.V)  # ∂L/∂θ at fixed geometry [N]
    dlnF = -float(dL[0][free].mean()) / float(np.abs(opt.L_si[0][free]).mean())  # d ln F̄ / dθ
    dLh = dL / sc.force - opt.Lh * dlnF
    dp = np.zeros(opt.p.size)
    for c in range(C):
        row = opt.load_offset + c * nf  # where case c's L_free sits in p
        dp[row:row + nf] = dLh[c][free]
    r1 = Mp @ dp
    if par.objective_name is not None:
        r1 = r1 + _objective_gradient(form, par.objective_name, opt.nlp["x"], opt.x, opt.nlp["p"], opt.p)
    r2 = Gp[act.E] @ dp
    if act.hull_sign.size:  # active hull rows: g = ±h, h = t / 2 in scaled lengths
        r2[act.n_eq:] -= act.hull_sign * 0.5 * par.d_thickness(problem) / sc.length
    # bounds in scaled units: ŵ = w D / F̄. The default ε is stated in scaled units (fixed);
    # an explicit ε or w_max [N/m] moves with 1 / F̄ and w_max with its own derivative.
    lo_si, _ = problem.bounds.active(problem.scene)
    # (per-edge NaN entries are the default ε, fixed in scaled units)
    d_lo = np.zeros(C * m) if lo_si is None else np.where(np.tile(np.isnan(np.broadcast_to(lo_si, (m,))), C), 0.0,
                                                          -act.lo * dlnF)
    d_up = np.tile(np.broadcast_to(par.d_upper(problem) * sc.length / sc.force, (m,)), C) - \
        np.where(np.isfinite(act.up), act.up, 0.0) * dlnF
    r3 = -np.concatenate([np.zeros(act.fixed.size), d_lo[act.A_lo - 3 * nf], d_up[act.A_up - 3 * nf]])
    return -np.concatenate([r1, r2, r3]), dlnF


def _solve_kkt(K: sp.csc_matrix, rhs: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``dz = K⁻¹ rhs`` by sparse LU, its relative residual and K's 1-norm condition estimate."""
    try:
        lu = splu(K)
    except RuntimeError as e:  # "Factor is exactly singular"
        raise InputError(f"the KKT matrix is singular at this optimum ({e}): the active set is degenerate") from None
    dz = lu.solve(rhs)
    solve_res = float(np.abs(K @ dz - rhs).max() / max(np.abs(rhs).max(), 1e-300))
    n_K = K.shape[0]
    inv = LinearOperator((n_K, n_K), matvec=lu.solve, rmatvec=lambda v: lu.solve(v, trans="T"), dtype=float)
    return dz, solve_res, float(onenormest(K) * onenormest(inv))


def _in_si(opt: _Optimum, act: _ActiveSet, *, dz: np.ndarray, dlnF: float) -> tuple[np.ndarray, tuple, dict]:
    """dV/dθ, dw/dθ per case (SI, mesh order) and the active set by mesh index:
    ``V = D X̂ + c``; ``w = ŵ F̄ / D`` with F̄ moving as ``d ln F̄ / dθ``."""
    form, sc, scene = opt.form, opt.sc, opt.problem.scene
    free, C, m, nf = form.topology.free, form.n_cases, form.topology.m, form.topology.n_free
    act_edges = scene.active_edges
    dX, dW = dz[:3 * nf].reshape(nf, 3), dz[3 * nf:opt.x.size].reshape(C, m)
    d_vertices = np.zeros_like(opt.V)
    d_vertices[free] = sc.length * dX
    d_weights = []
    for c in range(C):
        dw = np.zeros(scene.mesh.n_edges)
        dw[act_edges] = sc.force / sc.length * (dW[c] + opt.W[c] * dlnF)
        d_weights.append(dw)
    act_idx = np.flatnonzero(act_edges)
    on_up = act.on_up & ~act.on_lo
    active = {"lower": tuple(act_idx[np.flatnonzero(act.on_lo[c * m:(c + 1) * m])] for c in range(C)),
              "upper": tuple(act_idx[np.flatnonzero(on_up[c * m:(c + 1) * m])] for c in range(C)),
              "fixed_xy": np.flatnonzero(free)[np.unique(act.fixed // 3)] if act.fixed.size else np.zeros(0, int),
              "hull": form.hull.idx[act.hull_on] if form.hull is not None else np.zeros(0, int)}
    return d_vertices, tuple(d_weights), active


def _with_members(problem: Problem, members: dict[int, tuple[int, float]], par: Parameter, result: SolveResult,
                  d_weights: tuple, active: dict[str, Any]) -> tuple[tuple, dict[str, Any], tuple[str, ...]]:
    """Every case's dw/dθ and active bounds, the proportional cases (``members``, left out of the
    NLP) added: a member's weights are its case's times ``k = L_c·L_r / L_r·L_r`` at any geometry,
    so ``dw_c = k dw_r + (dk/dθ) w_r`` with ``dk/dθ`` from ∂L/∂θ at the optimum; its bounds
    held are its case's. ``result``: the optimum of the NLP without the members."""
    free, V = ~problem.scene.supports, result.network.vertices
    L = problem.loads.nodal(problem.scene.mesh, V)[:, free]
    dL = par.d_loads(problem, V)[:, free]
    kept = [c for c in range(len(problem.loads)) if c not in members]
    solved = dict(zip(kept, range(len(kept))))
    nets = [n.weights for _, n in result.case_networks]
    dw, lower, upper = [], [], []
    for c in range(len(problem.loads)):
        r = members[c][0] if c in members else c
        j = solved[r]
        if c in members:
            k = load_factor(L[c], L[r])
            dk = float(dL[c] @ L[r] + L[c] @ dL[r] - 2.0 * k * (L[r] @ dL[r])) / float(L[r] @ L[r])
            dw.append(k * d_weights[j] + dk * nets[j])
        else:
            dw.append(d_weights[j])
        lower.append(active["lower"][j])
        upper.append(active["upper"][j])
    return tuple(dw), {**active, "lower": tuple(lower), "upper": tuple(upper)}, tuple(problem.loads.names)


# -------------------------------------------------------------------------------- main
def sensitivity(result_or_run: Any, parameter: str | Parameter, *, problem: Problem | None = None) -> Sensitivity:
    """dV/dθ and dw/dθ of a converged simultaneous (IPOPT) solve, from its KKT system.

    Parameters
    ----------
    result_or_run
        A :class:`~selfsupport.methods.simultaneous.SimultaneousRun` (its NLP and scaling are
        used as they were) or the :class:`SolveResult` of a cold-started simultaneous solve (the
        NLP is rebuilt from the problem).
    parameter
        See :func:`parse_parameter` and the module docstring.
    problem
        The solved :class:`Problem`; ``None``: rebuilt from the result (:func:`problem_of`).

    Returns
    -------
    Sensitivity

    Raises
    ------
    InputError
        The result is not a converged simultaneous optimum (not a KKT point), the parameter is
        not part of the problem, or the KKT matrix is singular at that active set.
    """
    result, answer = _converged_result(result_or_run)
    if problem is None:
        problem = problem_of(result)
    par = parse_parameter(parameter)
    theta = par.value(problem)
    full = problem
    members = proportional_members(problem) if result.parameters.get("proportional_cases") else {}
    if members:  # (the NLP was solved without them: see Simultaneous; they are added below)
        kept = [c for c in range(len(problem.loads)) if c not in members]
        problem, result = without_members(problem, members), kept_cases(result, kept)
    form, sc = _formulation(result, answer, problem)
    opt = _optimum(result, problem, form, sc)
    act = _active_set(opt)
    kkt = _kkt_functions(form, opt.nlp)
    lam_g, stationarity, weak, J = _multipliers(kkt, opt, act)
    K, Mp, Gp = _kkt_matrix(kkt, opt, act, lam_g=lam_g, J=J)
    rhs, dlnF = _parameter_rhs(par, opt, act, Mp=Mp, Gp=Gp)
    dz, solve_res, cond = _solve_kkt(K, rhs)
    d_vertices, d_weights, active = _in_si(opt, act, dz=dz, dlnF=dlnF)
    names = tuple(form.case_names)
    if members:
        d_weights, active, names = _with_members(full, members, par, result, d_weights, active)
    return Sensitivity(parameter=par.label, value=theta, d_vertices=d_vertices, d_weights=d_weights,
                       case_names=names, active=active, kkt_residual=stationarity,
                       weakly_active=weak, condition=cond, solve_residual=solve_res)
