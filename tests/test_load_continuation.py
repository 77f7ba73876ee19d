"""Several load cases on one geometry: the continuation from the cases' envelope
(selfsupport/methods/staggered/cases.py) and its report when it is blocked."""
from __future__ import annotations

import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest

from formulations import Problem
from formulations.equilibrium import Topology, weight_matrix
from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.loads import PointLoad, SelfWeight
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import barrel_vault, make_shape
from selfsupport.io.problem import load_spec
from selfsupport.methods.base import proportional_members
from selfsupport.methods.deadline import remaining
from selfsupport.methods.memory import GIB, estimate_solve_bytes
from selfsupport.methods.simultaneous import Simultaneous, kept_cases
from selfsupport.methods.solve import solve
from selfsupport.methods.staggered import StaggeredLinearization, StaggeredOptions, cases
from selfsupport.methods.staggered.cases import BLOCKED_RESIDUAL, continuation
from selfsupport.methods.staggered.run import _Run
from studies import load_cases as study
from studies.common import vault_pillar_layout
from tests.conftest import independent_check

SW = SelfWeight(density=2000.0, thickness=0.1)


def _point_case(scene, vertex: int, share: float) -> PointLoad:
    """A point load of ``share`` of the self-weight at ``vertex``."""
    f = np.zeros(scene.mesh.n_vertices)
    f[vertex] = share * float(SW.nodal(scene.mesh, scene.mesh.vertices).sum())  # (negative: down)
    return PointLoad(f)


def test_two_proportional_cases_converge_exactly_like_one():
    """A heavier material is the self-weight times 1.5: the geometry of the one case, each case
    in equilibrium by the independent checker."""
    scene = make_shape("dome", n_vertices=100)
    one = StaggeredLinearization().solve(scene, SW)
    two = StaggeredLinearization().solve(scene, {"a": SW, "b": SelfWeight(density=3000.0, thickness=0.1)})
    assert one.status == two.status == "converged"
    diag = float(np.linalg.norm(np.ptp(scene.mesh.vertices, axis=0)))
    np.testing.assert_allclose(two.network.vertices, one.network.vertices, rtol=0, atol=1e-9 * diag)
    for _, net in two.case_networks:
        report = independent_check(net, tol=1e-9)
        assert report.ok, report.stdout


def test_a_symmetric_dome_carries_an_apex_load_case_by_the_continuation():
    """Self-weight, and self-weight with 5% of it on the apex of a dome (a triangle mesh):
        the continuation carries both cases on one geometry, each case passes the independent checker,
    and the geometry is nearer the reference than the iteration over both cases at once finds."""
    scene = make_shape("dome", n_vertices=100)
    apex = int(np.argmax(scene.mesh.vertices[:, 2]))
    res = StaggeredLinearization().solve(scene, {"empty": SW, "apex": SW + _point_case(scene, apex, 0.05)})
    rec = res.parameters["load_continuation"]
    assert res.status == "converged" and rec["reached"] == 1.0 and rec["base_refinement"][0]["applied"]
    for _, net in res.case_networks:
        report = independent_check(net, tol=1e-9)
        assert report.ok, report.stdout
    (_, a), (_, b) = res.case_networks
    assert np.abs(a.weights - b.weights).max() > 1e-3 * np.abs(a.weights).max()  # (two weight vectors)
    plain = StaggeredLinearization(continuation=False).solve(
        scene, {"empty": SW, "apex": SW + _point_case(scene, apex, 0.05)})
    assert plain.status == "converged" and res.distance_mean < plain.distance_mean


def _quad_grid_point_case():
    """A quad barrel vault supported all round; self-weight, and self-weight with 5% of it on the
    middle vertex v."""
    scene = barrel_vault(nx=6, ny=6, quads=True)
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    v = int(free[np.argmin(np.linalg.norm(V[free, :2] - V[free, :2].mean(0), axis=1))])
    return Problem.build(scene, {"empty": SW, "point": SW + _point_case(scene, v, 0.05)}), v


def test_a_point_load_on_a_quad_grid_is_blocked_at_the_loaded_vertex_before_any_stage():
    """Inner vertices of a quad grid have four edges: the horizontal equilibrium has as many rows
    as weights, so at the envelope's network no change of the weights the polish moves carries
    the cases' difference (a load at v alone). The first-order test sees it before any stage, at
    the unrefined envelope: no stage is run, both cases' difference fits leave a residual above
    the threshold, and the case without the point load fits worst at v."""
    problem, v = _quad_grid_point_case()
    res, rec = continuation(StaggeredLinearization(), problem, StaggeredOptions(), None, None,
                            time.perf_counter() + 60)
    assert res is None and rec["reached"] == 0.0
    assert rec["blocked_at_start"] and rec["stages"] == []
    assert "base_refinement" not in rec  # (blocked at the unrefined envelope: its refinement is skipped)
    b = rec["blocking"]
    assert b["case"] == "empty" and b["vertices"][0] == v and b["max_relative_error"] > 0.1
    for d in b["difference"].values():
        assert d["max_relative_residual"] > BLOCKED_RESIDUAL
    assert rec["difference_residual"] == max(d["max_relative_residual"] for d in b["difference"].values())
    assert f"vertices [{v}," in rec["message"] and "stages were skipped" in rec["message"]


def _two_iterations(monkeypatch) -> None:
    """Hold the staggered iteration over every case to two iterations (not the envelope's)."""
    iterate = StaggeredLinearization._iterate
    monkeypatch.setattr(StaggeredLinearization, "_iterate", lambda self, problem, opt, *a: iterate(
        self, problem, replace(opt, max_iter=2) if len(problem.loads) > 1 else opt, *a))


def test_a_blocked_continuation_is_reported_on_a_result_that_does_not_converge(monkeypatch):
    """The iteration over both cases converges on the quad grid after the blocked continuation;
    held to two iterations, without IPOPT's finish, it does not, and the result's message carries
    the continuation's report."""
    problem, v = _quad_grid_point_case()
    _two_iterations(monkeypatch)
    res = StaggeredLinearization(ipopt_finish=False).solve(problem)
    assert res.status != "converged" and "ipopt_from_staggered" not in res.parameters
    rec = res.parameters["load_continuation"]
    assert rec["blocking"]["case"] == "empty" and rec["message"] in res.message


