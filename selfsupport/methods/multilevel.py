"""Multilevel solve for big meshes: coarsen the top view, solve, prolong, solve again.

The staggered method's outer iterations follow its schedule for α, the pull towards the
reference (halved after every accepted step, from 1): 25–45 iterations at 16k–64k vertices,
each one Step-2 fit whose cost grows faster than n. A network solved on a coarser mesh of the
same surface carries the same stress field, so the fine solve can start from a network in
equilibrium built from it and needs no schedule at all. Level by level, coarsest first:

1. :func:`coarsen` makes a mesh of the same top view with ~``factor``× fewer vertices, the
   boundary loops subsampled at the coarse spacing (their sharp corners and both ends of every
   supported run kept), holes kept, heights from the reference. First choice: a mesh of the
   fine mesh's own vertices, its triangles the fine triangles that join three graph-Voronoi
   clusters, so its edges follow chains of fine edges and keep their directions. A thrust
   network depends on them: on a grid split by parallel diagonals the compressive weights need
   a surface shaped for those diagonals, and a network from a Delaunay coarsening, prolonged to
   that grid, stalled at fit error 0.17 (16k pillar vault), where one from the clusters
   converged in 13 iterations. When the clusters do not form a valid triangulation (a quad
   mesh's 1-rings leave every other vertex; folds, gaps), a constrained quality Delaunay
   triangulation of the top view (Shewchuk's Triangle, via ``igl.triangle``) with interior
   supports subsampled. The coarse problem has the fine one's load models, bounds, objective
   and constraints, evaluated on the coarse mesh.
   A scene made by :func:`~selfsupport.core.subdivision.subdivide_scene` brings its own
   levels: the designer's coarser scenes it was refined from (the paper's §4 upsample, then
   polish). They are used as they are (``use_subdivision``) while the scene is unchanged since
   the subdivision. On the paper's scenes subdivided twice they converged in 2.8–3.8 s (one
   level stalled on lilium and lilium-pillar; the clusters took up to 47 s), three times in
   14 s (lilium, 111k vertices; clusters 327 s), ending 0.4–3.5× as far from the reference as
   the clusters' network (README, subdivided designs). Where the stress does not carry (cyl2's
   quads), the level below subdivided by the same step starts the level (:mod:`.prolong`, step 5).
2. The coarsest level is solved cold by :class:`~.staggered.StaggeredLinearization`.
3. Each finer level starts from the level below carried over by its stress field
   (:mod:`.prolong`): a network in equilibrium on the finer mesh, about as near the reference as
   the level below, so one iteration confirms it (the staggered method polishes it). A level
   that ends more than :data:`RECLAIM` × farther from the reference than the one below is, when
   it is an intermediate level of at most :data:`COLD_MAX` vertices, solved cold (the stress
   below did not carry); the finest or a larger one is first solved cold for one iteration, which
   finds a reference that stands as designed (a barrel vault: the carried stress reproduces it
   only to the fine mesh's discretization), and failing that walked back by up to
   :data:`RECLAIM_STEPS` SQP steps in equilibrium (:mod:`.refine`). Where the polish comes
   within :data:`START_TOL` of equilibrium but not to the prolongation's own tolerance, the
   level iterates from that network (and returns it when it stops out of equilibrium farther
   from it, with its weights refit to its positions as stored where that balances it:
   :mod:`.weight_refit`). A 256k pillar vault's free-boundary arches hold that network at its
   round-off floor (2.07e-8); the staggered method then stops at its first polish (3 s, not
   640 s of iterating), and the start, refit, is in equilibrium (8.42e-9). Where the refit does
   not balance it, the result says why (``parameters["roundoff_limit"]``). Where
   that prolongation fails (its polish does not reach equilibrium; several load cases or a
   constraint), or with ``prolongation="interpolation"``, the level starts from the one below's
   offsets from its reference interpolated C¹ over the top view with weights from the nearest
   edge (:mod:`.warm`), and iterates from there (``warm_iterate``) with the pull starting at
   :data:`WARM_ALPHA0` instead of 1: 10–21 iterations at 16k–64k vertices. A fine level of at
   most :data:`COLD_MAX` vertices that does not converge from there is solved cold, as on one
   level, and so is a fine level of any size that stops out of equilibrium, whatever its start,
   unless the rounding of its positions alone holds it there; the nearer to equilibrium of the
   two is the answer.

Only the finest level is the answer; its result carries the usual evidence and, under
``parameters["multilevel"]``, every level's size, status, iterations and time. A problem whose
data are tied to vertex indices (point loads, extra masses, per-edge bounds, explicit
objective terms built on the mesh) cannot be coarsened: it is solved on one level, and
``parameters["multilevel"]["why"]`` says so.

Example
-------
>>> from selfsupport.core.shapes import make_shape
>>> scene = make_shape("pillar_vault", n_vertices=1600)
>>> res = Multilevel(direct_max=500).solve(scene)
>>> [(lv["coarsening"], lv["status"]) for lv in res.parameters["multilevel"]["levels"]]
[('clusters', 'converged'), (None, 'converged')]
>>> res.max_relative_error < 1e-9
True
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from formulations import FixedTopView, Hull, Problem
from formulations.problem import Bounds, ObjectiveTerm
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import distance_stats, roundoff_message, triangulate
from selfsupport.core.geometry import mean_edge_length, turning_angles
from selfsupport.core.loads import CombinedLoad, SelfWeight
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import SolveResult
from selfsupport.core.scene import Scene
from selfsupport.core.subdivision import subdivide_like, subdivision_parents
from selfsupport.methods import METHODS
from selfsupport.methods.base import as_problem, loads_or_options, term_values
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.prolong import START_TOL, Prolongation, prolong
from selfsupport.methods.staggered import DEFAULT_OBJECTIVE, StaggeredLinearization
from selfsupport.methods.warm import WarmStart, as_warm_start, interpolate_over_top_view
from selfsupport.methods.weight_refit import edge_bounds, refit_weights
from selfsupport.methods.weightfit import WeightFitBackend

__all__ = ["Multilevel", "solve_warm", "coarsen", "coarse_problem", "why_not", "DIRECT_MAX", "FACTOR", "WARM_ALPHA0",
           "START_TOL"]

#: Meshes up to this many vertices are solved on one level: a cold solve there takes seconds, and
#: above it two levels cost less than one (``python -m studies.method_choice`` measures the crossover).
DIRECT_MAX = 6000
#: Vertex ratio between neighbouring levels (halving the spacing).
FACTOR = 4.0
#: α at the start of a warm level: small, so that the level keeps its warm start's shape instead of
#: repeating the α schedule from the top (α₀ = 1), which costs nearly a cold solve's iterations.
WARM_ALPHA0 = 1e-4
#: How a level's network starts the next: "stress" (its stress field carried to the finer mesh
#: and the network put in equilibrium there, :mod:`.prolong`; the interpolation where that fails)
#: or "interpolation" (its offsets interpolated and iterated from, :mod:`.warm`).
PROLONGATIONS = ("stress", "interpolation")
#: A level prolonged by its stress that ends more than this many times farther from the reference
#: than the level below (mean distance) is probed by one cold iteration and, unless that converges,
#: refined by up to RECLAIM_STEPS SQP steps in equilibrium (refine.py). Not lower: a prolonged level
#: may end somewhat farther than the one below where its grid can do no better (a surface already
#: in equilibrium is reproduced only to the fine mesh's discretization), and a probe there costs
#: minutes at large sizes for nothing.
RECLAIM = 2.0
RECLAIM_STEPS = 10
#: ... but an intermediate level of at most this many vertices is solved cold instead (its first
#: iteration is that probe; it is to start the next level, not to be the answer, where the
#: refinement walks back closer): the level below's stress did not carry (a coarse mesh can hold a
#: stress whose directions this mesh's edges cannot carry in compression, and refining from there
#: stalls), and a cold solve at this size takes seconds. Larger levels are refined.
#: A fine level this small that iterated from interpolated heights without converging is solved cold
#: (a larger one only when it stopped out of equilibrium, not held there by rounding alone).
COLD_MAX = 4 * DIRECT_MAX
#: A boundary corner turning more than this [degrees] is kept on every level.
CORNER_ANGLE = 30.0


def _carried_record(carried: dict[str, Any]) -> dict[str, Any]:
    """The progress record of a level's start carried from the level below (a 256k prolongation
    takes a minute; progress shows it between the levels' iterations)."""
    return {"iteration": "carried", "by": carried["by"],
            **({"max_rel_error": carried["max_relative_error"]} if "max_relative_error" in carried else {})}


