"""The design problem, stated once: scene + load cases + weight bounds + objective +
constraints. Every method (staggered, refinement, polish, IPOPT, nlopt) and ``check`` consume
it; it owns its scale-free units (:meth:`Problem.scaled`).

    minimise    Σ_t weight_t · ‖r_t(V)‖²                        (objective terms, :mod:`.terms`)
    over        free positions V, one weight vector w_c per load case c
    subject to  Σ_j w_c,ij (v_j − v_i) = (0, 0, L_c,i(V))     every case, every free vertex (eqs. 2-3)
                lower ≤ w_c ≤ upper                              (scalar or per edge)
                |⟨n_i, v_i − p_i⟩| ≤ t/2                         (optional: the masonry hull)
                x_i, y_i fixed                                   (optional: fixed top view, the TNA setting)

``objective=None`` leaves the objective to the method's default (staggered: distance to the
reference surface + smooth displacement; simultaneous: distance to the reference vertices); an
explicit objective is used as stated by every method.

Example
-------
>>> from selfsupport.core.shapes import make_shape
>>> p = Problem.build(make_shape("dome", n_vertices=80), objective={"vertices": 1.0, "planarity": 10.0})
>>> [t.name for t in p.objective], p.loads.names
(['vertices', 'planarity'], ('self-weight',))
>>> sp = p.scaled()
>>> sp.L.shape[0] == len(p.loads) and bool((sp.L[:, sp.top.free] < 0).all())
True
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from formulations.equilibrium import Topology
from formulations.loadcases import LoadCases
from formulations.scaling import Scaling, default_eps
from formulations.terms import TERMS, Scaled, Sum, Term, TermContext
from selfsupport.core.errors import InputError
from selfsupport.core.geometry import edge_tributary_widths, edge_vectors

#: Largest nodal load magnitude [N] the arithmetic takes: forces are squared in norms and in the
#: fits (1e150² = 1e300, below the double range 1.8e308); its inverse is the smallest.
LOAD_LIMIT = 1e150


# ------------------------------------------------------------------------------ bounds
#: Pascals per megapascal (``--max-stress`` is stated in MPa).
MPA = 1e6


@dataclass(frozen=True, eq=False)
class Bounds:
    """Weight bounds [N/m], ``lower ≤ w ≤ upper`` on every active edge: the one statement of the
    bounds that every method honours (through :meth:`Problem.scaled`).

    ``lower`` (w_min; ``None``: the scale-free default ε of
    :func:`~formulations.scaling.default_eps`) and ``upper`` (w_max; ``None``: unbounded) are
    each a scalar, one value per mesh edge, or one per active edge. A NaN entry of a per-edge
    array is not stated: that edge takes the default (ε below, no bound above). ``lower`` may be
    zero or negative: a negative weight is tension, for structures that may take it (paper §5,
    steel and glass); ``upper`` must be positive (``inf``: unbounded on that edge).
    """

    lower: float | np.ndarray | None = None
    upper: float | np.ndarray | None = None

    @staticmethod
    def _per_active(value, scene, what: str, *, upper: bool) -> np.ndarray | float | None:
        if value is None:
            return None
        a = np.asarray(value, float)
        act = scene.active_edges
        if a.ndim == 0:
            out = float(a)
        elif a.shape == (scene.mesh.n_edges,):
            out = a[act]
        elif a.shape == (int(act.sum()),):
            out = a
        else:
            raise InputError(f"{what} has {a.shape} entries; give a scalar, one per mesh edge ({scene.mesh.n_edges}) "
                             f"or one per active edge ({int(act.sum())})")
        o = np.atleast_1d(np.asarray(out, float))
        stated = ~np.isnan(o) if a.ndim else np.ones(1, bool)  # (a scalar NaN is refused, not a default)
        bad = (~(o > 0) if upper else ~np.isfinite(o)) & stated
        if bad.any():
            k = int(np.argmax(bad))
            at = "" if a.ndim == 0 else f" on {_edge_name(scene, k)}"
            need = ("positive (the most force density an edge may carry; inf: unbounded)" if upper
                    else "a finite number (negative: tension allowed down to it)")
            raise InputError(f"{what} must be {need}, got {o[k]:g}{at}")
        return out

    def active(self, scene) -> tuple[np.ndarray | float | None, np.ndarray | float | None]:
        """``(lower, upper)`` restricted to the scene's active edges (scalars stay scalars; NaN
        entries: the default)."""
        return (self._per_active(self.lower, scene, "the lower weight bound (eps, w_min)", upper=False),
                self._per_active(self.upper, scene, "w_max", upper=True))

    def over(self, base: "Bounds") -> "Bounds":
        """These bounds where they are stated, ``base``'s on every other edge (a per-edge NaN is
        not stated): a bounds file over the command line's scalar bounds."""
        return Bounds(_overlay(self.lower, base.lower), _overlay(self.upper, base.upper))

    @property
    def has_upper(self) -> bool:
        if self.upper is None:
            return False
        u = np.asarray(self.upper, float)
        return bool(np.any(np.isfinite(u)))

    @property
    def allows_tension(self) -> bool:
        """Whether a stated lower bound is at or below zero (``--eps 0``, a negative ``--w-min``
        or file ``w_min``): the compression floor ε is lifted, and the solve reports its tension
        edges."""
        return self.lower is not None and bool(np.any(np.asarray(self.lower, float) <= 0))


