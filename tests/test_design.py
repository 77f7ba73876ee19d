"""Design operations: Laplacian handle edits, Catmull–Clark, edits, warm re-solves and
edit scripts — on generated meshes only."""
from __future__ import annotations

import numpy as np
import pytest

from selfsupport.core.mesh import PolyMesh
from selfsupport.core.shapes import make_shape
from selfsupport.core.subdivision import catmull_clark, subdivide_scene
from selfsupport.design.edits import Cut, Delete, Design, Pillar, Select, cut_along
from selfsupport.design.laplacian import LaplacianEditor, laplacian_matrix, ring_region
from selfsupport.design.script import EditScript, replay
from selfsupport.methods.staggered import StaggeredLinearization
from tests.conftest import independent_check, requires_checker


def grid(n: int = 9, jitter: float = 0.0, mixed: bool = False, seed: int = 0) -> PolyMesh:
    """A planar n×n vertex grid (z = 0) of quads; ``mixed`` splits every third quad in two (not the corner quads of n = 7)."""
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.c_[xs.ravel(), ys.ravel(), np.zeros(n * n)]
    interior = (xs.ravel() > 0) & (xs.ravel() < 1) & (ys.ravel() > 0) & (ys.ravel() < 1)
    V[interior, :2] += np.random.default_rng(seed).uniform(-jitter, jitter, (int(interior.sum()), 2))
    faces = []
    for k, (j, i) in enumerate((j, i) for j in range(n - 1) for i in range(n - 1)):
        q = [j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i]
        faces += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] if mixed and k % 3 == 1 else [q]
    return PolyMesh.from_faces(V, faces)


# ----------------------------------------------------------------------------- Laplacian
def test_laplacian_edit_reproduces_handles_exactly() -> None:
    mesh = make_shape("dome", n_vertices=300).mesh
    h = np.zeros(mesh.n_vertices, bool)
    h[[int(np.argmax(mesh.vertices[:, 2])), 40, 41]] = True
    ed = LaplacianEditor(mesh, h, roi=ring_region(mesh, h, 5))
    target = mesh.vertices[h] + np.array([[0.3, -0.2, 0.7], [0.1, 0.1, -0.4], [0.0, 0.2, 0.3]])
    V = ed.deform(target)
    assert np.array_equal(V[h], target)
    outside = ~ring_region(mesh, h, 5)
    assert np.array_equal(V[outside], mesh.vertices[outside])  # anchors stay


@pytest.mark.parametrize("mixed", [False, True])
def test_affine_move_keeps_a_plane_planar(mixed: bool) -> None:
    """Mean-value Laplacian coordinates reproduce affine maps on a planar (irregular, mixed) mesh:
    handles and anchors moved by one affine map give exactly that map everywhere."""
    mesh = grid(11, jitter=0.03, mixed=mixed)
    A = np.array([[1.1, 0.2, 0.1], [-0.1, 0.9, 0.3], [0.2, -0.3, 1.2]])
    b = np.array([0.1, 0.2, 0.3])
    h = mesh.boundary_vertex_mask.copy()
    h[60] = True
    V = LaplacianEditor(mesh, h).deform(mesh.vertices[h] @ A.T + b)
    np.testing.assert_allclose(V, mesh.vertices @ A.T + b, atol=1e-12)
    # planar: every vertex on the plane through three of them
    nrm = np.cross(V[1] - V[0], V[12] - V[0])
    assert np.abs((V - V[0]) @ nrm).max() < 1e-12 * np.linalg.norm(nrm)


def test_height_and_top_view_edits_keep_the_other_coordinates() -> None:
    mesh = make_shape("dome", n_vertices=300).mesh
    h = np.zeros(mesh.n_vertices, bool)
    h[int(np.argmax(mesh.vertices[:, 2]))] = True
    ed = LaplacianEditor(mesh, h, roi=ring_region(mesh, h, 6))
    moved = mesh.vertices[h] + [0.4, -0.3, 0.8]
    Vh = ed.deform(moved, mode="height")
    assert np.array_equal(Vh[:, :2], mesh.vertices[:, :2])
    assert Vh[h, 2] == pytest.approx(moved[:, 2]) and (Vh[:, 2] > mesh.vertices[:, 2] + 1e-6).sum() > 10
    Vt = ed.deform(moved, mode="top_view")
    assert np.array_equal(Vt[:, 2], mesh.vertices[:, 2])
    np.testing.assert_allclose(Vt[h, :2], moved[:, :2])
    assert ed.solves == 2  # one factor served both edits


