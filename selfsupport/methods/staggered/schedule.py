"""When Step 3 turns coupled and how hard the coupled step holds the weights."""
from __future__ import annotations

#: Largest mesh (vertices) on which a creeping fit of one load case turns Step 3 coupled
#: (``creep_window``): the coupled step factors a (3n + m) system (a 16k pillar vault: 67 s with
#: the switch, 66 s without), beyond this the memory of that factor, not the iterations, would
#: decide. With C load cases the system is 3n + C·m (m ≈ 3n): the limit is scaled by 2 / (1 + C).
COUPLE_MAX = 24_000


def _coupled_fits(n_vertices: int, n_cases: int) -> bool:
    """Is the mesh small enough for the coupled step to be taken unasked (:data:`COUPLE_MAX`)?"""
    return n_vertices * (1 + n_cases) <= 2 * COUPLE_MAX

#: Strongest hold on the weights the coupled step's damping is raised to after rejected steps
#: (relative to the mean diagonal of the weights' Gram block, at the median gap to the bound):
#: beyond it the coupled step is the plain one in all but cost.
DAMPING_MAX = 1.0