def _with_network(res: SolveResult, problem: Problem, network: Any, note: str, tol: float,
                  status: str | None = None) -> SolveResult:
    """``res`` with ``network`` as its answer: the evidence and the objective's terms recomputed
    from that network, the run's status (or ``status``), iterations, time and settings kept. A
    network returned out of equilibrium at ``tol`` that rounding alone holds there says so
    (``parameters["roundoff_limit"]``, its own report, whatever the run's was)."""
    # (a status of its own: the run's message described the run's network, not this one)
    params, message = dict(res.parameters), f"{note} ({res.message})" if res.message and not status else note
    params.pop("roundoff_limit", None)
    limit = network.roundoff_limit(tol)  # (None for a network in equilibrium at tol)
    if limit is not None:
        params["roundoff_limit"], message = limit, f"{roundoff_message(limit, tol)}; {note}"
    return SolveResult.build(network, status=status or res.status, method=res.method, backend=res.backend,
                             iterations=res.iterations, wall_time=res.wall_time, history=res.history,
                             message=message, parameters=params,
                             terms=term_values(problem, network, default=DEFAULT_OBJECTIVE))


# ------------------------------------------------------------------------------ coarsening
def _boundary_keep(loop: np.ndarray, xy: np.ndarray, supports: np.ndarray, h: float) -> np.ndarray:
    """Indices into ``loop`` kept on the coarse boundary: about one per ``h`` of arc length, plus
    every sharp corner and both ends of every supported run (supports stay where they were)."""
    P = xy[loop]
    s = supports[loop]
    forced = turning_angles(P) > CORNER_ANGLE
    # both ends of every supported run, and beside each the first unsupported vertex h/2 or more
    # away along the loop: the coarse supports end where the fine ones do, give or take h/2
    # (its direct neighbour leaves a fine-length edge on every coarser level; none at all let
    # the coarse supports reach up to h into the free boundary)
    ends = s & ~(np.roll(s, 1) & np.roll(s, -1))
    forced |= ends
    seg = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    m = len(loop)
    for i in np.flatnonzero(ends):
        for step in (1, -1):  # along the loop and against it
            j, d = i, 0.0
            while True:
                d += seg[j] if step == 1 else seg[(j - 1) % m]
                j = (j + step) % m
                if s[j] or j == i:
                    break  # (another support within h/2: nothing to add)
                if d >= 0.5 * h:
                    forced[j] = True
                    break
    keep, acc = [], np.inf
    for i in range(len(loop)):
        if forced[i] or acc >= h:
            keep.append(i)
            acc = 0.0
        acc += seg[i]
    if len(keep) > 1 and not forced[keep[-1]] and np.linalg.norm(P[keep[-1]] - P[keep[0]]) < 0.5 * h:
        keep.pop()  # (the walk ends just short of where it started)
    if len(keep) < 3:  # a small hole: a triangle at least
        keep = sorted(set(keep) | set(np.linspace(0, len(loop), 4, endpoint=False).astype(int).tolist()))
    return np.asarray(keep, np.int64)


