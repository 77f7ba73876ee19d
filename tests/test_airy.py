"""Airy stress surface, reciprocal diagram, curvatures (paper §2): identities on networks in
equilibrium, built by the §2.5 construction (random convex φ, random top views) and by the
staggered method on built-in shapes."""
from __future__ import annotations

import json

import numpy as np
import pytest

from selfsupport.analysis import airy, construct, curvatures, reciprocal, write_vector_fields
from selfsupport.analysis.construction import lifting_weights, lower_hull
from selfsupport.analysis.curvature import relative_principal, vertex_hessians
from selfsupport.analysis.reciprocal import vertex_face_rings
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.core.shapes import disk_points, make_shape
from selfsupport.io.axes import to_ours
from tests.conftest import SHARED


def J(v: np.ndarray) -> np.ndarray:
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


# ------------------------------------------------------------------------------ networks
def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random points in the unit disk plus a rim of points on its circle."""
    k = int(2 * np.sqrt(np.pi * n))
    t = np.sort(rng.uniform(0, 2 * np.pi, k))
    r = np.sqrt(rng.uniform(0, 1, n)) * 0.97
    a = rng.uniform(0, 2 * np.pi, n)
    return np.vstack([np.c_[np.cos(t), np.sin(t)], np.c_[r * np.cos(a), r * np.sin(a)]])


def random_convex_phi(rng: np.random.Generator):
    """½ xᵀ A x + b·x + c |x|⁴ with A symmetric positive definite: strictly convex."""
    Q = rng.normal(size=(2, 2))
    A = Q @ Q.T + 0.5 * np.eye(2)
    b = rng.normal(size=2)
    c = rng.uniform(0, 0.5)

    def phi(x, y):
        return 0.5 * (A[0, 0] * x * x + 2 * A[0, 1] * x * y + A[1, 1] * y * y) + b[0] * x + b[1] * y + c * (x * x + y * y) ** 2
    return phi


def random_network(seed: int, n: int = 250) -> Network:
    rng = np.random.default_rng(seed)
    pts = random_points(rng, n)
    load = -rng.uniform(0.5, 2.0, len(pts))
    return construct(pts, random_convex_phi(rng), load=load, boundary_heights=lambda x, y: 0.1 * x)


def lifted_network(values: np.ndarray, rings: int = 7) -> Network:
    """The ring triangulation of the disk, weights from the creases of the lifting of ``values``
    (any sign), heights from (3): a network in equilibrium with tensile edges where Φ is concave."""
    pts = disk_points(rings)
    scene = make_shape("disk", n_rings=rings)
    mesh = scene.mesh
    w, _ = lifting_weights(mesh, values)
    sup = mesh.boundary_vertex_mask
    w[sup[mesh.edges[:, 0]] & sup[mesh.edges[:, 1]]] = 0.0
    from scipy.sparse.linalg import spsolve

    from formulations.equilibrium import Topology, stress_laplacian

    L = stress_laplacian(Topology.build(len(pts), mesh.edges, sup), w)
    loads = np.full(len(pts), -1.0 / len(pts))
    s = np.zeros(len(pts))
    s[~sup] = spsolve(L[~sup][:, ~sup].tocsc(), loads[~sup])
    return Network(mesh=mesh.with_vertices(np.c_[pts, s]), weights=w, loads=loads, supports=sup)


@pytest.fixture(scope="module")
def solved():
    """Networks from the staggered method (converged to machine precision)."""
    from selfsupport.core.loads import SelfWeight
    from selfsupport.methods.staggered import StaggeredLinearization

    out = {}
    for name in ("dome", "barrel_vault", "pillar_vault"):
        res = StaggeredLinearization().solve(make_shape(name, n_vertices=300), SelfWeight())
        assert res.converged, res.summary()
        out[name] = res.network
    return out


def jump_scale(net: Network) -> float:
    e = net.mesh.edges
    return float(np.mean(np.abs(net.weights) * np.linalg.norm(net.vertices[e[:, 1], :2] - net.vertices[e[:, 0], :2], axis=1)))


def check_reciprocal_identities(net: Network, res, *, skip_cut: bool = True, tol: float = 1e-9) -> None:
    """The checker's two statements: dual edges are ±w J e', and each face plane through
    (x_i, y_i, φ_i) has gradient reciprocal_vertices[f]."""
    R = res.reciprocal_vertices
    e, ef = net.mesh.edges, net.mesh.edge_faces
    inter = (ef >= 0).all(axis=1)
    if skip_cut:
        inter[res.cut_edges] = False
    ev = net.vertices[e[:, 1], :2] - net.vertices[e[:, 0], :2]
    d = R[ef[inter, 0]] - R[ef[inter, 1]]
    want = net.weights[inter, None] * J(ev[inter])
    err = np.minimum(np.linalg.norm(d - want, axis=1), np.linalg.norm(d + want, axis=1))
    assert err.max() <= tol * jump_scale(net)
    # planes through the vertex values: least-squares fit per face, gradient = R[f]
    xy, phi = net.vertices[:, :2], res.phi
    for f, face in enumerate(net.mesh.faces):
        A = np.c_[xy[face], np.ones(len(face))]
        coef, *_ = np.linalg.lstsq(A, phi[face], rcond=None)
        assert np.linalg.norm(coef[:2] - R[f]) <= tol * max(np.abs(R).max(), 1.0)


# ------------------------------------------------------------------------------ identities
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reciprocal_edges_and_face_gradients_random_networks(seed):
    net = random_network(seed)
    assert net.max_relative_error() < 1e-11
    res = airy(net)
    assert res.max_closure_residual < 1e-12
    check_reciprocal_identities(net, res, tol=1e-9)
    # on integrable input the spanning-tree integration is the least-squares solution
    tree, ls = airy(net, integration="tree"), airy(net, integration="least-squares")
    assert (tree.integration, ls.integration) == ("tree", "least-squares")
    np.testing.assert_allclose(tree.reciprocal_vertices, ls.reciprocal_vertices, rtol=0,
                               atol=1e-10 * np.abs(ls.reciprocal_vertices).max())
    np.testing.assert_allclose(tree.phi, ls.phi, rtol=0, atol=1e-10 * np.abs(ls.phi).max())
    rd = reciprocal(res)
    # the diagram's own edge list says the same, with the sign fixed: vertices[L] − vertices[R] = w J e'
    assert rd.edge_residual.max() <= 1e-11 * jump_scale(net)


@pytest.mark.parametrize("seed", [3, 4])
def test_stress_laplacian_of_phi_is_twice_the_reciprocal_cell_area(seed):
    net = random_network(seed)
    res = airy(net)
    rd = reciprocal(res)
    from formulations.equilibrium import Topology, stress_laplacian

    L = stress_laplacian(Topology.build(net.mesh.n_vertices, net.edges, net.supports), net.weights)
    lap = L @ res.phi
    inner = ~net.mesh.boundary_vertex_mask
    # cell areas by the shoelace formula over the ordered cells (independent of the edge sums)
    shoe = np.full(net.mesh.n_vertices, np.nan)
    for v, cell in zip(rd.cell_vertex, rd.cells):
        p = rd.vertices[cell]
        shoe[v] = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - p[:, 1] * np.roll(p[:, 0], -1))
    assert np.all(shoe[inner] > 0)  # convex Φ: positively oriented cells
    np.testing.assert_allclose(lap[inner], 2 * shoe[inner], rtol=1e-10, atol=0)
    np.testing.assert_allclose(rd.cell_areas[inner], shoe[inner], rtol=1e-12, atol=0)


def test_eq5_and_eq6_hold_to_round_off_on_random_and_solved_networks(solved):
    for net in (random_network(5), solved["dome"], solved["pillar_vault"]):
        cv = curvatures(net, directions=False)
        d = cv.defined
        assert d.sum() > 50
        # eq. (5): Δφ s / Δφ φ equals the mixed-area ratio A(Φ*, S*) / A(Φ*) on triangle meshes
        c = cv.closed
        np.testing.assert_allclose(cv.H_rel[c], cv.H_rel_mixed[c], rtol=1e-9, atol=0)
        # eq. (6): 2 K_Φ H_rel = F_i, F_i the load per unit top-view area
        np.testing.assert_allclose(2 * cv.K_phi[d] * cv.H_rel[d], cv.load_density[d], rtol=1e-9, atol=0)
        assert cv.max_balance_residual < 1e-9
        assert cv.max_identity_residual < 1e-9
        assert np.all(np.isnan(cv.H_rel[~d]))


def test_polar_dual_faces_lie_on_the_polar_planes_of_the_vertices():
    net = random_network(6, n=120)
    res = airy(net)
    rd = reciprocal(res)
    xy = net.vertices[:, :2]
    for v, cell in zip(rd.cell_vertex, rd.cells):
        p = rd.polar_vertices[cell]
        # pole (g, −c) of plane z = g·x + c lies on the polar plane of (x_i, φ_i): z = x_i · y − φ_i
        np.testing.assert_allclose(p[:, 2], p[:, :2] @ xy[v] - res.phi[v], rtol=0, atol=1e-10 * np.abs(p).max())
    assert rd.mesh("polar").n_faces == len(rd.cell_vertex)


def test_rings_are_counter_clockwise_and_complete():
    mesh = make_shape("dome", rings=5).mesh
    off, faces = vertex_face_rings(mesh, 1)
    face_of, _, _ = mesh.corner_data
    for v in range(mesh.n_vertices):
        ring = faces[off[v]:off[v + 1]]
        assert sorted(ring.tolist()) == sorted(face_of[mesh.face_vertices == v].tolist())
        c = np.array([mesh.vertices[mesh.faces[f], :2].mean(axis=0) for f in ring]) - mesh.vertices[v, :2]
        ang = np.unwrap(np.arctan2(c[:, 1], c[:, 0]))
        assert np.all(np.diff(ang) > 0)  # counter-clockwise around the vertex


# ------------------------------------------------------------------------------ convexity
def test_phi_is_convex_exactly_when_all_weights_are_nonnegative():
    pts = disk_points(7)
    rng = np.random.default_rng(7)
    base = 0.5 * (pts ** 2).sum(axis=1)
    for trial in range(6):
        vals = base.copy()
        if trial:  # dents: concave spots make tensile edges
            k = rng.choice(np.flatnonzero(np.hypot(*pts.T) < 0.8), size=trial, replace=False)
            vals[k] += rng.uniform(0.02, 0.2, size=trial)
        net = lifted_network(vals)
        assert net.max_relative_error() < 1e-10
        res = airy(net)
        act = net.active_edges & (net.mesh.edge_faces >= 0).all(axis=1)
        # Φ's creases are the weights, sign included
        np.testing.assert_allclose(res.crease_weights[act], net.weights[act], rtol=0,
                                   atol=1e-9 * np.abs(net.weights).max())
        assert res.convex == bool(np.all(net.weights[act] >= 0))
        assert res.convex == (trial == 0)


def test_flipping_one_weight_makes_phi_not_convex():
    net = construct(disk_points(6), "paraboloid", load=-1.0)
    assert airy(net).convex
    act = np.flatnonzero(net.active_edges & (net.mesh.edge_faces >= 0).all(axis=1))
    for k in act[::7]:
        w = net.weights.copy()
        w[k] = -w[k]
        res = airy(Network(mesh=net.mesh, weights=w, loads=net.loads, supports=net.supports))
        assert not res.convex
        assert res.max_closure_residual > 1e-3  # the flipped edge breaks (2) at its ends: reported


# ------------------------------------------------------------------------------ holes, supports, orientation
def cheese_network(support_holes: bool = False) -> Network:
    from selfsupport.analysis import construct_detailed

    rings, h = 14, 1 / 14
    pts = disk_points(rings)
    holes, extra = [], []
    keep = np.ones(len(pts), bool)
    for cx, cy, r in ((0.35, 0.1, 0.2), (-0.3, -0.25, 0.16)):
        keep &= np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) > r + 0.5 * h
        k = max(8, int(2 * np.pi * r / h))
        t = 2 * np.pi * np.arange(k) / k
        ring = np.c_[cx + r * np.cos(t), cy + r * np.sin(t)]
        extra.append(ring)
        holes.append(ring)
    # co-circular rims: Φ is one plane over each hole, so the rims stand free
    return construct_detailed(np.vstack([pts[keep]] + extra), "paraboloid", load=-1.0, holes=holes,
                              support_holes=support_holes).network


def test_free_holes_have_zero_period_and_a_single_valued_phi():
    net = cheese_network()
    assert len(net.mesh.boundary_loops) == 3 and net.max_relative_error() < 1e-11
    res = airy(net)
    assert [p.kind for p in res.periods] == ["hole", "hole"]
    scale = jump_scale(net)
    for p in res.periods:
        assert np.linalg.norm(p.gradient) < 1e-10 * scale * 10 and np.linalg.norm(p.thrust) < 1e-10
    # single valued: the identities hold on every interior edge, cuts included
    check_reciprocal_identities(net, res, skip_cut=False)
    assert np.nanmax(res.vertex_spread) < 1e-10 * scale


def test_interior_supports_have_periods_equal_to_their_reactions(solved):
    net = solved["pillar_vault"]
    res = airy(net)
    interior_sup = np.flatnonzero(net.supports & ~net.mesh.boundary_vertex_mask)
    assert len(res.periods) == len(interior_sup) > 0
    xy = net.vertices[:, :2]
    e, w = net.edges, net.weights
    push = np.zeros((net.mesh.n_vertices, 2))  # thrust of compression on each vertex: Σ w (x_i − x_j)
    np.add.at(push, e[:, 0], w[:, None] * (xy[e[:, 0]] - xy[e[:, 1]]))
    np.add.at(push, e[:, 1], w[:, None] * (xy[e[:, 1]] - xy[e[:, 0]]))
    for p in res.periods:
        v = p.vertices
        T = push[v].sum(axis=0)
        M = float(np.sum(xy[v, 0] * push[v, 1] - xy[v, 1] * push[v, 0]))
        assert np.linalg.norm(T) > 1e-3 * jump_scale(net)  # a real reaction
        np.testing.assert_allclose(p.gradient, J(T), rtol=1e-9, atol=1e-9 * np.linalg.norm(T))
        # M is a small difference of large moments: compare on the scale |x| |T|
        assert abs(p.offset - M) <= 1e-12 * np.linalg.norm(xy[v], axis=1).max() * np.linalg.norm(T)
    # off the cuts (support–support edges, which carry nothing) the identities hold
    assert np.all(net.weights[res.cut_edges] == 0)
    R = res.reciprocal_vertices
    ef = net.mesh.edge_faces
    live = (ef >= 0).all(axis=1)
    live[res.cut_edges] = False
    ev = xy[e[:, 1]] - xy[e[:, 0]]
    d = R[ef[live, 0]] - R[ef[live, 1]]
    assert np.abs(d - w[live, None] * J(ev[live])).max() <= 1e-9 * jump_scale(net)


def holed_dome() -> Network:
    """A dome with an off-centre hole whose rim is pinned and one pinned interior vertex, solved:
    both sources have a non-zero period and their cuts run through free vertices."""
    from selfsupport.core.loads import SelfWeight
    from selfsupport.core.scene import Scene
    from selfsupport.methods.staggered import StaggeredLinearization

    m = make_shape("dome", rings=10).mesh
    V = m.vertices
    cen = np.array([V[f, :2].mean(axis=0) for f in m.faces])
    faces = [f for f, c in zip(m.faces, cen) if np.hypot(c[0] - 1.6, c[1] - 0.7) > 1.2]
    used = np.unique(np.concatenate(faces))
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    mesh = PolyMesh.from_faces(V[used], [remap[f] for f in faces])
    sup = mesh.boundary_vertex_mask.copy()
    d = np.hypot(mesh.vertices[:, 0] + 2.0, mesh.vertices[:, 1] + 1.0)
    d[sup] = np.inf
    sup[np.argmin(d)] = True
    res = StaggeredLinearization().solve(Scene(mesh=mesh, supports=sup, name="holed dome"), SelfWeight())
    assert res.converged and res.network.max_relative_error() < 1e-11
    return res.network


@pytest.fixture(scope="module")
def holed():
    return holed_dome()


def test_eq6_and_cell_identity_hold_next_to_cuts_of_supported_holes_and_interior_supports(holed):
    net = holed
    res = airy(net)
    assert len(net.mesh.boundary_loops) == 2
    assert sorted(p.kind for p in res.periods) == ["hole", "support"]
    assert all(np.linalg.norm(p.gradient) > 1e-3 * jump_scale(net) for p in res.periods)
    e = net.mesh.edges[res.cut_edges]
    on_cut = np.unique(e[~net.supports[e]])
    assert on_cut.size >= 5  # the cuts run through free vertices
    cv = curvatures(net, res, directions=False)
    free = ~net.supports
    assert np.array_equal(cv.defined, free)
    assert np.all(np.isfinite(cv.balance_residual[free])) and np.all(np.isfinite(cv.identity_residual[free]))
    assert cv.max_balance_residual <= 1e-9 and cv.max_identity_residual <= 1e-9
    assert not cv.flat.any()
    np.testing.assert_allclose(2 * cv.K_phi[free] * cv.H_rel[free], cv.load_density[free], rtol=1e-9, atol=0)
    # the star sums are Σ_j w_ij (φ_j − φ_i) with φ_j on vertex i's branch: off the cuts' vertices
    # and their neighbours that is the plain stress Laplacian of φ
    from formulations.equilibrium import Topology, stress_laplacian

    L = stress_laplacian(Topology.build(net.mesh.n_vertices, net.edges, net.supports), net.weights)
    near = np.zeros(net.mesh.n_vertices, bool)
    near[np.unique(e)] = True
    near[np.unique(net.edges[near[net.edges].any(axis=1)])] = True
    far = free & ~near
    np.testing.assert_allclose(cv.laplacian_phi[far], (L @ res.phi)[far], rtol=1e-9,
                               atol=1e-12 * np.abs(cv.laplacian_phi).max())
    rd = reciprocal(res)
    inner = free & ~net.mesh.boundary_vertex_mask
    np.testing.assert_allclose(2 * rd.cell_areas[inner], cv.laplacian_phi[inner], rtol=1e-9, atol=0)


def test_exported_phi_is_cut_open_along_cuts_with_planar_faces(holed, tmp_path):
    net = holed
    res = airy(net)
    n = net.mesh.n_vertices
    assert res.n_cover_copies > 0 and res.nonplanar_faces.size == 0 and res.split_edges.size == 0
    assert np.array_equal(res.cover_parent[:n], np.arange(n))
    assert np.isin(res.cover_parent[n:], net.mesh.edges[res.cut_edges]).all()  # copies only on cuts
    assert np.nanmax(res.vertex_spread) < 1e-10 * np.ptp(res.phi)
    from selfsupport.io import read_mesh, write_mesh

    write_mesh(tmp_path / "phi.obj", res.stress_mesh())
    phi_mesh = read_mesh(tmp_path / "phi.obj")
    assert phi_mesh.n_vertices == n + res.n_cover_copies and phi_mesh.n_faces == net.mesh.n_faces
    np.testing.assert_allclose(phi_mesh.vertices[:n, 2], res.phi, rtol=0, atol=1e-12 * np.abs(res.phi).max())
    # every face of Φ lies in its own plane, whose gradient is the reciprocal vertex
    P = phi_mesh.vertices
    for f, face in enumerate(phi_mesh.faces):
        plane = P[face, :2] @ res.face_gradients[f] + res.face_offsets[f]
        assert np.abs(P[face, 2] - plane).max() <= 1e-10 * np.ptp(res.phi)
    # and its faces still meet along the network's edges off the cuts: the copies sit on cut vertices only
    assert len(np.unique(P[:, :2].round(9), axis=0)) == n


def test_free_boundary_vertices_balance_with_the_plane_beyond_the_boundary():
    net = cheese_network()
    res = airy(net)
    cv = curvatures(net, res, directions=False)
    rim = ~net.supports & net.mesh.boundary_vertex_mask
    assert rim.sum() > 20
    assert np.all(np.isfinite(cv.balance_residual[rim])) and cv.max_balance_residual < 1e-9
    assert cv.max_identity_residual < 1e-9 and np.all(cv.reciprocal_areas[rim] > 0)
    assert np.isnan(cv.H_rel_mixed[rim]).all()  # S has no plane beyond the boundary


def test_reversed_faces_give_the_same_surface_and_diagram(solved):
    for net in (random_network(8, n=150), solved["pillar_vault"]):
        flipped = PolyMesh.from_faces(net.vertices, [f[::-1] for f in net.mesh.faces])
        assert np.array_equal(flipped.edges, net.mesh.edges)
        other = Network(mesh=flipped, weights=net.weights, loads=net.loads, supports=net.supports)
        a, b = airy(net), airy(other)
        assert (a.orientation, b.orientation) == (1, -1)
        scale = np.abs(a.phi).max()
        np.testing.assert_allclose(b.phi, a.phi, atol=1e-10 * scale)
        np.testing.assert_allclose(b.reciprocal_vertices, a.reciprocal_vertices, atol=1e-10 * np.abs(a.reciprocal_vertices).max())
        for p, q in zip(a.periods, b.periods):
            np.testing.assert_allclose(q.gradient, p.gradient, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(reciprocal(b).cell_areas, reciprocal(a).cell_areas, rtol=1e-9)


# ------------------------------------------------------------------------------ polygons, non-integrable input
def test_quad_network_has_planar_phi_faces(solved):
    net = solved["barrel_vault"]
    assert set(net.mesh.face_sizes.tolist()) == {4}
    res = airy(net)
    assert res.nonplanar_faces.size == 0 and res.convex
    check_reciprocal_identities(net, res, tol=1e-9)


def test_non_integrable_input_is_fitted_and_reported(solved):
    net = solved["barrel_vault"]
    rng = np.random.default_rng(0)
    w = net.weights * (1 + 1e-4 * rng.normal(size=net.weights.shape))
    res = airy(Network(mesh=net.mesh, weights=w, loads=net.loads, supports=net.supports))
    assert res.integration == "least-squares"
    assert 1e-7 < res.max_closure_residual < 1e-3  # the horizontal imbalance, reported
    assert 1e-7 < res.max_edge_residual < 1e-2  # spread by least squares, not accumulated
    # quads whose vertex values are no longer coplanar are split by fan diagonals
    assert res.nonplanar_faces.size > 0
    assert len(res.split_edges) == res.nonplanar_faces.size  # one diagonal per quad
    quads = [set(net.mesh.faces[f]) for f in res.nonplanar_faces]
    assert all(set(d) <= q for d, q in zip(res.split_edges.tolist(), quads))
    assert np.abs(res.split_edge_weights).max() < 1e-2 * np.abs(net.weights).max()


# ------------------------------------------------------------------------------ principal directions
def test_quadratic_fits_recover_hessians_and_relative_principal_directions():
    rng = np.random.default_rng(11)
    pts = random_points(rng, 200)
    tri, _ = lower_hull(pts, 0.5 * (pts ** 2).sum(axis=1))
    mesh = PolyMesh(np.c_[pts, np.zeros(len(pts))], tri.ravel(), np.arange(0, 3 * len(tri) + 1, 3))
    Hp = np.array([[2.0, 0.3], [0.3, 1.0]])
    Hs = np.array([[-1.0, 0.4], [0.4, -3.0]])
    x, y = pts[:, 0], pts[:, 1]
    phi = 0.5 * (Hp[0, 0] * x * x + 2 * Hp[0, 1] * x * y + Hp[1, 1] * y * y) + 0.2 * x
    s = 0.5 * (Hs[0, 0] * x * x + 2 * Hs[0, 1] * x * y + Hs[1, 1] * y * y) - y + 1
    Hp_est, Hs_est = vertex_hessians(mesh, [phi, s])
    np.testing.assert_allclose(Hp_est, np.broadcast_to(Hp, Hp_est.shape), atol=1e-9)
    np.testing.assert_allclose(Hs_est, np.broadcast_to(Hs, Hs_est.shape), atol=1e-9)
    lam, vec = relative_principal(Hp_est, Hs_est)
    w, V = np.linalg.eig(np.linalg.solve(Hp, Hs))
    order = np.argsort(w.real)
    np.testing.assert_allclose(lam, np.broadcast_to(w.real[order], lam.shape), rtol=1e-9)
    for k in range(2):
        ref = V[:, order[k]].real / np.linalg.norm(V[:, order[k]].real)
        assert np.allclose(np.abs(vec[:, :, k] @ ref), 1.0, atol=1e-9)


def test_vector_field_export_layout(tmp_path, solved):
    net = solved["dome"]
    cv = curvatures(net)
    out = tmp_path / "dome-vf.txt"
    write_vector_fields(out, net, cv, up="-y")
    rows = np.loadtxt(out)
    assert rows.shape == (net.mesh.n_faces, 6)
    u, v = to_ours(rows[:, :3], "-y"), to_ours(rows[:, 3:], "-y")
    ok = np.isfinite(rows).all(axis=1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(np.linalg.norm(u[ok], axis=1), 1.0, atol=1e-8)
    # tangent to the faces of the network
    from selfsupport.core.geometry import face_normals

    nrm = face_normals(net.mesh)
    assert np.abs((u * nrm).sum(axis=1)[ok]).max() < 1e-6 and np.abs((v * nrm).sum(axis=1)[ok]).max() < 1e-6
    # on the spherical dome with its rotationally symmetric stress field, the directions are radial and circumferential
    c = np.array([net.vertices[f, :2].mean(axis=0) for f in net.mesh.faces])
    far = ok & (np.linalg.norm(c, axis=1) > 1.0)
    radial = c[far] / np.linalg.norm(c[far], axis=1, keepdims=True)
    cosines = np.abs(np.c_[(u[far, :2] * radial).sum(axis=1), (v[far, :2] * radial).sum(axis=1)]
                     / np.c_[np.linalg.norm(u[far, :2], axis=1), np.linalg.norm(v[far, :2], axis=1)])
    # one of the two is (nearly) radial
    assert np.median(cosines.max(axis=1)) > 0.95


@pytest.mark.skipif(not (SHARED / "paper-scenes" / "published" / "lilium-n-vf.txt").exists(),
                    reason="the paper scenes (../shared) are not beside the repository")
def test_published_vector_field_has_the_exported_layout():
    rows = np.loadtxt(SHARED / "paper-scenes" / "published" / "lilium-n-vf.txt")
    assert rows.shape[1] == 6
    ok = np.isfinite(rows).all(axis=1)  # like ours, the paper's file has nan where Φ is not strictly convex
    assert ok.mean() > 0.9
    np.testing.assert_allclose(np.linalg.norm(rows[ok, :3], axis=1), 1.0, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(rows[ok, 3:], axis=1), 1.0, atol=1e-4)


# ------------------------------------------------------------------------------ CLI
def test_cli_airy_writes_the_documented_file(tmp_path):
    from selfsupport.cli import main
    from selfsupport.io import write_network

    net = cheese_network()
    src = tmp_path / "net.json"
    write_network(src, net)
    out = tmp_path / "airy.json"
    code = main(["airy", str(src), "--out", str(out), "--stress", str(tmp_path / "phi.obj"),
                 "--reciprocal", str(tmp_path / "recip.obj"), "--vector-fields", str(tmp_path / "vf.txt")])
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["in_equilibrium"] is True and doc["max_relative_error"] <= doc["tol"]
    for key in ("phi", "reciprocal_vertices", "H_rel", "K_phi", "balance_residual", "closure_residual", "convex"):
        assert key in doc
    assert len(doc["phi"]) == net.mesh.n_vertices
    R = np.array(doc["reciprocal_vertices"])
    assert R.shape == (net.mesh.n_faces, 2)
    assert doc["convex"] is True and doc["closure_residual"] < 1e-12
    bal = np.array([np.nan if x is None else x for x in doc["balance_residual"]])
    assert np.nanmax(bal) < 1e-9 and np.isnan(bal[net.supports]).all()
    from selfsupport.io import read_mesh

    phi_mesh = read_mesh(tmp_path / "phi.obj")
    np.testing.assert_allclose(phi_mesh.vertices[:, 2], doc["phi"], rtol=1e-12, atol=1e-12)
    assert (tmp_path / "recip.obj").read_text().count("\nf ") == int((~net.mesh.boundary_vertex_mask).sum())


def test_cli_airy_of_a_network_not_in_equilibrium_says_so_and_exits_nonzero(tmp_path, capsys):
    """Free vertices moved sideways: every weight is still compressive, but the network has no Airy
    surface; the verdict is that it is not in equilibrium (exit 4), not that some weight is tensile."""
    from dataclasses import replace

    from selfsupport.cli import main
    from selfsupport.io import write_network

    net = cheese_network()
    V = net.vertices.copy()
    free = ~net.supports
    V[free, :2] += 0.05 * np.random.default_rng(0).standard_normal((int(free.sum()), 2))
    moved = replace(net, mesh=net.mesh.with_vertices(V))
    assert moved.min_weight() > 0 and moved.max_relative_error() > 1e-3
    src, out = tmp_path / "net.json", tmp_path / "airy.json"
    write_network(src, moved)
    code = main(["airy", str(src), "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 4 and cap.err.count("\n") == 1 and "NOT in equilibrium" in cap.err
    assert "tensile" not in cap.out + cap.err
    doc = json.loads(out.read_text())
    assert doc["in_equilibrium"] is False and doc["max_relative_error"] > doc["tol"]


def test_cli_airy_rejects_a_missing_file(tmp_path, capsys):
    from selfsupport.cli import main

    assert main(["airy", str(tmp_path / "nope.json"), "--out", str(tmp_path / "a.json")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_cli_choice_lists_match_the_registries():
    from selfsupport.analysis.airy import INTEGRATIONS
    from selfsupport.analysis.construction import PHI_FUNCTIONS
    from selfsupport.cli.airy import INTEGRATION_NAMES, PHI_NAMES

    assert sorted(PHI_NAMES) == sorted(PHI_FUNCTIONS)
    assert sorted(INTEGRATION_NAMES) == sorted(INTEGRATIONS)


def test_relative_principal_directions_do_not_depend_on_the_scale_of_the_hessians():
    """H_phi⁻¹ H_s at any scale (a network 1e150 m high, an Airy surface of 1e-150): the same
    directions, eigenvalues scaled by the ratio, and no numpy overflow warning on the way."""
    import warnings

    rng = np.random.default_rng(3)
    B = rng.standard_normal((50, 2, 2))
    Hp = B @ B.transpose(0, 2, 1) + 0.5 * np.eye(2)  # convex Φ: positive definite
    C = rng.standard_normal((50, 2, 2))
    Hs = C + C.transpose(0, 2, 1)
    lam, vec = relative_principal(Hp, Hs)
    assert np.isfinite(lam).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lam2, vec2 = relative_principal(Hp * 1e-150, Hs * 1e150)
    np.testing.assert_allclose(lam2, lam * 1e300, rtol=1e-9)
    np.testing.assert_allclose(np.abs((vec2 * vec).sum(axis=-2)), 1.0, atol=1e-9)  # same directions up to sign
