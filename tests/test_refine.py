"""The refinement phase (SQP on the simultaneous problem, methods/refine.py): its linearization
against finite differences, its step against a dense KKT solve, and what it does to a network."""
from __future__ import annotations

import numpy as np
import pytest

from formulations import Fairness, Problem, ReferenceDistance
from formulations.equilibrium import load_vector, weight_matrix
from selfsupport.core.evidence import closest_points
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.io import write_network
from selfsupport.methods import refine as refine_module
from selfsupport.methods.polish import load_colouring
from selfsupport.methods.refine import _linearize, _sqp_step
from selfsupport.methods.staggered import StaggeredLinearization
from tests.conftest import independent_check, requires_checker


@pytest.fixture(scope="module")
def setup():
    # (not a grid mesh: its right triangles sit on the kink of the mixed-area load model, where
    # dL/dx and dL/dy do not exist — pillar_vault's remainders fall by 2.3-49× per halving)
    scene = make_shape("dome", n_vertices=150)
    loads = SelfWeight()
    prob = Problem.build(scene, loads).scaled()
    top, sc = prob.top, prob.scaling
    rng = np.random.default_rng(3)
    X = prob.X.copy()
    X[top.free] += 1e-3 * rng.normal(size=(top.n_free, 3))  # off the reference: g ≠ 0
    w = np.maximum(prob.lower * 10, 1.0 + rng.random(top.m))
    w[::7] = prob.lower[::7]  # some weights at the lower bound
    L = sc.load(loads.nodal(scene.mesh, sc.pos_back(X)))
    reference = scene.mesh.with_vertices(prob.X)
    P, _, N = closest_points(X, reference)
    colouring = load_colouring(scene.mesh, top.free)
    objective = ReferenceDistance(points=P, normals=N, mask=top.free, tangential=0.05)
    lin = _linearize(top, X, w, L, objective, loads, scene.mesh, sc, colouring)
    return dict(scene=scene, loads=loads, top=top, sc=sc, X=X, w=w, L=L, lin=lin, lower=prob.lower, upper=prob.upper,
                P=P, N=N, colouring=colouring, reference=reference)


def test_the_constraint_linearization_is_first_order_exact(setup):
    """r(X + hΔx, w + hΔw) − r(X, w) − h (C_x Δx + A Δw) = O(h²): halving h quarters it."""
    s_, top, sc, X, w, L = setup, setup["top"], setup["sc"], setup["X"], setup["w"], setup["L"]
    Cx, A, r0, _, _, _ = s_["lin"]
    free = top.free
    s = np.repeat(1.0 / np.abs(L[free]), 3)  # the scaling is that of the base point, held fixed

    def r(Xc, wc):
        Lc = sc.load(s_["loads"].nodal(s_["scene"].mesh, sc.pos_back(Xc)))
        return s * (weight_matrix(top, Xc) @ wc - load_vector(top, Lc))

    assert np.allclose(r(X, w), r0, rtol=0, atol=1e-13 * np.abs(r0).max())
    rng = np.random.default_rng(4)
    dx, dw = rng.normal(size=(top.n_free, 3)), rng.normal(size=top.m) * w
    lin = Cx @ dx.ravel() + A @ dw
    rem = []
    for h in (1e-4, 5e-5, 2.5e-5):
        Xh = X.copy()
        Xh[free] += h * dx
        rem.append(np.abs(r(Xh, w + h * dw) - r0 - h * lin).max())
    assert 3.5 < rem[0] / rem[1] < 4.5 and 3.5 < rem[1] / rem[2] < 4.5
    assert rem[0] < 1e-2 * 1e-4 * np.abs(lin).max()  # and small against the first-order term


@pytest.mark.parametrize("release_cg", [True, False], ids=["released-by-cg", "released-refactored"])
def test_the_step_solves_the_kkt_system_of_its_qp(setup, monkeypatch, release_cg):
    """Against a dense KKT solve, with W and g built here from the normals: min ½ΔxᵀWΔx + gᵀΔx
    + ½ρΣ(Δw/w)² over the weights that move, s.t. C_x Δx + C_w Δw = −r, W = n nᵀ + τ(I − n nᵀ)
    per free vertex, g = W (x − p). The step satisfies the linearized constraint; a weight at a
    bound moves only inward (released), and then as a free variable of the same QP — solved
    again by CG preconditioned with the first factor, or (no CG iterations allowed) by a new
    factorization: the same step either way."""
    if not release_cg:
        monkeypatch.setattr(refine_module, "RELEASE_CG_MAX", 0)
    Cx, A, r, g_code, _, Winv = setup["lin"]
    top, X, w, lower, upper = setup["top"], setup["X"], setup["w"], setup["lower"], setup["upper"]
    free = top.free
    n = setup["N"][free]
    tau = 0.05
    Wb = np.einsum("ki,kj->kij", n, n) + tau * (np.eye(3)[None] - np.einsum("ki,kj->kij", n, n))
    W = np.zeros((3 * top.n_free, 3 * top.n_free))
    for k in range(top.n_free):
        W[3 * k:3 * k + 3, 3 * k:3 * k + 3] = Wb[k]
    g = np.einsum("kij,kj->ki", Wb, X[free] - setup["P"][free]).ravel()
    assert np.allclose(g_code, g, rtol=0, atol=1e-14 * np.abs(g).max())
    assert np.allclose(Winv.toarray() @ W, np.eye(W.shape[0]), rtol=0, atol=1e-12)
    rho = 1e-3
    dx, dw = _sqp_step(setup["lin"], w, lower, upper, rho)
    # the linearized constraint holds
    lin = Cx @ dx.ravel() + A @ dw
    assert np.abs(lin + r).max() <= 1e-8 * max(np.abs(r).max(), np.abs(lin).max())
    inner = (w > lower) & (w < upper)
    moved = ~inner & (dw != 0)
    assert moved.any()  # (the release path is exercised)
    assert np.all(dw[moved] > 0) and np.all(w[moved] <= lower[moved])  # released weights move inward
    F = inner | moved
    Cw = A[:, F].toarray()
    R = np.diag(rho / w[F] ** 2)
    nx, nw, nc = W.shape[0], R.shape[0], Cw.shape[0]
    K = np.block([[W, np.zeros((nx, nw)), Cx.toarray().T],
                  [np.zeros((nw, nx)), R, Cw.T],
                  [Cx.toarray(), Cw, np.zeros((nc, nc))]])
    sol = np.linalg.solve(K, np.r_[-g, np.zeros(nw), -r])
    assert np.allclose(dx.ravel(), sol[:nx], rtol=0, atol=1e-8 * np.abs(sol[:nx]).max())
    assert np.allclose(dw[F], sol[nx:nx + nw], rtol=0, atol=1e-8 * np.abs(sol[nx:nx + nw]).max())


