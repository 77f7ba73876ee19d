"""Will it stand: the masonry hull, added loads, the maximum load, destruction.

Generated shells only (:func:`selfsupport.core.shapes.make_shape`). "Inside the hull" is checked by a
distance computed here (brute-force point-to-triangle distances in numpy), never by the
solver's own numbers; equilibrium by the shared independent checker.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from selfsupport import api
from selfsupport.core.errors import InputError
from selfsupport.core.shapes import make_shape
from selfsupport.methods.base import HULL_TOL
from selfsupport.structure.destruction import destroy, sub_scene
from selfsupport.structure.stability import max_load, solve_in_hull, stability_series
from tests.conftest import independent_check, requires_checker


# ------------------------------------------------------------------ an independent distance
def point_triangle_distance(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Distance from each point P (k, 3) to each triangle (m, 3) -> (k, m), by projecting onto
    the plane and, when the projection falls outside, taking the nearest edge point (Ericson's
    region test replaced by the min over the three edges, which is exact as well)."""
    P = P[:, None, :]
    n = np.cross(B - A, C - A)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    dp = np.einsum("kmj,mj->km", P - A, n)
    Q = P - dp[..., None] * n  # projection onto each plane

    def inside(Q):
        c1 = np.einsum("kmj,mj->km", np.cross(B - A, Q - A), n)
        c2 = np.einsum("kmj,mj->km", np.cross(C - B, Q - B), n)
        c3 = np.einsum("kmj,mj->km", np.cross(A - C, Q - C), n)
        return (c1 >= 0) & (c2 >= 0) & (c3 >= 0)

    def seg(P, U, W):
        d = W - U
        s = np.clip(np.einsum("kmj,mj->km", P - U, d) / np.einsum("mj,mj->m", d, d), 0, 1)
        return np.linalg.norm(P - (U + s[..., None] * d), axis=2)

    edge = np.minimum(np.minimum(seg(P, A, B), seg(P, B, C)), seg(P, C, A))
    return np.where(inside(Q), np.abs(dp), edge)


def distance_to_mesh(points: np.ndarray, mesh) -> np.ndarray:
    """Unsigned distance of each point to a triangle mesh (fans for polygons), brute force."""
    tris = []
    for f in mesh.faces:
        tris += [(f[0], f[k], f[k + 1]) for k in range(1, len(f) - 1)]
    T = mesh.vertices[np.asarray(tris)]
    return point_triangle_distance(np.asarray(points, float), T[:, 0], T[:, 1], T[:, 2]).min(axis=1)


def assert_inside_hull(network, reference, t: float) -> None:
    d = distance_to_mesh(network.vertices, reference)
    free = ~np.asarray(network.supports)
    assert d[free].max() <= 0.5 * t * (1 + HULL_TOL), f"a free vertex is {d[free].max():.4g} m from the reference"


def test_independent_distance_is_right_on_a_triangle():
    A, B, C = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    P = np.array([[0.2, 0.2, 0.5], [2.0, 0.0, 0.0], [-1.0, -1.0, 1.0]])
    assert np.allclose(point_triangle_distance(P, A, B, C)[:, 0], [0.5, 1.0, np.sqrt(3.0)])


# ------------------------------------------------------------------ the hull
@requires_checker
def test_pillar_vault_solve_with_hull_stays_within_half_thickness(tmp_path, capsys):
    """``solve shape:pillar_vault --hull --thickness 0.5``: every free vertex within t/2 of the reference."""
    from selfsupport.cli import main
    from selfsupport.io import read_network

    out = tmp_path / "n.json"
    assert main(["solve", "shape:pillar_vault", "--hull", "--thickness", "0.5", "--out", str(out), "-q"]) == 0
    assert "stands: yes, certified by a network inside the hull" in " ".join(capsys.readouterr().out.split())
    net = read_network(out)
    ref = make_shape("pillar_vault").mesh
    assert_inside_hull(net, ref, 0.5)
    doc = json.loads(out.read_text())
    hull = doc["parameters"]["hull"]
    assert len(hull["signed_distance"]) == len(hull["inside"]) == ref.n_vertices and all(hull["inside"])
    assert independent_check(out).ok


