"""Closest points and distances on the reference (libigl's AABB tree) against trimesh's exact query."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from selfsupport.core.evidence import closest_points, distance_stats, roundoff_message, triangulate
from selfsupport.core.shapes import make_shape


def test_closest_points_agree_with_trimesh():
    ref = make_shape("concave_disk", n_vertices=500).mesh
    rng = np.random.default_rng(3)
    diag = np.linalg.norm(np.ptp(ref.vertices, axis=0))
    # points near the surface, as the solver produces them, and far from it
    P = ref.vertices[rng.integers(0, ref.n_vertices, 400)] + rng.normal(scale=0.02 * diag, size=(400, 3))
    P[::10] += rng.normal(scale=0.5 * diag, size=(40, 3))
    ours, d, n = closest_points(P, ref)
    tm = trimesh.Trimesh(ref.vertices, triangulate(ref), process=False)
    theirs, d_tm, _ = tm.nearest.on_surface(P)
    np.testing.assert_allclose(d, d_tm, rtol=1e-9, atol=1e-12 * diag)
    np.testing.assert_allclose(np.linalg.norm(ours - P, axis=1), d, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-12)
    assert np.all(n[:, 2] > 0)  # interpolated normals of an upward surface point up


def test_a_non_finite_point_has_no_closest_point():
    ref = make_shape("dome", n_vertices=200).mesh
    P = np.vstack([ref.vertices[:3], [[np.nan, 0.0, 0.0]], [[0.0, np.inf, 1.0]]])
    closest, d, n = closest_points(P, ref)
    np.testing.assert_allclose(closest[:3], ref.vertices[:3], atol=1e-12)
    assert np.all(np.isnan(closest[3:])) and np.all(np.isnan(n[3:])) and np.all(d[3:] == np.inf)


def test_normals_at_the_reference_vertices_are_its_vertex_normals():
    """At a vertex every adjacent triangle gives barycentric (1, 0, 0): the interpolated
    normal is exactly that vertex's normal, whichever triangle the tree reports."""
    from selfsupport.core.geometry import vertex_normals

    ref = make_shape("pillar_vault", n_vertices=400).mesh
    closest, d, n = closest_points(ref.vertices, ref)
    diag = np.linalg.norm(np.ptp(ref.vertices, axis=0))
    assert d.max() <= 1e-12 * diag
    np.testing.assert_allclose(closest, ref.vertices, atol=1e-12 * diag)
    np.testing.assert_allclose(n, vertex_normals(ref), atol=1e-9)


def test_points_on_the_surface_have_zero_distance():
    ref = make_shape("dome", n_vertices=300).mesh
    tris = triangulate(ref)
    bary = np.random.default_rng(0).dirichlet([1, 1, 1], size=len(tris))
    P = np.einsum("tc,tcj->tj", bary, ref.vertices[tris])
    _, d, _ = closest_points(P, ref)
    assert d.max() <= 1e-12 * np.linalg.norm(np.ptp(ref.vertices, axis=0))
    assert distance_stats(ref.vertices, ref) == (0.0, 0.0)


def test_distance_to_surface_is_exact_near_and_far():
    """libigl's AABB query equals trimesh's exact query, near the surface and far from it."""
    from selfsupport.core import evidence

    ref = make_shape("concave_disk", n_vertices=800).mesh
    rng = np.random.default_rng(5)
    diag = np.linalg.norm(np.ptp(ref.vertices, axis=0))
    near = ref.vertices[rng.integers(0, ref.n_vertices, 300)] + rng.normal(scale=0.005 * diag, size=(300, 3))
    far = ref.vertices[rng.integers(0, ref.n_vertices, 100)] + rng.normal(scale=0.5 * diag, size=(100, 3))
    P = np.vstack([near, far, [[np.nan, 0.0, 0.0]]])
    d = evidence.distance_to_surface(P, ref)
    tm = trimesh.Trimesh(ref.vertices, triangulate(ref), process=False)
    d_tm = tm.nearest.on_surface(P[:-1])[1]
    np.testing.assert_allclose(d[:-1], d_tm, rtol=1e-9, atol=1e-12 * diag)
    assert d[-1] == np.inf
    # far from the origin and at another scale: the same distances, scaled
    shift, k = np.array([3e5, -2e5, 7e4]), 1e3
    moved = evidence.distance_to_surface(k * P[:-1] + shift, ref.with_vertices(k * ref.vertices + shift))
    np.testing.assert_allclose(moved, k * d[:-1], rtol=1e-8, atol=1e-9 * k * diag)


