"""The polish's Newton: the coloured finite-difference load Jacobian against the plain one."""
from __future__ import annotations

import numpy as np
import pytest

from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.methods.polish import load_colouring, load_jacobian


@pytest.mark.parametrize("shape", ["pillar_vault", "concave_disk", "dome"])
def test_colouring_is_valid_and_small(shape):
    scene = make_shape(shape, n_vertices=400)
    free = np.ones(scene.mesh.n_vertices, bool)
    free[scene.supports] = False
    rows, cols, colour, k = load_colouring(scene.mesh, free)
    # no two columns of one colour share a row: every (row, colour) pair occurs once
    key = rows * k + colour[cols]
    assert len(np.unique(key)) == len(key)
    # far fewer load evaluations than columns (a mesh's face neighbourhoods are small)
    assert k <= 40 < free.sum()


@pytest.mark.parametrize("shape", ["pillar_vault", "dome"])
def test_coloured_jacobian_equals_column_by_column_differences(shape):
    """Each load depends only on heights of vertices sharing a face with it, so perturbing a
    colour class at once must give the same Jacobian as perturbing one column at a time —
    including every entry outside the pattern being zero."""
    scene = make_shape(shape, n_vertices=150)
    mesh = scene.mesh
    free = np.ones(mesh.n_vertices, bool)
    free[scene.supports] = False
    loads = SelfWeight(density=2000, thickness=0.1)
    X = mesh.vertices.copy()

    def loads_at(z):
        X[free, 2] = z
        return loads.nodal(mesh, X)[free] / 1e4

    z = mesh.vertices[free, 2].copy()
    Lz = loads_at(z)
    rows, cols, colour, k = load_colouring(mesh, free)
    J = load_jacobian(loads_at, z, Lz, rows, cols, colour, k).toarray()
    h = 1e-7 * max(float(np.abs(z).max()), 1.0)
    dense = np.empty_like(J)
    for j in range(z.size):
        e = np.zeros_like(z)
        e[j] = h
        dense[:, j] = (loads_at(z + e) - Lz) / h
    scale = np.abs(dense).max()
    np.testing.assert_allclose(J, dense, atol=1e-9 * scale, rtol=0)
    assert np.abs(J).max() > 0


def test_polish_with_loads_independent_of_the_geometry_is_one_linear_solve():
    """Fixed point loads: J = 0, so the Newton step is the exact stress-Laplacian solve and
    the polish ends after it (a second round only confirms); the result is in equilibrium."""
    from formulations import Problem
    from formulations.equilibrium import load_vector, weight_matrix
    from selfsupport.core.loads import PointLoad
    from selfsupport.methods.polish import polish
    from selfsupport.methods.staggered import StaggeredLinearization

    scene = make_shape("pillar_vault", n_vertices=200)
    res = StaggeredLinearization().solve(scene, SelfWeight())
    net = res.network
    loads = PointLoad(np.asarray(net.loads))
    prob = Problem.build(scene).scaled(np.asarray(net.loads))
    top, sc = prob.top, prob.scaling
    X = sc.pos(np.asarray(net.vertices))
    X[top.free] += 1e-2 * np.random.default_rng(0).standard_normal((top.n_free, 3))
    w = sc.weight(np.asarray(net.weights)[scene.active_edges])
    ws: dict = {}
    Xp, L, rounds = polish(top, X, w, loads, scene.mesh, sc, workspace=ws)
    assert rounds <= 2 and "colouring" not in ws
    r = np.linalg.norm((weight_matrix(top, Xp) @ w - load_vector(top, L)).reshape(-1, 3), axis=1)
    assert (r / np.abs(L[top.free])).max() <= 1e-12


def test_colourings_are_remembered_per_topology_and_free_set():
    """A re-solve of the same topology reuses the colouring (read-only); another free set or
    another face structure gets its own, valid one."""
    scene = make_shape("dome", n_vertices=120)
    free = ~scene.supports
    a = load_colouring(scene.mesh, free)
    assert load_colouring(scene.mesh.with_vertices(scene.mesh.vertices * 2.0), free.copy()) is a
    assert not a[2].flags.writeable
    free2 = free.copy()
    free2[np.flatnonzero(free)[0]] = False
    rows, cols, colour, k = b = load_colouring(scene.mesh, free2)
    assert b is not a and len(colour) == free2.sum()
    for c in range(k):  # no two columns of one colour share a row
        r = rows[colour[cols] == c]
        assert len(r) == len(np.unique(r))


