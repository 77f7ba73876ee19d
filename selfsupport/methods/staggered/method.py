"""The staggered method's entry point: the plain or the coupled Step 3, or both in turn."""
from __future__ import annotations

import dataclasses
import time
from dataclasses import replace
from typing import Any, Callable, Mapping

from formulations import LoadCases, Planar, Problem
from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.loads import LoadCase
from selfsupport.core.result import SolveResult
from selfsupport.core.scene import Scene
from selfsupport.methods import METHODS
from selfsupport.methods.base import (
    as_problem,
    cases_proportional,
    loads_or_options,
    proportional_members,
    with_members,
    without_members,
)
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.staggered.cases import (
    FINISH_SHARE,
    FIXED_PLAN_SHARE,
    any_weights_carry,
    carry_note,
    continuation,
    finish_note,
    fixed_plan,
    fixed_plan_note,
    ipopt_finish,
)
from selfsupport.methods.staggered.options import StaggeredOptions, _options
from selfsupport.methods.staggered.run import _Run
from selfsupport.methods.staggered.schedule import coupled_fits
from selfsupport.methods.weightfit import WeightFitBackend
from selfsupport.methods.weightfit_backends import make_backend


def _couples_first(problem: Problem) -> str | None:
    """Why the default Step 3 is the coupled one, or None: planar faces (one load case), or
    load cases that are not proportional (no hull, on meshes of at most 2·COUPLE_MAX/(1 + C)
    vertices); both with a free top view."""
    C = len(problem.loads)
    if problem.fixed_top_view:
        return None
    if any(isinstance(c, Planar) for c in problem.constraints):
        return "planar faces" if C == 1 else None
    if (C > 1 and problem.hull_thickness() is None and coupled_fits(problem.scene.mesh.n_vertices, C)
            and not cases_proportional(problem)):
        return "load cases that are not proportional"
    return None


