"""What every method is: ``solve(problem, options) -> SolveResult`` on a
:class:`formulations.Problem`, plus the helpers they share to honour that contract.

Methods also accept the short form ``solve(scene, loads, eps=..., w_max=..., objective=...)``,
which builds the problem with :func:`as_problem` — nothing more.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping, Protocol, runtime_checkable

import numpy as np

from formulations import Planar, Problem, TermContext
from formulations.loadcases import LoadCases
from formulations.scaling import Scaling
from formulations.terms.planarity import coplanarity_rows
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import DEGENERATE_LOAD, closest_points, degenerate, face_nonplanarity
from selfsupport.core.loads import LoadCase
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene


@runtime_checkable
class Method(Protocol):
    """A solution method: any object with a ``name`` and this ``solve``."""

    name: str

    def solve(self, problem: Problem, options: Mapping[str, Any] | None = None, *,
              progress: Callable[[dict], None] | None = None) -> SolveResult:
        """Solve ``problem``; ``options`` are the method's settings for this solve only."""
        ...  # pragma: no cover - protocol


def as_problem(problem: Problem | Scene, loads: Any = None, *, eps: Any = None, w_max: Any = None,
               objective: Any = None, constraints: Any = ()) -> Problem:
    """``problem`` itself, or the problem built from a scene and the short form's arguments
    (which must then not contradict a given problem)."""
    if isinstance(problem, Problem):
        extra = {k: v for k, v in (("loads", loads), ("eps", eps), ("w_max", w_max), ("objective", objective))
                 if v is not None}
        if extra or constraints:

            raise InputError(f"{sorted(extra) + (['constraints'] if constraints else [])} are part of the problem; "
                             "pass them to Problem.build instead")
        return problem
    return Problem.build(problem, loads, eps=eps, w_max=w_max, objective=objective, constraints=constraints)


def loads_or_options(options: Any, loads: Any = None) -> tuple[Any, Any]:
    """``(loads, options)`` of a short-form call ``solve(scene, LOADS)``: a second positional
    argument that is a load model, a set of them or a mapping name -> load model is the loads."""


    if isinstance(options, (LoadCase, LoadCases)) or (isinstance(options, Mapping) and options
                                                       and all(isinstance(v, LoadCase) for v in options.values())):
        return options, None
    return loads, options


def term_values(problem: Problem, network: Network, default: Any = None) -> dict[str, float]:
    """Each objective term's value at ``network`` in SI units (the reference term re-projected
    there), by name — for the summary and the JSON."""
    scene = problem.scene
    V = np.asarray(network.vertices, float)
    ctx = TermContext(vertices=scene.mesh.vertices, reference=scene.mesh, free=scene.free,
                      thickness=problem.hull_thickness())
    total = problem.terms(ctx, default=default)
    if total is None:
        return {}
    out: dict[str, float] = {}
    for t in total.parts():
        out[t.name] = out.get(t.name, 0.0) + t.at(V).numeric_value(V)
    return out


#: Tolerance of "inside the hull", relative to the half thickness t/2: a vertex counts as inside
#: when its distance to the reference surface is at most (1 + HULL_TOL) t/2. The methods hold the
#: hull on the tangent plane at each reference vertex, so a vertex resting on the hull's face ends
#: a hair beyond the curved offset surface (curvature × tangential slide); 1% of t/2 (0.5 mm at
#: t = 0.1 m) covers that and is far below any masonry tolerance.
HULL_TOL = 0.01


def hull_signed_distance(reference, vertices: np.ndarray) -> np.ndarray:
    """Signed distance [m] of each point to the reference surface (closest point on its
    triangulation, positive on the side of its normals, i.e. above for an upward-facing shell).

    This is the masonry hull's measure: a point lies in the hull of thickness t when
    ``|d| <= t/2``. (The solvers' hull term uses the tangent plane at the reference vertex
    instead, its linearization.)
    """

    V = np.asarray(vertices, float)
    C, dist, nrm = closest_points(V, reference)
    side = np.sign(np.einsum("ij,ij->i", V - C, nrm))
    return np.where(side < 0, -dist, dist)


