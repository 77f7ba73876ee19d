"""Sparse symmetric positive definite factorizations, shared by every solver of the project.

Every linear system the staggered method solves is SPD: the Step-2 normal equations
(``AᵀA + prox I``, plus the interior point's barrier diagonal), the Step-3 position system
and the stress Laplacian ``−K_ff`` of the polish. They are factored by CHOLMOD's supernodal
Cholesky (through cvxopt, which ships SuiteSparse in its wheels): 5–9× faster than QDLDL's
up-looking LDLᵀ on the 3n×3n Step-3 matrix of a 1,200-vertex mesh, and its symbolic
analysis is kept, so a matrix with the same pattern is refactored numerically only.

A matrix CHOLMOD rejects as not positive definite (round-off on a nearly singular system,
e.g. a flat network that carries no vertical load) goes to QDLDL (LDLᵀ without pivoting,
AMD ordering) and, should that produce non-finite values, to SuperLU with a diagonal shift
of 1e-12 of the largest diagonal entry.

Example
-------
>>> import numpy as np, scipy.sparse as sp
>>> M = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(5, 5))
>>> x = spd_factor(M).solve(np.ones(5))
>>> bool(np.allclose(M @ x, 1.0))
True
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_factor, cho_solve
from scipy.sparse.linalg import splu

try:  # cvxopt bundles CHOLMOD; without it the QDLDL path below still works
    from cvxopt import cholmod as _cholmod
    from cvxopt import matrix as _cvx_matrix
    from cvxopt import spmatrix as _cvx_spmatrix
except ImportError:  # pragma: no cover - cvxopt is a dependency
    _cholmod = None

__all__ = ["DENSE_ROW_MIN", "GramPattern", "LowRankUpdatedFactor", "SPDFactor", "SplitGram", "spd_factor",
           "structural_gram"]


def _lower_csc(M: sp.spmatrix) -> sp.csc_matrix:
    """The lower triangle of ``M``, sorted CSC, its stored zeros kept. A canonical CSC matrix
    (sorted, no duplicates: what the products and sums of the solvers give) keeps the entries
    on and below the diagonal as they are, ~10x faster than ``sp.tril``'s round trip through
    COO (a solve factors ~4 matrices an iteration); any other goes that way and sums its
    duplicates."""
    C = sp.csc_matrix(M)
    if C.has_canonical_format:
        n = C.shape[1]
        cols = np.repeat(np.arange(n), np.diff(C.indptr))
        keep = C.indices >= cols
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(cols[keep], minlength=n), out=indptr[1:])
        L = sp.csc_matrix((C.data[keep], C.indices[keep], indptr), shape=C.shape)
        L.has_canonical_format = True
        return L
    L = sp.tril(C, format="csc")
    L.sum_duplicates()
    L.sort_indices()
    return L


class SPDFactor:
    """A factorization of one SPD matrix: ``solve(rhs)`` for 1-D or 2-D right-hand sides,
    ``update(M)`` to refactor a new matrix (numerically only when the pattern is unchanged).
    ``backend`` says which library holds the factor ("cholmod", "qdldl" or "superlu")."""

    def __init__(self, M: sp.spmatrix, lower: bool = False) -> None:
        self.shape = M.shape
        self._symbolic = None
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None
        self._factor(M, lower)

    # ------------------------------------------------------------------ factorization
    def _factor(self, M: sp.spmatrix, lower: bool = False) -> None:
        L = sp.csc_matrix(M) if lower else _lower_csc(M)
        if L.shape[0] == 0:
            self.backend, self._f = "empty", None
            return
        if _cholmod is not None and self._cholmod(L):
            return
        self._ldl(L + sp.tril(L, k=-1, format="csc").T if lower else sp.csc_matrix(M))

    def _cholmod(self, L: sp.csc_matrix) -> bool:
        n = L.shape[0]
        same = (self._pattern is not None and self._symbolic is not None
                and np.array_equal(self._pattern[0], L.indptr) and np.array_equal(self._pattern[1], L.indices))
        if same and self.backend == "cholmod" and np.array_equal(self._values, L.data):
            return True  # (the very matrix factored last: its factor stands)
        try:
            if same:
                S = self._S
                S.V = _cvx_matrix(L.data)
            else:
                cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(L.indptr))
                S = _cvx_spmatrix(_cvx_matrix(L.data), _cvx_matrix(L.indices.astype(np.int64)),
                                  _cvx_matrix(cols), (n, n))
                self._symbolic = _cholmod.symbolic(S, uplo="L")
                self._pattern = (L.indptr.copy(), L.indices.copy())
            _cholmod.numeric(S, self._symbolic)
        except (ArithmeticError, ValueError):  # not (numerically) positive definite
            self._symbolic, self._pattern = None, None
            return False
        self._S, self._values = S, L.data.copy()
        self.backend, self._f = "cholmod", self._symbolic
        return True

    def _ldl(self, M: sp.csc_matrix) -> None:
        import qdldl

        try:
            self._f = qdldl.Solver(sp.triu(M, format="csc"))
            self.backend = "qdldl"
        except (ValueError, RuntimeError, ZeroDivisionError):
            self._superlu(M)
        self._M = M

    def _superlu(self, M: sp.csc_matrix) -> None:

        shift = 1e-12 * max(float(np.abs(M.diagonal()).max()), 1e-300)
        self._f = splu(M + shift * sp.identity(M.shape[0], format="csc"))
        self.backend = "superlu"

    def update_lower(self, L: sp.csc_matrix) -> None:
        """Refactor from the lower triangle ``L`` (CSC, sorted) without re-extracting it: the
        interior point's per-iteration path (numeric only while the pattern holds)."""
        self.shape = L.shape
        self._factor(L, lower=True)

    def update(self, M: sp.spmatrix) -> None:
        """Refactor for a new matrix (typically the same pattern with new values)."""
        self.shape = M.shape
        self._factor(M)

    # ------------------------------------------------------------------------ solves
    def solve(self, rhs: np.ndarray) -> np.ndarray:
        rhs = np.asarray(rhs, dtype=float)
        if self.backend == "empty":
            return np.zeros_like(rhs)
        if self.backend == "cholmod":
            B = _cvx_matrix(np.asfortranarray(rhs.reshape(rhs.shape[0], -1)))
            _cholmod.solve(self._f, B)
            return np.array(B).reshape(rhs.shape)
        if rhs.ndim == 2:
            return np.column_stack([self._solve1(np.ascontiguousarray(rhs[:, k])) for k in range(rhs.shape[1])])
        return self._solve1(rhs)

    def _solve1(self, rhs: np.ndarray) -> np.ndarray:
        if self.backend == "qdldl":
            x = self._f.solve(rhs)
            if np.all(np.isfinite(x)):
                return x
            self._superlu(self._M)  # LDLᵀ without pivoting broke down: pivot
        return self._f.solve(rhs)