def _overlay(top: Any, base: Any) -> Any:
    if top is None or (np.ndim(top) == 0 and np.isnan(float(top))):
        return base
    t = np.asarray(top, float)
    if t.ndim == 0 or base is None:
        return top
    b = np.asarray(base, float)
    if b.ndim and b.shape != t.shape:
        raise InputError(f"per-edge bounds of {t.shape[0]} and {b.shape[0]} edges cannot be combined; "
                         "state both for the same mesh")
    return np.where(np.isnan(t), b, t)


def _edge_name(scene, k: int) -> str:
    """Active edge ``k`` by its vertex pair, for messages."""
    i, j = scene.mesh.edges[np.flatnonzero(scene.active_edges)[k]]
    return f"edge ({int(i)}, {int(j)})"


def stress_w_max(mesh, max_stress: float, thickness: float) -> np.ndarray:
    """Per-edge w_max [N/m] from a material strength: ``σ_max · t · b_e / |e|``.

    An edge stands for the strip of shell around it: of thickness ``t`` and of its tributary
    width ``b_e`` (:func:`~selfsupport.core.geometry.edge_tributary_widths`: twice the area of the
    edge's triangles to the centroids of its faces over its length; on a regular grid of
    spacing ``h`` it is ``h``). The force that strip carries at stress ``σ_max`` is
    ``σ_max · t · b_e``; the edge's force is ``w |e|`` (``w`` is a force density, force per
    length), so ``w ≤ σ_max · t · b_e / |e|``. With ``A_e`` the area of influence,
    ``b_e = 2 A_e / |e|`` and the bound is ``2 σ_max t A_e / |e|²``; the original tool used
    ``σ_max t A_e / |e|² / 8``, 16 times less, a factor no derivation gives (it acts as a
    safety factor: pass a σ_max 16 times smaller for its bound). Lengths and widths are the
    reference mesh's.

    Parameters
    ----------
    mesh
        The reference :class:`~selfsupport.core.mesh.PolyMesh`.
    max_stress
        Allowable stress σ_max [Pa].
    thickness
        Shell thickness t [m].

    Returns
    -------
    numpy.ndarray
        One bound per mesh edge [N/m].
    """

    for name, v in (("the maximum stress", max_stress), ("the thickness", thickness)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v!r}")
    length = np.linalg.norm(edge_vectors(mesh.vertices, mesh.edges), axis=1)
    return float(max_stress) * float(thickness) * edge_tributary_widths(mesh) / length


