"""The weights refit to a network's stored positions (selfsupport/methods/weight_refit.py)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse.linalg as spla

import selfsupport.methods.staggered.run as staggered_module  # (where the solve calls refit_weights)
from formulations.equilibrium import Topology, load_vector, position_blocks
from selfsupport.core.loads import SelfWeight
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import make_shape
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.methods.weight_refit import refit_weights

from .conftest import independent_check


def _moved(net, offset):
    return dataclasses.replace(net, mesh=net.mesh.with_vertices(net.vertices + offset))


def _with_weights_at_bound(net, eps: float, count: int = 6):
    """``net`` with its ``count`` smallest active weights set to ``eps`` and its free vertices
    placed for those weights by the force-density method (supports and stored loads kept):
    ``K_ff X_f = b − K_fs X_s`` per coordinate, so it is in equilibrium with weights at the
    bound by construction, whatever the solve's own weights were."""
    a = net.active_edges
    w = net.weights.copy()
    lowest = np.flatnonzero(a)[np.argsort(w[a], kind="stable")[:count]]
    w[lowest] = eps
    top = Topology.build(len(net.vertices), net.edges[a], net.supports)
    K_ff, K_fs = position_blocks(top, w[a])
    b = load_vector(top, net.loads).reshape(-1, 3)
    V = net.vertices.copy()
    solve = spla.factorized(K_ff.tocsc())
    for c in range(3):
        V[top.free, c] = solve(b[:, c] - K_fs @ V[~top.free, c])
    return dataclasses.replace(net, mesh=net.mesh.with_vertices(V), weights=w)


def test_a_network_written_far_from_the_origin_is_balanced_again_by_its_weights_alone():
    """A dome in equilibrium with six weights at the lower bound, written 10⁸ m away, is out of
    equilibrium by the rounding of its positions (spacing of doubles 1.5e-8 m); its weights,
    refit to those positions, balance it to 1e-12 again, checked by the independent checker.
    Positions and loads stay bit for bit, every weight moves by the size of that rounding (under
    10³ spacings of doubles at the site over the shortest edge: the least change spreads a
    rounding residual over a vertex's edges, amplified by the framework's conditioning, ~10² on
    this dome), and a weight at the lower bound stays there."""
    res = StaggeredLinearization().solve(make_shape("dome", n_vertices=300))
    eps = res.parameters["eps"]
    net = _with_weights_at_bound(res.network, eps)
    assert net.max_relative_error() < 1e-12
    for offset in ([1e7, 0.5e7, 0.0], [1e8, -3e7, 10.0]):
        far = _moved(net, offset)
        assert far.max_relative_error() > 1e-8 and not independent_check(far, tol=1e-9).ok
        fit = refit_weights(far, 1e-9, lower=eps)
        assert fit is not None and fit.max_relative_error() < 1e-12
        assert independent_check(fit, tol=1e-9).ok
        assert np.array_equal(fit.vertices, far.vertices) and np.array_equal(fit.loads, far.loads)
        a = far.active_edges
        e = far.edges
        rounding = np.spacing(np.abs(far.vertices).max()) / np.linalg.norm(far.vertices[e[:, 1]] - far.vertices[e[:, 0]], axis=1).min()
        assert np.abs(fit.weights[a] / far.weights[a] - 1).max() < 1e3 * rounding
        at_bound = a & (far.weights <= eps)
        assert at_bound.sum() == 6 and np.array_equal(fit.weights[at_bound], far.weights[at_bound])
        assert np.all(fit.weights[~a] == 0.0)


def test_what_the_free_edges_flexes_hold_is_not_absorbed():
    """A pillar vault 10⁷ m from the origin: the rounding residual at its free edges lies largely
    along the framework's flexes, which no weights reach; the refit does not reach equilibrium
    and returns nothing rather than a network it did not balance."""
    scene, loads = make_shape("pillar_vault", n_vertices=600), SelfWeight(density=2000, thickness=0.1)
    res = StaggeredLinearization().solve(scene, loads)
    far = _moved(res.network, [1e7, 3e6, 0.0])
    assert far.max_relative_error() > 1e-7
    assert refit_weights(far, 1e-9, lower=res.parameters["eps"]) is None


@pytest.fixture(scope="module")
def vault_on_site():
    scene, loads = make_shape("pillar_vault", n_vertices=600), SelfWeight(density=2000, thickness=0.1)
    shift = np.array([5e5, 1.5e5, 0.0])
    far = Scene(mesh=scene.mesh.with_vertices(scene.mesh.vertices + shift), supports=scene.supports, name="site")
    return StaggeredLinearization().solve(scene, loads), far, loads, shift


def test_a_solve_held_at_its_round_off_floor_converges_by_the_refit(vault_on_site, monkeypatch):
    """The same vault 5·10⁵ m from the origin: its final polish is held above tol by rounding
    (1.35e-8 measured, over FLOOR_CAP); the weights refit to the stored positions put it in
    equilibrium, so the solve converges, its positions those of the solve at the origin, moved.
    Without the refit the same solve stops "stalled" at its floor."""
    at, far, loads, shift = vault_on_site
    res = StaggeredLinearization().solve(far, loads)
    refit = [h for h in res.history if h.get("iteration") == "weight refit"]
    assert res.status == "converged" and res.iterations == at.iterations
    assert len(refit) == 1 and refit[0]["applied"] and refit[0]["max_rel_error_before"] > 1e-8
    assert res.network.in_equilibrium(1e-9) and res.max_relative_error < 1e-8
    assert independent_check(res.network, tol=1e-8).ok
    assert np.abs(res.network.vertices - shift - at.network.vertices).max() <= 1e-8
    assert res.network.min_weight() >= res.parameters["eps"]
    monkeypatch.setattr(staggered_module, "refit_weights", lambda *a, **k: None)
    held = StaggeredLinearization().solve(far, loads)
    assert held.status == "stalled" and held.max_relative_error > 1e-8
    assert "roundoff_limit" in held.parameters
