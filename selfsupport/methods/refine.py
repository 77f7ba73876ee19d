"""Refinement: from a network in equilibrium, lower the problem's objective while keeping it
in equilibrium — sequential quadratic programming on the simultaneous problem

    minimise   Σ_t μ_t ‖r_t(V)‖²                 (the problem's objective terms, formulations.terms)
    subject to equilibrium (2)-(3) at every free vertex,   lower ≤ w ≤ upper

(the same terms as the staggered method's Step 3, Gauss–Newton-linearized and re-projected
every step; by default the distance to the reference surface and a smooth displacement). The
staggered iteration follows a penalty path
with one linearized step per α, and the network it ends in has drifted from the reference by up
to 3× more than the simultaneous optimum (structural, twocirc-3: the IPOPT runs of docs/guide/methods.md); this
phase walks back along the equilibrium manifold.

One step linearizes the equilibrium residual ``r(X, w) = A(X) w − b(L(X))`` (rows scaled by
``1 / |L_i|`` as everywhere) in the free positions — stress Laplacian ``K(w) ⊗ I₃`` minus the
load Jacobian ``∂L/∂X`` (coloured finite differences) — and in the weights not at a bound
(``A(X)``), and solves

    min  ½ Δxᵀ W Δx + gᵀ Δx + ½ ρ Σ_j (Δw_j / w_j)²     s.t.   C_x Δx + C_w Δw = −r

(``W = Σ μ JᵀJ``, ``g = Σ μ Jᵀr`` from the terms) through its Schur complement
``C_x W⁻¹ C_xᵀ + C_w R⁻¹ C_wᵀ`` (SPD, 3 n_free square, one CHOLMOD factorization) when ``W`` is
3×3 block diagonal (terms whose rows each involve one vertex), else through the KKT system
(sparse LU). ``ρ`` bounds the relative weight change: a trust region, divided by 3
after an accepted step and multiplied by 10 after a rejected one. Weights the step would carry
across a bound are clamped to it and stay there (cutting the whole step at the first bound
crawled, one weight per step); bounded weights whose multiplier pulls them inward are released
(and the step solved again with them free).
The trial is polished to exact equilibrium (Newton,
:mod:`~selfsupport.methods.polish`) and accepted when it is in equilibrium to ``tol`` and its
objective is smaller (in equilibrium to half of ``tol``: the caller rebuilds
the network in SI units, which costs a little round-off, and keeps it only within ``tol``).

Written here: no available sparse solver does SQP with this structure (IPOPT solves the same
problem from scratch: docs/guide/methods.md has its times and failures).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, cg

from formulations.equilibrium import Topology, block_diagonal, load_vector, position_blocks, residual, weight_matrix
from formulations.scaling import Scaling
from formulations.terms import Term
from selfsupport.core.linalg import spd_factor
from selfsupport.core.loads import LoadCase
from selfsupport.methods.polish import load_colouring, load_jacobian_xyz, polish


@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`refine` (scaled units)."""

    X: np.ndarray
    w: np.ndarray
    L: np.ndarray
    steps: int  # accepted steps
    tried: int  # linearized steps solved (accepted or not)
    history: tuple[dict, ...]  # one record per tried step


def objective_value(objective: Term, X: np.ndarray, projection: tuple | None = None) -> tuple[Term, float]:
    """The objective re-linearized at ``X`` (closest points there) and its value at ``X``."""
    t = objective.at(X, projection)
    return t, t.numeric_value(X)


