"""Step 4's schedule and the rules that end or redirect the iteration.

α weighs the objective in Step 3 and β the proximal step; an accepted step shrinks both (α in
proportion to the square root of the error reduction), a rejected one raises β fourfold (a trust
region) and, from the third rejection in a row, shrinks α too. Once α is at ``alpha_min`` the
reference no longer holds the network, and the fit errors from then on ("released") decide
whether Step 3 turns coupled (:func:`fit_creeps`) or the run stops (:func:`fit_stalls`).
"""
from __future__ import annotations

from dataclasses import dataclass

from selfsupport.methods.staggered.options import StaggeredOptions

#: Largest mesh (vertices) on which a creeping fit of one load case turns Step 3 coupled
#: (``creep_window``): beyond it the memory of the coupled step's (3n + m) factor, not the
#: iterations, would decide. With C load cases the system is 3n + C·m (m ≈ 3n): the limit is
#: scaled by 2 / (1 + C).
COUPLE_MAX = 24_000

#: Strongest hold on the weights the coupled step's damping is raised to after rejected steps
#: (relative to the mean diagonal of the weights' Gram block, at the median gap to the bound):
#: beyond it the coupled step is the plain one in all but cost.
DAMPING_MAX = 1.0

#: Window of the retry rule (:func:`retry_stopped`): iterations in which a retry's fit error must halve.
RETRY_WINDOW = 5


@dataclass
class Schedule:
    """Step 3's weights α (objective) and β (proximal step), and the rejected steps in a row."""

    alpha: float
    beta: float
    rejected: int = 0

    @classmethod
    def start(cls, opt: StaggeredOptions) -> Schedule:
        """The schedule at the first iteration (``alpha0``, ``beta0``)."""
        return cls(opt.alpha0, opt.beta0)

    def accept(self, ratio: float, opt: StaggeredOptions) -> None:
        """After an accepted step whose merit fell by ``ratio`` (new / old): shrink β, and α in
        proportion to ``√ratio``, towards "satisfy equilibrium" as fast as the error allows."""
        self.beta = max(self.beta * opt.shrink, opt.beta_min)
        self.alpha = max(self.alpha * min(1.0, ratio ** 0.5) * opt.shrink, opt.alpha_min)
        self.rejected = 0

    def reject(self, opt: StaggeredOptions) -> None:
        """After a rejected step: a smaller trust region (β × 4); from the third rejection in a
        row the steps are short and what stops the descent is the anchor itself, so α shrinks."""
        self.beta *= 4.0
        self.rejected += 1
        if self.rejected >= 3:
            self.alpha = max(self.alpha * opt.shrink, opt.alpha_min)

    def out_of_steps(self, opt: StaggeredOptions) -> bool:
        """No position step has lowered the fit error ``max_rejections`` times in a row."""
        return self.rejected > opt.max_rejections

    def released(self, opt: StaggeredOptions) -> bool:
        """α is at its minimum: the reference no longer holds the positions."""
        return self.alpha <= opt.alpha_min

    def finish_slack(self, opt: StaggeredOptions) -> float:
        """How much farther from the reference a finish may end: ``finish_slack``, or
        ``finish_slack_released`` once nothing pulls the iterate towards the reference."""
        return opt.finish_slack if self.alpha > opt.alpha_min else opt.finish_slack_released


def halving_missed(errors: list[float], window: int) -> bool:
    """The last error is above half the one ``window`` iterations before it."""
    return len(errors) > window and errors[-1] > 0.5 * errors[-1 - window]


def track_released(released: list[float], error: float, schedule: Schedule, opt: StaggeredOptions) -> list[float]:
    """The fit errors since α reached its minimum, ``error`` appended (empty while α is above it)."""
    return released + [error] if schedule.released(opt) else []


def coupled_fits(n_vertices: int, n_cases: int) -> bool:
    """Is the mesh small enough for the coupled step to be taken unasked (:data:`COUPLE_MAX`)?"""
    return n_vertices * (1 + n_cases) <= 2 * COUPLE_MAX


def fit_creeps(released: list[float], opt: StaggeredOptions, *, coupled: bool, fixed_xy: bool, n_vertices: int,
               n_cases: int) -> bool:
    """Creep: at α's minimum the plain Step 3 (weights held) has not halved the fit error in
    ``creep_window`` iterations, as under a point load, whose cone needs the weights and the
    positions to move together. Only for a plain step with a free top view, on meshes the
    coupled step fits (:func:`coupled_fits`), and with ``creep_window`` > 0."""
    return (not coupled and not fixed_xy and bool(opt.creep_window) and coupled_fits(n_vertices, n_cases)
            and halving_missed(released, opt.creep_window))


def fit_stalls(released: list[float], opt: StaggeredOptions) -> bool:
    """Stall: at α's minimum the fit error has not halved in ``stall_window`` iterations; the
    reference no longer holds the positions, and more iterations only move the network further
    (an infeasible design)."""
    return halving_missed(released, opt.stall_window)


def retry_stopped(retry_errors: list[float] | None) -> bool:
    """During a retry (a polish that missed equilibrium, iterating to a tighter fit): the fit
    error has not halved in :data:`RETRY_WINDOW` iterations, so polish again now."""
    return retry_errors is not None and halving_missed(retry_errors, RETRY_WINDOW)


def finish_due(gap: float, *, fresh: bool, last_try: float, warm_try: bool, fit_status: str,
               opt: StaggeredOptions) -> bool:
    """A finish try is due: a newly accepted iterate whose fit error (or planarity gap) is below
    ``finish_try`` and half the last try's (or a warm start's one try), fitted exactly (a trial
    fitted loosely waits one step: the finish polishes exact weights only)."""
    return (fresh and (gap <= min(opt.finish_try, 0.5 * last_try) or warm_try)
            and fit_status not in ("inexact", "time_limit"))


def tightened_rtol(rtol: float, opt: StaggeredOptions) -> float:
    """The far-phase fits' KKT tolerance after an exact fit overturned a loose fit's rejection:
    tenfold tighter, down to ``min(fit_rtol, 1e-6)``."""
    return max(0.1 * rtol, min(opt.fit_rtol, 1e-6))


def damping_after_fallback(damping: float) -> float:
    """The coupled step over-promised and the plain step was taken: hold the weights ten times
    harder in the next coupled step (up to :data:`DAMPING_MAX`)."""
    return min(10.0 * damping, DAMPING_MAX)


def damping_after_coupled_step(damping: float, opt: StaggeredOptions) -> float:
    """A coupled step was taken: halve the hold on the weights, down to ``coupled_damping``."""
    return max(0.5 * damping, opt.coupled_damping)