def test_laplacian_rows_sum_to_zero_and_planar_interior_rows_vanish() -> None:
    mesh = grid(7, jitter=0.05, mixed=True)
    L = laplacian_matrix(mesh)
    assert np.abs(np.asarray(L.sum(axis=1)).ravel()).max() < 1e-12
    delta = L @ mesh.vertices
    assert np.abs(delta[~mesh.boundary_vertex_mask]).max() < 1e-12  # linear precision


# ---------------------------------------------------------------------------- Catmull-Clark
def test_catmull_clark_stencils_on_a_regular_grid() -> None:
    rng = np.random.default_rng(3)
    n = 6
    mesh0 = grid(n)
    mesh = mesh0.with_vertices(np.c_[mesh0.vertices[:, :2], rng.normal(size=n * n)])  # non-planar heights
    s = catmull_clark(mesh)
    V, W = mesh.vertices, s.mesh.vertices
    faces = mesh.faces
    fp = np.array([V[f].mean(0) for f in faces])
    np.testing.assert_allclose(W[s.face_point(np.arange(len(faces)))], fp, atol=1e-14)  # face point = average
    E, ef = mesh.edges, mesh.edge_faces
    for k in range(mesh.n_edges):
        a, b = E[k]
        if (ef[k] >= 0).all():  # edge point = average of the ends and the two face points
            want = (V[a] + V[b] + fp[ef[k, 0]] + fp[ef[k, 1]]) / 4
        else:  # boundary: the midpoint (cubic B-spline curve)
            want = (V[a] + V[b]) / 2
        np.testing.assert_allclose(W[s.edge_point(k)], want, atol=1e-14)
    nb = mesh.vertex_neighbors
    for v in range(mesh.n_vertices):
        if mesh.boundary_vertex_mask[v]:
            bn = [u for u in nb[v] if mesh.boundary_vertex_mask[u] and
                  mesh.boundary_edge_mask[np.flatnonzero((E == sorted((v, u))).all(1))[0]]]
            if len(nb[v]) == 2:  # a grid corner stays
                want = V[v]
            else:  # boundary rule: the cubic B-spline curve (a + 6v + b) / 8
                want = (V[bn[0]] + 6 * V[v] + V[bn[1]]) / 8
        else:
            k = len(nb[v])
            Q = np.mean([fp[f] for f in range(len(faces)) if v in faces[f]], axis=0)
            R = np.mean([(V[v] + V[u]) / 2 for u in nb[v]], axis=0)
            want = (Q + 2 * R + (k - 3) * V[v]) / k
        np.testing.assert_allclose(W[v], want, atol=1e-14)


def test_catmull_clark_keeps_boundary_and_reproduces_a_plane() -> None:
    mesh = grid(7, jitter=0.04, mixed=True)
    s = catmull_clark(mesh)
    assert s.mesh.is_valid() and np.all(np.diff(s.mesh.face_offsets) == 4)
    assert s.mesh.n_faces == int(mesh.face_sizes.sum())
    assert np.abs(s.mesh.vertices[:, 2]).max() == 0.0  # a plane stays the plane
    # the outline stays on the unit square's sides, corners stay
    Wb = s.mesh.vertices[s.mesh.boundary_vertex_mask]
    assert (np.isclose(Wb[:, :2], 0) | np.isclose(Wb[:, :2], 1)).any(axis=1).all()
    for c in ([0, 0], [1, 0], [0, 1], [1, 1]):
        assert np.linalg.norm(s.mesh.vertices[:, :2] - c, axis=1).min() < 1e-15
    assert len(s.mesh.boundary_loops) == 1


def test_subdivision_carries_supports() -> None:
    scene = make_shape("barrel_vault", n_vertices=150)
    sub = subdivide_scene(scene, 1)
    assert np.array_equal(sub.supports, sub.mesh.boundary_vertex_mask)  # whole boundary supported, as before
    springing = np.isclose(np.abs(sub.mesh.vertices[:, 0]), np.abs(scene.mesh.vertices[:, 0]).max())
    assert sub.supports[springing].all() and np.all(sub.mesh.vertices[springing, 2] == 0.0)  # still on the ground


