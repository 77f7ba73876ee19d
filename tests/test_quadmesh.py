"""The seamless (integer-grid, MIQ-style) quad remesh on analytic cases: the frame/cross
decomposition, a flat rectangle along the axes (the exact grid), a disk along circles and radii
(one +1 of index in the field: its quarter-turn singularities are the mesh's valence-3 vertices),
and the default remesh of a generated dome (quads, manifold, covering the top view)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from selfsupport import api
from selfsupport.core.evidence import triangulate
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import make_shape
from selfsupport.remesh.param import frame_parametrization
from selfsupport.remesh.quadmesh import cross_indices, cross_to_frame, frame_to_cross, smooth_frames
from selfsupport.remesh.streamlines import remesh


def _lines_equal(F: np.ndarray, G: np.ndarray) -> bool:
    """Whether each frame of ``F`` spans the same two lines as the one of ``G`` (any order, signs)."""
    same = np.abs(np.einsum("kij,kil->kjl", F, G))  # |cos| between every pair of columns
    direct = np.minimum(same[:, 0, 0], same[:, 1, 1])
    swapped = np.minimum(same[:, 0, 1], same[:, 1, 0])
    return bool(np.all(np.maximum(direct, swapped) > 1 - 1e-12))


def _flat_scene(xy: np.ndarray) -> Scene:
    """A flat triangulated top view (Delaunay of ``xy``), its boundary supported."""
    m = PolyMesh.from_faces(np.c_[xy, np.zeros(len(xy))], Delaunay(xy).simplices.tolist())
    return Scene(mesh=m, supports=m.boundary_vertex_mask, name="flat")


def _area(mesh: PolyMesh) -> float:
    """Top-view area of a polygon mesh (shoelace per face)."""
    out = 0.0
    for f in mesh.faces:
        P = mesh.vertices[list(f), :2]
        out += 0.5 * abs(np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1]))
    return out


def test_a_frame_is_its_cross_times_a_symmetric_stretch():
    rng = np.random.default_rng(1)
    a1 = rng.uniform(-np.pi, np.pi, 50)
    a2 = a1 + rng.uniform(np.radians(25), np.radians(155), 50)
    F = np.stack([np.c_[np.cos(a1), np.sin(a1)], np.c_[np.cos(a2), np.sin(a2)]], axis=2)
    z, S = frame_to_cross(F)
    assert np.allclose(np.abs(z), 1.0) and np.allclose(S, np.transpose(S, (0, 2, 1)))
    assert np.all(np.linalg.eigvalsh(S) > 0)
    assert _lines_equal(cross_to_frame(z, S), F)
    # relabelling the frame (its lines swapped, a sign flipped) changes neither the cross nor the stretch
    z2, S2 = frame_to_cross(np.stack([F[:, :, 1], -F[:, :, 0]], axis=2))
    assert np.allclose(z2, z) and np.allclose(S2, S)
    # an orthogonal frame is a cross: no stretch
    O = np.stack([F[:, :, 0], np.c_[-F[:, 1, 0], F[:, 0, 0]]], axis=2)
    assert np.allclose(frame_to_cross(O)[1], np.eye(2))


def test_a_flat_rectangle_along_the_axes_is_the_exact_grid():
    rng = np.random.default_rng(0)
    W, H, h = 1.0, 0.6, 0.1
    gx, gy = np.meshgrid(np.linspace(0, W, 15), np.linspace(0, H, 10))
    xy = np.c_[gx.ravel(), gy.ravel()]
    inner = (xy[:, 0] > 0) & (xy[:, 0] < W) & (xy[:, 1] > 0) & (xy[:, 1] < H)
    xy[inner] += 0.01 * rng.standard_normal((inner.sum(), 2))  # an irregular triangulation inside
    scene = _flat_scene(xy)
    q = remesh(scene, spacing=h, field="grid", angle=0.0, method="seamless")
    m = q.scene.mesh
    assert m.is_valid() and q.face_size_counts == {4: 60} and q.irregular_vertices == 0
    grid = np.stack(np.meshgrid(np.arange(11) * h, np.arange(7) * h), axis=-1).reshape(-1, 2)
    V = m.vertices[:, :2]
    assert len(V) == len(grid)
    assert np.abs(np.sort(V[:, 0] + 10 * V[:, 1]) - np.sort(grid[:, 0] + 10 * grid[:, 1])).max() < 1e-6 * h
    assert np.abs(V / h - np.round(V / h)).max() < 1e-6  # (the solve's round-off) every vertex on the grid, every face a cell
    assert _area(m) == pytest.approx(W * H, rel=1e-12)


def _disk(n_rings: int = 12) -> np.ndarray:
    pts = [np.zeros((1, 2))]
    for k in range(1, n_rings + 1):
        r = k / n_rings
        t = np.linspace(0, 2 * np.pi, 6 * k, endpoint=False) + 0.3 * k
        pts.append(r * np.c_[np.cos(t), np.sin(t)])
    return np.vstack(pts)


def test_a_disk_along_circles_and_radii_gives_quads_whose_irregular_vertices_are_the_fields_singularities():
    xy = _disk()
    scene = _flat_scene(xy)
    ang = np.arctan2(xy[:, 1], xy[:, 0])
    D = np.stack([np.c_[np.cos(ang), np.sin(ang)], np.c_[-np.sin(ang), np.cos(ang)]], axis=2)  # radial, circular
    D[0] = np.eye(2)  # (the centre: any frame)
    tris = triangulate(scene.mesh)
    c = xy[tris].mean(axis=1)
    a = np.arctan2(c[:, 1], c[:, 0])
    F0 = np.stack([np.c_[np.cos(a), np.sin(a)], np.c_[-np.sin(a), np.cos(a)]], axis=2)
    assert cross_indices(xy, tris, F0).sum() == 1.0  # the data: index +1 at the centre
    idx = cross_indices(xy, tris, smooth_frames(xy, tris, F0, length=0.2))
    assert idx.sum() == 1.0 and np.all(idx[idx != 0] % 0.25 == 0)  # the smooth field: quarter turns of index
    q = remesh(scene, spacing=0.12, directions=D, smoothing=0.1, method="seamless")
    m = q.scene.mesh
    assert m.is_valid() and q.face_size_counts == {4: m.n_faces}
    val = np.bincount(m.edges.ravel(), minlength=m.n_vertices)
    b = m.boundary_vertex_mask
    assert np.all(val[b] == 3)  # the circle is a mesh line: every line ends on it at a right angle
    # one irregular vertex per singularity of the field, of the valence its index asks (index (4 − valence) / 4)
    sing = q.info["singular_indices"]
    assert sum(sing) == 1.0 and len(sing) >= 4
    assert sorted((4 - val[~b & (val != 4)]) / 4) == sorted(sing)
    assert _area(m) == pytest.approx(np.pi, rel=1e-2)


def test_singular_vertices_land_on_integer_points_and_seams_are_integer_jumps():
    xy = _disk(10)
    tris = Delaunay(xy).simplices
    c = xy[tris].mean(axis=1)
    a = np.arctan2(c[:, 1], c[:, 0])
    F = smooth_frames(xy, tris, np.stack([np.c_[np.cos(a), np.sin(a)], np.c_[-np.sin(a), np.cos(a)]], axis=2),
                      length=0.2)
    p = frame_parametrization(xy, tris, None, 0.2, frames=F, integer_singularities=True, batch=4)
    idx = cross_indices(xy, tris, F)
    assert p.rounded and sorted(p.singular) == sorted(np.flatnonzero(idx)) and idx.sum() == 1.0
    for v in p.singular:
        uv = p.uv[tris == v]  # every corner of the singular vertex
        assert np.abs(uv - np.round(uv)).max() < 1e-6
    # across each seam edge, the two sides differ by a quarter-turn-symmetric map and an integer translation
    for e in p.seams:
        ts = [t for t in range(len(tris)) if e[0] in tris[t] and e[1] in tris[t]]
        (ua, ub), (va, vb) = ([p.uv[t][tris[t] == e[0]][0] for t in ts], [p.uv[t][tris[t] == e[1]][0] for t in ts])
        R = np.array([[0.0, -1.0], [1.0, 0.0]])
        found = False
        for k in range(4):
            Rk = np.linalg.matrix_power(R, k)
            T = ub - Rk @ ua
            if np.allclose(vb - Rk @ va, T, atol=1e-6) and np.allclose(T, np.round(T), atol=1e-6):
                found = True
        assert found


def test_the_default_remesh_of_a_dome_is_quads_covering_its_top_view():
    """The regression of the remesh along relative principal directions: the streamline remesh it
    replaces left a triangle at every line's end (on this dome: 32 triangles in 237 faces). The top view's area is lost only in the chords along the curved boundary
    (a boundary line every 0.04 of the diagonal or more, where the radial lines spread)."""
    scene = make_shape("dome", n_vertices=400)
    net = api.solve(scene).network
    q = remesh(net, spacing=0.04, relative=True)
    m = q.scene.mesh
    assert m.is_valid() and q.method == "seamless"
    assert q.face_size_counts.get(4, 0) >= 0.95 * m.n_faces
    assert _area(m) == pytest.approx(_area(net.mesh), rel=1e-2)


def _unit_squares(xy: np.ndarray, tris: np.ndarray, uv: np.ndarray) -> float:
    """How many unit squares of ``(u, v)`` cover the triangles: ``Σ |area of the image triangle|``
    (per-corner ``uv`` ``(m, 3, 2)``; computed here from the corners, not by the package)."""
    a, b = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return float(0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum())


def _turning_frames(xy: np.ndarray, k: float) -> np.ndarray:
    """Per point an orthonormal frame turned by ``k x`` (its lines bend: ``curl d1 = k cos(kx) ≠ 0``,
    so no parametrization has the dual frame over the spacing as its gradient)."""
    th = k * xy[:, 0]
    return np.stack([np.c_[np.cos(th), np.sin(th)], np.c_[-np.sin(th), np.cos(th)]], axis=2)


def test_keep_density_covers_as_many_unit_squares_as_the_target_asks_for():
    """Where the field is not integrable the least squares keeps only the target's gradient part,
    which is shorter: the unrounded parametrization of a turning frame on a square covers clearly
    fewer unit squares than the area over h² (the lines come out farther apart than h). Scaled
    (``keep_density``), it covers exactly as many: the solve is linear in the target."""
    g = np.linspace(0.0, 1.0, 21)
    xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    tris = Delaunay(xy).simplices
    h = 0.1
    D = _turning_frames(xy, 2.5)
    want = 1.0 / h ** 2  # the unit square's area over h² (the frames are orthonormal)
    plain = frame_parametrization(xy, tris, D, h, round_seams=False, align_boundary=False)
    kept = frame_parametrization(xy, tris, D, h, round_seams=False, align_boundary=False, keep_density=True)
    assert _unit_squares(xy, tris, plain.uv) < 0.9 * want and plain.scale == 1.0
    assert _unit_squares(xy, tris, kept.uv) == pytest.approx(want, rel=1e-6)
    assert kept.scale > 1.05
    # an integrable field (constant frame) needs no scaling: the parametrization is already exact
    const = frame_parametrization(xy, tris, _turning_frames(xy, 0.0), h, round_seams=False, align_boundary=False,
                                  keep_density=True)
    assert const.scale == pytest.approx(1.0, abs=1e-9)


def test_the_seamless_remesh_along_a_bending_field_is_as_dense_as_the_grid_remesh():
    """The seamless remesh's density follows its spacing where the field is not integrable: a
    dome remeshed along frames turned by 0.3 x has as many vertices as its grid remesh at the
    same spacing, within a fifth (272 against 240; before the target was scaled: 156)."""
    net = api.solve(make_shape("dome", n_vertices=400)).network
    h = 0.6
    bent = remesh(net, spacing=h, directions=_turning_frames(net.vertices[:, :2], 0.3))
    grid = remesh(net, spacing=h, field="grid")
    assert bent.method == "seamless" and bent.info["density_scale"] > 1.05
    assert bent.scene.mesh.n_vertices == pytest.approx(grid.scene.mesh.n_vertices, rel=0.2)
