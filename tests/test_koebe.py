"""§5: Christoffel duals, Koebe meshes and the family Φ + αR (selfsupport.analysis.koebe).

The meshes are generated here (small inverted and plain grids); the equilibrium is judged by the
independent checker ``../shared/tools/check_network.py`` run as a subprocess.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from selfsupport.analysis.construction import lifting_weights
from selfsupport.analysis.koebe import (
    KINDS,
    KOEBE_EXAMPLES,
    LOAD_RULES,
    MOBIUS_MAPS,
    as_airy,
    christoffel_dual,
    family,
    koebe_mesh,
    minimal_partner,
    paraboloid_gaps,
    polar_mesh,
    quad_dual_scalars,
)
from selfsupport.core.errors import NotKoenigs
from selfsupport.core.evidence import face_nonplanarity
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.io import write_mesh, write_network

from .conftest import CHECKER, requires_checker

needs_checker = requires_checker
TOL = 1e-12


def small(kind: str = "tangent", **kw) -> PolyMesh:
    """A 10 × 10 inverted grid without its central 2 × 2 (the Enneper layout, small)."""
    return koebe_mesh("enneper", kind=kind, **{"n": 10, "hole": 2, **kw})


def run_checker(net: Network, path: Path, tol: float) -> tuple[int, float]:
    write_network(path, net)
    p = subprocess.run([sys.executable, str(CHECKER), str(path), "--tol", str(tol)], capture_output=True, text=True,
                       timeout=60)
    rel = float(p.stdout.split("max_rel_error=")[1].split()[0])
    return p.returncode, rel


def pq_height_space(mesh: PolyMesh) -> np.ndarray:
    """The heights over ``mesh``'s top view that keep every quad planar: rows of
    ``det[x y z 1] = 0`` (linear in z)."""
    xy = mesh.vertices[:, :2]
    rows = np.zeros((mesh.n_faces, mesh.n_vertices))
    for f, q in enumerate(mesh.face_vertices.reshape(-1, 4)):
        M = np.c_[xy[q], np.ones(4)]
        for k in range(4):
            rows[f, q[k]] = (-1) ** k * np.linalg.det(np.delete(M, k, axis=0))
    return rows


def parallel_defect(a: np.ndarray, b: np.ndarray) -> float:
    """Largest sine of the angle between corresponding rows."""
    return float((np.linalg.norm(np.cross(a, b), axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))).max())


# ------------------------------------------------------------------------------ the family in equilibrium
@needs_checker
@pytest.mark.parametrize("kind", KINDS)
def test_family_passes_the_independent_checker_for_every_alpha(kind, tmp_path):
    phi = small(kind)
    R = minimal_partner(phi)
    loads0 = None
    for alpha in (0.5, 1.0, 2.0):
        net = family(phi, alpha, partner=R).network
        code, rel = run_checker(net, tmp_path / f"a{alpha}.json", 1e-8)
        assert code == 0 and rel <= 1e-8, (alpha, rel)
        assert net.min_weight() > 0
        # the loads (unit load, −A*_i) and the weights do not depend on α: only the heights move
        if loads0 is None:
            loads0, w0 = net.loads, net.weights
        assert np.array_equal(net.loads, loads0) and np.array_equal(net.weights, w0)


def test_family_heights_are_minus_phi_plus_alpha_r_over_one_top_view():
    phi = small()
    fam = family(phi, 1.5)
    V = fam.network.vertices
    np.testing.assert_array_equal(V[:, :2], phi.vertices[:, :2])
    np.testing.assert_allclose(V[:, 2], -(phi.vertices[:, 2] + 1.5 * fam.r), rtol=0, atol=1e-15)


def test_inscribed_meshes_carry_exactly_unit_load_per_top_view_area():
    # vertices on the paraboloid: the reciprocal cells are the circumcentric (Voronoi) cells, K_Φ ≡ 1
    fam = family(small("inscribed"), 1.0)
    K = fam.gauss_curvature[~np.isnan(fam.gauss_curvature)]
    assert np.abs(K - 1).max() < 1e-12
    top = family(small("inscribed"), 1.0, loads="top-view").network
    assert top.max_relative_error() < 1e-10
    # tangent meshes only approximate the paraboloid: K_Φ near, not at, 1
    Kt = family(small("tangent"), 1.0).gauss_curvature
    Kt = Kt[~np.isnan(Kt)]
    assert 0.8 < Kt.min() and Kt.max() < 1.0 + 1e-12 and np.abs(Kt - 1).max() > 1e-3


def test_load_density_scales_weights_and_loads_together():
    phi = small()
    a, b = family(phi, 1.0).network, family(phi, 1.0, load_density=250.0).network
    np.testing.assert_allclose(b.weights, 250.0 * a.weights, rtol=1e-14)
    np.testing.assert_allclose(b.loads, 250.0 * a.loads, rtol=1e-14)
    assert b.max_relative_error() < 1e-10


# ------------------------------------------------------------------------------ the Koebe meshes
def test_tangent_meshes_touch_the_paraboloid_along_every_edge_and_inscribed_ones_carry_their_vertices():
    for kw in ({}, {"mobius": "identity", "hole": 0}):
        t, i = small("tangent", **kw), small("inscribed", **kw)
        vg, eg = paraboloid_gaps(t)
        ell = np.linalg.norm(t.vertices[t.edges[:, 1]] - t.vertices[t.edges[:, 0]], axis=1).mean()
        assert np.abs(eg).max() < 1e-12 * ell and vg.min() > 0  # edges tangent, vertices below
        vg, eg = paraboloid_gaps(i)
        assert np.abs(vg).max() < 1e-14 and eg.max() < 0  # vertices on it, edges are chords
        for m in (t, i):
            assert np.nanmax(face_nonplanarity(m)) < TOL


def test_on_a_plain_grid_tangent_and_inscribed_differ_by_a_vertical_shift():
    t, i = (koebe_mesh("grid", kind=k) for k in KINDS)
    h = KOEBE_EXAMPLES["grid"]["spacing"]
    np.testing.assert_allclose(i.vertices[:, 2] - t.vertices[:, 2], h * h / 8, rtol=0, atol=1e-15)


def test_grid_partner_is_the_hyperbolic_paraboloid():
    # the square grid on the paraboloid: planar faces force r = a(x) + b(y), Δ r = 0 forces a'' = −b''
    phi = koebe_mesh("grid", kind="inscribed")
    r = minimal_partner(phi).heights
    x, y = phi.vertices[:, 0], phi.vertices[:, 1]
    A = np.c_[x * x - y * y, x, y, np.ones_like(x)]
    c = np.linalg.lstsq(A, r, rcond=None)[0]
    assert np.abs(A @ c - r).max() < 1e-12 * np.abs(r).max()


# ------------------------------------------------------------------------------ the Christoffel dual
@pytest.mark.parametrize("which", ["phi", "polar"])
def test_christoffel_dual_has_parallel_edges_swapped_diagonals_and_is_an_involution(which):
    phi = small()
    mesh = phi if which == "phi" else polar_mesh(phi).mesh  # both are Koenigs nets in 3D
    D = christoffel_dual(mesh)
    assert D.koenigs_defect < 1e-12 and D.closure_residual < 1e-12
    e = mesh.edges
    X, Y = mesh.vertices, D.mesh.vertices
    assert parallel_defect(X[e[:, 1]] - X[e[:, 0]], Y[e[:, 1]] - Y[e[:, 0]]) < 1e-12
    Q = mesh.face_vertices.reshape(-1, 4)
    # non-corresponding diagonals parallel (the paper's Fig. 4)
    assert parallel_defect(Y[Q[:, 2]] - Y[Q[:, 0]], X[Q[:, 3]] - X[Q[:, 1]]) < 1e-10
    assert parallel_defect(Y[Q[:, 3]] - Y[Q[:, 1]], X[Q[:, 2]] - X[Q[:, 0]]) < 1e-10
    assert np.nanmax(face_nonplanarity(D.mesh)) < TOL
    # the dual of the dual is the primal up to scale and translation
    DD = christoffel_dual(D.mesh).mesh.vertices
    used = np.unique(mesh.face_vertices)
    A = np.c_[DD[used].reshape(-1), np.tile(np.eye(3), (len(used), 1))]
    coef = np.linalg.lstsq(A, X[used].reshape(-1), rcond=None)[0]
    assert abs(coef[0]) > 0.1
    assert np.abs(A @ coef - X[used].reshape(-1)).max() < 1e-10 * np.ptp(X[used], axis=0).max()


def test_quad_dual_scalars_close_the_quad_for_any_starting_corner():
    rng = np.random.default_rng(3)
    P = rng.normal(size=(5, 4, 2))
    P[:, 2] = P[:, 0] + (P[:, 2] - P[:, 0]) * 3  # keep the diagonals crossing away from corners
    P = np.concatenate([P, np.zeros((5, 4, 1))], axis=2)
    c, gap = quad_dual_scalars(P)
    assert np.abs(gap).max() < 1e-12
    edges = np.roll(P, -1, axis=1) - P
    assert np.abs(np.einsum("fk,fkd->fd", c, edges)).max() < 1e-12 * np.abs(edges).max()
    c2, _ = quad_dual_scalars(np.roll(P, -1, axis=1))
    ratio = c2 / np.roll(c, -1, axis=1)
    np.testing.assert_allclose(ratio, ratio[:, :1] * np.ones((1, 4)), rtol=1e-10)


def test_partner_is_minimal_planar_and_the_only_nonaffine_solution():
    # independent check: the heights with planar quads and Δ_φ r = 0 at interior vertices are the
    # affine functions and R — a 4-dimensional null space, found here by SVD
    phi = small("inscribed", n=8)
    R = minimal_partner(phi)
    r = R.heights
    # R as read off the dual is already harmonic: the final Dirichlet solve only removes round-off
    assert R.vertex_spread < 1e-12 and R.polish_change < 1e-12
    mesh_r = phi.with_vertices(np.c_[phi.vertices[:, :2], r])
    assert np.nanmax(face_nonplanarity(mesh_r)) < TOL
    w, _ = lifting_weights(phi, phi.vertices[:, 2])
    n, e = phi.n_vertices, phi.edges
    L = np.zeros((n, n))
    np.add.at(L, (e[:, 0], e[:, 1]), w)
    np.add.at(L, (e[:, 1], e[:, 0]), w)
    L -= np.diag(L.sum(axis=1))
    inner = ~phi.boundary_vertex_mask
    assert np.abs(L[inner] @ r).max() < 1e-12 * np.abs(L[inner] @ phi.vertices[:, 2]).max()
    P = pq_height_space(phi)
    A = np.vstack([P / np.abs(P).max(), L[inner] / np.abs(L).max()])
    s, Vt = np.linalg.svd(A)[1:]
    assert s[-4] < 1e-12 * s[0] < s[-5]  # exactly four zero singular values
    null = Vt[-4:].T
    assert np.abs(null @ np.linalg.lstsq(null, r, rcond=None)[0] - r).max() < 1e-10 * np.abs(r).max()


def test_a_vertex_on_faces_without_interior_vertices_is_refused():
    # a quad hung on the boundary of a 3 × 3 grid: no interior vertex of Φ sees it, so Φ* has no
    # face there and R's heights at its two outer vertices are not determined
    phi = koebe_mesh(n=4, hole=0, mobius="identity", spacing=1.0, kind="inscribed")
    V = phi.vertices
    right = np.flatnonzero(np.isclose(V[:, 0], V[:, 0].max()))[:2]  # two adjacent vertices on the right side
    new = V[right] + [1.0, 0, 0]
    new[:, 2] = 0.5 * (new[:, 0] ** 2 + new[:, 1] ** 2)
    a, b = right[np.argsort(V[right, 1])]
    n = phi.n_vertices
    faces = phi.faces + [[int(a), n, n + 1, int(b)]]
    hung = PolyMesh.from_faces(np.vstack([V, new[np.argsort(V[right, 1])]]), faces)
    with pytest.raises(Exception, match="faces without an interior vertex"):
        minimal_partner(hung)


# ------------------------------------------------------------------------------ negative controls
def random_pq_perturbation(phi: PolyMesh, size: float, seed: int = 1) -> PolyMesh:
    """Φ with heights moved along a random direction that keeps every quad planar."""
    P = pq_height_space(phi)
    U, s, Vt = np.linalg.svd(P)
    null = Vt[int(np.sum(s > 1e-10 * s[0])):]
    psi = null.T @ np.random.default_rng(seed).normal(size=len(null))
    psi *= size * np.ptp(phi.vertices[:, 2]) / np.abs(psi).max()
    return phi.with_vertices(phi.vertices + np.c_[np.zeros((phi.n_vertices, 2)), psi])


def test_a_perturbed_pq_mesh_is_not_koenigs():
    bad = random_pq_perturbation(small("inscribed", n=8), 1e-3)
    assert np.nanmax(face_nonplanarity(bad)) < 1e-12  # still PQ
    with pytest.raises(NotKoenigs, match="not a Koenigs net"):
        minimal_partner(bad)


@needs_checker
def test_a_perturbed_network_fails_the_unit_load_equilibrium(tmp_path):
    phi = small("inscribed", n=8)
    net = family(phi, 1.0).network
    code, rel = run_checker(net, tmp_path / "good.json", 1e-8)
    assert code == 0 and rel < 1e-8
    # the same weights and unit loads on a perturbed (non-Koebe) PQ mesh: out of equilibrium
    moved = random_pq_perturbation(net.mesh, 1e-2)
    bad = Network(mesh=moved, weights=net.weights, loads=net.loads, supports=net.supports)
    code, rel = run_checker(bad, tmp_path / "bad.json", 1e-8)
    assert code == 1 and rel > 1e-3


@needs_checker
def test_a_non_koebe_koenigs_mesh_fails_unit_top_view_load(tmp_path):
    # a translational (hence Koenigs, PQ, convex) net that is not on the paraboloid: R exists and
    # balances the loads A*_i, but those are not the unit load per top-view area
    phi = koebe_mesh("grid", kind="inscribed")
    x, y = phi.vertices[:, 0], phi.vertices[:, 1]
    quartic = phi.with_vertices(np.c_[x, y, 0.5 * (x * x + y * y) + 2.0 * (x ** 4 + y ** 4)])
    assert family(quartic, 1.0).network.max_relative_error() < 1e-10
    code, rel = run_checker(family(quartic, 1.0, loads="top-view").network, tmp_path / "q.json", 1e-8)
    assert code == 1 and rel > 1e-2
    code, rel = run_checker(family(phi, 1.0, loads="top-view").network, tmp_path / "p.json", 1e-8)
    assert code == 0 and rel < 1e-8


def test_a_dome_is_reflected_into_phi_and_refused_as_phi_itself():
    phi = small()
    dome = phi.with_vertices(phi.vertices * [1, 1, -1])
    back, flipped = as_airy(dome)
    assert flipped and np.array_equal(back.vertices, phi.vertices)
    assert as_airy(phi) == (phi, False)
    with pytest.raises(Exception, match="not convex"):
        family(dome, 1.0)


# ------------------------------------------------------------------------------ API and CLI
def test_cli_choices_match_the_registries():
    from selfsupport.cli import koebe as cli_koebe

    assert set(cli_koebe.EXAMPLE_NAMES) == set(KOEBE_EXAMPLES)
    assert set(cli_koebe.KIND_NAMES) == set(KINDS)
    assert set(cli_koebe.MOBIUS_NAMES) == set(MOBIUS_MAPS)
    assert set(cli_koebe.LOAD_RULE_NAMES) == set(LOAD_RULES)


@needs_checker
def test_cli_koebe_writes_a_network_the_checker_accepts(tmp_path, capsys):
    from selfsupport.cli import main

    out = tmp_path / "net.json"
    code = main(["koebe", "--example", "enneper", "--n", "10", "--hole", "2", "--alpha", "2", "--out", str(out),
                 "--phi-out", str(tmp_path / "phi.obj"), "--partner-out", str(tmp_path / "r.obj")])
    assert code == 0 and "max relative error" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["koebe"]["alpha"] == 2.0 and len(doc["koebe"]["r"]) == len(doc["vertices"])
    p = subprocess.run([sys.executable, str(CHECKER), str(out), "--tol", "1e-8"], capture_output=True, text=True)
    assert p.returncode == 0, p.stdout


def test_cli_koebe_reads_a_dome_file_and_rebuilds_the_same_network(tmp_path, capsys):
    from selfsupport.cli import main

    phi = small()
    write_mesh(tmp_path / "dome.obj", phi.with_vertices(phi.vertices * [1, 1, -1]), up="-y")
    out = tmp_path / "net.json"
    assert main(["koebe", "--mesh", str(tmp_path / "dome.obj"), "--up=-y", "--out", str(out)]) == 0
    assert "reflected" in capsys.readouterr().out
    ref = family(phi, 1.0).network
    got = np.asarray(json.loads(out.read_text())["vertices"])
    np.testing.assert_allclose(got, ref.vertices, rtol=0, atol=1e-12)


@pytest.mark.parametrize("argv, message", [
    (["--mesh", "M", "--n", "4"], "describe a built-in example"),
    (["--alpha", "nan"], "give a finite number in [-1e6, 1e6]"),
    (["--alpha", "1e300"], "give a finite number in [-1e6, 1e6]"),
    (["--hole", "-1"], "give an integer in [0, inf)"),
    (["--tol", "2"], "give a finite number in (0, 1]"),
    (["--up", "w"], "unknown vertical axis"),
    (["--mesh", "NOTKOENIGS"], "not a Koenigs net"),
    (["--phi-out", "OUT"], "name the same file"),
])
def test_cli_koebe_refuses_bad_input_in_one_line(tmp_path, capsys, argv, message):
    from selfsupport.cli import main

    bad = random_pq_perturbation(small("inscribed", n=8), 1e-2)
    write_mesh(tmp_path / "bad.obj", bad)
    write_mesh(tmp_path / "m.obj", small())
    subst = {"M": str(tmp_path / "m.obj"), "NOTKOENIGS": str(tmp_path / "bad.obj"), "OUT": str(tmp_path / "o.json")}
    code = main(["koebe", "--out", str(tmp_path / "o.json")] + [subst.get(a, a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("argv, cause", [
    (["--loads", "top-view"], "top-view loads are exact only where K_Φ = 1"),  # tangent: K_Φ = 0.91 .. 0.99
    (["--alpha", "1e6", "--tol", "1e-9"], "round-off grows with |α|"),
])
def test_cli_koebe_exits_nonzero_when_its_network_is_not_in_equilibrium(tmp_path, capsys, argv, cause):
    """The network is written (status 'failed'), the checker refuses it at the same tolerance, and
    the exit code and the one stderr line say that it is not in equilibrium, and why."""
    from selfsupport.cli import main

    out = tmp_path / "net.json"
    code = main(["koebe", "--example", "enneper", "--n", "10", "--hole", "2", "--out", str(out)] + argv)
    err = capsys.readouterr().err
    assert code == 4 and err.count("\n") == 1 and "NOT in equilibrium" in err and cause in err
    doc = json.loads(out.read_text())
    assert doc["status"] == "failed" and doc["max_relative_error"] > doc["tol"]
    if CHECKER.is_file():
        p = subprocess.run([sys.executable, str(CHECKER), str(out), "--tol", str(doc["tol"])], capture_output=True,
                           text=True, timeout=60)
        assert p.returncode != 0, p.stdout


def test_cli_koebe_writes_the_status_of_a_network_in_equilibrium(tmp_path):
    from selfsupport.cli import main

    out = tmp_path / "net.json"
    assert main(["koebe", "--example", "enneper", "--n", "10", "--hole", "2", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["status"] == "converged" and doc["max_relative_error"] <= doc["tol"]


def test_koebe_study_recovers_the_alpha_of_a_summed_mesh(tmp_path):
    # stand-ins for the published files, made here: Φ inscribed over the inverted grid (as the
    # paper's enneper-koebe.obj is) and Φ + αR, in the files' axes (the paraboloid's axis is y)
    from studies.koebe import report, run

    phi = koebe_mesh("enneper", kind="inscribed", spacing=0.3)
    r = minimal_partner(phi).heights
    pub = tmp_path / "published"
    pub.mkdir()
    write_mesh(pub / "enneper-koebe.obj", phi, up="y")
    write_mesh(pub / "enneper-summed.obj", phi.with_vertices(phi.vertices + np.c_[0 * r, 0 * r, -0.3 * r]), up="y")
    res = run(tmp_path, tmp_path / "out", checker=None)
    assert abs(res["inverted_grid"]["spacing"] - 0.3) < 1e-12
    assert abs(res["alpha_published"] + 0.3) < 1e-10
    first = res["comparisons"][0]
    assert first["distance"] < 1e-12 and first["fit_residual"] < 1e-10
    eq = [row for row in res["equilibrium"] if row["loads"] == "reciprocal"]
    assert max(row["max_rel_error"] for row in eq if not row["mesh"].startswith("published")) < 1e-10
    assert "Φ + αR with α = -0.300000" in report(res, tmp_path / "out")


@pytest.mark.parametrize("mobius, hole", [("identity", 0), ("inversion", 2)])
def test_a_disk_shaped_region_of_the_pattern_gives_a_family_too(mobius, hole):
    phi = koebe_mesh(n=16, hole=hole, mobius=mobius, region=lambda x, y: x * x + y * y <= 2.2)
    assert phi.n_vertices < 16 * 16 - hole * hole
    fam = family(phi, 2.0)
    assert fam.network.max_relative_error() < 1e-10 and fam.network.min_weight() > 0
    assert fam.partner.dual.koenigs_defect < 1e-12


def test_the_sign_of_R_does_not_follow_round_off():
    # Enneper's R is odd under x <-> y: its largest |r| is reached with both signs, so a sign
    # taken from "the largest entry" flipped with a spacing changed in the 13th digit
    a = minimal_partner(koebe_mesh("enneper", kind="inscribed", spacing=0.3)).heights
    b = minimal_partner(koebe_mesh("enneper", kind="inscribed", spacing=0.3 * (1 + 1e-13))).heights
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