def test_a_subdivided_scene_remembers_its_coarser_scenes_until_it_is_edited() -> None:
    """``subdivision_parents``: the scenes of every step, coarsest first, each the subdivision of
    the one before (subdividing them one step at a time gives the same meshes); after an edit of
    positions or supports the coarser scenes no longer describe this design, and none are given."""
    from dataclasses import replace

    from selfsupport.core.subdivision import subdivision_parents

    scene = make_shape("pillar_vault", n_vertices=120)
    fine = subdivide_scene(scene, 2)
    parents = subdivision_parents(fine)
    assert parents[0] is scene and len(parents) == 2
    once = subdivide_scene(scene, 1)
    assert np.array_equal(parents[1].mesh.vertices, once.mesh.vertices)
    assert np.array_equal(parents[1].supports, once.supports)
    assert [p.mesh.n_vertices for p in subdivision_parents(subdivide_scene(fine, 1))] == \
        [p.mesh.n_vertices for p in (*parents, fine)]  # a further step extends the chain
    moved = fine.mesh.vertices.copy()
    moved[7, 2] += 1e-9
    assert subdivision_parents(replace(fine, mesh=fine.mesh.with_vertices(moved))) == ()
    pinned = fine.supports.copy()
    pinned[np.flatnonzero(~pinned)[0]] = True
    assert subdivision_parents(replace(fine, supports=pinned)) == ()
    assert subdivision_parents(scene) == ()


@requires_checker
def test_upsampled_then_polished_network_passes_the_checker() -> None:
    method = StaggeredLinearization()
    scene = make_shape("barrel_vault", n_vertices=150)
    coarse = method.solve(Design(scene).problem())
    assert coarse.status == "converged"
    fine = subdivide_scene(scene.__class__(mesh=coarse.network.mesh, supports=scene.supports, name="net"), 1)
    res = method.solve(Design(fine).problem(), warm_start=coarse.network)
    assert res.status == "converged" and res.network.mesh.n_vertices == fine.mesh.n_vertices
    rep = independent_check(res, tol=1e-8)
    assert rep.ok, rep.stdout


# ------------------------------------------------------------------------------ edits
def test_pillar_hole_delete_and_cut() -> None:
    d = Design(make_shape("barrel_vault", n_vertices=200))
    n = d.scene.mesh.n_vertices
    p = Pillar(select=Select(nearest=(0.5, 0.5), relative=True), hole=True).apply(d)
    rim = p.scene.supports & ~d.scene.supports[p.origin]
    assert rim.sum() == 8 and p.scene.mesh.n_vertices == n - 1
    assert np.allclose(p.scene.mesh.vertices[rim, 2], d.scene.mesh.vertices[d.scene.supports, 2].min())
    h = Delete(select=Select(near=(0.3, 0.3), radius=0.08, relative=True), support=True).apply(d)
    assert len(h.scene.mesh.boundary_loops) == 2 and h.scene.mesh.is_valid()
    # a cut across the vault from gable to gable, along a grid line: the vertices on it split
    V = d.scene.mesh.vertices
    line = np.flatnonzero(np.isclose(V[:, 0], V[np.argmin(np.abs(V[:, 0])), 0]))
    chain = line[np.argsort(V[line, 1])]
    c = cut_along(d, chain)
    assert c.scene.mesh.n_vertices == n + len(chain) and c.scene.mesh.is_valid()
    assert len(c.scene.mesh.boundary_loops) == 2
    c2 = Cut(path=((0.5, 0.0), (0.5, 1.0)), relative=True, support=True).apply(d)
    assert c2.scene.mesh.n_vertices > n and c2.scene.supports.sum() > d.scene.supports.sum()


