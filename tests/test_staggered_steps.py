"""The staggered method's named parts: the α/β schedule and the stall/creep rules, the typed
state records, the one finish routine (its single-case and joint paths agree), and the size of
the functions in ``selfsupport/methods``."""
from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from formulations import Problem
from selfsupport.core.evidence import closest_points
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.methods.staggered import StaggeredLinearization, StaggeredOptions
from selfsupport.methods.staggered import schedule as sch
from selfsupport.methods.staggered.finish import try_finish
from selfsupport.methods.staggered.run import _Run
from selfsupport.methods.staggered.state import FinishAttempt

from .conftest import independent_check

OPT = StaggeredOptions()


def test_an_accepted_step_shrinks_alpha_by_the_root_of_the_error_reduction():
    s = sch.Schedule.start(OPT)
    s.rejected = 2
    s.accept(0.25, OPT)  # the merit fell to a quarter: α × √0.25 × shrink
    assert s.alpha == pytest.approx(OPT.alpha0 * 0.5 * OPT.shrink, rel=1e-15)
    assert s.beta == pytest.approx(OPT.beta0 * OPT.shrink, rel=1e-15) and s.rejected == 0
    s.accept(4.0, OPT)  # (a ratio above 1 never grows α)
    assert s.alpha == pytest.approx(OPT.alpha0 * 0.5 * OPT.shrink ** 2, rel=1e-15)
    for _ in range(200):
        s.accept(1e-3, OPT)
    assert (s.alpha, s.beta) == (OPT.alpha_min, OPT.beta_min) and s.released(OPT)
    assert s.finish_slack(OPT) == OPT.finish_slack_released


def test_rejections_widen_the_trust_region_and_loosen_the_anchor_from_the_third():
    s = sch.Schedule.start(OPT)
    alphas = []
    for _ in range(OPT.max_rejections + 1):
        assert not s.out_of_steps(OPT)
        s.reject(OPT)
        alphas.append(s.alpha)
    assert s.beta == pytest.approx(OPT.beta0 * 4.0 ** (OPT.max_rejections + 1), rel=1e-12)
    assert alphas[:2] == [OPT.alpha0] * 2 and alphas[2] == OPT.alpha0 * OPT.shrink
    assert s.out_of_steps(OPT) and s.finish_slack(OPT) == OPT.finish_slack


def test_the_halving_rules_fire_exactly_when_the_error_missed_halving_over_their_window():
    w = OPT.stall_window
    missed = [1.0] + [0.7] * (w - 1) + [0.5001]  # not halved over w iterations
    assert sch.fit_stalls(missed, OPT) and not sch.fit_stalls(missed[1:], OPT)  # (the window is w iterations)
    assert not sch.fit_stalls(missed[:-1] + [0.4999], OPT)
    assert not sch.retry_stopped(None)
    assert sch.retry_stopped([1.0, 0.9, 0.8, 0.7, 0.6, 0.55]) and not sch.retry_stopped([1.0, 0.9, 0.8, 0.7, 0.6, 0.5])
    creeping = [1.0] * (OPT.creep_window + 1)
    kw = dict(coupled=False, fixed_xy=False, n_vertices=1000, n_cases=1)
    assert sch.fit_creeps(creeping, OPT, **kw)
    assert not sch.fit_creeps(creeping, OPT, **{**kw, "coupled": True})
    assert not sch.fit_creeps(creeping, OPT, **{**kw, "fixed_xy": True})
    assert not sch.fit_creeps(creeping, replace(OPT, creep_window=0), **kw)
    # the coupled step's system grows with the cases: 2·COUPLE_MAX / (1 + C) vertices at most
    assert sch.coupled_fits(sch.COUPLE_MAX, 1) and not sch.coupled_fits(sch.COUPLE_MAX + 1, 1)
    assert not sch.fit_creeps(creeping, OPT, **{**kw, "n_vertices": sch.COUPLE_MAX, "n_cases": 2})


def test_a_finish_is_due_once_per_halving_and_never_on_a_loose_fit():
    due = dict(fresh=True, last_try=np.inf, warm_try=False, fit_status="optimal", opt=OPT)
    assert sch.finish_due(OPT.finish_try, **due) and not sch.finish_due(1.01 * OPT.finish_try, **due)
    assert not sch.finish_due(0.06, **{**due, "last_try": 0.1}) and sch.finish_due(0.05, **{**due, "last_try": 0.1})
    assert not sch.finish_due(0.01, **{**due, "fit_status": "inexact"})
    assert not sch.finish_due(0.01, **{**due, "fresh": False})
    assert sch.finish_due(0.4, **{**due, "warm_try": True})  # (a warm start's one try, above finish_try)
    assert sch.tightened_rtol(1e-3, OPT) == pytest.approx(1e-4) and sch.tightened_rtol(1e-6, OPT) == 1e-6
    assert sch.damping_after_fallback(0.5) == sch.DAMPING_MAX
    assert sch.damping_after_coupled_step(3e-4, OPT) == pytest.approx(1.5e-4)
    assert sch.damping_after_coupled_step(1.5e-4, OPT) == OPT.coupled_damping


