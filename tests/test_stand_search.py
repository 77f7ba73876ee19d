"""The stand-search study's own pieces (studies/stand_search.py): the quad weights of a
triangulated network and the perturbed starts. No paper scene is run."""
from __future__ import annotations

import numpy as np
import pytest

from selfsupport import api
from selfsupport.core.evidence import residuals, stress_sums
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.shapes import make_shape
from selfsupport.core.triangulation import split_faces
from studies.common import vault_pillar_layout
from studies.stand_search import perturbed_heights, quad_weights, write_control


def _split(mesh: PolyMesh) -> tuple[PolyMesh, np.ndarray]:
    """The split mesh and the mask of its diagonals (the edges the quad mesh does not have)."""
    tri = split_faces(mesh)
    quad = {tuple(sorted(e)) for e in mesh.edges.tolist()}
    return tri, np.array([tuple(sorted(e)) not in quad for e in tri.edges.tolist()])


def test_dropping_zero_diagonals_keeps_every_vertex_force_balance_of_the_split_network():
    sup, quads = vault_pillar_layout(6)
    n = 6
    g = np.arange(n)
    X, Y = np.meshgrid(g, g)
    V = np.c_[X.ravel(), Y.ravel(), 0.3 * np.sin(np.pi * X.ravel() / 5) * np.sin(np.pi * Y.ravel() / 5)]
    mesh = PolyMesh.from_faces(V, quads)
    tri, diag = _split(mesh)
    assert diag.sum() == mesh.n_faces and tri.n_edges == mesh.n_edges + mesh.n_faces
    rng = np.random.default_rng(3)
    W = rng.uniform(0.5, 2.0, (2, tri.n_edges))  # two load cases' weights
    W[:, diag] = 0.0
    loads = -rng.uniform(1.0, 2.0, len(V))
    Wq = quad_weights(tri.edges, W, mesh.edges)
    assert Wq.shape == (2, mesh.n_edges)
    for c in range(2):
        split = residuals(vertices=V, edges=tri.edges, weights=W[c], loads=loads)
        kept = residuals(vertices=V, edges=mesh.edges, weights=Wq[c], loads=loads)
        assert np.abs(kept - split).max() <= 1e-13 * np.abs(split).max()
        # every weight is the one of its own pair
        on = {tuple(sorted(e)): w for e, w in zip(tri.edges.tolist(), W[c])}
        assert np.array_equal(Wq[c], [on[tuple(sorted(e))] for e in mesh.edges.tolist()])


def test_dropping_loaded_diagonals_removes_exactly_their_forces():
    mesh = make_shape("barrel_vault", nx=5, ny=4).mesh
    tri, diag = _split(mesh)
    w = np.random.default_rng(1).uniform(0.5, 2.0, tri.n_edges)
    V = mesh.vertices
    split = stress_sums(edges=tri.edges, weights=w, values=V)
    kept = stress_sums(edges=mesh.edges, weights=quad_weights(tri.edges, w, mesh.edges), values=V)
    diagonals = stress_sums(edges=tri.edges[diag], weights=w[diag], values=V)
    assert np.abs(diagonals[:, :2]).max() > 1e-3  # (the diagonals pull horizontally: dropping them matters)
    assert np.allclose(split - kept, diagonals, rtol=0, atol=1e-12 * np.abs(split).max())


def test_an_edge_missing_from_the_split_mesh_is_refused():
    mesh = make_shape("barrel_vault", nx=4, ny=3).mesh
    tri = split_faces(mesh)
    with pytest.raises(ValueError, match="not edges of the split mesh"):
        quad_weights(tri.edges[1:], np.ones(tri.n_edges - 1), mesh.edges)


def test_perturbed_heights_move_only_the_free_heights_by_the_amplitude_and_repeat_by_seed():
    scene = make_shape("barrel_vault", nx=8, ny=6)
    V, free = scene.mesh.vertices, scene.free
    P = perturbed_heights(V, free, 0.05, seed=2)
    assert np.array_equal(P[:, :2], V[:, :2]) and np.array_equal(P[~free], V[~free])
    assert np.isclose(np.abs(P[free, 2] - V[free, 2]).max(), 0.05, rtol=1e-12)
    assert np.array_equal(P, perturbed_heights(V, free, 0.05, seed=2))
    assert not np.allclose(P, perturbed_heights(V, free, 0.05, seed=3))


def test_the_control_is_the_free_edged_quad_vault_with_as_many_edges_as_horizontal_equations(tmp_path):
    scene = api.as_scene(str(write_control(tmp_path)))
    assert scene.mesh.n_vertices == 100 and np.count_nonzero(scene.free) == 84
    assert np.count_nonzero(scene.active_edges) == 2 * 84 == 168
    sup, _ = vault_pillar_layout(10)
    assert np.array_equal(scene.supports, sup)
