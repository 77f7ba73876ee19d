"""The parts of the peers study (studies/peers.py) that run without the peers' environment:
the shared problem, the edge matching and the one metric every tool is judged by."""
from __future__ import annotations

import json

import numpy as np
import pytest

from formulations import Problem
from selfsupport.geometry import vertex_areas
from selfsupport.loads import PointLoad
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.shapes import make_shape
from studies.peers import align_weights, export_problem, main, network_metrics, problem_scene


@pytest.fixture(scope="module")
def scene():
    return make_shape("pillar_vault", n_vertices=120)


def test_problem_loads_are_the_self_weight_on_the_reference(scene):
    """Every vertex carries ρ t g times its 3D Voronoi area, downward; the loads sum to the
    surface's weight."""
    p = export_problem(scene, density=2000.0, thickness=0.1)
    areas = vertex_areas(scene.mesh, scene.mesh.vertices)
    np.testing.assert_allclose(p["loads"], -2000.0 * 0.1 * 9.81 * areas, rtol=1e-12)
    assert np.all(np.asarray(p["loads"]) <= 0)


def test_problem_round_trips_through_json(scene):
    """Export -> JSON -> scene gives back the mesh, its edges in their order and the supports."""
    p = json.loads(json.dumps(export_problem(scene)))
    back = problem_scene(p)
    np.testing.assert_array_equal(back.mesh.vertices, scene.mesh.vertices)
    np.testing.assert_array_equal(back.mesh.edges, scene.mesh.edges)
    np.testing.assert_array_equal(back.supports, scene.supports)
    np.testing.assert_array_equal(np.asarray(p["edges"]), scene.mesh.edges)


def test_align_weights_matches_edges_in_any_order_and_orientation():
    E = np.array([[0, 1], [1, 2], [2, 0]])
    got = align_weights(E, np.array([[0, 2], [2, 1]]), np.array([5.0, 7.0]))
    np.testing.assert_array_equal(got, [0.0, 7.0, 5.0])  # (0, 1) left out: 0
    with pytest.raises(ValueError):
        align_weights(E, np.array([[0, 3]]), np.array([1.0]))


def test_metrics_reproduce_the_solvers_own_error_on_a_solved_network(scene):
    """A selfsupport network solved under the problem's fixed loads: the study's recomputed
    error is the solver's own (same definition), the two implementations agree, and the
    network is compression-only."""
    p = export_problem(scene)
    problem = Problem.build(problem_scene(p), PointLoad(np.asarray(p["loads"])))
    res = StaggeredLinearization().solve(problem, {"time_limit": 60})
    net = res.network
    m = network_metrics(p, net.vertices, net.mesh.edges, net.weights)
    assert m["max_rel_error"] == pytest.approx(res.max_relative_error, rel=1e-6, abs=1e-15)
    assert m["max_rel_error_check"] == pytest.approx(m["max_rel_error"], rel=1e-6, abs=1e-15)
    assert m["min_w"] > 0 and m["n_tension"] == 0
    assert m["dist_mean"] == pytest.approx(res.distance_mean, rel=1e-9)


def test_metrics_of_the_reference_without_forces(scene):
    """w = 0: nothing holds any load, so every free vertex has relative error exactly 1; the
    reference itself is at distance 0 from itself with no plan drift."""
    p = export_problem(scene)
    V = np.asarray(p["vertices"])
    E = np.asarray(p["edges"])
    m = network_metrics(p, V, E, np.zeros(len(E)))
    assert m["max_rel_error"] == pytest.approx(1.0)
    assert m["dist_mean"] == pytest.approx(0.0, abs=1e-12)
    assert m["xy_drift"] == 0.0


def test_an_equilibrium_built_by_hand_has_zero_error():
    """A pyramid: apex over a square of supports; w = −L / (4 h) on the four legs balances the
    apex load exactly, and negated weights are tension."""
    V = np.array([[1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0], [0, 0, 2.0]])
    faces = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
    E = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 4], [1, 4], [2, 4], [3, 4]])
    L = np.array([0, 0, 0, 0, -80.0])
    p = {"name": "pyramid", "vertices": V.tolist(), "faces": faces, "edges": E.tolist(),
         "supports": [0, 1, 2, 3], "loads": L.tolist()}
    w = np.array([0, 0, 0, 0, 10.0, 10.0, 10.0, 10.0])  # 4 · w · h = 80 N at h = 2
    m = network_metrics(p, V, E, w)
    assert m["max_rel_error"] == pytest.approx(0.0, abs=1e-14)
    assert m["min_w"] == 10.0  # the base ring joins two supports: not counted
    m_t = network_metrics(p, V, E, -w)
    assert m_t["max_rel_error"] == pytest.approx(2.0)
    assert m_t["n_tension"] == 4


def test_missing_scenes_folder_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["--scenes", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no scenes folder" in err[0]
