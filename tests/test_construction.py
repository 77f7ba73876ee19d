"""The §2.5 construction: convex Airy function + top view + load -> self-supporting network.
Analytic cases (paraboloid on a disk), the Voronoi/Delaunay weights, zero-force edges,
holes, and equilibrium checked by the network's own evidence and by the independent checker."""
from __future__ import annotations

import json

import numpy as np
import pytest

from selfsupport.analysis import airy, construct, construct_detailed
from selfsupport.core.errors import InputError
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import disk_points
from tests.conftest import independent_check, requires_checker, roundoff_scale


def random_points(seed: int, n: int = 300) -> np.ndarray:
    rng = np.random.default_rng(seed)
    k = int(2 * np.sqrt(np.pi * n))
    t = np.sort(rng.uniform(0, 2 * np.pi, k))
    r = np.sqrt(rng.uniform(0, 1, n)) * 0.97
    a = rng.uniform(0, 2 * np.pi, n)
    return 3.0 * np.vstack([np.c_[np.cos(t), np.sin(t)], np.c_[r * np.cos(a), r * np.sin(a)]])


# ------------------------------------------------------------------------------ analytic: paraboloid on a disk
def test_paraboloid_constant_load_reproduces_the_analytic_surface_exactly():
    """φ = ½|x|²: Δ_φ is the cotangent Laplacian and Δ_φ φ = 2 × Voronoi area, so the quadratic
    s = (F/4)(r² − R²) solves Δ_φ s = A F exactly at every interior vertex (A = Voronoi area):
    the construction returns the analytic surface up to round-off at every resolution."""
    R, F = 2.0, -3.0
    for rings in (4, 9, 20):
        net = construct(disk_points(rings, radius=R), "paraboloid", load=F)
        v = net.vertices
        exact = F / 4 * ((v[:, :2] ** 2).sum(axis=1) - R ** 2)
        assert np.abs(v[:, 2] - exact).max() < 1e-12 * abs(F) * R ** 2
        assert net.max_relative_error() < 1e-12


def test_paraboloid_radial_load_converges_at_second_order():
    """Δ s = F₀ (1 + r²/R²) on the disk with s = 0 on the rim:
    s = F₀ ((r² − R²)/4 + (r⁴ − R⁴)/(16 R²)). The quadratic part is reproduced exactly (see
    above), the quartic part is not: the discrete surfaces converge in the max norm with
    log-log slope 2."""
    R, F0 = 2.0, -3.0
    hs, errs = [], []
    for rings in (4, 8, 16, 32):
        net = construct(disk_points(rings, radius=R), "paraboloid",
                        load=lambda x, y: F0 * (1 + (x * x + y * y) / R ** 2))
        v = net.vertices
        r2 = (v[:, :2] ** 2).sum(axis=1)
        errs.append(np.abs(v[:, 2] - F0 * ((r2 - R ** 2) / 4 + (r2 ** 2 - R ** 4) / (16 * R ** 2))).max())
        hs.append(R / rings)
        assert net.max_relative_error() < 1e-11
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert 1.9 < slope < 2.2, (slope, errs)
    local = np.diff(np.log(errs)) / np.diff(np.log(hs))
    assert np.all(local > 1.9)