def _grid_sample(xy: np.ndarray, h: float) -> np.ndarray:
    """Indices of ``xy`` with at most one point per ``h`` × ``h`` cell (the first in each)."""
    if len(xy) == 0:
        return np.zeros(0, np.int64)
    cells = np.floor((xy - xy.min(axis=0)) / h).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return np.sort(first)


def _coarsen_by_clusters(scene: Scene, n_target: int, h: float, boundary_ids: np.ndarray) -> Scene | None:
    """The coarse mesh made of the fine mesh's own vertices and edges (``None`` when it fails).

    Seeds: the kept boundary vertices, then interior vertices greedily, none in the 1-ring of
    another (about a quarter of a triangle mesh's vertices, whatever ``n_target``; more than
    1.6 ``n_target`` seeds are refused). Every fine vertex joins the seed
    nearest along the mesh's edges (graph Voronoi regions; boundary vertices only boundary
    seeds); every fine triangle whose corners lie in three regions becomes a coarse triangle.
    The coarse edges then run along chains of fine edges, so the coarse mesh keeps the fine
    one's edge directions — which a thrust network depends on: on a grid split by parallel
    diagonals a network solved on a Delaunay coarsening stalled at fit error 0.17 when prolonged,
    from this one it converged (16k pillar vault: 13 iterations, cold 26).
    """


    mesh = scene.mesh
    n = mesh.n_vertices
    xy = mesh.vertices[:, :2]
    E = mesh.edges
    bmask = mesh.boundary_vertex_mask
    nbrs = mesh.vertex_neighbors
    blocked = np.zeros(n, bool)
    seeds = list(boundary_ids)
    blocked[boundary_ids] = True
    for v in boundary_ids:
        blocked[nbrs[v]] = True
    blocked[bmask] = True  # other boundary vertices belong to boundary seeds
    for v in range(n):
        if not blocked[v]:
            seeds.append(v)
            blocked[v] = True
            blocked[nbrs[v]] = True
    seeds = np.asarray(seeds, np.int64)
    if len(seeds) > 1.6 * n_target:  # (a quad mesh's 1-rings leave every other vertex: too fine a level)
        return None
    length = np.linalg.norm(xy[E[:, 1]] - xy[E[:, 0]], axis=1) + 1e-300
    graph = coo_matrix((np.r_[length, length], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])), shape=(n, n)).tocsr()
    _, _, src = dijkstra(graph, directed=False, indices=seeds, min_only=True, return_predecessors=True)
    be = E[bmask[E[:, 0]] & bmask[E[:, 1]] & mesh.boundary_edge_mask]
    bl = np.linalg.norm(xy[be[:, 1]] - xy[be[:, 0]], axis=1) + 1e-300
    bgraph = coo_matrix((np.r_[bl, bl], (np.r_[be[:, 0], be[:, 1]], np.r_[be[:, 1], be[:, 0]])), shape=(n, n)).tocsr()
    _, _, bsrc = dijkstra(bgraph, directed=False, indices=np.asarray(boundary_ids), min_only=True,
                          return_predecessors=True)
    src = np.where(bmask, bsrc, src)
    if (src < 0).any():
        return None
    index = -np.ones(n, np.int64)
    index[seeds] = np.arange(len(seeds))
    T = index[src[triangulate(mesh)]]
    T = T[(T[:, 0] != T[:, 1]) & (T[:, 1] != T[:, 2]) & (T[:, 0] != T[:, 2])]
    _, first = np.unique(np.sort(T, axis=1), axis=0, return_index=True)
    T = T[np.sort(first)]
    P = xy[seeds]
    cross = ((P[T[:, 1]] - P[T[:, 0]])[:, 0] * (P[T[:, 2]] - P[T[:, 0]])[:, 1]
             - (P[T[:, 1]] - P[T[:, 0]])[:, 1] * (P[T[:, 2]] - P[T[:, 0]])[:, 0])
    sign = np.sign(np.median(cross))
    fine_area = _top_area(mesh)
    if not (cross * sign > 0).all() or abs(0.5 * np.abs(cross).sum() - fine_area) > 0.01 * fine_area:
        return None  # folded or gapped: not a triangulation of the top view
    try:
        coarse = PolyMesh.from_faces(mesh.vertices[seeds], T.tolist())
    except Exception:  # noqa: BLE001 - any structural failure means: use the Delaunay coarsening
        return None
    if (not coarse.is_valid() or len(coarse.boundary_loops) != len(mesh.boundary_loops)
            or np.setdiff1d(np.arange(len(seeds)), T).size):
        return None
    return Scene(mesh=coarse, supports=np.asarray(scene.supports, bool)[seeds],
                 name=f"{scene.name}-coarse{len(seeds)}", meta={"coarsening": "clusters"})


