"""The weights refit to a network's stored positions: what rounding the positions leaves.

A polish solves the positions for fixed weights, and storing them as doubles moves each vertex
by up to ``eps |v|``. Where an edge force is many times a vertex's load (a free boundary arch of
a fine mesh: 10⁵ times) that alone leaves a relative error of ``eps |v| w / |A_i F_i|``, the
round-off floor of :func:`~selfsupport.core.evidence.roundoff_floors` (2e-8 on a 256k pillar vault).
The weights need no such precision: a force ``w ℓ`` stored as a double is off by ``eps w ℓ``, which
is ``eps`` times the force ratio (2e-11 there). So the weights are moved, by the least relative
change, to fit the positions as stored:

    min Σ_e (δw_e / w_e)²   s.t.   A(V) (w + δw) = b      (rows weighted by each vertex's allowance)

``A(V)`` the equilibrium matrix at the stored positions (:func:`formulations.equilibrium.weight_matrix`),
solved through the vertex-sized normal equations ``B Bᵀ y = −r`` (``B = S A W``, ``W = diag |w|``,
``S`` the rows over ``|A_i F_i|`` times the vertex's allowed error: ``tol``, or its floor
tolerance where that is larger, so what cannot be absorbed is spread in proportion to what each
vertex may keep). A zero weight stays zero and a weight at a bound stays there; the changes are
of the size of the rounding (at most 2e-7 of a weight on that vault), so signs are kept.

What no weights absorb is the residual's part along the framework's flexes (the left null space
of ``A``): a vertex whose edges nearly lie in one plane cannot be balanced across it by weights.
Where the strip beside a free edge is squashed in plan that is most of it (the same vault before
its prolongation stopped squashing: 8.8e-8 → 6.5e-8 only; unsquashed: 2.1e-8 → 8.4e-9).

Example
-------
A dome solved at the origin, then written 10⁸ m away (site coordinates: a spacing of doubles
of 1.5e-8 m there), is out of equilibrium by its positions' rounding alone; its weights, refit
to those positions, balance it to round-off again, moved by less than 1e-6 of themselves:

>>> from selfsupport.core.shapes import make_shape
>>> from selfsupport.methods.staggered import StaggeredLinearization
>>> res = StaggeredLinearization().solve(make_shape("dome", n_vertices=150))
>>> far = dataclasses.replace(res.network, mesh=res.network.mesh.with_vertices(res.network.vertices + [1e8, 0, 0]))
>>> far.max_relative_error() > 1e-8
True
>>> fit = refit_weights(far, 1e-9, lower=res.parameters["eps"])
>>> fit.max_relative_error() < 1e-12
True
>>> a = far.active_edges
>>> bool(np.abs(fit.weights[a] / far.weights[a] - 1).max() < 1e-6 and fit.min_weight() >= res.parameters["eps"])
True
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from formulations import Problem, ScaledProblem
from formulations.equilibrium import Topology, load_vector, weight_matrix
from selfsupport.core.evidence import floor_tolerance, load_magnitudes
from selfsupport.core.linalg import spd_factor
from selfsupport.core.result import Network

__all__ = ["refit_weights", "edge_bounds", "MAX_CHANGE"]

#: A refit that needs a larger relative change of any weight is not removing rounding, and is not
#: applied (rounding needs far less, even 10⁶ m from the origin).
MAX_CHANGE = 0.01
#: Tikhonov shift of the normal equations, relative to their largest diagonal entry: ``B Bᵀ`` is
#: singular along the flexes, whose part of the residual the refit leaves (``Bᵀ`` maps them to 0).
SHIFT = 1e-15
#: Most refits with weights held at the bounds they would pass (each one factorization).
BOUND_ROUNDS = 4


def refit_weights(network: Network, tol: float, *, lower: np.ndarray | float = 0.0,
                  upper: np.ndarray | float = np.inf, rounds: int = 2) -> Network | None:
    """``network`` with its weights refit to its stored positions (see the module docstring),
    when that puts it in equilibrium (:meth:`Network.in_equilibrium` at ``tol``); else ``None``.
    ``lower``/``upper``: the weight bounds per mesh edge (or one value), which hold: a weight the
    refit would push past its bound is held there and the refit solved again (at most
    :data:`BOUND_ROUNDS` times); ``rounds``: solves with each factorization."""
    top = Topology.build(network.mesh.n_vertices, network.edges, network.supports)
    V, w0 = network.vertices, np.asarray(network.weights, float)
    lo = np.broadcast_to(np.asarray(lower, float), w0.shape)
    up = np.broadcast_to(np.asarray(upper, float), w0.shape)
    L = np.asarray(network.loads, float)
    allow = np.maximum(tol, floor_tolerance(network.roundoff_floors()))
    rows = np.repeat(1.0 / np.maximum(load_magnitudes(L)[top.free] * allow, 1e-300), 3)
    A = weight_matrix(top, V)
    SA = (sp.diags(rows) @ A).tocsc()
    b = load_vector(top, L)
    # held: an edge that carries nothing, and a weight at a bound (let move, many would cross it)
    held = (w0 == 0.0) | (w0 <= lo * (1 + 1e-12)) | (w0 >= up * (1 - 1e-12))
    for _ in range(BOUND_ROUNDS):
        w = _refit(SA, A, b, rows, w0, np.where(held, 0.0, np.abs(w0)), rounds)
        if w is None:
            return None
        past = (w < lo) | (w > up)
        if not past.any():
            break
        held |= past
    if np.max(np.abs(w - w0) / np.maximum(np.abs(w0), 1e-300)) > MAX_CHANGE:
        return None
    # (past BOUND_ROUNDS a few may be past their bounds, by ~1e-7 of themselves; held ones are w0)
    out = dataclasses.replace(network, weights=np.where(held, w0, np.clip(w, lo, up)))
    return out if out.in_equilibrium(tol) else None


def _refit(SA: sp.csc_matrix, A: sp.csc_matrix, b: np.ndarray, rows: np.ndarray, w0: np.ndarray,
           scale: np.ndarray, rounds: int) -> np.ndarray | None:
    """The least change ``scale · Bᵀ y`` of ``w0`` with ``B = S A diag(scale)``: ``rounds`` solves
    with one factorization of ``B Bᵀ`` (``None`` when nothing may move or it is not finite)."""
    B = (SA @ sp.diags(scale)).tocsr()
    M = (B @ B.T).tocsc()
    if M.shape[0] == 0 or not np.any(scale):
        return None
    factor = spd_factor(M + SHIFT * float(M.diagonal().max()) * sp.identity(M.shape[0], format="csc"))
    w = w0.copy()
    for _ in range(rounds):
        w = w + scale * (B.T @ factor.solve(-rows * (A @ w - b)))
    return w if np.all(np.isfinite(w)) else None


def edge_bounds(problem: Problem, scaled: ScaledProblem | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The problem's weight bounds [N/m] per mesh edge, for :func:`refit_weights` (0 and 0 on the
    edges it leaves out: those carry nothing and stay so); ``scaled``: ``problem.scaled()`` when
    the caller has it."""
    sp_ = problem.scaled() if scaled is None else scaled
    n_edges = problem.scene.mesh.n_edges
    lo, up = np.zeros(n_edges), np.zeros(n_edges)
    active = problem.scene.active_edges
    lo[active] = sp_.scaling.weight_back(np.asarray(sp_.lower, float))
    up[active] = sp_.scaling.weight_back(np.asarray(sp_.upper, float))
    return lo, up