def test_paraboloid_gives_delaunay_and_voronoi_over_delaunay_weights():
    from scipy.spatial import Delaunay, Voronoi

    pts = random_points(0, 200)
    c = construct_detailed(pts, "paraboloid", load=-1.0)
    mesh = c.network.mesh
    tris = {tuple(sorted(t)) for t in mesh.faces}
    assert tris == {tuple(sorted(t)) for t in Delaunay(pts).simplices.tolist()}
    # weights: length of the Voronoi edge dual to each Delaunay edge over the edge's length
    vor = Voronoi(pts)
    w_vor = {}
    for (i, j), rv in zip(vor.ridge_points.tolist(), vor.ridge_vertices):
        if -1 not in rv:
            a, b = vor.vertices[rv[0]], vor.vertices[rv[1]]
            w_vor[(min(i, j), max(i, j))] = np.linalg.norm(a - b) / np.linalg.norm(pts[i] - pts[j])
    inner = np.flatnonzero(c.network.active_edges)
    assert len(inner) > 400
    for k in inner:
        i, j = mesh.edges[k]
        assert c.network.weights[k] == pytest.approx(w_vor[(i, j)], rel=1e-9)
    # and the reciprocal diagram of a paraboloid lifting is the Voronoi diagram: face gradients are circumcentres
    # (up to Φ's affine gauge, which translates the diagram)
    res = airy(c.network)
    tri = np.array(mesh.faces)
    a, b, cc = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    M = np.stack([b - a, cc - a], axis=1)
    rhs = 0.5 * np.stack([((b - a) ** 2).sum(1), ((cc - a) ** 2).sum(1)], axis=1)
    circ = a + np.linalg.solve(M, rhs[..., None])[..., 0]
    shift = circ - res.reciprocal_vertices
    assert np.abs(shift - shift.mean(axis=0)).max() < 1e-9 * np.abs(circ).max()


# ------------------------------------------------------------------------------ equilibrium
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_convex_phi_and_points_give_networks_in_equilibrium(seed):
    rng = np.random.default_rng(seed)
    pts = random_points(seed)
    Q = rng.normal(size=(2, 2))
    A = Q @ Q.T + 0.3 * np.eye(2)

    def phi(x, y):
        return 0.5 * (A[0, 0] * x * x + 2 * A[0, 1] * x * y + A[1, 1] * y * y) + 0.05 * (x * x + y * y) ** 2

    c = construct_detailed(pts, phi, load=-rng.uniform(1, 3, len(pts)), boundary_heights=lambda x, y: 0.2 * y)
    net = c.network
    assert net.max_relative_error() < 1e-12
    assert net.min_weight() >= 0 and np.all(net.weights[~net.active_edges] == 0)
    assert np.all(net.supports == net.mesh.boundary_vertex_mask)
    np.testing.assert_allclose(net.vertices[net.supports, 2], 0.2 * net.vertices[net.supports, 1], atol=1e-15)
    res = airy(net)
    assert res.convex and res.max_closure_residual < 1e-12
    # Φ of the network is the lifting itself (up to the affine gauge): φ_i − φ(x_i) is affine
    d = res.phi - phi(net.vertices[:, 0], net.vertices[:, 1])
    M = np.c_[net.vertices[:, :2], np.ones(len(d))]
    coef, *_ = np.linalg.lstsq(M, d, rcond=None)
    assert np.abs(d - M @ coef).max() < 1e-10 * np.ptp(res.phi)


def test_self_weight_loads_are_consistent_with_the_constructed_geometry():
    load = SelfWeight(density=2000.0, thickness=0.1)
    c = construct_detailed(disk_points(10, radius=5.0), "quartic", load=load, rise=2.0)
    net = c.network
    z = net.vertices[:, 2]
    assert z.max() == pytest.approx(2.0, rel=1e-9)
    assert c.load_rounds > 1
    # loads of the network are the self-weight of its own (3D) geometry, and it stands
    np.testing.assert_allclose(net.loads, load.nodal(net.mesh, net.vertices), rtol=1e-12)
    assert net.max_relative_error() < 1e-11


