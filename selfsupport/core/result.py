"""Immutable results: the thrust network and what a solve says about itself."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from selfsupport.core.evidence import (
    distance_stats,
    floor_tolerance,
    reaction_summary,
    relative_errors,
    roundoff_floors,
    roundoff_limit,
    support_reactions,
)
from selfsupport.core.mesh import PolyMesh

#: Statuses a method may report.
STATUSES = ("converged", "stalled", "infeasible", "iteration_limit", "time_limit", "interrupted", "failed")


@dataclass(frozen=True, eq=False)
class Network:
    """A thrust network: geometry, one weight per mesh edge, loads, supports.

    ``weights[k]`` belongs to ``mesh.edges[k]``; edges between two supports carry no unknown
    and have weight 0. ``loads`` are signed vertical nodal loads [N] for every vertex, ``(n,)``,
    or nodal load vectors ``(n, 3)`` where loads have horizontal components.
    """

    mesh: PolyMesh
    weights: np.ndarray
    loads: np.ndarray
    supports: np.ndarray
    reference: PolyMesh | None = None
    handles: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("weights", "loads", "supports"):
            a = np.array(getattr(self, name), dtype=bool if name == "supports" else float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def vertices(self) -> np.ndarray:
        return self.mesh.vertices

    @property
    def edges(self) -> np.ndarray:
        return self.mesh.edges

    def relative_errors(self) -> np.ndarray:
        """Per free vertex: ``‖residual‖ / |A_i F_i|`` (read-only). Computed once per network
        and kept (everything in it is immutable): a solve's finish asks for it three times."""
        r = self.__dict__.get("_relative_errors")
        if r is None:
            r = relative_errors(vertices=self.vertices, edges=self.edges, weights=self.weights,
                                loads=self.loads, supports=self.supports)
            r.setflags(write=False)
            self.__dict__["_relative_errors"] = r
        return r

    def max_relative_error(self) -> float:
        r = self.relative_errors()
        return float(r.max()) if r.size else 0.0

    def roundoff_floors(self) -> np.ndarray:
        """Per free vertex: the relative error rounding alone can leave (:func:`~.evidence.roundoff_floors`;
        read-only, computed once per network like :meth:`relative_errors`)."""
        f = self.__dict__.get("_roundoff_floors")
        if f is None:
            f = roundoff_floors(vertices=self.vertices, edges=self.edges, weights=self.weights, loads=self.loads,
                                supports=self.supports)
            f.setflags(write=False)
            self.__dict__["_roundoff_floors"] = f
        return f

    def in_equilibrium(self, tol: float) -> bool:
        """Every free vertex within ``tol`` relative error, or within
        :data:`~.evidence.FLOOR_MARGIN` × its round-off floor (below which no positions can be
        told apart from equilibrium in double precision) and :data:`~.evidence.FLOOR_CAP`."""
        rel = self.relative_errors()
        if not np.all(np.isfinite(rel)):
            return False
        over = rel > tol
        if not over.any():
            return True
        return bool(np.all(rel[over] <= floor_tolerance(self.roundoff_floors()[over])))

    def roundoff_limit(self, tol: float) -> dict | None:
        """Why the network misses ``tol`` when only rounding to doubles holds it there, else
        ``None`` (:func:`~.evidence.roundoff_limit`)."""
        return roundoff_limit(vertices=self.vertices, edges=self.edges, weights=self.weights, loads=self.loads,
                              supports=self.supports, tol=tol, rel=self.relative_errors(),
                              floors=self.roundoff_floors())

    @property
    def active_edges(self) -> np.ndarray:
        e = self.edges
        return ~(self.supports[e[:, 0]] & self.supports[e[:, 1]])

    def support_reactions(self) -> np.ndarray:
        """``(k, 3)`` force [N] the ground exerts on each support, in vertex order
        (:func:`~.evidence.support_reactions`; read-only, computed once per network)."""
        r = self.__dict__.get("_support_reactions")
        if r is None:
            r = support_reactions(vertices=self.vertices, edges=self.edges, weights=self.weights, loads=self.loads,
                                  supports=self.supports)
            r.setflags(write=False)
            self.__dict__["_support_reactions"] = r
        return r

    def reaction_summary(self) -> dict:
        """Total, vertical, largest horizontal and summed horizontal reactions [N]
        (:func:`~.evidence.reaction_summary`)."""
        return reaction_summary(self.support_reactions(), self.loads, np.flatnonzero(self.supports))

    def min_weight(self) -> float:
        w = self.weights[self.active_edges]
        return float(w.min()) if w.size else 0.0

    def distance_to_reference(self) -> tuple[float, float]:
        """Mean and max distance to the reference surface / its bounding-box diagonal."""
        if self.reference is None:
            return float("nan"), float("nan")
        return distance_stats(self.vertices, self.reference)


@dataclass(frozen=True, eq=False)
class SolveResult:
    """What a method returns. ``history`` holds one dict per outer iteration."""

    network: Network
    status: str
    method: str
    backend: str
    iterations: int
    wall_time: float
    history: tuple[dict[str, Any], ...] = ()
    message: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    max_relative_error: float = float("nan")
    min_weight: float = float("nan")
    distance_mean: float = float("nan")
    distance_max: float = float("nan")
    #: one network per load case (name, network): same geometry, the case's weights and loads;
    #: ``network`` is the first. Empty for a single-case solve.
    cases: tuple[tuple[str, Network], ...] = ()
    #: each objective term's value at the result (SI units), by name
    terms: dict[str, float] = field(default_factory=dict)

    @classmethod
    def build(cls, network: Network, *, cases: tuple[tuple[str, Network], ...] = (), **kw) -> "SolveResult":
        """Fill the evidence fields from the network itself (never from the method's bookkeeping);
        with several load cases, the max error and min weight are over all of them."""
        dm, dx = network.distance_to_reference()
        nets = [n for _, n in cases] or [network]
        return cls(network=network, max_relative_error=max(n.max_relative_error() for n in nets),
                   min_weight=min(n.min_weight() for n in nets), distance_mean=dm, distance_max=dx,
                   cases=tuple(cases) if len(cases) > 1 else (), **kw)

    @property
    def case_networks(self) -> tuple[tuple[str, Network], ...]:
        """``(name, network)`` per load case (one entry for a single-case solve)."""
        return self.cases or ((str(self.parameters.get("load_cases", ["self-weight"])[0]), self.network),)

    @property
    def converged(self) -> bool:
        return self.status == "converged"

    def tension(self) -> dict[str, Any]:
        """The edges in tension (negative weight) over every load case: ``edges``, how many are in
        tension in some case; ``min_weight``, the most negative weight [N/m] (0 without tension);
        ``edge_indices``, those edges' indices in ``mesh.edges``."""
        nets = [n for _, n in self.case_networks]
        mask = np.zeros(self.network.mesh.n_edges, dtype=bool)
        for n in nets:
            mask |= n.active_edges & (n.weights < 0)
        return {"edges": int(mask.sum()), "min_weight": min(0.0, *(n.min_weight() for n in nets)),
                "edge_indices": np.flatnonzero(mask).tolist()}

    def summary(self) -> str:
        return (f"{self.method}/{self.backend}: {self.status}, {self.iterations} it, {self.wall_time:.3f} s, "
                f"max rel. error {self.max_relative_error:.2e}, min w {self.min_weight:.3e}, "
                f"distance to reference mean {self.distance_mean:.2e} max {self.distance_max:.2e} (of bbox diagonal)")
