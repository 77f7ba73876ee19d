"""Step-2 fit: the active-set backend solves the box-constrained least-squares problem exactly."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from formulations.equilibrium import Topology, load_vector, weight_matrix
from formulations.scaling import Scaling, default_eps
from selfsupport.core.errors import InputError
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.methods.weightfit import ActiveSetFit
from selfsupport.methods.weightfit_backends import make_backend


def kkt_violation(A, b, w, lo, up, prox, w0):
    """Projected-gradient norm of ½‖Aw−b‖² + ½prox‖w−w0‖² on the box (0 exactly at the optimum)."""
    g = A.T @ (A @ w - b) + prox * (w - w0)
    return float(np.abs(np.clip(w - g, lo, up) - w).max())


@pytest.mark.parametrize("seed", range(4))
def test_random_box_lsq_matches_lsq_linear(seed):
    rng = np.random.default_rng(seed)
    m, n = 120, 90
    A = sp.random(m, n, density=0.05, random_state=seed, format="csc") + sp.eye(m, n, format="csc") * 0.3
    b = rng.normal(size=m)
    lo, up = np.full(n, 0.05), np.where(rng.random(n) < 0.3, 0.4, np.inf)
    fit = ActiveSetFit().fit(A=A, b=b, lower=lo, upper=up, w0=np.ones(n), prox=0.0)
    ref = lsq_linear(A.toarray(), b, bounds=(lo, up), tol=1e-14, method="bvls")
    assert fit.status == "optimal"
    assert fit.objective == pytest.approx(0.5 * np.sum((A @ ref.x - b) ** 2), rel=1e-10, abs=1e-12)
    assert kkt_violation(A, b, fit.w, lo, up, 0.0, 0) <= 1e-10
    assert np.all(fit.w >= lo) and np.all(fit.w <= up)


def test_thrust_network_fit_warm_start_is_exact_and_cheap():
    """On a real network matrix: the cold fit (interior point + crossover) satisfies KKT to
    round-off, and a warm start from its active set finishes in one factorization."""
    scene = make_shape("concave_disk", n_vertices=400)
    m = scene.mesh
    L0 = SelfWeight().nodal(m, m.vertices)
    top = Topology.build(m.n_vertices, m.edges[scene.active_edges], scene.supports)
    sc = Scaling.of(m.vertices, L0, top.free)
    X, L = sc.pos(m.vertices), sc.load(L0)
    s = np.repeat(1 / np.abs(L[top.free]), 3)
    A = sp.diags(s) @ weight_matrix(top, X)
    b = s * load_vector(top, L)
    eps = default_eps(X, top.edges)
    lo, up = np.full(top.m, eps), np.full(top.m, np.inf)
    backend = ActiveSetFit()
    cold = backend.fit(A=A, b=b, lower=lo, upper=up, w0=lo, prox=1e-10)
    assert cold.status == "optimal" and cold.n_lower > 0  # the dent forces weights onto the bound
    scale = float(np.abs(A.T @ b).max())
    assert kkt_violation(A, b, cold.w, lo, up, 1e-10, lo) <= 1e-12 * scale
    warm = backend.fit(A=A, b=b, lower=lo, upper=up, w0=lo, prox=1e-10)  # same problem again
    assert warm.iterations == 1
    np.testing.assert_allclose(warm.w, cold.w, rtol=1e-8, atol=1e-12 * eps)


def test_an_inexact_fit_is_feasible_near_optimal_and_warm_starts_the_exact_one():
    """With a caller's rtol the interior point stops early (no crossover): the point is in the
    box and its objective within ~rtol of the optimum; the exact fit that follows, warm-started
    from the inexact one's guessed active set, reaches KKT to round-off."""
    rng = np.random.default_rng(7)
    m, n = 300, 240
    A = sp.random(m, n, density=0.03, random_state=7, format="csc") + sp.eye(m, n, format="csc") * 0.3
    b = rng.normal(size=m)
    lo, up = np.full(n, 0.05), np.where(rng.random(n) < 0.3, 0.4, np.inf)
    exact = ActiveSetFit().fit(A=A, b=b, lower=lo, upper=up, w0=np.ones(n), prox=1e-8)
    backend = ActiveSetFit()
    loose = backend.fit(A=A, b=b, lower=lo, upper=up, w0=np.ones(n), prox=1e-8, rtol=1e-6)
    assert loose.status == "inexact" and exact.status == "optimal" and exact.n_lower > 0
    assert np.all(loose.w >= lo) and np.all(loose.w <= up)
    assert exact.objective <= loose.objective <= exact.objective * (1 + 1e-5)  # measured 3.4e-6
    assert loose.n_lower == exact.n_lower  # the crossover's guess of the active set is right
    again = backend.fit(A=A, b=b, lower=lo, upper=up, w0=np.ones(n), prox=1e-8)
    assert again.status == "optimal" and again.iterations <= 2
    np.testing.assert_allclose(again.w, exact.w, rtol=1e-9, atol=1e-12)


