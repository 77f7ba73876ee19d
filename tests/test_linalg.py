"""The shared SPD factorization (selfsupport.core.linalg): CHOLMOD, its fallbacks, reuse of the pattern."""
import numpy as np
import pytest
import scipy.sparse as sp

from formulations.equilibrium import Topology, position_blocks
from selfsupport.core.linalg import spd_factor
from selfsupport.core.shapes import make_shape


def _stress_matrix(n_vertices=400, seed=0):
    """−K_ff of a dome with random positive weights: the polish's SPD matrix."""
    scene = make_shape("dome", n_vertices=n_vertices)
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)
    w = np.random.default_rng(seed).uniform(0.5, 2.0, top.m)
    return (-position_blocks(top, w)[0]).tocsc()


def test_solves_agree_with_a_dense_solve_for_vectors_and_blocks():
    M = _stress_matrix()
    f = spd_factor(M)
    assert f.backend == "cholmod"
    rng = np.random.default_rng(1)
    b, B = rng.standard_normal(M.shape[0]), rng.standard_normal((M.shape[0], 3))
    dense = M.toarray()
    np.testing.assert_allclose(f.solve(b), np.linalg.solve(dense, b), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(f.solve(B), np.linalg.solve(dense, B), rtol=1e-10, atol=1e-12)


def test_update_with_the_same_pattern_refactors_the_new_values():
    M1, M2 = _stress_matrix(seed=0), _stress_matrix(seed=1)
    assert np.array_equal(M1.indices, M2.indices) and not np.allclose(M1.data, M2.data)
    f = spd_factor(M1)
    f.update(M2)
    b = np.ones(M1.shape[0])
    np.testing.assert_allclose(M2 @ f.solve(b), b, atol=1e-10)
    # a different pattern (a coupling between two vertices that share no edge) is factored afresh
    n = M2.shape[0]
    i, j = 0, int(np.flatnonzero(M2[0].toarray().ravel() == 0)[-1])
    E = sp.coo_matrix(([0.1, 0.1, 0.2, 0.2], ([i, j, i, j], [j, i, i, j])), shape=(n, n))
    M3 = (M2 + E).tocsc()  # still diagonally dominant, so SPD
    assert M3.nnz == M2.nnz + 2
    f.update(M3)
    np.testing.assert_allclose(M3 @ f.solve(b), b, atol=1e-10)
    np.testing.assert_allclose(f.solve(b), np.linalg.solve(M3.toarray(), b), rtol=1e-10, atol=1e-12)


def test_reuse_refactors_in_place_and_starts_afresh_for_another_size():
    M1, M2 = _stress_matrix(seed=0), _stress_matrix(seed=1)
    f = spd_factor(M1)
    assert spd_factor(M2, reuse=f) is f
    b = np.ones(M2.shape[0])
    np.testing.assert_allclose(f.solve(b), np.linalg.solve(M2.toarray(), b), rtol=1e-10, atol=1e-12)
    lower = sp.tril(M1, format="csc")
    lower.sort_indices()
    assert spd_factor(lower, lower=True, reuse=f) is f
    np.testing.assert_allclose(f.solve(b), np.linalg.solve(M1.toarray(), b), rtol=1e-10, atol=1e-12)
    M3 = _stress_matrix(n_vertices=200)
    g = spd_factor(M3, reuse=f)
    assert g is not f and g.shape == M3.shape


def test_singular_matrix_falls_back_and_solves_a_consistent_system():
    # a pure Neumann Laplacian (no supports) is singular: CHOLMOD refuses it; the fallback
    # factors it with a tiny shift, and a consistent right-hand side is solved to round-off
    n = 50
    L = sp.diags([-np.ones(n - 1), np.r_[1.0, 2 * np.ones(n - 2), 1.0], -np.ones(n - 1)], [-1, 0, 1]).tocsc()
    f = spd_factor(L)
    assert f.backend in ("qdldl", "superlu")
    b = np.sin(np.arange(n))
    b -= b.mean()
    x = f.solve(b)
    assert np.all(np.isfinite(x))
    np.testing.assert_allclose(L @ x, b, atol=1e-9)


def test_rejects_a_non_square_matrix():
    with pytest.raises(ValueError, match="square"):
        spd_factor(sp.identity(3, format="csr")[:2])


@pytest.mark.parametrize("shift", [0.0, 0.25])
def test_structural_gram_is_the_gram_on_a_pattern_fixed_by_the_structure(shift):
    """Values of AᵀA + shift·I, on the pattern of the columns sharing a stored row whatever the
    values: a grid's edges at the reference (zero x, y or z differences) give the same pattern
    as after a step, so one symbolic analysis serves them and CHOLMOD orders the full pattern."""
    from formulations.equilibrium import Topology, weight_matrix
    from selfsupport.core.linalg import structural_gram
    from selfsupport.core.shapes import make_shape

    scene = make_shape("cross_vault", n_vertices=400)
    m = scene.mesh
    top = Topology.build(m.n_vertices, m.edges[scene.active_edges], scene.supports)
    flat = m.vertices.copy()
    flat[:, 2] = 0.0  # every z difference zero: a third of A's stored entries are explicit zeros
    moved = m.vertices + 1e-3 * np.random.default_rng(0).standard_normal(m.vertices.shape)
    grams = []
    for V in (flat, m.vertices, moved):
        A = weight_matrix(top, V)
        G = structural_gram(A, shift=shift)
        dense = (A.T @ A).toarray() + shift * np.eye(A.shape[1])
        assert np.allclose(G.toarray(), dense, rtol=0, atol=1e-14 * np.abs(dense).max())
        grams.append(G)
    A_flat = weight_matrix(top, flat)
    assert (A_flat.T @ A_flat).nnz < grams[0].nnz  # the plain product lost entries on the flat grid...
    for G in grams[1:]:  # ...the structural one did not
        assert np.array_equal(G.indptr, grams[0].indptr) and np.array_equal(G.indices, grams[0].indices)
    # one GramPattern, taken at the moved positions, serves the flat grid's matrix too (a solve
    # keeps it across its fits), and its lower triangle is the lower triangle of that matrix
    from selfsupport.core.linalg import GramPattern

    pattern = GramPattern(weight_matrix(top, moved))
    assert pattern.matches(A_flat)
    G = pattern.gram(A_flat, shift)
    assert np.array_equal(G.toarray(), grams[0].toarray())
    low = sp.csc_matrix((pattern.lower(G.data), pattern.lower_indices, pattern.lower_indptr), shape=G.shape)
    assert np.array_equal(low.toarray(), np.tril(G.toarray()))


def test_refactoring_the_very_same_matrix_keeps_the_factor_and_new_values_refactor(monkeypatch):
    """The finish's screen and the polish factor one matrix: the second factorization is skipped
    (the values are compared with a copy, so a caller changing its array in place is seen)."""
    from selfsupport.core import linalg

    M1, M2 = _stress_matrix(seed=0), _stress_matrix(seed=1)
    b = np.random.default_rng(2).standard_normal(M1.shape[0])
    fresh = spd_factor(M1).solve(b)
    calls = []
    numeric = linalg._cholmod.numeric
    monkeypatch.setattr(linalg._cholmod, "numeric", lambda *a: (calls.append(1), numeric(*a))[1])
    f = spd_factor(M1)
    assert spd_factor(M1.copy(), reuse=f) is f and len(calls) == 1
    assert np.array_equal(f.solve(b), fresh)
    M = M1.copy()
    spd_factor(M, reuse=f)
    M.data[:] = M2.data  # (new values in the same array, as an iterative caller writes them)
    spd_factor(M, reuse=f)
    assert len(calls) == 2
    np.testing.assert_allclose(f.solve(b), np.linalg.solve(M2.toarray(), b), rtol=1e-10, atol=1e-12)
    lower = sp.tril(M1, format="csc")
    lower.sort_indices()
    spd_factor(lower, lower=True, reuse=f)
    assert len(calls) == 3 and np.array_equal(f.solve(b), fresh)


@pytest.mark.parametrize("at_reference", [True, False])
def test_the_gram_matrix_from_kept_products_is_scipys_bit_for_bit(at_reference, monkeypatch):
    """A pattern keeps the products of AᵀA (small meshes) or not (GRAM_PRODUCTS_MAX): the same
    matrix either way, to the last bit, with A's exact zeros (a grid at its reference) too."""
    from formulations.equilibrium import weight_matrix
    from selfsupport.core import linalg

    scene = make_shape("cross_vault", n_vertices=400)
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports)
    rng = np.random.default_rng(5)
    V = scene.mesh.vertices + (0 if at_reference else 0.05 * rng.standard_normal(scene.mesh.vertices.shape))
    A = weight_matrix(top, V)
    A = sp.csc_matrix((A.data * rng.uniform(0.5, 2.0, A.shape[0])[A.indices], A.indices, A.indptr), shape=A.shape)
    kept = linalg.GramPattern(A)
    assert kept.products is not None
    monkeypatch.setattr(linalg, "GRAM_PRODUCTS_MAX", 0)
    plain = linalg.GramPattern(A)
    assert plain.products is None
    Qk, Qp = kept.gram(A, 0.25), plain.gram(A, 0.25)
    assert np.array_equal(Qk.indptr, Qp.indptr) and np.array_equal(Qk.indices, Qp.indices)
    assert np.array_equal(Qk.data, Qp.data)
    np.testing.assert_allclose(Qk.toarray(), (A.T @ A).toarray() + 0.25 * np.eye(A.shape[1]), rtol=1e-13, atol=1e-13)
    assert at_reference is False or int((A.data == 0).sum()) > 0  # (the reference's grid: exact zeros)


