"""The polish: equations (2)-(3) solved exactly for the free positions with the weights frozen,
the loads (which depend on the geometry) consistent with the result to round-off.

x and y do not depend on the loads and are solved once from the stress Laplacian. The heights
solve the nonlinear system ``R(z) = K z − z_s + L(z) = 0`` (``K = −K_ff`` SPD, ``L`` the scaled
free loads). First a few Anderson rounds (:data:`ANDERSON_FIRST`, method 2 below), which settle a
start already near equilibrium cheaply; then three methods, each a fallback for the one before:

1. **Newton** with the load Jacobian ``J = dL/dz`` from finite differences: a load depends
   only on the heights of the vertices sharing a face with it, so columns that share no row
   are perturbed together (a distance-2 colouring: 13–17 colours on the paper's scenes, each one load
   evaluation). ``K + J`` is factored once (SuperLU) and reused while the step contracts
   fast (a chord method); otherwise J is refreshed. Steps are backtracked on the fixed-point
   residual. From the iterates the solver polishes it converges in 4–13 steps on the paper's
   scenes, also where the load fixed point is no contraction (cyl2); far from a solution it
   may stall (seen on dome2), and the fallbacks take over.
2. **Anderson** mixing (:func:`~selfsupport.methods.anderson.anderson`) on the fixed point
   ``z = G(z) = K⁻¹(z_s − L(z))``: needs no Jacobian, used when Newton does not converge (e.g.
   a load model whose dependence is not face-local, so the colouring misses entries).
3. **Newton–Krylov** (scipy) on ``z − G(z)``, when even that diverges.
"""
from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, cg, splu

from formulations.equilibrium import Topology, position_blocks, residual, weight_matrix
from formulations.nlp import ThrustNetworkProblem
from formulations.scaling import Scaling
from selfsupport.core.linalg import spd_factor
from selfsupport.core.loads import LoadCase
from selfsupport.methods.anderson import anderson
from selfsupport.methods.deadline import DeadlineReached, out_of_time

#: Anderson's rounds tried before Newton (each one load evaluation and one solve with the stress
#: Laplacian's factor). From a start near equilibrium they converge where Newton first spends a
#: coloured finite-difference Jacobian and a SuperLU factorization (seconds at large sizes).
ANDERSON_FIRST = 8


