"""Planar faces by a homotopy in the allowed non-planarity (paper §5; the finish of
:func:`selfsupport.remesh.planar.solve_planar`).

Start: a network in equilibrium on the quad mesh, faces not planar (the staggered method finds
one in a fraction of a second). Each stage lowers the band ``b`` every face's non-planarity must
stay within (distance of the diagonals over the mean side length,
:func:`selfsupport.core.geometry.diagonal_distance`) and restores equilibrium with it by the
joint minimum-norm Gauss–Newton polish (:func:`~selfsupport.methods.polish.polish_joint`:
positions and free weights together, loads of the moving geometry). A face inside the band is
free; a face at or past it is held on it (an active set, re-read at every step). A stage that
does not reach equilibrium is retried with a smaller cut (``shrink ← √shrink``); one that does
lets the next cut grow (``shrink ← shrink^1.5``). The band ends at :data:`BAND_END` × the
required tolerance.

Why a homotopy: the planarity rows as equations all at once are far from the start (lilium's
remesh: rows up to 0.27), and a full Gauss–Newton step there leaves equilibrium by 3e2 and
diverges; the staggered method (planarity as a penalty) stalls at max relative error 0.5, and
IPOPT from the same start wanders to its time limit. Small cuts keep every stage within
Newton's reach of the last. Why a band rather than ``s × (initial rows)`` → 0: faces already
planar to the tolerance need not be made exactly planar, and requiring it (all rows scaled
together) met a fold at s ≈ 0.015 on that remesh. Why the diagonal distance rather than the
determinant rows ``det / ℓ³`` of :class:`~formulations.terms.planarity.PlanarFaces` (``ℓ`` of the
reference): those fall with the cube of a face's shrinking, and held small they were met by
shrinking faces — the same remesh ended with every row within 9e-4 but quads 2.9e-3 from planar
(after the remesher's split of its near-triangular quads; without the split, 5.4e-2 with corner
angles of 0.1°).

The pull: the stages' minimum-norm steps keep the network near the start of the homotopy,
which is only *a* network in equilibrium (the staggered solve without planar faces lifted the
free edges of the paper's vault remeshed along its principal directions 0.24 of the diagonal
off the remesh; at the published spacing 1.3 of it, and the homotopy stalled from there).
So the planar end is drawn toward the reference with its faces held in the band reached:
constrained Levenberg–Marquardt steps toward the tangent planes at the closest points of the
reference, each restored by the same polish and accepted only feasible and closer
(:func:`_pull`). The homotopy runs from the start as given first; only where it does not
converge (the vault's aligned remesh at the published spacing) does it run again from that
start pulled toward the reference in equilibrium (:func:`_pull_start`; the pulled start is not
always the easier one: from lilium's grid remesh pulled so, it crawls).

Example: a barrel vault remeshed along its relative principal directions, where the staggered
method with planar faces stalls:

>>> import numpy as np
>>> from formulations import Planar
>>> from selfsupport import api
>>> from selfsupport.core.shapes import make_shape
>>> from selfsupport.remesh.streamlines import remesh
>>> net = api.solve(make_shape("barrel_vault", nx=8, ny=10)).network
>>> q = remesh(net, field="principal", spacing=0.1, relative=True).scene
>>> eq = api.solve(q)  # in equilibrium, faces not planar
>>> r = planar_homotopy(api.problem(q, constraints=[Planar(tol=1e-3)]), eq)
>>> r.status, r.max_relative_error < 1e-8, r.parameters["planarity"]["max_nonplanarity"] <= 1e-3
('converged', True, True)
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from functools import partial
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from formulations import Planar, Problem, ThrustNetworkProblem, WeightBounds
from formulations.terms.planarity import coplanarity_rows
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import closest_points, distance_stats
from selfsupport.core.geometry import diagonal_distance, mean_edge_length
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import SolveResult
from selfsupport.methods.base import case_networks, nonplanar_faces_note, planarity_report, term_values
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.polish import case_load_jacobians, constrained_step, polish_joint
from selfsupport.methods.staggered import DEFAULT_OBJECTIVE
from selfsupport.methods.warm import as_warm_start, transfer

__all__ = ["planar_homotopy", "handles", "BAND_END"]

#: The band ends at this fraction of the problem's planarity tolerance (the margin keeps the
#: reported non-planarity, measured in SI units after the scaling's round trip, below it). A
#: stage whose band is within the tolerance ends the homotopy already when its network, in SI
#: units, is planar to the tolerance and in equilibrium (the margin is for the round trip, not a
#: goal).
BAND_END = 0.7
#: First cut of the band (b ← shrink · b).
FIRST_SHRINK = 0.9
#: A stage whose cut would have to be finer than this gives up ("stalled").
MAX_SHRINK = 0.9999
#: Max relative equilibrium error every stage reaches before the band is cut again.
STAGE_TOL = 1e-9
#: Gauss–Newton steps a stage may take.
STAGE_STEPS = 15
#: Most stages ("iteration_limit" after them): a converging homotopy needs tens to a few hundred;
#: beyond, it is crawling along a fold, cutting the band by ~1e-4 per stage.
MAX_STAGES = 400
#: Stages over which the band's pace is measured: once this many have run, a homotopy whose band,
#: falling at :data:`PACE_MARGIN` × its pace over them, would not reach the target within the
#: stages left stops ("stalled"): it is crawling along a fold, and the stages left would only
#: spend the time limit.
PACE_WINDOW = 30
#: How many times its recent pace a crawling homotopy is granted before it stops.
PACE_MARGIN = 2.0
#: The pull toward the reference after the homotopy (:func:`_pull`, Levenberg–Marquardt): the
#: first damping ``μ`` (a tangential move costs ``μ`` times a move across the surface), its
#: factors after an accepted and a rejected step, its floor, and the ceiling past which the pull
#: ends (the steps are then too short to matter).
PULL_MU_FIRST = 1e-2
PULL_MU_DOWN = 4.0
PULL_MU_UP = 8.0
PULL_MU_MIN = 1e-8
PULL_MU_MAX = 1e3
#: The pull has converged when its last :data:`PULL_WINDOW` accepted steps together lowered the
#: summed squared distance by less than the fraction :data:`PULL_GAIN` (1e-4 a step on average:
#: a hundred more would gain under 1 %). Measured over a window, not step by step: the steps
#: alternate between long and short ones where the band's active set changes.
PULL_GAIN = 5e-4
PULL_WINDOW = 5
#: The pull's share of the time left when it starts: it refines a network already planar and in
#: equilibrium, so one too slow to converge ends at its share with its best network, before the
#: run's limit, rather than being cut by it.
PULL_SHARE = 0.5
#: A backstop on the pull's steps where there is no time limit (a converging pull ends far
#: earlier: it is not a setting of the result).
PULL_MAX_STEPS = 2000
#: The pull has reached the reference when the free vertices' root-mean-square distance to it is
#: below this multiple of the planarity tolerance times the mean edge: a face may be off its
#: plane by that much, so a network nearer is on the reference to within what its planar faces
#: resolve.
PULL_ON_REFERENCE = 1.0
#: A vertex whose gap to its closest point makes an angle with the surface's normal there of
#: cosine at least this is drawn to the tangent plane, others (their closest point on the
#: surface's edge) to the point.
PULL_PLANE_COS = 0.95
#: Rounds of :func:`_band_step` (each holds the faces the step would carry past the band).
PULL_ACTIVE_ROUNDS = 5
#: The pull of the homotopy's start (:func:`_pull_start`): the first fraction of the way to the
#: closest points, the smallest one tried (below it the pull ends), its most steps; a step that
#: lowers the summed squared distance by less than :data:`START_PULL_GAIN` is small, and
#: :data:`START_PULL_PATIENCE` small steps in a row end it.
START_PULL_FIRST = 0.5
START_PULL_MIN = 1.0 / 64
START_PULL_MAX_STEPS = 60
START_PULL_GAIN = 1e-2
START_PULL_PATIENCE = 3
#: The pull of the start gets at most this share of the time left (the homotopy needs the rest).
PULL_START_SHARE = 0.25


@dataclass(frozen=True, eq=False)
class _Band:
    """The planarity rows of one stage, in the shape :func:`polish_joint` reads (``linearize``):
    each face whose non-planarity is at or past ``band`` held on it, the rest left free; or, with
    ``held`` (per face 0, or the sign of the side of the band it is held on), those faces."""

    rows: np.ndarray  # (r, 4) corners, coplanarity_rows' order
    band: float
    n_vertices: int
    held: np.ndarray | None = None

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        r, J = diagonal_distance(V, self.rows, jacobian=True)
        if self.held is not None:
            on = np.flatnonzero(self.held)
            if on.size:
                return r[on] - self.held[on] * self.band, J[on]
            return np.zeros(1), sp.csr_matrix((1, 3 * self.n_vertices))
        held = np.flatnonzero(np.abs(r) > (1 - 1e-3) * self.band)
        if held.size == 0:  # (one empty row: the polish's system keeps its shape)
            return np.zeros(1), sp.csr_matrix((1, 3 * self.n_vertices))
        return r[held] - np.sign(r[held]) * self.band, J[held]


def _crawling(bands: list[float], target: float) -> bool:
    """Whether the band, at :data:`PACE_MARGIN` × its pace (in log) over the last
    :data:`PACE_WINDOW` stages (``bands``: the band after each stage), would stay above
    ``target`` after the stages left of :data:`MAX_STAGES`."""
    if len(bands) <= PACE_WINDOW:
        return False
    pace = np.log(bands[-PACE_WINDOW - 1] / bands[-1]) / PACE_WINDOW
    return bool(PACE_MARGIN * pace * (MAX_STAGES - len(bands)) < np.log(bands[-1] / target))


def _stages(form_at: Callable[[np.ndarray, float], ThrustNetworkProblem], X: np.ndarray, W: np.ndarray, *,
            loads_at: Callable[[np.ndarray], np.ndarray], load_jacobian: Any, band: float, target: float,
            tol: float, planar_enough: Callable[[np.ndarray, np.ndarray], bool],
            deadline: float | None, progress: Callable[[dict], None] | None) -> tuple:
    """The homotopy's stages from the band ``band`` down to ``target``: each a joint polish with
    the faces held within the next band (``form_at(X, band)``); an accepted stage cuts faster, a
    failed one retries a finer cut. A stage within the tolerance ``tol`` ends it already when
    ``planar_enough(X, W)``; a homotopy too slow to reach ``target`` within :data:`MAX_STAGES`
    (:func:`_crawling`) stops. Returns (X, W, band reached, polish steps, history, status)."""
    shrink, steps, history, bands = FIRST_SHRINK, 0, [], []
    status = "stalled"
    first = True
    while True:
        if out_of_time(deadline):
            status = "time_limit"
            break
        if len(history) >= MAX_STAGES:
            status = "iteration_limit"
            break
        trial = band if first else max(band * shrink, target)  # (the first stage: equilibrium at the start's band)
        form = form_at(X, trial)
        t_stage = time.perf_counter()
        Xn, Wn, k, err, ok = polish_joint(form, X, W, loads_at=loads_at, tol=STAGE_TOL, max_iter=STAGE_STEPS,
                                          load_jacobian=load_jacobian, deadline=deadline)
        t_stage = time.perf_counter() - t_stage
        steps += k
        rec = {"iteration": len(history), "band": trial, "steps": k, "max_rel_error": err, "accepted": bool(ok)}
        history.append(rec)
        if progress is not None:
            progress(rec)
        if ok:
            X, W, band = Xn, Wn, trial
            shrink = shrink if first else shrink ** 1.5
            if band <= target or (band <= tol and planar_enough(X, W)):
                status = "converged"
                break
        elif out_of_time(deadline, t_stage):
            # (the polish stops a step short of the deadline: a stage failed so near it failed
            # for want of time, not for a cut too coarse, and another would fail the same way)
            status = "time_limit"
            break
        elif first:
            break  # the start is not in equilibrium to within the polish's reach
        else:
            shrink = shrink ** 0.5
            if shrink > MAX_SHRINK:
                break
        bands.append(band)
        if _crawling(bands, target):
            break
        first = False
    return X, W, band, steps, history, status


def _reference_step(X: np.ndarray, fidx: np.ndarray, closest: np.ndarray, normals: np.ndarray,
                    mu: float) -> tuple[np.ndarray, sp.csr_matrix]:
    """The Levenberg–Marquardt step toward the reference of the free vertices ``fidx`` and its
    metric, for :func:`~selfsupport.methods.polish.constrained_step` (flattened free positions).

    Gauss–Newton on the squared distance to the surface: at a vertex whose closest point lies
    inside the surface (the gap ``X − C`` along the surface's normal there, within
    :data:`PULL_PLANE_COS`; ``n`` its direction) the distance to the tangent plane,
    ``(n · (X + dX − C))²`` (sliding
    along the surface is free), else — the closest point on the surface's edge — the distance to
    the point, ``|X + dX − C|²``. With ``P`` the projection (``n nᵀ``, or ``I``) and the damping
    ``μ |dX|²``, the step minimising the sum is ``d0 = −P (X − C) / (1 + μ)`` and the cost of
    another step ``d`` is ``(d − d0)ᵀ (P + μ I) (d − d0)``, i.e. ``|D⁻¹ (d − d0)|²`` up to the
    factor ``μ`` with ``D = (P / μ + I)^(−½) = I + (s − 1) P``, ``s = √(μ / (1 + μ))``
    (tangential moves cost ``μ``, moves along ``P`` ``1 + μ``)."""
    g = X[fidx] - closest[fidx]
    gn = np.linalg.norm(g, axis=1)
    # (the plane's normal: the gap's direction, the distance's gradient — exactly the normal of
    # the reference's face the closest point lies on; on the surface, the surface's normal)
    off = gn > 1e-12 * max(float(np.abs(X).max()), 1.0)
    n = np.where(off[:, None], g / np.where(off, gn, 1.0)[:, None], normals[fidx])
    plane = ~off | (np.abs(np.einsum("ij,ij->i", n, normals[fidx])) >= PULL_PLANE_COS)
    P = np.where(plane[:, None, None], n[:, :, None] * n[:, None, :], np.eye(3)[None])
    d0 = -np.einsum("kab,kb->ka", P, g) / (1.0 + mu)
    blocks = np.eye(3)[None] + (np.sqrt(mu / (1.0 + mu)) - 1.0) * P
    k = np.arange(3 * len(fidx)).reshape(-1, 3)
    D = sp.csr_matrix((blocks.ravel(), (np.repeat(k, 3, axis=1).ravel(), np.tile(k, (1, 3)).ravel())),
                      shape=(3 * len(fidx),) * 2)
    return d0.ravel(), D


def _pull_start(form: Callable[[np.ndarray], ThrustNetworkProblem], X: np.ndarray, W: np.ndarray, *,
                loads_at: Callable[[np.ndarray], np.ndarray], load_jacobian: Any, free: np.ndarray,
                targets: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], feasible: Callable[[np.ndarray, np.ndarray], bool],
                deadline: float | None, progress: Callable[[dict], None] | None) -> tuple:
    """The start of the homotopy's second run drawn toward the targets: each step moves the free vertices the
    fraction ``alpha`` of the way to ``targets(X)`` (their closest points on the reference) and
    restores equilibrium (and the faces' band, where ``form(X)`` has one) by the joint
    minimum-norm polish. The restoration takes back the step's part across the linearised
    constraints, so the pair is a projected-gradient step on the summed squared distance. A step
    is accepted when the polish converges, the network is ``feasible`` and closer; ``alpha``
    then doubles after two accepted steps in a row, and halves after a rejected one.

    Not :func:`_pull`'s Gauss–Newton steps: those drew the vault's aligned remesh at the
    published spacing closer (2.0e-3 of the diagonal against 2.9e-3 after these), and the
    homotopy stalled from there where it converges from this start; a start for the homotopy
    is not better for being closer.

    Returns (X, W, polish steps, history, why it ended: as :func:`_pull`)."""
    def dist(Y: np.ndarray) -> float:
        return float(np.sum((targets(Y)[0][free] - Y[free]) ** 2))

    alpha, steps, history, f = START_PULL_FIRST, 0, [], dist(X)
    small = run = 0
    while alpha >= START_PULL_MIN and len(history) < START_PULL_MAX_STEPS and small < START_PULL_PATIENCE and not out_of_time(deadline):
        Xp = X.copy()
        Xp[free] += alpha * (targets(X)[0][free] - X[free])
        Xn, Wn, k, err, ok = polish_joint(form(Xp), Xp, W, loads_at=loads_at, tol=STAGE_TOL, max_iter=STAGE_STEPS,
                                          load_jacobian=load_jacobian, deadline=deadline)
        steps += k
        fn = dist(Xn) if ok else np.inf
        accept = bool(fn < f and feasible(Xn, Wn))
        rec = {"pull": len(history), "alpha": alpha, "steps": k, "max_rel_error": err, "distance": fn,
               "accepted": accept}
        history.append(rec)
        if progress is not None:
            progress(rec)
        if accept:
            small = small + 1 if fn > (1 - START_PULL_GAIN) * f else 0
            X, W, f, run = Xn, Wn, fn, run + 1
            alpha = min(2 * alpha, 1.0) if run >= 2 else alpha
        else:
            alpha, run = alpha / 2, 0
    stop = ("converged" if small >= START_PULL_PATIENCE else "no_closer_step" if alpha < START_PULL_MIN
            else "time_limit" if out_of_time(deadline) else "iteration_limit")
    return X, W, steps, history, stop


def _band_step(form: Callable[..., ThrustNetworkProblem], X: np.ndarray, W: np.ndarray, d0: np.ndarray,
               D: sp.spmatrix, *, loads_at: Callable[[np.ndarray], np.ndarray], load_jacobian: Any,
               deadline: float | None) -> tuple | None:
    """:func:`~selfsupport.methods.polish.constrained_step` with the faces' band as inequalities:
    no face held at first; a face the step would carry past the band is held on it (on the side
    it would cross) and the step redone, for at most :data:`PULL_ACTIVE_ROUNDS` rounds. (Holding
    every face at the band, as the polish does, kept faces the step would move inwards on it, and
    the pull stopped where they piled up.) ``form(X, held)``: the problem with ``held``
    (:class:`_Band`). Returns ``(X + d_X, W + d_W)``, or None past ``deadline``."""
    band = form(X).planar
    held = None if band is None else np.zeros(len(band.rows))
    found: list = []  # (every round linearises at X: the loads' Jacobian there, formed once)

    def jacobian_at_x(V: np.ndarray, L: np.ndarray, deadline: float | None = None) -> list | None:
        if not found:
            found.append(load_jacobian(V, L, deadline=deadline))
        return found[0]

    for _ in range(PULL_ACTIVE_ROUNDS):
        lin = constrained_step(form(X, held), X, W, d0, D, loads_at=loads_at,
                               load_jacobian=None if load_jacobian is None else jacobian_at_x, deadline=deadline)
        if lin is None or held is None:
            return lin
        r = diagonal_distance(lin[0], band.rows)[0]
        out = (held == 0) & (np.abs(r) > band.band)
        if not out.any():
            break
        held = held.copy()
        held[out] = np.sign(r[out])
    return lin


def _pull(form: Callable[..., ThrustNetworkProblem], X: np.ndarray, W: np.ndarray, *,
          loads_at: Callable[[np.ndarray], np.ndarray], load_jacobian: Any, free: np.ndarray,
          targets: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
          feasible: Callable[[np.ndarray, np.ndarray], bool], on_reference: float,
          deadline: float | None, progress: Callable[[dict], None] | None) -> tuple:
    """The feasible network nearest the reference, locally, by a constrained Levenberg–Marquardt
    iteration on the summed squared distance of the free vertices to it.

    Each step is the Gauss–Newton step toward the tangent planes at the closest points
    (``targets(X)``: closest points and unit normals; :func:`_reference_step`) restricted to the
    joint polish's linearised constraints (equilibrium, and where ``form(X)`` has a band the faces
    within it, :func:`_band_step`; ``form(X, held)`` that problem with the faces ``held``), then restored by
    the joint polish. A step is accepted when the polish converges and the network is
    ``feasible`` and closer; the damping ``μ`` then falls by :data:`PULL_MU_DOWN`, else rises by
    :data:`PULL_MU_UP`. Point-to-plane rather than point-to-point: the squared distance to a
    surface is curved only across it, and a step that paid for sliding along it (the
    Euclidean projected gradient) crept wherever the constraints ask for such sliding.

    The pull ends ``"on_reference"`` when the free vertices' root-mean-square distance is below
    ``on_reference`` (:data:`PULL_ON_REFERENCE`); ``"converged"`` when its last :data:`PULL_WINDOW`
    accepted steps together gained less than :data:`PULL_GAIN` (relative); ``"no_closer_step"`` when ``μ`` passes
    :data:`PULL_MU_MAX` (no step long enough to matter was feasible and closer: on the
    reference already, or the polish cannot restore equilibrium to its tolerance after any);
    ``"time_limit"`` when a step would end
    past ``deadline`` (the caller's share of the time, :data:`PULL_SHARE`; every step honours it
    inside); ``"iteration_limit"`` after :data:`PULL_MAX_STEPS` steps.

    Returns (X, W, polish steps, history, why it ended)."""
    def dist(Y: np.ndarray, closest: np.ndarray) -> float:
        return float(np.sum((closest[free] - Y[free]) ** 2))

    fidx = np.flatnonzero(free)
    near = targets(X)  # (the closest points and normals of the current network, found once per network)
    mu, steps, history, f = PULL_MU_FIRST, 0, [], dist(X, near[0])
    kept, t_step = [f], 0.0  # (the summed squared distance after each accepted step, from the start)
    while True:
        if f <= on_reference ** 2 * fidx.size:
            stop = "on_reference"
            break
        if len(kept) > PULL_WINDOW and kept[-1] > (1 - PULL_GAIN) * kept[-1 - PULL_WINDOW]:
            stop = "converged"
            break
        if mu > PULL_MU_MAX:
            stop = "no_closer_step"
            break
        if out_of_time(deadline, t_step):
            stop = "time_limit"
            break
        if len(history) >= PULL_MAX_STEPS:
            stop = "iteration_limit"
            break
        t0 = time.perf_counter()
        d0, D = _reference_step(X, fidx, *near, mu)
        lin = _band_step(form, X, W, d0, D, loads_at=loads_at, load_jacobian=load_jacobian, deadline=deadline)
        if lin is None:  # (the deadline passed inside the step)
            stop = "time_limit"
            break
        Xn, Wn, k, err, ok = polish_joint(form(lin[0]), *lin, loads_at=loads_at, tol=STAGE_TOL,
                                          max_iter=STAGE_STEPS, load_jacobian=load_jacobian, deadline=deadline)
        steps += k
        near_n = targets(Xn) if ok else None
        fn = dist(Xn, near_n[0]) if near_n is not None else np.inf
        accept = bool(fn < f and feasible(Xn, Wn))
        rec = {"pull": len(history), "mu": mu, "steps": k, "max_rel_error": err, "distance": fn, "accepted": accept}
        history.append(rec)
        if progress is not None:
            progress(rec)
        if accept:
            X, W, f, near = Xn, Wn, fn, near_n
            kept.append(f)
            mu = max(mu / PULL_MU_DOWN, PULL_MU_MIN)
        else:
            mu *= PULL_MU_UP
        t_step = time.perf_counter() - t0
    return X, W, steps, history, stop


def _nonplanarity(X: np.ndarray, rows: Any) -> float:
    """The largest distance between a face's diagonals (the planarity rows ``rows``) at ``X``."""
    return float(np.abs(diagonal_distance(X, rows)[0]).max(initial=0.0))