def test_a_finish_attempt_ends_the_iteration_only_when_kept_or_at_its_roundoff_floor():
    assert FinishAttempt(ok=True, error=1e-13).ending == "converged"
    assert FinishAttempt(ok=False, error=1e-8, roundoff_limit={"max_relative_error": 1e-8}).ending == "stalled"
    screened = FinishAttempt(ok=False, screened=1.7)
    assert screened.ending is None and screened.record() == {"ok": False, "screened": 1.7}


@pytest.fixture(scope="module")
def near_equilibrium():
    """A 300-vertex pillar vault's run and an iterate away from the reference, just short of the
    polish (fit error below finish_try)."""
    scene = make_shape("pillar_vault", n_vertices=300)
    problem = Problem.build(scene, SelfWeight(density=2000, thickness=0.1))
    run = _Run(StaggeredLinearization(), problem, StaggeredOptions(), None)
    s = run.start()
    while s.fit.max_rel_error > 0.05:
        Xt, trial, accepted = run.trial_step(s, {})
        run.advance(s, Xt, trial, accepted)
    return scene, run, s


def test_the_finish_routine_polishes_alike_with_the_current_weights_or_the_joint_polish(near_equilibrium):
    """One routine, two polishes: with one load case and a free top view, the Newton polish of
    the current weights and the joint polish (weights moving too, minimum norm) both finish the
    iterate: in equilibrium by the independent check, each moving the vertices by less than the
    fit's max relative error (in diagonals), and as close to the reference as each other (the
    mean-distance ratios within 1%). The joint step, which may move weights, moves positions less."""
    scene, run, s = near_equilibrium
    d_it = run.projection(s)[1]
    plain = try_finish(run, s.X, s.fit, d_it=d_it, slack=10.0)
    run.joint = True
    try:
        joint = try_finish(run, s.X, s.fit, d_it=d_it, slack=10.0)
    finally:
        run.joint = False
    assert plain.ok and joint.ok and plain.screened is not None and joint.screened is None
    assert joint.inside_hull is True and joint.planar is True
    for a in (plain, joint):
        net, _ = run.networks(a.X, a.w)
        assert independent_check(net, tol=1e-9).ok
        d = closest_points(a.X, run.reference)[1]  # (the recorded ratios, recomputed)
        assert a.dist_mean_ratio == pytest.approx(d.mean() / d_it.mean(), rel=1e-12)
        assert a.dist_max_ratio == pytest.approx(d.max() / d_it.max(), rel=1e-12)
    moves = [float(np.linalg.norm(a.X - s.X, axis=1).max()) for a in (plain, joint)]
    assert 0 < moves[1] <= moves[0] <= s.fit.max_rel_error
    assert abs(plain.dist_mean_ratio - joint.dist_mean_ratio) <= 0.01
    # the screen predicts the polished distance (within a factor of two)
    assert 0.5 < plain.screened / plain.dist_mean_ratio < 2.0


def test_a_finish_that_would_cost_closeness_is_refused_though_in_equilibrium(near_equilibrium):
    """The slack is what decides: a polish in equilibrium whose mean distance is not within
    (1 + slack) of the iterate's (a slack of −0.5: half of it) is refused, and the iteration goes on."""
    scene, run, s = near_equilibrium
    d_it = run.projection(s)[1]
    a = try_finish(run, s.X, s.fit, d_it=d_it, slack=-0.5)
    assert a.error <= run.opt.tol and a.dist_mean_ratio > 0.5
    assert not a.ok and a.ending is None and a.roundoff_limit is None
    assert a.record() == {"ok": False, "error": a.error, "screened": a.screened,
                          "dist_mean_ratio": a.dist_mean_ratio, "dist_max_ratio": a.dist_max_ratio}


#: Functions in selfsupport/methods longer than MAX_LINES, each with the reason it stays so (none).
LONG_FUNCTIONS: dict[tuple[str, str], str] = {}
#: Lines of a function from its ``def`` to its end, its docstring not counted (a public function's
#: numpy-style docstring documents every parameter; the rule is about the code a reader follows).
MAX_LINES = 80


def _code_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    first = node.body[0]
    doc = (first.end_lineno - first.lineno + 1
           if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str)
           else 0)
    return node.end_lineno - node.lineno + 1 - doc


def test_no_function_in_the_methods_is_longer_than_80_lines_but_the_named_ones():
    root = Path(__file__).resolve().parents[1] / "selfsupport" / "methods"
    long = set()
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if _code_lines(node) > MAX_LINES:
                    long.add((path.relative_to(root).as_posix(), node.name))
    assert long <= set(LONG_FUNCTIONS), sorted(long - set(LONG_FUNCTIONS))