def test_unknown_backend_and_option_are_named_errors():
    with pytest.raises(InputError, match="unknown weight-fit backend"):
        make_backend("gurobi")
    with pytest.raises(InputError, match="unknown option"):
        make_backend("active-set", speed=11)


def test_pdas_reduced_solve_in_the_full_pattern_equals_the_explicit_reduced_system():
    """PDAS solves the free variables' equations with the fixed ones at their bounds inside the
    full-size matrix (fixed rows and columns decoupled) so that one symbolic factorization
    serves every iteration; the result must equal the textbook reduced solve."""
    import scipy.sparse as sp

    from selfsupport.methods.weightfit import ActiveSetFit, _LowerQ

    rng = np.random.default_rng(7)
    A = sp.random(60, 45, density=0.15, random_state=8, format="csc") + sp.eye(60, 45, format="csc")
    Q = (A.T @ A + 1e-3 * sp.identity(45)).tocsc()
    c = rng.standard_normal(45)
    lower, upper = np.full(45, 0.1), np.full(45, 2.0)
    lo = rng.random(45) < 0.3
    up = ~lo & (rng.random(45) < 0.2)
    lowq = _LowerQ(Q)
    for _ in range(2):  # the second call refactors numerically in the same pattern
        w = ActiveSetFit._reduced_solve(lowq, Q, c, lower, upper, lo, up)
        fixed = lo | up
        Qd = Q.toarray()
        ref = np.where(lo, lower, np.where(up, upper, 0.0))
        f = ~fixed
        ref[f] = np.linalg.solve(Qd[np.ix_(f, f)], c[f] - Qd[np.ix_(f, fixed)] @ ref[fixed])
        np.testing.assert_allclose(w, ref, rtol=1e-10, atol=1e-12)
        lo, up = up, lo  # another active set, same pattern
    # and Q + diag(D) through the same pattern
    D = rng.random(45)
    x = lowq.with_diagonal(D).solve(c)
    np.testing.assert_allclose((Q + sp.diags(D)) @ x, c, atol=1e-10)


def _network_fit_sequence(n_vertices: int, steps: int, seed: int):
    """Step-2 problems of a generated concave disk along a sequence of perturbed geometries (the
    vertices jittered more at each step, as an outer iteration moves them): (A, b, lower, upper)."""
    scene = make_shape("concave_disk", n_vertices=n_vertices)
    m = scene.mesh
    top = Topology.build(m.n_vertices, m.edges[scene.active_edges], scene.supports)
    rng = np.random.default_rng(seed)
    out = []
    for k in range(steps):
        V = m.vertices.copy()
        V[top.free] += (0.02 * k) * rng.standard_normal((int(top.free.sum()), 3)) * np.ptp(V, axis=0).max() / 30
        L0 = SelfWeight().nodal(m, V)
        sc = Scaling.of(V, L0, top.free)
        X, L = sc.pos(V), sc.load(L0)
        s = np.repeat(1 / np.abs(L[top.free]), 3)
        A = (sp.diags(s) @ weight_matrix(top, X)).tocsc()
        eps = default_eps(X, top.edges)
        out.append((A, s * load_vector(top, L), np.full(top.m, eps), np.full(top.m, np.inf)))
    return out


@pytest.mark.parametrize("name", ["active-set-centred", "active-set-centred-all"])
def test_centred_restart_agrees_with_active_set_and_meets_kkt(name):
    """The centred-restart backend solves the same strictly convex problems: along a sequence of
    perturbed network fits (exact and loose alternating, as the staggered method asks them) its
    exact fits equal the plain active-set backend's to round-off and satisfy the KKT conditions
    (stationary on the free set, multipliers ≥ 0 on the bound); its restarts were used."""
    plain, centred = ActiveSetFit(), make_backend(name)
    w_prev = None
    used = 0
    for k, (A, b, lo, up) in enumerate(_network_fit_sequence(400, 6, seed=3)):
        w0 = lo.copy() if w_prev is None else w_prev
        prox = 1e-8 * float(np.asarray(A.multiply(A).sum(axis=0)).mean())
        rtol = 1e-5 if k % 2 else None
        used += centred._centred is not None
        f1 = plain.fit(A=A, b=b, lower=lo, upper=up, w0=w0, prox=prox, rtol=rtol)
        f2 = centred.fit(A=A, b=b, lower=lo, upper=up, w0=w0, prox=prox, rtol=rtol)
        assert np.all(f2.w >= lo) and np.all(f2.w <= up)
        if rtol is None:
            assert f1.status == f2.status == "optimal"
            np.testing.assert_allclose(f2.w, f1.w, rtol=1e-9, atol=1e-12 * lo[0])
            g = A.T @ (A @ f2.w - b) + prox * (f2.w - w0)
            at = f2.w <= lo
            gs = float(np.abs(A.T @ b).max())
            assert np.abs(g[~at]).max() <= 1e-9 * gs and g[at].min(initial=0.0) >= -1e-9 * gs
            assert kkt_violation(A, b, f2.w, lo, up, prox, w0) <= 1e-12 * gs
        else:  # a loose fit: within the box, near the optimum
            assert f2.objective <= f1.objective * (1 + 1e-2)
        w_prev = f2.w
    assert used >= 3  # the interior point did restart from a centred iterate


