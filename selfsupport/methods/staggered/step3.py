"""Step 3: the positions' sparse SPD least-squares update with the weights held."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, cg

from formulations.equilibrium import Topology, block_diagonal, position_blocks
from formulations.terms import HullPenalty, PlaneDistance, Term
from selfsupport.core.linalg import spd_factor
from selfsupport.methods.deadline import DeadlineReached, out_of_time

#: Weight of the hull's face pins in Step 3, relative to the objective's unit (a quasi-equality).
HULL_PIN = 1e6
#: Conjugate gradients solve Step 3 for the step (not the positions) to this relative residual
#: (option ``step_rtol``), tighter than the step needs, for reproducibility: a pillar vault turned
#: by 0.3 rad gives the turned network to 2e-10 of its diagonal, at 1e-4 to 3e-7, past the 1e-7 of
#: tests/test_invariance.py. 1e-4 would about halve the CG iterations and save about 5% of the solve
#: (the median over the paper's scenes, ``python -m studies.step_tolerance``).
STEP_RTOL = 1e-7


def _hull_faces(hull: HullPenalty, X: np.ndarray, active: np.ndarray) -> Term:
    """Pins of the ``active`` vertices' normal coordinates to the hull face they are nearest (on
    the side ``X`` is on), as a plane-distance term of weight :data:`HULL_PIN`."""
    n = hull.normals[active]
    side = np.sign(np.einsum("ij,ij->i", n, X[active] - hull.points[active]))
    side[side == 0] = 1.0
    P, N = hull.points.copy(), hull.normals.copy()
    P[active] = hull.points[active] + (side * hull.half_thickness)[:, None] * n
    return PlaneDistance(points=P, normals=N, mask=active, weight=HULL_PIN)


def _into_hull(hull: HullPenalty, X: np.ndarray, *, fixed_xy: bool = False) -> np.ndarray:
    """``X`` with every hull vertex moved along its normal (or, with a fixed top view, vertically)
    onto the hull's face where it lies outside ``±h``."""
    s = hull.signed_distance(X)
    excess = s - np.clip(s, -hull.half_thickness, hull.half_thickness)
    out = np.flatnonzero(excess)
    if out.size == 0:
        return X
    X = X.copy()
    idx, n = hull.idx[out], hull.normals[hull.idx[out]]
    if fixed_xy:  # along z, by the amount that brings ⟨n, v − p⟩ back to ±h
        X[idx, 2] -= excess[out] / np.where(np.abs(n[:, 2]) > 1e-12, n[:, 2], np.inf)
    else:
        X[idx] -= excess[out][:, None] * n
    return X


def _term_model(objective: Term | None, X: np.ndarray, *, free: np.ndarray, alpha: float, c: float, ws: dict,
                pinned: Term | None = None) -> tuple[sp.csr_matrix | None, np.ndarray, np.ndarray, np.ndarray,
                                                     sp.csr_matrix | None, np.ndarray]:
    """The objective's Gauss–Newton model at ``X`` over the free positions, weighted by ``c α``
    (constraint terms by ``c``): ``Σ μ ‖r + J Δx‖²`` split into a per-coordinate matrix ``H₁``
    (terms acting on x, y, z alike) with right-hand side ``(k, 3)``, 3×3 blocks per free vertex
    (vertex-local terms) with their right-hand side, and a general part (3 nf square). The
    right-hand sides are those of the normal equations in absolute positions:
    ``JᵀJ X − Jᵀ r`` at the current ``X``."""
    nf = int(free.sum())
    H1, rhs1 = None, np.zeros((nf, 3))
    blocks, rhs3 = np.zeros((nf, 3, 3)), np.zeros((nf, 3))
    Gg, rhsg = None, np.zeros(3 * nf)
    if objective is None and pinned is None:
        return H1, rhs1, blocks, rhs3, Gg, rhsg
    objective = objective if objective is not None else pinned
    cols3 = (3 * np.flatnonzero(free)[:, None] + np.arange(3)).ravel()
    fi = np.cumsum(free) - 1
    fi[~free] = -1  # vertex -> free index
    Xf = X[free]
    fixed = set(map(id, pinned.parts())) if pinned is not None else set()
    for t in objective.parts() + (pinned.parts() if pinned is not None else ()):
        mu = c * t.weight * (1.0 if t.constraint or id(t) in fixed else alpha)
        if mu == 0.0:
            continue
        if not t.couples_xyz:
            r1, J1 = t.per_coordinate(X)
            cache = ws.setdefault("per_coordinate", {})
            if id(t) not in cache:  # these terms' Jacobians are constant: JᵀJ once per solve
                J1f = J1[:, free].tocsr()
                cache[id(t)] = (t, J1f, (J1f.T @ J1f).tocsr())
            _, J1f, JtJ = cache[id(t)]
            H1 = mu * JtJ if H1 is None else H1 + mu * JtJ
            rhs1 += mu * (J1f.T @ (J1f @ Xf - r1))
            continue
        if t.vertex_local:  # 3×3 blocks straight from the term (no sparse products per iteration)
            idx, B, b = t.vertex_blocks(X)
            k = fi[idx]
            on = k >= 0  # (rows at supports do not move anything)
            np.add.at(blocks, k[on], mu * B[on])
            np.add.at(rhs3, k[on], mu * b[on])
            continue
        r, J = t.linearize(X)
        Jf = J[:, cols3].tocsr()
        rhsg += mu * (Jf.T @ (Jf @ Xf.ravel() - r))
        JtJ = (Jf.T @ Jf).tocsr()
        Gg = mu * JtJ if Gg is None else (Gg + mu * JtJ).tocsr()
    return H1, rhs1, blocks, rhs3, Gg, rhsg