# ------------------------------------------------------------------------- constraints
@dataclass(frozen=True)
class Hull:
    """Every free vertex within ±t/2 of the reference mid-surface, along the reference normal.
    ``thickness=None``: the self-weight's thickness. ``penalty``: weight of the hull's penalty
    term among the objective's terms (zero inside the hull; both methods hold the hull as hard
    bounds: IPOPT as inequality rows, the staggered method by an active set in Step 3)."""

    thickness: float | None = None
    penalty: float = 1e4
    name: ClassVar[str] = "hull"


@dataclass(frozen=True)
class FixedTopView:
    """The free vertices keep their x and y: only heights move (the thrust-network-analysis setting)."""

    name: ClassVar[str] = "fixed_top_view"


@dataclass(frozen=True)
class Planar:
    """Every face with four or more corners planar (paper §5: panels of glass or steel): the
    rows of :class:`~formulations.terms.PlanarFaces` held at zero — equality rows for IPOPT and
    the joint polish, a penalty of weight ``penalty`` in the staggered method's Step 3 (not
    relaxed along its path). A result meets it when every quad's non-planarity (distance of
    the diagonals over the mean edge length) is at most ``tol``."""

    tol: float = 1e-3
    # a gentle penalty: faces and equilibrium then converge together and the polish finishes
    # both; a strong one flattens the faces first and leaves the fit stuck
    penalty: float = 1e-2
    name: ClassVar[str] = "planar"


#: Constraint registry by name.
CONSTRAINTS: dict[str, type] = {c.name: c for c in (Hull, FixedTopView, Planar)}


# ---------------------------------------------------------------------------- objective
@dataclass(frozen=True)
class ObjectiveTerm:
    """One weighted registered term: ``TERMS[name]`` built for the problem with ``params``."""

    name: str
    weight: float = 1.0
    params: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in TERMS:
            raise InputError(f"unknown objective term {self.name!r}; choose from {', '.join(sorted(TERMS))}")
        w = float(self.weight)
        if not (np.isfinite(w) and w >= 0):
            raise InputError(f"objective weight of {self.name!r} must be a finite number >= 0, got {self.weight!r}")

    def build(self, ctx: TermContext) -> Term:
        return TERMS[self.name].build(ctx, weight=float(self.weight), **dict(self.params))


def parse_objective(spec: Any) -> tuple[ObjectiveTerm | Term, ...] | None:
    """``None``; a :class:`Term`; ``{"name": weight}``; ``"name=weight"`` strings; or a sequence
    of those -> a tuple of :class:`ObjectiveTerm` / user terms (in SI units)."""
    if spec is None:
        return None
    if isinstance(spec, (Term, ObjectiveTerm)):
        return (spec,)
    if isinstance(spec, Mapping):
        return tuple(ObjectiveTerm(str(k), float(v)) for k, v in spec.items())
    if isinstance(spec, str):
        name, sep, value = spec.partition("=")
        try:
            weight = float(value) if sep else 1.0
        except ValueError:
            raise InputError(f"objective {spec!r}: write NAME=WEIGHT with a number as WEIGHT") from None
        return (ObjectiveTerm(name.strip(), weight),)
    if isinstance(spec, Sequence):
        out: list = []
        for s in spec:
            out.extend(parse_objective(s) or ())
        return tuple(out)
    raise InputError(f"cannot read an objective from a {type(spec).__name__}")


# ------------------------------------------------------------------------------ problem
@dataclass(frozen=True, eq=False)
class ScaledProblem:
    """A problem in scale-free units (lengths / bbox diagonal, forces / mean nodal load of the
    first case): what the numeric methods and ``check`` work with."""

    top: Topology
    scaling: Scaling
    X: np.ndarray  # scaled reference positions (n, 3)
    L: np.ndarray  # scaled loads at the reference, (n_cases, n)
    lower: np.ndarray  # per active edge
    upper: np.ndarray


