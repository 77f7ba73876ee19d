"""Which method solves a problem when the user leaves the choice to us (``--method auto``).

The multilevel method (:mod:`.multilevel`) pays where the single-level staggered method's
schedule gets long: above :data:`~.multilevel.DIRECT_MAX` vertices, where it builds coarser
levels. Below it the multilevel method would solve on one level anyway, and the staggered
method is that solve. Measured with ``python -m studies.method_choice`` (CPU seconds, the
multilevel method given one coarser level at every size): at 1k–4k vertices the levels cost
more than they save on every shape, at 16k they paid on all but the dome, and a 64k pillar
vault converged in 40 s by levels where one level ran into its 600 s limit at fit error 0.44.

The rule looks at the problem only — never at the scene's name:

* the masonry hull (``--hull``): the staggered method (its penalty ladder is run on one level);
* at most :data:`~.multilevel.DIRECT_MAX` vertices: the staggered method;
* data tied to this mesh's vertices (point loads, extra masses, per-edge bounds, objective terms
  or constraints built on it: :func:`~.multilevel.why_not`): the staggered method — no coarser
  level can carry them;
* a start network: the multilevel method when it lies on one of the coarser scenes this one
  was subdivided from (the levels go up from it), else the staggered method from it;
* a scene subdivided from coarser designs: the multilevel method on those designs;
* a mesh without boundary (its top view has no outline to coarsen): the staggered method;
* otherwise the multilevel method on coarsened top views.

>>> from selfsupport.shapes import make_shape
>>> from formulations import Problem
>>> from selfsupport.loads import SelfWeight
>>> choose_method(Problem.build(make_shape("dome", n_vertices=300), SelfWeight())).method
'staggered'
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from formulations import Problem

__all__ = ["AUTO", "MethodChoice", "choose_method"]

#: The method name (``--method``) that leaves the choice to :func:`choose_method`.
AUTO = "auto"


@dataclass(frozen=True)
class MethodChoice:
    """The method :func:`choose_method` picked (a name of :data:`selfsupport.api.METHODS`) and
    why, in one line."""

    method: str
    why: str

    def as_dict(self) -> dict[str, str]:
        """What a result's ``parameters["method_choice"]`` records."""
        return {"requested": AUTO, "method": self.method, "why": self.why}


def choose_method(problem: Problem, *, warm_start: Any = None, direct_max: int | None = None) -> MethodChoice:
    """The method for ``problem``: ``"multilevel"`` where coarser levels can be built or exist
    and the mesh has more than ``direct_max`` vertices, else ``"staggered"`` (see the module
    docstring for the rule and its measurement).

    Parameters
    ----------
    problem
        The problem to solve (its scene, loads, bounds, objective, constraints).
    warm_start
        The network the solve starts from, if any (a network, a result or a
        :class:`~.warm.WarmStart`).
    direct_max
        Meshes up to this many vertices are solved on one level (default: the multilevel
        method's own, :data:`~.multilevel.DIRECT_MAX`).

    Returns
    -------
    MethodChoice
        The method's name and one line saying why.
    """
    # (imported here: the command line reads AUTO when it builds its parser)
    from ..design.subdivision import subdivision_parents
    from .multilevel import DIRECT_MAX, Multilevel, why_not
    from .warm import as_warm_start

    direct_max = DIRECT_MAX if direct_max is None else int(direct_max)
    scene = problem.scene
    n = scene.mesh.n_vertices
    size = f"{n:,} vertices"
    if problem.hull_thickness() is not None:
        return MethodChoice("staggered", f"{size}; the masonry hull search runs on one level")
    if n <= direct_max:
        return MethodChoice("staggered", f"{size} <= {direct_max:,}: one level is fastest at this size")
    why = why_not(problem)
    if why:
        return MethodChoice("staggered", f"{size}, but {why}: no coarser level can carry it, one level")
    if warm_start is not None:
        ml = Multilevel(direct_max=direct_max)
        if len(ml.levels_from(as_warm_start(warm_start).network, scene)) > 1:
            return MethodChoice("multilevel", f"{size} > {direct_max:,}, starting from a coarser design it was "
                                              "subdivided from: up its subdivision levels")
        return MethodChoice("staggered", f"{size}; starting from the given network, one level from it")
    if subdivision_parents(scene):
        return MethodChoice("multilevel", f"{size} > {direct_max:,}: the coarser designs it was subdivided "
                                          "from solved first")
    if not scene.mesh.boundary_loops:
        return MethodChoice("staggered", f"{size}, but the mesh has no boundary to coarsen: one level")
    return MethodChoice("multilevel", f"{size} > {direct_max:,}: coarsened top views solved first")
