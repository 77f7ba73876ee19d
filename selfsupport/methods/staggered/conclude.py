"""The end of a staggered solve: the final polish, the retry when it missed equilibrium, the
optional refinement and weight refit, and the verdict with its message and record."""
from __future__ import annotations

import time
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np

from formulations.scaling import Scaling
from selfsupport.core.evidence import FLOOR_CAP, FLOOR_MARGIN, closest_points, roundoff_message
from selfsupport.core.result import Network, SolveResult
from selfsupport.methods.base import (
    cases_in_equilibrium,
    cases_max_error,
    hull_report,
    load_cases_note,
    nonplanar_faces_note,
    planarity_report,
    short_of_tol,
    term_values,
)
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.staggered.options import DEFAULT_OBJECTIVE
from selfsupport.methods.staggered.state import IterState

if TYPE_CHECKING:
    from selfsupport.methods.staggered.run import _Run

Cases = tuple[tuple[str, Network], ...]


def _join(*parts: str) -> str:
    """Message parts joined by "; ", empty ones left out."""
    return "; ".join(m for m in parts if m)


def _si_bound(sc: Scaling, b: np.ndarray) -> Any:
    """A bound in N/m for the record: a number when it is the same on every edge."""
    v = sc.weight_back(np.asarray(b, float))
    if v.size and np.all(v == v[0]):
        return None if np.isinf(v[0]) else float(v[0])
    return v.tolist()


def final_polish(run: _Run, s: IterState) -> tuple[Network | None, Cases, dict]:
    """The network the iteration ends with: the accepted finish try, or a last fit with (almost)
    no proximal pull polished to exact equilibrium; the last iterate when the polish of a run
    that did not converge made it worse. Returns (network, case networks, the polish's record)."""
    opt, cur = run.opt, s.fit
    if s.status not in ("converged", "interrupted") and not s.at_floor:
        s.message = (f"{s.message or s.status}; vertices hardest to balance: {cur.worst_vertices[:5]} "
                     f"(max relative fit error {cur.max_rel_error:.2e}); try more supports there, a larger "
                     "w_max, a pillar, or more iterations").lstrip("; ")
    t0 = time.perf_counter()
    if s.finished is not None:  # the polish of the current weights was already accepted
        Xp, ws, load_rounds = s.finished.X, s.finished.w, s.finished.rounds
    else:
        # (when the deadline would cut it — a fit's factorizations cannot stop early — keep the
        # current weights; a warm start that fitted already cannot be balanced better than its floor)
        t_fit = cur.t_loads + cur.t_weights
        as_warm = cur is s.warm_fit and cur.fit_iterations == 0 and s.retry_errors is None
        last = None if out_of_time(run.deadline, t_fit) or as_warm else run.fit(s.X, cur.w, opt.prox_w_final)
        ws = last.w if last is not None and last.E <= cur.E else cur.w
        # the polish factors a system of the mesh's size before it can check the deadline: a run
        # the deadline stopped skips it when it would end past the deadline (a fit's time stands in)
        t0 = time.perf_counter()
        Xp, ws, _, load_rounds = run.polish(s.X, ws, stop=s.status != "converged" and out_of_time(run.deadline, t_fit))
    polish_move = float(np.linalg.norm(Xp - s.X, axis=1).max()) if np.all(np.isfinite(Xp)) else np.inf
    net, cases = run.networks(Xp, ws) if np.isfinite(polish_move) else (None, ())
    err = max(n.max_relative_error() for _, n in cases) if net is not None else np.inf
    final = {"iteration": "polish", "t_polish": time.perf_counter() - t0, "load_rounds": load_rounds,
             "polish_max_move": polish_move, "max_rel_error": err, "kept": True, "cpu_s": time.process_time()}
    if s.status != "converged" and not (np.isfinite(err) and err <= min(cur.max_rel_error, 1.0)):
        # from a poor fit the exact solve can land anywhere (even collapse): keep the last
        # iterate, labelled by its status, rather than a "polished" network that is worse
        final["kept"] = False
        net, cases = run.networks(s.X, ws)
        if ws is not cur.w:  # the final fit minimises the sum of squares, not the max error
            alt = run.networks(s.X, cur.w)
            if cases_max_error(alt[1]) < cases_max_error(cases):
                net, cases = alt
        s.message += ("; the final polish did not improve the network, so the last iterate is returned (not in "
                      "equilibrium)")
    elif s.status != "converged" and polish_move > opt.polish_tol:
        s.message += (f"; to reach equilibrium the final polish moved vertices by up to {polish_move:.2e} "
                      "of the bounding-box diagonal, so this network may be far from the design")
    return net, cases, final


