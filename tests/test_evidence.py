"""Closest points and distances on the reference (libigl's AABB tree) against trimesh's exact query."""
from __future__ import annotations

import numpy as np
import trimesh

from selfsupport.evidence import closest_points, distance_stats, triangulate
from selfsupport.shapes import make_shape


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
    from selfsupport.geometry import vertex_normals

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
    from selfsupport import evidence

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
