"""The study scripts' logic on small generated scenes: the table's columns, the paper's numbers,
errors recomputed from the saved networks, the published-network comparison, fitted exponents.

The end-to-end test names its generated scene after a paper scene (``structural.obj`` with a
``structural.supports`` file and a "published" ``structural-n.obj``) so that the study's lookup of
the paper's numbers, supports file, vertical axis and published network is exercised on a mesh
made here; the paper's own files are only read by the guarded cross-check of the lookup table.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from selfsupport.core.mesh import PolyMesh
from selfsupport.core.shapes import make_shape
from selfsupport.io import read_network, write_mesh
from selfsupport.io.sss import write_scene_sss
from studies import common, pq, scaling, table1
from tests.conftest import CHECKER, SHARED, document_errors

PAPER_README = SHARED / "paper-scenes" / "README.md"

#: Table 1 as the paper states it (docs/guide/paper.md): figure -> (vertices, edges, time [s], iterations, max rel. error)
DESIGN_TABLE1 = {
    "Fig. 5b": (1201, 3504, 21.6, 9, 4.2e-5),
    "Fig. 5d": (1200, 3500, 26.5, 10, 8.5e-5),
    "Fig. 6": (1535, 2976, 17.0, 21, 2.7e-5),
    "Fig. 8": (752, 2165, 8.0, 9, 5.8e-5),
    "Fig. 11": (2358, 4302, 19.5, 9, 3.0e-4),
    "Fig. 16": (527, 998, 5.7, 25, 2.4e-5),
}
#: which scene file is which figure (docs/guide/paper.md)
DESIGN_FIGURES = {"lilium": "Fig. 5b", "lilium-pillar": "Fig. 5d", "cas": "Fig. 6", "twocirc-3": "Fig. 8",
                  "cyl2": "Fig. 11", "structural": "Fig. 16"}


def _registry_row(p: common.PaperScene) -> tuple:
    return (p.vertices, p.edges, p.time_s, p.iterations, p.max_rel_error)


def test_paper_numbers_are_design_md_table1():
    assert set(common.PAPER_TABLE1) == set(DESIGN_FIGURES)
    for name, p in common.PAPER_TABLE1.items():
        assert p.figure == DESIGN_FIGURES[name]
        assert _registry_row(p) == DESIGN_TABLE1[p.figure]
    # the published networks in the same vertex order (the paper-scenes README)
    assert {n: p.published for n, p in common.PAPER_TABLE1.items() if p.published} == {
        "lilium": "lilium-n.obj", "lilium-pillar": "lilium-pillar-n.obj", "cyl2": "cheese-n.obj",
        "structural": "structural-n.obj"}
    s = common.PAPER_TABLE1["structural"]
    assert (s.file, s.up, s.supports) == ("structural.obj", "-y", "structural.supports")


@pytest.mark.skipif(not PAPER_README.is_file(), reason="paper-scenes README not available")
def test_paper_numbers_agree_with_the_paper_scenes_readme():
    """Parse the README's table independently: ``| scenes/X | Fig. F | V / E (table: V') | t s, it, err |``."""
    seen = set()
    for line in PAPER_README.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 4 or not cells[0].startswith("scenes/"):
            continue
        m = re.match(r"(\d+)\s*/\s*(\d+)(?:\s*\(table:\s*(\d+)\))?", cells[2])
        t = re.match(r"([\d.]+)\s*s,\s*(\d+),\s*([\d.e+-]+)", cells[3])
        if not (m and t):
            continue  # scenes outside Table 1 (dome2, vault)
        name = Path(cells[0].split()[0]).stem
        p = common.PAPER_TABLE1[name]
        v = int(m.group(3) or m.group(1))
        assert (p.figure, p.vertices, p.edges) == (cells[1], v, int(m.group(2)))
        assert (p.time_s, p.iterations, p.max_rel_error) == (float(t.group(1)), int(t.group(2)), float(t.group(3)))
        seen.add(name)
    assert seen == set(common.PAPER_TABLE1)


@pytest.fixture(scope="module")
def table_run(tmp_path_factory):
    """table1.main on a ~150-vertex dome stored as the 'structural' scene (staggered/active-set only)."""
    root = tmp_path_factory.mktemp("t1")
    scenes, out, published = root / "scenes", root / "out", root / "published"
    scenes.mkdir()
    published.mkdir()
    scene = make_shape("dome", n_vertices=150)
    write_mesh(scenes / "structural.obj", scene.mesh, up="-y")
    (scenes / "structural.supports").write_text("# supports\n" + " ".join(map(str, np.flatnonzero(scene.supports))))
    # the "paper's network": the reference with its top vertex pushed below all its neighbours —
    # a local minimum under a downward load, which no compressive weights can balance
    V = scene.mesh.vertices.copy()
    top = int(np.argmax(np.where(scene.supports, -np.inf, V[:, 2])))
    V[top, 2] = V[scene.mesh.vertex_neighbors[top], 2].min() - 0.1
    write_mesh(published / "structural-n.obj", scene.mesh.with_vertices(V), up="-y")
    rows = table1.main(["--scenes", str(scenes), "--out", str(out), "--methods", "staggered/active-set",
                        "--published", str(published), "--checker", str(CHECKER), "--repeat", "3"])
    return {"rows": rows, "out": out, "scene": scene}


def test_table1_writes_the_documented_columns(table_run):
    out = table_run["out"]
    csv_rows = common.read_csv_rows(out / "table1.csv")
    documented = ["scene", "figure", "vertices", "edges", "method", "backend", "status", "time_s", "paper_time_s",
                  "speedup_vs_paper", "time_vs_staggered", "iterations", "paper_iterations", "max_rel_error",
                  "paper_max_rel_error", "min_weight", "dist_ref_mean", "dist_ref_max", "dist_pub_mean",
                  "dist_pub_max", "peak_rss_mib", "commit", "date", "cpu_model", "cores", "load_start"]
    assert set(documented) <= set(csv_rows[0])
    stamp = common.run_stamp()  # one stamp per run, the same on every row
    assert all((r["commit"], r["cpu_model"], r["cores"]) == (stamp["commit"], stamp["cpu_model"], str(stamp["cores"]))
               and r["date"] == csv_rows[0]["date"] and r["load_start"] for r in csv_rows)
    assert list(csv_rows[0]) == [c.key for c in table1.COLUMNS]
    assert [(r["method"], r["backend"]) for r in csv_rows] == [("staggered", "active-set"),
                                                               ("published", "paper's network, weights fitted")]
    md = (out / "table1.md").read_text(encoding="utf-8")
    assert "`solve()` call alone" in md  # the header says what the time excludes
    assert md.count(f"| structural | Fig. 16 | {table_run['scene'].mesh.n_vertices} |") == 2  # both rows, our size


def test_table1_time_is_the_median_of_the_repeated_solves(table_run):
    r = table_run["rows"][0]
    d = json.loads((table_run["out"] / r["network"]).read_text(encoding="utf-8"))
    each = d["study"]["solve_seconds_each"]
    assert r["repeats"] == len(each) == 3
    assert r["time_s"] == pytest.approx(sorted(each)[1], rel=1e-12) and r["time_min_s"] == min(each)
    assert "differ" not in (r.get("message") or "")  # the solves are deterministic


def test_table1_carries_the_papers_numbers_and_our_sizes(table_run):
    r = table_run["rows"][0]
    scene = table_run["scene"]
    assert r["status"] == "converged"
    assert (r["figure"], r["paper_time_s"], r["paper_iterations"], r["paper_max_rel_error"]) == ("Fig. 16", 5.7, 25, 2.4e-5)
    assert (r["vertices"], r["edges"]) == (scene.mesh.n_vertices, scene.mesh.n_edges)  # ours, not the paper's 527/998
    assert r["speedup_vs_paper"] == pytest.approx(5.7 / r["time_s"], rel=1e-12)
    assert r["time_vs_staggered"] == pytest.approx(1.0, rel=1e-12)
    csv_row = common.read_csv_rows(table_run["out"] / "table1.csv")[0]
    assert float(csv_row["paper_max_rel_error"]) == 2.4e-5 and int(csv_row["paper_iterations"]) == 25


def test_table1_error_column_is_recomputed_from_the_saved_network(table_run):
    out = table_run["out"]
    for r in table_run["rows"]:
        d = json.loads((out / r["network"]).read_text(encoding="utf-8"))
        rel = document_errors(d)
        # equal up to the round-off of the residual sums (~1e-14 of the load)
        assert r["max_rel_error"] == pytest.approx(rel.max(), rel=1e-9, abs=1e-12)
        assert r["median_rel_error"] == pytest.approx(np.median(rel), rel=1e-9, abs=1e-12)
        if CHECKER.is_file():  # the shared checker prints 4 significant digits
            assert r["checker_error"] == pytest.approx(rel.max(), rel=1e-3, abs=1e-12)
    stag = table_run["rows"][0]
    assert stag["max_rel_error"] <= 1e-9  # the solve converged: the recomputed evidence says so too


def test_table1_published_comparison(table_run):
    """The 'published' network differs from the reference at one dented vertex: only that vertex
    is off the reference surface, our distance to it is vertex-to-vertex, and the dent (a
    local minimum) cannot be balanced by compressive weights."""
    stag, pub = table_run["rows"]
    n = table_run["scene"].mesh.n_vertices
    assert pub["dist_ref_max"] > 1e-3
    assert pub["dist_ref_mean"] == pytest.approx(pub["dist_ref_max"] / n, rel=1e-6)  # the other vertices: 0
    d = json.loads((table_run["out"] / stag["network"]).read_text(encoding="utf-8"))
    P = np.asarray(json.loads((table_run["out"] / pub["network"]).read_text(encoding="utf-8"))["vertices"])
    V, R = np.asarray(d["vertices"]), np.asarray(d["reference_vertices"])
    dist = np.linalg.norm(V - P, axis=1) / np.linalg.norm(R.max(axis=0) - R.min(axis=0))
    assert stag["dist_pub_mean"] == pytest.approx(dist.mean(), rel=1e-12)
    assert stag["dist_pub_max"] == pytest.approx(dist.max(), rel=1e-12)
    # at a vertex below all its neighbours every compressive force points up: residual >= |load|
    assert pub["status"] == "not self-supporting" and pub["max_rel_error"] >= 1.0


def test_fitted_exponent_recovers_a_power_law():
    n = np.array([1e3, 4e3, 1.6e4, 6.4e4])
    assert scaling.fitted_exponent(n, 3.0 * n ** 1.17) == pytest.approx(1.17, abs=1e-12)
    assert math.isnan(scaling.fitted_exponent([1e3], [2.0]))
    rows = [{"shape": "s", "method": "m", "vertices": v, "time_s": 1e-3 * v, "status": st,
             "peak_rss_mib": 100 + 1e-2 * v, "rss_before_mib": 100}
            for v, st in ((1000, "converged"), (4000, "converged"), (16000, "time_limit"))]
    fit = scaling.exponents(rows)[0]
    assert fit["time_exponent"] == pytest.approx(1.0) and fit["memory_exponent"] == pytest.approx(1.0)
    assert fit["sizes"] == "1000, 4000"  # the row that hit its limit is not fitted


def test_scaling_row_measures_the_factorization_floor(tmp_path):
    """In-process worker on a small vault: evidence recomputed from the JSON agrees with the
    solve's, and the factorization times are real measurements of the named matrices."""
    r = scaling.scaling_row(shape="pillar_vault", n_vertices=150, method="staggered", time_limit=60.0,
                            out_json=str(tmp_path / "n.json"), warmup=False)
    assert r["status"] == "converged"
    assert common.json_max_relative_error(tmp_path / "n.json") == pytest.approx(r["reported_error"], rel=1e-6, abs=1e-15)
    assert r["factor_K_s"] > 0 and r["factor_step3_s"] > 0 and r["factor_step3_pre_s"] > 0
    assert r["factor_step2_s"] > 0
    hist = json.loads((tmp_path / "n.json").read_text())["history"]
    fits = [h["fit_iterations"] for h in hist if isinstance(h.get("iteration"), int)]
    assert r["fit_its_mean"] == pytest.approx(np.mean(fits)) and r["fit_its_mean"] >= 1
    assert r["n_free"] == int(make_shape("pillar_vault", n_vertices=150).free.sum())
    assert 0 < r["factor_share"] < 1
    # every fit and every Step-3 preconditioner is a factorization: at least one per iteration
    assert r["n_factorizations"] >= r["iterations"]
    assert 0 < r["step2_s"] < r["time_s"] and 0 < r["step3_s"] < r["time_s"] and r["cg_mean"] >= 1
    # the limit column: an outer iteration in plain stress-Laplacian factorizations; every
    # iteration factors at least one matrix at least that large (the Step-3 preconditioner)
    ratios = scaling.iteration_ratios(r)
    assert ratios["limit_ratio"] == pytest.approx(r["time_s"] / (r["iterations"] * r["factor_K_s"]), rel=1e-12)
    assert ratios["limit_ratio"] > 1
    # its split by step: the two steps are parts of the iteration's time (the rest is judging,
    # polishing, bookkeeping), and the one-factorization floor is built from the named matrices
    unit = r["iterations"] * r["factor_K_s"]
    assert ratios["step2_ratio"] == pytest.approx(r["step2_s"] / unit, rel=1e-12)
    assert ratios["step3_ratio"] == pytest.approx(r["step3_s"] / unit, rel=1e-12)
    assert 0 < ratios["step2_ratio"] + ratios["step3_ratio"] < ratios["limit_ratio"]
    assert ratios["one_factor_ratio"] == pytest.approx(
        (r["factor_step2_s"] + r["factor_step3_pre_s"]) / r["factor_K_s"], rel=1e-12)