@dataclass(frozen=True)
class Coupling:
    """What the coupled Step 3 moves besides the positions: per load case, the scaled ``A`` at
    the iterate restricted to the weights off their bounds (``G``) and those weights' gaps to
    the lower bound; ``prox`` and ``damping`` weigh the proximal term and the hold on weights
    near their bound (relative to the mean diagonal of ``GᵀG``)."""

    G: list[sp.spmatrix]
    gap: list[np.ndarray]
    prox: float
    damping: float

    @property
    def moves(self) -> bool:
        """Any weight free to move (with every weight at a bound the coupled step is the plain one)."""
        return sum(g.shape[1] for g in self.G) > 0


def _stress_gram(top: Topology, X: np.ndarray, *, weights: list[np.ndarray], loads: np.ndarray) -> tuple:
    """The equilibrium part of Step 3 summed over the load cases: the Gram matrix ``H`` of the
    scaled stress Laplacians ``Kt = diag(1 / |L|) K_ff``, its right-hand side, the mean squared
    relative diagonal ``c`` (which turns relative residuals into lengths), and per case ``Kt``
    and the target of ``Kt X_free``."""
    free, nf = top.free, top.n_free
    H, rhs, cvals, Kts, targets = None, np.zeros((nf, 3)), [], [], []
    for w, Lc in zip(weights, loads):
        Kff, Kfs = position_blocks(top, w)
        s = 1.0 / np.abs(Lc[free])
        cvals.append(float(np.mean((-Kff.diagonal() * s) ** 2)))
        # rows scaled in place (the products diag(s) @ K_ff would form, without the sparse product)
        Kt = sp.csr_matrix((Kff.data * np.repeat(s, np.diff(Kff.indptr)), Kff.indices, Kff.indptr), shape=Kff.shape)
        B = np.zeros((nf, 3))
        B[:, 2] = Lc[free]
        target = s[:, None] * (B - Kfs @ X[~free])  # (nf, 3): target of Kt X_free
        H = (Kt.T @ Kt).tocsr() if H is None else (H + Kt.T @ Kt).tocsr()
        rhs += Kt.T @ target
        Kts.append(Kt)
        targets.append(target)
    return H, rhs, float(np.mean(cvals)), Kts, targets


def _heights(X: np.ndarray, free: np.ndarray, *, H: sp.spmatrix, blocks: np.ndarray, rhs: np.ndarray,
             Gg: sp.spmatrix | None, rhsg: np.ndarray, wsp: dict) -> np.ndarray:
    """Step 3 with a fixed top view: only the heights move, the zz part of the system
    ``M_zz z = rhs_z − M_z,xy x_xy`` with x, y held (H has no x-z coupling; blocks and G may)."""
    nf = int(free.sum())
    Xn = X.copy()
    Mz = (H + sp.diags(blocks[:, 2, 2])).tocsc()
    rz = rhs[:, 2] - np.einsum("kj,kj->k", blocks[:, 2, :2], X[free, :2])
    if Gg is not None:
        z3 = np.arange(nf) * 3 + 2
        xy = np.sort(np.r_[np.arange(nf) * 3, np.arange(nf) * 3 + 1])
        Gg = Gg.tocsr()
        Mz = (Mz + Gg[z3][:, z3]).tocsc()
        rz = rz + rhsg[z3] - Gg[z3][:, xy] @ X[free, :2].ravel()
    wsp["factor_z"] = spd_factor(Mz, reuse=wsp.get("factor_z"))
    Xn[free, 2] = wsp["factor_z"].solve(rz)
    return Xn