def retry_polish(run: _Run, s: IterState, cases: Cases, final: dict) -> bool:
    """The polish of a converged iteration missed equilibrium (its load fixed point stalled,
    e.g. on a kink of the area model), not by rounding alone: iterate on to a 100× tighter fit
    and polish again. True when the iteration resumes (``s`` set up for it)."""
    opt = run.opt
    if not (s.status == "converged" and s.finished is None and not cases_in_equilibrium(cases, opt.tol)
            and s.polish_tol > 1e-9 and s.it < opt.max_iter and not out_of_time(run.deadline)
            and run.roundoff_limit(cases) is None):
        return False
    s.history.append({**final, "kept": False, "retry": True})
    s.polish_tol *= 1e-2
    s.retry_errors = []
    s.status = "iteration_limit"
    return True


def refinement_steps(run: _Run) -> int:
    """The refinement's step limit: ``refine``, else ``refine_concentrated`` where a case
    concentrates a load on a free vertex, else 0 (none)."""
    # (a load on a support goes into the ground: it concentrates nothing on the network)
    concentrated = any(run.free[c.concentrated_at()].any() for c in run.loads.models)
    return run.opt.refine or (run.opt.refine_concentrated if concentrated else 0)


def conclude(run: _Run, s: IterState, net: Network, cases: Cases) -> SolveResult:
    """The solve's result: refinement, weight refit, the verdict and the record."""
    opt = run.opt
    err = cases_max_error(cases)
    steps = refinement_steps(run)
    if steps > 0 and s.status == "converged" and err <= opt.tol:
        net, cases, err = run.refine(net, cases, err, s.history, steps)
        if not s.history[-1].get("applied") and s.history[-1].get("tried"):
            # (say so: with a point load the unrefined network may be the spike under it)
            s.message = _join(s.message, (
                f"the refinement towards the reference kept none of its {s.history[-1]['tried']} trial steps "
                "(none stayed in equilibrium and came closer): the network is the unrefined one"))
    elif steps > 0 and s.status == "stalled" and s.stalled_at is not None and err <= opt.tol and not run.joint:
        net, cases, err = _refine_stalled(run, s, net, cases, err, steps)
    if (s.status == "converged" or s.at_floor) and not cases_in_equilibrium(cases, opt.tol) \
            and not out_of_time(run.deadline) and run.roundoff_limit(cases) is not None:
        net, cases, err = _weight_refit(run, s, net, cases, err)
    return _verdict(run, s, net, cases, err)


def _refine_stalled(run: _Run, s: IterState, net: Network, cases: Cases, err: float,
                    steps: int) -> tuple[Network, Cases, float]:
    """The stall rule stopped a creeping fit and the final polish moved the network away: the
    refinement walks it back in equilibrium, and a network as near the reference as the last
    iterate (within ``finish_slack_released``) is the method's answer, "converged"."""
    opt = run.opt
    net, cases, err = run.refine(net, cases, err, s.history, steps)
    d = float(closest_points(run.sc.pos(net.vertices), run.reference)[1].mean())
    s.history[-1]["stalled_at"], s.history[-1]["refined_to"] = s.stalled_at, d
    if err <= opt.tol and d <= (1 + opt.finish_slack_released) * s.stalled_at:
        s.status, s.message = "converged", (
            f"the fit stopped falling at α's minimum; its polish, refined in equilibrium, is as near the "
            f"reference as the last iterate ({d / s.stalled_at:.2f}× its mean distance)")
    return net, cases, err