def test_the_joint_polish_holds_the_hull_for_vertices_it_would_carry_out():
    """From a dome with uniform weights (not in equilibrium), the joint polish (positions and
    free weights) reaches equilibrium without carrying any vertex past the hull's slab: every
    vertex ends within ±h, although without the hull the polish takes some out."""
    from formulations import Hull, Problem, TermContext, ThrustNetworkProblem, WeightBounds
    from formulations.terms import TERMS
    from selfsupport.methods.polish import max_rel_error, polish_joint

    scene = make_shape("dome", n_vertices=100)
    prob = Problem.build(scene, SelfWeight(), constraints=[Hull(0.05)])
    sp_ = prob.scaled()
    ctx = TermContext(vertices=sp_.X, reference=scene.mesh.with_vertices(sp_.X), free=scene.free,
                      thickness=prob.hull_thickness() / sp_.scaling.length)
    hull = TERMS["hull"].build(ctx)
    W0 = np.full((1, sp_.top.m), float(np.median(sp_.L[0][scene.free])) * -3.0)

    def loads_at(X):
        return sp_.scaling.load(prob.loads.nodal(scene.mesh, sp_.scaling.pos_back(X)))

    def run(with_hull, **kw):
        form = ThrustNetworkProblem(sp_.top, sp_.X, sp_.L, WeightBounds(sp_.lower, sp_.upper),
                                    hull=hull if with_hull else None)
        return polish_joint(form, sp_.X, W0, loads_at=loads_at)

    Vf, _, _, err_free, _ = run(False)
    assert err_free <= 1e-8 and np.abs(hull.signed_distance(Vf)).max() > 1.5 * hull.half_thickness  # it would leave
    Vh, _, _, err, _ = run(True)
    assert err <= 1e-8
    # and no step carries a vertex out to be put back by the next one: one step stays inside
    form = ThrustNetworkProblem(sp_.top, sp_.X, sp_.L, WeightBounds(sp_.lower, sp_.upper), hull=hull)
    V1, _, k, err1, _ = polish_joint(form, sp_.X, W0, loads_at=loads_at, max_iter=1)
    assert k == 1 and err1 < max_rel_error(sp_.top, sp_.X, W0, loads_at(sp_.X))  # a step was taken
    assert np.abs(hull.signed_distance(Vh)).max() <= hull.half_thickness * (1 + 1e-9)
    assert np.abs(hull.signed_distance(V1)).max() <= hull.half_thickness * (1 + 1e-9)


def test_the_joint_polish_does_not_stop_while_each_step_still_gains_a_tenth():
    """Without the load Jacobian (loads lag one step) the polish converges linearly, an order of
    magnitude per step on a dome from uniform weights. Such a run passes 1e3 × tol while still
    gaining that order per step: it must go on to tol, not take the first iterate near it for a
    round-off floor (which stops only a step that gains less than a tenth)."""
    from formulations import Problem, ThrustNetworkProblem, WeightBounds
    from selfsupport.methods.polish import polish_joint

    scene = make_shape("dome", n_vertices=100)
    prob = Problem.build(scene, SelfWeight())
    sp_ = prob.scaled()
    W0 = np.full((1, sp_.top.m), float(np.median(sp_.L[0][scene.free])) * -3.0)

    def loads_at(X):
        return sp_.scaling.load(prob.loads.nodal(scene.mesh, sp_.scaling.pos_back(X)))

    form = ThrustNetworkProblem(sp_.top, sp_.X, sp_.L, WeightBounds(sp_.lower, sp_.upper))
    errs = [polish_joint(form, sp_.X, W0, loads_at=loads_at, tol=1e-9, max_iter=k)[3] for k in range(4, 8)]
    assert all(b < 0.2 * a for a, b in zip(errs, errs[1:]))  # linear, more than a tenth per step
    assert errs[1] < 1e3 * 1e-9 < errs[0]  # within 1e3 x tol only after the fifth step
    _, _, k, err, ok = polish_joint(form, sp_.X, W0, loads_at=loads_at, tol=1e-9, max_iter=30)
    assert ok and err <= 1e-9 and k > 5
