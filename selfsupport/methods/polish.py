"""The polish: equations (2)-(3) solved exactly for the free positions with the weights frozen,
the loads (which depend on the geometry) consistent with the result to round-off.

x and y do not depend on the loads and are solved once from the stress Laplacian. The heights
solve the nonlinear system ``R(z) = K z − z_s + L(z) = 0`` (``K = −K_ff`` SPD, ``L`` the scaled
free loads). Three methods, each a fallback for the one before:

1. **Newton** with the load Jacobian ``J = dL/dz`` from finite differences: a load depends
   only on the heights of the vertices sharing a face with it, so columns that share no row
   are perturbed together (a distance-2 colouring: 13–17 colours on the paper's scenes, each one load
   evaluation). ``K + J`` is factored once (SuperLU) and reused while the step contracts
   fast (a chord method); otherwise J is refreshed. Steps are backtracked on the fixed-point
   residual. From the iterates the solver polishes it converges in 4–13 steps on the paper's
   scenes, also where the load fixed point is no contraction (cyl2); far from a solution it
   may stall (seen on dome2), and the fallbacks take over.
2. **Anderson** mixing (depth 5) on the fixed point ``z = G(z) = K⁻¹(z_s − L(z))``: needs no
   Jacobian, used when Newton does not converge (e.g. a load model whose dependence is not
   face-local, so the colouring misses entries).
3. **Newton–Krylov** (scipy) on ``z − G(z)``, when even that diverges.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..linalg import spd_factor
from ..loads import LoadCase
from formulations.equilibrium import Topology, load_vector, position_blocks, weight_matrix
from formulations.scaling import Scaling


def polish(top: Topology, X: np.ndarray, w: np.ndarray, loads: LoadCase, mesh0, sc: Scaling,
           max_rounds: int = 60, newton: bool = True, workspace: dict | None = None,
           fallbacks: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """Positions in equilibrium with the frozen weights ``w`` (scaled units), the scaled loads
    of those positions, and the rounds taken: Newton steps, plus Anderson rounds and
    Newton–Krylov's evaluations of G when it came to those. ``max_rounds`` bounds Newton's
    steps and Anderson's rounds; ``workspace`` (a dict kept by the caller) caches the colouring.
    ``fallbacks=False``: Newton only, its last point returned when it does not converge (a
    cheap trial; the fixed-point fallbacks can take hundreds of load evaluations)."""
    free = top.free
    Kff, Kfs = position_blocks(top, w)
    K = (-Kff).tocsc()
    chol = spd_factor(K)
    Xn = X.copy()
    Xn[free, :2] = chol.solve(Kfs @ X[~free][:, :2])  # −K_ff X = K_fs X_s − B, B = 0 for x and y
    zs = Kfs @ X[~free, 2]

    def loads_at(z: np.ndarray) -> np.ndarray:
        Xn[free, 2] = z
        return sc.load(loads.nodal(mesh0, sc.pos_back(Xn)))[free]

    def G(z: np.ndarray) -> np.ndarray:
        return chol.solve(zs - loads_at(z))

    z_start = X[free, 2].copy()
    ftol = 1e-15 * max(float(np.abs(z_start).max()), 1.0)
    z, rounds, converged = z_start, 0, False
    if newton:
        ws = workspace if workspace is not None else {}
        constant = not loads.depends_on_geometry  # then J = 0 and one Newton step is exact
        if "colouring" not in ws and not constant:
            ws["colouring"] = load_colouring(mesh0, free)
        z, rounds, converged = _newton(K, zs, loads_at, chol, z_start, ws.get("colouring"), ftol, max_rounds,
                                       constant=constant)
    if not converged and fallbacks:
        z, r2, converged = _anderson(G, z_start, ftol, max_rounds)
        rounds += r2
    if not converged and fallbacks:
        z, r3 = _newton_krylov(G, z_start, z, ftol)
        rounds += r3
    Xn[free, 2] = z
    L = sc.load(loads.nodal(mesh0, sc.pos_back(Xn)))
    return Xn, L, rounds


def _newton(K: sp.csc_matrix, zs: np.ndarray, loads_at: Callable, chol, z: np.ndarray,
            colouring: tuple | None, ftol: float, max_steps: int, constant: bool = False
            ) -> tuple[np.ndarray, int, bool]:
    """Chord Newton on ``R(z) = K z − z_s + L(z)`` with a backtracking line search on the
    fixed-point residual ``f(z) = max |G(z) − z|`` (``G(z) − z = −K⁻¹ R(z)``), which is also the
    convergence test (``f ≤ ftol``). J is refreshed when the chord contracts slowly or a step
    fails; a step that fails with a fresh J ends the method. Returns z, steps, converged."""
    from scipy.sparse.linalg import splu

    def state(zc: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        Lc = loads_at(zc)
        Rc = K @ zc - zs + Lc
        fc = float(np.abs(chol.solve(zs - Lc) - zc).max()) if np.all(np.isfinite(Rc)) else np.inf
        return Lc, Rc, fc

    Lz, R, f = state(z)
    lu, fresh, stale, refreshed = None, False, False, 0
    for step in range(1, max_steps + 1):
        if f <= ftol:
            return z, step - 1, True
        if not np.isfinite(f):
            return z, step - 1, False
        if lu is None or (stale and not fresh):
            if refreshed >= 8:
                return z, step - 1, False
            J = sp.csc_matrix(K.shape) if constant else load_jacobian(loads_at, z, Lz, *colouring)
            try:
                lu = splu((K + J).tocsc())
            except RuntimeError:  # singular: leave it to the fixed-point methods
                return z, step - 1, False
            fresh, refreshed = True, refreshed + 1
        dz = lu.solve(R)
        t = 1.0
        while t >= 1.0 / 16:  # backtracking: the full step can overshoot far from the solution
            zt = z - t * dz
            Lt, Rt, ft = state(zt)
            if ft <= (1.0 - 1e-4 * t) * f:
                break
            t *= 0.5
        else:
            if fresh:  # no descent even with an up-to-date Jacobian
                return z, step, False
            stale = True  # retry from here with a new J
            continue
        stale = ft > 0.25 * f  # the chord (an old J) contracts slowly: refresh it
        z, Lz, R, f, fresh = zt, Lt, Rt, ft, False
    return z, max_steps, f <= ftol


def load_jacobian(loads_at: Callable, z: np.ndarray, Lz: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                   colour: np.ndarray, n_colours: int) -> sp.csc_matrix:
    """``dL/dz`` on the face-neighbour pattern, one load evaluation per colour (forward
    differences; the Jacobian only steers the Newton step, the residual decides convergence)."""
    h = 1e-7 * max(float(np.abs(z).max()), 1.0)
    D = np.empty((n_colours, z.size))
    for k in range(n_colours):
        D[k] = (loads_at(z + h * (colour == k)) - Lz) / h
    return sp.csc_matrix((D[colour[cols], rows], (rows, cols)), shape=(z.size, z.size))


def load_colouring(mesh, free: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Pattern of ``dL_free/dz_free`` (vertices sharing a face) and a colouring of its columns
    such that no two columns of one colour share a row. Returns (rows, cols, colour, count)."""
    face_of, _, _ = mesh.corner_data
    VF = sp.csr_matrix((np.ones(len(face_of)), (mesh.face_vertices, face_of)), shape=(mesh.n_vertices, mesh.n_faces))
    B = (VF @ VF.T).tocsr()[free][:, free]
    B.data[:] = 1.0
    coo = B.tocoo()
    rows, cols = coo.row.astype(np.int64), coo.col.astype(np.int64)
    colour = _colour_graph((B.T @ B).tocsr())  # columns sharing a row conflict
    return rows, cols, colour, int(colour.max()) + 1 if colour.size else 0


