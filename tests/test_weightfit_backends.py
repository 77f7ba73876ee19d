"""Step-2 backends (IPOPT, OSQP, nlopt) against scipy's lsq_linear on small box-constrained
least-squares problems: first-order optimality, bounds, agreement of the optimum."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from selfsupport.errors import BackendUnavailable, InputError
from selfsupport.methods.weightfit_backends import IpoptFit, NloptFit, OsqpFit

BACKENDS = {"ipopt": IpoptFit, "osqp": OsqpFit, "nlopt": NloptFit}


def make_backend(name, **opts):
    try:
        return BACKENDS[name](**opts)
    except BackendUnavailable as exc:
        pytest.skip(str(exc))


def box_ls(rows: int, cols: int, prox: float, seed: int):
    rng = np.random.default_rng(seed)
    A = (sp.random(rows, cols, density=0.15, random_state=rng, format="csc")
         + 0.5 * sp.eye(rows, cols, format="csc"))
    b = rng.standard_normal(rows)
    lower = np.full(cols, 0.05)
    upper = np.full(cols, np.inf)
    upper[:5] = 0.3
    w0 = rng.random(cols)
    return {"A": A, "b": b, "lower": lower, "upper": upper, "w0": w0, "prox": prox}


PROBLEMS = {"tall": (60, 40, 0.0, 1), "wide": (30, 50, 0.0, 2), "wide-prox": (30, 50, 1e-3, 3),
            "tall-prox": (60, 40, 1e-2, 4)}


def kkt(P, w) -> float:
    """Projected gradient of ½‖Aw−b‖² + ½prox‖w−w0‖², relative (independent of the package)."""
    A, b, prox = P["A"].toarray(), P["b"], P["prox"]
    g = A.T @ (A @ w - b) + prox * (w - P["w0"])
    scale = max(np.abs(A.T @ b).max(), np.abs(A.T @ (A @ w)).max())
    return float(np.abs(w - np.clip(w - g, P["lower"], P["upper"])).max() / scale)


def reference(P):
    A, b = P["A"].toarray(), P["b"]
    if P["prox"]:
        A = np.vstack([A, np.sqrt(P["prox"]) * np.eye(A.shape[1])])
        b = np.r_[b, np.sqrt(P["prox"]) * P["w0"]]
    return lsq_linear(A, b, bounds=(P["lower"], P["upper"]), method="bvls", tol=1e-14).x


@pytest.mark.parametrize("problem", sorted(PROBLEMS))
@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_backend_agrees_with_lsq_linear(name, problem):
    P = box_ls(*PROBLEMS[problem])
    be = make_backend(name)
    out = be.fit(**P)
    w_ref = reference(P)
    assert kkt(P, w_ref) < 1e-10  # the reference itself is optimal
    assert np.all(out.w >= P["lower"]) and np.all(out.w <= P["upper"])
    assert kkt(P, out.w) <= 1e-6
    f_ref = 0.5 * np.sum((P["A"] @ w_ref - P["b"]) ** 2)
    assert out.objective == pytest.approx(0.5 * np.sum((P["A"] @ out.w - P["b"]) ** 2), rel=1e-12)
    if P["prox"]:  # strictly convex: the minimiser is unique
        np.testing.assert_allclose(out.w, w_ref, atol=1e-6 * np.abs(w_ref).max())
    else:
        assert out.objective == pytest.approx(f_ref, rel=1e-6)
    if name in ("ipopt", "osqp"):
        assert out.status == "optimal"
    else:  # nlopt: "optimal" only with its own KKT check passed
        assert out.status in ("optimal", "max_iter")
    assert out.n_lower > 0  # the lower bound is active in all these problems
    if P["prox"]:
        tol = 1e-8 * np.abs(w_ref).max()
        assert (out.n_lower, out.n_upper) == (int(np.sum(w_ref <= P["lower"] + tol)),
                                              int(np.sum(w_ref >= P["upper"] - tol)))


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_backend_reuses_solver_for_same_pattern_and_adapts_to_new(name):
    be = make_backend(name)
    P = box_ls(*PROBLEMS["tall-prox"])
    first = be.fit(**P)
    Q = dict(P, A=P["A"] * 1.7, b=P["b"] * 0.5, w0=first.w)  # same pattern, new numbers, warm start
    second = be.fit(**Q)
    assert kkt(Q, second.w) <= 1e-6
    R = box_ls(*PROBLEMS["wide"])  # different pattern
    third = be.fit(**R)
    assert kkt(R, third.w) <= 1e-6


def test_nlopt_reports_max_iter_when_stopped_early():
    P = box_ls(*PROBLEMS["tall"])
    out = NloptFit(maxeval=3).fit(**P)
    assert out.status == "max_iter"
    assert np.all(out.w >= P["lower"]) and np.all(out.w <= P["upper"])


def test_unknown_options_are_rejected():
    with pytest.raises(InputError, match="unknown option"):
        IpoptFit(bogus=1)
    with pytest.raises(InputError):
        NloptFit(algorithm="LN_COBYLA")


def test_backend_names():
    assert {c.name for c in BACKENDS.values()} == set(BACKENDS)