def test_a_hull_search_that_finds_nothing_is_not_called_a_proof(tmp_path, capsys):
    """The thin hemisphere below through the CLI: the last line says the network written is in
    equilibrium but outside the hull, and that this proves no collapse (not the generic
    "no compressive network exists" of an infeasible solve)."""
    from selfsupport.cli import main
    from selfsupport.io import write_mesh

    scene = make_shape("dome", rings=8, radius=5.0, height=5.0)
    mesh, sup = tmp_path / "dome.obj", tmp_path / "dome.supports"
    write_mesh(mesh, scene.mesh)
    sup.write_text("\n".join(str(i) for i in np.flatnonzero(scene.supports)) + "\n")
    code = main(["solve", str(mesh), "--supports", str(sup), "--hull", "--thickness", "0.1",
                 "--out", str(tmp_path / "n.json"), "-q"])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 4 and "status infeasible" in last
    assert "but is not inside the masonry hull" in last and "no proof of collapse" in last
    assert "no compressive network exists" not in last


def test_thin_hemisphere_is_reported_infeasible():
    """Heyman (1977): a hemispherical dome needs t/R >= 0.042 under self-weight (no tension, thrust
    anywhere in the section). Here the supports even hold the thrust at the mid-surface, which can
    only raise that minimum, so at t/R = 0.02 no compressive network fits the hull; the discrete
    slack (chord sag ~h²/8R = 0.005 R at 8 rings) does not close the gap."""
    scene = make_shape("dome", rings=8, radius=5.0, height=5.0)
    res = solve_in_hull(api.problem(scene, thickness=0.1, constraints=["hull"]))
    hull = res.parameters["hull"]
    assert res.status == "infeasible" and not hull["certified"]
    assert hull["outside"] > 0 and hull["max_excess"] > 0.05
    assert len(hull["outside_vertices"]) == len(hull["outside_excess"]) == hull["outside"]
    assert "outside" in res.message and "stands: not certified" in hull["stands"]
    # and the thick one (t/R = 0.1) is certified, inside by the independent distance
    thick = solve_in_hull(api.problem(scene, thickness=0.5, constraints=["hull"]))
    assert thick.status == "converged" and thick.parameters["hull"]["certified"]
    assert_inside_hull(thick.network, scene.mesh, 0.5)
    assert thick.max_relative_error <= 1e-6 and thick.min_weight > 0


# ------------------------------------------------------------------ added loads
def test_thick_dome_carries_an_apex_load_a_thin_one_does_not():
    scene = make_shape("dome", rings=6, radius=5.0, height=3.0)
    thin, = stability_series(scene, thickness=0.1, loads_kg=[5000.0], density=2000.0, at=[0])
    thick, = stability_series(scene, thickness=0.3, loads_kg=[5000.0], density=2000.0, at=[0])
    assert not thin.certified and thin.result.status == "infeasible"
    assert thick.certified
    assert_inside_hull(thick.result.network, scene.mesh, 0.3)
    # the added mass is in the loads: 5000 kg g more than the self-weight alone
    sw = api.problem(scene, thickness=0.3).loads.nodal(scene.mesh, thick.result.network.vertices)[0]
    assert thick.result.network.loads.sum() - sw.sum() == pytest.approx(-5000.0 * 9.81, rel=1e-9)


@pytest.mark.slow
def test_max_load_grows_with_thickness():
    scene = make_shape("dome", rings=6, radius=5.0, height=3.0)
    m1 = max_load(scene, thickness=0.1, density=2000.0, at=[0], start_kg=500.0, rel_tol=0.1)
    m3 = max_load(scene, thickness=0.3, density=2000.0, at=[0], start_kg=500.0, rel_tol=0.1)
    assert m1.kg is not None and m3.kg is not None and m3.kg > 2 * m1.kg
    assert m1.upper_kg - m1.kg <= 0.1 * m1.upper_kg  # the stated tolerance
    assert m3.certificate.parameters["hull"]["certified"]
    assert_inside_hull(m3.certificate.network, scene.mesh, 0.3)