def test_the_kkt_path_gives_the_schur_path_step_and_takes_general_objectives(setup):
    """The two ways the step is solved agree: the Schur complement (W block diagonal, W⁻¹ known)
    and the KKT system (any W, e.g. with the fairness term coupling neighbours). And with the
    fairness term added the step still satisfies the linearized constraint."""
    s_ = setup
    top, X, w, L = s_["top"], s_["X"], s_["w"], s_["L"]
    Cx, A, r, g, W, Winv = s_["lin"]
    assert Winv is not None
    rho = 1e-3
    dx_schur, dw_schur = _sqp_step(s_["lin"], w, s_["lower"], s_["upper"], rho)
    dx_kkt, dw_kkt = _sqp_step((Cx, A, r, g, W.tocsc(), None), w, s_["lower"], s_["upper"], rho)
    assert np.allclose(dx_kkt, dx_schur, rtol=0, atol=1e-8 * np.abs(dx_schur).max())
    assert np.allclose(dw_kkt, dw_schur, rtol=0, atol=1e-8 * np.abs(dw_schur).max())
    free = top.free
    obj = (ReferenceDistance(points=s_["P"], normals=s_["N"], mask=free, tangential=0.05)
           + Fairness(mesh=s_["reference"], free=free, targets=s_["reference"].vertices) * 100.0)
    lin = _linearize(top, X, w, L, obj, s_["loads"], s_["scene"].mesh, s_["sc"], s_["colouring"])
    assert lin[5] is None  # fairness couples neighbours: no block inverse
    dx, dw = _sqp_step(lin, w, s_["lower"], s_["upper"], rho)
    c = lin[0] @ dx.ravel() + lin[1] @ dw
    assert np.abs(c + lin[2]).max() <= 1e-8 * np.abs(lin[2]).max()


@pytest.fixture(scope="module")
def solved():
    scene = make_shape("concave_disk", n_vertices=400)
    plain = StaggeredLinearization().solve(scene, SelfWeight())
    records: list[dict] = []
    refined = StaggeredLinearization(refine=10).solve(scene, SelfWeight(), progress=records.append)
    return scene, plain, refined, records


def test_each_refinement_step_is_reported_as_it_is_tried(solved):
    """A refinement step takes seconds on a large mesh: progress hears of each one, in order,
    with the error and objective the history keeps for it."""
    _, _, refined, records = solved
    rec = next(h for h in refined.history if h["iteration"] == "refine")
    steps = [r for r in records if str(r.get("iteration", "")).startswith("refine ")]
    assert [r["iteration"] for r in steps] == [f"refine {k}" for k in range(1, rec["tried"] + 1)]
    assert sum(r["accepted"] for r in steps) == rec["steps"]
    assert [r["objective"] for r in steps if r["accepted"]] == rec["objective"]
    assert all(r["max_rel_error"] <= 0.5 * refined.parameters["tol"] for r in steps if r["accepted"])


def test_refinement_moves_the_network_closer_and_keeps_it_in_equilibrium(solved):
    scene, plain, refined, _ = solved
    assert plain.status == refined.status == "converged"
    rec = next(h for h in refined.history if h["iteration"] == "refine")
    assert rec["steps"] >= 1
    assert refined.max_relative_error <= 1e-9  # loads of its own geometry (Network recomputes them)
    assert refined.distance_mean < 0.5 * plain.distance_mean  # measured: 6.7e-3 -> 9.3e-4
    f = rec["objective"]
    assert all(b < a for a, b in zip(f, f[1:]))  # every accepted step lowered the objective
    # (the objective in SI units is the scaled one times the length²)
    total = sum(refined.terms.values())
    assert total == pytest.approx(f[-1] * refined.parameters["scaling"]["length"] ** 2, rel=1e-6)
    assert total < sum(plain.terms.values())
    net = refined.network
    active = scene.active_edges
    eps = refined.parameters["eps"]
    assert np.all(net.weights[active] >= eps * (1 - 1e-12))  # compression, bounds kept
    # the supports did not move
    assert np.array_equal(net.vertices[scene.supports], scene.mesh.vertices[scene.supports])


def test_refinement_is_off_by_default_and_the_plain_network_unchanged(solved):
    _, plain, _, _ = solved
    assert plain.parameters["refine"] == 0
    assert not any(h["iteration"] == "refine" for h in plain.history)


@requires_checker
def test_the_independent_checker_accepts_a_refined_network(solved, tmp_path):
    _, _, refined, _ = solved
    out = tmp_path / "refined.json"
    write_network(out, refined)
    p = independent_check(out)
    assert p.returncode == 0, p.stdout
    assert p.max_rel_error == pytest.approx(refined.max_relative_error, rel=1e-2, abs=1e-13)
