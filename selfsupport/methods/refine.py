"""Refinement: from a network in equilibrium, move it closer to the reference while keeping it
in equilibrium — sequential quadratic programming on the simultaneous problem

    minimise   Σ_i (v_i − p_i)ᵀ (n_i n_iᵀ + τ (I − n_i n_iᵀ)) (v_i − p_i)
    subject to equilibrium (2)-(3) at every free vertex,   lower ≤ w ≤ upper

(``p_i``, ``n_i``: closest point on the reference and its normal, re-projected every step; the
same anchor as the staggered method's Step 3). The staggered iteration follows a penalty path
with one linearized step per α, and the network it ends in has drifted from the reference by up
to 3× more than the simultaneous optimum (structural, twocirc-3: DESIGN.md's IPOPT runs); this
phase walks back along the equilibrium manifold.

One step linearizes the equilibrium residual ``r(X, w) = A(X) w − b(L(X))`` (rows scaled by
``1 / |L_i|`` as everywhere) in the free positions — stress Laplacian ``K(w) ⊗ I₃`` minus the
load Jacobian ``∂L/∂X`` (coloured finite differences) — and in the weights not at a bound
(``A(X)``), and solves

    min  ½ Δxᵀ W Δx + gᵀ Δx + ½ ρ Σ_j (Δw_j / w_j)²     s.t.   C_x Δx + C_w Δw = −r

through its Schur complement ``C_x W⁻¹ C_xᵀ + C_w R⁻¹ C_wᵀ`` (SPD, 3 n_free square, one
CHOLMOD factorization). ``ρ`` bounds the relative weight change: a trust region, divided by 3
after an accepted step and multiplied by 10 after a rejected one. Weights the step would carry
across a bound are clamped to it and stay there (cutting the whole step at the first bound
crawled, one weight per step); bounded weights whose multiplier pulls them inward are released
(and the step solved again with them free).
The trial is polished to exact equilibrium (Newton,
:mod:`~selfsupport.methods.polish`) and accepted when it is in equilibrium to ``tol`` and its
mean distance to the reference is smaller (in equilibrium to half of ``tol``: the caller rebuilds
the network in SI units, which costs a little round-off, and keeps it only within ``tol``).

Written here: no available sparse solver does SQP with this structure (IPOPT solves the same
problem from scratch: DESIGN.md §2 has its times and failures).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..evidence import closest_points
from ..linalg import spd_factor
from ..loads import LoadCase
from formulations.equilibrium import Topology, block_diagonal, load_vector, position_blocks, residual, weight_matrix
from .polish import _load_colouring, _load_jacobian, polish
from formulations.scaling import Scaling


@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`refine` (scaled units)."""

    X: np.ndarray
    w: np.ndarray
    L: np.ndarray
    steps: int  # accepted steps
    tried: int  # linearized steps solved (accepted or not)
    history: tuple[dict, ...]  # one record per tried step


def refine(top: Topology, X: np.ndarray, w: np.ndarray, loads: LoadCase, mesh0, sc: Scaling, reference,
           lower: np.ndarray, upper: np.ndarray, *, max_steps: int, tau: float = 0.05, tol: float = 1e-9,
           rho0: float = 1e-6, min_gain: float = 1e-2, deadline: float = np.inf,
           workspace: dict | None = None) -> Refinement:
    """Refine the network ``(X, w)`` (in equilibrium, scaled units) towards ``reference``.

    Stops after ``max_steps`` tried steps, when an accepted step gains less than ``min_gain`` of
    the mean distance, after 6 rejected steps in a row, or at ``deadline``
    (``time.perf_counter()``). The result is in equilibrium with loads of its own geometry (the
    polish's accuracy) whenever ``steps > 0``, else it is the input.
    """
    ws = workspace if workspace is not None else {}
    free = top.free
    if "colouring" not in ws and loads.depends_on_geometry:
        ws["colouring"] = _load_colouring(mesh0, free)
    L = sc.load(loads.nodal(mesh0, sc.pos_back(X)))
    P, d, N = closest_points(X, reference)
    dist = float(d.mean())
    rho, lin, rejected = rho0, None, 0
    steps, history = 0, []
    for tried in range(1, max_steps + 1):
        if time.perf_counter() > deadline:
            break
        if lin is None:  # the linearization at the current network (kept while steps are rejected)
            lin = _linearize(top, X, w, L, P, N, loads, mesh0, sc, tau, ws.get("colouring"))
        dx, dw = _sqp_step(lin, w, lower, upper, rho)
        # the full step, weights that would cross a bound clamped to it (they stay fixed next
        # step; cutting the step at the first bound instead crawled, one weight per step)
        wt = np.clip(w + dw, lower, upper)
        Xt = X.copy()
        Xt[free] += dx
        Xp, Lp, _ = polish(top, Xt, wt, loads, mesh0, sc, workspace=ws, fallbacks=False)
        ok = bool(np.all(np.isfinite(Xp)))
        err = float((np.linalg.norm(residual(top, Xp, wt, Lp), axis=1) / np.abs(Lp[free])).max()) if ok else np.inf
        Pp, dp, Np = closest_points(Xp, reference) if ok else (None, np.full(1, np.inf), None)
        new = float(dp.mean())
        accepted = err <= 0.5 * tol and new < dist  # (margin: the caller rebuilds the network in SI units)
        history.append({"step": tried, "rho": rho, "clamped": int(np.sum(wt != w + dw)), "error": err,
                        "dist_mean": new, "accepted": accepted})
        if not accepted:
            rho *= 10.0  # a smaller step
            rejected += 1
            if rejected >= 6:
                break
            continue
        gain = 1.0 - new / dist
        X, w, L, P, N, dist = Xp, wt, Lp, Pp, Np, new
        lin, rejected = None, 0
        steps += 1
        rho = max(rho / 3.0, 1e-12)  # accepted: a larger step next (÷10 alternated accept / reject)
        if gain < min_gain:
            break
    return Refinement(X=X, w=w, L=L, steps=steps, tried=len(history), history=tuple(history))


