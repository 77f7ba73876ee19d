"""Where the horizontal self-stresses of a network's plan live, and whether they carry a point
load's difference from the network's own load case.

::

    python -m studies.plan_self_stresses NET.json --vertex 54 --point-load 354656 [--rings 8]

Every case's weights over one plan balance every free vertex in plan (``H(x, y) w = 0``,
:func:`selfsupport.methods.staggered.cases.plan_matrix`), so two cases at one geometry differ
by a self-stress ``δw`` of the plan, and their load difference must be its vertical load
``D_z δw`` (the z rows of (2)). Measured at a network (one case, in equilibrium):

* the self-stresses: an orthonormal basis ``N`` of the null space of ``H`` (singular values at
  most :data:`~selfsupport.methods.staggered.cases.SELF_STRESS_RTOL` of the largest, as
  :func:`~selfsupport.methods.staggered.cases.top_view_self_stresses` counts them);
* their reach around the loaded vertex (:func:`reach_by_ring`): per ring ``k`` of edges around it,
  the largest ``|δw_e|`` over unit self-stresses (the row norm of ``N``) over the largest anywhere,
  with and without the network's own weights (which are a self-stress: they reach every edge);
* the fixed-plan fit (:func:`fixed_plan_fit`): the least-squares ``δw`` among the self-stresses
  for the vertical difference ``P`` at the vertex, relative to the point case's load per vertex.
  A residual near the difference itself says no weights over this plan carry the point load.

* the compression test at this geometry (:func:`~selfsupport.methods.staggered.cases.least_tension`,
  a linear program): whether weights within the network's bounds (its ``eps``, ``w_max``) carry
  the point case exactly here, and if not the least total force by which they fall short of the
  lower bound (tension) over the case's total load, and on how many edges.

A residual near the whole difference at the loaded vertex, while the self-stresses reach it
(the ring table), says the plan blocks the case as a whole, not locally: too few self-stresses,
not too few near the load. A fit at round-off with tension in the compression test says the
plan has room but this geometry carries the point case only with tension: the geometry must move.
"""
from __future__ import annotations

import argparse
import json
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from formulations.equilibrium import Topology, weight_matrix
from selfsupport.core.result import Network
from selfsupport.methods.staggered import cases
from selfsupport.methods.staggered.cases import least_tension


def network_topology(net: Network) -> Topology:
    """The topology of a network's active edges (those with a free end)."""
    return Topology.build(net.mesh.n_vertices, net.edges[net.active_edges], net.supports)


def self_stress_basis(top: Topology, X: np.ndarray) -> np.ndarray:
    """An orthonormal basis ``(m, k)`` of the plan's horizontal self-stresses at ``X``
    (:func:`selfsupport.methods.staggered.cases.self_stress_basis`, by the count's route)."""
    return cases.self_stress_basis(top, X, cases.top_view_self_stresses(top, X)["self_stresses"])


def edge_rings(top: Topology, vertex: int) -> np.ndarray:
    """Per edge of ``top``, the ring it lies in around ``vertex``: the smaller of its ends'
    edge distances from it (0: the vertex's own edges; -1: not connected)."""
    adj: list[list[int]] = [[] for _ in range(top.n)]
    for i, j in top.edges:
        adj[i].append(int(j))
        adj[j].append(int(i))
    dist = np.full(top.n, -1)
    dist[vertex], queue = 0, deque([vertex])
    while queue:
        a = queue.popleft()
        for b in adj[a]:
            if dist[b] < 0:
                dist[b] = dist[a] + 1
                queue.append(b)
    d = dist[top.edges]
    return np.where((d < 0).any(axis=1), -1, d.min(axis=1))


