"""The peel from the free edges (formulations/peel.py): where two load cases on one
geometry can differ in their weights."""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from formulations import Problem
from formulations.equilibrium import Topology, weight_matrix
from formulations.peel import difference_peel, loads_differ, star_degeneracy
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.shapes import make_shape
from selfsupport.methods.staggered import StaggeredLinearization
from studies.common import vault_pillar_layout
from tests.test_load_continuation import SW, _free_edged_quad_vault, _point_case, _two_iterations

N = 10


def _vault(seed: int, split: tuple[int, int] | None = None) -> tuple[PolyMesh, np.ndarray, np.ndarray]:
    """The vault-pillar layout over a paraboloid, every coordinate moved by a random normal offset
    (3 cm standard deviation: a generic geometry), the quads with both grid indices in ``split`` divided into triangles; the
    mesh, its supports and its edges that enter an equation (not between two supports)."""
    sup, quads = vault_pillar_layout(N)
    t = np.linspace(-1.5, 1.5, N)
    x, y = np.meshgrid(t, t)
    V = np.column_stack([x.ravel(), y.ravel(), 1.0 - 0.15 * (x ** 2 + y ** 2).ravel()])
    V += np.random.default_rng(seed).normal(scale=0.03, size=V.shape)
    faces = []
    for q in quads:
        j, i = divmod(q[0], N)
        if split and split[0] <= i <= split[1] and split[0] <= j <= split[1]:
            faces += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
        else:
            faces.append(q)
    mesh = PolyMesh.from_faces(V, faces)
    return mesh, sup, mesh.edges[~sup[mesh.edges].all(axis=1)]


def _differences(mesh: PolyMesh, sup: np.ndarray, edges: np.ndarray, loaded: int) -> np.ndarray:
    """An orthonormal basis of every weight difference on ``edges`` that balances every free vertex
    but ``loaded`` in space (``A(X) d = 0`` there), at the mesh's positions."""
    top = Topology.build(mesh.n_vertices, edges, sup)
    A = weight_matrix(top, mesh.vertices).toarray()
    rows = np.ones(A.shape[0], bool)
    rows[3 * top.free_index[loaded]:3 * top.free_index[loaded] + 3] = False
    return sla.null_space(A[rows])


def test_at_a_generic_geometry_every_weight_difference_vanishes_on_the_forced_edges():
    """The peel's claim, checked against linear algebra: with a quarter of the vault split into
    triangles there are weight differences that balance every vertex but the loaded one, and
    every one of them is zero on the forced edges, at several generic geometries."""
    for seed in range(3):
        mesh, sup, edges = _vault(seed, split=(0, 4))
        for loaded in (22, 33):
            peel = difference_peel(mesh.n_vertices, edges, sup, [loaded])
            D = _differences(mesh, sup, edges, loaded)
            assert D.shape[1] >= 1 and 0 < peel.forced.sum() < len(edges)
            assert np.abs(D[peel.forced]).max() < 1e-11
            assert np.abs(D[~peel.forced]).max() > 0.1


def test_a_quad_vault_with_free_edges_is_peeled_to_its_loaded_vertex():
    """As quads, the free edges peel the whole vault: no weight difference of either sign balances
    every other vertex, so a load at vertex 27 alone is carried by none (least squares leave a
    residual of order one), and the peel's stars are not degenerate there."""
    mesh, sup, edges = _vault(0)
    peel = difference_peel(mesh.n_vertices, edges, sup, [27])
    assert peel.blocked and peel.blocked_at.tolist() == [27]
    assert peel.forced.sum() == len(edges) == 168 and peel.steps == int((~sup).sum()) - 1
    assert _differences(mesh, sup, edges, 27).shape[1] == 0
    top = Topology.build(mesh.n_vertices, edges, sup)
    A = weight_matrix(top, mesh.vertices).toarray()
    b = np.zeros(A.shape[0])
    b[3 * top.free_index[27] + 2] = 1.0
    d = np.linalg.lstsq(A, b, rcond=None)[0]
    assert np.linalg.norm(A @ d - b) > 0.1
    assert star_degeneracy(peel, mesh.vertices).smallest > 1e-3


def test_a_triangle_dome_supported_all_round_is_not_peeled():
    """Six edges at every inner vertex and no free edge: nothing is forced and nothing blocked."""
    scene = make_shape("dome", n_vertices=100)
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    apex = int(free[np.argmax(V[free, 2])])
    peel = difference_peel(scene.mesh.n_vertices, scene.mesh.edges, scene.supports, [apex])
    assert not peel.blocked and peel.steps == 0 and not peel.forced.any()


def test_the_forced_edges_do_not_depend_on_the_vertex_numbering():
    """The peel relabelled is the relabelled peel (the set of forced edges is the closure, not an
    artefact of the order the vertices are taken in)."""
    mesh, sup, edges = _vault(1, split=(0, 4))
    perm = np.random.default_rng(7).permutation(mesh.n_vertices)  # new label of each old vertex
    a = difference_peel(mesh.n_vertices, edges, sup, [27])
    new_sup = np.zeros_like(sup)
    new_sup[perm] = sup
    b = difference_peel(mesh.n_vertices, perm[edges][::-1], new_sup, [perm[27]])
    assert np.array_equal(a.forced, b.forced[::-1])
    assert a.forced.sum() not in (0, len(edges))


