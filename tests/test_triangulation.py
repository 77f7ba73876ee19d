"""Splitting a design's polygons into triangles (selfsupport.core.triangulation, solve --triangulate):
the split covers each face exactly and keeps every edge, quads split along the shorter diagonal,
faces that are not convex are refused, and a triangulated solve carries what the quad design's
plan blocks."""
from __future__ import annotations

import json

import numpy as np
import pytest

from formulations import Planar
from selfsupport import api, cli
from selfsupport.core.errors import MeshError
from selfsupport.core.evidence import triangulate
from selfsupport.core.loads import SelfWeight
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import make_shape, meridian_dome
from selfsupport.core.subdivision import subdivide_scene
from selfsupport.core.triangulation import split_faces, split_scene
from selfsupport.io import read_scene, write_mesh
from selfsupport.io.sss import write_scene_sss
from studies.common import vault_pillar_layout
from tests.conftest import independent_check
from tests.test_cli import assert_one_line_error


def _convex_polygon(n: int, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A random strictly convex n-gon placed in a random plane in 3D, and its area (the shoelace
    formula in its own plane)."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    while np.diff(np.r_[ang, ang[0] + 2 * np.pi]).max() >= np.pi:  # (the centre inside: convex)
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(0.5, 2.0)
    xy = np.c_[r * np.cos(ang), 0.7 * r * np.sin(ang)]  # (an ellipse: corners on a convex curve)
    area = 0.5 * abs(np.dot(xy[:, 0], np.roll(xy[:, 1], -1)) - np.dot(xy[:, 1], np.roll(xy[:, 0], -1)))
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return np.c_[xy, np.zeros(n)] @ Q.T + rng.normal(size=3), float(area)


def _triangle_areas(mesh: PolyMesh) -> np.ndarray:
    P = mesh.vertices[np.asarray(mesh.faces)]
    return 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)


def _edge_set(mesh: PolyMesh) -> set[tuple[int, int]]:
    return set(map(tuple, mesh.edges.tolist()))


def test_the_split_covers_every_planar_convex_face_exactly_and_keeps_its_edges():
    """Polygons of 3 to 9 corners in random planes: the triangles of each face add up to its
    shoelace area, each turns the face's way (its normal along the face's), the face's edges
    are all kept, and n − 3 diagonals are added per n-gon."""
    rng = np.random.default_rng(7)
    V, faces, areas = [], [], []
    for n in [3, 4, 4, 5, 6, 7, 8, 9] * 3:
        P, a = _convex_polygon(n, rng)
        faces.append(list(range(len(V), len(V) + n)))
        V.extend(P.tolist())
        areas.append(a)
    mesh = PolyMesh.from_faces(np.array(V), faces)
    out = split_faces(mesh)
    assert out.is_triangular and np.array_equal(out.vertices, mesh.vertices)
    sizes = mesh.face_sizes
    assert out.n_faces == int((sizes - 2).sum())
    owner = np.repeat(np.arange(mesh.n_faces), sizes - 2)  # (face order kept: each face's triangles in place)
    np.testing.assert_allclose(np.bincount(owner, weights=_triangle_areas(out)), areas, rtol=1e-12)
    T = out.vertices[np.asarray(out.faces)]
    tri_normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    P = [mesh.vertices[f] for f in faces]
    face_normal = np.array([np.cross(p - p.mean(0), np.roll(p, -1, 0) - p.mean(0)).sum(0) for p in P])
    assert (np.einsum("ij,ij->i", tri_normal, face_normal[owner]) > 0).all()
    assert _edge_set(mesh) <= _edge_set(out)
    assert out.n_edges - mesh.n_edges == int((sizes - 3).sum())


