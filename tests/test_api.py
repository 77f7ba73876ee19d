"""The convenience layer: ``api.solve`` (scale laws of the result, the method registry) and
``api.check`` (analytic verdicts: a vertex below its neighbours, a flat disk, a network in
equilibrium; invariance under load and length scaling)."""
from __future__ import annotations

import numpy as np
import pytest

from selfsupport import api
from selfsupport.core.errors import BackendUnavailable, InputError, SupportError
from selfsupport.core.loads import G
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import make_shape
from selfsupport.io import write_network
from tests.conftest import relative_residuals


@pytest.fixture(scope="module")
def barrel():
    return make_shape("barrel_vault", n_vertices=300)


@pytest.fixture(scope="module")
def barrel_result(barrel):
    return api.solve(barrel)


# ------------------------------------------------------------------------------ solve
def test_solve_returns_a_network_in_equilibrium(barrel, barrel_result):
    res = barrel_result
    net = res.network
    assert res.status == "converged"
    rel = relative_residuals(net.vertices, net.edges, net.weights, net.loads, net.supports)
    assert rel.max() <= 1e-9 and rel.max() == pytest.approx(res.max_relative_error, rel=1e-6, abs=1e-15)
    assert net.weights[net.active_edges].min() > 0
    assert res.parameters["loads"] == {"type": "self_weight", "density": 2000.0, "thickness": 0.1, "g": G}


def test_doubling_the_density_doubles_the_weights_and_keeps_the_geometry(barrel, barrel_result):
    """Equilibrium is linear in the load and the solver works in scale-free units, so ρ → 2ρ
    must give the same positions and twice the weights."""
    res2 = api.solve(barrel, density=4000.0)
    a, b = barrel_result.network, res2.network
    diag = np.linalg.norm(np.ptp(a.vertices, axis=0))
    assert np.abs(a.vertices - b.vertices).max() <= 1e-9 * diag
    act = a.active_edges
    assert np.allclose(b.weights[act], 2 * a.weights[act], rtol=1e-6)
    assert b.loads.sum() == pytest.approx(2 * a.loads.sum(), rel=1e-12)


def test_solve_accepts_files_and_supports_specs(tmp_path, barrel):
    from selfsupport.io import write_mesh

    p = tmp_path / "b.obj"
    write_mesh(p, barrel.mesh)
    s_file = api.as_scene(p, supports="boundary")
    idx = np.flatnonzero(barrel.mesh.boundary_vertex_mask)
    s_idx = api.as_scene(p, supports=idx)
    assert np.array_equal(s_file.supports, barrel.supports)
    assert np.array_equal(s_idx.supports, barrel.supports)
    assert np.array_equal(api.as_scene(barrel.mesh, supports=barrel.supports).supports, barrel.supports)
    with pytest.raises(InputError, match="supports"):
        api.as_scene(barrel.mesh)
    with pytest.raises(SupportError):
        api.as_scene(p)


def test_method_registry():
    assert set(api.METHODS) >= {"staggered", "ipopt", "nlopt"}
    st = api.make_method("staggered", backend="active-set")
    assert type(st).__name__ == "StaggeredLinearization" and st.backend.name == "active-set"
    with pytest.raises(InputError, match="unknown method"):
        api.make_method("simplex")
    with pytest.raises(InputError, match="unknown backend"):
        api.make_method("staggered", backend="nope")


def test_a_method_that_is_not_installed_is_reported_not_crashed(monkeypatch):
    monkeypatch.setitem(api.METHODS, "ghost", api.MethodSpec("selfsupport.methods.no_such_module", "Ghost", "x"))
    with pytest.raises(BackendUnavailable, match="choose another"):
        api.solve(make_shape("dome", n_vertices=100), method="ghost")
    monkeypatch.setitem(api.METHODS, "ghost", api.MethodSpec("selfsupport.methods.staggered", "Ghost", "x"))
    with pytest.raises(BackendUnavailable, match="has no Ghost"):
        api.make_method("ghost")


@pytest.mark.parametrize("method", ["ipopt"])  # nlopt's dense SLSQP needs > 60 s even here
def test_simultaneous_methods_through_the_api_agree_with_staggered_on_a_dome(method):
    """A spherical dome on its rim stands as it is (``check`` says so), so every method must
    return a network in equilibrium that is the reference itself, up to solver tolerance."""
    scene = make_shape("dome", n_vertices=100)
    assert api.check(scene).self_supporting
    r_s = api.solve(scene, method="staggered")
    r_m = api.solve(scene, method=method, time_limit=60)
    assert r_m.status == "converged", r_m.message
    for r in (r_s, r_m):
        net = r.network
        assert relative_residuals(net.vertices, net.edges, net.weights, net.loads, net.supports).max() <= 1e-8
        assert r.distance_max <= 1e-4


