"""The simultaneous method: all free positions and every load case's weights at once, with IPOPT.

    minimise    Σ weight_t · term_t(V)  (+ a tiny weight regulariser)
                                   (default objective: Σ ‖v_i − v_i^ref‖² over free vertices)
    subject to  Σ_j w_c,ij (v_j − v_i) = (0, 0, L_c,i)    every load case c, every free vertex
                eps ≤ w_c ≤ w_max                           (scalar or per edge)
                −t/2 ≤ ⟨n_i, v_i − p_i⟩ ≤ t/2               (the problem's :class:`~formulations.Hull`)
                x_i, y_i fixed                              (the problem's :class:`~formulations.FixedTopView`)

The problem is a :class:`formulations.Problem`; it is stated as a
:class:`formulations.nlp.ThrustNetworkProblem` (one weight vector per case, ``x = [X, w_1, …, w_C]``)
and solved by ``ca.nlpsol`` (IPOPT with MUMPS, adaptive μ) in the problem's scale-free units
(:meth:`formulations.Problem.scaled`: lengths / bounding-box diagonal, forces / mean nodal load
of the first case). Constraint rows are divided by ``|L_c,i|``, so IPOPT's ``tol`` bounds the
paper's relative error directly. The hull is hard here: its penalty term, which
:meth:`~formulations.Problem.terms` appends for penalty methods, is left out of the objective.
A case that another carries with its weights times a factor (snow on the self-weight:
:func:`~selfsupport.methods.base.proportional_members`) is left out of the NLP and added to the
result with those scaled weights: it adds no condition, and left in, it made three cases on a
quad mesh a square system, whose rounds IPOPT ends only at an acceptable level.

Loads depend on the geometry (self-weight ∝ area). They are held fixed during one IPOPT run;
then every case's loads are re-estimated from the result (Anderson-accelerated) and the problem
re-solved, warm-started (1–20 IPOPT iterations each), until they change by less than
:data:`LOAD_TOL` (relative, max-norm). IPOPT's positions are only as accurate as its ``tol``, so
once the change is below :data:`POLISH_FROM` (or stops shrinking below :data:`POLISH_ACCEPT`) the
result is polished to round-off:

* one load case, no hull, free top view: the weights are frozen and the positions solved
  exactly from (2)-(3) with loads of their own geometry (:func:`~selfsupport.methods.polish.polish`,
  the staggered method's polish);
* otherwise (several cases — positions cannot be solved from one case's frozen weights and
  still balance the others —, a hull, or a fixed top view, which a free x, y solve would
  break): :func:`polish_joint`, a Gauss–Newton iteration with *minimum-norm* steps on the
  positions (z only for a fixed top view) and every case's weights that are off their bounds,
  active hull rows held, loads re-estimated every step. The steps are of the size of IPOPT's
  residual (~tol), so the optimum moves by that much only.

Either way the final loads are those of the final geometry and every case is in equilibrium to
round-off. On vault / vault-pillar: 8–14 rounds; domes: 2–4.

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

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import casadi as ca
import numpy as np

from formulations import Problem, Term, TermContext, ThrustNetworkProblem, WeightBounds
from formulations.scaling import Scaling
from formulations.terms import HullPenalty, PlanarFaces, Sum
from selfsupport.core.errors import InputError
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.methods import METHODS
from selfsupport.methods.anderson import Anderson
from selfsupport.methods.base import (
    HULL_TOL,
    as_problem,
    case_networks,
    cases_in_equilibrium,
    cases_max_error,
    load_cases_note,
    planarity_report,
    proportional_members,
    short_of_tol,
    term_values,
    with_members,
    without_members,
)
from selfsupport.methods.deadline import ipopt_stop_callback, out_of_time
from selfsupport.methods.polish import HULL_ACTIVE_REL, JOINT_POLISH_TOL, case_load_jacobians, polish_joint
from selfsupport.methods.polish import max_rel_error as _max_rel_error
from selfsupport.methods.polish import polish as _polish
from selfsupport.methods.validate import require_top_view_balance, validate_problem

#: Relative (max-norm) change of the loads between rounds below which they count as
#: consistent with the geometry.
LOAD_TOL = 1e-12
#: Load change below which the IPOPT rounds stop and the heights are solved with the weights
#: fixed (:func:`~selfsupport.methods.polish.polish`): IPOPT's
#: positions are only as accurate as its ``tol``, too coarse to make the loads consistent to
#: :data:`LOAD_TOL` by re-solving; the fixed-weight solve is exact.
POLISH_FROM = 1e-8
#: The polish also starts when the rounds stop contracting (IPOPT's accuracy limits them,
#: ~1e-7 at tol 1e-9 on 1,000+ vertices) below this load change; the objective is then optimal
#: for loads within this of the final ones. Above it the rounds go on (or give up: "stalled").
POLISH_ACCEPT = 1e-6
#: At most this many IPOPT runs with re-estimated loads.
MAX_LOAD_ROUNDS = 30
#: The values of :attr:`SimultaneousOptions.warm_barrier`.
WARM_BARRIERS = ("auto", "low", "default")
#: Depth of the Anderson acceleration of the load fixed point (0: plain re-estimation).
ANDERSON_DEPTH = 3
#: At most this many re-anchorings of the hull's slabs (each slab is the hull's tangent-plane
#: linearization; a vertex that slides along it leaves the curved shell, so after a round that
#: leaves a vertex outside the true hull the slabs move to the vertices' closest points and the
#: rounds go on, warm). A design whose network keeps sliding out is not certified ("stalled").
MAX_HULL_ANCHORINGS = 8
#: Natural weight scale in scaled units: ``1 / ĥ²`` (ĥ = mean edge length / bbox diagonal).
#: Cold-start weights, relative to it (IPOPT's path from larger starts is often long and ends
#: in worse local optima; 0.003–0.01 was consistently good on vault, vault-pillar and domes).
COLD_START_FACTOR = 0.01
#: ``mean((w / natural scale)²)`` is added to the objective with this factor. Without it the
#: objective ignores ``w``, the optimal weights are not unique, and IPOPT drifts towards
#: degenerate optima with weights 10³–10⁶ × typical (seen on vault, vault-pillar); at 1e-6
#: the change of the distance term is ~1e-6 relative.
WEIGHT_REGULARIZATION = 1e-6

#: IPOPT statuses of a load round after which the rounds go on, warm from its point, instead of
#: ending the run: the round met IPOPT's acceptable tolerances but not its own. Only the last
#: round has to be exact. (The remeshed barrel vault of ``tests/test_pq.py``, warm from its
#: staggered network: with OpenBLAS's Haswell kernels IPOPT converged in every round; with its
#: AVX-512 kernels the first round returned "acceptable" and the run ended "stalled" at 4.2e-2.)
ACCEPTABLE_ROUND = frozenset({"Solved_To_Acceptable_Level"})
#: IPOPT ``return_status`` -> our status (selfsupport.core.result.STATUSES); unknown ones are "failed".
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


#: Objective of a problem that leaves it to this method: distance to the reference vertices.
DEFAULT_OBJECTIVE = "vertices"


@dataclass(frozen=True)
class SimultaneousOptions:
    """Settings of one simultaneous solve.

    Attributes
    ----------
    tol
        IPOPT's ``tol`` (the constraint rows are relative residuals).
    max_iter
        IPOPT iteration limit per load round (nlopt: evaluations per round).
    time_limit
        Wall-clock limit [s] of the whole solve (IPOPT's ``max_wall_time`` gets what is left).
    warm_start
        A previous :class:`~selfsupport.core.result.Network` (or :class:`~selfsupport.core.result.SolveResult`,
        then one weight vector per case) on the same mesh: its free positions and active weights
        start IPOPT.
    verbose
        Print IPOPT's log.
    nearest_to_start
        Measure the objective's distances to the warm start's positions instead of the
        reference: the network in equilibrium nearest a start that nearly is one (a projection
        onto the constraints; the staggered method's finish over several load cases). The first
        round then starts IPOPT's barrier low (:attr:`Simultaneous.near_start_defaults`). The
        result's distances are still to the reference.
    warm_barrier
        How IPOPT's barrier starts in the first round of a warm-started solve: ``"low"``
        (:attr:`Simultaneous.low_barrier`: the start kept), ``"default"`` (IPOPT's own: μ from
        0.1, variables pushed 1e-2 into their bounds — a start moved off its bounds first), or
        ``"auto"``: low when the start is this method's optimum (a converged result of it, or
        the network file one wrote: :func:`~selfsupport.io.scenes.design_of`), IPOPT's own
        otherwise (a plain network carries no such record). The stages of a regulariser
        homotopy (``continuation``) after the first keep IPOPT's own unless "low".
    """

    tol: float = 1e-9
    max_iter: int = 3000
    time_limit: float = 120.0
    warm_start: Network | SolveResult | None = None
    verbose: bool = False
    nearest_to_start: bool = False
    warm_barrier: str = "auto"

    @classmethod
    def of(cls, options: "SimultaneousOptions | Mapping[str, Any] | None" = None, **kw: Any) -> "SimultaneousOptions":
        """From an instance, a mapping and/or keywords (keywords win); unknown names are an error."""
        base = dataclasses.asdict(options) if isinstance(options, SimultaneousOptions) else dict(options or {})
        if isinstance(options, SimultaneousOptions):
            base["warm_start"] = options.warm_start  # asdict would deep-copy the network
        base.update(kw)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(base) - known)
        if unknown:
            raise InputError(f"unknown option(s) {unknown} of the simultaneous method; known: {sorted(known)}")
        if base.get("warm_barrier", "auto") not in WARM_BARRIERS:
            raise InputError(f"warm_barrier {base['warm_barrier']!r}: one of {', '.join(WARM_BARRIERS)}")
        return cls(**base)

    def low_barrier_first(self, method: str) -> bool:
        """Whether the first IPOPT round starts its barrier low (see ``warm_barrier``); ``method``:
        the solving method's name (a converged result of it is its optimum)."""
        if self.warm_start is None or self.warm_barrier == "default":
            return False
        if self.warm_barrier == "low":
            return True
        start = self.warm_start
        return isinstance(start, SolveResult) and start.method == method and start.status == "converged"


@dataclass(frozen=True, eq=False)
class IpoptAnswer:
    """IPOPT's own answer in the last load round (before any polish), in scaled units: what a
    KKT check or a sensitivity needs. ``nlp`` is the NLP dict of ``formulation``; ``p`` the
    parameter vector of that round; ``lam_x``, ``lam_g`` CasADi's multipliers
    (``∇f + Jᵀ lam_g + lam_x = 0`` at a KKT point)."""

    formulation: ThrustNetworkProblem
    nlp: dict
    x: np.ndarray
    p: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    f: float
    scaling: Scaling
    raw_status: str


@dataclass(frozen=True, eq=False)
class SimultaneousRun:
    """:meth:`Simultaneous.run`'s answer: the result and IPOPT's last answer (``None`` when no
    round ran, e.g. a time limit before the first)."""

    result: SolveResult
    answer: IpoptAnswer | None


@dataclass(eq=False)
class _Rounds:
    """The state of one run's load rounds, in the problem's scaled units."""

    problem: Problem
    opts: SimultaneousOptions
    deadline: float
    progress: Callable[[dict], None] | None
    form: ThrustNetworkProblem  # the NLP of the next round (its hull's slabs anchored)
    sc: Scaling
    nlp: dict
    x: np.ndarray  # the current iterate
    L_cur: np.ndarray  # (n_cases, n) loads of the next round
    mixer: Anderson
    best: tuple[float, np.ndarray]  # (load change, iterate) of the most load-consistent converged round
    history: list[dict[str, Any]] = field(default_factory=list)
    warm: dict | None = None  # IPOPT's multipliers for the next round
    answer: IpoptAnswer | None = None
    status: str = "failed"
    raw: str = ""  # IPOPT's status of the last round
    message: str = ""
    iterations: int = 0
    polish: bool = False
    x_ok: np.ndarray | None = None  # last iterate of a converged round
    anchorings: int = 0  # re-anchorings of the hull's slabs so far
    polished_change: float | None = None  # the best round's change, when it (not the last) is polished
    unsettled: bool = False  # the rounds stopped without settling the loads (status "stalled")

    @property
    def joint(self) -> bool:
        """Whether the polish is the joint one (several cases, a hull, a fixed top view, planar rows)."""
        return (len(self.problem.loads) > 1 or self.form.hull is not None or self.problem.fixed_top_view
                or self.form.n_planar > 0)

    def loads_at(self, Vs: np.ndarray) -> np.ndarray:
        """Every case's scaled loads at scaled positions ``Vs``."""
        return self.sc.loads_at(self.problem.loads, self.problem.scene.mesh, Vs)

    def record(self, rec: dict[str, Any]) -> None:
        self.history.append(rec)
        if self.progress is not None:
            self.progress(rec)

    def next_round(self, Vs: np.ndarray, L_new: np.ndarray, *, hull: bool = False) -> None:
        """The next round's loads (mixed) and, with ``hull``, the hull's slabs at ``Vs``."""
        C = len(self.problem.loads)
        self.L_cur = self.mixer.next(self.L_cur.ravel(), L_new.ravel()).reshape(C, -1)
        if hull:
            self.form = dataclasses.replace(self.form, hull=self.form.hull.at(Vs))
            self.nlp = self.form.nlp()


class Simultaneous:
    """Method object: positions and weights at once with IPOPT (backend ``"ipopt"``).

    Example
    -------
    >>> from selfsupport.core.shapes import make_shape
    >>> from formulations import Problem
    >>> from selfsupport.core.loads import SelfWeight
    >>> res = Simultaneous().solve(Problem.build(make_shape("dome", n_vertices=100), SelfWeight()))
    >>> res.status, res.max_relative_error < 1e-9
    ('converged', True)
    """

    name = "ipopt"
    backend = "ipopt"
    #: The hull and planar faces are hard rows here (one solve decides); a previous network can
    #: start the solve (declared in the registry).
    capabilities = METHODS["ipopt"].capabilities
    #: IPOPT options (``ipopt.`` prefix added); ``tol``, ``max_iter``, ``max_wall_time`` and
    #: ``print_level`` come from the solve's options.
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

    #: Extra IPOPT options for the first round of a solve nearest its start
    #: (``nearest_to_start``). The start is nearly feasible with many weights on their lower
    #: bound, where IPOPT's defaults (μ from 0.1, variables pushed 1e-2 into their bounds) first
    #: move it away: the barrier starts low and the start is kept. And the objective, the squared
    #: distance to the start, is zero with a zero gradient there, so IPOPT's gradient-based
    #: scaling leaves it tiny beside the barrier terms of the weights on their bound and the steps
    #: are barely held to the start (the line search cuts them to a few percent): its factor
    #: (which leaves the optimum where it is) lets the distance shape the steps. Triangulated cas,
    #: empty + 5% at its highest vertex, from the staggered network at 4.4e-3: factor 1, not
    #: converged after 200 s (0.64, vertices moved ~1 m); converged at one network (moved 2.3 cm)
    #: with 1e2 in 194 s (300 iterations), 1e4 in 42 s (140), 1e6 in 36 s (97). The triangulated 16 × 16 free-edged vault from 5.8e-3:
    #: 137 s with IPOPT's default barrier, 30 s with the low one.
    near_start_defaults: dict[str, Any] = {
        "mu_strategy": "monotone",
        "mu_init": 1e-6,
        "bound_push": 1e-8,
        "bound_frac": 1e-8,
        "obj_scaling_factor": 1e4,
    }
    #: Extra IPOPT options for the first round of a solve warm-started from an IPOPT optimum
    #: (``warm_barrier``): the barrier of :attr:`near_start_defaults`, its objective as stated.
    #: IPOPT's defaults move such a start off its bounds first and may not come back
    #: (``python -m studies.ipopt_warm``): from its own optimum structural ran to the 120 s limit
    #: (max relative error 5.5e3) and twocirc-3 took 568 iterations, where the low barrier
    #: converges in 38 and 35 at the same network; after a point load of 2 % of the self-weight
    #: structural again ran to the limit and twocirc-3 took 2,180, the low barrier 54 and 97. The
    #: low barrier keeps the optimum near the start: after that edit the vault ended 6.6 % farther
    #: from the reference than with IPOPT's own, which converged there too.
    low_barrier: dict[str, Any] = {k: v for k, v in near_start_defaults.items() if k != "obj_scaling_factor"}

    #: Weight of the regulariser ``mean((w / scale)²)`` in the objective; ``None``:
    #: :data:`WEIGHT_REGULARIZATION`. Raising it is what makes IPOPT converge on lilium and
    #: lilium-pillar (README, "Reproducing the paper"), at the price of a slightly different problem.
    weight_regularization: float | None = None
    #: Continuation: regulariser weights solved in turn, each stage warm-started from the last,
    #: before the solve with :attr:`weight_regularization` (empty: one solve).
    continuation: tuple[float, ...] = ()

    def __init__(self, *, weight_regularization: float | None = None, continuation: Sequence[float] = (),
                 **ipopt_options: Any) -> None:
        for v in (() if weight_regularization is None else (weight_regularization,)) + tuple(continuation):
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"a weight regulariser must be a finite number >= 0, got {v!r}")
        self.weight_regularization = None if weight_regularization is None else float(weight_regularization)
        self.continuation = tuple(float(v) for v in continuation)
        self.options = {**self.defaults, **ipopt_options}

    # ------------------------------------------------------------------ public
    def solve(self, problem: Problem | Scene, options: SimultaneousOptions | Mapping[str, Any] | Any = None, *,
              progress: Callable[[dict], None] | None = None, **kw: Any) -> SolveResult:
        """Solve for the thrust network nearest to the reference (see :meth:`run`)."""
        return self.run(problem, options, progress=progress, **kw).result

    def run(self, problem: Problem | Scene, options: SimultaneousOptions | Mapping[str, Any] | Any = None, *,
            progress: Callable[[dict], None] | None = None, loads: Any = None, eps: Any = None, w_max: Any = None,
            objective: Any = None, constraints: Any = (), deadline: float | None = None,
            **option_kw: Any) -> SimultaneousRun:
        """Solve ``problem`` and also return IPOPT's last answer (multipliers included).

        Parameters
        ----------
        problem
            A :class:`formulations.Problem`, or a scene for the short form: then the second
            positional argument is the load model (as in ``solve(scene, SelfWeight())``) and
            ``eps``, ``w_max``, ``objective``, ``constraints`` build the problem
            (:func:`~selfsupport.methods.base.as_problem`).
        options
            :class:`SimultaneousOptions` or a mapping of its fields (a :class:`Problem` only).
        progress
            Called with the history record of every round (``stage`` "ipopt" or "polish").
        deadline
            ``time.perf_counter()`` value at which the solve stops (default: ``time_limit``
            seconds from now): each IPOPT round gets what is left as ``max_wall_time``, the
            polish stops there too.
        **option_kw
            Fields of :class:`SimultaneousOptions` (``tol``, ``max_iter``, ``time_limit``,
            ``warm_start``, ``verbose``).
        """
        t_start = time.perf_counter()
        if not isinstance(problem, Problem):
            if loads is not None and options is not None:
                raise InputError("give the load model once (second argument or loads=)")
            loads, options = (options if loads is None else loads), None
        opts = SimultaneousOptions.of(options, **option_kw)
        deadline = t_start + opts.time_limit if deadline is None else deadline
        problem = as_problem(problem, loads, eps=eps, w_max=w_max, objective=objective, constraints=constraints)
        validate_problem(problem)
        self._check_problem(problem)
        members = proportional_members(problem)
        if members:  # (a case another carries with scaled weights: solved without it, then added)
            kept = [c for c in range(len(problem.loads)) if c not in members]
            inner = self.run(without_members(problem, members),
                             dataclasses.replace(opts, warm_start=kept_cases(opts.warm_start, kept)),
                             progress=progress, deadline=deadline)
            return SimultaneousRun(with_members(problem, inner.result, members, opts.tol), inner.answer)
        if self.continuation:
            return self._continue(problem, opts, deadline, progress, t_start)
        st = self._start(problem, opts, deadline, progress)
        self._load_rounds(st)
        if st.polish:
            self._final_polish(st)
        return self._result(st, t_start)

    # ------------------------------------------------------------------ the run's steps
    def _start(self, problem: Problem, opts: SimultaneousOptions, deadline: float,
               progress: Callable[[dict], None] | None) -> "_Rounds":
        """The NLP at the start (the reference, or the warm start's free positions and weights)."""
        scene = problem.scene
        V = _start_vertices(scene, opts.warm_start)
        if problem.fixed_top_view:  # (the top view the solve keeps: the start's)
            require_top_view_balance(scene, V)
        if opts.nearest_to_start and (opts.warm_start is None or problem.hull_thickness() is not None):
            raise InputError("nearest_to_start needs a warm_start (the network whose nearest equilibrium is sought) "
                             "and no masonry hull (the hull is stated around the reference)")
        # (nearest the start: the objective's reference is the start; the result's is the design's)
        stated = dataclasses.replace(problem, scene=dataclasses.replace(scene, mesh=scene.mesh.with_vertices(V))) \
            if opts.nearest_to_start else problem
        form, sc = self.formulation(stated, V, weight_regularization=self.weight_regularization)
        C, free = len(problem.loads), form.topology.free
        W0 = _start_weights(opts.warm_start, scene, C, sc) if opts.warm_start is not None else \
            np.full((C, form.topology.m), COLD_START_FACTOR * form.weight_scale)  # weight_scale = 1 / h²
        x = form.pack(sc.pos(V), np.clip(W0, form.lower, form.upper))
        # mixed loads must stay downward, and a mixed step no longer than the plain one (against a runaway
        # when the rounds are far from contractive, e.g. under a tight w_max)
        mixer = Anderson(ANDERSON_DEPTH, accept=lambda Lm: bool(np.all(Lm.reshape(C, -1)[:, free] < 0)),
                         limit_step=True)
        return _Rounds(problem=problem, opts=opts, deadline=deadline, progress=progress, form=form, sc=sc,
                       nlp=form.nlp(), x=x, L_cur=form.loads, mixer=mixer, best=(np.inf, x))

    def _load_rounds(self, st: "_Rounds") -> None:
        """IPOPT with the loads of the last round's geometry, until they are consistent with it;
        sets ``st.polish`` when the result is to be polished."""
        for rnd in range(1, MAX_LOAD_ROUNDS + 1):
            remaining = st.deadline - time.perf_counter()
            if remaining <= 0:
                st.status = "time_limit"
                st.message = f"time limit {st.opts.time_limit:g} s reached before load round {rnd}"
                st.polish = st.x_ok is not None
                return
            rec, Vs, L_new = self._round(st, rnd, remaining)
            if not self._go_on(st, rnd, rec, Vs, L_new):
                return

    def _round(self, st: "_Rounds", rnd: int, remaining: float) -> tuple[dict, np.ndarray, np.ndarray]:
        """One IPOPT run at the current loads; its history record, positions and their loads."""
        form, opts = st.form, st.opts
        out = self._solve_round(form, st.nlp, st.x, st.L_cur, st.warm, tol=opts.tol, max_iter=opts.max_iter,
                                remaining=remaining, verbose=opts.verbose,
                                extra=self.near_start_defaults if opts.nearest_to_start
                                else self.low_barrier if opts.low_barrier_first(self.name) else None)
        st.iterations += out["iterations"]
        st.x, st.warm = out["x"], out["warm"]
        if st.warm is not None:
            st.answer = IpoptAnswer(form, st.nlp, st.x.copy(), form.parameters(st.L_cur),
                                    np.asarray(st.warm["lam_x0"]).ravel(), np.asarray(st.warm["lam_g0"]).ravel(),
                                    out["objective"], st.sc, out["raw"])
        Vs, Ws = form.unpack_cases(st.x)
        L_new = st.loads_at(Vs)
        rec = {"round": rnd, "stage": self.backend, "solver_status": out["raw"], "iterations": out["iterations"],
               "seconds": out["seconds"], "objective": out["objective"],
               "load_change": _relative_change(L_new, st.L_cur),
               "max_relative_error": _max_rel_error(form.topology, Vs, Ws, L_new)}
        st.record(rec)
        st.status, st.raw = out["status"], out["raw"]
        return rec, Vs, L_new

    def _go_on(self, st: "_Rounds", rnd: int, rec: dict, Vs: np.ndarray, L_new: np.ndarray) -> bool:
        """Judge a round: another round (True), or the end of the rounds (False, with the status,
        the message and whether to polish set on ``st``)."""
        change, hull = rec["load_change"], st.form.hull
        last = rnd == MAX_LOAD_ROUNDS
        if st.raw in ACCEPTABLE_ROUND and not last and np.all(np.isfinite(st.x)):
            # a round that is not the last only has to bring the loads nearer: the next one, warm
            # from here with the new loads, decides (the rounds' own evidence is what is judged)
            rec["acceptable"] = True
            st.next_round(Vs, L_new)
            return True
        if st.status != "converged":
            self._failed_round(st, rnd)
            return False
        st.x_ok = st.x
        if change < st.best[0]:
            st.best = (change, st.x)
        if hull is not None and self._left_the_hull(st, rec, Vs):
            if st.anchorings == MAX_HULL_ANCHORINGS:
                return False
            # the slabs at the closest points, warm from here (the rows keep their order)
            st.anchorings += 1
            st.next_round(Vs, L_new, hull=True)
            return True
        if change < LOAD_TOL:
            st.message = f"{self.backend} converged; loads consistent with the geometry after {rnd} round(s)"
            st.polish = st.joint  # (every row exact)
            return False
        history = st.history
        stagnating = len(history) > 1 and change > 0.5 * history[-2]["load_change"]
        if change < POLISH_FROM or (stagnating and change < POLISH_ACCEPT):
            st.polish = True
            return False
        if last or (len(history) > 3 and change >= history[-4]["load_change"]):
            self._unsettled(st, rnd, change)
            return False
        st.next_round(Vs, L_new)
        return True

    def _failed_round(self, st: "_Rounds", rnd: int) -> None:
        """A round IPOPT did not solve: the hull's diagnosis, or the last converged round, polished."""
        st.message = f"{self.backend} returned {st.raw} in load round {rnd}"
        if st.status == "infeasible" and st.form.hull is not None:
            st.message = self._hull_diagnosis(st.form, st.x, st.L_cur, st.form.hull, st.sc, tol=st.opts.tol,
                                              remaining=st.deadline - time.perf_counter())
        elif st.x_ok is not None:
            st.x, st.polish = st.x_ok, True
            st.message += "; the last converged round's result is returned, polished"

    def _left_the_hull(self, st: "_Rounds", rec: dict, Vs: np.ndarray) -> bool:
        """Whether the round's network leaves the curved hull (its slabs are tangent planes); past
        :data:`MAX_HULL_ANCHORINGS` re-anchorings that ends the rounds, "stalled"."""
        hull = st.form.hull
        excess = float((np.abs(hull.at(Vs).signed_distance(Vs)) - hull.half_thickness).max(initial=0.0))
        rec["hull_excess"] = excess / hull.half_thickness  # beyond the true hull, relative to t/2
        if excess <= HULL_TOL * hull.half_thickness:
            return False
        if st.anchorings == MAX_HULL_ANCHORINGS:
            st.status = "stalled"
            st.message = (f"the network keeps leaving the curved masonry hull (by up to {excess * st.sc.length:.3g} m "
                          f"beyond t/2 after {st.anchorings} re-anchorings of its tangent slabs): no network "
                          "inside the hull was found; try a larger thickness or a smaller load")
        return True

    def _unsettled(self, st: "_Rounds", rnd: int, change: float) -> None:
        """The rounds stopped contracting: polish the most load-consistent round."""
        best_change, best_x = st.best
        if best_change < POLISH_ACCEPT:  # an earlier round was consistent enough: polish that one
            st.x, st.polish, st.polished_change = best_x, True, best_change
            return
        # The most consistent round is polished, like the last converged round of a run that stopped
        # early: equilibrium for its weights, though optimal only for nearby loads.
        st.status, st.polish, st.unsettled, st.x = "stalled", True, True, best_x
        st.message = (f"the loads do not settle: the geometry changes them by {change:.2e} (relative) "
                      f"after {rnd} {self.backend} round(s); the most consistent round (change {best_change:.2e}) "
                      "is returned")

    def _final_polish(self, st: "_Rounds") -> None:
        """Equilibrium to round-off with loads of the final geometry (module docstring), and the
        message that says what it did."""
        form, problem = st.form, st.problem
        top, mesh0 = form.topology, problem.scene.mesh
        t0 = time.perf_counter()
        V0, Wp = form.unpack_cases(st.x)
        L_before = st.loads_at(V0)
        if st.joint:
            Vp, Wp, k, perr, ok = polish_joint(  # (with the load Jacobian: Newton, not a load lag)
                form, V0, Wp, loads_at=st.loads_at, deadline=st.deadline,
                load_jacobian=case_load_jacobians(problem.loads.models, mesh0, st.sc, top.free))
        else:
            # kept when better than IPOPT's round even above tol: vertices that carry almost no
            # load can hold it there (the evidence check below then names them)
            before = _max_rel_error(top, V0, Wp[0], L_before[0])
            Vp, Lp, k = _polish(top, V0, Wp[0], problem.loads.primary, mesh0, st.sc, deadline=st.deadline)
            perr = _max_rel_error(top, Vp, Wp[0], Lp)
            ok = perr <= JOINT_POLISH_TOL or perr < before
        # the polishes' target is round-off (1e-12); one that stops at its floor above that
        # (planarity rows: 1.7e-12 on a vault remesh) still meets the method's tolerance
        ok = ok or perr <= st.opts.tol
        if ok:
            st.x = form.pack(Vp, Wp)
        st.record({"round": len(st.history) + 1, "stage": "polish",
                   "solver_status": "converged" if ok else "not converged", "iterations": k,
                   "seconds": time.perf_counter() - t0, "objective": None,
                   "load_change": _relative_change(st.loads_at(Vp), L_before),
                   "max_relative_error": _max_rel_error(top, Vp, Wp, st.loads_at(Vp))})
        moved = float(np.abs(Vp - V0).max()) if ok else float("nan")
        self._polish_message(st, ok, f"max relative error {perr:.1e}", k, moved)

    def _polish_message(self, st: "_Rounds", ok: bool, what: str, k: int, moved: float) -> None:
        """The run's status and message after the polish (``what``: its final error, ``k`` steps,
        ``moved``: how far it moved the vertices, scaled)."""
        if st.unsettled and ok:
            st.message += (f", polished into equilibrium for its weights (vertices moved by up to {moved:.1e} of "
                           "the bounding-box diagonal): nearest to the reference only for loads within "
                           f"{st.best[0]:.1e} of its own")
        elif st.unsettled:
            st.message += (" with loads of its own geometry, not in equilibrium (its polish did not reach it: a "
                           "tight w_max, or a design that cannot carry its own weight?)")
        elif st.status != "converged":
            pass  # keep the solver's status and message
        elif not ok and out_of_time(st.deadline):
            st.status = "time_limit"
            st.message = (f"time limit {st.opts.time_limit:g} s reached in the final polish; the last "
                          f"{self.backend} round's network is returned with loads of its own geometry")
        elif not ok:
            st.status = "stalled"
            st.message = (f"the final polish did not reach equilibrium to round-off (still {what} after {k} "
                          f"steps); the last {self.backend} round's network is returned with loads of its own "
                          "geometry")
        else:
            # (the load change of the round polished: the last IPOPT round's, or the best one's)
            rounds = [h for h in st.history if h["stage"] != "polish"]
            switch = rounds[-1]["load_change"] if st.polished_change is None else st.polished_change
            how = ("joint minimum-norm Gauss-Newton correction of positions and free weights of every case"
                   if st.joint else "heights solved with fixed weights")
            st.message = (f"{self.backend} converged in {len(st.history) - 1} load round(s) (load change "
                          f"{switch:.1e} in the round polished); {how} until {what}")

    def _result(self, st: "_Rounds", t_start: float) -> SimultaneousRun:
        """The result: the final network per case, judged by its own evidence (equilibrium of
        every case, planarity), with the run's parameters."""
        problem, form, sc, opts = st.problem, st.form, st.sc, st.opts
        Vs, Ws = form.unpack_cases(st.x)
        first, cases = case_networks(problem, sc, Vs, list(Ws))
        status, message = st.status, st.message
        if status == "converged" and not cases_in_equilibrium(cases, opts.tol):
            # (IPOPT's rows are relative to |L_i| as the metric is, but a vertex whose faces collapsed
            # carries almost no load: 3.7e-4 on a vault with half its supports, "converged")
            status, message = "stalled", short_of_tol(first, opts.tol, cases_max_error(cases))
        _, up = problem.bounds.active(problem.scene)
        planarity = planarity_report(problem, first)
        if planarity is not None and status == "converged" and not planarity["met"]:
            status, message = "stalled", (f"{message}; but faces are not planar: max non-planarity "
                                          f"{planarity['max_nonplanarity']:.2e} > {planarity['tol']:g}")
        if status != "converged":
            message = "; ".join(m for m in (message, load_cases_note(problem)) if m)
        return SimultaneousRun(SolveResult.build(
            first, cases=cases, terms=term_values(problem, first, default=DEFAULT_OBJECTIVE),
            status=status, method=self.name, backend=self.backend, iterations=st.iterations,
            wall_time=time.perf_counter() - t_start, history=tuple(st.history), message=message,
            parameters={"eps": float(np.min(sc.weight_back(form.lower))),
                        "w_max": None if up is None else _jsonable(problem.bounds.upper),
                        "tol": opts.tol, "max_iter": opts.max_iter, "time_limit": opts.time_limit,
                        "objective": _describe_objective(problem),
                        "problem": problem.describe(), "load_cases": list(problem.loads.names),
                        "warm_start": opts.warm_start is not None, "load_rounds": len(st.history),
                        "nearest_to_start": opts.nearest_to_start,
                        "solver_options": dict(self.options), "weight_regularization": form.weight_regularization,
                        "regularizer_share": _regularizer_share(st.answer),
                        **({"planarity": planarity} if planarity is not None else {})}), st.answer)

    def _continue(self, problem: Problem, opts: SimultaneousOptions, deadline: float,
                  progress: Callable[[dict], None] | None, t_start: float) -> SimultaneousRun:
        """The homotopy in the weight regulariser: :attr:`continuation`'s weights, then this
        method's own, each stage a full solve warm-started from the previous stage's network.
        A stage that does not converge ends the run (its result, labelled)."""
        stages: list[dict[str, Any]] = []
        history: list[dict[str, Any]] = []
        start, run = opts.warm_start, None
        for reg in (*self.continuation, self.weight_regularization):
            stage = type(self)(weight_regularization=reg, **self.options)
            # (a later stage starts from the last one's optimum of another regulariser: IPOPT's own
            # barrier, as measured in Table 1, unless the low one is asked for)
            barrier = opts.warm_barrier if start is opts.warm_start or opts.warm_barrier == "low" else "default"
            run = stage.run(problem, dataclasses.replace(opts, warm_start=start, warm_barrier=barrier),
                            progress=progress, deadline=deadline)
            res = run.result
            stages.append({"weight_regularization": res.parameters["weight_regularization"], "status": res.status,
                           "iterations": res.iterations, "seconds": res.wall_time,
                           "regularizer_share": res.parameters.get("regularizer_share"),
                           "max_relative_error": res.max_relative_error, "distance_mean": res.distance_mean})
            history += [{**h, "continuation_stage": len(stages)} for h in res.history]
            if res.status != "converged":
                break
            start = res
        res = run.result
        done = len(stages) == len(self.continuation) + 1 and res.status == "converged"
        note = (f"continuation in the weight regulariser over {len(stages)} stage(s) "
                f"({', '.join(format(st['weight_regularization'], 'g') for st in stages)})")
        if not done:
            note += f"; stage {len(stages)} ended {res.status}"
        result = dataclasses.replace(
            res, wall_time=time.perf_counter() - t_start, iterations=sum(st["iterations"] for st in stages),
            history=tuple(history), message=f"{note}; {res.message}",
            parameters={**res.parameters, "continuation": stages, "warm_start": opts.warm_start is not None})
        return SimultaneousRun(result, run.answer)

    # ------------------------------------------------------------------ formulation
    @staticmethod
    def formulation(problem: Problem, start: np.ndarray, *,
                    weight_regularization: float | None = None) -> tuple[ThrustNetworkProblem, Scaling]:
        """The NLP this method solves for ``problem`` started at ``(n, 3)`` positions ``start``
        [m], and its scaling: lengths / the reference's bounding-box diagonal, forces / the mean
        nodal load of the first case *at the start* (so the default lower bound and the weight
        regulariser, stated in these units, follow the loads). Also used by
        :mod:`selfsupport.methods.sensitivity` to differentiate the optimum."""
        scene = problem.scene
        mesh0 = scene.mesh
        sp_ = problem.scaled(problem.loads.nodal(mesh0, start))
        sc, top = sp_.scaling, sp_.top
        ctx = TermContext(vertices=sc.pos(start), reference=mesh0.with_vertices(sp_.X), free=scene.free)
        total = problem.terms(ctx, scaling=sc, default=DEFAULT_OBJECTIVE)
        parts = total.parts() if total is not None else ()
        hull = next((t for t in parts if isinstance(t, HullPenalty)), None) if problem.hull_thickness() else None
        planar = next((t for t in parts if isinstance(t, PlanarFaces)), None)
        kept = [t for t in parts if not t.constraint]  # the hull and planarity are rows here, not penalties
        objective_term = None if not kept else kept[0] if len(kept) == 1 else Sum(tuple(kept))
        h = float(np.linalg.norm(sp_.X[top.edges[:, 1]] - sp_.X[top.edges[:, 0]], axis=1).mean())
        form = ThrustNetworkProblem(top, sc.pos(start), sp_.L, WeightBounds(sp_.lower, sp_.upper),
                                    objective=objective_term,
                                    weight_regularization=(WEIGHT_REGULARIZATION if weight_regularization is None
                                                           else weight_regularization),
                                    weight_scale=1.0 / h ** 2, hull=hull, planar=planar,
                                    # (the start's top view, as in the staggered method: a warm start's)
                                    fixed_xy=sc.pos(start)[top.free, :2] if problem.fixed_top_view else None,
                                    case_names=problem.loads.names)
        return form, sc

    # ------------------------------------------------------------------ hooks
    def _check_problem(self, problem: Problem) -> None:
        """Refuse problems this backend cannot state (IPOPT states them all)."""

    def _hull_diagnosis(self, form: ThrustNetworkProblem, x: np.ndarray, L: np.ndarray, hull: HullPenalty,
                        sc: Scaling, *, tol: float, remaining: float) -> str:
        """Message for an infeasible hull: the equilibrium network closest to the hull (hull
        penalty minimised, hull rows dropped) and how many free vertices it puts outside."""
        if remaining <= 0:  # (no time left for the search of the closest network)
            return (f"no compressive network in equilibrium within the masonry hull was found ({self.backend} "
                    "reported it infeasible; the time limit left no time to find how far outside it must go)")
        relaxed = dataclasses.replace(form, objective=hull * 1.0, hull=None)
        relaxed.__post_init__()
        out = self._solve_round(relaxed, relaxed.nlp(), x, L, None, tol=tol, max_iter=3000,
                                remaining=remaining, verbose=False)
        Vs, _ = relaxed.unpack_cases(out["x"])
        d = np.abs(hull.signed_distance(Vs)) - hull.half_thickness
        outside = d > HULL_ACTIVE_REL * hull.half_thickness + 1e-12
        t = 2 * hull.half_thickness * sc.length
        if out["status"] != "converged":
            return (f"no compressive network in equilibrium within the masonry hull (t = {t:.4g} m) was found "
                    f"({self.backend} reported it infeasible; the closest-network search ended {out['raw']})")
        return (f"no compressive network in equilibrium stays within the masonry hull (t = {t:.4g} m): "
                f"{int(outside.sum())} of {len(d)} free vertices must leave it (the least-squares closest "
                f"network puts them up to {float(d.max()) * sc.length:.3g} m outside); thicken the shell or "
                "change the design")

    # ------------------------------------------------------------------ backend
    def _solve_round(self, problem: ThrustNetworkProblem, nlp: dict, x: np.ndarray, loads_scaled: np.ndarray,
                     warm: dict | None, *, tol: float, max_iter: int, remaining: float, verbose: bool,
                     extra: Mapping[str, Any] | None = None) -> dict:
        """One IPOPT run with the loads ``(n_cases, n)`` fixed. Returns ``x``, ``warm`` (multipliers
        for the next round), ``raw`` (IPOPT's status), ``status``, ``iterations``, ``objective``,
        ``seconds``. ``extra``: IPOPT options of a cold round (a warm one has :attr:`warm_defaults`)."""
        deadline = time.perf_counter() + remaining
        opts = dict(self.options)
        if warm is None and extra:
            opts.update(extra)
        if warm is not None:
            opts.update(self.warm_defaults)
            opts["mu_init"] = min(opts.get("mu_init", 1.0), 0.01 * tol)
        opts.update({"tol": tol, "max_iter": int(max_iter), "max_wall_time": float(max(remaining, 1e-3)),
                     "print_level": 5 if verbose else 0})
        # IPOPT's max_wall_time counts from its own start, after the solver is built (tens of
        # seconds for several cases on a thousand vertices): the callback holds the deadline itself
        size = {k: int(nlp[k].numel()) if k in nlp else 0 for k in ("x", "g", "p")}
        stop = ipopt_stop_callback(size["x"], size["g"], size["p"])
        stop.deadline = deadline
        solver = ca.nlpsol("simultaneous", "ipopt", nlp,
                           {"ipopt": opts, "print_time": bool(verbose), "error_on_fail": False,
                            "iteration_callback": stop})
        args = problem.solver_args(x, loads_scaled)
        if warm is not None:
            args.update(warm)
        t0 = time.perf_counter()
        sol = solver(**args)
        seconds = time.perf_counter() - t0
        st = solver.stats()
        ret = str(st.get("return_status", "unknown"))
        timed_out = stop.stopped or out_of_time(deadline)  # (the callback stops before an iteration that would overrun)
        status = "time_limit" if ret == "User_Requested_Stop" and timed_out else IPOPT_STATUS.get(ret, "failed")
        return {"x": np.asarray(sol["x"]).ravel(), "warm": {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]},
                "raw": ret, "status": status,
                "iterations": 0 if ret in _NO_ITERATIONS else int(st.get("iter_count", 0) or 0),
                "objective": float(sol["f"]), "seconds": seconds}


