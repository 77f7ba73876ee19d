"""Step-2 fit: the active-set backend solves the box-constrained least-squares problem exactly."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from selfsupport.loads import SelfWeight
from selfsupport.methods.assembly import Topology, load_vector, weight_matrix
from selfsupport.methods.scaling import Scaling, default_eps
from selfsupport.methods.weightfit import ActiveSetFit, make_backend
from selfsupport.errors import InputError
from selfsupport.shapes import make_shape


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


def test_unknown_backend_and_option_are_named_errors():
    with pytest.raises(InputError, match="unknown weight-fit backend"):
        make_backend("gurobi")
    with pytest.raises(InputError, match="unknown option"):
        make_backend("active-set", speed=11)
