"""The paper's staggered linearization (§3, Steps 0–4), in scale-free units.

Step 1 computes the loads of the current geometry; Step 2 fits the weights with the positions
held (a box-constrained sparse least-squares fit of the relative residual, one per load case);
Step 3 moves the positions with the weights held (a sparse SPD least-squares step: the
equilibrium residual, the problem's objective relaxed by α, a proximal step β, the masonry hull
as hard bounds); Step 4 accepts a trial only when Steps 1-2 there lower the fit error, and
shrinks α and β as it falls. Near equilibrium the iterate is polished: weights frozen, positions
solved exactly from (2)-(3) with loads consistent with the geometry. The theory, and why each
rule is there: docs/theory/staggered.md.

Modules: :mod:`.options` (settings), :mod:`.method` (the entry point), :mod:`.run` (one solve as
named steps), :mod:`.state` (a fit, a finish attempt, the loop's state), :mod:`.schedule` (α, β
and the stall/creep rules), :mod:`.step3` (the position step's numerics), :mod:`.finish` (the
finish try), :mod:`.conclude` (final polish and verdict).
"""
from __future__ import annotations

from selfsupport.methods.polish import polish as _polish
from selfsupport.methods.staggered.method import StaggeredLinearization, _couples_first
from selfsupport.methods.staggered.options import DEFAULT_OBJECTIVE, StaggeredOptions, parse_option
from selfsupport.methods.staggered.schedule import COUPLE_MAX, DAMPING_MAX
from selfsupport.methods.staggered.step3 import _solve_blocks

__all__ = ["COUPLE_MAX", "DAMPING_MAX", "DEFAULT_OBJECTIVE", "StaggeredLinearization", "StaggeredOptions",
           "_couples_first", "_polish", "_solve_blocks", "parse_option"]