def refine(top: Topology, X: np.ndarray, w: np.ndarray, loads: LoadCase, mesh0, sc: Scaling, objective: Term,
           lower: np.ndarray, upper: np.ndarray, *, max_steps: int, tol: float = 1e-9, rho0: float = 1e-6,
           min_gain: float = 1e-2, deadline: float = np.inf, workspace: dict | None = None,
           progress: Callable[[dict], None] | None = None) -> Refinement:
    """Refine the network ``(X, w)`` (in equilibrium, scaled units) towards the optimum of
    ``objective`` (a :class:`~formulations.terms.Term` in the same units).

    Stops after ``max_steps`` tried steps, when two accepted steps in a row lower the objective by
    less than ``min_gain`` (relative) each, after 6 rejected steps in a row, or at
    ``deadline`` (``time.perf_counter()``). The result is in equilibrium with loads of its own
    geometry (the polish's accuracy) whenever ``steps > 0``, else it is the input. ``progress``
    gets one record per tried step (a step takes seconds on a large mesh).
    """
    ws = workspace if workspace is not None else {}
    free = top.free
    if "colouring" not in ws and loads.depends_on_geometry:
        ws["colouring"] = load_colouring(mesh0, free)
    L = sc.loads_at(loads, mesh0, X)
    obj, F = objective_value(objective, X)
    rho, lin, rejected, small = rho0, None, 0, 0
    steps, history = 0, []
    for tried in range(1, max_steps + 1):
        if time.perf_counter() > deadline:
            break
        if lin is None:  # the linearization at the current network (kept while steps are rejected)
            lin = _linearize(top, X, w, L, obj, loads, mesh0, sc, ws.get("colouring"))
        dx, dw = _sqp_step(lin, w, lower, upper, rho, ws)
        # the full step, weights that would cross a bound clamped to it (they stay fixed next
        # step; cutting the step at the first bound instead crawled, one weight per step)
        wt = np.clip(w + dw, lower, upper)
        Xt = X.copy()
        Xt[free] += dx
        Xp, Lp, _ = polish(top, Xt, wt, loads, mesh0, sc, workspace=ws, fallbacks=False,
                           deadline=None if np.isinf(deadline) else deadline)
        ok = bool(np.all(np.isfinite(Xp)))
        err = float((np.linalg.norm(residual(top, Xp, wt, Lp), axis=1) / np.abs(Lp[free])).max()) if ok else np.inf
        obj_p, F_p = objective_value(objective, Xp) if ok else (None, np.inf)
        accepted = err <= 0.5 * tol and F_p < F  # (margin: the caller rebuilds the network in SI units)
        history.append({"step": tried, "rho": rho, "clamped": int(np.sum(wt != w + dw)), "error": err,
                        "objective": F_p, "accepted": accepted})
        if progress:
            progress({"iteration": f"refine {tried}", "max_rel_error": err, "objective": F_p, "accepted": accepted})
        if not accepted:
            rho *= 10.0  # a smaller step
            rejected += 1
            if rejected >= 6:
                break
            continue
        gain = 1.0 - F_p / F if F > 0 else 0.0
        X, w, L, obj, F = Xp, wt, Lp, obj_p, F_p
        lin, rejected = None, 0
        steps += 1
        rho = max(rho / 3.0, 1e-12)  # accepted: a larger step next (÷10 alternated accept / reject)
        small = small + 1 if gain < min_gain else 0
        if small >= 2:  # (one small gain alone is no sign: a step of 0.1% preceded one of 41% on cas)
            break
    ws.pop("schur", None)  # (the Schur factor serves this run's steps only: free its memory)
    return Refinement(X=X, w=w, L=L, steps=steps, tried=len(history), history=tuple(history))