def test_a_result_asks_the_reference_once_about_its_vertices(monkeypatch):
    """The distance evidence, the objective terms and the hull record of one result all ask about
    the same final vertices: one AABB query per reference mesh and set of points (0.3 s at 200k
    vertices), whose answer is exactly that of a fresh query."""
    from selfsupport.core import evidence
    from selfsupport.methods.base import hull_signed_distance

    ref = make_shape("dome", n_vertices=300).mesh
    V = ref.vertices + np.random.default_rng(5).normal(scale=1e-2, size=ref.vertices.shape)
    evidence._INDEX_CACHE.clear()
    idx = evidence._reference_index(ref)
    calls = []
    real = idx.tree.squared_distance

    class Counting:  # (igl's AABB is a C++ object: wrap it rather than patch its method)
        def squared_distance(self, *a):
            calls.append(1)
            return real(*a)

    monkeypatch.setattr(idx, "tree", Counting())
    first = closest_points(V, ref)
    stats = distance_stats(V, ref)
    side = hull_signed_distance(ref, V)
    assert len(calls) == 1
    closest_points(V + 1e-9, ref)  # other points: a new query
    assert len(calls) == 2
    evidence._INDEX_CACHE.clear()  # a fresh index gives the same answers, bit for bit
    fresh = closest_points(V, ref)
    for a, b in zip(first, fresh):
        np.testing.assert_array_equal(a, b)
    assert distance_stats(V, ref) == stats
    np.testing.assert_array_equal(hull_signed_distance(ref, V), side)


def test_residuals_sum_in_the_order_of_np_add_at():
    """The bincount residuals are the np.add.at sums bit for bit (same terms, same order)."""
    from selfsupport.core.evidence import residuals

    m = make_shape("cross_vault", n_vertices=400).mesh
    rng = np.random.default_rng(2)
    V = m.vertices + rng.normal(scale=1e-3, size=m.vertices.shape)
    w, L = rng.uniform(0.1, 10.0, m.n_edges), -rng.uniform(1.0, 2.0, m.n_vertices)
    e = m.edges
    f = w[:, None] * (V[e[:, 1]] - V[e[:, 0]])
    expect = np.zeros_like(V)
    np.add.at(expect, e[:, 0], f)
    np.add.at(expect, e[:, 1], -f)
    expect[:, 2] -= L
    np.testing.assert_array_equal(residuals(vertices=V, edges=e, weights=w, loads=L), expect)


def test_a_network_far_from_the_origin_is_in_equilibrium_to_its_roundoff_floor():
    """Moved 10⁵ m from the origin, a network in equilibrium to 4e-13 reads a relative error of
    ~3e-9: its coordinates are rounded to 1.5e-11 m and its forces are large against its loads.
    That error is within the round-off floor (the floor bounds it), so the network is in
    equilibrium to a tolerance of 1e-9 as far as doubles can tell; a vertex moved by 1e-7 m is
    not (its error is ~100× the floor). Moved 10⁶ m (error ~3e-8) it is within its floor but
    above FLOOR_CAP, which the floor never relaxes a tolerance past."""
    from selfsupport.core.evidence import FLOOR_CAP, FLOOR_MARGIN
    from selfsupport.core.result import Network
    from selfsupport.methods.staggered import StaggeredLinearization

    net = StaggeredLinearization().solve(make_shape("pillar_vault", n_vertices=400)).network
    assert net.in_equilibrium(1e-9) and net.max_relative_error() <= 1e-11

    def moved(V, by=1e5):
        return Network(mesh=net.mesh.with_vertices(V + [by, by, 0.0]), weights=net.weights, loads=net.loads,
                       supports=net.supports)

    far = moved(net.vertices)
    assert 1e-9 < far.max_relative_error() < FLOOR_CAP  # rounding alone
    assert np.all(far.relative_errors() <= far.roundoff_floors())  # (measured ≤ 0.2× the floor)
    assert far.in_equilibrium(1e-9)
    farther = moved(net.vertices, 1e6)
    assert np.all(farther.relative_errors() <= farther.roundoff_floors()) and farther.max_relative_error() > FLOOR_CAP
    assert not farther.in_equilibrium(1e-9) and farther.in_equilibrium(1e-7)
    # ... and its report says why: the offset, not its forces (centred, its floor is ~1e-12)
    assert far.roundoff_limit(1e-9) is None and net.roundoff_limit(1e-9) is None
    limit = farther.roundoff_limit(1e-9)
    assert limit["max_relative_error"] == farther.max_relative_error()
    assert limit["n_vertices"] == int(np.sum(farther.relative_errors() > 1e-9))
    assert abs(limit["offset"] - np.linalg.norm(0.5 * (farther.vertices.min(0) + farther.vertices.max(0)))) < 1e-6
    assert limit["centred_floor"] < 1e-4 * limit["floor"] and FLOOR_MARGIN * limit["centred_floor"] < 1e-9
    assert "translate it near the origin" in roundoff_message(limit, 1e-9)
    V = net.vertices.copy()
    i = int(np.flatnonzero(~net.supports)[10])
    V[i, 2] += 1e-7
    off = moved(V)
    assert not off.in_equilibrium(1e-9)
    assert off.max_relative_error() > 10 * FLOOR_MARGIN * off.roundoff_floors().max()  # (measured ~100×)
    assert off.roundoff_limit(1e-9) is None  # (off for a reason other than rounding)