def _top_area(mesh: PolyMesh) -> float:

    xy = mesh.vertices[:, :2]
    t = triangulate(mesh)
    u, v = xy[t[:, 1]] - xy[t[:, 0]], xy[t[:, 2]] - xy[t[:, 0]]
    return 0.5 * float(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum())


def coarsen(scene: Scene, n_target: int) -> Scene:
    """A coarser scene over the same top view with about ``n_target`` vertices
    (``meta["coarsening"]`` says which of the two ways, see the module docstring).

    Either way its boundary vertices are vertices of ``scene`` (support flags kept). The
    clusters keep fine vertices only; the Delaunay fallback (Triangle: no Steiner points on the
    boundary, minimum angle 30°, the area bound rescaled until the count is within 15% of the
    target) subsamples interior supports on a grid of the coarse spacing and interpolates the
    heights of its new vertices linearly over the reference's top view.

    >>> from selfsupport.core.shapes import make_shape
    >>> fine = make_shape("pillar_vault", n_vertices=4000)
    >>> c = coarsen(fine, 1000)
    >>> 700 < c.mesh.n_vertices < 1400, c.mesh.is_valid(), bool(c.supports.sum() > 4)
    (True, True, True)
    """
    import igl.triangle
    from shapely.geometry import Polygon

    mesh = scene.mesh
    V = mesh.vertices
    xy = V[:, :2]
    sup = np.asarray(scene.supports, bool)
    n = mesh.n_vertices
    h = mean_edge_length(np.c_[xy, np.zeros(n)], mesh.edges) * np.sqrt(n / max(int(n_target), 3))
    loops = mesh.boundary_loops
    if not loops:
        raise InputError("a mesh without boundary cannot be coarsened for the multilevel solve")
    areas = [0.5 * float(np.sum(xy[lp, 0] * np.roll(xy[lp, 1], -1) - np.roll(xy[lp, 0], -1) * xy[lp, 1]))
             for lp in loops]
    outer = int(np.argmax(np.abs(areas)))
    ids: list[np.ndarray] = []  # fine vertex index of each coarse input point
    segments, holes = [], []
    start = 0
    for k, lp in enumerate(loops):
        keep = lp[_boundary_keep(lp, xy, sup, h)]
        ids.append(keep)
        m = len(keep)
        segments.append(np.c_[start + np.arange(m), start + (np.arange(m) + 1) % m])
        start += m
        if k != outer:
            holes.append(np.asarray(Polygon(xy[lp]).representative_point().coords[0]))
    clustered = _coarsen_by_clusters(scene, n_target, h, np.concatenate(ids))
    if clustered is not None:
        return clustered
    inner = np.flatnonzero(sup & ~mesh.boundary_vertex_mask)
    ids.append(inner[_grid_sample(xy[inner], h)])
    fixed = np.concatenate(ids)
    area = np.sqrt(3.0) / 4.0 * h * h
    pts, segs = np.ascontiguousarray(xy[fixed]), np.ascontiguousarray(np.vstack(segments), dtype=np.int64)
    hole_pts = np.asarray(holes, float).reshape(-1, 2)
    for _ in range(3):  # Triangle's triangles stay below the area bound, ~0.65 of it on average: rescale
        # (the area in positional notation: Triangle reads "5e-05" as a = 5 and the switch "e",
        # whose extra output crashes the process)
        flags = f"pq30a{np.format_float_positional(area, trim='-')}YQ"
        V2, F2, *_ = igl.triangle.triangulate(pts, segs, hole_pts, flags=flags)
        ratio = len(V2) / max(int(n_target), 3)
        if abs(ratio - 1.0) < 0.15:
            break
        area *= ratio
    V2, F2 = np.asarray(V2, float), np.asarray(F2, np.int64)
    if len(V2) < len(fixed) or not np.allclose(V2[:len(fixed)], xy[fixed]):
        raise InputError("the top view could not be coarsened (Triangle moved its boundary); solve on one level")
    z = np.empty(len(V2))
    z[:len(fixed)] = V[fixed, 2]
    new = V2[len(fixed):]
    if len(new):  # (linear over the fine top view; nearest vertex outside it, or where matplotlib
        # cannot locate points: the Fig. 16 vault subdivided twice, "Triangulation is invalid")
        z[len(fixed):] = interpolate_over_top_view(mesh, V[:, 2:3], new, cubic=False)[:, 0]
    coarse = PolyMesh.from_faces(np.c_[V2, z], F2.tolist())
    if not coarse.is_valid():  # (Triangle's mesh of the Fig. 16 vault subdivided twice had a
        # vertex joining two boundary fans, and the coarse level's mesh check raised)
        raise InputError(f"the top view could not be coarsened ({coarse.problems()[0]}); solve on one level")
    supports = np.zeros(len(V2), bool)
    supports[:len(fixed)] = sup[fixed]
    return Scene(mesh=coarse, supports=supports, name=f"{scene.name}-coarse{len(V2)}",
                 meta={"coarsening": "delaunay"})