def test_ipopt_finishes_a_stalled_iteration_over_every_case(monkeypatch):
    """The same stalled iteration handed to IPOPT over both cases, warm from its network and
    each case's weights: the method's answer is IPOPT's, every case in equilibrium by the
    independent checker to 1e-8, with the staggered numbers it started from on record."""
    problem, v = _quad_grid_point_case()
    _two_iterations(monkeypatch)
    alone = StaggeredLinearization(ipopt_finish=False).solve(problem)
    res = StaggeredLinearization().solve(problem)
    assert alone.status == "iteration_limit"
    fin = res.parameters["ipopt_from_staggered"]
    assert res.status == fin["status"] == "converged" and fin["ipopt_status"] == "Solve_Succeeded"
    assert res.parameters["staggered"]["max_relative_error"] == pytest.approx(alone.max_relative_error, rel=1e-6)
    assert fin["start_distance_mean"] == pytest.approx(alone.distance_mean, rel=1e-6)
    assert "IPOPT over every case jointly, started from its network, converged" in res.message
    for name, net in res.case_networks:
        report = independent_check(net, tol=1e-8)
        assert report.ok, (name, report.stdout)


def test_ipopt_finish_runs_within_the_solves_deadline(monkeypatch):
    """The finish gets the solve's own deadline (IPOPT's max_wall_time and its polish stop
    there), not a fresh time limit; and where IPOPT does not converge either, the result is the
    staggered one with IPOPT's status and the joint count beside its numbers."""
    problem, v = _quad_grid_point_case()
    _two_iterations(monkeypatch)
    seen = {}
    solve = Simultaneous.solve

    def held(self, problem, options=None, *, deadline=None, **kw):
        seen["deadline"], seen["time_limit"] = deadline, options["time_limit"]
        return solve(self, problem, {**options, "max_iter": 1}, deadline=deadline, **kw)

    monkeypatch.setattr(Simultaneous, "solve", held)
    t0 = time.perf_counter()
    res = StaggeredLinearization().solve(problem, time_limit=30.0)
    assert t0 + 30.0 - 1.0 <= seen["deadline"] <= t0 + 30.0 + 1.0
    assert seen["time_limit"] <= seen["deadline"] - t0
    fin = res.parameters["ipopt_from_staggered"]
    assert res.status != "converged" and fin["status"] != "converged" and fin["ipopt_status"] is not None
    assert f"ended {fin['status']} (IPOPT: {fin['ipopt_status']})" in res.message
    assert "for the network nearest it, ended" in res.message and fin["nearest_to_start"]
    assert f"its vertices up to {fin['moved']:.3g} m from it" in res.message
    assert f"{fin['unknowns']} unknowns for {fin['equations']} equations" in res.message


def test_a_stage_starts_only_when_the_last_stages_time_fits_in_the_share(monkeypatch):
    """Stages that take 0.5 s each and never converge (a stand-in for the joint polish, which
    stops at the deadline it is given): no stage starts with less time left in the
    continuation's share than the last one took, and the blocked continuation still reports
    what blocks it (one fit per case, in the solve's time after the share)."""
    scene = make_shape("dome", n_vertices=100)
    apex = int(np.argmax(scene.mesh.vertices[:, 2]))
    problem = Problem.build(scene, {"empty": SW, "apex": SW + _point_case(scene, apex, 0.05)})
    starts, polish = [], _Run.polish

    def slow_polish(self, X, ws, *, fallbacks=True, stop=False, blend=None):
        if blend is None:  # (the envelope's own solve)
            return polish(self, X, ws, fallbacks=fallbacks, stop=stop)
        starts.append(remaining(self.deadline))
        time.sleep(min(0.5, remaining(self.deadline)))
        return X.copy(), ws, self.blended(blend)[0](X), 0

    monkeypatch.setattr(_Run, "polish", slow_polish)
    t0 = time.perf_counter()
    res, rec = continuation(StaggeredLinearization(), problem, StaggeredOptions(), None, None,
                            t0 + 3.0 / cases.SHARE)
    assert res is None and rec["reached"] == 0.0 and len(starts) == len(rec["stages"]) >= 1
    for left, last in zip(starts[1:], rec["stages"][:-1]):
        assert left >= last["t_stage"]
    assert rec["stopped"] == "time" and rec["blocking"]["case"] in ("empty", "apex")
    assert "share of the time" in rec["message"]


def test_the_joint_count_of_a_supported_quad_grid():
    """A quad grid of nx × ny cells supported all round: (nx−1)(ny−1) free vertices and
    2·nx·ny − nx − ny edges that are not between two supports, so C cases leave
    3·n_free + C·m − 3·C·n_free = (3 − C)·n_free + C·(nx + ny − 2) unknowns beyond the equations:
    with three cases only the boundary's 3·(nx + ny − 2)."""
    nx, ny = 6, 8
    scene = barrel_vault(nx=nx, ny=ny, quads=True)
    n_free = (nx - 1) * (ny - 1)
    for C in (1, 2, 3):
        loads = {f"c{k}": SelfWeight(density=2000.0 * (k + 1), thickness=0.1) for k in range(C)}
        count = cases.joint_freedom(Problem.build(scene, loads))
        assert count["free_vertices"] == n_free and count["edges"] == 2 * nx * ny - nx - ny
        assert count["freedom"] == count["unknowns"] - count["equations"] == (3 - C) * n_free + C * (nx + ny - 2)


