"""The parts of the peers study (studies/peers.py) that run without the peers' environment:
the shared problem, the edge matching and the one metric every tool is judged by; and the
comparison with the paper's original code: its RESULT line and trace, the times to a threshold,
the rows without a driver, and (slow, with the built driver) a run of both tools."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from formulations import Problem
from selfsupport.core.geometry import vertex_areas
from selfsupport.core.loads import PointLoad
from selfsupport.core.shapes import make_shape
from selfsupport.methods.staggered import StaggeredLinearization
from studies.common import read_csv_rows
from studies.peers import (
    ORIGINAL_STOP,
    align_weights,
    cpu_to_reach,
    export_problem,
    find_original_driver,
    main,
    network_metrics,
    original_input,
    original_row,
    parse_original_result,
    problem_scene,
    read_original_trace,
    selfsupport_cpu_points,
)


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


# ------------------------------------------------------------------ the paper's original code as a peer
#: the driver's console output: its scene line, then the RESULT line (driver.cpp's formats)
DRIVER_OUTPUT = (
    "scene s.sss  V=752 E=2165 F=1414 pinned=40  load(s)=0.012  stored-loads imply rho*t=50 (GUI default 50)\n"
    "RESULT scene=s.sss V=752 E=2165 iters=50 wall_s=5.412 cpu_s=5.301 maxrel_app=2.112e-04 "
    "maxrel_consistent=1.404e-04 (vertex 311) converged=0 min_w=0.001 max_w=812.5\n")
TRACE_HEADER = "iter,wall_s,cpu_s,maxrel_app,maxrel_consistent,beta\n"


def test_the_original_result_line_is_parsed_into_numbers():
    r = parse_original_result(DRIVER_OUTPUT)
    assert r["iters"] == 50 and isinstance(r["iters"], int)
    assert r["cpu_s"] == 5.301 and r["maxrel_consistent"] == 1.404e-4 and r["converged"] == 0
    assert r["scene"] == "s.sss" and "vertex" not in r  # "(vertex 311)" is no key=value pair
    with pytest.raises(ValueError, match="no RESULT line"):
        parse_original_result(DRIVER_OUTPUT.splitlines()[0])
    with pytest.raises(ValueError, match="cpu_s"):
        parse_original_result(DRIVER_OUTPUT.replace("cpu_s=5.301", "cpu_s=nothing"))


def test_the_original_trace_is_read_and_a_half_written_last_line_left_out(tmp_path):
    path = tmp_path / "t.trace.csv"
    path.write_text(TRACE_HEADER + "1,0.5,0.4,0.2,0.3,0.1\n2,1.0,0.9,2e-3,9e-4,0.05\n3,1.6,1.5,1e-4,", encoding="utf-8")
    rows = read_original_trace(path)
    assert [r["iter"] for r in rows] == [1.0, 2.0]
    assert rows[1]["cpu_s"] == 0.9 and rows[1]["maxrel_consistent"] == 9e-4
    (tmp_path / "bad.csv").write_text("iter,cpu_s,maxrel_app\n1,0.4,0.2\n", encoding="utf-8")
    with pytest.raises(ValueError, match="maxrel_consistent"):
        read_original_trace(tmp_path / "bad.csv")


def test_time_to_a_threshold_is_the_first_crossing_of_a_hand_made_trace(tmp_path):
    """The error with current loads crosses 1e-3 at 0.9 s, rises above it again (a load update)
    and reaches 1e-4 at 2.5 s; exactly 1e-3 is not below it; 1e-6 is never reached."""
    path = tmp_path / "t.trace.csv"
    rows = [(1, 0.4, 0.3), (2, 0.9, 9.9e-4), (3, 1.5, 1.2e-3), (4, 2.0, 1e-3), (5, 2.5, 9e-5)]
    path.write_text(TRACE_HEADER + "".join(f"{i},{t},{t},1,{e},0.1\n" for i, t, e in rows), encoding="utf-8")
    points = [(r["cpu_s"], r["maxrel_consistent"]) for r in read_original_trace(path)]
    assert cpu_to_reach(points, 1e-3) == 0.9
    assert cpu_to_reach(points, 1e-4) == 2.5
    assert cpu_to_reach(points, 1.2e-3) == 0.9 and cpu_to_reach(points[2:], 1e-3) == 2.5
    assert np.isnan(cpu_to_reach(points, 1e-6))


def test_selfsupport_history_points_start_at_the_solve_and_skip_discarded_networks():
    doc = {"parameters": {"cpu": {"at_entry": 10.0, "solve": 3.0}},
           "history": [{"iteration": 1, "max_rel_error": 0.5, "cpu_s": 10.5},
                       {"iteration": 2, "max_rel_error": 5e-4, "cpu_s": 11.0},
                       {"iteration": "polish", "max_rel_error": 1e-12, "cpu_s": 11.5, "kept": False, "retry": True},
                       {"iteration": 3, "max_rel_error": 2e-5, "cpu_s": 12.0},
                       {"iteration": "polish", "max_rel_error": 3e-13, "cpu_s": 12.25, "kept": True},
                       {"iteration": "refine", "max_rel_error": 1e-13}]}
    points = selfsupport_cpu_points(doc)
    assert points == [(0.5, 0.5), (1.0, 5e-4), (2.0, 2e-5), (2.25, 3e-13)]
    assert [cpu_to_reach(points, t) for t in (1e-3, 1e-4, 1e-9)] == [1.0, 2.0, 2.25]
    assert selfsupport_cpu_points({"history": doc["history"]}) == []  # no origin: no times


def test_a_solve_stamps_its_history_with_process_cpu_from_its_start(scene):
    """The stamps the study reads: every fitted iterate and the polish carry the process's CPU
    seconds, increasing, after the solve's entry and within the CPU the solve reports."""
    from selfsupport import api

    res = api.solve(scene)
    cpu = res.parameters["cpu"]
    stamped = [h for h in res.history if "cpu_s" in h]
    assert all("cpu_s" in h for h in res.history if isinstance(h["iteration"], int) or h["iteration"] == "polish")
    points = selfsupport_cpu_points({"parameters": res.parameters, "history": list(res.history)})
    assert len(points) == len(stamped) >= 2
    times = [t for t, _ in points]
    assert times == sorted(times) and times[0] >= 0.0 and times[-1] <= cpu["solve"]
    assert res.converged and cpu_to_reach(points, 1e-9) <= cpu["solve"]


