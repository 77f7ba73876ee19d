"""The staggered iteration's state: a fit (Steps 1-2), a finish attempt, and the loop's own state."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from selfsupport.methods.staggered.schedule import Schedule


@dataclass(frozen=True)
class FitState:
    """Steps 1-2 at positions ``X`` (scaled units): the loads, one weight fit per load case and
    what the iteration reads of it."""

    X: np.ndarray  #: positions (n, 3)
    L: np.ndarray  #: nodal loads of every case at X, (n_cases, n)
    w: list[np.ndarray]  #: fitted weights, one vector per case
    As: list[sp.csc_matrix]  #: each case's A(X) with rows scaled by 1 / |L_i|
    E: float  #: the fit error Σ_c Σ_i ‖r_c,i‖² of the relative residuals
    merit: float  #: what a step must lower: E, plus the planarity rows when planar faces are required
    max_rel_error: float  #: the largest relative residual over the cases
    worst_vertices: list[int]  #: the ten vertices of largest residual in the worst case (mesh numbers)
    fit_iterations: int
    fit_status: str  #: "optimal", "inexact" (stopped at a KKT tolerance) or "time_limit"
    n_at_lower: int
    n_at_upper: int
    t_loads: float  #: seconds spent in Step 1
    t_weights: float  #: seconds spent in Step 2
    cpu_s: float  #: process CPU time when the fit was known
    planar_rows: np.ndarray | None = None  #: the planarity rows at X (planar faces required)

    def record(self) -> dict[str, Any]:
        """The fit's scalars for an iteration's history record."""
        rec = {"E": self.E, "max_rel_error": self.max_rel_error, "worst_vertices": self.worst_vertices,
               "fit_iterations": self.fit_iterations, "fit_status": self.fit_status, "n_at_lower": self.n_at_lower,
               "n_at_upper": self.n_at_upper, "t_loads": self.t_loads, "t_weights": self.t_weights,
               "cpu_s": self.cpu_s}
        if self.planar_rows is not None:
            rec["merit"] = self.merit
        return rec


@dataclass(frozen=True)
class FinishAttempt:
    """One finish try (:func:`~selfsupport.methods.staggered.finish.try_finish`): the iterate
    polished with its weights, and the checks that decide whether it ends the iteration."""

    ok: bool  #: in equilibrium (and inside the hull, planar) and no farther from the reference than allowed
    X: np.ndarray | None = None  #: polished positions; None when the screen skipped the polish
    w: list[np.ndarray] | None = None  #: the weights of the polished network
    rounds: int = 0  #: load rounds of the polish
    error: float | None = None  #: max relative residual of the polished network
    screened: float | None = None  #: screen's predicted mean-distance ratio (one case, free top view)
    inside_hull: bool | None = None  #: (the joint polish) inside the hull
    planar: bool | None = None  #: (the joint polish) faces planar within their tolerance
    dist_mean_ratio: float | None = None  #: polished mean distance to the reference / the iterate's
    dist_max_ratio: float | None = None  #: ... and the same for the largest distance
    roundoff_limit: dict | None = None  #: held above tol by rounding alone (Network.roundoff_limit)

    @property
    def ending(self) -> str | None:
        """How the attempt ends the iteration: "converged", "stalled" (at its round-off floor,
        above tol: stop there), or None (iterate on)."""
        if self.ok:
            return "converged"
        return "stalled" if self.roundoff_limit is not None else None

    def record(self) -> dict[str, Any]:
        """The checks for the history record (the fields that apply to this attempt)."""
        keys = ("ok", "error", "screened", "inside_hull", "planar", "dist_mean_ratio", "dist_max_ratio",
                "roundoff_limit")
        return {k: getattr(self, k) for k in keys if getattr(self, k) is not None}


@dataclass
class IterState:
    """The iteration's state between steps: the iterate and its fit, the schedule, and what the
    rules that end or redirect the loop remember."""

    X: np.ndarray  #: the iterate (scaled positions)
    fit: FitState  #: Steps 1-2 at X
    schedule: Schedule
    w_start: list[np.ndarray]  #: the cold start's first-fit centre (uniform weights per case)
    polish_tol: float  #: fit error at which the iteration hands over to the polish
    coupled: bool  #: Step 3 moves the free weights with the positions
    t_iteration: float  #: duration of the last iteration (the next starts only if it can end in time)
    warm_fit: FitState | None = None  #: the warm start's own fit (None: a cold start)
    warm_try: bool = False  #: one finish try from the warm start as it is, else a cold start
    it: int = 0  #: the current iteration
    history: list[dict[str, Any]] = field(default_factory=list)
    status: str = "iteration_limit"
    message: str = ""
    at_floor: bool = False  #: stopped by a finish try held above tol by rounding alone
    stalled_at: float | None = None  #: mean distance of the iterate where the stall rule stopped the run
    fresh: bool = True  #: the iterate is new (accepted, or the start): a finish try may be due
    finished: FinishAttempt | None = None  #: the finish attempt that ended the iteration
    last_try: float = np.inf  #: gap at the last finish try (the next waits for it to halve)
    released: list[float] = field(default_factory=list)  #: fit errors since α reached its minimum
    retry_errors: list[float] | None = None  #: fit errors since a retry began (None: no retry)
    proj: tuple | None = None  #: closest points of X on the reference (at most once per iterate)