def test_rise_scales_phi_and_weights_inversely_to_height():
    pts = disk_points(8, radius=3.0)
    a = construct_detailed(pts, "paraboloid", load=-1000.0, rise=1.0).network
    b = construct_detailed(pts, "paraboloid", load=-1000.0, rise=2.0).network
    assert a.vertices[:, 2].max() == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(b.vertices[:, 2], 2 * a.vertices[:, 2], rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(a.weights, 2 * b.weights, rtol=1e-10)


@requires_checker
def test_independent_checker_accepts_the_constructed_network(tmp_path):
    """The construction is exact up to round-off: Maxwell's reciprocal figure balances the
    horizontal forces identically and the heights solve Δ_φ s = A F. So the checker's error is
    bounded by round-off × the conditioning of the residual sum: with every term w_ij (v_j − v_i)
    carrying ~ε w_ij (‖v_i‖ + ‖v_j‖), the relative residual cannot be resolved below
    ε Σ_j w_ij (‖v_i‖ + ‖v_j‖) / |L_i| (:func:`roundoff_scale`, ~4e-12 here, measured errors
    0.03-0.5 × it over seeds 0-6). The allowance of 10 × that covers the backward error of the
    height solve and the valence-many roundings; a load or weight wrong by one part in 1e9
    already exceeds it, and a real defect gives errors of order 1."""
    from selfsupport.io import write_network

    net = construct(random_points(4), "cosh", load=-2.0)
    path = tmp_path / "net.json"
    write_network(path, net)
    out = independent_check(path)
    assert out.returncode == 0, out.stdout
    floor = roundoff_scale(net.vertices, net.edges, net.weights, net.loads, net.supports).max()
    assert floor < 1e-10  # the bound itself is tight: a well-conditioned network
    assert out.max_rel_error <= 10 * floor


# ------------------------------------------------------------------------------ degenerate hulls, holes, errors
def test_cocircular_grid_gives_zero_force_diagonals_and_a_quad_network():
    """On a square grid every cell's corners are co-circular, so the lifted paraboloid has
    quadrilateral hull faces: qhull's diagonals are zero-force edges. Dropping them leaves a
    quad network that is in equilibrium and whose Airy surface has planar quads."""
    from selfsupport.core.mesh import PolyMesh
    from selfsupport.core.result import Network

    k = 8
    g = np.linspace(-1, 1, k + 1)
    X, Y = np.meshgrid(g, g)
    pts = np.c_[X.ravel(), Y.ravel()]
    c = construct_detailed(pts, "paraboloid", load=-1.0)
    net = c.network
    assert len(c.zero_force_edges) == k * k  # one diagonal per cell
    assert np.all(net.weights[c.zero_force_edges] == 0)
    assert net.max_relative_error() < 1e-12
    quads = [[j * (k + 1) + i, j * (k + 1) + i + 1, (j + 1) * (k + 1) + i + 1, (j + 1) * (k + 1) + i]
             for j in range(k) for i in range(k)]
    qm = PolyMesh.from_faces(net.vertices, quads).validate()
    key = {tuple(e): w for e, w in zip(net.edges.tolist(), net.weights.tolist())}
    qnet = Network(mesh=qm, weights=np.array([key[tuple(e)] for e in qm.edges.tolist()]), loads=net.loads,
                   supports=net.supports)
    assert qnet.max_relative_error() < 1e-12
    res = airy(qnet)
    assert res.nonplanar_faces.size == 0 and res.convex
    assert res.planarity_residual.max() < 1e-12 * np.ptp(res.phi)


def test_holes_with_cocircular_rims_stand_free_and_others_need_supports():
    rings, h = 12, 1 / 12
    pts = disk_points(rings)
    cx, cy, r = 0.3, -0.1, 0.25
    keep = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) > r + 0.5 * h
    t = 2 * np.pi * np.arange(20) / 20
    rim = np.c_[cx + r * np.cos(t), cy + r * np.sin(t)]
    c = construct_detailed(np.vstack([pts[keep], rim]), "paraboloid", load=-1.0, holes=[rim])
    net = c.network
    assert len(net.mesh.boundary_loops) == 2
    rim_v = np.flatnonzero(np.isin(c.points_used, np.arange(keep.sum(), keep.sum() + 20)))
    assert len(rim_v) == 20 and not net.supports[rim_v].any()
    assert net.max_relative_error() < 1e-12
    # a square hole cuts through Φ's creases: its rim cannot stand free ...
    sq = np.array([[0.0, 0.0], [0.4, 0.0], [0.4, 0.4], [0.0, 0.4]])
    with pytest.raises(InputError, match="support the rims"):
        construct_detailed(disk_points(rings), "paraboloid", load=-1.0, holes=[sq])
    # ... but stands on supports
    net2 = construct_detailed(disk_points(rings), "paraboloid", load=-1.0, holes=[sq], support_holes=True).network
    assert net2.max_relative_error() < 1e-12 and len(net2.mesh.boundary_loops) == 2