# ------------------------------------------------------------------------- warm re-solve
def test_warm_resolve_reaches_the_cold_network_in_fewer_iterations() -> None:
    """A small height edit (2e-3 of the diagonal) of a concave disk (cold: ~25 iterations)."""
    method = StaggeredLinearization()
    scene = make_shape("concave_disk", n_vertices=400)
    base = method.solve(Design(scene).problem())
    mesh = scene.mesh
    V0 = mesh.vertices
    c = V0[:, :2].mean(0) + 0.2 * np.ptp(V0[:, :2], axis=0)
    h = np.zeros(mesh.n_vertices, bool)
    h[int(np.argmin(np.linalg.norm(V0[:, :2] - c, axis=1)))] = True
    diag = float(np.linalg.norm(np.ptp(V0, axis=0)))
    V = LaplacianEditor(mesh, h, roi=ring_region(mesh, h, 5), fixed=scene.supports).deform(
        V0[h] + [0, 0, 0.002 * diag], mode="height")
    edited = Design(scene.__class__(mesh=mesh.with_vertices(V), supports=scene.supports, name="edited"))
    cold = method.solve(edited.problem())
    warm = method.solve(edited.problem(), warm_start=base.network)
    assert cold.status == warm.status == "converged"
    assert warm.parameters["warm_start"] == {"same_topology": True, "used": True}
    assert warm.iterations < cold.iterations
    assert warm.max_relative_error <= 1e-9
    # The nearest network is not unique along the staggered path: both are in equilibrium and as
    # close to the reference (measured: mean distance 6.82e-3 vs 6.73e-3 of the diagonal), and
    # they differ pointwise by at most 4.8e-3 of the diagonal (the same order as that distance).
    assert warm.distance_mean <= 1.05 * cold.distance_mean
    gap = float(np.linalg.norm(warm.network.vertices - cold.network.vertices, axis=1).max()) / diag
    assert gap < 1e-2


def test_a_warm_start_that_does_not_finish_restarts_cold_and_ends_where_the_cold_solve_does() -> None:
    """A top-view move of 3% of the diagonal: the warm start's first fit is far from equilibrium.
    With a large ``warm_accept`` it gets its one polish; whether or not that finishes, the result is
    either a warm network as close to the reference as the cold one, or exactly the cold solve."""
    scene = make_shape("concave_disk", n_vertices=300)
    base = StaggeredLinearization().solve(Design(scene).problem())
    mesh = scene.mesh
    V0 = mesh.vertices
    h = np.zeros(mesh.n_vertices, bool)
    h[int(np.argmin(np.linalg.norm(V0[:, :2] - V0[:, :2].mean(0) - 0.2 * np.ptp(V0[:, :2], 0), axis=1)))] = True
    diag = float(np.linalg.norm(np.ptp(V0, axis=0)))
    V = LaplacianEditor(mesh, h, roi=ring_region(mesh, h, 5), fixed=scene.supports).deform(
        V0[h] + [0.03 * diag, 0, 0], mode="top_view")
    edited = Design(scene.__class__(mesh=mesh.with_vertices(V), supports=scene.supports, name="edited"))
    cold = StaggeredLinearization().solve(edited.problem())
    for accept in (0.0, 10.0):
        warm = StaggeredLinearization(warm_accept=accept).solve(edited.problem(), warm_start=base.network)
        assert warm.status == cold.status == "converged" and warm.max_relative_error <= 1e-9
        info = warm.parameters["warm_start"]
        if info["used"]:
            assert accept > 0 and warm.distance_mean <= 1.05 * cold.distance_mean
        else:  # the fallback is the cold solve (the active set the warm fit left differs: ~1e-10)
            assert info["first_error"] > 0.1
            gap = np.abs(warm.network.vertices - cold.network.vertices).max() / diag
            assert gap < 1e-8, (accept, gap)


# ----------------------------------------------------------------------------- scripts
SCRIPT = """
[start]
scene = "shape:barrel_vault:150"
density = 1800.0
thickness = 0.12

[[edit]]
op = "raise"
select = { nearest = [0.5, 0.5], relative = true }
by = 0.02
relative_dummy_removed = 0
"""


@pytest.mark.parametrize("table, needle", [
    ('select = { nearest = [nan, nan] }', "nearest[0] must be a finite number"),
    ('select = { nearest = [0.5] }', "nearest must be a list of 2 entries"),
    ('select = { nearest = ["x", 0.5] }', "nearest[0] must be a finite number, got 'x'"),
    ('select = { nearest = [0.5, 0.5], relative = "yes" }', "relative must be true or false"),
    ('select = { nearest = [0.5, 0.5] }\nroi_rings = -1', "roi_rings=-1 is out of range: it must lie in [0, inf)"),
    ('select = { nearest = [0.5, 0.5] }\nroi_rings = 2.5', "roi_rings must be an integer, got 2.5"),
    ('select = { nearest = [0.5, 0.5] }\nroi_radius = -0.1', "roi_radius=-0.1 is out of range"),
    ('select = { nearest = [0.5, 0.5] }\nsolve = "false"', "solve must be true or false (no quotes), got 'false'"),
    ('select = { nearest = [0.5, 0.5] }\nby = inf', "by must be a finite number"),
])
def test_edit_script_fields_are_checked_strictly_when_the_script_is_read(table, needle) -> None:
    """A string is not a bool ("false" is true in Python), NaN is no point, a negative ring count
    is no region: each is refused when the script is parsed, naming the edit and the field."""
    from selfsupport.core.errors import InputError

    text = '[start]\nscene = "shape:dome:80"\n[[edit]]\nop = "raise"\n' + table + "\n"
    with pytest.raises(InputError) as e:
        EditScript.loads(text)
    assert needle in str(e.value) and "[[edit]] number 1" in str(e.value)