def spd_factor(M: sp.spmatrix, *, lower: bool = False, reuse: SPDFactor | None = None) -> SPDFactor:
    """Factor the symmetric positive (semi)definite matrix ``M`` (see the module docstring).
    With ``lower=True``, ``M`` is its lower triangle, in sorted CSC form, used as it is.
    ``reuse``: a factor of an earlier matrix of the same size, refactored in place and
    returned (numerically only while the pattern holds) — the path of iterative callers."""
    if M.shape[0] != M.shape[1]:
        raise ValueError(f"spd_factor needs a square matrix, got {M.shape}")
    if reuse is not None and reuse.shape == M.shape:
        if lower:
            reuse.update_lower(sp.csc_matrix(M))
        else:
            reuse.update(M)
        return reuse
    return SPDFactor(M, lower=lower)


def structural_gram(A: sp.spmatrix, shift: float = 0.0) -> sp.csc_matrix:
    """``AᵀA + shift·I`` (sorted CSC) stored on the *structural* pattern of ``A``: every pair of
    columns that share a stored row of ``A`` (explicit zeros included) keeps its entry, as an
    explicit zero where the product vanishes.

    Why: scipy's product drops the entries that come out exactly zero, and CHOLMOD orders the
    thinner pattern it is given far worse. The first weight fit of a cross vault sits at the
    reference, whose grid edges have zero x, y or z differences, so its matrix loses entries and
    its factorizations slow down many times (``studies.theory_whys`` measures both). A fixed
    pattern also lets every fit of a solve reuse one symbolic analysis. (:class:`GramPattern` keeps the
    pattern for a series of matrices of one structure.)

    >>> A = sp.csc_matrix(np.array([[1.0, 1.0], [1.0, -1.0]]))
    >>> (A.T @ A).nnz, structural_gram(A).nnz  # (columns orthogonal: the product drops 2 entries)
    (2, 4)
    >>> structural_gram(A, shift=0.5).toarray()
    array([[2.5, 0. ],
           [0. , 2.5]])
    """
    A = sp.csc_matrix(A)
    return GramPattern(A).gram(A, shift)


#: A row of ``A`` with more stored entries than this is a *dense row*: :class:`GramPattern` leaves
#: it out of ``AᵀA`` and the solvers add it back as a low-rank term (:class:`SplitGram`,
#: :class:`LowRankUpdatedFactor`). A row is a free vertex's coordinate and its entries are the
#: vertex's edges, so a vertex of valence ``k`` puts a dense ``k × k`` block into ``AᵀA`` (a fan of
#: thousands of supported rim vertices around one free apex would fill gigabytes). Ordinary meshes
#: have no row near this length (valence 3-12).
DENSE_ROW_MIN = 256

