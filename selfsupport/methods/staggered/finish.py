"""The finish try: polish the iterate with its weights, and keep it when that costs no closeness.

Once the fit error is below ``finish_try``, every new iterate is polished (positions exact for
its weights, loads consistent) and the polish is kept when it is in equilibrium and its mean
distance to the reference exceeds the iterate's by at most the slack: iterating on could then
only drift. With one load case and a free top view a screen comes first (one stress-Laplacian
solve predicts the polished distance) and the polish is Newton only. With several cases, a fixed
top view, a hull or planar faces it is the joint polish, which moves the weights with the
positions: near equilibrium its Newton steps converge where Step 3, with the weights held, creeps.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from formulations.equilibrium import Topology, position_blocks, residual
from selfsupport.core.evidence import closest_points
from selfsupport.core.linalg import spd_factor
from selfsupport.core.mesh import PolyMesh
from selfsupport.methods.base import HULL_TOL, cases_max_error, planarity_report
from selfsupport.methods.staggered.state import FinishAttempt, FitState

if TYPE_CHECKING:
    from selfsupport.methods.staggered.run import _Run


def screen_ratio(*, top: Topology, X: np.ndarray, w: np.ndarray, L: np.ndarray, reference: PolyMesh,
                 d_it: np.ndarray, workspace: dict | None = None) -> float | None:
    """Mean distance to ``reference`` of the positions in equilibrium with ``w`` and the
    iterate's loads ``L`` (one stress-Laplacian solve), over the iterate's ``d_it``: a
    prediction of the polished distance. None when that solve breaks down. ``workspace`` (a
    dict kept across tries, the polish's) holds the factor: the polish that follows factors the
    same matrix, and the next try reuses its symbolic analysis."""
    free = top.free
    Kff, Kfs = position_blocks(top, w)
    B = np.zeros((top.n_free, 3))
    B[:, 2] = L[free]
    Xs = X.copy()
    ws = workspace if workspace is not None else {}
    ws["laplacian"] = spd_factor((-Kff).tocsc(), reuse=ws.get("laplacian"))  # (the polish's factor too)
    Xs[free] = ws["laplacian"].solve(Kfs @ X[~free] - B)  # −K_ff X_f = K_fs X_s − B
    if not np.all(np.isfinite(Xs)):
        return None
    return float(closest_points(Xs, reference)[1].mean() / max(float(d_it.mean()), 1e-300))


def try_finish(run: _Run, X: np.ndarray, fit: FitState, *, d_it: np.ndarray, slack: float) -> FinishAttempt | None:
    """Polish the iterate ``X`` with the weights of ``fit`` and check it: in equilibrium, inside
    the hull, planar, and no farther from the reference than the iterate (``d_it`` its
    distances; mean within ``slack``, max within 4× that). None when the polish breaks down.

    A polish that meets everything but ``tol`` and is held above it by rounding alone carries
    its ``roundoff_limit``: the iteration stops there (more iterations cannot lower it)."""
    opt = run.opt
    screened = None
    if not run.joint:  # one case, free top view: a screen first, then Newton only
        screened = screen_ratio(top=run.top, X=X, w=fit.w[0], L=fit.L[0], reference=run.reference, d_it=d_it,
                                workspace=run.polish_ws)
        if screened is None:
            return None
        if screened > 1 + opt.finish_screen:
            return FinishAttempt(ok=False, screened=screened)
    Xp, ws, L, rounds = run.polish(X, fit.w, fallbacks=bool(opt.try_fallbacks))
    if not np.all(np.isfinite(Xp)):
        return None
    inside = planar = None
    if run.joint:
        net, cases = run.networks(Xp, ws)
        err = cases_max_error(cases)
        # (the true distance: the slabs re-anchored at the polished positions)
        inside = run.hull is None or bool(np.all(
            np.abs(run.hull.at(Xp).signed_distance(Xp)) <= run.hull.half_thickness * (1 + HULL_TOL)))
        planar = run.planar is None or planarity_report(run.problem, net)["met"]
    else:
        free = run.top.free
        err = float((np.linalg.norm(residual(run.top, Xp, ws[0], L[0]), axis=1) / np.abs(L[0][free])).max())
    d_p = closest_points(Xp, run.reference)[1]
    ok = (err <= opt.tol and inside is not False and planar is not False
          and float(d_p.mean()) <= (1 + slack) * float(d_it.mean())
          and float(d_p.max()) <= (1 + 4 * slack) * float(d_it.max()))
    attempt = FinishAttempt(ok=bool(ok), X=Xp, w=ws, rounds=rounds, error=err, screened=screened,
                            inside_hull=inside, planar=planar,
                            dist_mean_ratio=float(d_p.mean() / max(d_it.mean(), 1e-300)),
                            dist_max_ratio=float(d_p.max() / max(d_it.max(), 1e-300)))
    if (not ok and err > opt.tol and inside is not False and planar is not False
            and attempt.dist_mean_ratio <= 1 + slack and attempt.dist_max_ratio <= 1 + 4 * slack):
        limit = run.roundoff_limit(run.networks(Xp, ws)[1])
        if limit is not None:
            attempt = replace(attempt, roundoff_limit=limit)
    return attempt
