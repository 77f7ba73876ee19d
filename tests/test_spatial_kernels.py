"""The numpy kernels that stand in for scipy.spatial on the solve path: :func:`near_pairs` (the
input check's coincident vertices) against ``cKDTree.query_pairs``, and :func:`convex_hull_2d`
(the scale-free unit's smallest box) against Qhull."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull, cKDTree

from selfsupport.core import geometry
from selfsupport.core.geometry import convex_hull_2d, near_pairs, plan_box_diagonal


def _kd_pairs(P: np.ndarray, r: float) -> np.ndarray:
    pairs = cKDTree(P).query_pairs(r, output_type="ndarray")
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if len(pairs) else np.zeros((0, 2), np.intp)


def _planted(rng: np.random.Generator, n: int, d: int, r: float) -> np.ndarray:
    """Random points in the unit cube with pairs planted across the borders of near_pairs' grid
    (cells r(1 + 1e-9) wide from the lowest coordinate): one at ``k w − a``, one at ``k w + b`` on
    every axis at once (a diagonal neighbour), ``a + b`` just under or just over r / √d."""
    P = rng.random((n, d))
    P[0] = 0.0  # (the grid's origin)
    w = r * (1 + 1e-9)
    k = rng.integers(1, int(0.9 / w), size=(n // 4, 1))
    gap = r / np.sqrt(d) * rng.choice([0.5, 0.999, 1.001, 1.5], size=(n // 4, 1))
    a = gap * rng.random((n // 4, 1))
    side = rng.choice([-1.0, 1.0], size=(n // 4, d))  # (crossing the border in either sense)
    lo = k * w - side * a
    hi = lo + side * gap
    return np.vstack([P, lo, hi])


@pytest.mark.parametrize("d", [1, 2, 3])
@pytest.mark.parametrize("seed", range(4))
def test_near_pairs_are_the_kd_trees_pairs_across_cell_borders(d, seed):
    rng = np.random.default_rng(seed)
    for r in (1e-3, 2e-2, 0.2):
        P = _planted(rng, 400, d, r)
        got = near_pairs(P, r)
        assert np.array_equal(got, _kd_pairs(P, r)), (d, r)
        assert len(got) >= 1 and (got[:, 0] < got[:, 1]).all()


def test_near_pairs_finds_the_coincident_vertices_of_a_large_mesh_as_the_check_asks():
    """The input check's radius, 1e-10 of the diagonal: welded copies found, neighbours 1e-9 apart not."""
    rng = np.random.default_rng(7)
    P = rng.random((20000, 3)) * [30.0, 20.0, 8.0] + [1e5, -3e4, 12.0]  # (far from the origin)
    r = 1e-10 * float(np.linalg.norm(np.ptp(P, axis=0)))
    copies = rng.choice(len(P), 50, replace=False)
    near = P[copies[:25]] + rng.normal(size=(25, 3)) * r * 0.2
    apart = P[copies[25:]] + np.array([1.0, 0.0, 0.0]) * 10 * r
    Q = np.vstack([P, P[copies[25:30]], near, apart])
    got = near_pairs(Q, r)
    assert np.array_equal(got, _kd_pairs(Q, r))
    assert len(got) == 30  # five exact copies and 25 near ones; those ten radii away are not pairs


def test_near_pairs_with_radius_zero_pairs_identical_points_only():
    P = np.array([[0.0, 1, 2], [0, 1, 2], [0, 1, 2 + 1e-15], [5, 5, 5], [5, 5, 5]])
    assert near_pairs(P, 0.0).tolist() == [[0, 1], [3, 4]] == _kd_pairs(P, 0.0).tolist()
    assert near_pairs(P[:1], 1.0).shape == (0, 2)


def test_near_pairs_beyond_one_integer_key_falls_back_to_the_kd_tree():
    """Ten dimensions: the cells cannot be numbered in one int64 (the fallback), same pairs."""
    rng = np.random.default_rng(3)
    P = rng.random((300, 10))
    P = np.vstack([P, P[:40] + rng.normal(size=(40, 10)) * 0.01])
    assert np.array_equal(near_pairs(P, 0.05), _kd_pairs(P, 0.05))


