"""Sensitivities of the simultaneous optimum (:mod:`selfsupport.methods.sensitivity`) against
central finite differences of two warm-started re-solves, and an analytic case.

Why the tests raise the weight regulariser (``WEIGHT_REGULARIZATION`` 1e-6 -> 1e-2): at the
default the weights in the null space of the equilibrium Jacobian are fixed by the regulariser
alone, the KKT matrix has condition ~1e14 in scaled units and IPOPT's final barrier terms are as
large as the regulariser's gradient, so neither the re-solves nor the base point resolve the
optimum well enough for a finite difference to mean anything (measured: 0.1-10 relative
disagreement, KKT residual 5e-5). At 1e-2 the condition is ~1e10 and the re-solves are accurate.
:func:`test_default_regulariser_is_flagged` keeps that limitation visible.

Why the base solve is re-run warm-started from itself: the NLP's force unit (and with it the
default lower bound and the regulariser) is the mean load at the solve's *start*; the re-solves
at θ ± h start at the optimum, so the base must too, else the two NLPs differ by the load change
between reference and optimum (~1e-3) and the derivatives by ~1e-4.

Tolerance 1e-4 (max-abs error / max-abs derivative): the re-solves are optimal to IPOPT's tol
1e-12 (positions ~1e-11 relative), divided by 2h (h = 1e-3 θ) gives ~1e-8; the central
difference's truncation error is O(h²) relative ~1e-6; the measured agreement is 3e-6 (density,
thickness, point load), 2e-5 (w_max) and 6e-4 / 1e-4 (positions / weights; objective weight, whose derivative is the most
curved: the tolerance is 1e-3 there).
"""
from __future__ import annotations

import numpy as np
import pytest

import selfsupport.methods.simultaneous as simultaneous
from formulations import Problem
from selfsupport import api
from selfsupport.core.errors import InputError
from selfsupport.core.loads import PointLoad, SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.methods.sensitivity import parse_parameter, sensitivity
from selfsupport.methods.simultaneous import Simultaneous

from .test_simultaneous import dome_scene

SCENE = dome_scene(8)  # dented 64-vertex dome: the optimum moves ~5 cm from the reference
APEX = int(np.argmax(np.where(SCENE.free, SCENE.mesh.vertices[:, 2], -np.inf)))
TIGHT = 1e-12


def build(density=2000.0, thickness=0.1, point=3000.0, w_max=None, w_vertices=1.0) -> Problem:
    f = np.zeros(SCENE.mesh.n_vertices)
    f[APEX] = -point
    return Problem.build(SCENE, SelfWeight(density=density, thickness=thickness) + PointLoad(f), w_max=w_max,
                         objective={"vertices": w_vertices})


@pytest.fixture
def regularised(monkeypatch):
    monkeypatch.setattr(simultaneous, "WEIGHT_REGULARIZATION", 1e-2)


def anchored_run(problem: Problem):
    """The optimum, re-solved from itself (so its NLP starts where the re-solves start)."""
    first = Simultaneous().run(problem, tol=TIGHT)
    return Simultaneous().run(problem, tol=TIGHT, warm_start=first.result)


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def w_max_active() -> float:
    """A w_max below the five largest weights of the unbounded optimum (so it is active)."""
    return float(np.sort(Simultaneous().solve(build(), tol=TIGHT).network.weights)[-5])


CASES = {  # parameter -> (problem factory of θ, θ, tolerance)
    "density": (lambda t: build(density=t), 2000.0, 1e-4),
    "thickness": (lambda t: build(thickness=t), 0.1, 1e-4),
    f"point_load:{APEX}": (lambda t: build(point=t), 3000.0, 1e-4),
    "w_max": (lambda t: build(w_max=t), None, 1e-4),
    "objective:vertices": (lambda t: build(w_vertices=t), 1.0, 1e-3),
}


@pytest.mark.parametrize("parameter", sorted(CASES))
def test_matches_finite_differences_of_re_solves(regularised, parameter):
    make, theta, tol = CASES[parameter]
    theta = w_max_active() if theta is None else theta
    h = 1e-3 * theta
    base = anchored_run(make(theta))
    assert base.result.status == "converged"
    s = sensitivity(base, parameter, problem=make(theta))
    assert s.value == pytest.approx(theta, rel=1e-12) and s.parameter == parameter
    plus, minus = (Simultaneous().solve(make(theta + sg * h), tol=TIGHT, warm_start=base.result) for sg in (1, -1))
    assert plus.status == minus.status == "converged"
    dV = (plus.network.vertices - minus.network.vertices) / (2 * h)
    dw = (plus.network.weights - minus.network.weights) / (2 * h)
    assert np.abs(dV).max() > 0 and np.abs(dw).max() > 0  # the parameter does move the network
    assert rel(s.d_vertices, dV) <= tol, rel(s.d_vertices, dV)
    assert rel(s.d_weights[0], dw) <= tol, rel(s.d_weights[0], dw)
    assert s.kkt_residual <= 1e-9 and s.solve_residual <= 1e-10
    if parameter == "w_max":
        assert len(s.active["upper"][0]) > 0  # the bound shaped the answer
    np.testing.assert_array_equal(s.d_vertices[SCENE.supports], 0.0)