def hull_excess(scene: Scene, network: Network, thickness: float, *, tol: float = HULL_TOL) -> dict[str, Any]:
    """Where the network sits in the masonry hull of thickness t (the reference mid-surface ± t/2):
    per-vertex signed distance to the reference surface [m] and inside/outside (supports count as
    inside), the free vertices outside (worst first) with their excess beyond t/2 [m], the max
    excess. The one computation behind the ``hull`` record of a solve, the certification of
    :mod:`selfsupport.structure.stability` and the warning of :mod:`selfsupport.methods.diagnostics`."""
    t = float(thickness)
    d = hull_signed_distance(scene.mesh, network.vertices)
    excess = np.abs(d) - 0.5 * t
    excess[scene.supports] = -0.5 * t  # held by the ground where the design put them
    inside = excess <= tol * 0.5 * t
    outside = np.flatnonzero(~inside)
    order = outside[np.argsort(-excess[outside], kind="stable")]  # worst first
    return {"thickness": t, "tolerance": tol * 0.5 * t, "max_excess": float(max(excess.max(initial=0.0), 0.0)),
            "outside": int(outside.size), "outside_vertices": order.tolist(),
            "outside_excess": excess[order].tolist(), "signed_distance": d.tolist(), "inside": inside.tolist(),
            "inside_all": bool(outside.size == 0), "free": int((~scene.supports).sum())}


def hull_report(problem: Problem, network: Network, thickness: float | None = None, *,
                tol: float = HULL_TOL) -> dict[str, Any] | None:
    """:func:`hull_excess` for the problem's hull constraint, else for ``thickness`` (a diagnosis
    of a problem without the constraint); ``None`` without either."""
    t = problem.hull_thickness() if problem.hull_thickness() is not None else thickness
    return None if t is None else hull_excess(problem.scene, network, t, tol=tol)


#: How many of the quads farthest from planar a planarity report names.
WORST_FACES = 5


def nonplanar_faces_note(report: dict[str, Any]) -> str:
    """One clause naming the quads of a :func:`planarity_report` past its tolerance (farthest
    first) and the exempt ones, for a message; empty when none is past it."""
    worst = report.get("worst_faces") or []
    if not worst:
        return ""
    names = ", ".join(f"{f} ({q:.1e})" for f, q in worst)
    exempt = report.get("exempt_faces", 0)
    held = (f"; {exempt} faces with three or more supported corners are exempt (their plane is the supports')"
            if exempt else "")
    return f"faces farthest from planar: {names}{held}"


def planarity_report(problem: Problem, network: Network) -> dict[str, Any] | None:
    """For a problem with the :class:`~formulations.problem.Planar` constraint: the largest and
    mean quad non-planarity (:func:`~selfsupport.core.evidence.face_nonplanarity`, distance of the
    diagonals over the mean edge length), the largest coplanarity row of the polygons with more
    than four corners (over ``ℓ_f³``: for a square twice its non-planarity), the tolerance and
    whether it is met; ``None`` without the constraint. Faces with three or more supported
    corners are not counted (their plane is the supports'; see
    :func:`~formulations.terms.planarity.coplanarity_rows`): ``exempt_faces`` says how many there
    are and ``max_nonplanarity_exempt`` how far from planar they are. ``worst_faces``: the
    counted quads past the tolerance, farthest first (at most :data:`WORST_FACES`)."""


    planar = problem.constraint(Planar)
    if planar is None:
        return None
    mesh = network.mesh
    sup = np.asarray(network.supports, bool)
    face_of, _, _ = mesh.corner_data  # (faces with three supported corners are the supports' own plane)
    held = np.bincount(face_of, weights=sup[mesh.face_vertices], minlength=mesh.n_faces) >= 3
    q_all = face_nonplanarity(mesh)
    exempt = q_all[np.isfinite(q_all) & held]
    q = q_all[np.isfinite(q_all) & ~held]
    Q, owner, inv_ell2 = coplanarity_rows(mesh, sup)
    big = mesh.face_sizes[owner] > 4
    poly = 0.0
    if big.any():
        V = mesh.vertices
        e1, e2, e3 = (V[Q[big, k]] - V[Q[big, 0]] for k in (1, 2, 3))
        poly = float((np.abs(np.einsum("ij,ij->i", e1, np.cross(e2, e3))) * inv_ell2[big] ** 1.5).max())
    qmax = float(q.max()) if q.size else 0.0
    past = np.flatnonzero(np.isfinite(q_all) & ~held & (q_all > planar.tol))
    worst = past[np.argsort(-q_all[past])][:WORST_FACES]
    return {"worst_faces": [[int(f), float(q_all[f])] for f in worst], "tol": planar.tol, "max_nonplanarity": qmax, "mean_nonplanarity": float(q.mean()) if q.size else 0.0,
            "max_polygon_row": poly, "met": bool(qmax <= planar.tol and poly <= 2 * planar.tol),
            "exempt_faces": int(exempt.size), "max_nonplanarity_exempt": float(exempt.max(initial=0.0))}