class StaggeredLinearization:
    """The paper's method. ``backend`` names the Step-2 solver (see ``WEIGHT_FIT_BACKENDS``).

    Example
    -------
    >>> from selfsupport.core.loads import SelfWeight
    >>> from selfsupport.core.shapes import make_shape
    >>> res = StaggeredLinearization().solve(make_shape("dome", n_vertices=300), SelfWeight())
    >>> res.status, res.max_relative_error < 1e-9
    ('converged', True)
    """

    name = "staggered"
    capabilities = METHODS["staggered"].capabilities  # (declared in the registry)

    def __init__(self, backend: str | WeightFitBackend = "active-set", **options: Any) -> None:
        self.backend = make_backend(backend) if isinstance(backend, str) else backend
        self.options = _options(StaggeredOptions(), options)

    def solve(self, problem: Problem | Scene, options: Mapping[str, Any] | LoadCase | LoadCases | None = None, *,
              progress: Callable[[dict], None] | None = None, loads: Any = None, eps: Any = None,
              w_max: Any = None, objective: Any = None, warm_start: Any = None, deadline: float | None = None,
              **overrides: Any) -> SolveResult:
        """Solve for the thrust network of ``problem`` (see :mod:`formulations.problem`).

        Parameters
        ----------
        problem
            A :class:`~formulations.Problem`, or a :class:`Scene` (the short form: then ``loads``
            — also accepted as the second positional argument — ``eps``, ``w_max`` [N/m] and
            ``objective`` build the problem, see :func:`~selfsupport.methods.base.as_problem`).
        options
            :class:`StaggeredOptions` fields for this solve only (also as keywords).
        progress
            Called with the history record of each iteration.
        warm_start
            A previous network (:class:`~selfsupport.methods.warm.WarmStart`, a network or a solve
            result): its offset from its reference and its weights are the starting iterate and
            the first fit's warm start (transferred by position when the topology changed).
        deadline
            A ``time.perf_counter()`` value at which the solve stops (status ``"time_limit"``,
            its best network so far); default: ``time_limit`` seconds from now. Every inner
            loop (Step 2, Step 3's CG, the polish, the refinement) honours it.
        """
        loads, options = loads_or_options(options, loads)
        problem = as_problem(problem, loads, eps=eps, w_max=w_max, objective=objective)
        opt = _options(self.options, {**dict(options or {}), **overrides})
        if opt.refine > 0 and len(problem.loads) > 1:  # (the refinement's SQP step carries one weight vector)
            raise InputError(f"the refinement (refine={opt.refine}) handles one load case and this problem has "
                             f"{len(problem.loads)}; drop refine, or solve with --method ipopt, which lowers the "
                             "objective over every case jointly")
        if opt.continuation and opt.coupled is None and len(problem.loads) > 1 and not cases_proportional(problem):
            members = proportional_members(problem)
            if members:  # (a case another carries with scaled weights: solved without it, then added)
                res = self._cases(without_members(problem, members), opt, progress, warm_start, deadline)
                return with_members(problem, res, members, opt.tol)
            return self._cases(problem, opt, progress, warm_start, deadline)
        return self._iterate(problem, opt, progress, warm_start, deadline)

    def _cases(self, problem: Problem, opt: StaggeredOptions, progress: Callable[[dict], None] | None,
               warm_start: Any, deadline: float | None) -> SolveResult:
        """Load cases that are not proportional: the continuation from the cases' envelope
        (:mod:`.cases`); when it is blocked, the iteration over every case at once in the time left,
        and the continuation's measurement of what blocks it in the message of a result that did not
        converge."""
        t0 = time.perf_counter()
        deadline = t0 + opt.time_limit if deadline is None else deadline
        res, rec = continuation(self, problem, opt, progress, warm_start, deadline)
        if res is not None:
            return res
        # (IPOPT's finish, when it may run, keeps its share of the time from the iteration)
        until = deadline - FINISH_SHARE * (deadline - t0) if opt.ipopt_finish else deadline
        other = self._iterate(problem, opt, progress, warm_start, until) if not out_of_time(until) else None
        if other is not None and other.status == "converged":
            return dataclasses.replace(other, wall_time=time.perf_counter() - t0,
                                       parameters={**other.parameters, "load_continuation": rec})
        if other is None:  # (no time left: the envelope's network is no answer)
            other = _Run(self, problem, replace(opt, coupled=False, time_limit=0.0), progress, None, None).solve()
        note, params = None, {**other.parameters, "load_continuation": rec}
        # whether the iteration's plan can carry every case (its share of the time before the finish)
        fp = fixed_plan(other, min(deadline, time.perf_counter() + FIXED_PLAN_SHARE * (deadline - t0))) \
            if len(other.case_networks) > 1 else None
        if fp is not None:
            params["fixed_plan"] = fp
        fin = None
        if opt.ipopt_finish and not out_of_time(deadline):
            try:
                fin, params["ipopt_from_staggered"] = ipopt_finish(problem, other, deadline, progress)
            except SelfSupportError as e:  # (a problem IPOPT cannot state: the staggered result stands)
                params["ipopt_from_staggered"] = {"status": "not run", "reason": str(e)}
                note = f"IPOPT over every case jointly was not run: {e}"
            if fin is not None and fin.status == "converged":
                note = (f"the staggered method over every case ended {other.status} at max relative error "
                        f"{other.max_relative_error:.2e}; IPOPT over every case jointly, started from its network, converged")
                return dataclasses.replace(fin, wall_time=time.perf_counter() - t0, iterations=other.iterations + fin.iterations,
                                           message=f"{fin.message}; {note}",
                                           parameters={**fin.parameters, "load_continuation": rec,
                                                       "ipopt_from_staggered": params["ipopt_from_staggered"],
                                                       "staggered": {"status": other.status,
                                                                     "max_relative_error": other.max_relative_error}})
            if fin is not None:
                note = finish_note(other, params["ipopt_from_staggered"])
        carry = None
        if len(other.case_networks) > 1 and other.status != "converged":
            params["any_weights_carry"] = any_weights_carry(other)
            carry = carry_note(params["any_weights_carry"])
        plan = fixed_plan_note(fp) if fp is not None else None
        return dataclasses.replace(other, wall_time=time.perf_counter() - t0,
                                   message="; ".join(m for m in (other.message, rec.get("message"), carry, plan, note)
                                                     if m),
                                   parameters=params)

    def _iterate(self, problem: Problem, opt: StaggeredOptions, progress: Callable[[dict], None] | None,
                 warm_start: Any, deadline: float | None) -> SolveResult:
        """The staggered iteration over every case at once: the plain or the coupled Step 3, or
        the coupled one first and the plain one when it stalls."""
        why = _couples_first(problem) if opt.coupled is None else None
        if why is None:
            return _Run(self, problem, replace(opt, coupled=bool(opt.coupled)), progress, warm_start, deadline).solve()
        # with the weights held, Step 3 can only trade one case's error against another's, or the
        # planarity penalty against the fit: the coupled step first, and the plain one from the start
        # again when it stalls (the better of the two is returned)
        t0 = time.perf_counter()
        deadline = t0 + opt.time_limit if deadline is None else deadline
        first = _Run(self, problem, replace(opt, coupled=True), progress, warm_start, deadline).solve()
        if first.status != "stalled" or out_of_time(deadline):
            return first
        second = _Run(self, problem, replace(opt, coupled=False), progress, warm_start, deadline).solve()
        better = second.status == "converged" or second.max_relative_error < first.max_relative_error
        chosen, other = (second, first) if better else (first, second)
        note = (f"the coupled Step 3 (tried first with {why}) stalled at max relative error "
                f"{first.max_relative_error:.2e}; the plain one ended {second.status} at {second.max_relative_error:.2e}")
        return dataclasses.replace(chosen, wall_time=time.perf_counter() - t0,
                                   iterations=first.iterations + second.iterations,
                                   message="; ".join(m for m in (chosen.message, note) if m),
                                   parameters={**chosen.parameters, "other_run": {
                                       "coupled": other.parameters.get("coupled"), "status": other.status,
                                       "max_relative_error": other.max_relative_error,
                                       "iterations": other.iterations}})