def reach_by_ring(N: np.ndarray, rings: np.ndarray, k_max: int, without: np.ndarray | None = None) -> list[float]:
    """Per ring ``k = 0..k_max`` (:func:`edge_rings`): the largest ``|δw_e|`` over unit
    self-stresses (row norms of the basis ``N``) on the edges within ``k`` rings, over the largest
    anywhere. ``without``: a self-stress projected out first (the network's own weights)."""
    if without is not None:
        u = N.T @ without
        Q = N - np.outer(N @ u, u) / float(u @ u)
        U, s, _ = np.linalg.svd(Q, full_matrices=False)
        N = U[:, : N.shape[1] - 1]
    reach = np.linalg.norm(N, axis=1)
    top = float(reach.max(initial=0.0))
    return [float(reach[(rings >= 0) & (rings <= k)].max(initial=0.0)) / top for k in range(k_max + 1)]


def fixed_plan_fit(top: Topology, X: np.ndarray, N: np.ndarray, vertex: int, load: float,
                   loads: np.ndarray) -> dict[str, float]:
    """The least-squares self-stress ``δw = N u`` whose vertical load ``D_z δw`` is the point
    load ``load`` [N, down negative] at ``vertex`` and nothing elsewhere, each vertex's row over
    the point case's load there (``|loads + load e_vertex|``). Returns its residual at the vertex
    over the difference there, and the largest residual elsewhere over the same."""
    fi = int(top.free_index[vertex])
    Z = weight_matrix(top, X).tocsr()[np.flatnonzero(np.arange(3 * top.n_free) % 3 == 2)]
    point = np.asarray(loads, float)[top.free].copy()
    point[fi] += load
    s = 1.0 / np.abs(point)
    diff = np.zeros(top.n_free)
    diff[fi] = s[fi] * load
    B = s[:, None] * (Z @ N)
    u, *_ = np.linalg.lstsq(B, diff, rcond=None)
    r = np.abs(B @ u - diff)
    return {"at_vertex": float(r[fi] / abs(diff[fi])), "elsewhere": float(np.delete(r, fi).max(initial=0.0) / abs(diff[fi]))}


def measure(net: Network, vertex: int, load: float, rings: int, lower: float = 0.0,
            upper: float = np.inf) -> dict[str, Any]:
    """Every measurement of the module docstring at the network ``net`` (``lower``, ``upper``: its
    weight bounds [N/m], for the compression test)."""
    top = network_topology(net)
    X = net.vertices
    N = self_stress_basis(top, X)
    w = net.weights[net.active_edges]
    ring = edge_rings(top, vertex)
    return {"edges": top.m, "horizontal_equations": 2 * top.n_free, "self_stresses": int(N.shape[1]),
            "weights_off_the_space": float(np.linalg.norm(w - N @ (N.T @ w)) / np.linalg.norm(w)),
            "vertex_edges": int(np.count_nonzero(ring == 0)),
            "reach": reach_by_ring(N, ring, rings), "reach_without_weights": reach_by_ring(N, ring, rings, w),
            "fixed_plan_fit": fixed_plan_fit(top, X, N, vertex, load, net.loads),
            "compression": least_tension(top, X, _with_point(net.loads, vertex, load), lower, upper)}


def _with_point(loads: np.ndarray, vertex: int, load: float) -> np.ndarray:
    """The nodal loads with ``load`` [N, down negative] added at ``vertex``."""
    out = np.asarray(loads, float).copy()
    out[vertex] += load
    return out


def main(argv: list[str] | None = None) -> int:
    from selfsupport.io import read_network

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("network", type=Path, help="a network file (one case, in equilibrium)")
    ap.add_argument("--vertex", type=int, required=True, help="the loaded vertex")
    ap.add_argument("--point-load", type=float, required=True, help="its point load [N, downwards]")
    ap.add_argument("--rings", type=int, default=8)
    a = ap.parse_args(argv)
    params = json.loads(a.network.read_text()).get("parameters", {}) if a.network.suffix == ".json" else {}
    bounds = {"lower": params.get("eps") if params.get("eps") is not None else 0.0,
              "upper": params.get("w_max") if params.get("w_max") is not None else np.inf}
    net = read_network(a.network)
    bounds = {k: np.asarray(v, float)[net.active_edges] if np.ndim(v) else v for k, v in bounds.items()}
    print(json.dumps(measure(net, a.vertex, -abs(a.point_load), a.rings, **bounds), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