def test_the_split_keeps_the_euler_characteristic_and_the_boundary():
    """A quad barrel vault and a dome of quads and triangles: V − E + F and the boundary loops
    are unchanged, supports and vertex data carry over as they are."""
    for scene in (make_shape("barrel_vault", nx=5, ny=7), meridian_dome(parallels=4, meridians=9)):
        m = scene.mesh
        t = split_scene(scene)
        assert (m.n_vertices - m.n_edges + m.n_faces) == (t.mesh.n_vertices - t.mesh.n_edges + t.mesh.n_faces)
        assert [sorted(b.tolist()) for b in m.boundary_loops] == [sorted(b.tolist()) for b in t.mesh.boundary_loops]
        assert np.array_equal(t.supports, scene.supports) and t.name == scene.name


def test_a_quad_splits_along_its_shorter_diagonal_whichever_corner_comes_first():
    """A trapezoid 0 (0,0), 1 (4,0), 2 (3,1), 3 (1,1) whose diagonals 0-2 and 1-3 are both √10 in
    plan: lifting corner 2 by 0.5 lengthens 0-2 to √10.25, so the split takes 1-3; lifting corner 3
    instead lengthens 1-3, so it takes 0-2. Every rotation of the corner order gives the same
    diagonal."""
    base = np.array([[0, 0, 0], [4, 0, 0], [3, 1, 0], [1, 1, 0.]])
    for lifted, diagonal in ((2, (1, 3)), (3, (0, 2))):
        V = base.copy()
        V[lifted, 2] = 0.5
        for k in range(4):
            face = np.roll([0, 1, 2, 3], k).tolist()
            out = split_faces(PolyMesh.from_faces(V, [face]))
            added = _edge_set(out) - {tuple(sorted((face[i], face[(i + 1) % 4]))) for i in range(4)}
            assert added == {diagonal}, (lifted, k, added)


def test_equal_diagonals_split_as_the_fan_from_corner_0():
    """A flat square grid (diagonals equal up to round-off): the split is the fan of
    selfsupport.core.evidence.triangulate, triangle for triangle."""
    t = np.linspace(0.0, 1.0, 5)
    x, y = np.meshgrid(t, t)
    V = np.c_[x.ravel(), y.ravel(), np.zeros(25)]
    quads = [[j * 5 + i, j * 5 + i + 1, (j + 1) * 5 + i + 1, (j + 1) * 5 + i] for j in range(4) for i in range(4)]
    mesh = PolyMesh.from_faces(V, quads)
    assert np.array_equal(np.asarray(split_faces(mesh).faces), triangulate(mesh))


def test_a_quad_with_one_reflex_or_straight_corner_splits_from_that_corner():
    """A thin dart 0 (0,0), 1 (10,0.5), 2 (2,0), 3 (10,−0.5), reflex at 2: its shorter diagonal 1-3
    (length 1) lies outside it, so the split takes 0-2 (length 2), and the two triangles cover its
    shoelace area 1. A triangle with a fourth vertex on one side (straight at 2) splits from that
    vertex, into two triangles of positive area."""
    dart = PolyMesh.from_faces(np.array([[0, 0, 0], [10, 0.5, 0], [2, 0, 0], [10, -0.5, 0]]), [[0, 1, 2, 3]])
    out = split_faces(dart)
    assert _edge_set(out) - _edge_set(dart) == {(0, 2)}
    assert _triangle_areas(out).sum() == pytest.approx(1.0, rel=1e-12)
    side = PolyMesh.from_faces(np.array([[0, 0, 0], [4, 0, 0], [2, 2, 0], [0, 4, 0.]]), [[1, 2, 3, 0]])
    out = split_faces(side)  # (2, 2) lies on the side from (4, 0) to (0, 4)
    assert _edge_set(out) - _edge_set(side) == {(0, 2)}
    np.testing.assert_allclose(_triangle_areas(out), [4.0, 4.0], rtol=1e-12)