def _colour_graph(C: sp.csr_matrix) -> np.ndarray:
    """Colouring of the graph ``C`` (symmetric pattern): each colour class is a maximal
    independent set grown by rounds of local priority maxima (Luby), all vectorised. Written
    here: scipy's column grouping for sparse finite differences is private API."""
    n = C.shape[0]
    C = C.tocsr().copy()
    C.setdiag(0)
    C.eliminate_zeros()
    C.data[:] = 1.0
    priority = np.random.default_rng(0).permutation(n).astype(float)  # deterministic
    colour = -np.ones(n, dtype=np.int64)
    has_nb = np.diff(C.indptr) > 0
    k = 0
    while (colour < 0).any():
        avail = colour < 0
        while avail.any():
            vals = np.where(avail[C.indices], priority[C.indices], -1.0)
            nb_max = np.full(n, -1.0)
            nb_max[has_nb] = np.maximum.reduceat(vals, C.indptr[:-1][has_nb])
            chosen = avail & (priority > nb_max)
            colour[chosen] = k
            avail &= ~chosen & ~((C @ chosen.astype(float)) > 0)
        k += 1
    return colour


def _anderson(G: Callable, z: np.ndarray, ftol: float, max_rounds: int) -> tuple[np.ndarray, int, bool]:
    """Anderson-accelerated fixed-point iteration (depth 5); gives up when it diverges."""
    dz_hist: list[np.ndarray] = []
    df_hist: list[np.ndarray] = []
    f_prev = z_prev = None
    f_first = np.inf
    for rounds in range(1, max_rounds + 1):
        gz = G(z)
        f = gz - z
        fmax = float(np.abs(f).max())
        if fmax <= ftol:
            return gz, rounds, True
        f_first = fmax if rounds == 1 else f_first
        if rounds >= 15 and fmax > f_first:  # diverging: leave it to Newton–Krylov
            return z, rounds, False
        if f_prev is not None:
            dz_hist.append(z - z_prev)
            df_hist.append(f - f_prev)
            dz_hist, df_hist = dz_hist[-5:], df_hist[-5:]
        z_prev, f_prev = z, f
        if df_hist:
            dF = np.stack(df_hist, axis=1)
            gamma = np.linalg.lstsq(dF, f, rcond=None)[0]
            z = z + f - (np.stack(dz_hist, axis=1) + dF) @ gamma
        else:
            z = gz
    return z, max_rounds, False