#: Most pairs of stored entries (``Σ_r nnz(row r)²``, ~50 per free vertex) for which
#: :class:`GramPattern` keeps the products of ``AᵀA`` as index arrays (three int64 per pair,
#: 14 MB at the limit): each Gram matrix is then one gather and one sum (3-6× faster than
#: scipy's product and the search of its entries in the pattern up to 2,000 free vertices).
#: Above it (about 12,000 free vertices) the factorizations dominate and memory is kept small.
GRAM_PRODUCTS_MAX = 600_000


class GramPattern:
    """The structural pattern of ``AᵀA + I`` for one sparsity structure of ``A`` (see
    :func:`structural_gram`), computed once: each fit of a staggered solve has a new ``A`` on
    the same structure (building the pattern is most of the cost of the product). ``gram``
    gives the matrix on it, ``lower`` its lower triangle's data (sorted CSC, diagonal stored).

    Rows with more than :data:`DENSE_ROW_MIN` entries (``dense``, their indices) are left out of
    the pattern and of ``gram``: ``AᵀA = gram(A) + UᵀU`` with ``U = dense_part(A)``, which
    :class:`SplitGram` and :class:`LowRankUpdatedFactor` use without forming ``UᵀU``.

    >>> A = sp.csc_matrix(np.array([[1.0, 2.0, 0.0], [0.0, 1.0, 3.0]]))
    >>> g = GramPattern(A)
    >>> g.matches(A), np.allclose(g.gram(A, 1.0).toarray(), (A.T @ A).toarray() + np.eye(3))
    (True, True)
    >>> sp.csc_matrix((g.lower(g.gram(A, 1.0).data), g.lower_indices, g.lower_indptr)).toarray()
    array([[ 2.,  0.,  0.],
           [ 2.,  6.,  0.],
           [ 0.,  3., 10.]])
    """

    def __init__(self, A: sp.csc_matrix) -> None:
        n = A.shape[1]
        self.shape = A.shape
        self.structure = (A.indptr.copy(), A.indices.copy())
        is_dense = np.bincount(A.indices, minlength=A.shape[0]) > DENSE_ROW_MIN
        self.dense = np.flatnonzero(is_dense)
        # the stored entries of the other rows, and their column pointers
        self.sparse_entries = ~is_dense[A.indices] if self.dense.size else None
        A = self._sparse_rows(A)
        S = sp.csc_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape)
        # (products of ones plus I: nothing cancels; the pattern is structural, the diagonal stored)
        P = (S.T @ S + sp.identity(n, format="csc")).tocsc()
        P.sort_indices()
        self.indptr, self.indices = P.indptr, P.indices
        self.keys = self._keys(P.indptr, P.indices, n)
        self.diag = np.searchsorted(self.keys, np.arange(n, dtype=np.int64) * (n + 1))
        cols = np.repeat(np.arange(n), np.diff(P.indptr))
        low = P.indices >= cols  # a sorted column's lower part: its diagonal, then the rows below
        self.low = np.flatnonzero(low)
        self.lower_indices = P.indices[low]
        self.lower_indptr = np.r_[0, np.cumsum(np.bincount(cols[low], minlength=n))]
        self.products = self._products(A)

    def _products(self, A: sp.csc_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The products ``A_ri A_rj`` that make up ``AᵀA``, as pairs of stored entries of ``A``
        and the pattern slot each adds to, ordered by ``r`` as scipy's product adds them (so the
        sums are the same to the last bit); None above :data:`GRAM_PRODUCTS_MAX` pairs."""
        n = self.shape[1]
        rows = A.indices
        per_row = np.bincount(rows, minlength=A.shape[0]).astype(np.int64)
        total = int(per_row @ per_row)
        if total > GRAM_PRODUCTS_MAX:
            return None
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(A.indptr))
        by_row = np.lexsort((cols, rows))  # the stored entries row by row
        start = np.r_[0, np.cumsum(per_row)[:-1]]
        k = np.repeat(per_row, per_row * per_row)  # each row's k² pairs (a, b), a-major
        t = np.arange(total) - np.repeat(np.r_[0, np.cumsum(per_row * per_row)[:-1]], per_row * per_row)
        first = by_row[np.repeat(start, per_row * per_row) + t // np.maximum(k, 1)]
        second = by_row[np.repeat(start, per_row * per_row) + t % np.maximum(k, 1)]
        slot = np.searchsorted(self.keys, cols[second] * n + cols[first])
        return first, second, slot

    @staticmethod
    def _keys(indptr: np.ndarray, indices: np.ndarray, n: int) -> np.ndarray:
        return np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr)) * n + indices

    def matches(self, A: sp.csc_matrix) -> bool:
        """Whether ``A`` has this structure (same shape, same stored positions)."""
        return (A.shape == self.shape and np.array_equal(A.indptr, self.structure[0])
                and np.array_equal(A.indices, self.structure[1]))

    def _sparse_rows(self, A: sp.csc_matrix) -> sp.csc_matrix:
        """``A`` without the entries of its dense rows (``A`` itself when it has none)."""
        if self.sparse_entries is None:
            return A
        keep = self.sparse_entries
        cols = np.repeat(np.arange(A.shape[1]), np.diff(A.indptr))
        indptr = np.r_[0, np.cumsum(np.bincount(cols[keep], minlength=A.shape[1]))]
        return sp.csc_matrix((A.data[keep], A.indices[keep], indptr), shape=A.shape)

    def dense_part(self, A: sp.csc_matrix) -> sp.csr_matrix | None:
        """The dense rows of ``A`` (``k × n``, CSR), or None when it has none."""
        return sp.csr_matrix(A)[self.dense] if self.dense.size else None

    def gram(self, A: sp.csc_matrix, shift: float = 0.0) -> sp.csc_matrix:
        """``AᵀA + shift·I`` on the pattern (``A`` must match it), without the dense rows."""
        n = self.shape[1]
        A = self._sparse_rows(A)
        if self.products is not None:  # (each slot's products summed in scipy's order)
            first, second, slot = self.products
            data = np.bincount(slot, weights=A.data[first] * A.data[second],
                               minlength=self.indices.size).astype(np.float64, copy=False)  # (int64 when empty)
            data[self.diag] += shift
            return sp.csc_matrix((data, self.indices, self.indptr), shape=(n, n))
        Q = (A.T @ A).tocsc()
        Q.sort_indices()
        data = np.zeros(self.indices.size)
        data[np.searchsorted(self.keys, self._keys(Q.indptr, Q.indices, n))] = Q.data
        data[self.diag] += shift
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(n, n))

    def lower(self, data: np.ndarray) -> np.ndarray:
        """The lower triangle's entries of a matrix on this pattern, given its ``data``."""
        return data[self.low]


