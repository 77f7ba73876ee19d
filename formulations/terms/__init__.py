"""Objective terms: one class per file, registered in :data:`TERMS` by name.

Adding a term is one class in one file and one line here; methods, the CLI
(``--objective NAME=WEIGHT``), sweeps and studies pick it up from the registry.

Example
-------
>>> import numpy as np
>>> V0 = np.zeros((2, 3))
>>> t = PointDistance(targets=V0) * 2.0 + PointDistance(targets=V0)
>>> float(t.value(np.ones((2, 3))))
18.0
>>> r, J = t.linearize(np.ones((2, 3)))
>>> J.shape, float(r @ r)
((12, 6), 18.0)
>>> sorted(TERMS)
['fairness', 'hull', 'normal_drift', 'planar', 'planarity', 'planarity_volume', 'reference', 'vertices']
"""
from formulations.terms.base import PlaneDistance, Scaled, Sum, Term, TermContext
from formulations.terms.fairness import Fairness
from formulations.terms.hull import HullPenalty
from formulations.terms.normal_drift import NormalDrift
from formulations.terms.planarity import PlanarFaces, Planarity, PlanarityVolume
from formulations.terms.reference import TANGENTIAL, ReferenceDistance
from formulations.terms.vertices import PointDistance

#: Registry of objective terms by name (``--objective NAME=WEIGHT``).
TERMS: dict[str, type[Term]] = {cls.name: cls for cls in
                                (ReferenceDistance, PointDistance, NormalDrift, Fairness, Planarity,
                                 PlanarityVolume, PlanarFaces, HullPenalty)}

__all__ = ["TERMS", "Term", "TermContext", "Sum", "Scaled", "PlaneDistance", "PointDistance", "ReferenceDistance",
           "NormalDrift", "Fairness", "Planarity", "PlanarityVolume", "PlanarFaces", "HullPenalty",
           "TANGENTIAL"]