def test_a_case_carried_by_scaled_weights_matches_finite_differences(regularised):
    """Snow on the self-weight is the empty case times k = 1 + 80 / (0.1 ρ) at any geometry: the
    simultaneous method solves without it and adds k w, so its derivative is k dw + (dk/dρ) w
    (dk/dρ ≠ 0: ρ is the self-weight's, not the snow's), against central differences of re-solves."""
    def make(rho: float) -> Problem:
        sw = SelfWeight(density=rho, thickness=0.1)
        return Problem.build(SCENE, {"empty": sw, "snow": sw + SelfWeight(density=80.0, thickness=1.0)})

    theta, h = 2000.0, 2.0
    base = anchored_run(make(theta))
    assert base.result.status == "converged" and "snow" in base.result.parameters["proportional_cases"]
    s = sensitivity(base, "density", problem=make(theta))
    assert s.case_names == ("empty", "snow")
    np.testing.assert_array_equal(s.active["lower"][1], s.active["lower"][0])
    plus, minus = (Simultaneous().solve(make(theta + sg * h), tol=TIGHT, warm_start=base.result) for sg in (1, -1))
    assert plus.status == minus.status == "converged"
    for c in range(2):
        dw = (plus.case_networks[c][1].weights - minus.case_networks[c][1].weights) / (2 * h)
        assert rel(s.d_weights[c], dw) <= 1e-4, (c, rel(s.d_weights[c], dw))
    k = 1 + 80.0 / (0.1 * theta)
    w = base.result.case_networks[0][1].weights
    np.testing.assert_allclose(s.d_weights[1], k * s.d_weights[0] - 800.0 / theta ** 2 * w,
                               rtol=0, atol=1e-9 * np.abs(s.d_weights[1]).max())


def test_pure_self_weight_scales_analytically():
    """Pure self-weight: the scaled problem does not depend on ρ, so the shape stays and every
    weight (those on ε too: ε is relative to the load) scales with ρ: dw/dρ = w/ρ, dV/dρ = 0.
    At the method's default settings, on a second load case too."""
    scene = make_shape("dome", n_vertices=60)
    loads = {"a": SelfWeight(density=2000.0), "b": SelfWeight(density=2000.0, thickness=0.1)}
    problem = Problem.build(scene, loads)
    run = Simultaneous().run(problem)
    s = sensitivity(run, "density", problem=problem)
    assert s.case_names == ("a", "b")
    for (_, net), dw in zip(run.result.case_networks, s.d_weights):
        np.testing.assert_allclose(dw, net.weights / 2000.0, rtol=1e-9, atol=1e-12 * net.weights.max() / 2000.0)
    assert np.abs(s.d_vertices).max() <= 1e-12 * np.ptp(scene.mesh.vertices)


def test_api_dispatches_and_rebuilds_the_problem():
    res = api.solve(make_shape("dome", n_vertices=60), method="ipopt", density=1500.0, thickness=0.2)
    s = api.sensitivity(res, "thickness")
    assert s.value == 0.2
    np.testing.assert_allclose(s.d_weights[0], res.network.weights / 0.2, rtol=1e-9,
                               atol=1e-12 * res.network.weights.max())


def test_default_regulariser_is_flagged():
    """At the default regulariser the optimum's weights are barely determined: the result says so
    through its condition number and KKT residual (see the module docstring)."""
    base = Simultaneous().run(build())
    s = sensitivity(base, f"point_load:{APEX}", problem=build())
    assert s.condition > 1e12 and s.kkt_residual > 1e-6


def test_refusals():
    problem = build()
    run = Simultaneous().run(problem)
    with pytest.raises(InputError, match="unknown parameter"):
        sensitivity(run, "gravity", problem=problem)
    with pytest.raises(InputError, match="no w_max"):
        sensitivity(run, "w_max", problem=problem)
    with pytest.raises(InputError, match="objective:planarity"):
        sensitivity(run, "objective:planarity", problem=problem)
    staggered = api.solve(make_shape("dome", n_vertices=60))
    with pytest.raises(InputError, match="simultaneous"):
        api.sensitivity(staggered, "density")
    assert parse_parameter("point_load:3@snow").label == "point_load:3@snow"