@requires_checker
def test_stability_cli_max_load_line(tmp_path, capsys):
    from selfsupport.cli import main

    rc = main(["stability", "shape:dome:127", "--thickness", "0.3", "--density", "2000", "--load-at", "0",
               "--max-load", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    lines = [ln for ln in out.splitlines() if ln.startswith("max load:")]
    assert len(lines) == 1
    kg = float(re.fullmatch(r"max load: (\S+) kg", lines[0]).group(1))
    assert kg > 0
    doc = json.loads((tmp_path / "max-load.json").read_text())
    assert doc["added_mass_kg"] == pytest.approx(kg, rel=1e-5) and doc["parameters"]["hull"]["certified"]  # (%g)
    assert independent_check(tmp_path / "max-load.json").ok


# ------------------------------------------------------------------ holes, several boundary loops
def _oculus_dome():
    """A dome with its central cap removed: two boundary loops, the inner one free."""
    scene = make_shape("dome", rings=7, radius=5.0, height=3.0)
    keep = [k for k, f in enumerate(scene.mesh.faces) if not (set(f) & set(range(7)))]
    sc, _ = sub_scene(scene, keep)
    return sc


@requires_checker
def test_a_dome_with_an_oculus_stands_in_its_hull():
    sc = _oculus_dome()
    assert len(sc.mesh.boundary_loops) == 2 and sc.mesh.isolated_vertices.size == 0
    res = solve_in_hull(api.problem(sc, thickness=0.3, constraints=["hull"]))
    assert res.parameters["hull"]["certified"]
    assert_inside_hull(res.network, sc.mesh, 0.3)
    assert independent_check(res).ok


# ------------------------------------------------------------------ destruction
@requires_checker
def test_destruction_is_deterministic_without_orphans_and_every_stage_is_in_equilibrium():
    scene = make_shape("barrel_vault", nx=8, ny=6, gables_supported=False)
    v = int(np.argmin(np.linalg.norm(scene.mesh.vertices[:, :2] - scene.mesh.vertices[:, :2].mean(0), axis=1)))
    a = destroy(scene, [v], thickness=0.05, density=2000.0)
    b = destroy(scene, [v], thickness=0.05, density=2000.0)
    assert [(s.faces, s.removed, s.vertices, s.status) for s in a] == [(s.faces, s.removed, s.vertices, s.status)
                                                                       for s in b]
    assert a[0].status == "stands" and len(a) > 2 and a[1].n_faces < a[0].n_faces
    assert all(x.n_faces > y.n_faces for x, y in zip(a, a[1:]))
    for s in a:
        if s.result is None:
            assert s.status == "empty" and not s.faces
            continue
        mesh = s.result.network.mesh
        assert mesh.isolated_vertices.size == 0  # never a vertex without faces
        used = sorted({u for k in s.faces for u in scene.mesh.faces[k]})
        assert list(s.vertices) == used
        assert independent_check(s.result).ok, f"stage {s.index}"
        if s.status == "stands":
            assert_inside_hull(s.result.network, s.scene.mesh, 0.05)


def test_chosen_faces_and_a_start_state_chain_removals():
    """``remove_faces`` deletes exactly those faces (plus what falls with them), and a sequence
    started from a previous one's final faces begins where that one ended."""
    scene = make_shape("barrel_vault", nx=8, ny=6, gables_supported=False)
    first = destroy(scene, remove_faces=[20, 21], thickness=0.2, density=2000.0)
    assert first[-1].status == "stands"
    assert {20, 21} <= set(first[1].removed) and not {20, 21} & set(first[-1].faces)
    second = destroy(scene, remove_faces=[5], faces=first[-1].faces, thickness=0.2, density=2000.0)
    assert second[0].faces == first[-1].faces and second[0].why_removed == "before the removal"
    assert 5 not in second[-1].faces and set(second[-1].faces) <= set(first[-1].faces)
    with pytest.raises(InputError):
        destroy(scene, remove_faces=[scene.mesh.n_faces], thickness=0.2)


def test_the_papers_cuts_are_recovered_from_renumbered_stages(tmp_path):
    """The destruction study's reading of published stages: OBJ files (y down, renumbered
    vertices, faces in another order) of a vault, the vault less a few faces (a cut) and less a
    third of them (a collapse): the lost faces are found, mapped back onto the scene's faces
    and classified."""
    from studies.destruction import paper_steps

    scene = make_shape("barrel_vault", nx=10, ny=8)
    V, F = scene.mesh.vertices, [list(f) for f in scene.mesh.faces]
    rng = np.random.default_rng(1)

    def write(path, keep):
        perm = rng.permutation(len(V))  # file vertex j is scene vertex perm[j]
        inv = np.argsort(perm)
        lines = [f"v {x:.9f} {-z:.9f} {y:.9f}" for x, y, z in V[perm]]
        lines += ["f " + " ".join(str(inv[v] + 1) for v in F[k]) for k in rng.permutation(sorted(keep))]
        path.write_text("\n".join(lines) + "\n")
        return path

    every = set(range(len(F)))
    cut = {11, 12, 13}
    collapse = set(range(len(F) // 3)) - cut
    files = [write(tmp_path / "s0.obj", every), write(tmp_path / "s1.obj", every - cut),
             write(tmp_path / "s2.obj", every - cut - collapse)]
    steps = paper_steps(scene, files)
    assert [s["kind"] for s in steps] == ["cut", "collapse"]
    assert set(steps[0]["paper_lost"]) == cut and set(steps[1]["paper_lost"]) == collapse
    assert [s["paper_faces"] for s in steps] == [len(F) - 3, len(F) - 3 - len(collapse)]


def test_the_default_load_points_are_the_free_handled_vertices():
    """A scene's handled vertices are where the added mass goes by default; one that is also
    pinned carries nothing (lilium-pillar has one) and is left out, not blamed on --load-at."""
    import dataclasses

    from selfsupport.structure.stability import spread_mass

    scene = make_shape("dome", n_vertices=100)
    free, pinned = np.flatnonzero(~scene.supports)[:3], np.flatnonzero(scene.supports)[:1]
    handles = np.zeros(scene.mesh.n_vertices, bool)
    handles[np.r_[free, pinned]] = True
    spread = spread_mass(dataclasses.replace(scene, handles=handles), None, 300.0)
    assert sorted(spread) == sorted(free.tolist()) and sum(spread.values()) == pytest.approx(300.0)
    with pytest.raises(InputError, match="is a support"):  # (named by the user: refused)
        spread_mass(scene, [int(pinned[0])], 300.0)
    only_pinned = np.zeros_like(handles)
    only_pinned[pinned] = True
    with pytest.raises(InputError, match="handled vertices are all supports"):
        spread_mass(dataclasses.replace(scene, handles=only_pinned), None, 300.0)


# ------------------------------------------------------------------ the hard hull rows (IPOPT)
def test_ipopt_holds_the_hull_as_hard_rows_warm_started_from_the_previous_load():
    """A method that states the hull as inequality rows (capability ``hull_as_rows``) is asked once
    per load, with the hull hard, and every load after the first starts from the previous
    certified network; the penalty ladder is for the other methods."""
    from selfsupport.methods.simultaneous import Simultaneous

    scene = make_shape("dome", rings=5, radius=5.0, height=3.0)
    steps = stability_series(scene, thickness=0.4, loads_kg=[0.0, 500.0], density=2000.0, at=[0],
                             method=Simultaneous())
    assert [s.result.parameters["hull_search"][0]["penalty"] for s in steps] == ["hard", "hard"]
    assert [len(s.result.parameters["hull_search"]) for s in steps] == [1, 1]
    assert [s.result.parameters["warm_start"] for s in steps] == [False, True]
    assert all(s.certified for s in steps)
    assert_inside_hull(steps[1].result.network, scene.mesh, 0.4)