@dataclass(frozen=True, eq=False)
class Problem:
    """A thrust-network design problem (see the module docstring). Build with :meth:`build`."""

    scene: Any  # selfsupport.core.scene.Scene
    loads: LoadCases
    bounds: Bounds = Bounds()
    objective: tuple | None = None  # of ObjectiveTerm / Term (SI units); None: the method's default
    constraints: tuple = ()

    @classmethod
    def build(cls, scene, loads: Any = None, *, eps: Any = None, w_max: Any = None, objective: Any = None,
              constraints: Sequence[Any] = (), bounds: Bounds | None = None) -> "Problem":
        """From a scene, load model(s) (one model, a mapping name -> model, or :class:`LoadCases`;
        the scene's extras are added to each), bounds [N/m] (``eps``, ``w_max``; ``bounds``:
        per-edge bounds stated over them, e.g. a bounds file's, see :meth:`Bounds.over`), an
        objective (see :func:`parse_objective`) and constraints (instances or names in
        :data:`CONSTRAINTS`)."""
        cons = []
        for c in constraints:
            if isinstance(c, str):
                if c not in CONSTRAINTS:
                    raise InputError(f"unknown constraint {c!r}; choose from {', '.join(CONSTRAINTS)}")
                c = CONSTRAINTS[c]()
            cons.append(c)
        stated = Bounds(eps, w_max) if bounds is None else bounds.over(Bounds(eps, w_max))
        return cls(scene=scene, loads=LoadCases.of(loads, scene), bounds=stated,
                   objective=parse_objective(objective), constraints=tuple(cons))

    # -------------------------------------------------------------- constraints
    def constraint(self, kind: type) -> Any:
        """The problem's constraint of that class, or ``None``."""
        return next((c for c in self.constraints if isinstance(c, kind)), None)

    @property
    def fixed_top_view(self) -> bool:
        return self.constraint(FixedTopView) is not None

    def hull_thickness(self) -> float | None:
        """The masonry hull's thickness [m] when the problem has one."""
        h = self.constraint(Hull)
        if h is None:
            return None
        t = h.thickness
        if t is None:
            t = next((getattr(m, "thickness", None) for m in _flatten(self.loads.models)
                      if getattr(m, "thickness", None) is not None), None)
        if t is None or not (np.isfinite(t) and t > 0):
            raise InputError("the masonry hull needs a positive thickness (--thickness)")
        return float(t)

    # ---------------------------------------------------------------- checks
    def validate(self) -> None:
        """Mesh and supports; raises named errors (a flat reference's need for ``w_max`` is
        :func:`selfsupport.methods.validate.validate_problem`'s, which needs a weight fit)."""
        self.scene.mesh.validate()
        self.scene.check_supports()

    # ---------------------------------------------------------------- units
    def scaled(self, loads: np.ndarray | None = None) -> ScaledProblem:
        """The problem in scale-free units, with ``loads`` ((n_cases, n) [N]; default: at the
        reference). Raises :class:`InputError` when a free vertex carries no downward load in
        some case or the bounds are inconsistent."""
        scene = self.scene
        mesh = scene.mesh
        top = Topology.build(mesh.n_vertices, mesh.edges[scene.active_edges], scene.supports)
        free = top.free
        with np.errstate(all="ignore"):
            L = self.loads.nodal(mesh, mesh.vertices) if loads is None else np.atleast_2d(np.asarray(loads, float))
            big = float(np.max(np.abs(L))) if L.size else 0.0
        if not np.isfinite(L).all() or big > LOAD_LIMIT:
            raise InputError(f"the loads overflow floating-point arithmetic (largest nodal load {big:.3g} N, the limit "
                             f"is {LOAD_LIMIT:.0e} N: squared forces would be non-finite); check the units of "
                             "--density, --thickness and the extra loads")
        if not big > 1.0 / LOAD_LIMIT:
            raise InputError(f"the loads vanish in floating-point arithmetic (largest nodal load {big:.3g} N, below "
                             f"{1 / LOAD_LIMIT:.0e} N); check the units of --density, --thickness and the mesh")
        for name, Lc in zip(self.loads.names, L):
            if np.any(Lc[free] >= 0):
                k = int(np.flatnonzero(free & (Lc >= 0))[0])
                where = f" in load case {name!r}" if len(L) > 1 else ""
                if Lc[k] > 0:  # (not a degenerate face: extra loads that outweigh the self-weight)
                    raise InputError(f"vertex {k} carries a net upward load of {Lc[k]:.3g} N{where}: a negative extra "
                                     "mass or an upward point load there outweighs its self-weight, and a thrust "
                                     "network carries downward loads only; make the extra loads there smaller")
                raise InputError(f"vertex {k} carries no downward load{where} (zero area?); remove degenerate faces "
                                 "or add a load there")
        sc = Scaling.of(mesh.vertices, L[0], free)
        X = sc.pos(mesh.vertices)
        lo, up = self.bounds.active(scene)
        lower = np.broadcast_to(np.nan if lo is None else sc.weight(np.asarray(lo, float)), (top.m,)).astype(float)
        lower[np.isnan(lower)] = default_eps(X, top.edges)  # (not stated: the scale-free default)
        upper = np.broadcast_to(np.nan if up is None else sc.weight(np.asarray(up, float)), (top.m,)).astype(float)
        upper[np.isnan(upper)] = np.inf
        if np.any(lower >= upper):
            k = int(np.argmax(lower >= upper))
            raise InputError(f"w_max ({sc.weight_back(upper[k]):.6g} N/m) must exceed the lower weight bound "
                             f"({sc.weight_back(lower[k]):.3g} N/m) on {_edge_name(scene, k)}; raise w_max there "
                             "or lower the lower bound")
        return ScaledProblem(top=top, scaling=sc, X=X, L=sc.load(L), lower=lower, upper=upper)

    # ---------------------------------------------------------------- objective
    def terms(self, ctx: TermContext, scaling: Scaling | None = None, default: Any = None) -> Term | None:
        """The objective as one :class:`Term` in the units of ``ctx`` (``scaling`` converts user
        terms stated in SI units); ``default`` (a spec) when the problem leaves it to the method.
        The hull and planarity constraints add their penalty terms (``constraint``: methods do
        not relax them)."""
        spec = self.objective if self.objective is not None else parse_objective(default)
        built: list[Term] = []
        for item in spec or ():
            if isinstance(item, ObjectiveTerm):
                built.append(item.build(ctx))
            elif scaling is not None:
                built.append(Scaled(item, length=scaling.length, center=scaling.center))
            else:
                built.append(item)
        planar = self.constraint(Planar)
        if planar is not None:
            built.append(TERMS["planar"].build(ctx, weight=planar.penalty))
        t = self.hull_thickness()
        if t is not None:
            h = self.constraint(Hull)
            th = t / scaling.length if scaling is not None else t
            built.append(TERMS["hull"].build(ctx, weight=h.penalty, thickness=th))
        if not built:
            return None
        return built[0] if len(built) == 1 else Sum(tuple(built))

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (for the network file's ``parameters.problem``)."""
        obj = None if self.objective is None else [
            {"name": o.name, "weight": float(o.weight), **({"params": dict(o.params)} if o.params else {})}
            if isinstance(o, ObjectiveTerm) else {"name": getattr(o, "name", type(o).__name__), "user_term": True}
            for o in self.objective]
        return {"load_cases": list(self.loads.names), "objective": obj,
                "constraints": [{"name": c.name, **({"thickness": self.hull_thickness()} if isinstance(c, Hull) else {}),
                                 **({"tol": c.tol} if isinstance(c, Planar) else {})}
                                for c in self.constraints],
                "bounds": {"eps": _jsonable(self.bounds.lower), "w_max": _jsonable(self.bounds.upper)}}


def _flatten(models) -> list:
    out = []
    for m in models:
        out.extend(_flatten(m.cases) if hasattr(m, "cases") else [m])
    return out


def _jsonable(v: Any) -> Any:
    if v is None:
        return None
    a = np.asarray(v, float)
    return float(a) if a.ndim == 0 else a.tolist()