# ------------------------------------------------------------------------------ check
@pytest.mark.parametrize("shape", ["pillar_vault", "dome"])
def test_check_finds_equilibrium_weights_of_solved_networks(shape):
    """The pillar vault's solution has many weights at ε; the fit must still find weights that
    balance it to round-off, not stop at the normal equations' floor."""
    res = api.solve(make_shape(shape, n_vertices=250))
    assert res.max_relative_error <= 1e-10
    rep = api.check(res.network)
    assert rep.self_supporting and rep.max_relative_error <= 1e-10
    net = rep.network
    assert relative_residuals(net.vertices, net.edges, net.weights, net.loads, net.supports).max() <= 1e-10


def test_check_of_a_network_fits_from_its_own_weights_too():
    """A flattened pillar vault (heights × 0.6): the fit from ε alone stalls near 1e-5, while the
    solved network's own weights balance it to 1e-12; check must not deny what they prove."""
    base = make_shape("pillar_vault", n_vertices=500)
    V = base.mesh.vertices.copy()
    V[:, 2] = V[:, 2].min() + 0.6 * (V[:, 2] - V[:, 2].min())
    res = api.solve(Scene(mesh=base.mesh.with_vertices(V), supports=base.supports))
    assert res.status == "converged" and res.max_relative_error <= 1e-10
    rep = api.check(res.network)
    assert rep.self_supporting and rep.stored_self_supporting and rep.max_relative_error <= 1e-10
    net = rep.network
    assert relative_residuals(net.vertices, net.edges, net.weights, net.loads, net.supports).max() <= 1e-10
    assert net.weights[net.active_edges].min() >= 0


def test_check_a_solved_network_is_self_supporting(barrel_result, tmp_path):
    rep = api.check(barrel_result.network)
    assert rep.self_supporting and rep.max_relative_error <= 1e-10
    net = rep.network  # fitted weights at the given positions, loads of that geometry
    assert relative_residuals(net.vertices, net.edges, net.weights, net.loads, net.supports).max() <= 1e-10
    assert net.weights[net.active_edges].min() >= 0  # compression (the fit's ε may be undercut, see _refine)
    # through a file: the stored weights are evaluated as they are, too
    p = tmp_path / "n.json"
    write_network(p, barrel_result)
    rep_f = api.check(p)
    assert rep_f.self_supporting
    assert rep_f.stored_max_relative_error == pytest.approx(barrel_result.max_relative_error, rel=1e-6, abs=1e-15)
    # the density the file was solved with is read back, so the stored weights match the loads
    assert rep_f.stored_max_relative_error_recomputed <= 1e-8


def test_check_a_vertex_below_all_its_neighbours_cannot_stand(barrel_result):
    """Σ_j w_ij (z_j − z_i) ≥ 0 for w ≥ 0 when z_i is below every z_j, while A_i F_i < 0:
    the vertical residual at i is at least |A_i F_i|, so the relative error is ≥ 1."""
    net = barrel_result.network
    V = net.vertices.copy()
    free = np.flatnonzero(~net.supports)
    k = int(free[len(free) // 2])
    nb = net.mesh.vertex_neighbors[k]
    V[k, 2] = V[nb, 2].min() - 0.01
    rep = api.check(Scene(mesh=net.mesh.with_vertices(V), supports=net.supports))
    assert not rep.self_supporting
    assert rep.max_relative_error >= 1.0 - 1e-12
    rel = rep.network.relative_errors()
    assert rel[np.searchsorted(free, k)] >= 1.0 - 1e-12  # the bound holds at that very vertex


def test_check_a_flat_disk_has_relative_error_exactly_one():
    """On a flat disk every edge is horizontal: no weights give vertical force, so the best fit
    balances the horizontal components exactly and leaves the whole load: error 1 everywhere."""
    rep = api.check(make_shape("disk", n_vertices=200))
    assert not rep.self_supporting
    rel = rep.network.relative_errors()
    assert np.allclose(rel, 1.0, atol=1e-9)


def test_check_verdict_is_invariant_under_load_and_length_scaling():
    scene = make_shape("pillar_vault", n_vertices=150)
    base = api.check(scene)
    heavy = api.check(scene, density=5000.0, thickness=0.3)
    big = api.check(Scene(mesh=scene.mesh.with_vertices(10.0 * scene.mesh.vertices), supports=scene.supports))
    assert not base.self_supporting  # the pillar vault has to move to stand (the demo shows it)
    assert heavy.max_relative_error == pytest.approx(base.max_relative_error, rel=1e-6)
    assert big.max_relative_error == pytest.approx(base.max_relative_error, rel=1e-6)
    # weights scale with the load (× 7.5) and, at fixed load per area, with length (× 100 / 10)
    act = base.network.active_edges
    assert np.allclose(heavy.network.weights[act], 7.5 * base.network.weights[act], rtol=1e-5, atol=1e-9 * base.network.weights.max())
    assert np.allclose(big.network.weights[act], 10.0 * base.network.weights[act], rtol=1e-5, atol=1e-9 * base.network.weights.max())


def test_check_rejects_bad_material():
    with pytest.raises(InputError, match="density"):
        api.check(make_shape("dome", n_vertices=100), density=-1.0)