def _result(problem: Problem, sc: Any, X: np.ndarray, W: np.ndarray, *, status: str, band: float, target: float,
            steps: int, t0: float, history: list, homotopy: dict[str, Any]) -> SolveResult:
    """The homotopy's result from its scaled end ``X``, ``W``: the network and the planarity
    report recomputed in SI units (a ``converged`` end that does not hold there is ``stalled``)."""
    net, cases = case_networks(problem, sc, X, list(W))
    report = planarity_report(problem, net)
    if status == "converged" and not (report["met"] and net.in_equilibrium(STAGE_TOL)):  # (recomputed in SI)
        status = "stalled"
    message = "" if status == "converged" else (
        f"the planar homotopy stopped ({status}) with every face within {band:.2e} of planar, above the "
        f"{target:.2e} it aims at (max non-planarity {report['max_nonplanarity']:.2e}, max relative error "
        f"{net.max_relative_error():.2e}{'; ' + note if (note := nonplanar_faces_note(report)) else ''}); "
        "try a quad mesh along the relative principal directions (selfsupport pq), or there another "
        "--spacing or remesher")
    return SolveResult.build(
        net, cases=cases, status=status, method="planar-homotopy", backend="joint-polish", iterations=steps,
        wall_time=time.perf_counter() - t0, history=tuple(history), message=message,
        parameters={"homotopy": {"start_nonplanarity": homotopy["start_nonplanarity"], "band": band,
                                 "target": target, "stages": len(history),
                                 "accepted": sum(r["accepted"] for r in history),
                                 "starts": homotopy["starts"], "pull": homotopy["pull"]},
                    "planarity": report, "problem": problem.describe(), "load_cases": list(problem.loads.names),
                    "scaling": asdict(sc)},
        terms=term_values(problem, net, default=DEFAULT_OBJECTIVE))


