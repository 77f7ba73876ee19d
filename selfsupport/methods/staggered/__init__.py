"""The paper's staggered linearization (§3, Steps 0–4), in scale-free units.

Step 1  loads from the current geometry.
Step 2  weights with positions fixed: a box-constrained sparse least-squares fit of the
        relative residual ``(A w − b)_i / |A_i F_i|`` (pluggable backend, warm-started). While
        the fit error is above ``finish_try`` the backend may stop at a KKT tolerance of
        ``fit_rtol`` = 1e-3: those fits only steer the iteration. A loose fit overstates
        min_w E, so it may reject a step that lowers it; a rejection is therefore confirmed by an
        exact fit (without that, a 4k concave disk stalled at its first step), and when the exact
        fit overturns it the tolerance is tightened tenfold for the rest of the solve (a 64k
        disk, whose E falls by ~0.1% per step, otherwise paid an exact fit on every step).
        Measured against 1e-6 on 37 solves (paper scenes, rotated/scaled and jittered variants,
        generated shapes): all converge, 7 end closer to the reference (up to 30%), 4 farther
        (up to 6%); lilium takes 0.71-0.83x the time (two alternating measurements). The fits
        the finish and the polish use are exact (a loosely fitted iterate waits one step for
        its exact fit before the finish is tried).
Step 3  positions with weights fixed: a sparse SPD linear least-squares problem

            Σ_c Σ_i ‖r_c,i / d_i‖² + α Σ_t μ_t ‖r_t + J_t Δx‖² + Σ_h μ_h ‖r_h + J_h Δx‖² + β ‖Δx‖²

        the equilibrium residual of every load case ``c`` (rows scaled by ``1 / |A_i F_i|``, the
        error the fit measures), plus the problem's objective terms (:mod:`formulations.terms`,
        each Gauss–Newton-linearized at the iterate, weight ``μ_t``) relaxed by α, plus a
        proximal step β; the masonry hull is held as hard bounds (vertices a step carries out are
        pinned to its face and the step solved again, then projected). The penalties
        are multiplied by the mean ``(d_i / |A_i F_i|)²``, ``d_i = Σ_j w_ij``, which turns the
        relative residual into a length. Without an objective in the problem the method uses
        :data:`DEFAULT_OBJECTIVE`: the distance to the reference surface (tangent-plane
        linearization at the closest point ``p_i``, normal ``n_i``, re-projected as the vertex
        slides, with a weak tangential hold τ). Whatever the objective, the step also asks for a
        smooth displacement (option ``smoothing``: γ ‖U (v − v_ref)‖², U the umbrella Laplacian,
        γ/α = 100, the :class:`~formulations.terms.Fairness` term). It belongs to the method, not
        to the problem: it keeps vertices whose weights sit at ε from being thrown far away
        along the penalty path (with the vertex-distance objective alone a concave disk ended
        1.5 diagonals away), as the original tool's smoothing did; the refinement and the
        reported objective use the problem's terms only. All terms are lengths relative to the
        bounding-box diagonal, so the weights are dimensionless.
        Terms that act on x, y, z alike (fairness, vertex distance) enter one n×n matrix; terms
        whose rows each involve one vertex (reference distance, hull) enter 3×3 blocks; the
        system is solved by CG preconditioned with one n×n factorization (:func:`_solve_blocks`).
        Other terms (planarity) couple neighbouring vertices' coordinates: then the 3n×3n system
        is factored. With a fixed top view only the heights move (an n×n system).
Step 4  repeat. A trial position is accepted only if Steps 1-2 there give a smaller fit error
        (the merit is E(X) = min_w E(X, w), so the iteration is a descent method); otherwise β is
        multiplied by 4 and the step retried (a trust region). After an accepted step α and β
        shrink, α in proportion to the square root of the error reduction, so the iteration goes
        from "stay on the reference" towards "satisfy equilibrium" as fast as the error allows.
        From the third rejection in a row α shrinks too: by then the steps are short, and what
        stops the descent is the anchor itself (the positions sit at a stationary point of the
        Step-3 objective for this α). A flat disk with ``w_max`` stalled this way (w_max 3e3 and
        1e4 of 1e2...1e5; 1e2 fails in IPOPT too); on the paper's scenes no step is rejected.
        Once α is at ``alpha_min`` the reference no longer holds the network; if the fit error
        then does not halve within ``stall_window`` iterations the design is taken as
        infeasible and the solve stops "stalled" (the paper's scenes spend at most 2 iterations
        at ``alpha_min``; without the rule a 1200-vertex vault with one pillar base freed ran on
        to the 200-iteration limit, the network drifting further all the while). Before it
        stalls, the run tries the finish once more (below). If the fit error does not halve in
        ``creep_window`` iterations there, Step 3 turns coupled (below) for the rest of the run:
        with the weights held it creeps under a point load, whose cone needs both to move.
Coupled (option ``coupled``) Step 3 may also move the weights that are not at a bound, with a
        damping ∝ 1/(w − ε)² so that weights near ε hardly move: a Gauss-Newton step on the
        reduced error min_w E(X, w) instead of on E(X, w_k). It follows the penalty path more
        faithfully (measured: up to 1.65× closer to the reference on the paper's scenes) but costs a
        (3n + C·m)-sized factorization per step (C load cases, each moving its own weights); a
        rejected coupled step falls back to the plain one, and when that one is taken the
        damping is raised tenfold for the next coupled step (halved after an accepted one, down
        to ``coupled_damping``, up to :data:`DAMPING_MAX`). Not the default: slower, and its
        weights are less reproducible under rotations and scalings of the input (up to ~1.5% of
        the weight moves, against < 1% for the plain step) — except with planar faces or load
        cases that are not proportional, where it is tried first (:func:`_couples_first`).
Finish  once the fit's max relative error is below ``finish_try``, every accepted step tries the
        polish below with the current weights and keeps it when the polished network is in
        equilibrium and its mean distance to the reference exceeds the iterate's by at most
        ``finish_slack``: finishing then costs (almost) no closeness, and iterating on could only
        drift. Once α is at ``alpha_min`` nothing pulls the iterate towards the reference any
        more, and the slack is ``finish_slack_released``. A try is screened first: positions in
        equilibrium with the weights and the iterate's loads (one stress-Laplacian solve)
        predict the polished distance, and a try
        predicted far beyond the slack is not polished (twocirc-3: 4 tries of 20–33 ms skipped,
        0.83× the time, the same network). A try uses Newton only: one that Newton cannot
        finish fails cheaply (the fixed-point fallbacks took 0.7 s of 1.9 s on a 1k concave
        disk for a try that failed anyway). The linear systems are factored by CHOLMOD (:mod:`selfsupport.core.linalg`).
Polish  once the fit's max relative error is below ``polish_tol``, the weights are frozen and
        the positions solved exactly from (2)-(3) — a stress-Laplacian system — with the loads
        re-estimated from the new geometry until they are consistent to round-off (Newton with
        a coloured finite-difference load Jacobian; :mod:`~selfsupport.methods.polish`). The
        result is in equilibrium to machine precision with loads of its own geometry. With
        several load cases, or a fixed top view, frozen weights cannot balance every case (or
        x and y) by moving the positions alone: the polish is then a minimum-norm Newton
        iteration on positions and the weights off their bounds together
        (:func:`~selfsupport.methods.polish.polish_joint`).
"""
from __future__ import annotations

from selfsupport.methods.polish import polish as _polish  # noqa: F401  (tests patch it here)
from selfsupport.methods.staggered.method import StaggeredLinearization
from selfsupport.methods.staggered.method import _couples_first as _couples_first
from selfsupport.methods.staggered.options import DEFAULT_OBJECTIVE, StaggeredOptions, parse_option
from selfsupport.methods.staggered.schedule import COUPLE_MAX, DAMPING_MAX
from selfsupport.methods.staggered.step3 import _solve_blocks as _solve_blocks

__all__ = ["COUPLE_MAX", "DAMPING_MAX", "DEFAULT_OBJECTIVE", "StaggeredLinearization", "StaggeredOptions",
           "parse_option"]