def why_not(problem: Problem) -> str | None:
    """Why ``problem`` cannot be restated on a coarser mesh (``None``: it can)."""
    scene = problem.scene
    if scene.extra_mass is not None or scene.point_loads is not None:
        return "the scene has extra masses or point loads (tied to vertex indices)"

    def area_load(c: Any) -> bool:
        return isinstance(c, SelfWeight) or (isinstance(c, CombinedLoad) and all(map(area_load, c.cases)))

    if not all(area_load(c) for c in problem.loads.models):
        return "a load case is not a self-weight (point loads or masses are tied to vertex indices)"
    if any(b is not None and np.ndim(b) > 0 for b in (problem.bounds.lower, problem.bounds.upper)):
        return "the weight bounds are given per edge"
    if problem.objective is not None and not all(isinstance(t, ObjectiveTerm) for t in problem.objective):
        return "the objective holds terms built on this mesh"
    if any(not isinstance(c, (FixedTopView, Hull)) for c in problem.constraints):
        return "a constraint (planar faces) belongs to this mesh's faces"
    return None


def _subdivision_levels(parents: Sequence[Scene]) -> list[Scene]:
    """The designer's coarser scenes as levels (marked so in each level's report)."""
    return [dataclasses.replace(p, meta={**p.meta, "coarsening": "subdivision"}) for p in parents]


def coarse_problem(problem: Problem, scene: Scene) -> Problem:
    """``problem`` restated on ``scene`` (a coarsening of its scene): same load models, bounds,
    objective and constraints."""
    return Problem(scene=scene, loads=problem.loads, bounds=Bounds(problem.bounds.lower, problem.bounds.upper),
                   objective=problem.objective, constraints=problem.constraints)


# ------------------------------------------------------------------------------ the method
@dataclasses.dataclass
class _LevelStart:
    """How a level starts: its warm start (None: cold), extra staggered settings, the report of
    how it was carried from the level below (None: not carried), a one-iteration probe that is
    already the level's result, whether progress has been told, and the prolongation."""

    warm: Any = None
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)
    carried: dict[str, Any] | None = None
    probed: SolveResult | None = None
    announced: bool = False
    pro: Prolongation | None = None