@pytest.mark.parametrize("start, needle", [
    ('density = "x"', "density must be a finite number, got 'x'"),
    ("thickness = -0.1", "thickness must be positive"),
    ("w_max = nan", "w_max must be a finite number"),
])
def test_edit_script_start_values_are_checked_when_the_script_is_read(start, needle) -> None:
    from selfsupport.core.errors import InputError

    with pytest.raises(InputError, match="edit script \\[start\\]") as e:
        EditScript.loads('[start]\nscene = "shape:dome:80"\n' + start + "\n")
    assert needle in str(e.value)


def test_cli_edit_refuses_a_bad_script_in_one_line_before_any_work(tmp_path, capsys) -> None:
    from selfsupport.cli import main

    script = tmp_path / "e.toml"
    script.write_text('[start]\nscene = "shape:dome:80"\n[[edit]]\nop = "pin"\nselect = { vertices = [3] }\n'
                      'solve = "false"\n')
    out = tmp_path / "out"
    assert main(["edit", str(script), "--out", str(out), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "solve must be true or false" in err and not out.exists()


def test_edit_script_round_trips_and_replays_deterministically() -> None:
    text = SCRIPT.replace("relative_dummy_removed = 0\n", "roi_rings = 3\n") + """
[[edit]]
op = "pin"
select = { vertices = [20, 21] }
solve = false

[[edit]]
op = "material"
w_max = 0.0
density = 2000.0

[[edit]]
op = "delete"
select = { near = [0.3, 0.7], radius = 0.06, relative = true }
"""
    s = EditScript.loads(text)
    assert [e.op for e in s.edits] == ["raise", "pin", "material", "delete"]
    again = EditScript.loads(s.dumps())
    assert again.to_dict() == s.to_dict() and again.edits == s.edits
    a, b = replay(s), replay(again)
    assert len(a) == 4  # start, raise, pin+material, delete
    for x, y in zip(a, b):
        assert x.result.status == "converged"
        assert np.array_equal(x.result.network.vertices, y.result.network.vertices)
        assert np.array_equal(x.result.network.weights, y.result.network.weights)
    assert a[2].design.density == 2000.0 and a[1].warm


def test_a_subdivide_stage_goes_up_from_the_previous_network_by_its_stress() -> None:
    """A ``subdivide`` stage (two steps) starts from the previous stage's network and goes up level
    by level (:class:`Multilevel` with that network as the coarse level's start); the fine network
    stands by the independent checker."""
    s = EditScript.loads("""
[start]
scene = "shape:pillar_vault:150"

[[edit]]
op = "subdivide"
levels = 2
""")
    start, sub = replay(s)
    assert start.result.status == "converged" and sub.warm
    res = sub.result
    levels = res.parameters["multilevel"]["levels"]
    assert res.method == "multilevel" and res.status == "converged" and res.max_relative_error <= 1e-9
    assert [lv["n_vertices"] for lv in levels] == [start.design.scene.mesh.n_vertices,
                                                   subdivide_scene(start.design.scene, 1).mesh.n_vertices,
                                                   sub.design.scene.mesh.n_vertices]
    # the previous network confirmed as it is, the fine level from the carried stress (the
    # middle one, carried 2.6x farther from its reference than the level below, is solved
    # cold: the multilevel RECLAIM rule)
    assert levels[0]["iterations"] == 1 and levels[-1]["iterations"] == 1
    assert all(lv["status"] == "converged" for lv in levels)
    assert levels[-1]["prolongation"]["by"] == "stress"
    assert independent_check(res).ok


def test_edit_script_rejects_unknown_keys() -> None:
    from selfsupport.core.errors import InputError

    with pytest.raises(InputError, match="unknown key"):
        EditScript.loads(SCRIPT)
    with pytest.raises(InputError, match="unknown edit op"):
        EditScript.loads('[[edit]]\nop = "explode"\n')