@pytest.mark.parametrize("name", ["active-set", "ipopt", "nlopt"])
def test_a_start_that_already_fits_is_the_fit(name):
    """``A w0 = b`` with w0 inside the box: w0 is the unique minimiser of ½‖Aw−b‖² + ½prox‖w−w0‖²,
    returned as it is by every backend; a start that misses by more than FITS_ALREADY is fitted."""
    from selfsupport.methods.weightfit import FITS_ALREADY

    rng = np.random.default_rng(5)
    m, n = 60, 90  # more columns than rows, as a triangle mesh's fit: a face of minimisers without prox
    A = (sp.random(m, n, density=0.08, random_state=5, format="csc") + sp.eye(m, n, format="csc")).tocsc()
    lo, up = np.full(n, 0.05), np.full(n, np.inf)
    w_true = lo + rng.uniform(0.0, 1.0, n)
    w_true[:10] = lo[:10]  # some at the bound: multipliers of zero there (degenerate)
    b = A @ w_true
    backend = make_backend(name)
    got = backend.fit(A=A, b=b, lower=lo, upper=up, w0=w_true, prox=1e-8)
    assert got.status == "optimal" and got.iterations == 0 and np.array_equal(got.w, w_true)
    off = w_true.copy()
    off[20] += 100 * FITS_ALREADY * float(np.abs(b).max()) / float(np.abs(A[:, 20]).max())
    fitted = backend.fit(A=A, b=b, lower=lo, upper=up, w0=off, prox=1e-8)
    assert fitted.iterations > 0
    # a caller's per-row round-off floor above that residual: the start fits already; below it, not
    r = np.abs(A @ off - b) / float(np.abs(b).max())
    assert backend.fit(A=A, b=b, lower=lo, upper=up, w0=off, prox=1e-8, fits=2 * r).iterations == 0
    assert backend.fit(A=A, b=b, lower=lo, upper=up, w0=off, prox=1e-8, fits=0.5 * r).iterations > 0


def _lsmr_counted(monkeypatch):
    """Count LSMR's iterations where the correction looks it up."""
    from selfsupport.methods import fixed_fit

    real, calls = fixed_fit.lsmr, []

    def counted(*a, **k):
        out = real(*a, **k)
        calls.append(int(out[2]))
        return out
    monkeypatch.setattr(fixed_fit, "lsmr", counted)
    return calls


def test_the_lsmr_correction_reaches_an_attainable_fit(monkeypatch):
    """A consistent system (b = A w*, w* inside the bounds): from a perturbed start the
    correction brings every row's residual to round-off."""
    from selfsupport.methods.fixed_fit import REFINED, lsmr_correction

    rng = np.random.default_rng(3)
    A = sp.random(300, 200, density=0.05, random_state=4, format="csc") + sp.eye(300, 200, format="csc")
    w_true = rng.uniform(1.0, 2.0, 200)
    b = A @ w_true
    w = w_true * (1 + 1e-3 * rng.standard_normal(200))
    rel = np.linalg.norm((A @ w - b).reshape(-1, 3), axis=1)
    calls = _lsmr_counted(monkeypatch)
    w2, rel2 = lsmr_correction(A, b, w, np.full(200, 0.5), np.full(200, np.inf), rel)
    assert rel2.max() <= REFINED < rel.max() and calls
    assert np.allclose(np.linalg.norm((A @ w2 - b).reshape(-1, 3), axis=1), rel2)


def test_the_lsmr_correction_stops_once_it_stalls(monkeypatch):
    """LSMR's tolerances (1e-16) are out of reach on a network's fit, so it is run in chunks and
    stopped once a chunk does not halve the max error. Checking a solved 600-vertex pillar vault
    took 24,922 LSMR iterations (0.85 s) that way before, for the same 2.3e-13; a jittered
    2,000-vertex dome ran to the limit, 120,000 iterations (16 s), and gained 20%."""
    from selfsupport import api
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods.fixed_fit import LSMR_CHUNK

    res = api.solve(make_shape("pillar_vault", n_vertices=600))
    calls = _lsmr_counted(monkeypatch)
    rep = api.check(res.network)
    assert rep.self_supporting and rep.max_relative_error <= 1e-12
    assert sum(calls) <= 5 * LSMR_CHUNK
