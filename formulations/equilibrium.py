"""Equilibrium constraints (paper eqs. 2, 3), stated once: symbolically in CasADi and in their
sparse numeric form.

At every free (non-support) vertex ``i``

    r_i = Σ_j w_ij (v_j − v_i) − (0, 0, L_i) = 0,        L_i = A_i F_i (negative = down),

with ``w_ij ≥ 0`` meaning compression. The unknowns are the free positions ``X`` (flattened,
entry ``3 k + c`` is coordinate ``c`` of the ``k``-th free vertex) and the weights ``w`` of
the active edges (``Topology.edges``); the support positions and the loads are parameters.

* :class:`Equilibrium` — the CasADi statement (IPOPT, nlopt, sensitivities);
* :func:`weight_matrix`, :func:`position_blocks`, :func:`residual` … — the same residual as
  scipy matrices for the numeric methods: with positions fixed it is linear in the weights,
  ``r = A(V) w − b``; with weights fixed it is linear in the positions, ``r = K(w) V − b``.

Both use the row order ``3 k + c``, so ``∂r/∂w = A(V)`` and ``∂r/∂X = K_ff ⊗ I₃``; the tests
check the CasADi Jacobians against these matrices.

Example
-------
>>> import numpy as np
>>> top = Topology.build(3, np.array([[0, 1], [1, 2]]), np.array([True, False, True]))
>>> eq = Equilibrium(top, symbol="SX")
>>> sorted(eq.groups)
['equilibrium_x', 'equilibrium_y', 'equilibrium_z']
>>> X, w, V_sup, L = [0.5, 0, -1.0], [1.0, 1.0], [0, 0, 0, 1, 0, 0.], [0.0]
>>> eq.residual_function()(X, w, V_sup, L).full().ravel().tolist()
[0.0, 0.0, 2.0]
>>> V = np.array([[0, 0, 0], [0.5, 0, -1.0], [1, 0, 0]])
>>> residual(top, V, np.array([1.0, 1.0]), np.zeros(3)).tolist()
[[0.0, 0.0, 2.0]]
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from selfsupport.core.errors import InputError
from selfsupport.core.lazy import lazy_module

ca = lazy_module("casadi")  # (imported when first used: a plain staggered solve never is)

#: Symbol types a formulation can be built with (MX: fast to build for large graphs; SX:
#: scalar graphs, handy for small Jacobian checks).
SYMBOLS = ("MX", "SX")

#: Names of the constraint groups, one per coordinate; group ``c`` holds rows ``c::3``.
GROUP_NAMES = ("equilibrium_x", "equilibrium_y", "equilibrium_z")


def symbol_type(symbol: str | type) -> type:
    """``"MX"``/``"SX"`` (or the class itself) -> the CasADi symbol class."""
    if isinstance(symbol, str):
        if symbol.upper() not in SYMBOLS:
            raise InputError(f"unknown CasADi symbol type {symbol!r}; use one of {sorted(SYMBOLS)}")
        return getattr(ca, symbol.upper())
    if symbol in (ca.MX, ca.SX):
        return symbol
    raise InputError(f"unknown CasADi symbol type {symbol!r}; use one of {sorted(SYMBOLS)}")


def to_dm(a: sp.spmatrix) -> ca.DM:
    """Sparse scipy matrix -> sparse CasADi DM (keeps the sparsity pattern)."""
    return ca.DM(sp.csc_matrix(a))


def flat_selection(rows: np.ndarray, n: int) -> sp.csr_matrix:
    """``(3 len(rows), 3 n)`` matrix picking the 3 coordinates of vertices ``rows`` from a flat vector."""
    rows = np.asarray(rows, np.int64)
    r = np.arange(3 * len(rows))
    c = (3 * rows[:, None] + np.arange(3)).ravel()
    return sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(3 * len(rows), 3 * n))


# ---------------------------------------------------------------- numeric form (scipy)
@dataclass(frozen=True, eq=False)
class Topology:
    """Index bookkeeping shared by every assembly: free vertices and active edges."""

    n: int
    edges: np.ndarray  # (m, 2) active edges only
    free: np.ndarray  # bool (n,)
    free_index: np.ndarray  # (n,) position among free vertices, -1 for supports

    @classmethod
    def build(cls, n: int, edges: np.ndarray, supports: np.ndarray) -> "Topology":
        free = ~np.asarray(supports, bool)
        fi = -np.ones(n, dtype=np.int64)
        fi[free] = np.arange(int(free.sum()))
        return cls(n=n, edges=np.asarray(edges, np.int64), free=free, free_index=fi)

    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    @property
    def m(self) -> int:
        return int(self.edges.shape[0])

    @cached_property
    def weight_pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The CSC structure of :func:`weight_matrix` (sorted row indices, the layout scipy's
        COO conversion gives) and the order that takes its entries, listed end by end and
        coordinate by coordinate as :meth:`weight_entries` gives them, into it: ``(indptr,
        indices, order)``, 32-bit indices where they fit. Built once; each assembly orders values."""
        rows, cols = [], []
        k = np.arange(self.m)
        for end in (0, 1):
            fi = self.free_index[self.edges[:, end]]
            ok = fi >= 0
            for c in range(3):
                rows.append(3 * fi[ok] + c)
                cols.append(k[ok])
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        index = np.int32 if max(3 * self.n_free, rows.size) < np.iinfo(np.int32).max else np.int64
        order = np.lexsort((rows, cols)).astype(index)
        indptr = np.r_[0, np.cumsum(np.bincount(cols, minlength=self.m))].astype(index)
        return indptr, rows[order].astype(index), order

    def weight_entries(self, vertices: np.ndarray) -> np.ndarray:
        """The entries of :func:`weight_matrix` listed end by end (``v_j − v_i`` where the edge's
        first end is free, then ``v_i − v_j`` where its second is), each as x, y, z blocks."""
        e = self.edges
        d = vertices[e[:, 1]] - vertices[e[:, 0]]
        vals = []
        for end, sign in ((0, 1.0), (1, -1.0)):
            ok = self.free_index[e[:, end]] >= 0
            vals += [sign * d[ok, c] for c in range(3)]
        return np.concatenate(vals)

    @cached_property
    def laplacian_pattern(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], np.ndarray]:
        """The structures of :func:`position_blocks`' ``K_ff`` and ``K_fs`` (CSR ``(indptr,
        indices, source)``: entry ``source`` of ``[w, w, −Σ_j w_ij]``, the edges in both
        directions, then the diagonal) and the permutation that orders ``[w, w]`` as the CSR
        data of the weight graph (whose row sums are the diagonal). Built once."""
        e, n, m = self.edges, self.n, self.m
        ids = np.arange(1, 2 * m + 1, dtype=float)  # (exact identifiers: no duplicates to sum)
        W = sp.coo_matrix((ids, (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
        L = (W + sp.diags(2 * m + 1 + np.arange(n, dtype=float))).tocsr()[self.free]
        Kff, Kfs = L[:, self.free].tocsr(), L[:, ~self.free].tocsr()
        index = np.int32 if 2 * m + n < np.iinfo(np.int32).max else np.int64
        blocks = tuple((K.indptr.copy(), K.indices.copy(), (K.data - 1).astype(index)) for K in (Kff, Kfs))
        return blocks[0], blocks[1], (W.indptr.copy(), W.indices.copy(), (W.data - 1).astype(index))


def weight_matrix(top: Topology, vertices: np.ndarray) -> sp.csc_matrix:
    """``A(V)``, shape ``(3 n_free, m)``: column ``k`` holds ``v_j − v_i`` at free ``i`` and
    ``v_i − v_j`` at free ``j`` for edge ``k = (i, j)``. The structure is the topology's
    (:attr:`Topology.weight_pattern`); only the values are computed here."""
    indptr, indices, order = top.weight_pattern
    return sp.csc_matrix((top.weight_entries(vertices)[order], indices, indptr), shape=(3 * top.n_free, top.m))


def load_vector(top: Topology, loads: np.ndarray) -> np.ndarray:
    """``b``: ``(0, 0, A_i F_i)`` stacked over free vertices (or the rows of ``(n, 3)`` loads with
    horizontal components)."""
    loads = np.asarray(loads, float)
    if loads.ndim == 2:
        return loads[top.free].ravel()
    b = np.zeros((top.n_free, 3))
    b[:, 2] = loads[top.free]
    return b.ravel()


def stress_laplacian(top: Topology, weights: np.ndarray) -> sp.csr_matrix:
    """``L_w`` (n × n): ``(L_w f)_i = Σ_j w_ij (f_j − f_i)`` — the stress Laplacian Δ_φ."""
    e = top.edges
    n = top.n
    W = sp.coo_matrix((np.r_[weights, weights], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    return (W - sp.diags(np.asarray(W.sum(axis=1)).ravel())).tocsr()


def position_blocks(top: Topology, weights: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Rows of ``L_w`` at free vertices, split into free columns ``K_ff`` and support columns ``K_fs``.

    Per coordinate, the residual at free vertices is ``K_ff X_free + K_fs X_sup − b_c``. The
    structures are the topology's (:attr:`Topology.laplacian_pattern`), the values those of
    :func:`stress_laplacian`; a zero weight or row sum, which that drops from the structure,
    takes its path.
    """
    weights = np.asarray(weights, float)
    ff, fs, (w_ptr, w_idx, w_src) = top.laplacian_pattern
    both = np.r_[weights, weights]
    W = sp.csr_matrix((both[w_src], w_idx, w_ptr), shape=(top.n, top.n))
    src = np.r_[both, -np.asarray(W.sum(axis=1)).ravel()]
    if not np.all(src):
        L = stress_laplacian(top, weights)[top.free]
        return L[:, top.free].tocsr(), L[:, ~top.free].tocsr()
    nf = top.n_free
    return tuple(sp.csr_matrix((src[source], indices, indptr), shape=(nf, cols))
                 for (indptr, indices, source), cols in ((ff, nf), (fs, top.n - nf)))


def residual(top: Topology, vertices: np.ndarray, weights: np.ndarray, loads: np.ndarray) -> np.ndarray:
    """``(n_free, 3)`` residual of (2)-(3) at free vertices."""
    return (weight_matrix(top, vertices) @ weights - load_vector(top, loads)).reshape(-1, 3)


def block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """The (3k × 3k) block-diagonal matrix of ``k`` 3×3 ``blocks`` (one per free vertex)."""
    k = blocks.shape[0]
    rows = (3 * np.arange(k)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
    cols = (3 * np.arange(k)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * k, 3 * k))


# ---------------------------------------------------------------- bounds
@dataclass(frozen=True)
class WeightBounds:
    """``lower ≤ w ≤ upper`` for the active edges; scalars broadcast, ``upper=None`` is +∞; a
    negative ``lower`` allows tension."""

    lower: float | np.ndarray
    upper: float | np.ndarray | None = None

    def arrays(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        lo = np.broadcast_to(np.asarray(self.lower, float), (m,)).copy()
        up = np.full(m, np.inf) if self.upper is None else np.broadcast_to(np.asarray(self.upper, float), (m,)).copy()
        if np.any(~np.isfinite(lo)):
            raise InputError("the lower weight bound must be finite (negative: tension allowed down to it)")
        if np.any(up < lo):
            k = int(np.argmax(up < lo))
            raise InputError(f"w_max ({up[k]:.3g}) is below the lower bound ({lo[k]:.3g}) on active edge {k}; "
                             "raise w_max or lower eps")
        return lo, up


@dataclass(eq=False)
class Equilibrium:
    """Symbols and the residual of (2)-(3) for one topology.

    Attributes (CasADi symbols of type ``symbol``):
    ``X`` (3 n_free), ``w`` (m), ``V_sup`` (3 n_sup, support positions, flattened),
    ``L`` (n_free loads at the free vertices).
    """

    topology: Topology
    symbol: str | type = "MX"
    X: object = field(init=False)
    w: object = field(init=False)
    V_sup: object = field(init=False)
    L: object = field(init=False)

    def __post_init__(self) -> None:
        S = symbol_type(self.symbol)
        top = self.topology
        self.X = S.sym("X", 3 * top.n_free)
        self.w = S.sym("w", top.m)
        self.V_sup = S.sym("V_sup", 3 * (top.n - top.n_free))
        self.L = S.sym("L", top.n_free)

    # ---------------------------------------------------------------- constant matrices
    @cached_property
    def free_vertices(self) -> np.ndarray:
        return np.flatnonzero(self.topology.free)

    @cached_property
    def support_vertices(self) -> np.ndarray:
        return np.flatnonzero(~self.topology.free)

    @cached_property
    def _matrices(self) -> dict[str, sp.csr_matrix]:
        top = self.topology
        n, m = top.n, top.m
        e = top.edges
        Pf = flat_selection(self.free_vertices, n).T.tocsr()  # (3n, 3nf)
        Ps = flat_selection(self.support_vertices, n).T.tocsr()
        # edge differences d[3k + c] = v_j[c] − v_i[c]
        k3 = (3 * np.arange(m)[:, None] + np.arange(3)).ravel()
        ci = (3 * e[:, 0][:, None] + np.arange(3)).ravel()
        cj = (3 * e[:, 1][:, None] + np.arange(3)).ravel()
        D = sp.csr_matrix((np.r_[-np.ones(3 * m), np.ones(3 * m)], (np.r_[k3, k3], np.r_[ci, cj])),
                          shape=(3 * m, 3 * n))
        # assembly at free vertices: +f at end i, −f at end j
        fi = top.free_index
        rows, cols, vals = [], [], []
        for end, sign in ((0, 1.0), (1, -1.0)):
            idx = fi[e[:, end]]
            ok = idx >= 0
            r = (3 * idx[ok][:, None] + np.arange(3)).ravel()
            c = (3 * np.flatnonzero(ok)[:, None] + np.arange(3)).ravel()
            rows.append(r)
            cols.append(c)
            vals.append(np.full(len(r), sign))
        B = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * top.n_free, 3 * m))
        R = sp.csr_matrix((np.ones(3 * m), (np.arange(3 * m), np.repeat(np.arange(m), 3))), shape=(3 * m, m))
        Z = sp.csr_matrix((np.ones(top.n_free), (3 * np.arange(top.n_free) + 2, np.arange(top.n_free))),
                          shape=(3 * top.n_free, top.n_free))
        return {"Pf": Pf, "Ps": Ps, "Df": (D @ Pf).tocsr(), "Ds": (D @ Ps).tocsr(), "B": B, "R": R, "Z": Z}

    # ---------------------------------------------------------------- expressions
    def all_positions(self, X=None, V_sup=None):
        """Flattened positions of all vertices (3 n), free from ``X``, supports from ``V_sup``."""
        M = self._matrices
        X = self.X if X is None else X
        V_sup = self.V_sup if V_sup is None else V_sup
        return ca.mtimes(to_dm(M["Pf"]), X) + ca.mtimes(to_dm(M["Ps"]), V_sup)

    def residual(self, X=None, w=None, V_sup=None, L=None):
        """Flattened residual (3 n_free), row ``3 k + c`` = coordinate ``c`` at free vertex ``k``."""
        M = self._matrices
        X = self.X if X is None else X
        w = self.w if w is None else w
        V_sup = self.V_sup if V_sup is None else V_sup
        L = self.L if L is None else L
        d = ca.mtimes(to_dm(M["Df"]), X) + ca.mtimes(to_dm(M["Ds"]), V_sup)
        f = ca.mtimes(to_dm(M["R"]), w) * d
        return ca.mtimes(to_dm(M["B"]), f) - ca.mtimes(to_dm(M["Z"]), L)

    @property
    def groups(self) -> dict[str, np.ndarray]:
        """Constraint group name -> row indices in the flattened residual."""
        nf = self.topology.n_free
        return {name: 3 * np.arange(nf) + c for c, name in enumerate(GROUP_NAMES)}

    def split(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """Split a flattened per-row vector (residual, multipliers) into the named groups."""
        v = np.asarray(values).ravel()
        return {name: v[idx] for name, idx in self.groups.items()}

    # ---------------------------------------------------------------- functions
    def residual_function(self) -> ca.Function:
        """``residual(X, w, V_sup, L) -> r``."""
        return ca.Function("residual", [self.X, self.w, self.V_sup, self.L], [self.residual()],
                           ["X", "w", "V_sup", "L"], ["r"])

    def jacobian_functions(self) -> dict[str, ca.Function]:
        """``{"X": dr/dX, "w": dr/dw, "V_sup": dr/dV_sup}``, each a function of ``(X, w, V_sup, L)``."""
        r = self.residual()
        args = [self.X, self.w, self.V_sup, self.L]
        names = ["X", "w", "V_sup", "L"]
        return {k: ca.Function(f"jac_r_{k}", args, [ca.jacobian(r, s)], names, [f"dr_d{k}"])
                for k, s in (("X", self.X), ("w", self.w), ("V_sup", self.V_sup))}