def test_scaling_methods_name_a_step2_backend():
    assert scaling.method_entry("staggered/active-set-centred")[1] == scaling.METHODS["staggered"][1]
    assert scaling.method_entry("staggered/active-set-centred")[0]().backend.name == "active-set-centred"
    assert scaling.is_staggered("staggered/ipopt") and not scaling.is_staggered("ipopt")
    with pytest.raises(KeyError):
        scaling.method_entry("staggered/gurobi")


def test_run_isolated_contains_failures():
    """One row's crash, exception or memory blow-up is a status, not the end of the table."""
    crashed = common.run_isolated("os:abort", {}, hard_timeout=60)
    assert crashed["status"] == "crashed" and "-6" in crashed["message"]
    err = common.run_isolated("studies.common:scene_file", {"scenes_dir": "/nonexistent", "name": "x"}, hard_timeout=60)
    assert err["status"] == "error" and err["message"].startswith("FileNotFoundError")
    big = common.run_isolated("numpy:ones", {"shape": (100_000_000,)}, hard_timeout=60, max_rss_mib=200)
    assert big["status"] == "killed" and big["peak_rss_mib"] > 200


def test_a_row_process_reports_its_own_peak_memory_not_its_parents():
    """A spawned row is forked from the study process first: its peak must not start from the
    study's resident memory (``ru_maxrss`` does, through fork and exec)."""
    held = np.ones(80_000_000)  # 610 MiB resident in this process
    own = common.run_isolated("builtins:dict", {}, hard_timeout=60)
    assert held.sum() > 0 and own["peak_rss_mib"] < 300


