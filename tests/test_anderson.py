"""The one Anderson accelerator (selfsupport.methods.anderson): its rules on small linear maps,
and that the polish's height iteration and IPOPT's load rounds both run on it."""
from __future__ import annotations

import time

import numpy as np
import pytest

from selfsupport.methods.anderson import DIVERGING_FROM, Anderson, anderson


def _growing_map(n: int = 6, rate: float = 1.2):
    """``G(u) = A u + b`` with A a rotation by 90° in each plane scaled by ``rate`` (> 1): the
    plain iteration diverges, the fixed point ``(I − A)⁻¹ b`` exists."""
    A = np.zeros((n, n))
    for k in range(0, n, 2):
        A[k, k + 1], A[k + 1, k] = rate, -rate
    b = np.arange(1.0, n + 1)
    return (lambda u: A @ u + b), np.linalg.solve(np.eye(n) - A, b)


def test_anderson_converges_where_the_plain_iteration_diverges_and_that_one_gives_up():
    G, fixed = _growing_map()
    u, rounds, converged = anderson(G, np.zeros(6), tol=1e-12, max_rounds=50)
    assert converged and rounds < DIVERGING_FROM
    np.testing.assert_allclose(u, fixed, rtol=0, atol=1e-11)
    # depth 0 is the plain iteration: its residual grows, and it stops at the give-up round
    u, rounds, converged = anderson(G, np.zeros(6), tol=1e-12, max_rounds=50, depth=0)
    assert not converged and rounds == DIVERGING_FROM
    assert np.abs(G(u) - u).max() > np.abs(G(np.zeros(6))).max()


def test_anderson_past_its_deadline_returns_the_start_without_evaluating():
    calls = []

    def G(u):
        calls.append(1)
        return 0.5 * u

    start = np.ones(4)
    u, rounds, converged = anderson(G, start, tol=1e-12, max_rounds=50, deadline=time.perf_counter() - 1.0)
    assert (rounds, converged, calls) == (0, False, []) and u is start


@pytest.mark.parametrize("veto", ["accept", "limit_step"])
def test_a_vetoed_mixed_step_is_the_plain_step(veto):
    """On ``G(u) = 2u + 1`` the mixed step from 0, 1 lands on the fixed point −1, four times as
    far from ``G(1) = 3`` as that is from 1: a veto (``accept``, or ``limit_step`` for a step
    longer than the plain one) returns the plain ``G(u)`` instead."""
    def G(u):
        return 2.0 * u + 1.0

    u0, u1 = np.zeros(1), np.ones(1)
    free = Anderson(3)
    free.next(u0, G(u0))
    np.testing.assert_allclose(free.next(u1, G(u1)), [-1.0], rtol=0, atol=1e-15)
    guarded = Anderson(3, accept=lambda v: False) if veto == "accept" else Anderson(3, limit_step=True)
    guarded.next(u0, G(u0))
    np.testing.assert_array_equal(guarded.next(u1, G(u1)), G(u1))


def test_the_polish_and_ipopts_load_rounds_share_the_accelerator(monkeypatch):
    """One accelerator: the polish's fixed-point rounds (Newton off) and the simultaneous method's
    load rounds both mix through :class:`Anderson`."""
    from formulations import Problem
    from selfsupport.core.loads import SelfWeight
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods.polish import polish
    from selfsupport.methods.simultaneous import Simultaneous

    seen: list[int] = []
    real = Anderson.next

    def counted(self, u, Gu):
        seen.append(u.size)
        return real(self, u, Gu)

    monkeypatch.setattr(Anderson, "next", counted)
    scene = make_shape("dome", n_vertices=60)
    loads = SelfWeight(density=2000.0, thickness=0.1)
    res = Simultaneous().solve(scene, loads)
    assert res.status == "converged" and len(res.history) > 2  # (two load rounds at least, then the polish)
    n = scene.mesh.n_vertices
    assert n in seen  # the load rounds mix whole load vectors
    seen.clear()
    sp_ = Problem.build(scene, loads).scaled()
    X = sp_.X.copy()
    X[sp_.top.free, 2] *= 1.01
    w = np.full(sp_.top.m, 10.0)
    polish(sp_.top, X, w, loads, scene.mesh, sp_.scaling, newton=False, krylov=False)
    assert seen and set(seen) == {sp_.top.n_free}  # the polish mixes free heights