def _sqp_step(lin: tuple, w: np.ndarray, lower: np.ndarray, upper: np.ndarray, rho: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """The step ``(Δx (n_free, 3), Δw)`` of the equality-constrained QP in the module docstring
    through the Schur complement of its KKT system. Weights at a bound are held there unless
    their multiplier pulls them inward; those are released and the QP solved again with them
    free, so the step satisfies the linearized constraint."""
    Cx, A, r, g, Winv = lin
    free_w = (w > lower) & (w < upper)
    CWC = Cx @ Winv @ Cx.T  # the positions' part of the Schur complement (the same for both attempts)
    rhs = r - Cx @ (Winv @ g)
    for attempt in range(2):  # (a second release is left to the next step)
        Cw = A[:, free_w]
        Rinv = sp.diags(w[free_w] ** 2 / rho)
        M = (CWC + Cw @ Rinv @ Cw.T).tocsc()
        lam = spd_factor(M).solve(rhs)
        pull = -(A.T @ lam) * w ** 2 / rho  # the step of each weight, were it free
        release = ~free_w & (((w <= lower) & (pull > 0)) | ((w >= upper) & (pull < 0)))
        if attempt or not release.any():
            break
        free_w = free_w | release
    dx = -(Winv @ (g + Cx.T @ lam)).reshape(-1, 3)
    dw = np.where(free_w, pull, 0.0)
    return dx, dw


def _linearize(top: Topology, X: np.ndarray, w: np.ndarray, L: np.ndarray, P: np.ndarray, N: np.ndarray,
               loads: LoadCase, mesh0, sc: Scaling, tau: float, colouring: tuple | None):
    """The step's data at ``(X, w)``: the scaled constraint Jacobians ``C_x`` (positions) and
    ``A`` (all weights), the scaled residual, the objective's gradient and ``W⁻¹``."""
    free = top.free
    s = np.repeat(1.0 / np.abs(L[free]), 3)
    n = N[free]
    nn = n[:, :, None] * n[:, None, :]
    Wb = tau * np.eye(3)[None] + (1 - tau) * nn
    Winv = block_diagonal(nn + (np.eye(3)[None] - nn) / tau)  # W⁻¹ = n nᵀ + (I − n nᵀ) / τ
    g = np.einsum("kij,kj->ki", Wb, X[free] - P[free]).ravel()
    Kff, _ = position_blocks(top, w)
    Cx = sp.kron(Kff, sp.identity(3), format="csr")
    if loads.depends_on_geometry:
        Cx = Cx - _load_jacobian_xyz(loads, mesh0, sc, X, L, np.flatnonzero(free), colouring)
    S = sp.diags(s)
    A = (S @ weight_matrix(top, X)).tocsc()
    return (S @ Cx).tocsr(), A, A @ w - s * load_vector(top, L), g, Winv


def _load_jacobian_xyz(loads: LoadCase, mesh0, sc: Scaling, X: np.ndarray, L: np.ndarray, fidx: np.ndarray,
                       colouring: tuple) -> sp.csr_matrix:
    """``∂L_free / ∂X_free`` placed in the z rows of the 3 n_free residual: the polish's
    coloured forward differences (:func:`~selfsupport.methods.polish._load_jacobian`) once per
    coordinate — a load depends on the positions of the vertices sharing a face with it, in x,
    y and z alike, so the colouring of ``dL/dz`` serves all three."""
    nf = fidx.size
    blocks = []
    for c in range(3):
        def loads_at(v: np.ndarray, c: int = c) -> np.ndarray:
            Xh = X.copy()
            Xh[fidx, c] = v
            return sc.load(loads.nodal(mesh0, sc.pos_back(Xh)))[fidx]

        blocks.append(_load_jacobian(loads_at, X[fidx, c], L[fidx], *colouring).tocoo())
    R = np.concatenate([3 * J.row + 2 for J in blocks])
    C = np.concatenate([3 * J.col + c for c, J in enumerate(blocks)])
    return sp.csr_matrix((np.concatenate([J.data for J in blocks]), (R, C)), shape=(3 * nf, 3 * nf))