class Multilevel:
    """The staggered method on a hierarchy of coarsened top views (see the module docstring).

    Parameters
    ----------
    backend
        The staggered method's Step-2 backend.
    direct_max
        Meshes up to this many vertices are solved on one level; above, the coarsest level has
        at most this many.
    factor
        Vertex ratio between neighbouring levels (the clusters give ~4 whatever it is; the
        Delaunay fallback follows it).
    prolongation
        How a level starts the next (:data:`PROLONGATIONS`).
    use_subdivision
        Solve the coarser scenes a subdivided scene came from as its levels (see :meth:`levels`);
        False: coarsen its top view like any other mesh.
    """

    name = "multilevel"
    capabilities = METHODS["multilevel"].capabilities  # (declared in the registry)

    def __init__(self, backend: str | WeightFitBackend = "active-set", *, direct_max: int = DIRECT_MAX,
                 factor: float = FACTOR, prolongation: str = "stress", use_subdivision: bool = True,
                 **options: Any) -> None:
        if not factor > 1.5:
            raise InputError(f"the multilevel factor must exceed 1.5, got {factor}")
        if prolongation not in PROLONGATIONS:
            raise InputError(f"unknown prolongation {prolongation!r}; choose one of {list(PROLONGATIONS)}")
        self.prolongation, self.use_subdivision = prolongation, bool(use_subdivision)
        self.staggered = StaggeredLinearization(backend, **options)
        self.backend = self.staggered.backend
        self.direct_max, self.factor = int(direct_max), float(factor)

    def levels(self, scene: Scene) -> list[Scene]:
        """The scenes solved, coarsest first, ``scene`` last.

        A scene refined by :func:`~selfsupport.core.subdivision.subdivide_scene` (and unchanged
        since) has its own hierarchy: the designer's coarser scenes, from the finest one of at
        most ``direct_max`` vertices (coarsened further when even the coarsest is larger)."""
        parents = subdivision_parents(scene) if self.use_subdivision else ()
        if parents and scene.mesh.n_vertices > self.direct_max:
            small = [k for k, p in enumerate(parents) if p.mesh.n_vertices <= self.direct_max]
            chain = _subdivision_levels(parents[(small[-1] if small else 0):])
            return self.levels(chain[0])[:-1] + chain + [scene]
        out = [scene]
        while out[-1].mesh.n_vertices > self.direct_max:
            try:
                coarse = coarsen(out[-1], int(out[-1].mesh.n_vertices / self.factor))
            except InputError:  # (a top view Triangle cannot mesh: the levels made so far)
                break
            if coarse.mesh.n_vertices >= 0.8 * out[-1].mesh.n_vertices:  # (nothing gained)
                break
            out.append(coarse)
        return out[::-1]

    def levels_from(self, network: Any, scene: Scene) -> list[Scene]:
        """The subdivision levels from the scene ``network`` has the mesh of up to ``scene``;
        ``[scene]`` when it has none of theirs."""
        parents = subdivision_parents(scene) if self.use_subdivision else ()
        for k, p in enumerate(parents):
            if p.mesh.n_vertices == network.mesh.n_vertices and np.array_equal(p.mesh.edges, network.mesh.edges):
                return _subdivision_levels(parents[k:]) + [scene]
        return [scene]

    def solve(self, problem: Problem | Scene, options: Mapping[str, Any] | None = None, *,
              progress: Callable[[dict], None] | None = None, loads: Any = None, deadline: float | None = None,
              warm_start: Any = None, **overrides: Any) -> SolveResult:
        """Solve ``problem`` level by level; ``options`` are staggered settings (every level).

        A ``warm_start`` on the mesh of a scene this one was subdivided from starts that level
        (one iteration confirms it when it is that scene's network), and the levels go up from
        there; any other warm start skips the hierarchy: the fine level starts from it as the
        staggered method would."""
        t0 = time.perf_counter()
        loads, options = loads_or_options(options, loads)
        problem = as_problem(problem, loads)
        opts = {**dict(options or {}), **overrides}
        # one deadline for all levels (each level's messages name the whole limit)
        deadline = t0 + float(opts.get("time_limit", self.staggered.options.time_limit)) if deadline is None else deadline
        scenes, why = self._scenes(problem, warm_start)
        if len(scenes) == 1:
            res = self.staggered.solve(problem, opts, progress=progress, deadline=deadline, warm_start=warm_start)
            info = {"levels": [self._level(res, problem.scene)], "why": why or
                    f"{problem.scene.mesh.n_vertices} vertices: one level (direct_max {self.direct_max})"}
            return dataclasses.replace(res, method=self.name, parameters={**res.parameters, "multilevel": info})
        levels: list[dict[str, Any]] = []
        res: SolveResult | None = None
        prev_scene: Scene | None = None
        for k, scene in enumerate(scenes):
            fine = scene is problem.scene
            prob = problem if fine else coarse_problem(problem, scene)
            step = None if progress is None else (lambda rec, k=k: progress({**rec, "level": k}))
            start = _LevelStart(warm=warm_start if k == 0 else None) if res is None else \
                self._carry(prob, res, prev_scene, opts, fine=fine, step=step, deadline=deadline)
            if step is not None and start.carried is not None and not start.announced:
                step(_carried_record(start.carried))
            res = start.probed or self.staggered.solve(prob, {**opts, **start.extra}, progress=step,
                                                       deadline=deadline, warm_start=start.warm)
            if res.status == "interrupted":  # Ctrl-C: no level, refinement or cold solve after it
                if not fine:  # (a coarser level's network is no answer for this mesh)
                    raise KeyboardInterrupt(f"interrupted on level {k} ({scene.mesh.n_vertices} vertices)")
                levels.append(self._level(res, scene, start.carried))
                break
            tol = float(res.parameters.get("tol", self.staggered.options.tol))
            res = self._start_if_nearer(res, prob, start, tol=tol, deadline=deadline)
            levels.append(self._level(res, scene, start.carried))
            if fine and start.carried is not None:
                res, cold_why = self._cold_if_stopped(res, problem, start.carried, opts, tol=tol, step=step,
                                                      deadline=deadline, levels=levels)
                why = cold_why or why
            prev_scene = scene
            in_equilibrium = res.max_relative_error <= START_TOL
            if not fine and (not in_equilibrium or out_of_time(deadline)):
                # a coarse network out of equilibrium is no better a start than the reference: the
                # fine level goes cold (one that stalled but was polished into equilibrium is a
                # network near the reference all the same, and the next level starts from it)
                why = (f"the time limit was reached on level {k} ({scene.mesh.n_vertices} vertices)"
                       if in_equilibrium else
                       f"level {k} ({scene.mesh.n_vertices} vertices) ended {res.status} out of equilibrium: "
                       "the fine level started cold")
                fine_step = None if progress is None else (lambda rec: progress({**rec, "level": len(scenes) - 1}))
                res = self.staggered.solve(problem, opts, progress=fine_step, deadline=deadline)
                levels.append(self._level(res, problem.scene))
                break
        assert res is not None
        info = {"levels": levels, "factor": self.factor, "direct_max": self.direct_max, "warm_alpha0": WARM_ALPHA0}
        if why:
            info["why"] = why
        return dataclasses.replace(res, method=self.name, wall_time=time.perf_counter() - t0,
                                   parameters={**res.parameters, "multilevel": info})

    def _scenes(self, problem: Problem, warm_start: Any) -> tuple[list[Scene], str | None]:
        """The levels to solve, coarsest first, and why there is only one (None: not said)."""
        why = why_not(problem)
        if why:
            return [problem.scene], why
        if warm_start is not None:
            # a network of one of the scenes this one was subdivided from (the edit tool's
            # subdivide stage): the levels go up from that scene, starting from the network
            scenes = self.levels_from(as_warm_start(warm_start).network, problem.scene)
            return scenes, None if len(scenes) > 1 else "a warm start was given"
        return self.levels(problem.scene), None

    def _carry(self, prob: Problem, below: SolveResult, below_scene: Scene, opts: dict[str, Any], *, fine: bool,
               step: Callable[[dict], None] | None, deadline: float) -> _LevelStart:
        """How the level of ``prob`` starts from the level below: carried over by its stress field, in
        equilibrium here (prolong.py); failing that, its offsets interpolated, iterated from (warm.py)."""
        scene = prob.scene
        pro = prolong(prob, below.network, below_scene.mesh, deadline=deadline,
                      subdivision=subdivide_like(scene, below_scene, below.network.vertices)) \
            if self.prolongation == "stress" else None
        extra = {"warm_iterate": True, "alpha0": min(WARM_ALPHA0, float(opts.get("alpha0", 1.0)))}
        if pro is not None and pro.network is not None:
            return self._carried_by_stress(prob, pro, below, opts, extra, fine=fine, step=step, deadline=deadline)
        if pro is not None and pro.nearest is not None and pro.max_relative_error <= START_TOL:
            # the polish came near equilibrium but not to PROLONG_TOL (held by the round-off
            # floor of free-boundary arches): a start as good as a level's network (START_TOL),
            # far nearer than interpolated heights
            carried = {"by": "stress, nearest", "seconds": pro.seconds,
                       "max_relative_error": pro.max_relative_error, "why": pro.info.get("why")}
            return _LevelStart(warm=WarmStart(pro.nearest, reference=scene.mesh), extra=extra, carried=carried,
                               pro=pro)
        carried = {"by": "interpolation"}
        if pro is not None:
            carried["why"] = pro.info.get("why")
        return _LevelStart(warm=WarmStart(below.network, reference=below_scene.mesh), extra=extra, carried=carried,
                           pro=pro)

    def _carried_by_stress(self, prob: Problem, pro: Prolongation, below: SolveResult, opts: dict[str, Any],
                           extra: dict[str, Any], *, fine: bool, step: Callable[[dict], None] | None,
                           deadline: float) -> _LevelStart:
        """The level starts from the prolonged network ``pro.network`` (progress is told so),
        unless it lies more than :data:`RECLAIM` × farther from the reference than the level
        below: then an intermediate level of at most :data:`COLD_MAX` vertices is solved cold, and
        any other is probed by one cold iteration and, unless that converges, refined."""
        scene = prob.scene
        warm = WarmStart(pro.network, reference=scene.mesh)
        d_pro = distance_stats(pro.network.vertices, scene.mesh)[0]
        d_below = distance_stats(below.network.vertices, scene.mesh)[0]
        carried = {"by": "subdivision" if pro.info.get("weights") == "subdivided" else "stress",
                   "seconds": pro.seconds, "max_relative_error": pro.max_relative_error,
                   "distance": d_pro, "distance_below": d_below, **pro.info}
        if step is not None:  # (before the probe below)
            step(_carried_record(carried))
        probed = None
        if d_pro > RECLAIM * d_below and not fine and scene.mesh.n_vertices <= COLD_MAX:
            # the stress below did not carry: an intermediate level this small is solved
            # cold (whose first iteration is the probe below)
            warm, extra, carried["cold"] = None, {}, True
        elif d_pro > RECLAIM * d_below:
            # farther from the reference than the level below. A reference that stands
            # as it is (a surface already in equilibrium, which the carried stress only
            # reproduces to the fine mesh's discretization) is found by one cold
            # iteration; otherwise walk back in equilibrium
            probe = self.staggered.solve(prob, {**opts, "max_iter": 1}, progress=step, deadline=deadline)
            carried["probe"] = {"status": probe.status, "seconds": probe.wall_time}
            if probe.status in ("converged", "interrupted"):  # (Ctrl-C ends the level too)
                probed = probe
            elif len(prob.loads) == 1:  # (the refinement carries one load case)
                extra["refine"] = max(int(opts.get("refine", 0)), RECLAIM_STEPS)
                carried["refine"] = extra["refine"]
        return _LevelStart(warm=warm, extra=extra, carried=carried, probed=probed, announced=True, pro=pro)

    @staticmethod
    def _start_if_nearer(res: SolveResult, prob: Problem, start: _LevelStart, *, tol: float,
                         deadline: float) -> SolveResult:
        """``res``, or the level's start where that was the nearest prolongation and iterating from
        it did not converge and ended farther from equilibrium: the start is the answer, its
        weights refit to its positions where that balances it (held above tol by rounding: a 256k
        pillar vault, 2.07e-8 -> 8.4e-9, where the iterate's own refit did not reach 1e-8)."""
        carried, pro = start.carried, start.pro
        if not (carried is not None and carried["by"] == "stress, nearest" and res.status != "converged"
                and not res.max_relative_error <= pro.max_relative_error):
            return res
        refit = None
        if not (pro.nearest.in_equilibrium(tol) or out_of_time(deadline)):
            lo, up = edge_bounds(prob)  # (the scaled problem: built only when refitting)
            refit = refit_weights(pro.nearest, tol, lower=lo, upper=up)
        start_net = pro.nearest if refit is None else refit
        res = _with_network(res, prob, start_net, (
            f"the level's start, its prolonged network (max relative error {pro.max_relative_error:.2e}"
            + ("" if refit is None else f"; {start_net.max_relative_error():.2e} with its weights refit to its "
               "positions as stored") + f"), is returned: iterating from it ended at "
            f"{res.max_relative_error:.2e}, {res.status}"), tol, status=None if refit is None else "converged")
        carried["returned"] = True
        carried["refit"] = refit is not None
        return res

    def _cold_if_stopped(self, res: SolveResult, problem: Problem, carried: dict[str, Any], opts: dict[str, Any], *,
                         tol: float, step: Callable[[dict], None] | None, deadline: float,
                         levels: list[dict[str, Any]]) -> tuple[SolveResult, str | None]:
        """The fine level solved cold (appended to ``levels``) where iterating from its carried start
        did not converge: a fine level of at most :data:`COLD_MAX` vertices that started from
        interpolated heights, or any that stopped out of equilibrium not held there by the rounding
        of its positions alone. Returns the nearer to equilibrium of the two, and why the cold one
        is the answer (None: ``res`` is)."""
        # out of equilibrium, and not held there by the rounding of its positions alone (which
        # no solve would mend: the 256k pillar vault's arches)
        unbalanced = res.max_relative_error > tol and "roundoff_limit" not in res.parameters
        if (res.status in ("converged", "time_limit")
                or not (unbalanced or (carried["by"] == "interpolation"
                                       and problem.scene.mesh.n_vertices <= COLD_MAX))
                or out_of_time(deadline)):
            return res, None
        # (interpolated heights can hold a level near a stall that a cold solve of the same level
        # does not meet)
        cold = self.staggered.solve(problem, opts, progress=step, deadline=deadline)
        levels.append({**self._level(cold, problem.scene), "cold_after": res.status})
        if cold.status in ("converged", "interrupted") or cold.max_relative_error < res.max_relative_error:
            began = "from interpolated heights" if carried["by"] == "interpolation" else \
                f"from its prolongation ({carried['by']})"
            return cold, f"the fine level iterated {began} ended {res.status}: it was solved cold"
        return res, None

    @staticmethod
    def _level(res: SolveResult, scene: Scene, carried: dict[str, Any] | None = None) -> dict[str, Any]:
        """The report of one level (with how its start was carried, when it was)."""
        first = next((h.get("max_rel_error") for h in res.history if isinstance(h.get("iteration"), int)), None)
        return {"n_vertices": scene.mesh.n_vertices, "n_edges": scene.mesh.n_edges,
                "coarsening": scene.meta.get("coarsening"), "status": res.status,
                "iterations": res.iterations, "time": res.wall_time, "first_fit_error": first,
                "max_relative_error": res.max_relative_error, **({"prolongation": carried} if carried else {})}


def solve_warm(method: StaggeredLinearization, problem: Problem, options: Mapping[str, Any] | None = None, *,
               warm_start: Any = None, progress: Callable[[dict], None] | None = None) -> SolveResult:
    """``method`` from ``warm_start`` (the design tools' next stage after an edit), except that a
    warm start on the mesh of a scene ``problem`` was subdivided from goes up level by level
    from it (:meth:`Multilevel.levels_from`): a warm start interpolated onto a mesh 23× finer
    (lilium subdivided twice) was too far from equilibrium, and the cold solve then stalled."""
    if warm_start is not None:
        ml = Multilevel(method.backend)
        ml.staggered = method  # (every level with the caller's settings)
        if len(ml.levels_from(as_warm_start(warm_start).network, as_problem(problem).scene)) > 1:
            return ml.solve(problem, options, progress=progress, warm_start=warm_start)
    return method.solve(problem, options, progress=progress, warm_start=warm_start)