def _coupled_solve(M: sp.spmatrix, rhs: np.ndarray, *, Kts: list, targets: list, coupling: Coupling) -> np.ndarray:
    """The coupled step's positions: the weights not at a bound move with them (Gauss-Newton on
    the reduced error min_w E(X, w) rather than on E(X, w_k)), each load case its own; their
    moves only shape the position step (the trial is refitted exactly)."""
    off, diag, rhs_w = [], [], []
    for Kt, target, Gc, gc in zip(Kts, targets, coupling.G, coupling.gap):
        if Gc.shape[1] == 0:  # (every weight of this case at a bound)
            continue
        GtG = (Gc.T @ Gc).tocsr()
        mean = float(GtG.diagonal().mean())
        # weights near their bound may hardly move (an interior-point-like scaling), since the
        # refit will clamp them there
        gc = np.asarray(gc, float)
        pw = coupling.prox * mean + coupling.damping * mean * (np.median(gc) / gc) ** 2
        off.append(sp.kron(Kt, sp.identity(3), format="csr").T @ Gc)
        diag.append(GtG + sp.diags(pw))
        # the target of J x + G dw is the scaled target t (the current residual is J x_k − t)
        rhs_w.append(Gc.T @ target.ravel())
    C = len(off)
    N = sp.bmat([[M] + off] + [[off[c].T] + [diag[c] if d == c else None for d in range(C)] for c in range(C)],
                format="csc")
    sol = spd_factor(N).solve(np.concatenate([rhs, *rhs_w]))
    return sol[:M.shape[0]].reshape(-1, 3)


def _position_step(top: Topology, X: np.ndarray, *, weights: list[np.ndarray], loads: np.ndarray,
                   objective: Term | None, alpha: float, beta: float, coupling: Coupling | None = None,
                   workspace: dict | None = None, fixed_xy: bool = False, pinned: Term | None = None,
                   deadline: float | None = None, rtol: float = STEP_RTOL) -> np.ndarray:
    """Step 3: the SPD least-squares update of the free positions (see the package docstring).

    ``weights`` and ``loads`` hold one weight vector and one load vector per load case. The
    residual rows of each case are scaled by ``1 / |A_i F_i|`` as in the fit (so the step
    decreases the very error the fit measures); the penalties are multiplied by the mean of
    ``(d_i / |A_i F_i|)²``, which converts that relative residual into a length, so that the
    objective's weights, α and β compare lengths with lengths whatever the mesh resolution.

    The system is ``(H ⊗ I₃ + ⊕ B_i + G) x = rhs`` with H the (n_free × n_free) Gram matrix of
    the scaled stress Laplacians (+ per-coordinate terms), ``B_i`` 3×3 blocks (vertex-local
    terms + β) and ``G`` the general terms. Without ``G`` it is solved by conjugate gradients
    preconditioned with one n×n factorization (:func:`_solve_blocks`), a 3n×3n factorization
    costing ~27× the flops; for the default objective the preconditioned condition number is at
    most ``1 + (1 − τ)/(τ + β/α)``. The direct 3n×3n factorization remains for general terms,
    the coupled step (``coupling``) and as a fallback; with a fixed top view only the heights
    move (an n×n factorization); ``rtol`` is the conjugate gradients' tolerance on the step's own
    residual. ``workspace`` (a dict kept by the caller across steps) holds
    the factor objects, whose symbolic analyses are reused, and the constant Gram matrices of
    the per-coordinate terms.
    """
    wsp = workspace if workspace is not None else {}
    wsp["cg_iterations"] = 0  # stays 0 unless conjugate gradients solve the step
    free = top.free
    H, rhs, c, Kts, targets = _stress_gram(top, X, weights=weights, loads=loads)
    H1, rhs1, blocks, rhs3, Gg, rhsg = _term_model(objective, X, free=free, alpha=alpha, c=c, ws=wsp, pinned=pinned)
    if H1 is not None:
        H = (H + H1).tocsr()
    blocks = blocks + (c * beta) * np.eye(3)[None]
    rhs += rhs1 + rhs3 + (c * beta) * X[free]
    if fixed_xy:
        return _heights(X, free, H=H, blocks=blocks, rhs=rhs, Gg=Gg, rhsg=rhsg, wsp=wsp)
    Xn = X.copy()
    coupled = coupling is not None and coupling.moves
    if Gg is None and not coupled:
        sol = _solve_blocks(H, blocks, rhs, wsp, start=X[free], rtol=rtol, deadline=deadline)
        if sol is not None:
            Xn[free] = sol
            return Xn
    M = (sp.kron(H, sp.identity(3), format="csr") + block_diagonal(blocks)).tocsc()
    rhs_flat = rhs.ravel() + (rhsg if Gg is not None else 0.0)
    if Gg is not None:
        M = (M + Gg).tocsc()
    if coupled:
        Xn[free] = _coupled_solve(M, rhs_flat, Kts=Kts, targets=targets, coupling=coupling)
        return Xn
    wsp["factor"] = spd_factor(M, reuse=wsp.get("factor"))
    Xn[free] = wsp["factor"].solve(rhs_flat).reshape(-1, 3)
    return Xn


