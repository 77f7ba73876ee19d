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

from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..linalg import spd_factor
from ..loads import LoadCase
from formulations.equilibrium import Topology, position_blocks
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
            ws["colouring"] = _load_colouring(mesh0, free)
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
            J = sp.csc_matrix(K.shape) if constant else _load_jacobian(loads_at, z, Lz, *colouring)
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


def _load_jacobian(loads_at: Callable, z: np.ndarray, Lz: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                   colour: np.ndarray, n_colours: int) -> sp.csc_matrix:
    """``dL/dz`` on the face-neighbour pattern, one load evaluation per colour (forward
    differences; the Jacobian only steers the Newton step, the residual decides convergence)."""
    h = 1e-7 * max(float(np.abs(z).max()), 1.0)
    D = np.empty((n_colours, z.size))
    for k in range(n_colours):
        D[k] = (loads_at(z + h * (colour == k)) - Lz) / h
    return sp.csc_matrix((D[colour[cols], rows], (rows, cols)), shape=(z.size, z.size))


def _load_colouring(mesh, free: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
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
