"""The Step-2 fit at fixed positions, for ``check``: the best compressive weights of each load
case for a surface as it is, in the staggered method's units, bounds and backend, then
corrected by LSMR where the box fit's normal equations stall.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import lsmr

from formulations import Problem
from formulations.equilibrium import load_vector, weight_matrix
from selfsupport.methods.staggered import StaggeredOptions
from selfsupport.methods.weightfit_backends import make_backend

#: :func:`fit_weights` starts with the staggered method's proximal weight
#: (``StaggeredOptions.prox_w``, relative to the mean squared column norm of the scaled A) and
#: divides it by :data:`PROX_STEP` per refit down to :data:`PROX_FLOOR`: a continuation towards
#: the unregularised fit. Below ~1e-16 the normal equations' round-off (~1e-9 relative error)
#: dominates, and prox = 0 makes the interior-point fallback factor a singular matrix.
PROX_STEP = 100.0
PROX_FLOOR = 1e-16
#: Max relative error of a fit below which no further refinement is attempted.
REFINED = 1e-13
#: LSMR iterations between checks of the max relative error (:func:`lsmr_correction`).
LSMR_CHUNK = 500


@dataclass(frozen=True, eq=False)
class WeightFitReport:
    """The Step-2 fit at fixed positions, in SI units."""

    weights: np.ndarray  # per active edge [N/m]
    relative_errors: np.ndarray  # per free vertex
    E: float  # Σ_i relative_error_i² (the staggered method's fit energy)
    eps: float  # lower weight bound used [N/m]
    n_at_lower: int
    n_at_upper: int
    status: str  # the backend's status
    iterations: int


def fit_weights(problem: Problem, loads: np.ndarray | None = None, *, backend: str = "active-set",
                start: Sequence[np.ndarray | None] | None = None) -> list[WeightFitReport]:
    """Step 2 of the staggered method at the problem's positions, one fit per load case: the
    best weights in ``[eps, w_max]`` for the nodal loads (``loads``: (n_cases, n) [N]; default:
    those of the geometry), fitted to the *relative* residual, then corrected by LSMR
    (:func:`lsmr_correction`), which may leave some weights between 0 and ``eps`` (still
    compressive) when that brings the network into equilibrium.

    Same units as :class:`~selfsupport.methods.staggered.StaggeredLinearization`
    (:meth:`formulations.Problem.scaled`): lengths / bounding-box diagonal, forces / mean nodal
    load, rows divided by ``|A_i F_i|``, the default ``eps`` of
    :func:`~formulations.scaling.default_eps`, and the same small proximal term.

    ``start``: per load case, weights [N/m] on the active edges to start from (clipped to the
    bounds; ``None``: from ``eps``), e.g. a network file's own. A start within the bounds that
    already fits is returned as it is; from a clipped one the fit can end worse than from ``eps``
    (a solved 400-vertex concave disk: 3.5e-6 against 7.3e-14), so callers compare.
    """

    prob = problem.scaled(loads)
    top, sc, X, lower, upper = prob.top, prob.scaling, prob.X, prob.lower, prob.upper
    free = top.free
    A = weight_matrix(top, X)
    reports = []
    for k, L in enumerate(prob.L):
        s = np.repeat(1.0 / np.abs(L[free]), 3)
        As = sp.diags(s) @ A
        bs = s * load_vector(top, L)
        col2 = float(np.asarray(As.multiply(As).sum(axis=0)).mean())
        rel_prox = [StaggeredOptions().prox_w]
        while rel_prox[-1] / PROX_STEP >= PROX_FLOOR * (1 - 1e-9):
            rel_prox.append(rel_prox[-1] / PROX_STEP)
        be = make_backend(backend)
        fit, rel, iterations = None, None, 0
        given = start[k] if start is not None and k < len(start) else None
        w0 = lower.copy() if given is None else np.clip(sc.weight(np.asarray(given, float)), lower, upper)
        # The proximal term (needed: A has more columns than rows, so the plain fit has a face of
        # minimisers) biases the answer towards w0; in the staggered loop w0 is the previous iterate
        # and the bias fades, here it would not: on a solved barrel vault one fit leaves 6e-4 where
        # 1e-12 is attainable. So continue with a shrinking proximal weight, each fit warm-started
        # from the last, while that helps; then correct the residual with LSMR.
        for rp in rel_prox:
            fit = be.fit(A=As, b=bs, lower=lower, upper=upper, w0=w0, prox=rp * col2)
            w0, iterations = fit.w, iterations + fit.iterations
            prev = rel
            rel = np.linalg.norm((As @ fit.w - bs).reshape(-1, 3), axis=1)
            if rel.size == 0 or rel.max() <= REFINED or (prev is not None and rel.max() > 0.5 * prev.max()):
                break  # exact enough, or the normal equations' floor: further stages do not help
        w = fit.w
        if rel.size and rel.max() > REFINED:
            w, rel = lsmr_correction(As, bs, w, lower, upper, rel)
        reports.append(WeightFitReport(weights=sc.weight_back(w), relative_errors=rel, E=float(rel @ rel),
                                       eps=float(sc.weight_back(lower.min())), n_at_lower=int(np.sum(w <= lower)),
                                       n_at_upper=int(np.sum(w >= upper)), status=fit.status,
                                       iterations=iterations))
    return reports


def lsmr_correction(A: sp.spmatrix, b: np.ndarray, w: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            rel: np.ndarray, max_rounds: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares corrections of the weights off their bounds, by LSMR on A itself.

    The box fit works on the normal equations AᵀA, whose condition number is the square of
    A's; on networks that are in equilibrium to 1e-13 it stalls at relative errors of 1e-8
    (solved barrel vault, 300 vertices) to 4e-6 (solved lilium, weights spanning four orders
    of magnitude, several hundred of them at ε), returning an interior point. Here the weights
    the fit holds on a bound stay there; LSMR gives the minimum-norm correction of the others;
    a corrected weight that turns tensile (< 0) or exceeds ``upper`` is fixed at its bound and
    the correction repeated. The lower bound of this correction is 0, not ε: whether the
    surface stands is a question of compression, ε only keeps the fit away from degenerate
    zero weights. The corrected weights are kept only if they lower the max error.
    """

    A = sp.csc_matrix(A)
    fixed = (w <= lower) | (w >= upper)
    best_w, best_rel = w, rel
    for _ in range(max_rounds):
        free = ~fixed
        if not free.any():
            break
        base = np.where(fixed, np.clip(w, lower, upper), w)
        Af, r0 = A[:, free], b - A @ base
        d, worst, limit, done = None, np.inf, 20 * int(free.sum()), 0
        d_best = None
        while done < limit:
            # (in chunks, warm: its tolerances are out of reach by design, and run to the limit it
            # spent 120k iterations, 16 s, on a 2k-vertex network for a gain of 20% in the max error)
            d = lsmr(Af, r0, atol=1e-16, btol=1e-16, maxiter=LSMR_CHUNK, x0=d)[0]
            done += LSMR_CHUNK
            now = float(np.linalg.norm((Af @ d - r0).reshape(-1, 3), axis=1).max(initial=0.0))
            if now < worst:  # (LSMR lowers the 2-norm; the max over vertices may rise in a chunk)
                d_best = d
            if now <= REFINED or now > 0.5 * worst:
                break  # exact enough, or stalled: the last chunk did not halve the max error
            worst = now
        d = d_best
        w2 = base.copy()
        w2[free] += d
        bad = free & ((w2 < 0) | (w2 > upper))
        if not bad.any():
            rel2 = np.linalg.norm((A @ w2 - b).reshape(-1, 3), axis=1)
            if rel2.max() < best_rel.max():
                best_w, best_rel = w2, rel2
            break
        fixed |= bad
        w = np.clip(w2, lower, upper)
    return best_w, best_rel