def test_table1_surface_variant_hands_its_objective_to_ipopt(tmp_path):
    """The IPOPT row meant for comparison with the refinement minimises the distance to the
    reference surface: its solve records that objective and, started from the same staggered
    network of a concave disk (not self-supporting as designed), ends closer to the surface
    than the vertex-objective row (measured 0.97e-3 against 1.19e-3)."""
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    scene = make_shape("concave_disk", n_vertices=150)
    write_mesh(scenes / "structural.obj", scene.mesh, up="-y")
    (scenes / "structural.supports").write_text(" ".join(map(str, np.flatnonzero(scene.supports))))
    common_kw = {"scenes_dir": str(scenes), "scene_name": "structural", "time_limit": 60.0, "warmup": False}
    warm = tmp_path / "staggered.json"
    table1.solve_row(variant="staggered/active-set", out_json=str(warm), **common_kw)
    rows = {}
    for key in ("simultaneous/ipopt-warm", "simultaneous/ipopt-surface-warm"):
        path = tmp_path / (key.replace("/", "__") + ".json")
        rows[key] = table1.solve_row(variant=key, out_json=str(path), warm_from=str(warm), **common_kw)
        d = json.loads(path.read_text(encoding="utf-8"))
        assert rows[key]["status"] == "converged"
        assert d["parameters"]["objective"] == (["reference=1", "vertices=0.1"] if "surface" in key else None)
        assert document_errors(d).max() <= 1e-8
    surface, vertices = rows["simultaneous/ipopt-surface-warm"], rows["simultaneous/ipopt-warm"]
    assert surface["dist_ref_mean"] < 0.9 * vertices["dist_ref_mean"]


