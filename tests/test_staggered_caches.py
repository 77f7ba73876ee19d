"""What the staggered iteration keeps across iterations gives what building it afresh gives:
the sparsity structures of ``A(V)`` and of the stress Laplacian's blocks (kept per topology),
and Step 3's Gram matrices of the constant per-coordinate terms (kept per term)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from formulations.equilibrium import Topology, position_blocks, stress_laplacian, weight_matrix
from formulations.terms import TERMS, Sum, TermContext
from selfsupport.core.shapes import make_shape
from selfsupport.methods.staggered.step3 import _term_model


def _coo_weight_matrix(top: Topology, V: np.ndarray) -> sp.csc_matrix:
    """``A(V)`` assembled from triplets, entry by entry as its docstring states it."""
    rows, cols, vals = [], [], []
    for k, (i, j) in enumerate(top.edges):
        for end, other, sign in ((i, j, 1.0), (j, i, -1.0)):
            if top.free_index[end] >= 0:
                for c in range(3):
                    rows.append(3 * top.free_index[end] + c)
                    cols.append(k)
                    vals.append(sign * (V[j, c] - V[i, c]))
    return sp.csc_matrix((vals, (rows, cols)), shape=(3 * top.n_free, top.m))


def _sliced_blocks(top: Topology, w: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """``K_ff``, ``K_fs`` sliced out of the full stress Laplacian."""
    L = stress_laplacian(top, w)[top.free]
    return L[:, top.free].tocsr(), L[:, ~top.free].tocsr()


def _identical(a: sp.spmatrix, b: sp.spmatrix) -> bool:
    a, b = a.tocsr(), b.tocsr()
    a.sort_indices()
    b.sort_indices()
    return (a.shape == b.shape and np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
            and np.array_equal(a.data, b.data))


@pytest.fixture(scope="module")
def scene():
    return make_shape("pillar_vault", n_vertices=300)


def _topology(scene, supports: np.ndarray) -> Topology:
    return Topology.build(scene.mesh.n_vertices, scene.mesh.edges, supports)


@pytest.mark.parametrize("seed", [0, 1])
def test_kept_structures_give_the_matrices_assembled_afresh_bit_for_bit(scene, seed):
    rng = np.random.default_rng(seed)
    top = _topology(scene, scene.supports)
    for _ in range(2):  # (the second assembly reuses the structures of the first)
        V = scene.mesh.vertices + 0.1 * rng.normal(size=scene.mesh.vertices.shape)
        w = rng.uniform(0.1, 2.0, top.m)
        A = weight_matrix(top, V)
        assert _identical(A, _coo_weight_matrix(top, V))
        # the layout scipy's triplet conversion gives (the weight fit's orderings follow it)
        ref = sp.csc_matrix(_coo_weight_matrix(top, V))
        assert np.array_equal(A.indices, ref.indices) and np.array_equal(A.indptr, ref.indptr)
        for kept, fresh in zip(position_blocks(top, w), _sliced_blocks(top, w)):
            assert _identical(kept, fresh)
        # the stress Laplacian is A's transpose acting on coordinates: K_ff X_f + K_fs X_s = A w
        Kff, Kfs = position_blocks(top, w)
        lhs = Kff @ V[top.free] + Kfs @ V[~top.free]
        np.testing.assert_allclose(lhs.ravel(), A @ w, rtol=0, atol=1e-12 * np.abs(A @ w).max())


def test_the_structures_belong_to_their_topology(scene):
    """Other supports, other structures: a topology never sees another's."""
    rng = np.random.default_rng(2)
    top = _topology(scene, scene.supports)
    more = scene.supports.copy()
    more[np.flatnonzero(~more)[:7]] = True
    other = _topology(scene, more)
    V = scene.mesh.vertices + 0.05 * rng.normal(size=scene.mesh.vertices.shape)
    w = rng.uniform(0.1, 2.0, top.m)
    weight_matrix(top, V), position_blocks(top, w)  # (the first topology's structures exist)
    assert weight_matrix(other, V).shape == (3 * other.n_free, other.m)
    assert _identical(weight_matrix(other, V), _coo_weight_matrix(other, V))
    for kept, fresh in zip(position_blocks(other, w), _sliced_blocks(other, w)):
        assert _identical(kept, fresh)
    assert position_blocks(other, w)[0].shape != position_blocks(top, w)[0].shape