def test_the_lower_triangle_is_scipys_tril_entry_for_entry_stored_zeros_kept():
    """The factorizations' lower triangle: for canonical CSC/CSR input (the solvers' products),
    with stored zeros and for a matrix with duplicates (summed), the same pattern and the same
    values as ``sp.tril``'s, in sorted CSC."""
    from selfsupport.core.linalg import _lower_csc

    rng = np.random.default_rng(3)
    for trial in range(60):
        n = int(rng.integers(1, 40))
        A = sp.random(n, n, density=rng.uniform(0.05, 0.6), random_state=rng, format="csr")
        M = (A + A.T + sp.identity(n)).tocsr()
        M.data[rng.random(M.nnz) < 0.2] = 0.0  # stored zeros: CHOLMOD's ordering depends on them
        coo = M.tocoo()
        dup = sp.csc_matrix((np.r_[coo.data, 1.5], (np.r_[coo.row, n - 1], np.r_[coo.col, 0])), shape=M.shape)
        for X in (M, M.tocsc(), dup):
            L, ref = _lower_csc(X), sp.tril(sp.csc_matrix(X), format="csc")
            ref.sum_duplicates()
            ref.sort_indices()
            assert L.format == "csc" and L.has_canonical_format
            for a, b in ((L.indptr, ref.indptr), (L.indices, ref.indices), (L.data, ref.data)):
                np.testing.assert_array_equal(a, b)
        assert np.count_nonzero(_lower_csc(M).data == 0) == np.count_nonzero(coo.data[coo.row >= coo.col] == 0)