def _regularizer_share(answer: IpoptAnswer | None) -> float | None:
    """The weight regulariser's part of IPOPT's last objective value (how far the regularised
    problem is from the stated one), or ``None`` without an answer."""
    if answer is None or not answer.f > 0:
        return None
    form = answer.formulation
    W = form.unpack_cases(answer.x)[1]
    reg = form.weight_regularization * float(np.mean((W / form.weight_scale) ** 2))
    return reg / answer.f


def _start_vertices(scene: Scene, warm_start: Network | SolveResult | None) -> np.ndarray:
    """The reference, with the free vertices of ``warm_start`` (checked to be on the same mesh)."""
    V = scene.mesh.vertices.copy()
    if warm_start is None:
        return V
    net = warm_start.network if isinstance(warm_start, SolveResult) else warm_start
    n = scene.mesh.n_vertices
    if net.mesh.n_vertices != n or net.weights.shape != (scene.mesh.n_edges,):
        raise InputError(f"warm_start network has {net.mesh.n_vertices} vertices / {net.weights.shape[0]} edges, "
                         f"the scene {n} / {scene.mesh.n_edges}; warm-start only from a network on the same mesh")
    V[scene.free] = net.vertices[scene.free]
    return V


def kept_cases(warm_start: Any, kept: list[int]) -> Any:
    """A result of the problem without its proportional cases (a warm start, the NLP's optimum):
    a result with every case's network keeps those of the ``kept`` cases (the first among them);
    anything else as it is."""
    if not isinstance(warm_start, SolveResult) or len(warm_start.cases) <= max(kept, default=0):
        return warm_start
    nets = tuple(warm_start.cases[c] for c in kept)
    return dataclasses.replace(warm_start, network=nets[0][1], cases=nets if len(nets) > 1 else ())


def _start_weights(warm_start: Network | SolveResult, scene: Scene, n_cases: int, sc: Scaling) -> np.ndarray:
    """``(n_cases, m)`` scaled starting weights: one per case of a result with as many cases,
    else the (first) network's weights for every case."""
    act = scene.active_edges
    if isinstance(warm_start, SolveResult):
        nets = [n for _, n in warm_start.case_networks]
        if len(nets) == n_cases:
            return np.stack([sc.weight(n.weights[act]) for n in nets])
        warm_start = warm_start.network
    return np.tile(sc.weight(warm_start.weights[act]), (n_cases, 1))


def _describe_objective(problem: Problem) -> Any:
    """``None`` (the method's default) or ``["name=weight", …]`` (user terms by class name)."""
    if problem.objective is None:
        return None
    return [type(o).__name__ if isinstance(o, Term) else f"{o.name}={float(o.weight):g}" for o in problem.objective]


def _jsonable(v: Any) -> Any:
    a = np.asarray(v, float)
    return float(a) if a.ndim == 0 else a.tolist()


def _relative_change(new: np.ndarray, old: np.ndarray) -> float:
    return float(np.abs(new - old).max() / max(np.abs(new).max(), 1e-300))
