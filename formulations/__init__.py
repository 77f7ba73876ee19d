"""The thrust-network problem stated once, symbolically, in CasADi.

* :mod:`formulations.equilibrium` — unknowns, the residual of eqs. (2)-(3), weight bounds;
* :mod:`formulations.objectives` — one class per objective term (``TERMS`` registry);
* :mod:`formulations.problem` — :class:`ThrustNetworkProblem`, the NLP handed to solvers.
"""
from .equilibrium import GROUP_NAMES, Equilibrium, WeightBounds
from .objectives import (TERMS, Fairness, NormalDrift, Planarity, PointDistance, ReferenceDistance, Scaled, Sum,
                         Term)
from .problem import ThrustNetworkProblem

__all__ = ["GROUP_NAMES", "Equilibrium", "WeightBounds", "TERMS", "Term", "Sum", "Scaled", "PointDistance",
           "ReferenceDistance", "NormalDrift", "Planarity", "Fairness", "ThrustNetworkProblem"]