@pytest.mark.parametrize("corners, face, vertex, kind", [
    ([[0, 0, 0], [4, 0, 0], [4, 4, 0], [2, 1, 0.2], [0, 4, 0]], "0 1 2 3 4", 3, "reflex"),  # an arrow
    ([[0, 0, 0], [4, 0, 0], [2, 2, 0], [0, 4, 0], [-1, 1, 0]], "0 1 2 3 4", 2, "straight"),
    ([[0, 0, 0], [3, 0, 0], [0, 1, 0], [2, 1.2, 0]], "0 1 2 3", 2, "reflex"),  # a bow-tie: corners 2, 3
])
def test_a_face_that_is_not_convex_is_refused_by_name(corners, face, vertex, kind):
    """An arrow-shaped pentagon (reflex), a pentagon with a vertex on a side (straight) and a
    self-crossing quad (two corners turn the wrong way): refused, naming the face, the corner and
    what to do. (The triangle before it is face 0.)"""
    V = np.r_[np.array(corners, float), [[9, 9, 9], [9, 10, 9], [10, 9, 9]]]
    n = len(corners)
    mesh = PolyMesh.from_faces(V, [[n, n + 1, n + 2], list(range(n))])
    with pytest.raises(MeshError, match=rf"face 1 \(vertices {face}\) .* corner at vertex {vertex} is {kind}.*"
                                        r"split that face by hand"):
        split_faces(mesh)


def test_solve_triangulate_refuses_a_non_convex_face_in_one_line(tmp_path, capsys):
    V = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [2, 1, 0.5], [0, 4, 0], [2, 6, 0]], float)
    obj = tmp_path / "arrow.obj"
    write_mesh(obj, PolyMesh.from_faces(V, [[0, 1, 2, 3, 4], [4, 3, 2, 5]]), up="z")
    out = tmp_path / "net.json"
    code = cli.main(["solve", str(obj), "--up", "z", "--supports", "boundary", "--triangulate", "--out", str(out), "-q"])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle="is not convex in its plane")
    assert not out.exists()


def test_planar_faces_and_triangulate_together_are_refused(tmp_path, capsys):
    out = tmp_path / "net.json"
    code = cli.main(["solve", "shape:barrel_vault:60", "--triangulate", "--planar", "--out", str(out), "-q"])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle="drop --planar or --triangulate")
    assert not out.exists()
    with pytest.raises(Exception, match="a triangulated mesh has none"):
        api.solve(make_shape("barrel_vault", n_vertices=60), triangulate=True, constraints=[Planar(tol=1e-3)])


# ------------------------------------------------------------------ edge data on the split mesh
def test_sss_edge_weights_stay_on_their_edges_and_diagonals_are_written_as_zero(tmp_path):
    scene = make_shape("barrel_vault", nx=4, ny=5)
    E = scene.mesh.edges
    w = np.arange(1.0, len(E) + 1)
    path = tmp_path / "vault.sss"
    write_scene_sss(path, Scene(scene.mesh, scene.supports, meta={"sss_edge_weights": np.c_[E, w]}))
    split = api.triangulated_design(path)
    again = tmp_path / "split.sss"
    write_scene_sss(again, split)
    stored = read_scene(again).meta["sss_edge_weights"]
    got = {(int(i), int(j)): x for i, j, x in stored}
    kept = {tuple(e): x for e, x in zip(E.tolist(), w)}
    assert len(got) == split.mesh.n_edges
    assert all(got[e] == x for e, x in kept.items())
    assert all(x == 0.0 for e, x in got.items() if e not in kept)


def test_bounds_from_a_file_hold_on_the_kept_edges_and_the_diagonals_take_the_defaults(tmp_path):
    """A w_max of 0.7 of what they carry on the quad edges that carry most in the triangulated
    solve, stated by vertex pair: the triangulated solve holds it there, and a diagonal is bounded
    only by the default (no upper bound)."""
    scene = make_shape("barrel_vault", nx=5, ny=7)
    free = api.solve(scene, triangulate=True)
    m = free.network.mesh
    quad_edges = _edge_set(scene.mesh)
    kept = np.array([tuple(e) in quad_edges for e in m.edges.tolist()])
    w = free.network.weights
    busy = kept & (w > 0.7 * w[kept].max())
    cap = 0.7 * float(w[busy].max())
    path = tmp_path / "cap.csv"
    path.write_text("i,j,w_min,w_max\n" + "\n".join(f"{i},{j},,{cap!r}" for i, j in m.edges[busy].tolist()) + "\n")
    res = api.solve(scene, triangulate=True, bounds=str(path))
    assert res.converged and np.array_equal(res.network.mesh.edges, m.edges)
    wb = res.network.weights
    assert wb[busy].max() <= cap * (1 + 1e-9) < w[busy].max()
    bounds = api.weight_bounds(api.triangulated_design(scene), bounds=str(path))
    assert np.isnan(bounds.upper[~kept]).all() and np.isfinite(bounds.upper[busy]).all()
    assert independent_check(res, tol=1e-8).ok