def _same_corners(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    return set(map(tuple, points[a])) == set(map(tuple, points[b]))


@pytest.mark.parametrize("seed", range(5))
def test_convex_hull_2d_has_qhulls_corners_counter_clockwise(seed):
    rng = np.random.default_rng(seed)
    clouds = [rng.random((500, 2)), rng.normal(size=(300, 2)) * [1e4, 1e-3] + 5e6,
              np.c_[np.cos(t := rng.random(200) * 2 * np.pi), np.sin(t)] * rng.random((200, 1)) ** 0.05]
    for P in clouds:
        h = convex_hull_2d(P)
        assert _same_corners(P, h, ConvexHull(P).vertices)
        e = np.roll(P[h], -1, axis=0) - P[h]
        assert (e[:, 0] * np.roll(e[:, 1], -1) - e[:, 1] * np.roll(e[:, 0], -1) > 0).all()  # convex, CCW


def test_convex_hull_2d_leaves_out_points_on_its_edges_and_degenerate_sets():
    g = np.stack(np.meshgrid(np.arange(7.0), np.arange(4.0)), -1).reshape(-1, 2)  # a grid: 16 points on the sides
    assert sorted(g[convex_hull_2d(g)].tolist()) == [[0, 0], [0, 3], [6, 0], [6, 3]]
    assert _same_corners(g, convex_hull_2d(g), ConvexHull(g).vertices)
    line = np.c_[np.arange(5.0), 2 * np.arange(5.0)]
    assert len(convex_hull_2d(line)) == 0 and len(convex_hull_2d(g[:2])) == 0
    assert len(convex_hull_2d(np.array([[0.0, 0], [1, 0], [np.nan, 1]]))) == 0


@pytest.mark.parametrize("seed", range(3))
def test_plan_box_diagonal_is_the_same_number_as_with_qhulls_hull(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    t = rng.random() * np.pi
    R = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    V = (rng.random((800, 3)) * [12.0, 5.0, 2.0]) @ R.T + [300.0, -40.0, 0.0]
    ours = plan_box_diagonal(V)
    monkeypatch.setattr(geometry, "convex_hull_2d", lambda p: ConvexHull(p).vertices)
    assert ours == plan_box_diagonal(V)  # (bit for bit: the scale of every solve)


@pytest.mark.parametrize("r", [0.0, 1e-10, 0.999, 1.0, 1.4])
def test_near_pairs_on_a_grid_whose_coordinates_tie_along_every_axis(r):
    """A 6 × 5 × 4 grid of unit spacing (ties along every axis, which a screen along one axis
    would take for near pairs): none closer than 1, the axis neighbours at 1, the face diagonals
    at √2 > 1.4."""
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(5.0), np.arange(4.0)), -1).reshape(-1, 3) + [1e3, -2e3, 5.0]
    got = near_pairs(g, r)
    assert np.array_equal(got, _kd_pairs(g, r))
    assert len(got) == (0 if r < 1 else 5 * 5 * 4 + 6 * 4 * 4 + 6 * 5 * 3)


def test_near_pairs_far_from_the_origin_across_the_screening_direction():
    """Coordinates of 1e9 whose products with the screen's direction cancel (the rounding of the
    projections far above the radius): the pairs are still all found."""
    u = np.sqrt([2.0, 3.0, 4.0])
    u /= np.linalg.norm(u)
    w = np.cross(u, [1.0, 0.0, 0.0])
    rng = np.random.default_rng(0)
    P = 1e9 * w / np.linalg.norm(w) + rng.random((200, 3))
    Q = np.vstack([P, P[:20] + rng.normal(size=(20, 3)) * 2e-9])
    got = near_pairs(Q, 1e-8)
    assert np.array_equal(got, _kd_pairs(Q, 1e-8)) and len(got) == 20