def _newton_krylov(G: Callable, z_start: np.ndarray, z_best: np.ndarray, ftol: float) -> tuple[np.ndarray, int]:
    """scipy's Newton–Krylov on ``z − G(z)``; returns whichever of its result and ``z_best``
    has the smaller fixed-point residual, and the number of evaluations of G it made."""
    from scipy.optimize import NoConvergence, newton_krylov

    count = [0]

    def F(v: np.ndarray) -> np.ndarray:
        count[0] += 1
        return G(v) - v

    try:
        # f_tol a little above the round-off floor: asking for 1e-15 spends dozens of
        # Newton steps on noise (the equilibrium error it leaves is ~1e-12 either way)
        zk = newton_krylov(F, z_start, f_tol=100 * ftol, maxiter=30)
    except NoConvergence as e:  # its last iterate, usually converged to round-off
        zk = np.asarray(e.args[0], float)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return z_best, count[0]
    if np.all(np.isfinite(zk)) and float(np.abs(G(zk) - zk).max()) < float(np.abs(G(z_best) - z_best).max()):
        return zk, count[0]
    return z_best, count[0]


def load_jacobian_xyz(loads: LoadCase, mesh0, sc: Scaling, X: np.ndarray, L: np.ndarray, fidx: np.ndarray,
                       colouring: tuple) -> sp.csr_matrix:
    """``∂L_free / ∂X_free`` placed in the z rows of the 3 n_free residual: the polish's
    coloured forward differences (:func:`~selfsupport.methods.polish.load_jacobian`) once per
    coordinate — a load depends on the positions of the vertices sharing a face with it, in x,
    y and z alike, so the colouring of ``dL/dz`` serves all three."""
    nf = fidx.size
    blocks = []
    for c in range(3):
        def loads_at(v: np.ndarray, c: int = c) -> np.ndarray:
            Xh = X.copy()
            Xh[fidx, c] = v
            return sc.load(loads.nodal(mesh0, sc.pos_back(Xh)))[fidx]

        blocks.append(load_jacobian(loads_at, X[fidx, c], L[fidx], *colouring).tocoo())
    R = np.concatenate([3 * J.row + 2 for J in blocks])
    C = np.concatenate([3 * J.col + c for c, J in enumerate(blocks)])
    return sp.csr_matrix((np.concatenate([J.data for J in blocks]), (R, C)), shape=(3 * nf, 3 * nf))


