"""Step 2 of the staggered method: the box-constrained sparse least-squares fit of the weights.

Every backend solves, with positions fixed,

    min_w  ½‖A w − b‖² + ½ prox ‖w − w0‖²    s.t.  lower ≤ w ≤ upper

(``prox`` > 0 makes the problem strictly convex: A has more columns than rows on typical
triangle meshes, so the plain fit has a whole face of minimisers). Backends are thin
adapters with a ``defaults`` dict; a backend object may keep state between calls (warm starts).
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from selfsupport.core.errors import InputError
from selfsupport.core.linalg import GramPattern, LowRankUpdatedFactor, SplitGram, spd_factor
from selfsupport.methods.deadline import out_of_time


@dataclass(frozen=True)
class WeightFit:
    """Outcome of one Step-2 fit."""

    w: np.ndarray
    objective: float  # ½‖A w − b‖² (without the proximal term)
    iterations: int
    status: str  # "optimal" | "inexact" (stopped at the caller's looser rtol) | "max_iter" | "failed"
    # | "time_limit" (stopped at the caller's deadline: the point reached so far)
    seconds: float
    n_lower: int = 0
    n_upper: int = 0


class WeightFitBackend:
    """Base class of Step-2 backends."""

    name: str = "base"
    defaults: dict[str, Any] = {}

    def __init__(self, **options: Any) -> None:
        unknown = set(options) - set(self.defaults)
        if unknown:

            raise InputError(f"unknown option(s) {sorted(unknown)} for weight-fit backend {self.name!r}; "
                             f"known: {sorted(self.defaults)}")
        self.options = {**self.defaults, **options}

    def fit(self, *, A: sp.spmatrix, b: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            w0: np.ndarray, prox: float = 0.0, rtol: float | None = None,
            deadline: float | None = None, fits: np.ndarray | None = None) -> WeightFit:
        """Solve the fit. ``rtol``: a looser relative KKT tolerance the caller accepts for this
        fit (``None``: the backend's own); a backend may ignore it. ``deadline``: a
        ``time.perf_counter()`` value; past it the backend returns the point it has, status
        ``"time_limit"`` (``None``: no deadline). A deadline already passed runs no backend at
        all: the start, clipped to the bounds, is returned (a fast backend would otherwise finish
        within its own minimum time limit and report "optimal"). So is a start inside the box
        that already fits, ``|A w0 − b| ≤`` :data:`FITS_ALREADY` ``· max |b|`` row by row (status
        ``"optimal"``): with ``A w0 = b`` it is the unique minimiser, and with a residual ``r`` it
        is within ``½‖r‖²`` of the minimum. A network prolonged in equilibrium
        (:mod:`.prolong`) is such a start, and its bounds are degenerate (multipliers of zero), on
        which PDAS cycles and the interior point used its 100 iterations (4 s at 16k vertices).
        ``fits``: per row, a larger residual (in units of ``max |b|``) that counts as fitting
        already — the caller's round-off floor of a start in equilibrium (a 64k prolonged level's
        first fit, with its floor at 1e-8, ran the interior point for minutes)."""
        t0 = time.perf_counter()
        w = np.clip(np.asarray(w0, float), lower, upper)
        late = out_of_time(deadline)
        if late or (np.array_equal(w, w0) and _fits_already(A, b, w, fits)):
            nl, nu = count_bounds(w, lower, upper)
            return WeightFit(w=w, objective=_objective(A, b, w), iterations=0, status="time_limit" if late else "optimal",
                             seconds=time.perf_counter() - t0, n_lower=nl, n_upper=nu)
        return self._fit(A=A, b=b, lower=np.asarray(lower, float), upper=np.asarray(upper, float), w0=w0,
                         prox=prox, rtol=rtol, deadline=deadline)

    def _fit(self, *, A: sp.spmatrix, b: np.ndarray, lower: np.ndarray, upper: np.ndarray,
             w0: np.ndarray, prox: float, rtol: float | None,
             deadline: float | None) -> WeightFit:  # pragma: no cover - abstract
        """The backend's own fit (:meth:`fit` has checked the deadline)."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget warm-start state (new problem)."""

    def warm(self, w: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        """Seed the warm-start state from weights of a previous solve (default: nothing)."""


#: A start whose every residual row is at most this times ``max |b|`` is returned as the fit (the
#: staggered method's default tolerance on the max relative error: its rows are relative errors).
FITS_ALREADY = 1e-9


def _fits_already(A: sp.spmatrix, b: np.ndarray, w: np.ndarray, fits: np.ndarray | None = None) -> bool:
    r = A @ w - b
    tol = FITS_ALREADY if fits is None else np.maximum(FITS_ALREADY, fits)
    return bool(np.all(np.isfinite(r))) and bool(np.all(np.abs(r) <= tol * float(np.abs(b).max(initial=0.0))))


def _objective(A: sp.spmatrix, b: np.ndarray, w: np.ndarray) -> float:
    r = A @ w - b
    return 0.5 * float(r @ r)


def count_bounds(w: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[int, int]:
    """How many weights sit at their lower / upper bound (to 1e-8 of the largest weight)."""
    tol = 1e-8 * max(float(np.abs(w).max(initial=0.0)), 1e-300)
    return int(np.sum(w <= lower + tol)), int(np.sum(np.isfinite(upper) & (w >= upper - tol)))


class _LowerQ:
    """The lower triangle of ``Q`` (sorted CSC, every diagonal entry stored) and one SPD factor
    object for all the matrices of a fit that share its pattern — ``Q + diag(D)`` in the
    interior point, ``Q`` with the fixed variables' rows and columns replaced by their
    diagonal in PDAS — so that each is a numeric refactorization only (the symbolic analysis
    is done once per pattern, and kept across fits while the pattern holds).

    ``dense``: the dense rows ``U`` of :class:`~selfsupport.core.linalg.GramPattern`, left out of
    ``Q`` (which is then ``Q_s``, the full matrix being ``Q_s + UᵀU``); each factor is then a
    :class:`~selfsupport.core.linalg.LowRankUpdatedFactor` of the full matrix."""

    def __init__(self, Q: sp.spmatrix, factor: Any = None, pattern: GramPattern | None = None,
                 dense: sp.csr_matrix | None = None) -> None:
        n = Q.shape[0]
        ii = np.arange(n)
        if pattern is not None:  # Q on a GramPattern: its lower triangle by indexing (diagonal stored)
            M = sp.csc_matrix((pattern.lower(Q.data), pattern.lower_indices, pattern.lower_indptr), shape=Q.shape)
        else:
            Qc = sp.tril(Q, format="coo")
            M = sp.coo_matrix((np.r_[Qc.data, np.zeros(n)], (np.r_[Qc.row, ii], np.r_[Qc.col, ii])),
                              shape=Q.shape).tocsc()
            M.sort_indices()  # explicit zeros survive coo -> csc: the diagonal is always stored
        self.M, self.base = M, M.data.copy()
        self.diag_pos = M.indptr[:-1]  # a sorted lower-triangular column starts at its diagonal
        self.diag = self.base[self.diag_pos]
        self.rows, self.cols = M.indices, np.repeat(ii, np.diff(M.indptr))
        self.factor = factor
        self.dense = self.active_dense = dense
        if dense is not None:  # (the full matrix's diagonal: the dense rows' share added)
            self.diag = self.diag + np.asarray(dense.multiply(dense).sum(axis=0)).ravel()

    def _factor(self, data: np.ndarray):
        self.M.data = data
        self.factor = spd_factor(self.M, lower=True, reuse=self.factor)
        if self.active_dense is None:
            return self.factor
        L = sp.csc_matrix((data, self.M.indices, self.M.indptr), shape=self.M.shape)
        d = data[self.diag_pos]
        return LowRankUpdatedFactor(self.factor, lambda x: L @ x + L.T @ x - d * x, self.active_dense)

    def with_diagonal(self, D: np.ndarray):
        """Factor of ``Q + diag(D)``."""
        data = self.base.copy()
        data[self.diag_pos] += D
        self.active_dense = self.dense
        return self._factor(data)

    def fixing(self, fixed: np.ndarray):
        """Factor of ``Q`` with the rows and columns of ``fixed`` variables decoupled (their
        diagonal kept, so a solve returns ``x_i = rhs_i / Q_ii`` there)."""
        data = self.base.copy()
        data[fixed[self.rows] | fixed[self.cols]] = 0.0
        keep = np.where(self.diag > 0, self.diag, 1.0)
        data[self.diag_pos[fixed]] = keep[fixed]
        if self.dense is not None:  # (the dense rows without the fixed columns)
            self.active_dense = sp.csr_matrix(self.dense.multiply((~fixed)[None, :]))
        return self._factor(data), keep


def _ipm_start(Q: sp.csc_matrix, c: np.ndarray, lower: np.ndarray, upper: np.ndarray, w0: np.ndarray, *,
               lowq: _LowerQ, gs: float, warm: tuple[np.ndarray, np.ndarray] | None,
               centred: tuple | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The interior point's first iterate (w, z, y) strictly inside the box, and the typical
    weight ``scale_w`` its test is relative to: a centred iterate of the previous fit, a warm
    start nudged off the bounds, or the unconstrained minimiser pushed inside. ``gs``: the
    gradient scale max |c|."""
    fin = np.isfinite(upper)
    span = np.where(fin, upper - lower, np.inf)
    if centred is not None and centred[0].shape == c.shape:
        # a centred iterate of the previous fit (a few iterations before its end): the next
        # problem's barrier path passes close to it (about a third fewer iterations)
        w, z, y = (np.array(v, float) for v in centred)
        scale_w = max(float(np.median(np.abs(w))), float(np.abs(lower).max()), 1e-300)
        gap = np.minimum(1e-3 * scale_w, 0.25 * span)
        w = np.clip(w, lower + gap, np.where(fin, upper - gap, np.inf))
        gm = 1e-12 * gs
        z, y = np.maximum(z, gm), np.where(fin, np.maximum(y, gm), 0.0)
    elif warm is not None and warm[0].shape == c.shape:
        # warm start near the previous solution and its multipliers, nudged off the bounds by 10%
        # of the typical weight (nearer, the interior point method must first re-centre)
        w, z_prev = warm
        scale_w = max(float(np.median(np.abs(w))), float(np.abs(lower).max()), 1e-300)
        push = np.minimum(0.1 * scale_w, 0.25 * span)
        w = np.clip(w, lower + push, np.where(fin, upper - push, np.inf))
        g = Q @ w - c
        gm = max(float(np.median(np.abs(g))), 1e-3 * gs)
        z = np.maximum(np.maximum(z_prev, g), 0) + 0.1 * gm
        y = np.where(fin, np.maximum(-g, 0) + 0.1 * gm, 0.0)
    else:
        # Mehrotra-style start: the unconstrained minimiser, pushed well inside the box
        w = lowq.with_diagonal(np.zeros(Q.shape[0])).solve(c)
        if not np.all(np.isfinite(w)):
            w = np.asarray(w0, float).copy()
        dist = np.abs(w - np.clip(w, lower, upper))
        scale_w = max(float(np.median(np.abs(w))), float(np.abs(lower).max()), 1e-300)
        push = np.minimum(0.1 * scale_w + dist, 0.25 * span)
        w = np.clip(w, lower + push, np.where(fin, upper - push, np.inf))
        g = Q @ w - c
        gm = max(float(np.median(np.abs(g))), 1e-3 * gs)
        z = np.maximum(g, 0) + gm
        y = np.where(fin, np.maximum(-g, 0) + gm, 0.0)
    return w, z, y, scale_w


def _box_qp_ipm(Q: sp.csc_matrix, c: np.ndarray, lower: np.ndarray, upper: np.ndarray, w0: np.ndarray,
                tol: float, max_iter: int, warm: tuple[np.ndarray, np.ndarray] | None = None,
                lowq: _LowerQ | None = None, deadline: float | None = None, centred: tuple | None = None,
                trail: list | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, str]:
    """Mehrotra predictor-corrector interior point for ``min ½wᵀQw − cᵀw, l ≤ w ≤ u``.

    One sparse factorization of ``Q + Z/S + Y/T`` per iteration; robust whatever the
    structure of Q. Returns the point, the multipliers of both bounds, iterations, status
    (``"time_limit"`` when the next iteration would end past ``deadline``: the iterate is
    strictly inside the box, a usable if inexact fit).
    """
    lowq = lowq if lowq is not None else _LowerQ(Q)
    fin = np.isfinite(upper)
    gs = max(float(np.abs(c).max()), 1e-300)
    w, z, y, scale_w = _ipm_start(Q, c, lower, upper, w0, lowq=lowq, gs=gs, warm=warm, centred=centred)
    n_con = w.size + int(fin.sum())
    has_up = bool(fin.any())  # (y = 0 and t = 1 wherever the upper bound is infinite)
    zero = np.zeros_like(w)
    it = 0
    t_iter = 0.0  # duration of the last iteration (predicts the next one for the deadline)
    for it in range(1, max_iter + 1):
        t_it = time.perf_counter()
        g = Q @ w - c  # the gradient, shared by the test and both directions
        s_ = w - lower
        t_ = np.where(fin, upper - w, 1.0) if has_up else 1.0
        mu = (float(s_ @ z) + (float(t_[fin] @ y[fin]) if has_up else 0.0)) / n_con
        if np.abs(g - z + y).max() <= tol * gs and mu <= tol * gs * scale_w:
            return w, z, y, it, "optimal"
        if out_of_time(deadline, t_iter):
            return w, z, y, it - 1, "time_limit"
        with np.errstate(divide="ignore", invalid="ignore"):
            zs, yt = z / s_, (y / t_ if has_up else zero)
            D = zs + yt
        if not (np.all(np.isfinite(D)) and np.all(s_ > 0)):
            return w, z, y, it, "failed"  # the barrier broke down (degenerate problem)
        lu = lowq.with_diagonal(D)  # one pattern every iteration: numeric refactorization only

        def direction(sig_mu, corr_s, corr_t):
            a_s = (sig_mu - corr_s) / s_
            if has_up:
                a_t = np.where(fin, (sig_mu - corr_t) / t_, 0.0)
                dw = lu.solve(a_s - a_t - g)
                return dw, a_s - z - zs * dw, np.where(fin, a_t - y + yt * dw, 0.0)
            dw = lu.solve(a_s - g)
            return dw, a_s - z - zs * dw, zero

        def max_step(dw, dz, dy):
            a = min(_ratio(s_, dw), _ratio(z, dz))
            return min(a, _ratio(t_[fin], -dw[fin]), _ratio(y[fin], dy[fin])) if has_up else a

        dw, dz, dy = direction(0.0, 0.0, 0.0)
        a = max_step(dw, dz, dy)
        mu_aff = (float((s_ + a * dw) @ (z + a * dz))
                  + (float((t_ - a * dw)[fin] @ (y + a * dy)[fin]) if has_up else 0.0)) / n_con
        sigma = (mu_aff / mu) ** 3
        dw, dz, dy = direction(sigma * mu, dw * dz, -dw * dy if has_up else 0.0)
        a = min(1.0, 0.995 * max_step(dw, dz, dy))
        w, z, y = w + a * dw, z + a * dz, (y + a * dy if has_up else y)
        if trail is not None:  # the last iterates (the caller keeps a bounded deque)
            trail.append((w, z, y))
        t_iter = time.perf_counter() - t_it
    return w, z, y, it, "max_iter"


def _ratio(v: np.ndarray, dv: np.ndarray) -> float:
    """The largest step ``a ≤ 1`` with ``v + a dv ≥ 0`` (v > 0)."""
    neg = dv < 0
    return float((-v[neg] / dv[neg]).min(initial=1.0))


class ActiveSetFit(WeightFitBackend):
    """Primal-dual active set (Hintermüller, Ito & Kunisch 2002) on the normal equations,
    warm-started from the previous call's active set, with an interior-point fallback.

    When the active set of the previous outer iteration is nearly right — the usual case once
    the geometry settles — PDAS finishes in one to three sparse factorizations. PDAS may
    cycle when Q is not an M-matrix (far from equilibrium it does, badly), so after
    ``max_pdas`` iterations the problem goes to a Mehrotra interior-point method
    (:func:`_box_qp_ipm`), whose result seeds PDAS once more (crossover) so that the final
    point satisfies the KKT conditions exactly. PDAS hands over early when its guess is not
    settling (the number of changed bounds falls by less than ``1 − pdas_settle`` per
    iteration; a warm start after a design edit fell 79 → 38 → 23 → … and was handed to the
    interior point's ~19 factorizations under a halving rule). With a caller's ``rtol`` above
    ``tol`` the interior point stops there and its point is returned as it is (status
    ``"inexact"``, bounds counted from the crossover's guess).

    ``centred_back`` > 0: the interior point restarts from its own iterate of the previous fit
    that many iterations before that run's end with its multipliers (held at least 0.1% of the
    typical weight inside the box), instead of from the previous point nudged 10% off the bounds — for every fit, or with
    ``centred_loose`` False for the exact fits only (:class:`CentredActiveSetFit`).

    Written here rather than taken from a library: scipy's ``lsq_linear`` takes 10–90 s at
    3,500 edges (docs/theory/staggered.md), and none of the available sparse QP solvers warm-starts from
    an active set.
    """

    name = "active-set"
    defaults = {"max_pdas": 10, "max_ipm": 100, "tol": 1e-12, "pdas_settle": 0.75, "centred_back": 0,
                "centred_loose": True}

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self._active: tuple[np.ndarray, np.ndarray] | None = None
        self._ipm_warm: tuple[np.ndarray, np.ndarray] | None = None
        self._factor = None  # kept across fits: its symbolic analysis holds while Q's pattern does
        self._pattern: GramPattern | None = None
        self._centred: tuple | None = None

    def reset(self) -> None:
        self._active = None
        self._ipm_warm = None
        self._factor = None
        self._pattern = None
        self._centred = None

    def warm(self, w: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        # the previous solve's bounds as PDAS's first guess (weights within round-off of a bound)
        tol = 1e-9 * np.maximum(np.abs(lower), 1e-300)
        self._active = (w <= lower + tol, np.isfinite(upper) & (w >= upper - tol))

    def _fit(self, *, A, b, lower, upper, w0, prox, rtol, deadline):
        t0 = time.perf_counter()
        A = sp.csc_matrix(A)
        if self._pattern is None or not self._pattern.matches(A):  # (one structure for a whole solve)
            self._pattern = GramPattern(A)
        # (the structural pattern, linalg.structural_gram: the one CHOLMOD orders well)
        Q = self._pattern.gram(A, shift=prox if prox > 0 else 0.0)
        c = A.T @ b + prox * w0
        w, it, status = None, 0, "max_iter"
        # (spd_factor starts afresh when the size changed)
        lowq = _LowerQ(Q, self._factor, self._pattern, dense=self._pattern.dense_part(A))
        if lowq.dense is not None:  # a high-valence vertex's rows, kept out of the sparse Gram matrix
            Q = SplitGram(Q, lowq.dense)
        guess = None
        if self._active is not None and self._active[0].shape == w0.shape:
            w, it, status, guess = self._pdas(lowq, Q, c, lower, upper, *self._active, deadline=deadline)
        wi = z = None
        if status not in ("optimal", "time_limit"):
            loose = rtol is not None and rtol > self.options["tol"]
            back = int(self.options["centred_back"])
            trail = deque(maxlen=back + 1) if back > 0 else None
            wi, z, y, it_ipm, st_ipm = _box_qp_ipm(Q, c, lower, upper, w0, rtol if loose else self.options["tol"],
                                                   self.options["max_ipm"], warm=self._ipm_warm, lowq=lowq,
                                                   deadline=deadline, trail=trail,
                                                   centred=self._centred if back and (
                                                       self.options["centred_loose"] or not loose) else None)
            if trail is not None and len(trail) == back + 1:
                self._centred = trail[0]
            # crossover: bounds whose multiplier dominates their slack start PDAS
            ws = max(float(np.median(np.abs(wi))), 1e-300)
            gs = max(float(np.abs(c).max()), 1e-300)
            lo = z * ws > (wi - lower) * gs
            up = np.isfinite(upper) & (y * ws > (upper - wi) * gs) & ~lo
            guess = (lo, up)
            if loose and st_ipm == "optimal":  # the caller accepts this accuracy: no crossover
                it += it_ipm
                w, status = wi, "inexact"
            elif st_ipm == "time_limit":  # no time for the crossover: the interior point as it is
                it += it_ipm
                w, status = wi, "time_limit"
            else:
                wp, it_pd, st_pd, guess = self._pdas(lowq, Q, c, lower, upper, lo, up, deadline=deadline)
                it += it_ipm + it_pd
                w, status = (wp, st_pd) if st_pd == "optimal" else (wi, st_ipm)
        self._factor = lowq.factor
        if w is None:  # stopped before PDAS solved anything
            w = np.asarray(w0, float)
        w = np.clip(w, lower, upper)
        g = Q @ w - c
        if status == "optimal" or guess is None:
            guess = ((w <= lower) & (g > 0), (w >= upper) & (g < 0))
        # next call's warm starts: this active set (for an interior point: the crossover's guess)
        self._active = guess
        # (an inexact fit's own interior point and multipliers; else the point and its gradient)
        self._ipm_warm = (wi, z) if status in ("inexact", "time_limit") and wi is not None \
            else (w, np.maximum(g, 0.0))
        return WeightFit(w=w, objective=_objective(A, b, w), iterations=it, status=status,
                         seconds=time.perf_counter() - t0, n_lower=int(guess[0].sum()), n_upper=int(guess[1].sum()))

    def _pdas(self, lowq, Q, c, lower, upper, lo, up, deadline=None):
        """PDAS from the guess (lo, up): fix those bounds, solve for the rest, release bounds
        whose multiplier has the wrong sign and fix variables that left the box; stop when the
        guess repeats (then the KKT conditions hold exactly), or give up when the number of
        changed bounds stops halving (then it would cycle), or when the next solve would end past
        ``deadline`` (status ``"time_limit"``, ``w`` None if none was made). Returns w,
        iterations, status and the last guess."""
        w = None
        changes = []
        t_solve = 0.0
        for it in range(1, self.options["max_pdas"] + 1):
            if out_of_time(deadline, t_solve):
                return w, it - 1, "time_limit", (lo, up)
            t_it = time.perf_counter()
            w = self._reduced_solve(lowq, Q, c, lower, upper, lo, up)
            t_solve = time.perf_counter() - t_it
            g = Q @ w - c
            lo_n = np.where(lo, g > 0, w < lower)
            up_n = np.where(up, g < 0, w > upper) & ~lo_n
            if np.array_equal(lo_n, lo) and np.array_equal(up_n, up):
                return w, it, "optimal", (lo, up)
            changes.append(int(np.sum(lo_n != lo) + np.sum(up_n != up)))
            lo, up = lo_n, up_n
            if len(changes) > 1 and changes[-1] > max(self.options["pdas_settle"] * changes[-2], 10):
                break  # the guess is not settling: leave it to the interior point
        return w, it, "max_iter", (lo, up)

    @staticmethod
    def _reduced_solve(lowq, Q, c, lower, upper, lo, up):
        """The free variables' equations with the fixed ones at their bounds, solved in the
        full-size system whose fixed rows and columns are decoupled (one pattern throughout)."""
        fixed = lo | up
        w = np.where(lo, lower, np.where(up, upper, 0.0))
        if not fixed.any():
            return lowq.with_diagonal(np.zeros(Q.shape[0])).solve(c)
        lu, keep = lowq.fixing(fixed)
        rhs = c - Q @ np.where(fixed, w, 0.0)
        rhs[fixed] = keep[fixed] * w[fixed]
        out = lu.solve(rhs)
        out[fixed] = w[fixed]  # exactly at the bound
        return out


class CentredActiveSetFit(ActiveSetFit):
    """:class:`ActiveSetFit` whose interior point restarts from a centred iterate of the
    previous fit (``centred_back`` iterations before its end) instead of from the previous
    solution nudged off its bounds: the barrier path of the next, nearby problem passes close
    to it (a continuation that keeps the interior point centred). Exact fits only
    (``centred_loose`` False): their minimiser is unique, so the staggered iteration follows
    the same path as with :class:`ActiveSetFit`, only cheaper."""

    name = "active-set-centred"
    defaults = {**ActiveSetFit.defaults, "centred_back": 1, "centred_loose": False}


class CentredAllActiveSetFit(ActiveSetFit):
    """The centred restart for every fit, the loose far-phase fits included: their points then
    lie nearer the optimum (a 16k disk: objective 0.1–40% lower at the same tolerance), which
    changes the staggered iteration's path and is not faster at every size, hence not the default."""

    name = "active-set-centred-all"
    defaults = {**ActiveSetFit.defaults, "centred_back": 5, "centred_loose": True}
