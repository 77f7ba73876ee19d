"""Which method solves a problem when the user leaves the choice to us (``--method auto``).

The multilevel method (:mod:`.multilevel`) pays where the single-level staggered method's
schedule gets long: each coarser level is a solve of its own, which costs more than it saves on
small meshes and less on large ones, and a network carried up the levels can end farther from
the reference than one solved on its own mesh. So small meshes, the paper's Table 1 scenes
among them, stay on one level. ``python -m studies.method_choice`` measures both methods on
built-in shapes and the paper's scenes and says whether :data:`LEVELS_ABOVE` lies between the
sizes where one level paid and where the levels did.

The rule looks at the problem only, never at the scene's name:

* the masonry hull (``--hull``): the staggered method (its penalty ladder runs on one level);
* at most :data:`LEVELS_ABOVE` vertices: the staggered method;
* data tied to this mesh's vertices (point loads, extra masses, per-edge bounds, objective terms
  or constraints built on it: :func:`~.multilevel.why_not`): the staggered method, since no
  coarser level can carry them;
* a start network: the multilevel method when it lies on one of the coarser scenes this one
  was subdivided from (the levels go up from it), else the staggered method from it;
* a scene subdivided from coarser designs: the multilevel method on those designs;
* a mesh without boundary (its top view has no outline to coarsen): the staggered method;
* otherwise the multilevel method on coarsened top views.

Above :data:`LEVELS_ABOVE` and up to the multilevel method's own
:data:`~.multilevel.DIRECT_MAX` the multilevel method is run with ``direct_max`` =
:data:`LEVELS_ABOVE`, so that it does build a coarser level there; above ``DIRECT_MAX`` it
runs as it is.

>>> from formulations import Problem
>>> from selfsupport.core.loads import SelfWeight
>>> from selfsupport.core.shapes import make_shape
>>> choose_method(Problem.build(make_shape("dome", n_vertices=300), SelfWeight())).method
'staggered'
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping

from selfsupport.core.subdivision import subdivision_parents
from selfsupport.methods.warm import as_warm_start

if TYPE_CHECKING:
    from formulations import Problem

__all__ = ["AUTO", "CANDIDATES", "LEVELS_ABOVE", "MethodChoice", "candidates", "choose_method"]

#: The method name (``--method``) that leaves the choice to :func:`choose_method`.
AUTO = "auto"
#: The methods :func:`choose_method` picks from.
CANDIDATES = ("staggered", "multilevel")
#: Meshes with more vertices than this are solved by levels where they can be: above the paper's
#: scenes (up to 2,348 vertices), below the sizes where the levels pay on every shape
#: (``studies.method_choice``).
LEVELS_ABOVE = 3000


def candidates(n_vertices: int) -> tuple[str, ...]:
    """The methods :func:`choose_method` may pick for a mesh of ``n_vertices``: the staggered
    method alone up to :data:`LEVELS_ABOVE` vertices, else any of :data:`CANDIDATES`.

    >>> candidates(500), candidates(50_000)
    (('staggered',), ('staggered', 'multilevel'))
    """
    return CANDIDATES if n_vertices > LEVELS_ABOVE else CANDIDATES[:1]


@dataclass(frozen=True)
class MethodChoice:
    """The method :func:`choose_method` picked (a name of :data:`selfsupport.api.METHODS`), one
    line saying why, and keywords for its constructor (:func:`selfsupport.api.make_method`)."""

    method: str
    why: str
    settings: Mapping[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """What a result's ``parameters["method_choice"]`` records."""
        return {"requested": AUTO, "method": self.method, "why": self.why, **({"settings": dict(self.settings)}
                                                                            if self.settings else {})}


def choose_method(problem: Problem, *, warm_start: Any = None, levels_above: int | None = None) -> MethodChoice:
    """The method for ``problem``: ``"multilevel"`` where the mesh has more than
    ``levels_above`` vertices and coarser levels exist or can be built, else ``"staggered"``
    (the rule: see the module docstring).

    Parameters
    ----------
    problem
        The problem to solve (its scene, loads, bounds, objective, constraints).
    warm_start
        The network the solve starts from, if any (a network, a result or a
        :class:`~.warm.WarmStart`).
    levels_above
        Meshes up to this many vertices are solved on one level (default :data:`LEVELS_ABOVE`).

    Returns
    -------
    MethodChoice
        The method's name, one line saying why, and its constructor's keywords.
    """
    levels_above = LEVELS_ABOVE if levels_above is None else int(levels_above)
    scene = problem.scene
    n = scene.mesh.n_vertices
    size = f"{n:,} vertices"
    if problem.hull_thickness() is not None:
        return MethodChoice("staggered", f"{size}; the masonry hull search runs on one level")
    if n <= levels_above:  # (as candidates(n) says for the default levels_above)
        return MethodChoice(CANDIDATES[0], f"{size} <= {levels_above:,}: one level is fastest at this size")
    # (imported only now: a small mesh's solve does not pay for loading the multilevel machinery)
    from selfsupport.methods.multilevel import DIRECT_MAX, Multilevel, why_not

    why = why_not(problem)
    if why:
        return MethodChoice("staggered", f"{size}, but {why}: no coarser level can carry it, one level")
    # (the multilevel method builds levels only above its direct_max)
    settings = {"direct_max": levels_above} if n <= DIRECT_MAX else {}
    more = f"{size} > {levels_above:,}"
    if warm_start is not None:
        if len(Multilevel(**settings).levels_from(as_warm_start(warm_start).network, scene)) > 1:
            return MethodChoice("multilevel", f"{more}, starting from a coarser design it was subdivided from: "
                                              "up its subdivision levels", settings)
        return MethodChoice("staggered", f"{size}; starting from the given network, one level from it")
    if subdivision_parents(scene):
        return MethodChoice("multilevel", f"{more}: the coarser designs it was subdivided from solved first",
                            settings)
    if not scene.mesh.boundary_loops:
        return MethodChoice("staggered", f"{size}, but the mesh has no boundary to coarsen: one level")
    return MethodChoice("multilevel", f"{more}: coarsened top views solved first", settings)