def test_a_zero_weight_leaves_the_structure_as_the_stress_laplacian_does(scene):
    """scipy drops an entry that comes out zero; the kept structure must not keep it."""
    top = _topology(scene, scene.supports)
    w = np.linspace(0.5, 1.5, top.m)
    w[[3, 10]] = 0.0
    for kept, fresh in zip(position_blocks(top, w), _sliced_blocks(top, w)):
        assert _identical(kept, fresh)
        assert kept.nnz == fresh.nnz


def test_step3_keeps_one_gram_matrix_per_constant_term_across_iterations(scene):
    """The smoothing term inside the objective's sum is the same term every iteration (a
    part of weight 1 is the term itself), so its JᵀJ is built once and equals a fresh one."""
    mesh = scene.mesh
    ctx = TermContext(vertices=mesh.vertices, reference=mesh, free=~scene.supports)
    smooth = TERMS["fairness"].build(ctx, weight=100.0)
    objective = Sum((TERMS["reference"].build(ctx), smooth))
    assert smooth in objective.parts() and (smooth * 1.0) is smooth
    assert (smooth * 2.0).weight == 200.0 and smooth.weight == 100.0
    free = ~scene.supports
    rng = np.random.default_rng(3)
    ws: dict = {}
    for it in range(3):
        X = mesh.vertices + 0.01 * rng.normal(size=mesh.vertices.shape)
        objective = objective.at(X)  # (re-projected every iteration, as the run does)
        kept = _term_model(objective, X, free=free, alpha=0.5, c=2.0, ws=ws)
        fresh = _term_model(objective, X, free=free, alpha=0.5, c=2.0, ws={})
        assert len(ws["per_coordinate"]) == 1
        assert _identical(kept[0], fresh[0])
        for a, b in zip(kept[1:4], fresh[1:4]):
            assert np.array_equal(a, b)


def test_the_finish_screen_and_the_polish_share_one_factor_and_polish_alike(scene):
    """The screen's factor of −K_ff is the polish's: the polish with that workspace gives the
    positions a polish without one gives, bit for bit."""
    from formulations import Problem
    from selfsupport.core.loads import SelfWeight
    from selfsupport.methods.polish import polish
    from selfsupport.methods.staggered.finish import screen_ratio

    prob = Problem.build(scene, SelfWeight())
    sp_ = prob.scaled()
    top, sc, X = sp_.top, sp_.scaling, sp_.X
    rng = np.random.default_rng(4)
    w = rng.uniform(0.5, 1.5, top.m) * float(np.median(np.abs(sp_.L[0])))
    L = sc.loads_at(prob.loads, scene.mesh, X)[0]
    ref = scene.mesh.with_vertices(X)
    ws: dict = {}
    d_it = np.full(len(X), 1e-3)
    assert screen_ratio(top=top, X=X, w=w, L=L, reference=ref, d_it=d_it, workspace=ws) > 0
    shared = ws["laplacian"]
    kept = polish(top, X, w, prob.loads.primary, scene.mesh, sc, workspace=ws, fallbacks=False)
    alone = polish(top, X, w, prob.loads.primary, scene.mesh, sc, fallbacks=False)
    assert ws["laplacian"] is shared
    assert np.array_equal(kept[0], alone[0]) and np.array_equal(kept[1], alone[1]) and kept[2] == alone[2]
    assert screen_ratio(top=top, X=X, w=w, L=L, reference=ref, d_it=d_it, workspace=ws) == \
        screen_ratio(top=top, X=X, w=w, L=L, reference=ref, d_it=d_it)