def test_the_refinement_refuses_several_load_cases(tmp_path):
    """The refinement's SQP step carries one weight vector: asked for with two cases, the solve
    refuses in one line that names the way out (IPOPT), in the API and on the command line
    (exit 2, nothing written)."""
    scene = make_shape("dome", n_vertices=60)
    apex = int(np.argmax(scene.mesh.vertices[:, 2]))
    loads = {"empty": SW, "apex": SW + _point_case(scene, apex, 0.05)}
    with pytest.raises(InputError, match="handles one load case .* --method ipopt"):
        StaggeredLinearization(refine=3).solve(scene, loads)
    toml = tmp_path / "cases.toml"
    toml.write_text('[cases.empty]\n\n[cases.hoist]\npoint_loads = { "0" = 3000.0 }\n')
    out = tmp_path / "net.json"
    p = subprocess.run([sys.executable, "-m", "selfsupport", "solve", "shape:dome:60", "--load-cases", str(toml),
                        "--method", "staggered", "--option", "refine=3", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and "handles one load case" in lines[0], p.stderr
    assert "Traceback" not in p.stderr and not out.exists()


def test_the_load_cases_study_states_the_issues_cases(tmp_path):
    """The study's TOML, read back by the CLI's reader, gives the study's cases: the self-weight
    alone, the self-weight plus 80 kg/m² (a factor on the self-weight at every vertex, so
    proportional to the first), and the self-weight plus the point load at its one vertex."""
    scene = make_shape("dome", n_vertices=60)
    v, weight = 7, 1000.0
    cases = {"empty": {}, "snow": {"uniform_mass": 80.0}, "point": {"point_loads": {v: round(0.05 * weight, 2)}}}
    toml = tmp_path / "cases.toml"
    toml.write_text(study.toml_text(cases))
    L = load_spec(load_cases=toml).cases(scene.mesh.n_vertices)
    nodal = {k: c.nodal(scene.mesh, scene.mesh.vertices) for k, c in L.items()}
    assert list(nodal) == ["empty", "snow", "point"]
    ratio = nodal["snow"] / nodal["empty"]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)  # (proportional: a factor on the self-weight)
    diff = nodal["point"] - nodal["empty"]
    assert diff[v] == pytest.approx(-50.0) and np.count_nonzero(diff) == 1


def _pyramid_cases(height: float) -> SolveResult:
    """One free apex over a unit square of four supports at ``height`` above them; case "a"
    loads it with 1 N, case "b" with 3 N (weights of no account here)."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, height]], float)
    mesh = PolyMesh.from_faces(V, [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    supports = np.array([True, True, True, True, False])
    nets = [Network(mesh=mesh, weights=np.ones(mesh.n_edges), loads=np.array([0, 0, 0, 0, -f]), supports=supports)
            for f in (1.0, 3.0)]
    return SolveResult.build(nets[0], cases=(("a", nets[0]), ("b", nets[1])), status="stalled", method="test",
                             backend="test", iterations=0, wall_time=0.0)


def test_any_weights_carry_a_load_difference_at_a_raised_apex_but_not_at_a_flat_one():
    """The apex's four edges carry any vertical load once it is raised: the difference of 2 N is
    carried to round-off. At the supports' height its edges are horizontal, no weights carry a
    vertical load, and the relative residual is the whole difference over case b's load, 2/3;
    the note then says the geometry blocks."""
    raised = cases.any_weights_carry(_pyramid_cases(0.5))
    assert raised["b"]["from"] == "a" and raised["b"]["max_relative_residual"] < 1e-12
    assert "bounds, or the iteration's reach, block it" in cases.carry_note(raised)
    flat = cases.any_weights_carry(_pyramid_cases(0.0))
    assert flat["b"]["max_relative_residual"] == pytest.approx(2.0 / 3.0, rel=1e-12) and flat["b"]["vertices"] == [4]
    assert "the geometry blocks" in cases.carry_note(flat) and "vertices [4]" in cases.carry_note(flat)


def test_a_stalled_result_over_several_cases_says_whether_any_weights_carry_them(monkeypatch):
    """The quad grid's two-iteration result, without the IPOPT finish: its message carries the
    measurement of :func:`any_weights_carry` at its network, the same as recomputed from it."""
    problem, v = _quad_grid_point_case()
    _two_iterations(monkeypatch)
    res = StaggeredLinearization(ipopt_finish=False).solve(problem)
    carry = res.parameters["any_weights_carry"]
    again = cases.any_weights_carry(res)
    assert carry["point"]["max_relative_residual"] == pytest.approx(again["point"]["max_relative_residual"], abs=1e-12)
    assert cases.carry_note(carry) in res.message


def test_a_finish_ipopt_cannot_state_leaves_the_staggered_result(monkeypatch):
    """IPOPT refusing the problem (an input error of its own) does not lose the staggered
    result: it is returned with IPOPT's reason in its message and record."""
    problem, v = _quad_grid_point_case()
    _two_iterations(monkeypatch)

    def refuse(self, *a, **kw):
        raise InputError("no IPOPT here")

    monkeypatch.setattr(Simultaneous, "solve", refuse)
    res = StaggeredLinearization().solve(problem)
    assert res.status == "iteration_limit" and res.method == "staggered"
    assert res.parameters["ipopt_from_staggered"] == {"status": "not run", "reason": "no IPOPT here"}
    assert "IPOPT over every case jointly was not run: no IPOPT here" in res.message


def test_the_ipopt_finish_is_left_out_where_its_memory_estimate_exceeds_the_limit(tmp_path):
    """Two cases on a 100-vertex dome under --max-memory 0.17 GiB: the staggered solve's estimate
    fits (about 0.16 GiB), IPOPT's (about 0.2 GiB) does not, so the solve runs without the
    finish; with room for both, the finish stays on."""
    scene = make_shape("dome", n_vertices=100)
    n = scene.mesh.n_vertices
    assert estimate_solve_bytes(n, "staggered", 2) < 0.17 * GIB < estimate_solve_bytes(n, "ipopt", 2)
    apex = int(np.argmax(scene.mesh.vertices[:, 2]))
    path = tmp_path / "cases.toml"
    path.write_text(study.toml_text({"empty": {}, "hoist": {"point_loads": {apex: 500.0}}}))
    tight = solve(scene, method="staggered", load_cases=path, max_memory=0.17, max_iter=1)
    roomy = solve(scene, method="staggered", load_cases=path, max_memory=4.0, max_iter=1)
    assert tight.parameters["ipopt_finish"] is False and roomy.parameters["ipopt_finish"] is True


def test_a_case_proportional_to_another_is_carried_by_its_scaled_weights():
    """Empty, snow (80 kg/m² on the self-weight of 2000 kg/m³ × 0.1 m: the empty loads × 1.4 at
    any geometry) and a point case on a dome: the snow case is solved as the empty one's weights
    times 1.4, so the joint problem is the two other cases'; every case passes the independent
    checker, the snow network's weights are the empty one's × 1.4 and its loads the empty one's ×
    1.4 at the common geometry."""
    scene = make_shape("dome", n_vertices=100)
    apex = int(np.argmax(scene.mesh.vertices[:, 2]))
    problem = Problem.build(scene, {"empty": SW, "snow": SW + SelfWeight(density=80.0, thickness=1.0),
                                    "point": SW + _point_case(scene, apex, 0.05)})
    assert proportional_members(problem) == {1: (0, pytest.approx(1.4, rel=1e-12))}
    res = StaggeredLinearization().solve(problem)
    assert res.status == "converged" and [n for n, _ in res.case_networks] == ["empty", "snow", "point"]
    nets = dict(res.case_networks)
    np.testing.assert_allclose(nets["snow"].weights, 1.4 * nets["empty"].weights, rtol=1e-12)
    np.testing.assert_allclose(nets["snow"].loads, 1.4 * nets["empty"].loads, rtol=1e-12)
    assert res.parameters["proportional_cases"]["snow"]["of"] == "empty"
    for name, net in res.case_networks:
        report = independent_check(net, tol=1e-9)
        assert report.ok, (name, report.stdout)


def test_ipopt_over_three_cases_carries_the_proportional_one_by_scaled_weights():
    """The simultaneous method leaves a case another carries with scaled weights out of its joint
    problem, as the staggered method does. On a 100-vertex quad pillar vault with empty, snow (the
    empty loads × 1.4) and 5% of the self-weight at the highest free vertex, the snow case's
    weights as IPOPT's own unknowns made the count square: every round ended at an acceptable
    level and the solve at its 60 s limit, worst case 0.23. Without them it converges, the snow
    weights are the empty ones × 1.4, and every case passes the independent checker."""
    scene = make_shape("pillar_vault", n_vertices=100)
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    top = int(free[np.argmax(V[free, 2])])
    problem = Problem.build(scene, {"empty": SW, "snow": SW + SelfWeight(density=80.0, thickness=1.0),
                                    "point": SW + _point_case(scene, top, 0.05)})
    res = Simultaneous().solve(problem, {"time_limit": 60})
    assert res.status == "converged" and [n for n, _ in res.case_networks] == ["empty", "snow", "point"]
    assert res.parameters["proportional_cases"]["snow"]["of"] == "empty"
    nets = dict(res.case_networks)
    np.testing.assert_allclose(nets["snow"].weights, 1.4 * nets["empty"].weights, rtol=1e-12)
    for name, net in res.case_networks:
        report = independent_check(net, tol=1e-9)
        assert report.ok, (name, report.stdout)
    # a warm start with every case's network gives the joint problem those of the cases it keeps
    kept = kept_cases(res, [0, 2])
    assert [n for n, _ in kept.case_networks] == ["empty", "point"] and kept.network is nets["empty"]


def test_no_case_is_scaled_where_the_bounds_would_not_hold_it():
    """With an upper bound, or a lower bound that allows tension, scaled weights may leave the
    bounds: no case is taken for a member then; nor a lighter case (its scaled weights would go
    below ε)."""
    scene = make_shape("dome", n_vertices=60)
    loads = {"empty": SW, "snow": SW + SelfWeight(density=80.0, thickness=1.0), "point": SW + _point_case(scene, 5, 0.05)}
    assert proportional_members(Problem.build(scene, loads))
    assert not proportional_members(Problem.build(scene, loads, w_max=1e6))
    assert not proportional_members(Problem.build(scene, loads, eps=-1.0))
    lighter = {"snow": SW + SelfWeight(density=80.0, thickness=1.0), "empty": SW, "point": SW + _point_case(scene, 5, 0.05)}
    assert not proportional_members(Problem.build(scene, lighter))


@pytest.mark.slow
def test_three_cases_on_a_free_edged_vault_converge_with_the_snow_case_scaled():
    """Empty, snow and 5% of the self-weight at the highest free vertex on a 100-vertex pillar
    vault (quads, free edges between the pillars): solved with the snow case as its own, the
    staggered method stalled (6.6e-3 after 60 s); carried by the empty case's weights × 1.4 the
    joint problem is the two other cases', which converges, every case by the independent
    checker."""
    scene = make_shape("pillar_vault", n_vertices=100)
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    top = int(free[np.argmax(V[free, 2])])
    problem = Problem.build(scene, {"empty": SW, "snow": SW + SelfWeight(density=80.0, thickness=1.0),
                                    "point": SW + _point_case(scene, top, 0.05)})
    res = StaggeredLinearization(ipopt_finish=False).solve(problem, {"time_limit": 60})
    assert res.status == "converged" and "snow" in res.parameters["proportional_cases"]
    for name, net in res.case_networks:
        report = independent_check(net, tol=1e-8)
        assert report.ok, (name, report.stdout)


def _free_edged_quad_vault(n: int = 10, span: float = 3.0):
    """An n × n quad vault on three vertices at each corner and a 2 × 2 pillar in the middle (the
    paper's vault-pillar layout): at n = 10, 168 edges for 84 free vertices, as many edges as
    horizontal equations. Self-weight, and self-weight with 5% of it at the highest free vertex."""
    t = np.linspace(-0.5, 0.5, n) * span
    x, y = np.meshgrid(t, t)
    V = np.column_stack([x.ravel(), y.ravel(), 1.0 - 0.15 * (x ** 2 + y ** 2).ravel()])
    sup, quads = vault_pillar_layout(n)
    scene = Scene(PolyMesh.from_faces(V, quads), sup, name="free-edged quad vault")
    free = np.flatnonzero(~sup)
    v = int(free[np.argmax(V[free, 2])])
    return scene, Problem.build(scene, {"empty": SW, "point": SW + _point_case(scene, v, 0.05)})


def _plan_matrix(scene, X: np.ndarray) -> np.ndarray:
    """The x and y rows of the equilibrium matrix at ``X`` (dense)."""
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)
    A = weight_matrix(top, X).toarray()
    return A[np.arange(A.shape[0]) % 3 != 2]


