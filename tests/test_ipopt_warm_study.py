"""The IPOPT warm-start study's own pieces (studies/ipopt_warm.py). No paper scene is run."""
from __future__ import annotations

import pytest

from selfsupport.core.defaults import DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.geometry import face_areas
from selfsupport.core.loads import G
from selfsupport.core.shapes import make_shape
from studies.ipopt_warm import highest_free_load


def test_the_edit_is_its_share_of_the_whole_self_weight_at_the_highest_free_vertex():
    """The point load is ``share`` × ρ t g × the surface's area (the nodal self-weights sum to the
    load of the whole surface), at the free vertex of greatest height."""
    scene = make_shape("pillar_vault", n_vertices=200)
    load = highest_free_load(scene, 0.02)
    (v, p), = load.items()
    V = scene.mesh.vertices
    assert scene.free[v] and V[v, 2] == V[scene.free, 2].max()
    assert p == pytest.approx(0.02 * DEFAULT_DENSITY * DEFAULT_THICKNESS * G * face_areas(scene.mesh).sum(), rel=1e-12)