def polish(top: Topology, X: np.ndarray, w: np.ndarray, loads: LoadCase, mesh0, sc: Scaling,
           max_rounds: int = 60, newton: bool = True, workspace: dict | None = None,
           fallbacks: bool = True, deadline: float | None = None,
           krylov: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """Positions in equilibrium with the frozen weights ``w`` (scaled units), the scaled loads
    of those positions, and the rounds taken: Anderson's first rounds (:data:`ANDERSON_FIRST`),
    Newton's steps, plus Anderson's rounds and Newton–Krylov's evaluations of G when it came to
    those. ``max_rounds`` bounds Newton's steps and each of Anderson's tries; ``workspace`` (a
    dict kept by the caller) caches the colouring and the stress Laplacian's factor. ``fallbacks=False``: Anderson's first rounds
    and Newton only, Newton's last point returned when it does not converge (a cheap trial; the
    fixed-point fallbacks can take hundreds of load evaluations). Past
    ``deadline`` (``time.perf_counter()``) every method returns its best point so far: ``X``
    itself when the deadline has passed on entry (not even x, y are solved). ``newton=False,
    krylov=False``: Anderson's fixed-point rounds only (each one load evaluation and one solve
    with the Cholesky factor; at 256k vertices 15 rounds took 2.8 s where Newton's steps, each
    refreshed Jacobian a SuperLU factorization of K + J, took 35 s to the same error)."""
    free = top.free
    if out_of_time(deadline):
        return X.copy(), sc.loads_at(loads, mesh0, X), 0
    Kff, Kfs = position_blocks(top, w)
    K = (-Kff).tocsc()
    ws = workspace if workspace is not None else {}
    # (the finish's screen factors this very matrix first: its factor is reused)
    chol = ws["laplacian"] = spd_factor(K, reuse=ws.get("laplacian"))
    Xn = X.copy()
    Xn[free, :2] = chol.solve(Kfs @ X[~free][:, :2])  # −K_ff X = K_fs X_s − B, B = 0 for x and y
    zs = Kfs @ X[~free, 2]

    def loads_at(z: np.ndarray) -> np.ndarray:
        Xn[free, 2] = z
        return sc.loads_at(loads, mesh0, Xn)[free]

    def G(z: np.ndarray) -> np.ndarray:
        return chol.solve(zs - loads_at(z))

    z_start = X[free, 2].copy()
    ftol = 1e-15 * max(float(np.abs(z_start).max()), 1.0)
    z, rounds, converged = z_start, 0, False
    first = min(ANDERSON_FIRST, max_rounds) if newton else 0
    if first:
        # a start already near the fixed point (the fit was nearly exact; a warm start or a
        # prolonged network in equilibrium) settles in a few cheap rounds, before Newton's
        # colouring and factorization
        za, rounds, converged = anderson(G, z_start, tol=ftol, max_rounds=first, deadline=deadline)
        z = za if converged else z_start
    if newton and not converged:
        constant = not loads.depends_on_geometry  # then J = 0 and one Newton step is exact
        if "colouring" not in ws and not constant:
            ws["colouring"] = load_colouring(mesh0, free)
        z, r1, converged = _newton(K, zs, loads_at, chol, z_start, ws.get("colouring"), ftol, max_rounds,
                                   constant=constant, deadline=deadline)
        rounds += r1
    if not converged and fallbacks and max_rounds > first and not out_of_time(deadline):
        # (with no more rounds than the first try had, it would repeat that try round for round)
        z, r2, converged = anderson(G, z_start, tol=ftol, max_rounds=max_rounds, deadline=deadline)
        rounds += r2
    if not converged and fallbacks and krylov and not out_of_time(deadline):
        z, r3 = _newton_krylov(G, z_start, z, ftol, deadline=deadline)
        rounds += r3
    Xn[free, 2] = z
    L = sc.loads_at(loads, mesh0, Xn)
    return Xn, L, rounds


def _newton(K: sp.csc_matrix, zs: np.ndarray, loads_at: Callable, chol, z: np.ndarray,
            colouring: tuple | None, ftol: float, max_steps: int, constant: bool = False,
            deadline: float | None = None) -> tuple[np.ndarray, int, bool]:
    """Chord Newton on ``R(z) = K z − z_s + L(z)`` with a backtracking line search on the
    fixed-point residual ``f(z) = max |G(z) − z|`` (``G(z) − z = −K⁻¹ R(z)``), which is also the
    convergence test (``f ≤ ftol``). J is refreshed when the chord contracts slowly or a step
    fails; a step that fails with a fresh J ends the method, and so does ``deadline`` (checked before each step with the duration of the
    last). Returns z, steps, converged."""

    def state(zc: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        Lc = loads_at(zc)
        Rc = K @ zc - zs + Lc
        fc = float(np.abs(chol.solve(zs - Lc) - zc).max()) if np.all(np.isfinite(Rc)) else np.inf
        return Lc, Rc, fc

    Lz, R, f = state(z)
    lu, fresh, stale, refreshed = None, False, False, 0
    t_step = 0.0
    for step in range(1, max_steps + 1):
        if f <= ftol:
            return z, step - 1, True
        if not np.isfinite(f) or out_of_time(deadline, t_step):
            return z, step - 1, False
        t0 = time.perf_counter()
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
        t_step = time.perf_counter() - t0
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


#: Colourings by (face structure, free mask): a design session re-solves one topology many times
#: (12 ms of a 76 ms warm re-solve on lilium went into colouring it again).
_COLOURINGS: "OrderedDict[bytes, tuple]" = OrderedDict()
_COLOURINGS_KEPT = 8


def load_colouring(mesh, free: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Pattern of ``dL_free/dz_free`` (vertices sharing a face) and a colouring of its columns
    such that no two columns of one colour share a row. Returns (rows, cols, colour, count),
    read-only arrays, remembered for the last few topologies."""
    face_of, _, _ = mesh.corner_data
    h = hashlib.blake2b(digest_size=16)
    for a in (np.asarray(mesh.face_vertices, np.int64), np.asarray(face_of, np.int64), np.asarray(free, bool)):
        h.update(a.tobytes())
        h.update(b"|")
    key = h.digest()
    if key in _COLOURINGS:
        _COLOURINGS.move_to_end(key)
        return _COLOURINGS[key]
    VF = sp.csr_matrix((np.ones(len(face_of)), (mesh.face_vertices, face_of)), shape=(mesh.n_vertices, mesh.n_faces))
    B = (VF @ VF.T).tocsr()[free][:, free]
    B.data[:] = 1.0
    coo = B.tocoo()
    rows, cols = coo.row.astype(np.int64), coo.col.astype(np.int64)
    colour = _colour_graph((B.T @ B).tocsr())  # columns sharing a row conflict
    for a in (rows, cols, colour):
        a.setflags(write=False)
    out = (rows, cols, colour, int(colour.max()) + 1 if colour.size else 0)
    _COLOURINGS[key] = out
    while len(_COLOURINGS) > _COLOURINGS_KEPT:
        _COLOURINGS.popitem(last=False)
    return out


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


def _newton_krylov(G: Callable, z_start: np.ndarray, z_best: np.ndarray, ftol: float,
                   deadline: float | None = None) -> tuple[np.ndarray, int]:
    """scipy's Newton–Krylov on ``z − G(z)``; returns whichever of its result and ``z_best``
    has the smaller fixed-point residual, and the number of evaluations of G it made
    (``z_best`` when ``deadline`` passes during the run)."""
    # (the last fallback: scipy.optimize, 0.1 s to import, loads only when it runs)
    from scipy.optimize import NoConvergence, newton_krylov

    count = [0]

    def F(v: np.ndarray) -> np.ndarray:
        if out_of_time(deadline):
            raise DeadlineReached
        count[0] += 1
        return G(v) - v

    try:
        # f_tol a little above the round-off floor: asking for 1e-15 spends dozens of
        # Newton steps on noise (the equilibrium error it leaves is ~1e-12 either way)
        zk = newton_krylov(F, z_start, f_tol=100 * ftol, maxiter=30)
    except NoConvergence as e:  # its last iterate, usually converged to round-off
        zk = np.asarray(e.args[0], float)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError, DeadlineReached):
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
            return sc.loads_at(loads, mesh0, Xh)[fidx]

        blocks.append(load_jacobian(loads_at, X[fidx, c], L[fidx], *colouring).tocoo())
    R = np.concatenate([3 * J.row + 2 for J in blocks])
    C = np.concatenate([3 * J.col + c for c, J in enumerate(blocks)])
    return sp.csr_matrix((np.concatenate([J.data for J in blocks]), (R, C)), shape=(3 * nf, 3 * nf))


def case_load_jacobians(models, mesh0, sc: Scaling, free: np.ndarray) -> Callable[..., list | None]:
    """For :func:`polish_joint`: ``(V, L, deadline=None) -> [∂L_c/∂X_free or None per case]``
    (None for a load independent of the geometry), one colouring shared by the cases (cached per
    topology); ``None`` instead of the list when ``deadline`` passes between two cases (each is
    three coloured finite differences: 300 cases on a 91-vertex dome took 5 s)."""
    fidx = np.flatnonzero(free)
    colouring = load_colouring(mesh0, free) if any(m.depends_on_geometry for m in models) else None

    def jacobians(V: np.ndarray, L: np.ndarray, deadline: float | None = None) -> list | None:
        out = []
        for c, m in enumerate(models):
            if m.depends_on_geometry and out_of_time(deadline):
                return None
            out.append(load_jacobian_xyz(m, mesh0, sc, V, L[c], fidx, colouring) if m.depends_on_geometry else None)
        return out

    return jacobians


#: Target of :func:`polish_joint`: max relative residual over every case (round-off is ~1e-14).
JOINT_POLISH_TOL = 1e-12
#: A weight within this fraction of its bound counts as on it (held by :func:`polish_joint`).
BOUND_ACTIVE_REL = 1e-6
#: A hull row within this fraction of ``t/2`` of the hull's face is held by :func:`polish_joint`.
HULL_ACTIVE_REL = 1e-6
#: :func:`polish_joint` measures weight steps in units of ``weight_scale / WEIGHT_STEP_PREFERENCE``:
#: its minimum-norm steps then change weights rather than positions where both can remove a
#: residual. Weights do not change the loads; positions do (self-weight), and with an active
#: hull position steps fed a load-lag cycle that did not converge (dome + point load, t = 2 cm).
WEIGHT_STEP_PREFERENCE = 1e3
#: Most steps of :func:`polish_joint`.
JOINT_POLISH_MAX_ITER = 100


def max_rel_error(top: Topology, V: np.ndarray, W: np.ndarray, L: np.ndarray) -> float:
    """Max relative residual at free vertices over every case (scaled units; ``W`` ``(m,)`` or
    ``(n_cases, m)``, ``L`` ``(n,)`` or ``(n_cases, n)``)."""
    out = 0.0
    for w, Lc in zip(np.atleast_2d(W), np.atleast_2d(L)):
        r = residual(top, V, w, Lc)
        Lf = np.abs(Lc[top.free])
        if Lf.size:
            out = max(out, float((np.linalg.norm(r, axis=1) / np.maximum(Lf, 1e-300)).max()))
    return out


#: Load cases up to which :func:`polish_joint` factors ``J Jᵀ`` whole (:func:`min_norm_step`). Its
#: blocks couple every pair of cases through the shared positions, so the factor grows with the
#: square of the cases (4 cases on a 5,000-vertex dome: 1.6 GB against 0.16 GB for one; 60 cases on
#: a 91-vertex dome: 2.4 GB and 20 s for one step); above this the step is found by conjugate
#: gradients preconditioned by the groups' own blocks instead (memory linear in the cases, the
#: step less exact: the Gauss-Newton iteration corrects it). :mod:`selfsupport.methods.memory` counts both.
DIRECT_CASES_MAX = 4
#: Relative residual of ``J Jᵀ y = b`` at which the conjugate gradients of :func:`min_norm_step` stop.
MIN_NORM_RTOL = 1e-14


def min_norm_step(J: sp.csr_matrix, groups: list[int], b: np.ndarray, *, direct: bool = True,
                  deadline: float | None = None) -> np.ndarray | None:
    """The minimum-norm ``d`` with ``J d = b``: ``d = Jᵀ (J Jᵀ + μ I)⁻¹ b`` (``μ`` round-off level,
    only where ``J`` is rank deficient).

    Parameters
    ----------
    J
        The stacked rows, ``groups[i]`` rows per group (a load case, the planarity rows, the hull rows).
    groups
        Row counts of the groups, in order.
    b
        Right-hand side, one entry per row of ``J``.
    direct
        Factor ``J Jᵀ`` (else conjugate gradients, see below).
    deadline
        ``time.perf_counter()`` value; past it the conjugate gradients stop.

    Returns
    -------
    d, or ``None`` when ``deadline`` passed before it was found.

    ``direct``: ``J Jᵀ`` is factored (one step of iterative refinement). Otherwise it is never formed: conjugate gradients apply it as ``J (Jᵀ y)``,
    preconditioned by the factors of its diagonal blocks (each group's rows with themselves, the
    size of one case's system), so memory and time grow linearly with the cases.
    """
    if out_of_time(deadline):
        return None
    mu = 1e-14 * float(np.asarray(J.multiply(J).sum(axis=1)).max(initial=1.0))  # (J Jᵀ's largest diagonal entry)
    groups = [g for g in groups if g > 0]
    if direct or len(groups) < 2:
        M = (J @ J.T).tocsc()
        fac = spd_factor(M + mu * sp.identity(M.shape[0], format="csc"))
        y = fac.solve(b)
        y = y + fac.solve(b - J @ (J.T @ y))  # one step of iterative refinement
        return J.T @ y

    bounds = np.r_[0, np.cumsum(groups)]
    factors = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        if out_of_time(deadline):
            return None
        Jg = J[lo:hi]
        factors.append(spd_factor((Jg @ Jg.T).tocsc() + mu * sp.identity(hi - lo, format="csc")))

    def precondition(r: np.ndarray) -> np.ndarray:
        return np.concatenate([f.solve(r[lo:hi]) for f, lo, hi in zip(factors, bounds[:-1], bounds[1:])])

    def stop_at_deadline(_: np.ndarray) -> None:
        if out_of_time(deadline):
            raise DeadlineReached

    n = J.shape[0]
    op = LinearOperator((n, n), matvec=lambda y: J @ (J.T @ y) + mu * y, dtype=float)
    pre = LinearOperator((n, n), matvec=precondition, dtype=float)
    try:
        y, _ = cg(op, b, rtol=MIN_NORM_RTOL, atol=0.0, maxiter=10 * len(groups) + 100, M=pre,
                  callback=stop_at_deadline)
    except DeadlineReached:
        return None
    return J.T @ y


def _joint_rows(form: ThrustNetworkProblem, V: np.ndarray, W: np.ndarray, L: np.ndarray, *, S: np.ndarray,
                dL: list, xcols: np.ndarray, planar_rows: tuple | None) -> tuple[list, np.ndarray]:
    """The joint polish's equilibrium rows on the movable positions, per case (scaled by ``S``;
    with the load Jacobian ``dL[c]`` when the loads move with the positions: a Newton step),
    then the planarity rows ``(r, J)`` when given, and their right-hand side ``−r``."""
    top, C = form.topology, form.n_cases
    JX, rhs = [], []
    for c in range(C):
        sr = np.repeat(S[c], 3)
        Kff, _ = position_blocks(top, W[c])
        Cx = sp.kron(Kff, sp.identity(3), format="csr")
        if dL[c] is not None:  # the loads move with the positions (self-weight): a Newton step
            Cx = Cx - dL[c]
        JX.append(sp.diags(sr) @ Cx.tocsr()[:, xcols])
        rhs.append(-(sr * residual(top, V, W[c], L[c]).ravel()))
    b_eq = np.concatenate(rhs)
    if planar_rows is not None:  # equality rows: every face held planar
        rp, Jp = planar_rows
        free_cols = (3 * np.flatnonzero(top.free)[:, None] + np.arange(3)).ravel()
        JX.append(Jp.tocsc()[:, free_cols].tocsr()[:, xcols])
        b_eq = np.concatenate([b_eq, -rp])
    return JX, b_eq


def _held_step(form: ThrustNetworkProblem, V: np.ndarray, W: np.ndarray, JX: list, b_eq: np.ndarray, *,
               S: np.ndarray, inner: np.ndarray, xcols: np.ndarray, hull_rows_all: sp.spmatrix | None,
               deadline: float | None, toward: tuple | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """One minimum-norm step of the joint polish on the positions and the ``inner`` weights
    (updated in place): weights a step would push past a bound, and vertices it would carry out
    of the hull, are held (the vertices on the face they would cross) and the step redone.
    ``toward`` ``(d0, D)``: instead the step nearest ``d0`` (a step of the movable positions) in
    the metric ``|D⁻¹ (d − d0)|`` on the positions (``D`` sparse, square), the weights' as before
    (:func:`constrained_step`). Returns (the flattened free-position step, the weights after
    it), or None past the deadline."""
    top, C, hull = form.topology, form.n_cases, form.hull
    free, nf = top.free, top.n_free
    lo, up = form.lower, form.upper
    s_w = form.weight_scale * WEIGHT_STEP_PREFERENCE
    Aw = weight_matrix(top, V)
    if hull is not None:  # rows of the vertices on the hull's face: held there (or put back)
        h = max(hull.half_thickness, 1e-300)
        sd = hull.signed_distance(V)
        on = np.abs(sd) >= hull.half_thickness * (1 - HULL_ACTIVE_REL)
        goal = np.clip(sd, -hull.half_thickness, hull.half_thickness)
    for _ in range(20):  # weights a step would push past a bound, and vertices it would carry
        # out of the hull, are held (the vertices on the face they would cross), the step redone
        Hr, b = None, b_eq
        if hull is not None and on.any():
            Hr = hull_rows_all[np.flatnonzero(on)][:, xcols] / h
            b = np.concatenate([b_eq, (goal[on] - sd[on]) / h])
        wcols = [np.flatnonzero(inner[c]) for c in range(C)]
        nW = [len(i) for i in wcols]
        # J = [position columns | each case's weight columns, block-diagonal by case]; the
        # planarity and hull rows have position columns only
        Xrows = JX + ([Hr] if Hr is not None else [])
        extra = sum(r.shape[0] for r in Xrows[C:])
        JW = sp.block_diag([sp.diags(np.repeat(S[c], 3)) @ Aw[:, wcols[c]] * s_w for c in range(C)], format="csr")
        J = sp.hstack([sp.vstack(Xrows), sp.vstack([JW, sp.csr_matrix((extra, JW.shape[1]))])], format="csr")
        groups = [r.shape[0] for r in Xrows]
        if len(JX) > C and groups[C]:  # planarity rows (JX's after the cases') scaled to the equilibrium rows' size:
            # the same solution, and min_norm_step's μ stays round-off for them too
            p0 = sum(groups[:C])
            sq = np.asarray(J.multiply(J).sum(axis=1)).ravel()
            top_p = sq[p0:p0 + groups[C]].max(initial=0.0)  # (0: no row held, one empty row)
            c = np.sqrt(sq[:p0].max(initial=0.0) / top_p) if top_p > 0 else 1.0
            if c > 1.0:
                D = np.ones(J.shape[0])
                D[p0:p0 + groups[C]] = c
                J, b = sp.diags(D) @ J, D * b
        if toward is not None:  # d = d0 + D e, e the minimum-norm solution of (J D) e = b − J d0
            nx = len(xcols)
            b = b - J[:, :nx] @ toward[0]
            J = sp.hstack([J[:, :nx] @ toward[1], J[:, nx:]], format="csr")
        d = min_norm_step(J, groups, b, direct=C <= DIRECT_CASES_MAX, deadline=deadline)
        if d is None:  # the deadline passed inside the step: the best iterate so far
            break
        if toward is not None:
            d = np.concatenate([toward[0] + toward[1] @ d[:nx], d[nx:]])
        off, crossing = len(xcols), False
        Wn = W.copy()
        for c in range(C):
            Wn[c, wcols[c]] += s_w * d[off:off + nW[c]]
            out = wcols[c][(Wn[c, wcols[c]] < lo[wcols[c]]) | (Wn[c, wcols[c]] > up[wcols[c]])]
            if out.size:
                inner[c, out], crossing = False, True
            off += nW[c]
        dX = np.zeros(3 * nf)
        dX[xcols] = d[:len(xcols)]
        if hull is not None:
            Vt = V.copy()
            Vt[free] += dX.reshape(-1, 3)
            sd_t = hull.signed_distance(Vt)
            cross = ~on & (np.abs(sd_t) > hull.half_thickness)
            if cross.any():
                on |= cross
                goal[cross] = np.sign(sd_t[cross]) * hull.half_thickness
                crossing = True
        if not crossing:
            break
    if d is None:
        return None
    return dX, Wn


def _joint_error(form: ThrustNetworkProblem, V: np.ndarray, W: np.ndarray, L: np.ndarray
                 ) -> tuple[float, tuple | None]:
    """The joint polish's error: the max relative error of every case, and of the planarity rows
    (``form.planar``), which count like relative residuals; with those rows ``(r, J)`` (None
    without planarity)."""
    err = max_rel_error(form.topology, V, W, L)
    if not form.n_planar:
        return err, None
    rp, Jp = form.planar.linearize(V)
    return max(err, float(np.abs(rp).max())), (rp, Jp)


def _inner_weights(form: ThrustNetworkProblem, W: np.ndarray) -> np.ndarray:
    """``(n_cases, m)`` mask of the weights strictly inside their bounds (the joint polish's unknowns)."""
    lo, up = form.lower, form.upper
    below_up = W < up - BOUND_ACTIVE_REL * np.abs(np.nan_to_num(up, posinf=0.0))  # ∞ stays ∞
    return (W > lo + BOUND_ACTIVE_REL * np.maximum(lo, 1e-300)) & below_up


def _columns(form: ThrustNetworkProblem) -> tuple[np.ndarray, sp.spmatrix | None]:
    """The joint polish's movable entries of the flattened free positions (z only with a fixed
    top view), and the hull's rows on the free positions' coordinates (None without a hull)."""
    coords = np.array([2]) if form.fixed_xy is not None else np.arange(3)
    xcols = (3 * np.arange(form.topology.n_free)[:, None] + coords).ravel()
    fc = (3 * np.flatnonzero(form.topology.free)[:, None] + np.arange(3)).ravel()
    return xcols, (form.hull._rows[:, fc] if form.hull is not None else None)


def _linear_step(form: ThrustNetworkProblem, V: np.ndarray, W: np.ndarray, L: np.ndarray, planar_rows: tuple | None,
                 *, load_jacobian: Callable[..., list | None] | None, xcols: np.ndarray,
                 hull_rows_all: sp.spmatrix | None, deadline: float | None,
                 toward: tuple | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """One step of the joint polish's linearisation at ``V``, ``W`` (loads ``L``): the rows
    (:func:`_joint_rows`), then the step with weights and hull held (:func:`_held_step`, with
    ``toward``). Returns (free-position step, weights) or None past ``deadline``."""
    S = form.row_scale(L)  # (C, nf)
    dL = load_jacobian(V, L, deadline=deadline) if load_jacobian is not None else [None] * form.n_cases
    if dL is None:  # the deadline passed while the load Jacobians were formed
        return None
    JX, b_eq = _joint_rows(form, V, W, L, S=S, dL=dL, xcols=xcols, planar_rows=planar_rows)
    return _held_step(form, V, W, JX, b_eq, S=S, inner=_inner_weights(form, W), xcols=xcols,
                      hull_rows_all=hull_rows_all, deadline=deadline, toward=toward)


def constrained_step(form: ThrustNetworkProblem, V: np.ndarray, W: np.ndarray, d0: np.ndarray, D: sp.spmatrix, *,
                     loads_at: Callable[[np.ndarray], np.ndarray],
                     load_jacobian: Callable[..., list | None] | None = None,
                     deadline: float | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The step of the joint polish's linearised system nearest a wanted step ``d0``.

    Among the steps ``d`` of the free positions and the inner weights that solve the joint
    polish's linearised equations at ``V``, ``W`` (every case's equilibrium, the held planarity
    rows of ``form.planar``; weights on a bound held), the one minimising
    ``|D⁻¹ (d_X − d0)|² + |d_W|²`` (weights in the polish's units, :data:`WEIGHT_STEP_PREFERENCE`).
    With ``D = I`` and ``d0 = 0`` it is the polish's own minimum-norm step.

    Parameters
    ----------
    form
        As for :func:`polish_joint` (scaled units).
    V, W
        ``(n, 3)`` positions and ``(n_cases, m)`` active weights, the point of linearisation.
    d0
        Wanted step of the movable free positions, flattened (``(3 n_free,)`` with a free top view).
    D
        Square sparse metric on those entries (the step costs ``|D⁻¹ (d_X − d0)|²``).
    loads_at, load_jacobian, deadline
        As for :func:`polish_joint`.

    Returns
    -------
    ``(V + d_X, W + d_W)`` (weights clipped to their bounds), or None past ``deadline``.
    """
    V, W = np.array(V, float), np.array(W, float)
    L = loads_at(V)
    _, planar_rows = _joint_error(form, V, W, L)
    xcols, hull_rows_all = _columns(form)
    step = _linear_step(form, V, W, L, planar_rows, load_jacobian=load_jacobian, xcols=xcols,
                        hull_rows_all=hull_rows_all, deadline=deadline, toward=(d0, sp.csr_matrix(D)))
    if step is None:
        return None
    dX, Wn = step
    V[form.topology.free] += dX.reshape(-1, 3)
    return V, np.clip(Wn, form.lower, form.upper)


def polish_joint(form: ThrustNetworkProblem, V: np.ndarray, W: np.ndarray, *,
                 loads_at: Callable[[np.ndarray], np.ndarray], tol: float = JOINT_POLISH_TOL,
                 max_iter: int = JOINT_POLISH_MAX_ITER,
                 load_jacobian: Callable[..., list | None] | None = None,
                 deadline: float | None = None) -> tuple[np.ndarray, np.ndarray, int, float, bool]:
    """Every load case in equilibrium to round-off, with loads of the final geometry.

    Gauss–Newton with minimum-norm steps on the system ``r_c(X, w_c; L_c(V)) = 0`` (all cases,
    rows scaled as in the NLP): the unknowns are the free positions (z only with a fixed top
    view) and, per case, the weights strictly inside their bounds (measured so that the step
    prefers weights, :data:`WEIGHT_STEP_PREFERENCE`: they leave the loads unchanged); weights on
    a bound and hull rows on the hull's face are held (:func:`_held_step`). The planarity rows
    (``form.planar``) are equations of the same system, counted like relative residuals. The
    loads are re-estimated from the geometry before every step (a lag of one step, of the size
    of the residual). ``δ = Jᵀ (J Jᵀ + μ I)⁻¹ (−r)`` with one refinement step; ``μ`` is
    round-off level and only matters where ``J`` is rank deficient.

    Parameters
    ----------
    form
        The NLP statement (topology, bounds, row scaling, hull, fixed top view) in scaled units.
    V, W
        ``(n, 3)`` positions and ``(n_cases, m)`` active weights to correct (scaled units).
    loads_at
        ``V -> (n_cases, n)`` scaled loads of a geometry.
    deadline
        ``time.perf_counter()`` value: no step starts that would end after it (the duration
        of the last step predicts the next); the best iterate so far is returned.

    Returns
    -------
    V, W, steps, max relative error, converged
    """
    top = form.topology
    free = top.free
    V, W = np.array(V, float), np.array(W, float)
    xcols, hull_rows_all = _columns(form)
    err = np.inf
    best = (np.inf, V.copy(), W.copy())
    since, best_before, t_step = 0, np.inf, 0.0
    for k in range(max_iter + 1):
        t0 = time.perf_counter()
        L = loads_at(V)
        err, planar_rows = _joint_error(form, V, W, L)
        if err < best[0]:
            best = (err, V.copy(), W.copy())
        if err <= tol:
            return V, W, k, err, True
        stuck = err > 0.9 * best_before  # (less than a tenth off the best before this step)
        since = since + 1 if stuck else 0
        best_before = min(best_before, err)
        if (k == max_iter or (k >= 5 and stuck and best[0] < 1e3 * tol) or since >= 4
                or out_of_time(deadline, t_step)):
            break  # round-off floor reached, or no progress for 4 steps (far from a solution: the
            # caller iterates on and polishes from closer): keep the best iterate
        step = _linear_step(form, V, W, L, planar_rows, load_jacobian=load_jacobian, xcols=xcols,
                            hull_rows_all=hull_rows_all, deadline=deadline)
        if step is None:  # the deadline passed while the step was formed
            break
        dX, Wn = step
        V[free] += dX.reshape(-1, 3)
        W = np.clip(Wn, form.lower, form.upper)
        t_step = time.perf_counter() - t0
    err, V, W = best
    return V, W, k, err, err <= tol
