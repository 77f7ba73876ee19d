"""Sparse matrices of the equilibrium equations (2)-(3), built with scipy.

With positions fixed the residual is linear in the weights, ``r = A(V) w − b``; with
weights fixed it is linear in the positions, ``r = K(w) V − b``. Rows are ordered
``(free vertex, coordinate)``: row ``3 k + c`` is coordinate ``c`` of the ``k``-th free vertex.
``formulations.equilibrium`` states the same equations symbolically in CasADi; the tests
check that its Jacobians equal these matrices.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


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


def weight_matrix(top: Topology, vertices: np.ndarray) -> sp.csc_matrix:
    """``A(V)``, shape ``(3 n_free, m)``: column ``k`` holds ``v_j − v_i`` at free ``i`` and
    ``v_i − v_j`` at free ``j`` for edge ``k = (i, j)``."""
    e = top.edges
    d = vertices[e[:, 1]] - vertices[e[:, 0]]
    rows, cols, vals = [], [], []
    k = np.arange(top.m)
    for end, sign in ((0, 1.0), (1, -1.0)):
        fi = top.free_index[e[:, end]]
        ok = fi >= 0
        for c in range(3):
            rows.append(3 * fi[ok] + c)
            cols.append(k[ok])
            vals.append(sign * d[ok, c])
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(3 * top.n_free, top.m))


def load_vector(top: Topology, loads: np.ndarray) -> np.ndarray:
    """``b``: ``(0, 0, A_i F_i)`` stacked over free vertices."""
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

    Per coordinate, the residual at free vertices is ``K_ff X_free + K_fs X_sup − b_c``.
    """
    L = stress_laplacian(top, weights)[top.free]
    return L[:, top.free].tocsr(), L[:, ~top.free].tocsr()


def residual(top: Topology, vertices: np.ndarray, weights: np.ndarray, loads: np.ndarray) -> np.ndarray:
    """``(n_free, 3)`` residual of (2)-(3) at free vertices."""
    return (weight_matrix(top, vertices) @ weights - load_vector(top, loads)).reshape(-1, 3)


def block_diagonal(blocks: np.ndarray) -> sp.csr_matrix:
    """The (3k × 3k) block-diagonal matrix of ``k`` 3×3 ``blocks`` (one per free vertex)."""
    k = blocks.shape[0]
    rows = (3 * np.arange(k)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
    cols = (3 * np.arange(k)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * k, 3 * k))
