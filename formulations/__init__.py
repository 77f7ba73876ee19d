"""The thrust-network problem stated once.

* :mod:`formulations.problem` — :class:`Problem`: scene + load cases + bounds + objective +
  constraints, with its scale-free units; what every method consumes;
* :mod:`formulations.equilibrium` — eqs. (2)-(3): the CasADi statement and its sparse numeric form;
* :mod:`formulations.terms` — one class per objective term (``TERMS`` registry), each with a
  CasADi residual and a numeric Gauss–Newton linearization;
* :mod:`formulations.loadcases` — :class:`LoadCases`, the named set of load cases;
* :mod:`formulations.peel` — which meshes carry two cases on one geometry only at a degenerate
  vertex star (the peel of their weights' difference from the free edges);
* :mod:`formulations.scaling` — the scale-free units;
* :mod:`formulations.nlp` — :class:`ThrustNetworkProblem`, the NLP handed to IPOPT / nlopt.
"""
from formulations.equilibrium import GROUP_NAMES, Equilibrium, Topology, WeightBounds
from formulations.loadcases import DEFAULT_CASE, LoadCases
from formulations.nlp import ThrustNetworkProblem
from formulations.problem import (
                      CONSTRAINTS,
                      Bounds,
                      FixedTopView,
                      Hull,
                      ObjectiveTerm,
                      Planar,
                      Problem,
                      ScaledProblem,
                      parse_objective,
)
from formulations.scaling import Scaling, default_eps
from formulations.terms import (
                      TERMS,
                      Fairness,
                      HullPenalty,
                      NormalDrift,
                      PlanarFaces,
                      Planarity,
                      PlanarityVolume,
                      PointDistance,
                      ReferenceDistance,
                      Scaled,
                      Sum,
                      Term,
                      TermContext,
)

__all__ = ["Problem", "ScaledProblem", "Bounds", "Hull", "FixedTopView", "Planar", "CONSTRAINTS", "ObjectiveTerm",
           "parse_objective", "LoadCases", "DEFAULT_CASE", "GROUP_NAMES", "Equilibrium", "Topology", "WeightBounds",
           "TERMS", "Term", "TermContext", "Sum", "Scaled", "PointDistance", "ReferenceDistance", "NormalDrift",
           "Planarity", "PlanarityVolume", "PlanarFaces", "Fairness", "HullPenalty", "ThrustNetworkProblem", "Scaling", "default_eps"]