def test_a_flat_arch_is_held_above_tol_by_its_thrust_not_by_where_it_lies():
    """A two-bar arch of rise 1e-9 m at the origin: its thrust (1 N) is 5e8 times its crown's
    load (2e-9 N), so one spacing of doubles in the crown's x (2.2e-16 m) is a relative error of
    2.2e-7 — above the cap, within the floor (eps·4 N·m / 2e-9 N = 4.4e-7). Moving it to the
    origin would not help; the report says the forces are why."""
    from selfsupport.core.evidence import FLOOR_CAP, roundoff_limit

    h = 1e-9
    V = np.array([[0.0, 0, 0], [1.0, 0, h], [2.0, 0, 0]])
    kw = dict(edges=np.array([[0, 1], [1, 2]]), weights=np.ones(2), loads=np.array([0.0, -2 * h, 0.0]),
              supports=np.array([True, False, True]))
    assert roundoff_limit(vertices=V, tol=1e-12, **kw) is None  # exactly in equilibrium
    V[1, 0] = np.nextafter(1.0, 2.0)
    limit = roundoff_limit(vertices=V, tol=1e-12, **kw)
    assert FLOOR_CAP < limit["max_relative_error"] <= limit["floor"]
    assert limit["force_ratio"] == pytest.approx(1 / (2 * h), rel=1e-6)
    assert limit["centred_floor"] == pytest.approx(limit["floor"] / 2, rel=1e-6)  # (|x| sums 4 → 2)
    assert "edge forces there reach 5e+08×" in roundoff_message(limit, 1e-12)
    # a vertex off by more than its floor allows is not held there by rounding
    V[1, 0] = 1.0 + 1e-12
    assert roundoff_limit(vertices=V, tol=1e-12, **kw) is None


def test_the_round_off_report_names_a_vertex_whose_squashed_faces_carry_little_load():
    """A four-bar flat arch (thrust 1 N, rise ~1e-9 m) whose middle vertex carries 0.02 of its
    neighbours' load (2e-11 N against 1e-9 N): one spacing of doubles in its x is within its
    floor, and the report blames the small load alongside the forces. The same arch with equal
    loads is not called squashed."""
    from selfsupport.core.evidence import DEGENERATE_LOAD, SQUASHED_LOAD, residuals, roundoff_limit

    h = 1e-9
    q = np.array([1.0, 0.02, 1.0]) * h  # the free vertices' loads (second differences of z)
    K = 2 * np.eye(3) - np.eye(3, k=1) - np.eye(3, k=-1)
    z = np.r_[0.0, np.linalg.solve(K, q), 0.0]
    V = np.c_[np.arange(5.0), np.zeros(5), z]
    E = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    L = residuals(vertices=V, edges=E, weights=np.ones(4), loads=np.zeros(5))[:, 2]
    kw = dict(edges=E, weights=np.ones(4), loads=L, supports=np.array([1, 0, 0, 0, 1], bool))
    assert np.allclose(-L[1:4], q, rtol=1e-6)
    assert roundoff_limit(vertices=V, tol=1e-12, **kw) is None
    V[2, 0] = np.nextafter(2.0, 3.0)
    limit = roundoff_limit(vertices=V, tol=1e-12, **kw)
    assert limit is not None and DEGENERATE_LOAD < limit["load_ratio"] < SQUASHED_LOAD
    assert limit["load_ratio"] == pytest.approx(0.02, rel=1e-6)
    msg = roundoff_message(limit, 1e-12)
    assert "edge forces there reach" in msg and "carry only 0.02 of the median vertex load" in msg
    # the same network with the middle vertex carrying its share: no squashed faces named
    q[1] = h
    z = np.r_[0.0, np.linalg.solve(K, q), 0.0]
    V = np.c_[np.arange(5.0), np.zeros(5), z]
    kw["loads"] = residuals(vertices=V, edges=E, weights=np.ones(4), loads=np.zeros(5))[:, 2]
    V[2, 0] = np.nextafter(2.0, 3.0)
    limit = roundoff_limit(vertices=V, tol=1e-12, **kw)
    assert limit is not None and limit["load_ratio"] == pytest.approx(1.0, rel=1e-6)
    assert "squashed" not in roundoff_message(limit, 1e-12)