def test_a_regular_grid_plan_has_one_self_stress_per_grid_line():
    """A quad barrel vault's plan is a tensor grid supported all round: in plan a vertex with two
    straight grid lines through it balances only equal weights on each line, so the horizontal
    self-stresses are one constant weight per inner grid line, (nx − 1) + (ny − 1) of them, and
    that is also edges less horizontal equations (the plan matrix has full row rank)."""
    nx, ny = 5, 7
    scene = barrel_vault(nx=nx, ny=ny, quads=True)
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)
    tv = cases.top_view_self_stresses(top, scene.mesh.vertices)
    assert tv["self_stresses"] == (nx - 1) + (ny - 1) == tv["edges"] - tv["horizontal_equations"]
    assert tv["next_singular"] > 1e-3


def test_a_free_edged_quad_plan_carries_only_proportional_cases_over_its_one_self_stress():
    """The free-edged quad vault has as many edges as horizontal equations. Its cases' envelope
    solved alone has a plan with exactly one self-stress (its own weights): over that plan no
    heights carry two cases that are not proportional, and the blocked continuation says so.
    Self-weight alone there is carried (its loads are the envelope's up to the point load's
    share), so the statement is about the cases' difference, not about the plan standing."""
    scene, problem = _free_edged_quad_vault()
    res, rec = continuation(StaggeredLinearization(), problem, StaggeredOptions(), None, None,
                            time.perf_counter() + 60)
    tv = rec["top_view"]
    assert res is None and rec["blocked_at_start"]
    assert tv["edges"] == tv["horizontal_equations"] == 168 and tv["self_stresses"] == 1
    assert tv["next_singular"] > 1e4 * cases.SELF_STRESS_RTOL
    assert "horizontal self-stresses" in rec["message"] and "are one-dimensional (168 edges for 168" in rec["message"]
    # the linear program at that geometry agrees: no weights of either sign carry the blocked case
    assert rec["blocking"]["tension"]["status"] == "no weights"
    assert f"no weights of either sign carry case {rec['blocking']['case']!r}" in rec["message"]
    # the plan of a network in equilibrium for one case: its own weights span the self-stresses
    one = StaggeredLinearization().solve(scene, SW)
    H = _plan_matrix(scene, one.network.vertices)
    _, s, Vt = np.linalg.svd(H)
    w = one.network.weights[scene.active_edges]
    assert s[-1] <= cases.SELF_STRESS_RTOL * s[0] < s[-2]
    assert abs(Vt[-1] @ w) / np.linalg.norm(w) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.slow