class SplitGram:
    """``Q = Q_s + UᵀU``: a sparse Gram matrix ``Q_s`` and the dense rows ``U`` (``k × n``) of
    :class:`GramPattern`, applied without forming ``UᵀU``. Supports ``Q @ x`` and ``shape``."""

    def __init__(self, sparse: sp.csc_matrix, dense: sp.csr_matrix) -> None:
        self.sparse, self.dense, self.shape = sparse, dense, sparse.shape

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        return self.sparse @ x + self.dense.T @ (self.dense @ x)


#: Most refinement steps of :meth:`LowRankUpdatedFactor.solve`.
REFINE_MAX = 8


class LowRankUpdatedFactor:
    """Solves ``(M + UᵀU) x = r`` from a factor of the sparse SPD ``M`` and the few dense rows
    ``U`` (``k × n``) by the Sherman–Morrison–Woodbury formula,
    ``x = M⁻¹r − Z (I + U Z)⁻¹ U M⁻¹r`` with ``Z = M⁻¹Uᵀ`` (``k`` solves, an ``n × k`` block
    and a ``k × k`` matrix: memory linear in ``n``), followed by iterative refinement on the
    true matrix: where ``M`` is nearly singular (a proximal term of 1e-12) the formula cancels
    digits, and each refinement step wins them back.

    Parameters
    ----------
    factor
        Factor of ``M`` with ``solve`` (:class:`SPDFactor`).
    apply_m
        ``x -> M x``.
    dense
        ``U``, the dense rows.
    """

    def __init__(self, factor: SPDFactor, apply_m, dense: sp.csr_matrix) -> None:
        self.factor, self.dense = factor, dense
        self._apply_m = apply_m
        self._Z = np.asarray(factor.solve(dense.T.toarray())).reshape(dense.shape[1], dense.shape[0])
        self._C = cho_factor(np.eye(dense.shape[0]) + dense @ self._Z)
        self.backend = factor.backend

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``(M + UᵀU) x``."""
        return self._apply_m(x) + self.dense.T @ (self.dense @ x)

    def _woodbury(self, r: np.ndarray) -> np.ndarray:
        y = self.factor.solve(r)
        return y - self._Z @ cho_solve(self._C, self.dense @ y)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        r = np.asarray(rhs, dtype=float)
        x = self._woodbury(r)
        res = r - self.apply(x)
        size = float(np.linalg.norm(res))
        for _ in range(REFINE_MAX):  # while a step shrinks the residual at least twofold
            x_new = x + self._woodbury(res)
            res_new = r - self.apply(x_new)
            new = float(np.linalg.norm(res_new))
            if not new < size:
                break
            x, res, shrunk, size = x_new, res_new, new < 0.5 * size, new
            if not shrunk or size == 0.0:
                break
        return x