def handles(problem: Problem) -> bool:
    """Whether :func:`planar_homotopy` takes ``problem``: one load case, a free top view, no hull."""
    return len(problem.loads) == 1 and not problem.fixed_top_view and problem.hull_thickness() is None


def _planar_of(problem: Problem) -> Planar:
    """The problem's planarity constraint; :class:`InputError` where the homotopy cannot take it."""
    planar = problem.constraint(Planar)
    if planar is None:
        raise InputError("the planar homotopy needs the Planar constraint in the problem")
    if not handles(problem):
        raise InputError("the planar homotopy handles one load case, a free top view and no hull")
    return planar


def planar_homotopy(problem: Problem, warm_start: Any, *, deadline: float | None = None,
                    progress: Callable[[dict], None] | None = None, reference: PolyMesh | None = None,
                    pull: bool = True) -> SolveResult:
    """Planar faces in equilibrium from a network in equilibrium on the same mesh (module docstring).

    Parameters
    ----------
    problem
        With the :class:`~formulations.problem.Planar` constraint; one load case, a free top
        view and no hull (what the polish's band rows are written for).
    warm_start
        A network (or solve result) in equilibrium on ``problem``'s mesh, faces not yet planar.
    deadline
        ``time.perf_counter()`` value after which no stage starts and no polish step runs.
    progress
        Called with each stage's record (and each pull step's).
    reference
        The surface the pull draws the planar network toward (default: the problem's reference,
        ``problem.scene.mesh``; a remesh's reference is the network it was lifted to, so pass the
        design's own surface to stay near that).
    pull
        After a converged homotopy, move toward ``reference`` while staying in equilibrium and
        planar (:func:`_pull`): the homotopy's minimum-norm steps find *a* planar network in
        equilibrium near its start, not the one nearest the reference. Where the homotopy does
        not converge, its start is moved toward ``reference`` in equilibrium and it runs again.

    Returns
    -------
    SolveResult
        ``converged`` when the band reached :data:`BAND_END` × the tolerance with every stage in
        equilibrium, or the tolerance with the network planar to it in SI units (the planarity report and the max relative error are recomputed from the
        network); ``stalled`` when the cuts became finer than :data:`MAX_SHRINK` first, or the
        band's pace could not reach the target within :data:`MAX_STAGES` (:data:`PACE_WINDOW`);
        ``iteration_limit`` after :data:`MAX_STAGES` stages; ``time_limit``. ``parameters["homotopy"]``: start, band reached, target, stages,
        ``starts`` (2: the homotopy from the start as given did not converge and ran again from
        the start pulled toward ``reference``; each history record names its ``start``), and
        ``pull`` (``None`` without the pull; else per pull that ran, ``start`` and ``planar``, its
        steps, the accepted ones, why it ended (``stop``: ``on_reference``, ``converged``, ``no_closer_step``,
        ``time_limit`` — the planar pull gets :data:`PULL_SHARE` of the time left — or
        ``iteration_limit``; :func:`_pull`), and the
        mean distance to ``reference`` over its bounding-box diagonal before and after).
    """
    t0, planar = time.perf_counter(), _planar_of(problem)
    scene, mesh0 = problem.scene, problem.scene.mesh
    sp_ = problem.scaled()
    top, sc = sp_.top, sp_.scaling
    V, w, _ = transfer(as_warm_start(warm_start), scene)
    X = sc.pos(V)
    X[scene.supports] = sp_.X[scene.supports]
    W = np.clip(sc.weight(w[scene.active_edges]), sp_.lower, sp_.upper)[None]
    rows = coplanarity_rows(mesh0, ~np.asarray(scene.free, bool))[0]

    def loads_at(Y: np.ndarray) -> np.ndarray:
        return sc.loads_at(problem.loads, mesh0, Y)

    jac = case_load_jacobians(problem.loads.models, mesh0, sc, top.free)
    h, target = mean_edge_length(X, top.edges), BAND_END * planar.tol
    ref = mesh0 if reference is None else reference
    ref_scaled = ref.with_vertices(sc.pos(ref.vertices))  # (the polish's units)

    def form_at(Y: np.ndarray, trial: float | None, held: np.ndarray | None = None) -> ThrustNetworkProblem:
        # (trial None: no planarity rows; held: the faces held, see _Band)
        return ThrustNetworkProblem(top, Y, loads_at(Y), WeightBounds(sp_.lower, sp_.upper), weight_scale=1.0 / h ** 2,
                                    planar=None if trial is None else _Band(rows, trial, mesh0.n_vertices, held))

    def in_equilibrium(Y: np.ndarray, Wy: np.ndarray) -> bool:  # (in SI units)
        return bool(case_networks(problem, sc, Y, list(Wy))[0].in_equilibrium(STAGE_TOL))

    def planar_enough(Y: np.ndarray, Wy: np.ndarray) -> bool:  # (every face within the tolerance, in SI units)
        net, _ = case_networks(problem, sc, Y, list(Wy))
        return bool(planarity_report(problem, net)["met"] and net.in_equilibrium(STAGE_TOL))

    def pull_toward_reference(Y: np.ndarray, Wy: np.ndarray, trial: float | None,
                              feasible: Callable[[np.ndarray, np.ndarray], bool], until: float | None) -> tuple:
        before = distance_stats(sc.pos_back(Y), ref)[0]
        # (the start, faces not yet planar (trial None): by _pull_start, see there)
        pull = _pull_start if trial is None else partial(_pull, on_reference=PULL_ON_REFERENCE * planar.tol * h)
        Y, Wy, k, trail, stop = pull(
            lambda Z, held=None: form_at(Z, trial, held), Y, Wy, loads_at=loads_at, load_jacobian=jac, free=np.asarray(scene.free, bool),
            targets=lambda Z: closest_points(Z, ref_scaled)[::2], feasible=feasible, deadline=until, progress=progress)
        return Y, Wy, k, {"steps": len(trail), "accepted": sum(r["accepted"] for r in trail), "stop": stop,
                          "distance_before": before, "distance_after": distance_stats(sc.pos_back(Y), ref)[0]}

    pulled: dict[str, Any] | None = {} if pull else None
    start, steps, history = _nonplanarity(X, rows), 0, []
    X0, W0, ended = X, W, None  # (ended: the first run's end, kept where the second reaches no narrower band)
    for n_start in range(2):
        if n_start:
            # (the homotopy from the start as given did not converge: again from the network in
            # equilibrium nearest the reference, faces not yet planar, with what time is left)
            now = time.perf_counter()
            X, W, k, pulled["start"] = pull_toward_reference(
                X0, W0, None, in_equilibrium, None if deadline is None else now + PULL_START_SHARE * (deadline - now))
            steps += k
            if not pulled["start"]["accepted"]:
                X, W, band, status = ended
                break
        X, W, band, k, tried, status = _stages(form_at, X, W, loads_at=loads_at, load_jacobian=jac,
                                               band=max(_nonplanarity(X, rows), target), target=target, tol=planar.tol,
                                               planar_enough=planar_enough, deadline=deadline, progress=progress)
        steps += k
        history += [{**h, "start": n_start} for h in tried]
        if ended is not None and status != "converged" and ended[2] < band:
            # (the first run's narrower band; a second run cut by the limit still ends the call by it)
            X, W, band, status = *ended[:3], status if status == "time_limit" else ended[3]
        if status == "converged" or pulled is None or start <= target:
            break
        if out_of_time(deadline):
            status = "time_limit"  # (the second start, not tried for want of time, ends it)
            break
        ended = (X, W, band, status)
    if status == "converged" and pulled is not None:  # (the end: faces held within the band reached)
        now = time.perf_counter()
        X, W, k, pulled["planar"] = pull_toward_reference(
            X, W, band, planar_enough, None if deadline is None else now + PULL_SHARE * (deadline - now))
        steps += k
    return _result(problem, sc, X, W, status=status, band=band, target=target, steps=steps, t0=t0,
                   history=history, homotopy={"start_nonplanarity": start, "starts": n_start + 1, "pull": pulled})
