"""Several load cases on one geometry: the continuation from the cases' envelope
(selfsupport/methods/staggered/cases.py) and its report when it is blocked."""
from __future__ import annotations

import time

import numpy as np

from formulations import Problem
from selfsupport.core.loads import PointLoad, SelfWeight
from selfsupport.core.shapes import barrel_vault, make_shape
from selfsupport.methods.staggered import StaggeredLinearization, StaggeredOptions
from selfsupport.methods.staggered.cases import continuation
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
    assert res.status == "converged" and res.parameters["load_continuation"]["reached"] == 1.0
    for _, net in res.case_networks:
        report = independent_check(net, tol=1e-9)
        assert report.ok, report.stdout
    (_, a), (_, b) = res.case_networks
    assert np.abs(a.weights - b.weights).max() > 1e-3 * np.abs(a.weights).max()  # (two weight vectors)
    plain = StaggeredLinearization(continuation=False).solve(
        scene, {"empty": SW, "apex": SW + _point_case(scene, apex, 0.05)})
    assert plain.status == "converged" and res.distance_mean < plain.distance_mean


def test_a_point_load_on_a_quad_grid_is_blocked_at_the_loaded_vertex():
    """A quad barrel vault supported all round, self-weight, and self-weight with 5% of it on the
    middle vertex v. Inner vertices have four edges: the horizontal equilibrium has as many rows
    as weights, so near the envelope's network no change of the weights carries a load at v
    alone. The continuation is blocked at its start and its measurements name v first: the
    case without the point load fits worst there, and the signed difference fit's residual is
    largest there (the difference of the two cases' loads is at v only)."""
    scene = barrel_vault(nx=6, ny=6, quads=True)
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    v = int(free[np.argmin(np.linalg.norm(V[free, :2] - V[free, :2].mean(0), axis=1))])
    problem = Problem.build(scene, {"empty": SW, "point": SW + _point_case(scene, v, 0.05)})
    res, rec = continuation(StaggeredLinearization(), problem, StaggeredOptions(), None, None,
                            time.perf_counter() + 60)
    assert res is None and rec["reached"] < 1.0
    b = rec["blocking"]
    assert b["case"] == "empty" and b["vertices"][0] == v and b["max_relative_error"] > 0.1
    d = b["difference"]["empty"]
    assert d["vertices"][0] == v and d["max_relative_residual"] > 0.1
    assert f"vertices [{v}," in rec["message"]