def test_a_vertex_with_next_to_no_load_is_degenerate_not_held_by_rounding():
    """A four-bar chain 10⁹ m from the origin, horizontal thrust 1 N, whose middle vertex has
    a kink of 1e-6 (load 1e-6 N against 0.5 N and 2.5 N at its neighbours): moved by one spacing
    of doubles, every vertex is within its floor — the middle one only because its load nearly
    vanishes. That is a degenerate vertex (load < DEGENERATE_LOAD × the median), so the report
    does not blame rounding; with a proper load there it does."""
    from selfsupport.core.evidence import DEGENERATE_LOAD, residuals, roundoff_limit

    def chain(kink: float) -> dict:
        V = np.array([[0.0, 0, 0], [1, 0, 1], [2, 0, 1.5], [3, 0, 2 - kink], [4, 0, 0]])
        E = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
        L = residuals(vertices=V, edges=E, weights=np.ones(4), loads=np.zeros(5))[:, 2]
        V[:, 0] += 1e9
        V[2, 0] = np.nextafter(V[2, 0], 2e9)
        return dict(vertices=V, edges=E, weights=np.ones(4), loads=L, supports=np.array([1, 0, 0, 0, 1], bool))

    kw = chain(1e-6)
    assert abs(kw["loads"][2]) < DEGENERATE_LOAD * np.median(np.abs(kw["loads"][1:4]))
    assert roundoff_limit(tol=1e-9, **kw) is None
    rep = roundoff_limit(tol=1e-9, **chain(0.25))  # (load 0.25 N there)
    assert rep is not None and rep["offset"] > 1e9


def test_a_warm_fit_counts_a_vertex_at_its_floor_as_fitted_unless_it_slid_onto_its_neighbours():
    """The warm start's 'fits already' tolerance: 4× the floor without the 1e-8 cap (the 256k
    pillar vault's start, floor 1.6e-7, ran the interior point 150 s for nothing), but capped
    at a vertex whose load is below DEGENERATE_LOAD × the median."""
    from selfsupport.core.evidence import DEGENERATE_LOAD, FLOOR_CAP, FLOOR_MARGIN, degenerate, fit_floor_tolerance

    floors = np.array([1e-13, 2.4e-7, 2.4e-7])
    loads = -np.array([1.0, 0.5, 0.1 * DEGENERATE_LOAD])
    assert degenerate(loads).tolist() == [False, False, True]
    np.testing.assert_array_equal(fit_floor_tolerance(floors, loads),
                                  [FLOOR_MARGIN * 1e-13, FLOOR_MARGIN * 2.4e-7, FLOOR_CAP])


def test_stress_sums_are_the_stress_laplacian_and_the_residual_is_built_on_them():
    """The one numeric form of eqs. (2)-(3)'s left side, ``Σ_j w_ij (f_j − f_i)``, equals the
    sparse stress Laplacian of the problem layer applied to scalars, top views and positions, and
    the residual is it minus the loads; ``force_sums`` is the sum of |w| × edge length."""
    from formulations.equilibrium import Topology, stress_laplacian
    from selfsupport.core.evidence import force_sums, residuals, stress_sums

    rng = np.random.default_rng(3)
    mesh = make_shape("dome", n_vertices=120).mesh
    e, n = mesh.edges, mesh.n_vertices
    w = rng.uniform(-1.0, 2.0, len(e))
    L = stress_laplacian(Topology.build(n, e, np.zeros(n, bool)), w)
    for values in (rng.normal(size=n), rng.normal(size=(n, 2)), mesh.vertices):
        np.testing.assert_allclose(stress_sums(edges=e, weights=w, values=values), L @ values, rtol=0, atol=1e-12)
    loads = rng.normal(size=n)
    r = residuals(vertices=mesh.vertices, edges=e, weights=w, loads=loads)
    np.testing.assert_array_equal(r[:, :2], stress_sums(edges=e, weights=w, values=mesh.vertices)[:, :2])
    np.testing.assert_allclose(r[:, 2], L @ mesh.vertices[:, 2] - loads, rtol=0, atol=1e-12)
    lengths = np.linalg.norm(mesh.vertices[e[:, 1]] - mesh.vertices[e[:, 0]], axis=1)
    expected = np.bincount(e.ravel(), weights=np.repeat(np.abs(w) * lengths, 2), minlength=n)
    np.testing.assert_allclose(force_sums(edges=e, weights=w, values=mesh.vertices), expected, rtol=1e-14)