def test_two_cases_on_a_free_edged_quad_plan_stand_on_a_plan_with_two_self_stresses():
    """What the note asks for, on a solve that finds it: the iteration over both cases converges
    on the free-edged quad vault (every case by the independent checker), and its plan has two
    self-stresses, spanned by the two cases' weights (which are not proportional)."""
    scene, problem = _free_edged_quad_vault()
    res = StaggeredLinearization(ipopt_finish=False).solve(problem, {"time_limit": 60})
    assert res.status == "converged"
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)
    assert cases.top_view_self_stresses(top, res.network.vertices)["self_stresses"] == 2
    H = _plan_matrix(scene, res.network.vertices)
    W = np.array([net.weights[scene.active_edges] for _, net in res.case_networks])
    assert np.abs(H @ W.T).max() <= 1e-12 * np.abs(H).max() * np.abs(W).max()
    assert np.linalg.svd(W / np.linalg.norm(W, axis=1, keepdims=True), compute_uv=False)[1] > 1e-3
    for name, net in res.case_networks:
        report = independent_check(net, tol=1e-8)
        assert report.ok, (name, report.stdout)


def test_the_one_self_stress_of_a_quad_plan_reaches_the_loaded_vertex_but_carries_no_point_load_there():
    """At the single-case network of the free-edged quad vault the plan's self-stresses are its
    own weights' multiples: they reach the loaded vertex (ring 0 reach = its largest weight over
    the largest anywhere, not zero), and their vertical loads are the self-weight's multiples,
    so the least-squares point load they carry is the projection on the self-weight ``b``
    (relative rows): residual at the vertex ``1 − b_v² / |b|²`` of the difference there, and
    ``|b_i| |b_v| / |b|²`` elsewhere."""
    from studies import plan_self_stresses as ps

    scene, problem = _free_edged_quad_vault()
    net = StaggeredLinearization().solve(scene, SW).network
    top = ps.network_topology(net)
    N = ps.self_stress_basis(top, net.vertices)
    w = net.weights[scene.active_edges]
    assert N.shape[1] == 1 and abs(N[:, 0] @ w) / np.linalg.norm(w) == pytest.approx(1.0, abs=1e-9)
    free = np.flatnonzero(~scene.supports)
    v = int(free[np.argmax(net.vertices[free, 2])])
    rings = ps.edge_rings(top, v)
    assert np.count_nonzero(rings == 0) == np.count_nonzero((top.edges == v).any(axis=1))
    assert ps.reach_by_ring(N, rings, 0)[0] == pytest.approx(w[rings == 0].max() / w.max(), rel=1e-6)
    P = -0.05 * float(-net.loads[free].sum())
    fit = ps.fixed_plan_fit(top, net.vertices, N, v, P, net.loads)
    point = net.loads[free].copy()
    fv = int(top.free_index[v])
    point[fv] += P
    b = net.loads[free] / np.abs(point)
    assert fit["at_vertex"] == pytest.approx(1.0 - b[fv] ** 2 / (b @ b), rel=1e-6)
    assert fit["elsewhere"] == pytest.approx(np.abs(np.delete(b, fv)).max() * abs(b[fv]) / (b @ b), rel=1e-6)
    assert fit["at_vertex"] > 0.9