def _weight_refit(run: _Run, s: IterState, net: Network, cases: Cases, err: float) -> tuple[Network, Cases, float]:
    """Held above tol by rounding the positions alone: the weights, refit to the positions as
    stored, absorb what the framework allows (:mod:`~selfsupport.methods.weight_refit`)."""
    t0 = time.perf_counter()
    refit = run.refit(cases)
    s.history.append({"iteration": "weight refit", "applied": refit is not None, "max_rel_error_before": err,
                      "t_refit": time.perf_counter() - t0})
    if refit is not None:
        net, cases = refit[0][1], refit
        err = s.history[-1]["max_rel_error"] = cases_max_error(cases)
        s.status, s.at_floor = "converged", False
        s.message = _join(s.message, (
            f"the polish was held at {s.history[-1]['max_rel_error_before']:.2e} by the rounding of its "
            "positions; its weights, refit to the positions as stored, put it in equilibrium"))
    return net, cases, err


def _verdict(run: _Run, s: IterState, net: Network, cases: Cases, err: float) -> SolveResult:
    """The status and message the evidence supports (round-off floor or limit, planarity), and
    the result with its record."""
    opt = run.opt
    floor, balanced = None, cases_in_equilibrium(cases, opt.tol)
    if s.status == "converged" and err > opt.tol and balanced:
        # (forces many times the loads: no positions balance those vertices better in doubles)
        floor = max(float(n.roundoff_floors().max(initial=0.0)) for _, n in cases)
        s.message = (f"max relative error {err:.2e} is above tol {opt.tol:g} but within {FLOOR_MARGIN:g}× the "
                     f"round-off floor of the vertices above it (max floor {floor:.2e}: forces far larger than "
                     f"those vertices' loads) and {FLOOR_CAP:g}; " + s.message).rstrip("; ")
    limit = run.roundoff_limit(cases) if (s.status == "converged" or s.at_floor) and not balanced else None
    if limit is not None:  # (held above tol by rounding alone: more supports or iterations cannot help)
        s.status, s.message = "stalled", _join(roundoff_message(limit, opt.tol), s.message)
    elif s.at_floor:  # (the last iterate was returned instead, and it is off the floor)
        s.message = _join(s.message, "the iteration stopped at a polish held above tol by rounding alone")
    if s.status == "converged" and not balanced:
        s.status, s.message = "stalled", short_of_tol(net, opt.tol, err)
    params = _parameters(run, s, net, floor=floor, limit=limit)
    if s.status != "converged":
        s.message = _join(s.message, load_cases_note(run.problem))
    return SolveResult.build(
        net, cases=cases, status=s.status, method=run.method.name, backend=run.method.backend.name,
        iterations=s.it, wall_time=time.perf_counter() - run.t_start, history=tuple(s.history), message=s.message,
        parameters=params, terms=term_values(run.problem, net, default=DEFAULT_OBJECTIVE))


def _parameters(run: _Run, s: IterState, net: Network, *, floor: float | None, limit: dict | None) -> dict[str, Any]:
    """The result's parameters: the options, bounds, scaling, problem, and the evidence records
    (round-off floor or limit, hull, planarity; an unmet planarity turns "converged" to "stalled")."""
    sc = run.sc
    params: dict[str, Any] = {**asdict(run.opt), "eps": _si_bound(sc, run.lower), "w_max": _si_bound(sc, run.upper),
                              "scaling": asdict(sc), "problem": run.problem.describe(),
                              "load_cases": list(run.loads.names), "warm_start": run.warm_info}
    if floor is not None:  # (converged at the round-off floor, above tol)
        params["roundoff_floor"] = floor
    if limit is not None:  # (stalled: held above tol by rounding alone)
        params["roundoff_limit"] = limit
    hull = hull_report(run.problem, net)
    if hull is not None:
        params["hull"] = hull
    planarity = planarity_report(run.problem, net)
    if planarity is not None:
        params["planarity"] = planarity
        if s.status == "converged" and not planarity["met"]:
            s.status, s.message = "stalled", (
                f"in equilibrium, but faces are not planar: max non-planarity {planarity['max_nonplanarity']:.2e} "
                f"> {planarity['tol']:g} (diagonal distance over mean edge length; "
                f"{nonplanar_faces_note(planarity)}); try a larger planarity "
                "penalty, or a quad mesh along the relative principal directions (selfsupport pq)")
    return params
