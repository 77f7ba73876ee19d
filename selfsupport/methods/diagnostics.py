"""Warnings about a solve's result that the summary table alone does not make obvious.

Each is one line (the CLI prints them as ``selfsupport: warning: ...`` on stderr):

* the input warnings of :func:`selfsupport.methods.validate.validate_scene` (``parameters.input_issues``);
* a converged network far from its reference: mean distance above :data:`FAR_FROM_REFERENCE`
  of the bounding-box diagonal (an upside-down dome read with the wrong ``--up`` converges
  to a network 0.42 of the diagonal away and said nothing);
* a converged network with most free vertices outside the masonry hull, reference ± t/2
  (:data:`HULL_MAJORITY`; the demo left 504 of 652 outside, which only a figure showed);
* a refinement that kept none of its trial steps (under a point load the unrefined network can
  be the spike the refinement is there to remove: a half-supported vault ended 0.11 of the
  diagonal from its reference, and only the history said why).
"""
from __future__ import annotations

from typing import Any

from selfsupport.methods.base import hull_excess

#: A converged network whose mean distance to the reference exceeds this fraction of the
#: bounding-box diagonal is reported: equilibrium was reached by moving far from the design.
FAR_FROM_REFERENCE = 0.1
#: Warn when more than this fraction of the free vertices leave the masonry hull.
HULL_MAJORITY = 0.5


def solve_warnings(result: Any, scene: Any) -> list[str]:
    """The warnings (one line each, without a prefix) about ``result``, a
    :class:`~selfsupport.core.result.SolveResult` of ``scene`` (:func:`selfsupport.api.solve`'s, whose
    ``parameters`` carry the input issues and the self-weight's thickness)."""
    params = result.parameters
    out = [str(i.get("message")) for i in params.get("input_issues", ()) if i.get("severity", "warning") == "warning"]
    if result.converged and result.distance_mean > FAR_FROM_REFERENCE:
        out.append(f"the network is in equilibrium but far from its reference: mean distance "
                   f"{result.distance_mean:.2f} of the bounding-box diagonal (warned above {FAR_FROM_REFERENCE:g}); "
                   "check the vertical axis (--up) and the supports, or the shape cannot stand near its design")
    # (a network that is not in equilibrium gets its own line from the caller; where it sits
    # in the hull says nothing then)
    hull = _hull(result, scene) if result.converged else None
    if hull is not None and hull["free"] and hull["outside"] > HULL_MAJORITY * hull["free"]:
        out.append(f"{hull['outside']} of {hull['free']} free vertices lie outside the masonry hull (reference "
                   f"± t/2, t = {hull['thickness']:.3g} m; up to {hull['max_excess']:.3g} m beyond it): the network "
                   "does not fit in the shell; solve with the hull constraint (--hull) or a thicker shell")
    refine = [h for h in result.history if isinstance(h, dict) and h.get("iteration") == "refine"]
    if result.converged and refine and refine[-1].get("tried") and not refine[-1].get("applied"):
        out.append(f"the refinement towards the reference kept none of its {refine[-1]['tried']} trial steps: the "
                   f"network is the unrefined one (max distance {result.distance_max:.2g} of the bounding-box "
                   "diagonal; under a point load often a spike under it)")
    return out


def _hull(result: Any, scene: Any) -> dict | None:
    """The solve's own hull record (a problem with the hull constraint), else the same report
    for the self-weight's shell thickness."""
    if result.parameters.get("hull") is not None:
        return result.parameters["hull"]
    t = (result.parameters.get("loads") or {}).get("thickness")
    if not t:
        return None

    return hull_excess(scene, result.network, t)