def test_original_row_takes_medians_and_the_ratios_original_over_selfsupport():
    nan = float("nan")
    orig = [{"status": "iteration_limit", "iterations": 50, "cpu_s": c, "cpu_to_1e-03": c / 2, "cpu_to_1e-04": nan,
             "error": 2e-4} for c in (3.0, 1.0, 2.0)]
    ours = [{"status": "converged", "method": "staggered", "iterations": 12, "solve_cpu_s": s, "process_cpu_s": s + 1,
             "cpu_to_1e-03": s / 4, "cpu_to_1e-04": s / 2, "cpu_to_1e-09": s, "error": 1e-12} for s in (0.2, 0.1, 0.3)]
    row = original_row("x", orig, ours, {"commit": "abc"})
    assert row["orig_cpu_s"] == 2.0 and row["ss_solve_cpu_s"] == 0.2 and row["ss_process_cpu_s"] == 1.2
    assert row["ratio_1e-03"] == pytest.approx(1.0 / 0.05)
    assert np.isnan(row["orig_cpu_to_1e-04"]) and np.isnan(row["ratio_1e-04"])  # never reached: no ratio
    assert row["ratio_solve"] == pytest.approx(10.0) and row["ratio_process"] == pytest.approx(2.0 / 1.2)
    assert row["commit"] == "abc" and row["rounds"] == 3
    stalled = [{**r, "status": "stalled", "error": 1e-3} for r in ours]
    assert np.isnan(original_row("x", orig, stalled, {})["ratio_solve"])  # not converged: no solve ratio


def test_the_driver_is_found_as_a_binary_or_in_its_build_folder(tmp_path):
    out = tmp_path / "orig"
    (out / "build").mkdir(parents=True)
    driver = out / "build" / "driver"
    driver.write_text("#!/bin/sh\n", encoding="utf-8")
    assert find_original_driver(out)[0] is None  # not executable: no driver
    driver.chmod(0o755)
    found = {find_original_driver(p) for p in (out, out / "build", driver)}
    assert found == {(driver, "")}
    missing, reason = find_original_driver(tmp_path / "nope")
    assert missing is None and "build.sh" in reason and "\n" not in reason


def _scenes_folder(scene, folder):
    """A held-out scenes folder: one z-up OBJ with its supports file beside it."""
    from selfsupport.io import write_mesh

    folder.mkdir()
    write_mesh(folder / "vault.obj", scene.mesh)
    (folder / "vault.supports").write_text("\n".join(map(str, np.flatnonzero(scene.supports))) + "\n")
    return folder


def test_a_held_out_mesh_goes_to_the_original_with_y_down(scene, tmp_path):
    """The original reads heights along −y: a z-up scene is written for it turned, the same
    vertices in the same order, with the same supports."""
    from selfsupport.io import read_scene

    scenes = _scenes_folder(scene, tmp_path / "scenes")
    work = tmp_path / "work"
    work.mkdir()
    args = original_input(scenes, "vault", work)
    assert args[1] == "--supports" and Path(args[0]).parent == work
    back = read_scene(args[0], up="-y", supports=args[2])
    np.testing.assert_allclose(back.mesh.vertices, scene.mesh.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back.supports, scene.supports)
    raw = np.array([ln.split()[1:] for ln in Path(args[0]).read_text().splitlines() if ln.startswith("v ")], float)
    np.testing.assert_allclose(raw[:, 1], -scene.mesh.vertices[:, 2], atol=1e-12)  # height along −y