def test_non_convex_samples_are_rejected_with_the_point_named():
    pts = disk_points(5)
    vals = 0.5 * (pts ** 2).sum(axis=1)
    vals[0] += 0.2  # the centre lifted above the hull: not a vertex of the lower hull
    with pytest.raises(InputError, match="point 0"):
        construct(pts, vals, load=-1.0)
    with pytest.raises(InputError, match="unknown Airy function"):
        construct(pts, "saddle")
    with pytest.raises(InputError, match="one value per point"):
        construct(pts, np.ones(3))


def test_cli_construct_writes_a_network_the_solver_format_reads(tmp_path):
    from selfsupport.cli import main
    from selfsupport.io import read_network

    out = tmp_path / "c.json"
    assert main(["construct", "--disk", "6", "--radius", "4", "--rise", "1.5", "--out", str(out)]) == 0
    net = read_network(out)
    assert net.vertices[:, 2].max() == pytest.approx(1.5, rel=1e-9)
    assert net.max_relative_error() < 1e-12
    doc = json.loads(out.read_text())
    assert doc["construction"]["phi"] == "paraboloid" and doc["status"] == "converged"
    assert main(["construct", "--random", "80", "--self-weight", "--phi", "quartic", "--out", str(out)]) == 0
    assert read_network(out).max_relative_error() < 1e-11


def test_cli_construct_exits_nonzero_when_round_off_leaves_it_out_of_equilibrium(tmp_path, capsys):
    """Supports 1e10 m up and a rise of 3 m: the heights keep only the rise's first digits, and the
    network misses the tolerance; it is written with status 'failed' and the exit code says so."""
    from selfsupport.cli import main
    from selfsupport.io import read_network

    out = tmp_path / "c.json"
    code = main(["construct", "--disk", "4", "--boundary-height", "1e10", "--out", str(out)])
    err = capsys.readouterr().err
    doc = json.loads(out.read_text())
    assert read_network(out).max_relative_error() > doc["tol"]
    assert code == 4 and err.count("\n") == 1 and "NOT in equilibrium" in err and doc["status"] == "failed"


def test_a_free_cluster_cut_off_from_the_supports_by_zero_weights_is_found():
    """−K_ff is singular exactly when some free points reach no support through positive weights.
    On a constructed network: all weights positive → none ungrounded; zero the weights of every
    edge leaving the ring around the centre → that inner cluster (and only it) is ungrounded, and
    the stress Laplacian restricted to it is singular (its rows sum to zero)."""
    from formulations.equilibrium import Topology, stress_laplacian
    from selfsupport.analysis.construction import _ungrounded

    net = construct(disk_points(4), "paraboloid", load=-1.0)
    e, sup = net.mesh.edges, np.asarray(net.supports, bool)
    w = np.asarray(net.weights, float).copy()
    w[sup[e[:, 0]] & sup[e[:, 1]]] = 1.0  # (edges between supports carry 0 by convention)
    assert _ungrounded(e, w, sup).size == 0
    r = np.hypot(net.vertices[:, 0], net.vertices[:, 1])
    inner = r < 0.3 * r.max()
    cut = inner[e[:, 0]] != inner[e[:, 1]]
    w[cut] = 0.0
    found = _ungrounded(e, w, sup)
    np.testing.assert_array_equal(found, np.flatnonzero(inner))
    L = stress_laplacian(Topology.build(net.mesh.n_vertices, e, sup), w).toarray()
    block = L[np.ix_(found, found)]
    assert np.abs(block.sum(axis=1)).max() <= 1e-12 * np.abs(block).max()