def case_networks(problem: Problem, scaling: Scaling, X: np.ndarray, ws: list[np.ndarray]
                  ) -> tuple[Network, tuple[tuple[str, Network], ...]]:
    """Networks in SI units for scaled positions ``X`` and one scaled weight vector per case:
    supports exactly where the design put them, each case's loads of this geometry."""
    scene = problem.scene
    mesh0 = scene.mesh
    V = scaling.pos_back(X)
    V[scene.supports] = mesh0.vertices[scene.supports]  # exactly, not through the scaling round trip
    mesh = mesh0.with_vertices(V)
    nets = []
    for (name, model), w in zip(problem.loads, ws):
        weights = np.zeros(mesh0.n_edges)
        weights[scene.active_edges] = scaling.weight_back(w)
        nets.append((name, Network(mesh=mesh, weights=weights, loads=model.nodal(mesh0, V), supports=scene.supports,
                                   reference=mesh0, handles=scene.handles)))
    return nets[0][1], tuple(nets)


def short_of_tol(net: Network, tol: float, err: float | None = None) -> str:
    """Why a polished network misses ``tol`` (``err``: its max relative error over every load
    case, default the network's own): its worst vertices by number and, where they carry almost
    no load (:func:`~selfsupport.core.evidence.degenerate`), that their faces collapsed.

    >>> import dataclasses
    >>> from selfsupport.methods.staggered import StaggeredLinearization
    >>> from selfsupport.core.shapes import make_shape
    >>> net = StaggeredLinearization().solve(make_shape("dome", n_vertices=60)).network
    >>> v = int(np.flatnonzero(~net.supports)[3])
    >>> loads = net.loads.copy(); loads[v] *= 1e-5  # that vertex's area collapsed
    >>> msg = short_of_tol(dataclasses.replace(net, loads=loads), 1e-9)
    >>> f"balance: [{v}," in msg, "1 of them carry under 0.001 of the median load" in msg
    (True, True)
    """
    free = np.flatnonzero(~np.asarray(net.supports, bool))
    rel = net.relative_errors()
    order = np.argsort(rel)[::-1][:5]  # (relative_errors is per free vertex: mapped back to numbers)
    err = float(rel.max(initial=0.0)) if err is None else err
    message = (f"the polished network has max relative error {err:.2e} > tol {tol:g}; "
               f"vertices hardest to balance: {[int(v) for v in free[order]]}; try more supports there, a larger "
               "w_max, or a pillar")
    flat = degenerate(net.loads[free])[order]
    if flat.any():  # (a collapsed face, e.g. at the free corner of a quad mesh, forced straight)
        message += (f"; {int(flat.sum())} of them carry under {DEGENERATE_LOAD:g} of the median load: their faces "
                    "collapsed onto their neighbours (as at a free corner of a quad mesh, whose two edges must lie "
                    "in line); supports there avoid it")
    return message


def cases_max_error(cases) -> float:
    """The max relative error over every case's network (``cases``: (name, network) pairs)."""
    return max(n.max_relative_error() for _, n in cases)


def cases_in_equilibrium(cases, tol: float) -> bool:
    """Every case's network within ``tol``, or at its round-off floor (:meth:`Network.in_equilibrium`)."""
    return bool(cases) and all(n.in_equilibrium(tol) for _, n in cases)


