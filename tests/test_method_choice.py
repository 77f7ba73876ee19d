"""``--method auto``: the rule that picks the multilevel or the staggered method from the problem
(selfsupport.methods.choice), what the command line and the file say about the choice, an
explicit method left alone, and the decision logic of the study that measured the rule."""
from __future__ import annotations

import json

import numpy as np
import pytest

from selfsupport import api, cli
from selfsupport.core.result import Network
from selfsupport.core.shapes import make_shape
from selfsupport.methods import choice
from selfsupport.methods.choice import LEVELS_ABOVE, choose_method
from selfsupport.methods.memory import estimate_solve_bytes
from selfsupport.methods.multilevel import DIRECT_MAX
from studies.common import PAPER_TABLE1
from studies.method_choice import paid, threshold_interval

from .conftest import SHARED, independent_check

SCENES = SHARED / "paper-scenes" / "scenes"


# ------------------------------------------------------------------------------- the rule
@pytest.mark.parametrize("shape", ["pillar_vault", "concave_disk"])
def test_small_meshes_are_solved_on_one_level_and_large_ones_by_levels(shape):
    """At most LEVELS_ABOVE vertices: staggered. Above: multilevel, told to build a coarser level
    where its own one-level size would not (up to DIRECT_MAX), as it is above that."""
    small = api.problem(make_shape(shape, n_vertices=LEVELS_ABOVE // 3))
    mid = api.problem(make_shape(shape, n_vertices=(LEVELS_ABOVE + DIRECT_MAX) // 2))
    big = api.problem(make_shape(shape, n_vertices=int(DIRECT_MAX * 1.1)))
    assert small.scene.mesh.n_vertices <= LEVELS_ABOVE < mid.scene.mesh.n_vertices <= DIRECT_MAX
    assert big.scene.mesh.n_vertices > DIRECT_MAX
    one = choose_method(small)
    assert one.method == "staggered" and f"<= {LEVELS_ABOVE:,}" in one.why and not one.settings
    two = choose_method(mid)
    assert two.method == "multilevel" and two.settings == {"direct_max": LEVELS_ABOVE}
    assert f"{mid.scene.mesh.n_vertices:,} vertices > {LEVELS_ABOVE:,}" in two.why
    # (so the method it is handed does build a coarser level)
    assert len(api.make_method("multilevel", **two.settings).levels(mid.scene)) > 1
    three = choose_method(big)
    assert three.method == "multilevel" and not three.settings


@pytest.mark.parametrize("extra, needle", [({"point_loads": {5: 100.0}}, "point loads"),
                                           ({"extra_mass": {7: 50.0}}, "masses"),
                                           ({"constraints": ["hull"]}, "masonry hull")])
def test_data_tied_to_the_mesh_keep_one_level(extra, needle):
    """A large mesh whose problem cannot be restated on a coarser mesh is solved on one level,
    and the line says what holds it there."""
    prob = api.problem(make_shape("pillar_vault", n_vertices=LEVELS_ABOVE * 2), **extra)
    c = choose_method(prob)
    assert c.method == "staggered" and needle in c.why


def test_per_edge_bounds_keep_one_level():
    scene = make_shape("concave_disk", n_vertices=LEVELS_ABOVE * 2)
    c = choose_method(api.problem(scene, w_max=np.full(scene.mesh.n_edges, 1e6)))
    assert c.method == "staggered" and "per edge" in c.why


def test_a_subdivided_design_goes_up_its_levels_and_a_start_decides_where_from():
    """A scene refined from a coarser design: multilevel (the design's levels exist). A start on
    the coarser design's mesh goes up from it; a start on the mesh itself is one level from it."""
    from selfsupport.core.subdivision import subdivide_scene, subdivision_parents

    coarse = make_shape("pillar_vault", n_vertices=300)
    scene = subdivide_scene(coarse, 2)
    assert scene.mesh.n_vertices > LEVELS_ABOVE
    prob = api.problem(scene)
    c = choose_method(prob)
    assert c.method == "multilevel" and "subdivided" in c.why

    def start(mesh):
        return Network(mesh=mesh, weights=np.ones(mesh.n_edges), loads=-np.ones(mesh.n_vertices),
                       supports=np.zeros(mesh.n_vertices, bool))

    up = choose_method(prob, warm_start=start(subdivision_parents(scene)[0].mesh))
    assert up.method == "multilevel" and "starting from a coarser design" in up.why
    same = choose_method(prob, warm_start=start(scene.mesh))
    assert same.method == "staggered" and "starting from the given network" in same.why


def test_a_mesh_without_boundary_keeps_one_level():
    """Coarsening needs the top view's outline: a closed mesh is solved on one level."""
    from formulations import Problem
    from selfsupport.core.loads import SelfWeight
    from selfsupport.core.mesh import PolyMesh
    from selfsupport.core.scene import Scene

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    sup = np.zeros(6, bool)
    sup[5] = True
    prob = Problem.build(Scene(mesh=PolyMesh.from_faces(V, F), supports=sup, name="octahedron"), SelfWeight())
    c = choose_method(prob, levels_above=3)
    assert c.method == "staggered" and "no boundary" in c.why


@pytest.mark.skipif(not SCENES.is_dir(), reason=f"the paper's scenes are not beside the repository ({SCENES})")
def test_the_paper_scenes_keep_the_staggered_method():
    """Table 1's scenes (527–2,348 vertices) are solved as before, on one level."""
    from studies.common import read_study_scene

    for name in PAPER_TABLE1:
        c = choose_method(api.problem(read_study_scene(SCENES, name)))
        assert c.method == "staggered", (name, c.why)


# ----------------------------------------------------------------- api and command line
def test_the_api_default_reports_its_choice_and_an_explicit_method_reports_none():
    scene = make_shape("dome", n_vertices=300)
    auto = api.solve(scene)
    assert auto.parameters["method_choice"]["method"] == "staggered" == auto.method
    assert auto.parameters["method_choice"]["requested"] == "auto"
    assert "method_choice" not in api.solve(scene, method="staggered").parameters


def test_the_command_line_default_says_which_method_and_why(tmp_path, capsys):
    out = tmp_path / "n.json"
    assert cli.main(["solve", "shape:dome:300", "--out", str(out), "-q"]) == 0
    stdout = capsys.readouterr().out
    line = next(ln for ln in stdout.splitlines() if ln.startswith("method"))
    assert "staggered (auto:" in line and "vertices" in line
    doc = json.loads(out.read_text())
    assert doc["method"] == "staggered"
    assert doc["parameters"]["method_choice"]["method"] == "staggered"
    assert "vertices <=" in doc["parameters"]["method_choice"]["why"]


@pytest.fixture
def low_threshold(monkeypatch):
    """The switch lowered so that a small mesh is solved by levels (fast)."""
    monkeypatch.setattr(choice, "LEVELS_ABOVE", 300)
    return 300


def test_the_command_line_default_solves_a_mesh_above_the_switch_by_levels(tmp_path, capsys, low_threshold):
    out = tmp_path / "n.json"
    assert cli.main(["solve", "shape:pillar_vault:900", "--out", str(out), "-q"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("method"))
    assert "multilevel (auto:" in line
    doc = json.loads(out.read_text())
    assert doc["method"] == "multilevel" and doc["parameters"]["method_choice"]["method"] == "multilevel"
    levels = doc["parameters"]["multilevel"]["levels"]
    assert len(levels) == 2 and levels[0]["n_vertices"] <= low_threshold
    assert independent_check(out).ok


def test_an_explicit_staggered_method_is_honoured_above_the_switch(tmp_path, capsys, low_threshold):
    out = tmp_path / "n.json"
    assert cli.main(["solve", "shape:pillar_vault:900", "--method", "staggered", "--out", str(out), "-q"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("method"))
    assert line.split() == ["method", "staggered"]
    doc = json.loads(out.read_text())
    assert doc["method"] == "staggered" and "method_choice" not in doc["parameters"]
    assert "multilevel" not in doc["parameters"]


def test_a_big_mesh_auto_kept_on_one_level_is_not_pointed_to_the_multilevel_method(tmp_path, capsys, monkeypatch):
    """A stalled staggered solve above DIRECT_MAX is told to try the multilevel method, unless
    auto chose one level because no coarser level can carry the problem (it would solve on one
    level all the same)."""
    from selfsupport.core.result import SolveResult

    scene = make_shape("dome", n_vertices=int(DIRECT_MAX * 1.1))
    net = Network(mesh=scene.mesh, weights=np.ones(scene.mesh.n_edges), loads=-np.ones(scene.mesh.n_vertices),
                  supports=scene.supports, reference=scene.mesh)
    why = choose_method(api.problem(scene, point_loads={5: 100.0})).as_dict()
    fake = SolveResult.build(net, status="stalled", method="staggered", backend="active-set", iterations=57,
                             wall_time=0.1, message="the fit error stopped falling",
                             parameters={"tol": 1e-9, "method_choice": why})
    monkeypatch.setattr(api, "solve", lambda *a, **k: fake)
    code = cli.main(["solve", f"shape:dome:{scene.mesh.n_vertices}", "--point-load", "5:100",
                     "--out", str(tmp_path / "n.json"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 4 and len(err) == 1 and "--method multilevel" not in err[0]


def test_choosing_for_a_small_mesh_does_not_load_the_multilevel_method():
    """The rule settles a small mesh before it needs the multilevel machinery (half a second of
    imports, paid by every small solve's process otherwise)."""
    import subprocess
    import sys

    code = ("import sys; from selfsupport import api; from selfsupport.core.shapes import make_shape; "
            "r = api.solve(make_shape('dome', n_vertices=200)); "
            "assert r.parameters['method_choice']['method'] == 'staggered'; "
            "print('selfsupport.methods.multilevel' in sys.modules)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"


def test_auto_needs_no_more_memory_than_the_methods_it_picks(tmp_path):
    """The memory guard estimates ``auto`` as the staggered / multilevel methods it runs (not as
    IPOPT's 6× larger need): a limit the staggered estimate fits under admits it."""
    n = 1000
    assert estimate_solve_bytes(n, "auto") == max(estimate_solve_bytes(n, "staggered"),
                                                  estimate_solve_bytes(n, "multilevel"))
    limit = (estimate_solve_bytes(n, "staggered") * 1.2) / 1024 ** 3
    assert estimate_solve_bytes(n, "ipopt") / 1024 ** 3 > limit  # (so the fallback would refuse)
    code = cli.main(["solve", f"shape:dome:{n}", "--method", "auto", "--max-memory", f"{limit:.4f}",
                     "--out", str(tmp_path / "n.json"), "-q"])
    assert code == 0


# ------------------------------------------------------------------------- the study
def test_the_study_counts_the_converged_or_the_cheaper_method_as_paid():
    ok, slow = {"status": "converged", "cpu_s": 10.0}, {"status": "converged", "cpu_s": 30.0}
    assert paid(slow, ok) == "multilevel" and paid(ok, slow) == "staggered"
    # a faster method that did not converge did not pay
    assert paid(slow, {"status": "time_limit", "cpu_s": 1.0}) == "staggered"
    assert paid({"status": "time_limit", "cpu_s": 600.0}, slow) == "multilevel"
    # neither converged: the one nearer equilibrium
    assert paid({"status": "stalled", "max_relative_error": 0.44},
                {"status": "time_limit", "max_relative_error": 1e-3}) == "multilevel"


def test_the_study_brackets_the_switch_between_sizes_where_one_method_always_paid():
    cases = [(1000, "staggered"), (1000, "staggered"), (4000, "staggered"), (4000, "multilevel"),
             (16000, "multilevel"), (16000, "multilevel"), (64000, "multilevel")]
    assert threshold_interval(cases) == (1000, 16000)
    assert threshold_interval([(1000, "multilevel"), (4000, "multilevel")]) == (None, 1000)
    assert threshold_interval([(1000, "staggered"), (4000, "staggered")]) == (4000, None)


def test_the_study_examples():
    """studies/ is not collected for doctests (scripts); the study's examples run here."""
    import doctest

    from studies import method_choice

    result = doctest.testmod(method_choice, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 4 and result.failed == 0