def test_a_network_file_is_triangulated_from_its_stored_reference(tmp_path, capsys):
    """Re-solving a quad network file with --triangulate solves its stored reference split
    into triangles, from that reference (the stored network's faces are not split), and the
    written reference is the split one."""
    first = tmp_path / "quads.json"
    assert cli.main(["solve", "shape:barrel_vault:60", "--out", str(first), "-q"]) == 0
    second = tmp_path / "tri.json"
    assert cli.main(["solve", str(first), "--triangulate", "--out", str(second), "-q"]) == 0
    out = capsys.readouterr().out
    d, q = json.loads(second.read_text()), json.loads(first.read_text())
    assert np.allclose(d["reference_vertices"], q["reference_vertices"])
    assert all(len(f) == 3 for f in d["reference_faces"]) and len(d["reference_faces"]) == 2 * len(q["faces"])
    assert "the stored reference triangulated" in d["parameters"]["design"]["start"]
    assert f"{len(q['faces'])} faces -> {2 * len(q['faces'])} triangles" in out


# ------------------------------------------------------------------ several load cases
def _free_edged_vault(n: int = 8) -> Scene:
    """An n × n quad vault over [−1, 1]² on three vertices at each corner and a 2 × 2 pillar in the
    middle, heights rising from the supports (0.9 (1 − exp(−(d / 0.35)²)), d the plan distance to the
    nearest support): the paper's vault-pillar layout, as many edges as horizontal equations."""
    t = np.linspace(-1.0, 1.0, n)
    x, y = np.meshgrid(t, t)
    sup, quads = vault_pillar_layout(n)
    P = np.c_[x.ravel(), y.ravel()]
    d = np.linalg.norm(P[:, None] - P[sup][None], axis=2).min(axis=1)
    V = np.c_[P, 0.9 * (1 - np.exp(-(d / 0.35) ** 2))]
    return Scene(PolyMesh.from_faces(V, quads), sup, name="free-edged vault")


def _vault_files(tmp_path) -> tuple[Scene, list[str]]:
    """The vault as OBJ and supports file, and a cases file: empty, and 5% of the self-weight at
    the highest free vertex."""
    scene = _free_edged_vault()
    obj, sup, toml = tmp_path / "vault.obj", tmp_path / "vault.supports", tmp_path / "cases.toml"
    write_mesh(obj, scene.mesh, up="z")
    sup.write_text("\n".join(map(str, np.flatnonzero(scene.supports))) + "\n")
    V, free = scene.mesh.vertices, np.flatnonzero(~scene.supports)
    v = int(free[np.argmax(V[free, 2])])
    weight = -float(SelfWeight().nodal(scene.mesh, V).sum())
    toml.write_text(f'[cases.empty]\n\n[cases.point]\npoint_loads = {{ "{v}" = {0.05 * weight!r} }}\n')
    return scene, [str(obj), "--up", "z", "--supports", str(sup), "--load-cases", str(toml)]