def test_a_triangulated_plan_carries_a_point_load_over_its_self_stresses_and_a_quad_grid_does_not():
    """A barrel vault supported all round, at the networks of its self-weight alone: split into
    triangles, its plan has more self-stresses (77) than free vertices (48), and their vertical
    loads carry the point load at the crown alone (residual at round-off); as a quad grid its
    self-stresses are one per grid line (14), each loading its whole line, and they leave
    nearly all of the point load there."""
    from studies import plan_self_stresses as ps

    fits, compression = {}, {}
    for quads in (True, False):
        scene = barrel_vault(nx=7, ny=9, quads=quads)
        res = StaggeredLinearization().solve(scene, SW)
        net = res.network
        top = ps.network_topology(net)
        N = ps.self_stress_basis(top, net.vertices)
        assert N.shape[1] == top.m - 2 * top.n_free  # (the plan matrix has full row rank)
        free = np.flatnonzero(~scene.supports)
        v = int(free[np.argmax(net.vertices[free, 2])])
        P = -0.05 * float(-net.loads[free].sum())
        fits[quads] = ps.fixed_plan_fit(top, net.vertices, N, v, P, net.loads)
        assert N.shape[1] > top.n_free if not quads else N.shape[1] == 6 + 8
        compression[quads] = ps.measure(net, v, P, 1, lower=res.parameters["eps"])["compression"]["status"]
    assert fits[False]["at_vertex"] < 1e-12 and fits[False]["elsewhere"] < 1e-12
    assert fits[True]["at_vertex"] > 0.9
    # the linear program agrees: over the triangulated plan compression carries the point case at
    # the self-weight's geometry; over the quad plan no weights of either sign do
    assert compression == {False: "carried", True: "no weights"}


def _pyramid_topology(height: float) -> tuple[Topology, np.ndarray]:
    """One free apex over a unit square of four supports at ``height`` above them (positions)."""
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, height]], float)
    mesh = PolyMesh.from_faces(V, [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    supports = np.array([True, True, True, True, False])
    active = ~(supports[mesh.edges[:, 0]] & supports[mesh.edges[:, 1]])
    return Topology.build(5, mesh.edges[active], supports), V


@pytest.mark.parametrize("load, lower, share", [
    (-1.0, 0.0, None),  # a downward load on a raised apex: compression carries it
    (1.0, 0.0, 1.0),  # upward: the four spokes' weights sum to −1/h, all tension: ℓ/h in total
    (1.0, 0.1, 1.0 + 4 * 0.1 * 0.5),  # ... and each spoke short of ε = 0.1 besides: ℓ (1/h + 4ε)
    (-1.0, 1.0, 4 * 1.0 * 0.5 - 1.0),  # downward, but ε = 1 asks Σw ≥ 4 where 1/h = 2 balances: ℓ (4ε − 1/h)
])
def test_least_tension_at_a_fixed_apex_is_the_analytic_shortfall(load, lower, share):
    """The apex at h = 1/2 over the unit square: vertical equilibrium −h Σ w = L fixes the
    spokes' sum, horizontal equilibrium pairs opposite spokes, so the least total force by which
    the spokes (length ℓ = √(1/2 + h²)) fall short of a lower bound ε is ℓ · max(0, 4ε + L/h)
    (L up positive), over the total load |L| = 1; zero shortfall is "carried"."""
    top, V = _pyramid_topology(0.5)
    out = cases.least_tension(top, V, np.array([0, 0, 0, 0, load]), lower, np.inf)
    ell = np.sqrt(0.5 + 0.25)
    if share is None:
        assert out["status"] == "carried"
    else:
        assert out["status"] == "tension" and out["tension_share"] == pytest.approx(ell * share / 0.5, rel=1e-9)
        assert all(4 in e for e in out["tension_edges"])


def test_least_tension_on_a_flat_apex_finds_no_weights_of_either_sign():
    """At the supports' height the spokes are horizontal: no weights carry a vertical load."""
    top, V = _pyramid_topology(0.0)
    out = cases.least_tension(top, V, np.array([0, 0, 0, 0, -1.0]), 0.0, np.inf)
    assert out["status"] == "no weights" and not out["bounded_above"]


def test_least_tension_names_an_upper_bound_that_leaves_no_weights():
    """The apex at h = 1/2 under a unit load needs spokes summing to 1/h = 2, opposite ones
    equal, so two neighbouring spokes sum to 1: with every weight at most 0.4 no weights carry
    it, and the verdict says an upper bound was in force; at most 0.6 they do (1/2 each)."""
    top, V = _pyramid_topology(0.5)
    L = np.array([0, 0, 0, 0, -1.0])
    out = cases.least_tension(top, V, L, 0.0, 0.4)
    assert out["status"] == "no weights" and out["bounded_above"]
    assert cases.least_tension(top, V, L, 0.0, 0.6)["status"] == "carried"


def test_a_blocked_continuation_reports_the_tension_its_geometry_needs(monkeypatch):
    """Half the self-weight at a dome's apex, the continuation's stages held where they start
    (a stand-in for a polish that makes no progress): at the envelope's network, shaped for the
    point load, the empty case's fit within the bounds is far from equilibrium with weights the
    polish holds on the lower bound (the report counts them as the polish does and names those
    the fit pushes against it), and the linear program finds no weights within the bounds that
    carry it there: the report says how much tension they would need. At the empty case's own
    network the same program finds it carried."""
    scene = make_shape("dome", n_vertices=100)
    apex = int(np.argmax(scene.mesh.vertices[:, 2]))
    problem = Problem.build(scene, {"empty": SW, "apex": SW + _point_case(scene, apex, 0.5)})
    polish = _Run.polish

    def stuck(self, X, ws, *, fallbacks=True, stop=False, blend=None):
        if blend is None:
            return polish(self, X, ws, fallbacks=fallbacks, stop=stop)
        return X.copy(), ws, self.blended(blend)[0](X), 0

    monkeypatch.setattr(_Run, "polish", stuck)
    res, rec = continuation(StaggeredLinearization(), problem, StaggeredOptions(), None, None,
                            time.perf_counter() + 60)
    b = rec["blocking"]
    assert res is None and rec["reached"] == 0.0 and b["case"] == "empty" and b["max_relative_error"] > 0.5
    assert b["pushing"] >= len(b["bound_edges"]) > 0 and b["at_bound"] >= b["pushing"]
    assert set(b["bound"]) == {"lower"}
    t = b["tension"]
    assert t["status"] == "tension" and t["tension_share"] > 1.0 and t["edges"] >= 1
    assert f"{b['at_bound']} of its weights on a bound" in rec["message"]
    assert f"by a total force of {t['tension_share']:.2g} times the case's total load" in rec["message"]
    one = StaggeredLinearization().solve(scene, SW)
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)
    own = cases.least_tension(top, one.network.vertices, one.network.loads, one.parameters["eps"], np.inf)
    assert own["status"] == "carried"


@pytest.mark.slow
def test_ipopt_nearest_to_the_stalled_network_finishes_a_triangulated_free_edged_vault():
    """The free-edged vault (n = 12) with its quads split into triangles, empty and 5% of the
    self-weight at the highest free vertex: the staggered iteration stalls (the continuation is
    blocked), and IPOPT over both cases, seeking the network in equilibrium nearest the stalled
    one, converges: every case passes the independent checker to 1e-8, within the solve's 60 s,
    with the vertices moved by under 1% of the span. (Asked for the distance to the reference
    from there, IPOPT did not settle its load rounds in the 60 s.)"""
    from selfsupport.core.evidence import triangulate

    quads, _ = _free_edged_quad_vault(12)
    scene = Scene(PolyMesh.from_faces(quads.mesh.vertices, triangulate(quads.mesh)), quads.supports, name="triangulated")
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    v = int(free[np.argmax(V[free, 2])])
    problem = Problem.build(scene, {"empty": SW, "point": SW + _point_case(scene, v, 0.05)})
    res = StaggeredLinearization().solve(problem, {"time_limit": 60})
    fin = res.parameters["ipopt_from_staggered"]
    assert res.parameters["staggered"]["status"] == "stalled" and res.parameters["staggered"]["max_relative_error"] > 1e-4
    assert res.status == fin["status"] == "converged" and fin["nearest_to_start"]
    span = float(np.ptp(V[:, 0]))
    assert fin["moved"] < 0.01 * span
    for name, net in res.case_networks:
        report = independent_check(net, tol=1e-8)
        assert report.ok, (name, report.stdout)


@pytest.mark.parametrize("finish", [True, False])
def test_the_iteration_over_every_case_leaves_the_finish_its_share_of_the_time(monkeypatch, finish):
    """Where the continuation is blocked (the quad grid's point load), the iteration over every
    case stops at 1 − FINISH_SHARE of the solve's time when IPOPT's finish may run, so that the
    finish has its share; without the finish it has the whole time."""
    from selfsupport.methods.staggered import method as staggered_method

    problem, v = _quad_grid_point_case()
    seen, iterate = [], StaggeredLinearization._iterate

    def held(self, problem, opt, progress, warm_start, deadline):
        if len(problem.loads) == 1:  # (the envelope's own solve)
            return iterate(self, problem, opt, progress, warm_start, deadline)
        seen.append(deadline)
        return iterate(self, problem, replace(opt, max_iter=2), progress, warm_start, deadline)

    monkeypatch.setattr(StaggeredLinearization, "_iterate", held)
    def no_finish(problem, stalled, deadline, progress):
        raise SelfSupportError("not in this test")

    monkeypatch.setattr(staggered_method, "ipopt_finish", no_finish)
    t0 = time.perf_counter()
    StaggeredLinearization(ipopt_finish=finish).solve(problem, time_limit=30.0)
    share = cases.FINISH_SHARE if finish else 0.0
    assert len(seen) == 1 and seen[0] == pytest.approx(t0 + (1 - share) * 30.0, abs=0.5)


def _svd_count(H: np.ndarray, rtol: float) -> int:
    """Edges less the rank of the dense plan matrix ``H`` (numpy's SVD, singular values above
    ``rtol`` times the largest): the plan's horizontal self-stresses, measured independently."""
    s = np.linalg.svd(H, compute_uv=False)
    return H.shape[1] - int(np.count_nonzero(s > rtol * s[0]))


def _plan_of(mesh: str):
    """The scene, the plan's positions and topology of the self-stress tests' two meshes: the
    free-edged quad vault's single-case network, or a quad barrel vault as built."""
    if mesh == "quad barrel vault":
        scene = barrel_vault(nx=5, ny=7, quads=True)
        X = scene.mesh.vertices
    else:
        scene, _ = _free_edged_quad_vault()
        X = StaggeredLinearization().solve(scene, SW).network.vertices
    return scene, X, Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)


