"""Step-2 backends (IPOPT, OSQP, nlopt) against scipy's lsq_linear on small box-constrained
least-squares problems: first-order optimality, bounds, agreement of the optimum."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from selfsupport.core.errors import BackendUnavailable, InputError
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


# ------------------------------------------------------------------ nlopt raising mid-run
def _nlopt_exceptions():
    """What ``nlopt.opt.optimize`` raises when a run stops without success, by wrapper generation:
    the SWIG classes of nlopt ≥ 2.8 (``nlopt.runtime_error`` — NLOPT_FAILURE, what L-BFGS raised on
    the structural scene's Step 2 — derives from ``nlopt.exception``, *not* ``RuntimeError``), its
    RoundoffLimited / ForcedStop, and the builtins of older wrappers."""
    import nlopt
    out = {"RuntimeError": lambda: RuntimeError("nlopt failure"), "ValueError": lambda: ValueError("nlopt invalid argument"),
           "MemoryError": lambda: MemoryError(), "RoundoffLimited": lambda: nlopt.RoundoffLimited(),
           "ForcedStop": lambda: nlopt.ForcedStop()}
    if hasattr(nlopt, "runtime_error"):
        out["nlopt.runtime_error"] = lambda: nlopt.runtime_error("nlopt failure")
    return out


def failing_optimize(monkeypatch, make_exc, *, evaluations: int, times: int | None = None):
    """Make ``nlopt.opt.optimize`` run the real optimizer for ``evaluations`` evaluations and then
    raise ``make_exc()`` (the first ``times`` calls only; all calls when None) — the way nlopt fails
    after having evaluated points. Returns the list of calls that raised."""
    import nlopt

    real = nlopt.opt.optimize
    raised = []

    def optimize(self, *args):
        if times is not None and len(raised) >= times:
            return real(self, *args)
        self.set_maxeval(evaluations)
        real(self, *args)
        raised.append(evaluations)
        raise make_exc()

    monkeypatch.setattr(nlopt.opt, "optimize", optimize)
    return raised


def dome_fit(n_vertices: int = 150, seed: int = 0):
    """Step 2's fit as the staggered method poses it (rows scaled by 1/|L_i|), on a generated dome
    with its free vertices moved off the reference."""
    from formulations import Problem
    from formulations.equilibrium import load_vector, weight_matrix
    from selfsupport.core.loads import SelfWeight
    from selfsupport.core.shapes import make_shape

    scene = make_shape("dome", n_vertices=n_vertices)
    loads = SelfWeight()
    prob = Problem.build(scene, loads).scaled()
    top, sc = prob.top, prob.scaling
    rng = np.random.default_rng(seed)
    X = prob.X.copy()
    X[top.free] += 1e-2 * rng.normal(size=(top.n_free, 3))
    L = sc.load(loads.nodal(scene.mesh, sc.pos_back(X)))
    s = np.repeat(1.0 / np.abs(L[top.free]), 3)
    A = (sp.diags(s) @ weight_matrix(top, X)).tocsc()
    return {"A": A, "b": s * load_vector(top, L), "lower": prob.lower, "upper": prob.upper,
            "w0": np.maximum(prob.lower, rng.lognormal(0.0, 1.0, top.m)), "prox": 0.0}


@pytest.mark.parametrize("exc", sorted(_nlopt_exceptions()))
def test_nlopt_fit_that_raises_returns_its_best_point_labelled(exc, monkeypatch):
    """Regression: nlopt ≥ 2.8 raised ``nlopt.runtime_error`` out of Step 2 on the structural scene
    (``solve … --backend nlopt`` ended in "internal error: runtime_error"). Whatever nlopt raises,
    the fit returns the best point it evaluated, within the bounds, labelled by the KKT check."""
    P = dome_fit()
    f0 = 0.5 * np.sum((P["A"] @ np.clip(P["w0"], P["lower"], P["upper"]) - P["b"]) ** 2)
    raised = failing_optimize(monkeypatch, _nlopt_exceptions()[exc], evaluations=5)
    out = NloptFit().fit(**P)
    assert raised == [5]
    assert np.all(out.w >= P["lower"]) and np.all(out.w <= P["upper"])
    assert out.objective == pytest.approx(0.5 * np.sum((P["A"] @ out.w - P["b"]) ** 2), rel=1e-12)
    assert out.objective < f0  # the best evaluated point, not the start
    assert kkt(P, out.w) > 1e-8  # 5 evaluations are far from the optimum ...
    assert out.status in ("failed", "max_iter")  # ... and the label says so, never "optimal"
    assert out.status == ("max_iter" if exc == "RoundoffLimited" else "failed")


def test_nlopt_fit_that_raises_at_the_optimum_is_optimal(monkeypatch):
    """A failure raised once the optimum is reached (L-BFGS's line search giving up on a flat
    objective) leaves a point that passes the first-order conditions: that is "optimal"."""
    import nlopt
    P = box_ls(*PROBLEMS["tall-prox"])
    exc = getattr(nlopt, "runtime_error", RuntimeError)
    failing_optimize(monkeypatch, lambda: exc("nlopt failure"), evaluations=20000)
    out = NloptFit().fit(**P)
    assert kkt(P, out.w) <= 1e-8 and out.status == "optimal"


def test_staggered_solve_survives_nlopt_failures_in_step_2(monkeypatch, tmp_path, capsys):
    """End to end through the CLI on a generated dome: the first three Step-2 fits raise nlopt's
    runtime_error after a few evaluations; the solve carries on to a network in equilibrium."""
    import nlopt

    from selfsupport import cli
    from selfsupport.core.shapes import make_shape
    from selfsupport.io import write_mesh
    from tests.conftest import document_errors

    scene = make_shape("dome", n_vertices=150)
    write_mesh(tmp_path / "dome.obj", scene.mesh)
    exc = getattr(nlopt, "runtime_error", RuntimeError)
    raised = failing_optimize(monkeypatch, lambda: exc("nlopt failure"), evaluations=10, times=3)
    out = tmp_path / "n.json"
    code = cli.main(["solve", str(tmp_path / "dome.obj"), "--supports", "boundary", "--backend", "nlopt",
                     "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert len(raised) == 3
    assert "internal error" not in err
    assert code == 0, err
    import json

    d = json.loads(out.read_text())
    assert d["backend"] == "nlopt" and d["status"] == "converged"
    assert document_errors(d).max() <= 1e-8