def test_the_degeneracy_of_a_star_is_its_smallest_singular_value():
    """One free vertex between two supports and a third edge: orthogonal edges give 1, the third
    edge in the plane of the other two gives 0; an edge of zero length carries no force and is left
    out (the two orthogonal edges left give 1)."""
    edges = np.array([[0, 1], [1, 2], [1, 3]])
    sup = np.array([True, False, True, True, False])
    peel = difference_peel(5, edges, sup, [4])
    assert peel.vertices.tolist() == [1] and peel.forced.all()
    X = np.array([[-1.0, 0, 0], [0, 0, 0], [0, 2, 0], [0, 0, 3], [9, 9, 9]])
    assert star_degeneracy(peel, X).smallest == 1.0
    X[3] = [1.0, 1.0, 0.0]
    assert star_degeneracy(peel, X).smallest < 1e-15
    X[3] = X[1]
    assert star_degeneracy(peel, X).smallest == 1.0
    X[2] = [2.0, 0.0, 0.0]  # (then the two edges left lie on one line)
    assert star_degeneracy(peel, X).smallest < 1e-15


def test_the_tests_free_edged_vault_carries_its_point_load_on_the_one_edge_the_peel_leaves_standing_vertical():
    """The tests' free-edged quad vault stands under the self-weight and a 5% point load (its
    highest free vertex is next to the pillar): its two cases' weights differ only on the loaded
    vertex's edge to the pillar, the one edge the peel leaves, and a single edge balances a
    vertical load only when it is vertical: the loaded vertex sits over the support in plan."""
    scene, problem = _free_edged_quad_vault()
    res = StaggeredLinearization(ipopt_finish=False).solve(problem, {"time_limit": 60})
    assert res.status == "converged"
    (_, empty), (_, point) = res.case_networks
    loaded = loads_differ(empty.loads, point.loads, ~scene.supports)
    assert loaded.size == 1
    v = int(loaded[0])
    edges = scene.mesh.edges[scene.active_edges]
    peel = difference_peel(scene.mesh.n_vertices, edges, scene.supports, loaded)
    (kept,) = np.flatnonzero(~peel.forced & ~scene.supports[edges].all(axis=1))
    assert v in edges[kept] and scene.supports[edges[kept]].any()
    d = (point.weights - empty.weights)[scene.active_edges]
    assert np.abs(d[peel.forced]).max() < 1e-9 * np.abs(d).max()
    X = res.network.vertices
    i, j = edges[kept]
    assert np.linalg.norm(X[i, :2] - X[j, :2]) < 1e-9 * np.ptp(X[:, :2])


def test_a_stalled_solve_says_that_the_peel_reaches_its_point_load(monkeypatch):
    """The tests' free-edged quad vault with the point load at vertex 27, two vertices from any
    support, its iteration over both cases held to two iterations: the result records the peel
    (every one of the 168 edges forced, vertex 27 reached), its degeneracy is the one at the
    result's positions, and the message says it."""
    scene, _ = _free_edged_quad_vault()
    problem = Problem.build(scene, {"empty": SW, "point": SW + _point_case(scene, 27, 0.05)})
    _two_iterations(monkeypatch)
    res = StaggeredLinearization(ipopt_finish=False).solve(problem)
    assert res.status != "converged"
    rec = res.parameters["any_weights_carry"]["point"]["peel"]
    assert rec["loaded"] == [27] and rec["blocked_at"] == [27] and rec["forced_edges"] == 168
    peel = difference_peel(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports, [27])
    assert rec["smallest_degeneracy"] == star_degeneracy(peel, res.network.vertices).smallest > 0
    assert "nor does any network of this mesh without a degenerate vertex star" in res.message


def test_the_peel_study_finds_the_free_edged_quad_vault_reached_and_a_dome_not(tmp_path):
    """The study over a folder of two scenes: the free-edged quad vault's peel of its highest free
    vertex leaves the loaded vertex its edge to the pillar (not reached, one edge kept), the same
    vault's rows as the library computes them; a triangle dome is not peeled."""
    import csv

    from selfsupport.io.sss import write_scene_sss
    from studies import peel as study
    from studies.stand_search import write_control

    write_control(tmp_path)
    write_scene_sss(tmp_path / "dome.sss", make_shape("dome", n_vertices=100))
    assert study.main(["--scenes", str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    rows = {r["scene"]: r for r in csv.DictReader((tmp_path / "out" / "peel.csv").open())}
    vault, dome = rows["free-edged-quad-vault"], rows["dome"]
    scene, _ = _free_edged_quad_vault()
    loaded = int(vault["loaded"])
    peel = difference_peel(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports, [loaded])
    assert vault["faces"] == "81 quads" and int(vault["edges"]) == 168 and int(vault["peel_starts"]) == 24
    assert vault["reaches"] == "no" and int(vault["forced"]) == int(peel.forced.sum()) == 167
    assert dome["faces"].endswith("triangles") and dome["reaches"] == "no" and int(dome["forced"]) == 0


def test_the_command_line_says_the_mesh_blocks_the_cases_and_what_to_change(tmp_path, capsys):
    """``selfsupport solve`` on the tests' free-edged quad vault with a point-load case at vertex
    27: it does not converge, the summary says the peel reaches vertex 27 and the last line names
    the mesh, not another method, as what to change."""
    from selfsupport import cli
    from studies.stand_search import write_control

    path = write_control(tmp_path)
    toml = tmp_path / "cases.toml"
    toml.write_text('[cases.empty]\n\n[cases.point]\npoint_loads = { "27" = 5000.0 }\n')
    code = cli.main(["solve", str(path), "--load-cases", str(toml), "--time-limit", "30", "--out", str(tmp_path / "o.json")])
    out, err = capsys.readouterr()
    assert code != 0
    assert "case 'point' shares a geometry with case 'empty' on this mesh only at a degenerate vertex star (the peel " \
           "from the free edges reaches vertex 27)" in " ".join(out.split())
    last = err.strip().splitlines()[-1]
    assert last.endswith("this mesh carries these load cases only at a degenerate vertex star: split the quads "
                         "into triangles (--triangulate), or support the free edges") and "try --method" not in last.rsplit(";", 1)[-1]