def test_without_a_driver_the_original_is_skipped_with_one_reason(scene, tmp_path, capsys, monkeypatch):
    """No driver: exit 0, every scene's row says "skipped" and why (one line, in the table and
    the CSV), stamped; nothing is solved."""
    import studies.peers as peers

    scenes = _scenes_folder(scene, tmp_path / "scenes")
    monkeypatch.setattr(peers, "DEFAULT_ORIGINAL_BUILD", tmp_path / "no-build")
    monkeypatch.setattr(peers, "run_selfsupport", lambda *a, **k: pytest.fail("solved without a driver"))
    for given in ([], ["--original-driver", str(tmp_path / "nope")]):
        out = tmp_path / f"out{len(given)}"
        assert main(["--scenes", str(scenes), "--out", str(out), "--tools", "original", *given]) == 0
        rows = read_csv_rows(out / "original.csv")
        assert [(r["scene"], r["orig_status"]) for r in rows] == [("vault", "skipped")]
        assert "build.sh" in rows[0]["message"] and rows[0]["commit"] and rows[0]["cores"] and rows[0]["load_start"]
        md = (out / "original.md").read_text()
        assert sum("build.sh" in ln for ln in md.splitlines()) == 1
        assert str(tmp_path / ("nope" if given else "no-build")) in rows[0]["message"]
        assert not (out / "original-runs").exists()


@pytest.mark.slow
def test_the_original_and_selfsupport_side_by_side_on_a_small_held_out_scene(scene, tmp_path):
    """End to end with the built driver (``SELFSUPPORT_ORIGINAL_DRIVER``, else the study's default
    build folder): both tools solve the same vault; the original's error recomputed from its
    file agrees with its own report and the independent checker's; its network lies on the
    reference, heights up (the axis turned right); selfsupport converges, and its times are in
    order: 1e-3 before 1e-4 before 1e-9, within the solve, within the process."""
    import os

    driver, reason = find_original_driver(os.environ.get("SELFSUPPORT_ORIGINAL_DRIVER"))
    if driver is None:
        pytest.skip(reason)
    from selfsupport.core.evidence import distance_stats
    from studies.common import json_network_arrays

    scenes = _scenes_folder(scene, tmp_path / "scenes")
    out = tmp_path / "out"
    assert main(["--scenes", str(scenes), "--out", str(out), "--tools", "original", "--repeat", "1",
                 "--original-driver", str(driver)]) == 0
    (row,) = read_csv_rows(out / "original.csv")
    f = {k: float(v) for k, v in row.items() if v and k.startswith(("orig_cpu", "ss_", "ratio", "orig_error"))
         if k not in ("ss_status", "ss_method")}
    assert row["orig_status"] in ("displayed tol", "iteration_limit")
    assert int(row["orig_iterations"]) <= int(ORIGINAL_STOP[3])
    assert f["orig_cpu_s"] > 0 and f["orig_error"] == pytest.approx(f["orig_error_driver"], rel=1e-2)
    if "orig_error_checker" in f:
        assert f["orig_error_checker"] == pytest.approx(f["orig_error"], rel=1e-2)
    net = json_network_arrays(out / "original-runs" / "vault.original.json")
    d_mean, _ = distance_stats(net["vertices"], scene.mesh)
    assert len(net["vertices"]) == scene.mesh.n_vertices and d_mean < 0.05 and np.all(net["loads"] < 0)
    assert row["ss_status"] == "converged" and f["ss_error"] <= 1e-9
    assert f["ss_cpu_to_1e-03"] <= f["ss_cpu_to_1e-04"] <= f["ss_cpu_to_1e-09"] <= f["ss_solve_cpu_s"] \
        <= f["ss_process_cpu_s"]
    assert f["ratio_process"] == pytest.approx(f["orig_cpu_s"] / f["ss_process_cpu_s"], rel=1e-9)
    assert row["commit"] and int(row["cores"]) >= 1


def test_the_timed_selfsupport_processes_keep_the_projects_bytecode(monkeypatch, tmp_path):
    """Where PYTHONDONTWRITEBYTECODE is set, the study still compiles the project once
    (compile_project) where a timed process finds it: every module's bytecode exists."""
    import importlib.util
    import os
    import sys

    from studies import peers
    from studies.common import REPO

    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    monkeypatch.setenv("PYTHONPYCACHEPREFIX", str(tmp_path))  # (the bytecode goes there, not into the checkout)
    env = peers.selfsupport_env()
    assert "PYTHONDONTWRITEBYTECODE" not in env and env["PYTHONPYCACHEPREFIX"] == str(tmp_path)
    assert env["PATH"] == os.environ["PATH"]
    assert peers.compile_project()
    monkeypatch.setattr(sys, "pycache_prefix", str(tmp_path))
    sources = [f for pkg in ("selfsupport", "formulations") for f in (REPO / pkg).rglob("*.py")]
    assert len(sources) > 50
    assert all(Path(importlib.util.cache_from_source(str(f))).is_file() for f in sources)