@pytest.mark.slow
def test_a_free_edged_quad_vault_blocks_two_cases_and_stands_under_them_triangulated(tmp_path, capsys):
    """Empty and a point load on the free-edged quad vault: as quads the solve stalls and its
    message names the plan's block and the option; with --triangulate it converges, every case
    in equilibrium by the independent checker, and the summary says what was split."""
    scene, args = _vault_files(tmp_path)
    quads, tri = tmp_path / "quads.json", tmp_path / "tri.json"
    code = cli.main(["solve", *args, "--time-limit", "10", "--out", str(quads), "-q"])
    err = capsys.readouterr().err
    assert code == 4 and "horizontal self-stresses" in err and "solve --triangulate" in err, err
    code = cli.main(["solve", *args, "--triangulate", "--time-limit", "30", "--out", str(tri), "-q"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    d = json.loads(tri.read_text())
    assert d["status"] == "converged" and len(d["load_cases"]) == 2
    assert f"{scene.mesh.n_faces} faces -> {2 * scene.mesh.n_faces} triangles" in captured.out
    for case in d["load_cases"]:
        report = independent_check({**d, "weights": case["weights"], "loads": case["loads"]}, tol=1e-8)
        assert report.ok, (case["name"], report.stdout)


def test_the_triangulated_free_edged_vault_stands_under_two_cases(tmp_path, capsys):
    """The fast half of the test above: with --triangulate the two cases converge, each case in
    equilibrium by the independent checker, the mesh's faces split in two and every vertex and
    support kept."""
    scene, args = _vault_files(tmp_path)
    tri = tmp_path / "tri.json"
    code = cli.main(["solve", *args, "--triangulate", "--time-limit", "30", "--out", str(tri), "-q"])
    assert code == 0, capsys.readouterr().err
    d = json.loads(tri.read_text())
    assert d["status"] == "converged" and d["parameters"]["triangulated"]["triangles"] == 2 * scene.mesh.n_faces
    assert len(d["faces"]) == 2 * scene.mesh.n_faces and sorted(d["supports"]) == np.flatnonzero(scene.supports).tolist()
    for case in d["load_cases"]:
        report = independent_check({**d, "weights": case["weights"], "loads": case["loads"]}, tol=1e-8)
        assert report.ok, (case["name"], report.stdout)


def test_subdivide_then_triangulate_splits_the_refined_quads(tmp_path, capsys):
    """--subdivide refines first (Catmull–Clark makes quads), then --triangulate splits every
    refined quad: 4 × 48 quads of the 60-vertex barrel vault, 384 triangles, and the supports of
    the subdivided design."""
    out = tmp_path / "net.json"
    code = cli.main(["solve", "shape:barrel_vault:60", "--subdivide", "1", "--triangulate", "--out", str(out), "-q"])
    assert code == 0, capsys.readouterr().err
    d = json.loads(out.read_text())
    sub = subdivide_scene(make_shape("barrel_vault", n_vertices=60), 1)
    assert sub.mesh.n_faces == 4 * 48 and d["parameters"]["triangulated"]["faces"] == sub.mesh.n_faces
    assert len(d["faces"]) == 2 * sub.mesh.n_faces and all(len(f) == 3 for f in d["faces"])
    assert sorted(d["supports"]) == np.flatnonzero(sub.supports).tolist()


def test_the_load_case_study_triangulates_by_the_solve_option(tmp_path):
    """The study's triangulated variant solves the scene file itself with --triangulate, and its
    plan count is that of the split design (active edges less twice the free vertices); with
    --variants it runs that variant alone."""
    from studies import load_cases as study

    scene = _free_edged_vault()
    write_scene_sss(tmp_path / "vault.sss", scene)
    (job,) = study.jobs(tmp_path, ("vault",), (0.01, 0.05), ("triangulated",))
    assert job["variant"] == "triangulated" and job["point_share"] == 0.05 and "--triangulate" in job["extra"]
    split = split_scene(api.as_scene(str(tmp_path / "vault.sss")))
    assert job["plan_count"] == int(split.active_edges.sum()) - 2 * int(split.free.sum())
    # one more than the quads' count per diagonal that carries a weight (not between two supports)
    quad_edges = _edge_set(scene.mesh)
    added = np.array([tuple(e) not in quad_edges for e in split.mesh.edges.tolist()])
    assert 0 < int((added & split.active_edges).sum()) < scene.mesh.n_faces
    assert job["plan_count"] == study.plan_count(study.design(tmp_path / "vault.sss")) + int((added & split.active_edges).sum())