@pytest.mark.slow
def test_fixed_costs_study_reports_wall_time_phases_and_json(tmp_path, capsys):
    """studies/fixed_costs.py runs end to end on a small shape."""
    from studies import fixed_costs

    assert fixed_costs.main(["--scene", "shape:dome:300", "--time-limit", "5", "--runs", "1", "--json-runs", "1",
                             "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "wall median" in out and "validate" in out and "JSON text" in out and "as write_network does" in out


def test_dome_study_configuration_supports_the_ground_ring_and_loads_the_apex():
    """dome2's experiment configuration on a generated dome whose .sss-like state pins a cap and
    leaves part of the ground ring free: the ground boundary becomes the supports (every vertex
    of it, none above), the cap is freed, and the load goes to the highest vertex."""
    import dataclasses

    from studies.stability_dome import experiment_configuration

    s = make_shape("dome", n_vertices=200)
    V = s.mesh.vertices
    ground = s.mesh.boundary_vertex_mask & (V[:, 2] <= V[:, 2].min() + 1e-9)
    assert ground.sum() > 4
    stored = ground.copy()
    stored[np.flatnonzero(ground)[::2]] = False  # half the ring left free
    stored[V[:, 2] >= np.quantile(V[:, 2], 0.97)] = True  # a pinned cap
    scene, at = experiment_configuration(dataclasses.replace(s, supports=stored))
    np.testing.assert_array_equal(scene.supports, ground)
    assert at == [int(np.argmax(V[:, 2]))] and not scene.supports[at[0]]


def test_dome_study_fitted_start_and_published_networks_against_the_hull():
    """A published network carries no weights: fitted at a solved network's positions they balance
    its loads (nonnegative); a network offset 0.03 m along the normals is inside a 0.1 m hull and
    outside a 0.05 m one, every free vertex."""
    from formulations.equilibrium import Topology, load_vector, weight_matrix
    from selfsupport import api
    from selfsupport.core.geometry import vertex_normals
    from studies.stability_dome import fitted_start, published_in_hull

    scene = make_shape("dome", rings=5, radius=5.0, height=2.0)
    solved = api.solve(scene, density=2500.0, thickness=0.1).network
    net = fitted_start(scene, solved.vertices, 0.1)
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges, scene.supports)
    b = load_vector(top, net.loads)
    assert net.weights.min() >= 0
    assert np.linalg.norm(weight_matrix(top, net.vertices) @ net.weights - b) <= 1e-6 * np.linalg.norm(b)
    V = scene.mesh.vertices + 0.03 * vertex_normals(scene.mesh) * (~scene.supports)[:, None]
    free = int((~scene.supports).sum())
    for t, outside in ((0.1, 0), (0.05, free)):
        (row,) = published_in_hull(scene, {0.0: V}, t)
        assert row["outside"] == outside and row["free"] == free and row["published"] == "dome2-0kg-n"
        assert row["max_distance_m"] == pytest.approx(0.03, rel=0.05)


def _dome_as_structural(tmp_path: Path):
    """A 150-vertex dome stored as the scenes folder's 'structural' (OBJ, -y up, supports file)."""
    scenes, out = tmp_path / "scenes", tmp_path / "out"
    scenes.mkdir()
    scene = make_shape("dome", n_vertices=150)
    write_mesh(scenes / "structural.obj", scene.mesh, up="-y")
    (scenes / "structural.supports").write_text(" ".join(map(str, np.flatnonzero(scene.supports))))
    return scenes, out, scene


def test_subdivided_study_solves_the_refined_scene_and_recomputes_its_evidence(tmp_path):
    """The subdivided-designs study on a 150-vertex dome stored as 'structural': one Catmull–Clark
    step gives V + E + F vertices, all quads; each method's row is converged, its error recomputed
    from the saved JSON equals the solve's own and the shared checker agrees."""
    from studies import subdivided

    scenes, out, scene = _dome_as_structural(tmp_path)
    rows = subdivided.main(["--scenes", str(scenes), "--out", str(out), "--only", "structural", "--levels", "1",
                            "--checker", str(CHECKER), "--no-warmup", "--time-limit", "120"])
    m = scene.mesh
    assert [r["method"] for r in rows] == ["staggered", "multilevel", "multilevel/clusters"]
    for r in rows:
        assert r["status"] == "converged" and r["subdivisions"] == 1
        assert r["vertices"] == m.n_vertices + m.n_edges + m.n_faces and r["quad_share"] == 1.0
        assert r["max_rel_error"] == pytest.approx(r["reported_error"], rel=1e-6, abs=1e-15) and r["max_rel_error"] <= 1e-9
        if CHECKER.is_file():
            assert r["checker_error"] == pytest.approx(r["max_rel_error"], rel=1e-3, abs=1e-14)
        assert (out / f"structural-x1__{r['method'].replace('/', '-')}.json").is_file()
    md = (out / "subdivided.md").read_text()
    assert md.count("| structural | none | 1 |") == 3


def test_subdivided_study_variants_are_the_designs_mapped_and_solve_to_the_mapped_network(tmp_path):
    """``--variants``: the turned variant (a similarity: turned, scaled by 2.5, moved) of a
    150-vertex dome solves to the original's network mapped the same way (to 1e-4 of the scaled
    diagonal, the invariance tests' tolerance); the flattened one keeps the plan and supports but
    is a different design, whose network differs; every row is converged by the checker."""
    from selfsupport.io.network_json import read_network
    from studies import subdivided
    from studies.variants import SCALE, VARIANTS

    scenes, out, scene = _dome_as_structural(tmp_path)
    rows = subdivided.main(["--scenes", str(scenes), "--out", str(out), "--only", "structural", "--levels", "0",
                            "--methods", "staggered", "--variants", "none,turned,flat", "--checker", str(CHECKER),
                            "--no-warmup", "--time-limit", "120"])
    assert [r["variant"] for r in rows] == ["none", "turned", "flat"]
    for r in rows:
        assert r["status"] == "converged" and r["max_rel_error"] <= 1e-9
        if CHECKER.is_file():
            assert r["checker_error"] <= 1e-8
    base, turned, flat = (read_network(out / f"{tag}-x0__staggered.json")
                          for tag in ("structural", "structural-turned", "structural-flat"))
    diag = float(np.linalg.norm(np.ptp(base.vertices, axis=0)))
    assert np.abs(turned.vertices - VARIANTS["turned"](base.vertices)).max() <= 1e-4 * SCALE * diag
    np.testing.assert_allclose(flat.reference.vertices[:, :2], base.reference.vertices[:, :2], atol=1e-12)
    assert np.abs(flat.vertices[:, 2] - base.vertices[:, 2]).max() > 1e-2 * diag


def test_a_folder_of_other_scenes_runs_as_it_is(tmp_path):
    """Held-out scenes of the same kind, under other names: without ``--only``, Table 1 and the
    subdivided study run every scene file of the folder (an ``.sss`` with its own pins; an OBJ
    with ``NAME.supports`` beside it), each row converged by the recomputed error and the shared
    checker; a folder with no scene file says so in one line."""
    from selfsupport.io.sss import write_scene_sss
    from studies import airy_cover, subdivided

    scenes = tmp_path / "scenes"
    scenes.mkdir()
    dome, vault = make_shape("dome", n_vertices=80), make_shape("pillar_vault", n_vertices=80)
    write_scene_sss(scenes / "held-a.sss", dome)
    write_mesh(scenes / "held-b.obj", vault.mesh)
    (scenes / "held-b.supports").write_text(" ".join(map(str, np.flatnonzero(vault.supports))))
    (scenes / "notes.txt").write_text("not a scene")
    assert common.study_scenes(scenes) == ["held-a", "held-b"]
    rows = table1.main(["--scenes", str(scenes), "--out", str(tmp_path / "t1"), "--methods", "staggered/active-set",
                        "--checker", str(CHECKER), "--no-warmup"])
    rows += subdivided.main(["--scenes", str(scenes), "--out", str(tmp_path / "sub"), "--levels", "1",
                             "--methods", "staggered", "--checker", str(CHECKER), "--no-warmup"])
    assert [(r.get("scene"), r.get("vertices")) for r in rows[:2]] == [
        ("held-a", dome.mesh.n_vertices), ("held-b", vault.mesh.n_vertices)]
    assert [r.get("scene") for r in rows[2:]] == ["held-a", "held-b"]
    for r in rows:
        assert r["status"] == "converged" and r["max_rel_error"] <= 1e-9
        if CHECKER.is_file():
            assert r["checker_error"] <= 1e-8
    empty = tmp_path / "empty"
    empty.mkdir()
    for study in (table1, subdivided, airy_cover):
        with pytest.raises(SystemExit, match=r"no scene file in .*empty \(looked for \*\.sss, \*\.obj"):
            study.main(["--scenes", str(empty), "--out", str(tmp_path / "x")])
        with pytest.raises(SystemExit, match=r"no scenes folder .*absent$"):
            study.main(["--scenes", str(tmp_path / "absent"), "--out", str(tmp_path / "x")])


def test_variants_docstring_examples():
    """studies/ is not collected for doctests (scripts); the variants' examples run here."""
    import doctest

    from studies import variants

    result = doctest.testmod(variants, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 5 and result.failed == 0


def test_common_docstring_examples():
    """The shared helpers' examples (scene selection, ratios, ...) run here, as the variants' do."""
    import doctest

    result = doctest.testmod(common, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 6 and result.failed == 0


def test_newton_systems_are_the_fits_gram_plus_a_positive_diagonal():
    """The captured systems are the interior point's Q + diag(D), Q = AᵀA + prox·I of the same fit
    (recomputed by the study from the recorded A), D > 0; the capture stops the solve after the
    last fit wanted and leaves the backend as it was."""
    from selfsupport.methods import weightfit
    from studies import newton_systems as ns

    before = weightfit._LowerQ.with_diagonal
    scene, systems = ns.record("pillar_vault", 400, [0, 2])
    assert weightfit._LowerQ.with_diagonal is before
    assert systems and {s[0] for s in systems} <= {0, 2}
    for _fit, L, Q in systems:
        M = ns.symmetric(L)
        diff = (M - Q).tocoo()
        off = diff.row != diff.col
        assert np.abs(diff.data[off]).max(initial=0.0) <= 1e-12 * np.abs(Q.data).max()
        D = (M - Q).diagonal()
        assert D.min() > 0 and Q.diagonal().min() > 0


def test_newton_systems_direct_solve_is_exact_and_cg_reports_what_it_reached():
    """CHOLMOD solves each system to round-off; a CG row counts as converged only with its true
    residual at the requested tolerance; the stale factor of the fit's own previous system is
    used from the fit's second system on."""
    from studies import newton_systems as ns

    _scene, systems = ns.record("concave_disk", 400, [0])
    rtol = 1e-8
    rows = ns.solve_systems(systems, ["cholmod", "cholmod-stale", "jacobi"], every=1, rtol=rtol, maxiter=200)
    chol = [r for r in rows if r["solver"] == "cholmod"]
    assert len(chol) == len(systems) >= 3
    assert max(r["residual"] for r in chol) < 1e-10
    stale = [r for r in rows if r["solver"] == "cholmod-stale"]
    assert len(stale) == len(systems) - 1 and all(r["converged"] for r in stale)
    for r in rows:
        if r["solver"] != "cholmod":
            assert not r["converged"] or r["residual"] <= 10 * rtol
    summary = ns.summarize([dict(r, shape="disk", vertices=400) for r in rows])
    assert {s["solver"] for s in summary} == {"cholmod", "cholmod-stale", "jacobi"}
    assert next(s for s in summary if s["solver"] == "cholmod")["over_cholmod"] == 1.0


def test_newton_systems_docstring_examples():
    """studies/ is not collected for doctests (scripts); the study's examples run here."""
    import doctest

    from studies import newton_systems

    result = doctest.testmod(newton_systems, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 3 and result.failed == 0


@pytest.mark.slow
def test_pq_study_remeshes_again_at_the_published_meshs_spacing(tmp_path):
    """``--densities published``: where ``published/NAME-pq-n.obj`` exists, both remeshes again
    with the spacing its mean top-view edge (a uniform grid of known cell size here), tagged
    ``published spacing``: the grid remesh there has about as many cells as the published grid
    (area / h²), and the rows at the network's mean edge keep their names."""
    bv = make_shape("barrel_vault", nx=6, ny=8)
    V = bv.mesh.vertices.copy()
    V[:, 2] += 0.02 * np.sin(V[:, 0]) * np.sin(0.5 * V[:, 1])  # (twisted: its quads not planar)
    scene = dataclasses.replace(bv, mesh=PolyMesh.from_faces(V, [list(f) for f in bv.mesh.faces]))
    (tmp_path / "scenes").mkdir()
    (tmp_path / "published").mkdir()
    write_scene_sss(tmp_path / "scenes" / "bv.sss", scene)
    # the "published" mesh: a 12 x 20 grid of square cells (0.5 m) over the vault's 6 x 10 m plan
    cell = 0.5
    x, y = np.arange(-3.0, 3.0 + 1e-9, cell), np.arange(-5.0, 5.0 + 1e-9, cell)
    X, Y = np.meshgrid(x, y)
    nx, ny = len(x) - 1, len(y) - 1
    quads = [[j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i]
             for j in range(ny) for i in range(nx)]
    write_mesh(tmp_path / "published" / "bv-pq-n.obj",
               PolyMesh.from_faces(np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)], quads), up="-y")
    rows = pq.run(tmp_path, tmp_path / "out", ["bv"], 1.0, 4.0, remeshers=("seamless",),
                  densities=("mean", "published"))
    by = {r["mesh"]: r for r in rows}
    tag = pq.PUBLISHED_SPACING
    assert {"scene as is", "remesh principal (seamless)", "remesh grid (seamless)", f"remesh principal (seamless, {tag})",
            f"remesh grid (seamless, {tag})", "published pq-n"} <= set(by)
    faces = lambda r: sum(int(c.split(":")[1]) for c in r["faces"].split())  # noqa: E731
    assert faces(by[f"remesh grid (seamless, {tag})"]) == pytest.approx(nx * ny, rel=0.25)
    assert faces(by["remesh grid (seamless)"]) == pytest.approx(scene.mesh.n_faces, rel=0.25)
    assert (tmp_path / "out" / "bv__grid-seamless-published.json").is_file()
    # the scene as is: the largest vertex move of its planar solve, and its interior quads' mean
    # non-planarity (distance of the diagonals over the mean side), recomputed here
    V0, V1 = scene.mesh.vertices, read_network(tmp_path / "out" / "bv__as-is.json").vertices
    diag = np.linalg.norm(np.ptp(V0, axis=0))
    assert by["scene as is"]["moved_max"] == pytest.approx(np.linalg.norm(V1 - V0, axis=1).max() / diag, rel=1e-9)
    gaps = []
    for f in scene.mesh.faces:
        if scene.mesh.boundary_vertex_mask[list(f)].any():
            continue
        a, b, c, d = V0[list(f)]
        n = np.cross(c - a, d - b)
        side = np.mean([np.linalg.norm(V0[f[(k + 1) % 4]] - V0[f[k]]) for k in range(4)])
        gaps.append(abs((b - a) @ n) / np.linalg.norm(n) / side)
    assert np.mean(gaps) > 1e-3 and by["scene as is"]["start_nonplanar_interior"] == pytest.approx(np.mean(gaps), rel=1e-9)
    assert by["scene as is"]["moved_max"] > 1e-4  # (made planar: its vertices moved)