#: Relative difference above which two load cases' nodal loads count as not proportional.
PROPORTIONAL_RTOL = 1e-6


def cases_proportional(problem: Problem) -> bool:
    """Are the free vertices' loads of every case, at the reference, one case's times a factor
    (within :data:`PROPORTIONAL_RTOL`)? A single case is; a uniform surcharge on the self-weight
    is; a point load or extra mass in one case is not.

    >>> from selfsupport.core.shapes import make_shape
    >>> from selfsupport.core.loads import PointLoad, SelfWeight
    >>> from formulations import Problem
    >>> scene = make_shape("dome", n_vertices=60)
    >>> f = np.zeros(scene.mesh.n_vertices); f[int(np.flatnonzero(~scene.supports)[0])] = -100.0
    >>> [cases_proportional(Problem.build(scene, loads=c)) for c in ({"a": SelfWeight(), "b": SelfWeight(density=3000)},
    ...                                                               {"a": SelfWeight(), "b": SelfWeight() + PointLoad(f)})]
    [True, False]
    """
    if len(problem.loads) < 2:
        return True
    scene = problem.scene
    L = problem.loads.nodal(scene.mesh, scene.mesh.vertices)[:, ~scene.supports]
    ref = L[0]
    scale = (L @ ref) / max(float(ref @ ref), 1e-300)  # best factor of each case onto the first
    off = np.abs(L - scale[:, None] * ref[None]).max(axis=1) / np.abs(L).max(axis=1)
    return bool(off.max() <= PROPORTIONAL_RTOL)


def load_factor(L_c: np.ndarray, L_r: np.ndarray) -> float:
    """The least-squares factor ``k`` of loads ``L_c ≈ k L_r`` (``L_c·L_r / L_r·L_r``): a
    proportional case's weights are its case's times ``k``."""
    return float(L_c @ L_r) / max(float(L_r @ L_r), 1e-300)


def proportional_members(problem: Problem) -> dict[int, tuple[int, float]]:
    """The cases another (earlier) case carries with its weights times a factor: ``{c: (r, k)}``
    where case ``c``'s loads at the reference are ``k ≥ 1`` times case ``r``'s (within
    :data:`~selfsupport.methods.base.PROPORTIONAL_RTOL`; snow on the self-weight, a heavier
    material). Weights ``k w_r`` balance ``k L_r`` at the same geometry exactly, so such a case
    adds equations and unknowns to the joint problem but no condition: left in, it makes the
    count square on a quad mesh (:func:`joint_freedom`), and the iteration must fit it as if it
    could pull the geometry elsewhere. Only where the bounds hold the scaled weights too: a
    positive lower bound (``k w_r ≥ w_r ≥ ε``) and no upper one; ``k ≥ 1`` for the same reason."""
    b = problem.bounds
    lower_ok = b.lower is None or bool(np.all(np.asarray(b.lower, float)[~np.isnan(np.asarray(b.lower, float))] > 0))
    upper_ok = b.upper is None or bool(np.all(~np.isfinite(np.asarray(b.upper, float))))
    if not (lower_ok and upper_ok):
        return {}
    scene = problem.scene
    L = problem.loads.nodal(scene.mesh, scene.mesh.vertices)[:, ~scene.supports]
    out: dict[int, tuple[int, float]] = {}
    for c in range(1, len(L)):
        for r in range(c):
            if r in out:
                continue
            k = load_factor(L[c], L[r])
            if k >= 1.0 and np.abs(L[c] - k * L[r]).max() <= PROPORTIONAL_RTOL * np.abs(L[c]).max():
                out[c] = (r, k)
                break
    return out


def without_members(problem: Problem, members: dict[int, tuple[int, float]]) -> Problem:
    """``problem`` with the cases of :func:`proportional_members` left out (the first case stays:
    it is never a member, and it sets the default bounds and the scaling)."""
    kept = tuple(case for c, case in enumerate(problem.loads.cases) if c not in members)
    return dataclasses.replace(problem, loads=LoadCases(kept))


