"""Built-in reference shapes: valid, oriented, supported, sized as asked, and shaped as promised."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from selfsupport.core.errors import InputError
from selfsupport.core.geometry import face_areas, face_normals
from selfsupport.core.shapes import (
    SHAPES,
    barrel_vault,
    concave_disk,
    cross_vault,
    disk,
    disk_points,
    dome,
    make_shape,
    meridian_dome,
    pillar_vault,
)

NAMES = sorted(SHAPES)


def _turns(loop_xy: np.ndarray) -> np.ndarray:
    """2D cross product of consecutive edges at every vertex of a closed polygon, signed so
    that positive means a convex turn (same sense as the loop's orientation)."""
    prev_e = loop_xy - np.roll(loop_xy, 1, axis=0)
    next_e = np.roll(loop_xy, -1, axis=0) - loop_xy
    cross = prev_e[:, 0] * next_e[:, 1] - prev_e[:, 1] * next_e[:, 0]
    x, y = loop_xy[:, 0], loop_xy[:, 1]
    orientation = np.sign(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return orientation * cross


def _triangle_angles(vertices: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """``(t, 3)``: the angle at each corner of each triangle."""
    p = vertices[tris]
    out = np.empty(tris.shape)
    for c in range(3):
        a = p[:, (c + 1) % 3] - p[:, c]
        b = p[:, (c + 2) % 3] - p[:, c]
        cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        out[:, c] = np.arccos(np.clip(cos, -1.0, 1.0))
    return out


# ---------------------------------------------------------------------------- every shape
@pytest.mark.parametrize("name", NAMES)
def test_shape_is_a_valid_supported_upward_mesh(name):
    scene = SHAPES[name]()
    mesh = scene.mesh
    assert mesh.problems() == []
    assert scene.supports.any() and scene.free.any()
    scene.check_supports()
    assert np.all(face_normals(mesh)[:, 2] > 0), "faces must run counter-clockwise seen from above"
    assert np.all(face_areas(mesh) > 1e-8 * face_areas(mesh).max()), "degenerate face"
    assert name in scene.name
    # one piece with one outer boundary; supports on it (pillar feet are patches around it)
    assert len(mesh.boundary_loops) == 1
    if name != "pillar_vault":
        assert np.all(mesh.boundary_vertex_mask[scene.supports])


@pytest.mark.parametrize("name", NAMES)
def test_shape_is_deterministic(name):
    a, b = SHAPES[name](), SHAPES[name]()
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.mesh.face_vertices, b.mesh.face_vertices)
    np.testing.assert_array_equal(a.supports, b.supports)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("target", [1000, 16000])
def test_make_shape_hits_the_vertex_count(name, target):
    scene = make_shape(name, n_vertices=target)
    assert abs(scene.mesh.n_vertices - target) <= 0.15 * target
    assert scene.mesh.problems() == []
    assert np.all(face_normals(scene.mesh)[:, 2] > 0)
    scene.check_supports()


def test_make_shape_64k_is_fast_and_sized():
    t0 = time.perf_counter()
    scene = make_shape("dome", n_vertices=64000)
    elapsed = time.perf_counter() - t0
    assert abs(scene.mesh.n_vertices - 64000) <= 0.15 * 64000
    assert elapsed < 1.0
    assert scene.mesh.problems() == []


def test_make_shape_passes_keywords_and_rejects_bad_requests():
    s = make_shape("barrel_vault", n_vertices=2000, quads=False, length=20.0)
    assert s.mesh.is_triangular and abs(s.mesh.n_vertices - 2000) <= 300
    assert np.ptp(s.mesh.vertices[:, 1]) == pytest.approx(20.0)
    with pytest.raises(InputError, match="known shapes: .*dome"):
        make_shape("cathedral")
    with pytest.raises(InputError, match="rings"):
        make_shape("dome", n_vertices=1000, rings=5)
    with pytest.raises(InputError, match="bad parameters"):
        make_shape("dome", radius=5.0, wingspan=3.0)


@pytest.mark.parametrize("call", [
    lambda: dome(height=6.0, radius=5.0),          # overhanging cap
    lambda: dome(rings=0),
    lambda: disk(radius=-1.0),
    lambda: cross_vault(n=31),                     # groins would miss the mesh edges
    lambda: concave_disk(dent=0.01),               # too shallow to make a dip
    lambda: pillar_vault(n=2),
    lambda: concave_disk(rings=2),
    lambda: barrel_vault(span=float("nan")),
])
def test_bad_parameters_raise_input_error(call):
    with pytest.raises(InputError):
        call()


# ---------------------------------------------------------------------------- shape-specific
def test_disk_is_the_delaunay_triangulation_of_disk_points():
    n, R = 12, 2.0
    scene = disk(n_rings=n, radius=R, z=0.3)
    v = scene.mesh.vertices
    np.testing.assert_allclose(v[:, :2], disk_points(n, R), atol=1e-12)
    assert np.all(v[:, 2] == 0.3)
    assert scene.supports.sum() == 6 * n
    np.testing.assert_allclose(np.linalg.norm(v[scene.supports, :2], axis=1), R)
    tris = scene.mesh.face_vertices.reshape(-1, 3)
    ang = _triangle_angles(v, tris)
    assert ang.max() < math.pi / 2, "every triangle is acute"
    # opposite angles of every interior edge sum to at most pi (local Delaunay), so the
    # Voronoi-dual/primal weights of the paper's section 2.5 are non-negative
    m = scene.mesh
    he_edge = m.halfedge_data["halfedge_edge"]
    # the angle opposite a half-edge (corner c -> c+1) is at corner c+2
    opposite = ang[:, [2, 0, 1]].ravel()
    sums = np.bincount(he_edge, weights=opposite, minlength=m.n_edges)
    assert sums.max() <= math.pi + 1e-9
    # quasi-uniform spacing h ~ R / n
    e = m.edges
    lengths = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    assert 0.7 * R / n < lengths.min() and lengths.max() < 1.6 * R / n


def test_dome_area_matches_the_spherical_cap():
    scene = dome(rings=40, radius=5.0, height=2.5)
    R = (5.0 ** 2 + 2.5 ** 2) / (2 * 2.5)
    exact = 2 * math.pi * R * 2.5
    assert scene.meta["area"] == pytest.approx(exact)
    area = face_areas(scene.mesh).sum()
    assert abs(area - exact) < 0.02 * exact and area < exact        # inscribed: slightly less
    coarse = face_areas(dome(rings=10).mesh).sum()
    assert exact - coarse > 4 * (exact - area)                        # second-order convergence
    v = scene.mesh.vertices
    assert v[:, 2].max() == pytest.approx(2.5)
    np.testing.assert_allclose(v[scene.supports, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(v[scene.supports, :2], axis=1), 5.0)


@pytest.mark.parametrize("height", [2.5, 5.0])
def test_meridian_dome_edges_run_along_meridians_and_hoops(height):
    scene = meridian_dome(6, 12, radius=5.0, height=height)
    mesh, v = scene.mesh, scene.mesh.vertices
    assert mesh.problems() == [] and len(mesh.boundary_loops) == 1 and mesh.n_vertices == 1 + 6 * 12
    assert np.all(face_normals(mesh)[:, 2] > 0) and np.all(mesh.boundary_vertex_mask[scene.supports])
    R = (5.0 ** 2 + height ** 2) / (2 * height)
    np.testing.assert_allclose(np.linalg.norm(v - [0, 0, height - R], axis=1), R, rtol=1e-12)
    a, b = v[mesh.edges[:, 0]], v[mesh.edges[:, 1]]
    hoop = np.isclose(a[:, 2], b[:, 2], atol=1e-12)
    meridian = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) < 1e-9      # in one vertical plane through the axis
    assert np.all(hoop ^ meridian) and hoop.sum() == 6 * 12 and meridian.sum() == 6 * 12
    assert np.all(~scene.supports[1:-12]) and v[scene.supports, 2].max() == 0.0


@pytest.mark.parametrize("rings", [3, 5, 18, 73])
def test_concave_disk_centre_is_a_dip(rings):
    scene = concave_disk(rings=rings)
    mesh = scene.mesh
    c = scene.meta["centre_vertex"]
    assert not scene.supports[c]
    z = mesh.vertices[:, 2]
    nb = mesh.vertex_neighbors[c]
    assert len(nb) >= 3 and np.all(z[nb] > z[c])
    np.testing.assert_allclose(z[scene.supports], 0.0)


def test_concave_disk_is_not_axisymmetric():
    scene = concave_disk(rings=12)
    v = scene.mesh.vertices
    r = np.round(np.linalg.norm(v[:, :2], axis=1), 9)
    ring = v[r == np.unique(r)[6]]
    assert np.ptp(ring[:, 2]) > 0.05


@pytest.mark.parametrize("n", [4, 12, 32])
def test_pillar_vault_free_boundary_is_concave_in_plan(n):
    scene = pillar_vault(n=n)
    mesh = scene.mesh
    (loop,) = mesh.boundary_loops
    turns = _turns(mesh.vertices[loop, :2])
    free = ~scene.supports[loop]
    assert free.sum() >= 4
    scale = np.ptp(mesh.vertices[:, 0]) ** 2
    assert np.all(turns[free] < -1e-9 * scale), "every free boundary vertex must turn inward"
    # the convex turns are the four plan corners, all supported
    assert np.sum(turns > 0) == 4 and np.all(scene.supports[loop[turns > 0]])


def test_pillar_vault_stands_on_four_corner_patches():
    span = 8.0
    scene = pillar_vault(n=40, span=span, pillar_radius_frac=0.1)
    v = scene.mesh.vertices
    corners = np.array([[-4, -4], [4, -4], [4, 4], [-4, 4.0]])
    d = np.linalg.norm(v[:, None, :2] - corners[None], axis=2)
    nearest = d.argmin(axis=1)
    sup = scene.supports
    assert np.all(d.min(axis=1)[sup] <= 0.1 * span + 1e-12)
    assert np.all(np.bincount(nearest[sup], minlength=4) >= 3)
    # the free edges are arches: clear of the ground between the pillars
    bnd_free = scene.mesh.boundary_vertex_mask & ~sup
    assert v[bnd_free, 2].min() > 0.0
    assert v[bnd_free, 2].max() > 0.5 * 2.0


def test_barrel_vault_quads_and_supports():
    nx, ny = 10, 14
    quads = barrel_vault(nx=nx, ny=ny, quads=True)
    assert np.all(quads.mesh.face_sizes == 4)
    assert quads.mesh.n_vertices == (nx + 1) * (ny + 1) and quads.mesh.n_faces == nx * ny
    # default: all boundary supported (straight free gables could not stand)
    np.testing.assert_array_equal(quads.supports, quads.mesh.boundary_vertex_mask)
    tris = barrel_vault(nx=nx, ny=ny, quads=False)
    assert tris.mesh.is_triangular and tris.mesh.n_faces == 2 * nx * ny
    np.testing.assert_array_equal(tris.mesh.vertices, quads.mesh.vertices)
    springing = barrel_vault(nx=nx, ny=ny, gables_supported=False)
    v = springing.mesh.vertices
    np.testing.assert_array_equal(springing.supports, np.isclose(np.abs(v[:, 0]), 3.0))
    springing.check_supports()
    # catenary profile of the requested rise, with near-uniform spacing along the arch
    assert v[:, 2].max() == pytest.approx(2.0)
    row = v[:nx + 1]
    seg = np.linalg.norm(np.diff(row[:, [0, 2]], axis=0), axis=1)
    assert np.ptp(seg) < 0.02 * seg.mean()


def test_cross_vault_groins_lie_on_mesh_edges():
    n = 16
    scene = cross_vault(n=n, span=6.0, rise=2.5)
    v = scene.mesh.vertices
    assert v[:, 2].max() == pytest.approx(2.5)
    np.testing.assert_array_equal(scene.supports, scene.mesh.boundary_vertex_mask)
    diag = np.flatnonzero(np.isclose(np.abs(v[:, 0]), np.abs(v[:, 1])))
    assert len(diag) == 2 * n + 1
    on_diag = np.zeros(len(v), dtype=bool)
    on_diag[diag] = True
    e = scene.mesh.edges
    groin_edges = e[on_diag[e[:, 0]] & on_diag[e[:, 1]]]
    assert len(groin_edges) == 2 * n                      # both diagonals are edge chains
    # the groins are valleys: off the diagonal, perpendicular to it, the surface rises
    i = np.arange(1, n // 2)                              # grid points (s_i, s_i) inside (+,+)
    at = lambda a, b: v[b * (n + 1) + a, 2]              # z at grid indices (column a, row b)
    k = n // 2 + i
    assert np.all(at(k + 1, k - 1) > at(k, k)) and np.all(at(k - 1, k + 1) > at(k, k))
    # and the boundary arches peak at full rise mid-side
    mid_side = v[np.isclose(v[:, 0], 3.0) & np.isclose(v[:, 1], 0.0)]
    assert mid_side[0, 2] == pytest.approx(2.5)