@pytest.mark.parametrize("mesh", ["free-edged quad vault", "quad barrel vault"])
def test_the_sparse_self_stress_count_is_numpys_svd_count(monkeypatch, mesh):
    """Above :data:`SELF_STRESS_MAX_EDGES` the count is the edges less the horizontal equations
    plus the plan's mechanisms (the zero eigenvalues of ``H Hᵀ``): on the free-edged quad
    vault's single-case network (as many edges as horizontal equations, one self-stress: one
    mechanism) and on a quad barrel vault's plan (one self-stress per inner grid line, no
    mechanism), with the dense route's limit set to zero, it equals numpy's SVD count of the plan
    matrix at the sparse route's resolution (the vault's plan has three more singular values
    between 1e-9 and 2e-8 of the largest, then none below 1e-3: four at that resolution, one at
    the dense route's)."""
    scene, X, top = _plan_of(mesh)
    expected = _svd_count(_plan_matrix(scene, X), cases.SELF_STRESS_SPARSE_RTOL)
    monkeypatch.setattr(cases, "SELF_STRESS_MAX_EDGES", 0)
    tv = cases.top_view_self_stresses(top, X)
    assert tv["route"] == "sparse" and tv["self_stresses"] == expected == (4 if mesh != "quad barrel vault" else 4 + 6)
    assert tv["next_singular"] > 1e3 * cases.SELF_STRESS_SPARSE_RTOL


def _quad_vault_cases_at_one_network() -> tuple[Scene, SolveResult]:
    """The free-edged quad vault's single-case network (self-weight alone) as a result over two
    cases: self-weight, and self-weight with 5% of it at the highest free vertex."""
    scene, _ = _free_edged_quad_vault()
    one = StaggeredLinearization().solve(scene, SW)
    net = one.network
    free = np.flatnonzero(~scene.supports)
    v = int(free[np.argmax(net.vertices[free, 2])])
    point = net.loads.copy()
    point[v] -= 0.05 * float(-net.loads[free].sum())
    nets = (("empty", net), ("point", replace(net, loads=point)))
    return scene, SolveResult.build(net, cases=nets, status="stalled", method="staggered", backend="x",
                                    iterations=0, wall_time=0.0)


