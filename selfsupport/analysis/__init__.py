"""Analysis of thrust networks (paper §2, §2.5, §5): the Airy stress surface Φ, the reciprocal
force diagram and the polar dual, curvatures relative to Φ (eqs. 5–6, relative principal
directions), and the construction of self-supporting networks from a convex Airy function.

>>> from selfsupport.analysis import airy, reciprocal, curvatures, construct
>>> from selfsupport.core.shapes import disk_points
>>> net = construct(disk_points(6), "paraboloid", load=-1.0)
>>> res = airy(net)
>>> float(abs(reciprocal(res).edge_residual).max()) < 1e-12
True
>>> curvatures(net, res).max_balance_residual < 1e-12
True
"""
from selfsupport.analysis.airy import AiryResult, Period, airy
from selfsupport.analysis.construction import (
                           AREA_RULES,
                           PHI_FUNCTIONS,
                           Construction,
                           construct,
                           construct_detailed,
                           lifting_weights,
                           lower_hull,
)
from selfsupport.analysis.curvature import Curvatures, curvatures, face_principal_directions, write_vector_fields
from selfsupport.analysis.reciprocal import ReciprocalDiagram, reciprocal

__all__ = ["airy", "AiryResult", "Period", "reciprocal", "ReciprocalDiagram", "curvatures", "Curvatures",
           "face_principal_directions", "write_vector_fields", "construct", "construct_detailed", "Construction",
           "lower_hull", "lifting_weights", "PHI_FUNCTIONS", "AREA_RULES"]