class _Operator(LinearOperator):
    """A square operator whose ``matvec`` is ``f`` itself: conjugate gradients call it ~40 times
    a step, and LinearOperator's own ``matvec`` checks and reshapes every vector (the same
    numbers, a third of the cost of a small mesh's products)."""

    def __init__(self, n: int, f: Callable[[np.ndarray], np.ndarray]) -> None:
        super().__init__(float, (n, n))
        self._f = f

    def _matvec(self, x: np.ndarray) -> np.ndarray:
        return self._f(x)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        return self._f(x)


def _solve_blocks(H: sp.csr_matrix, blocks: np.ndarray, rhs: np.ndarray, ws: dict, *, start: np.ndarray,
                  rtol: float = STEP_RTOL, maxiter: int = 200, deadline: float | None = None) -> np.ndarray | None:
    """``(H ⊗ I₃ + ⊕ B_i) x = rhs`` for ``(k, 3)`` arrays by preconditioned CG (scipy), the
    preconditioner ``(H + diag(λ_min(B_i)))⁻¹`` per coordinate (the isotropic part of each block;
    ``⊕ B_i − λ_min ⊗ I`` is PSD, so the preconditioned system's eigenvalues are ≥ 1), solved for
    ``x − start`` to ``rtol`` of its own residual (``start``: the current positions, so the
    tolerance is relative to the step, not to the coordinates); None if CG does not converge.
    Raises :class:`~selfsupport.methods.deadline.DeadlineReached` when the next CG iteration would
    end past ``deadline`` (a partial step is no step)."""
    k = H.shape[0]
    lam = np.linalg.eigvalsh(blocks)[:, 0]
    pre = ws["pre"] = spd_factor((H + sp.diags(lam)).tocsc(), reuse=ws.get("pre"))

    def matvec(x: np.ndarray) -> np.ndarray:
        Xv = x.reshape(k, 3)
        return (H @ Xv + np.einsum("kij,kj->ki", blocks, Xv)).ravel()

    op = _Operator(3 * k, matvec)
    prec = _Operator(3 * k, lambda r: pre.solve(r.reshape(k, 3)).ravel())
    count = [0]
    last = [time.perf_counter(), 0.0]  # end of the last iteration, its duration

    def callback(_: np.ndarray) -> None:
        count[0] += 1
        now = time.perf_counter()
        last[:] = [now, now - last[0]]
        if out_of_time(deadline, last[1]):
            raise DeadlineReached

    r = rhs - (H @ start + np.einsum("kij,kj->ki", blocks, start))
    d, info = cg(op, r.ravel(), x0=pre.solve(r).ravel(), rtol=rtol, atol=0.0, maxiter=maxiter, M=prec,
                 callback=callback)
    x = start + d.reshape(k, 3)
    ok = info == 0 and np.all(np.isfinite(x))
    ws["cg_iterations"] = count[0] if ok else 0  # 0: the caller falls back to the direct solve
    return x if ok else None