def test_over_a_plan_with_one_self_stress_no_heights_carry_a_point_load_case():
    """The fixed-plan test at the free-edged quad vault's single-case network: the count is
    numpy's SVD count (one self-stress ``u``), far below the ``⌈n/2⌉`` two cases need, and the
    least-squares floor is the analytic one: with case 'empty' balanced, ``D(a u) z = F_1`` makes
    the vertical load of any multiple of ``u`` at those heights a multiple of ``F_1``, so case
    'point' is left with the residual of projecting its relative rows on ``F_1``'s."""
    scene, res = _quad_vault_cases_at_one_network()
    net = res.network
    fp = cases.fixed_plan(res)
    free = ~scene.supports
    n = int(free.sum())
    assert fp["self_stresses"] == _svd_count(_plan_matrix(scene, net.vertices), cases.SELF_STRESS_RTOL) == 1
    assert fp["needed"] == -(-n // 2) and fp["unknowns"] == n + 2 and fp["equations"] == 2 * n
    F1, F2 = net.loads[free], res.case_networks[1][1].loads[free]
    a, b = F1 / np.abs(F2), F2 / np.abs(F2)
    floor = np.abs(b - (a @ b) / (a @ a) * a).max()
    assert fp["verdict"] == "blocked" and fp["case"] == "point"
    assert fp["residual"] == pytest.approx(floor, rel=1e-6) and floor > 0.5
    note = cases.fixed_plan_note(fp)
    assert "are 1-dimensional (168 edges for 168 horizontal equations)" in note and f"{floor:.2e}" in note
    assert "solve --triangulate" in note  # (the advice names the option that adds the edges)


def test_a_triangulated_plan_is_not_blocked_by_the_count():
    """The same vault split into triangles: edges less horizontal equations alone exceed the
    self-stresses two cases need over a fixed plan, and the count is numpy's SVD count."""
    from selfsupport.core.triangulation import split_scene

    quads, _ = _free_edged_quad_vault()
    scene = split_scene(quads)
    one = StaggeredLinearization().solve(scene, SW)
    res = SolveResult.build(one.network, cases=(("empty", one.network), ("again", one.network)), status="stalled",
                            method="staggered", backend="x", iterations=0, wall_time=0.0)
    fp = cases.fixed_plan(res)
    assert fp["self_stresses"] == _svd_count(_plan_matrix(scene, one.network.vertices), cases.SELF_STRESS_RTOL)
    assert fp["self_stresses"] >= fp["edges"] - fp["horizontal_equations"] >= fp["needed"]
    assert fp["verdict"] == "not blocked by the count" and cases.fixed_plan_note(fp) == ""


def test_a_stalled_result_on_a_free_edged_quad_vault_reports_its_plans_block(monkeypatch):
    """The free-edged quad vault's iteration over both cases held to two iterations, without the
    finish: the result records the fixed-plan test at its network, whose count is numpy's SVD
    count of its plan matrix and below what two cases need, and its message says so."""
    scene, problem = _free_edged_quad_vault()
    _two_iterations(monkeypatch)
    res = StaggeredLinearization(ipopt_finish=False).solve(problem)
    assert res.status != "converged"
    fp = res.parameters["fixed_plan"]
    assert fp["self_stresses"] == _svd_count(_plan_matrix(scene, res.network.vertices), cases.SELF_STRESS_RTOL)
    assert fp["self_stresses"] < fp["needed"] == 42 and fp["verdict"] == "blocked" and fp["residual"] > 1e-3
    assert cases.fixed_plan_note(fp) in res.message


@pytest.mark.parametrize("mesh", ["free-edged quad vault", "quad barrel vault"])
def test_the_sparse_self_stress_basis_spans_numpys_null_space_of_the_plan(monkeypatch, mesh):
    """:func:`self_stress_basis` by the sparse route (the dense route's limit set to zero) with
    the sparse count is orthonormal and spans the null space numpy's SVD gives for the plan
    matrix at that resolution (the cosines of the principal angles: all 1), on the vault's
    single-case network (four self-stresses at that resolution) and the barrel vault's plan (ten)."""
    import scipy.linalg

    scene, X, top = _plan_of(mesh)
    monkeypatch.setattr(cases, "SELF_STRESS_MAX_EDGES", 0)
    k = cases.top_view_self_stresses(top, X)["self_stresses"]
    H = _plan_matrix(scene, X)
    N = scipy.linalg.null_space(H, rcond=cases.SELF_STRESS_SPARSE_RTOL)
    S = cases.self_stress_basis(top, X, k)
    assert S.shape == N.shape == (top.m, 4 if mesh != "quad barrel vault" else 10)
    assert np.abs(S.T @ S - np.identity(k)).max() < 1e-12
    assert np.abs(H @ S).max() <= 1e-7 * np.abs(H).max()
    assert np.linalg.svd(N.T @ S, compute_uv=False).min() == pytest.approx(1.0, abs=1e-6)


def test_the_load_cases_study_takes_any_scene_in_its_folder_and_refuses_a_missing_one(tmp_path, capsys):
    """``--only`` names any ``.sss`` scene of ``--scenes`` (a scene of the same kind not among the
    paper's three gets the same cases); a missing one ends the study with one line, before any solve."""
    scene, _ = _free_edged_quad_vault()
    from selfsupport.io.sss import write_scene_sss

    write_scene_sss(tmp_path / "other-vault.sss", scene)
    jobs = study.jobs(tmp_path, ("other-vault",), (0.05,), ("default",))
    assert [j["scene"] for j in jobs] == ["other-vault"] and jobs[0]["peel"].blocked is False
    with pytest.raises(SystemExit) as e:
        study.main(["--scenes", str(tmp_path), "--only", "missing", "--out", str(tmp_path / "out")])
    assert e.value.code == 2 and "no scene" in capsys.readouterr().err and not (tmp_path / "out").exists()