def _sqp_step(lin: tuple, w: np.ndarray, lower: np.ndarray, upper: np.ndarray, rho: float,
              workspace: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The step ``(Δx (n_free, 3), Δw)`` of the equality-constrained QP in the module docstring
    (Schur complement when ``W⁻¹`` is known, else the KKT system). Weights at a bound are held
    there unless their multiplier pulls them inward; those are released and the QP solved
    again with them free, so the step satisfies the linearized constraint. That second solve
    adds the released columns' low-rank term to the Schur complement: CG preconditioned by the
    first factor (:func:`_released_solve`), refactored only where CG does not settle.
    ``workspace`` keeps the factor between steps (one symbolic analysis while the pattern holds)."""
    Cx, A, r, g, W, Winv = lin
    free_w = (w > lower) & (w < upper)
    ws = workspace if workspace is not None else {}
    if Winv is not None:
        CWC = Cx @ Winv @ Cx.T  # the positions' part of the Schur complement (the same for both attempts)
        rhs = r - Cx @ (Winv @ g)
    factor = M = lam = release = None  # (the second attempt's: set by the first)
    for attempt in range(2):  # (a second release is left to the next step)
        Cw = A[:, free_w]
        Rinv = sp.diags(w[free_w] ** 2 / rho)
        if Winv is not None:
            if factor is not None:  # the released weights' columns added to the matrix just factored
                lam = _released_solve(factor, M, A[:, release], w[release] ** 2 / rho, rhs, lam)
            if factor is None or lam is None:
                M = (CWC + Cw @ Rinv @ Cw.T).tocsc()
                factor = ws["schur"] = spd_factor(M, reuse=ws.get("schur"))  # (the pattern seldom changes)
                lam = factor.solve(rhs)
        else:  # [W Cxᵀ; Cx −Cw R⁻¹ Cwᵀ] [Δx; λ] = [−g; −r]
            K = sp.bmat([[W, Cx.T], [Cx, -(Cw @ Rinv @ Cw.T)]], format="csc")
            sol = sp.linalg.splu(K).solve(-np.r_[g, r])
            lam = sol[W.shape[0]:]
        pull = -(A.T @ lam) * w ** 2 / rho  # the step of each weight, were it free
        release = ~free_w & (((w <= lower) & (pull > 0)) | ((w >= upper) & (pull < 0)))
        if attempt or not release.any():
            break
        free_w = free_w | release
    dx = (-(Winv @ (g + Cx.T @ lam)) if Winv is not None else sol[:W.shape[0]]).reshape(-1, 3)
    dw = np.where(free_w, pull, 0.0)
    return dx, dw


#: CG iterations a released weights' re-solve may take before the Schur complement is factored
#: again: the released columns are a low-rank change, which CG preconditioned by the first factor
#: settles in a few iterations, each far cheaper than a factorization.
RELEASE_CG_MAX = 8


def _released_solve(factor, M: sp.spmatrix, B: sp.spmatrix, d: np.ndarray, rhs: np.ndarray, x0: np.ndarray
                    ) -> np.ndarray | None:
    """``(M + B diag(d) Bᵀ) x = rhs`` by CG preconditioned with ``factor`` (of ``M``), from
    ``x0`` (``M``'s solution); None unless it comes within the direct solve's own residual on
    ``M`` (or 1e-12 of ``rhs``) in :data:`RELEASE_CG_MAX` iterations. ``B diag(d) Bᵀ`` is PSD
    of rank ≤ B's columns, so CG on the preconditioned system ends in that many + 1 steps
    (exact arithmetic)."""

    n = M.shape[0]
    op = LinearOperator((n, n), matvec=lambda x: M @ x + B @ (d * (B.T @ x)), dtype=float)
    target = max(float(np.linalg.norm(M @ x0 - rhs)), 1e-12 * float(np.linalg.norm(rhs)))
    x, _ = cg(op, rhs, x0=x0, rtol=0.0, atol=target, maxiter=RELEASE_CG_MAX,
              M=LinearOperator((n, n), matvec=factor.solve, dtype=float))
    ok = np.all(np.isfinite(x)) and float(np.linalg.norm(op @ x - rhs)) <= 2.0 * target
    return x if ok else None


def _linearize(top: Topology, X: np.ndarray, w: np.ndarray, L: np.ndarray, objective: Term, loads: LoadCase,
               mesh0, sc: Scaling, colouring: tuple | None):
    """The step's data at ``(X, w)``: the scaled constraint Jacobians ``C_x`` (positions) and
    ``A`` (all weights), the scaled residual, the objective's gradient ``g``, its Gauss–Newton
    matrix ``W`` and ``W⁻¹`` when ``W`` is 3×3 block diagonal (else ``None``)."""
    free = top.free
    fidx = np.flatnonzero(free)
    cols3 = (3 * fidx[:, None] + np.arange(3)).ravel()
    s = np.repeat(1.0 / np.abs(L[free]), 3)
    W, g, local = None, np.zeros(3 * top.n_free), True
    for t in objective.parts():
        r, J = t.linearize(X)
        Jf = J[:, cols3].tocsr()
        W = t.weight * (Jf.T @ Jf) if W is None else W + t.weight * (Jf.T @ Jf)
        g += t.weight * (Jf.T @ r)
        local &= bool(t.vertex_local)
    W = W.tocsr()
    Winv = None
    if local:  # 3×3 blocks: invert each (every free vertex must carry a vertex-local term)
        coo = W.tocoo()
        blocks = np.zeros((top.n_free, 3, 3))
        np.add.at(blocks, (coo.row // 3, coo.row % 3, coo.col % 3), coo.data)
        if np.all(np.linalg.eigvalsh(blocks)[:, 0] > 0):
            Winv = block_diagonal(np.linalg.inv(blocks))
    if Winv is None:  # a small shift keeps the KKT matrix regular where the objective is flat
        W = (W + sp.identity(W.shape[0]) * (1e-12 * float(W.diagonal().mean()))).tocsc()
    Kff, _ = position_blocks(top, w)
    Cx = sp.kron(Kff, sp.identity(3), format="csr")
    if loads.depends_on_geometry:
        Cx = Cx - load_jacobian_xyz(loads, mesh0, sc, X, L, fidx, colouring)
    S = sp.diags(s)
    A = (S @ weight_matrix(top, X)).tocsc()
    return (S @ Cx).tocsr(), A, A @ w - s * load_vector(top, L), g, W, Winv