def polish_joint(top: Topology, X: np.ndarray, weights: list[np.ndarray], loads, mesh0, sc: Scaling,
                 lower: np.ndarray, upper: np.ndarray, *, fixed_xy: bool = False, workspace: dict | None = None,
                 max_rounds: int = 40, deadline: float = np.inf
                 ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, int]:
    """Exact equilibrium for several load cases (or a fixed top view): positions *and* the
    weights off their bounds move together, by minimum-norm Newton steps.

    With one weight vector per case, the frozen weights of the single-case polish cannot
    balance every case by moving the positions alone (3 n_free unknowns, 3 n_free equations per
    case), and with x, y fixed they cannot balance x and y at all. Here each round solves the
    linearized equations of every case, ``C_x Δx + S_c A Δw_c = −r_c`` (rows scaled by
    ``1/|L_c,i|``; ``C_x`` = stress Laplacian minus the coloured finite-difference load
    Jacobian, :func:`load_jacobian_xyz`), for the step of least ``‖Δx‖² + Σ_c ‖Δw_c / w_c‖²``
    (relative weight changes) through ``(J D² Jᵀ) y = r``, one sparse SPD factorization per
    round. Weights a step carries across a bound are clamped there and held. Converges
    quadratically from an iterate whose fit error is small (the staggered method's
    ``polish_tol``). ``loads`` is a :class:`~formulations.LoadCases`. Returns
    ``(X, weights, L (n_cases, n) scaled, rounds)`` — the best iterate (smallest max relative
    error) if it does not converge.
    """
    ws = workspace if workspace is not None else {}
    free = top.free
    fidx = np.flatnonzero(free)
    nf = top.n_free
    C = len(loads)
    if "colouring" not in ws and loads.depends_on_geometry:
        ws["colouring"] = load_colouring(mesh0, free)
    cols = np.arange(3 * nf).reshape(nf, 3)[:, 2] if fixed_xy else np.arange(3 * nf)
    X = X.copy()
    w = [np.asarray(wc, float).copy() for wc in weights]
    held = [(wc <= lower) | (wc >= upper) for wc in w]

    def state(Xc: np.ndarray, wc: list[np.ndarray]):
        Lc = sc.load(loads.nodal(mesh0, sc.pos_back(Xc)))
        A = weight_matrix(top, Xc)
        res, ss = [], []
        for c in range(C):
            s = np.repeat(1.0 / np.abs(Lc[c, free]), 3)
            res.append(s * (A @ wc[c] - load_vector(top, Lc[c])))
            ss.append(s)
        err = max(float(np.linalg.norm(r.reshape(-1, 3), axis=1).max()) for r in res)
        return Lc, A, res, ss, err if np.isfinite(err) else np.inf

    L, A, res, ss, err = state(X, w)
    best = (err, X.copy(), [wc.copy() for wc in w], L)
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        if err <= 1e-14 or time.perf_counter() > deadline:
            break
        blocks_x, blocks_w, D2w = [], [], []
        for c in range(C):
            Kff, _ = position_blocks(top, w[c])
            Cx = sp.kron(Kff, sp.identity(3), format="csr")
            if loads.models[c].depends_on_geometry:
                Cx = Cx - load_jacobian_xyz(loads.models[c], mesh0, sc, X, L[c], fidx, ws["colouring"])
            S = sp.diags(ss[c])
            blocks_x.append((S @ Cx).tocsr()[:, cols])
            mov = ~held[c]
            blocks_w.append((S @ A[:, mov]).tocsc())
            D2w.append(w[c][mov] ** 2)
        Jx = sp.vstack(blocks_x, format="csr")
        N = (Jx @ Jx.T + sp.block_diag([Bw @ sp.diags(d) @ Bw.T for Bw, d in zip(blocks_w, D2w)])).tocsc()
        N = (N + sp.identity(N.shape[0]) * (1e-14 * float(N.diagonal().mean()))).tocsc()
        try:
            y = spd_factor(N).solve(np.concatenate(res))
        except (RuntimeError, ValueError, ArithmeticError):
            break
        dx = -(Jx.T @ y)
        Xt = X.copy()
        Xt[fidx] = (Xt[fidx].ravel() + np.bincount(cols, weights=dx, minlength=3 * nf)).reshape(nf, 3)
        wt = []
        for c in range(C):
            yc = y[3 * nf * c:3 * nf * (c + 1)]
            wc = w[c].copy()
            mov = ~held[c]
            wc[mov] -= D2w[c] * (blocks_w[c].T @ yc)
            wt.append(wc)
        heldt = [h | (wc < lower) | (wc > upper) for h, wc in zip(held, wt)]
        wt = [np.clip(wc, lower, upper) for wc in wt]
        Lt, At, rest, sst, errt = state(Xt, wt)
        if not errt < err:  # no progress (a clamp, or the linearization no longer holds): stop
            if any((h != hn).any() for h, hn in zip(held, heldt)):
                held = heldt  # ... unless newly held weights change the next step
                continue
            break
        X, w, held, L, A, res, ss, err = Xt, wt, heldt, Lt, At, rest, sst, errt
        if err < best[0]:
            best = (err, X.copy(), [wc.copy() for wc in w], L)
    _, X, w, L = best
    return X, w, L, rounds