def with_members(problem: Problem, result: SolveResult, members: dict[int, tuple[int, float]],
                 tol: float) -> SolveResult:
    """The result of the problem without its members (:func:`without_members`) as a result of
    ``problem``: each member's network at the same geometry, its loads there and its case's
    weights times the factor of its loads over that case's there. Every case's evidence is its
    own network's; a result that was "converged" and has a member outside ``tol`` is "stalled"."""
    kept = [c for c in range(len(problem.loads)) if c not in members]
    solved = dict(zip(kept, (net for _, net in result.case_networks)))
    nets = []
    free = ~problem.scene.supports
    for c, (name, model) in enumerate(problem.loads.cases):
        if c in solved:
            nets.append((name, solved[c]))
            continue
        rep = solved[members[c][0]]
        L = model.nodal(rep.mesh, rep.vertices)
        k = load_factor(L[free], rep.loads[free])
        nets.append((name, dataclasses.replace(rep, weights=k * rep.weights, loads=L)))
    names = problem.loads.names
    note = "; ".join(f"case {names[c]!r} is case {names[r]!r} times {k:.6g} (its weights scaled)"
                     for c, (r, k) in members.items())
    status, message = result.status, f"{result.message}; {note}" if result.message else note
    if status == "converged" and not cases_in_equilibrium(nets, tol):
        status, message = "stalled", message + "; a scaled case is not in equilibrium at the result's geometry"
    return dataclasses.replace(result, cases=tuple(nets), status=status, message=message,
                               max_relative_error=max(n.max_relative_error() for _, n in nets),
                               min_weight=min(n.min_weight() for _, n in nets),
                               parameters={**result.parameters, "problem": problem.describe(), "proportional_cases": {
                                   names[c]: {"of": names[r], "factor": k} for c, (r, k) in members.items()}})


def load_cases_note(problem: Problem) -> str | None:
    """Why several load cases may have no common network: a sentence for the message of a solve
    that did not converge, or None when it does not apply.

    It applies when the cases' loads are not proportional at the reference (a point load or
    extra mass in one case, not a uniform surcharge, which scales the self-weight). One geometry
    must carry every case; their difference, a load on that same geometry, must be carried by a
    difference of weights of either sign. Free edges leave that little room, and the sentence
    names them when the mesh has boundary vertices that are not supports (``python -m
    studies.load_cases`` shows which of the paper's designs stand under which cases).

    >>> from selfsupport.core.shapes import make_shape
    >>> from selfsupport.core.loads import PointLoad, SelfWeight
    >>> from formulations import Problem
    >>> scene = make_shape("pillar_vault", n_vertices=100)
    >>> f = np.zeros(scene.mesh.n_vertices); f[45] = -1000.0
    >>> note = load_cases_note(Problem.build(scene, loads={"empty": SelfWeight(), "hoist": SelfWeight() + PointLoad(f)}))
    >>> note.startswith("the load cases are not proportional"), "boundary vertices are not supports" in note
    (True, True)
    >>> import dataclasses  # the same with every boundary vertex supported: no free edge named
    >>> held = dataclasses.replace(scene, supports=scene.supports | scene.mesh.boundary_vertex_mask)
    >>> load_cases_note(Problem.build(held, loads={"empty": SelfWeight(), "hoist": SelfWeight() + PointLoad(f)}))[:60]
    'the load cases are not proportional: one geometry must carry'
    >>> load_cases_note(Problem.build(scene, loads={"a": SelfWeight(), "b": SelfWeight(density=3000)})) is None
    True
    """
    if cases_proportional(problem):
        return None
    scene = problem.scene
    free_edge = np.flatnonzero(scene.mesh.boundary_vertex_mask & ~scene.supports)
    if free_edge.size:
        shown = ", ".join(str(int(v)) for v in free_edge[:8]) + (", ..." if free_edge.size > 8 else "")
        return (f"the load cases are not proportional and {free_edge.size} boundary vertices are not supports "
                f"({shown}): one geometry must carry every case, and with free edges such a geometry may not "
                "exist (vaults with free edges often stall with both methods, where domes with a supported "
                "boundary converge); solve the cases one at a time, or support the free boundary")
    return ("the load cases are not proportional: one geometry must carry every case, and the iteration may miss "
            "it or it may not exist near this reference; solve the cases one at a time, or make the loads of the "
            "cases more alike")
