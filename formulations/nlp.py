"""The thrust-network problem stated once: unknowns, equilibrium constraints, bounds, objective.

    minimise    objective(V)
    over        X (free positions), w (active-edge weights)
    subject to  Σ_j w_ij (v_j − v_i) − (0, 0, L_i) = 0    at free vertices   (named groups
                                                          equilibrium_x/y/z)
                lower ≤ w ≤ upper

The NLP vector is ``x = [X_free.ravel(), w]``; the parameters are
``p = [V_sup.ravel(), L_free, row_scale]`` so a solver built once can be re-run with new loads
(methods re-estimate self-weight from the geometry). Constraint rows may be scaled by
``row_scale`` (default ``1 / |L_i|`` per free vertex, so the constraint tolerance *is* the paper's
relative error); the residual functions are never scaled.

Methods pick their own units; :mod:`selfsupport.methods.simultaneous` builds this in scale-free
units and wraps user terms with :class:`formulations.terms.Scaled`.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from selfsupport.errors import InputError

from .equilibrium import Equilibrium, Topology, WeightBounds, symbol_type
from .terms import Term

#: Floor of the default row scale, relative to the mean |load| (guards free vertices without load).
ROW_SCALE_FLOOR = 1e-3


@dataclass(eq=False)
class ThrustNetworkProblem:
    """One thrust-network problem (numbers in whatever units the caller chose).

    Parameters
    ----------
    topology
        Free vertices and active edges.
    vertices
        ``(n, 3)`` positions; the support rows are the (fixed) support positions, the free rows
        only serve as the default starting point.
    loads
        ``(n,)`` signed vertical loads (only the free entries enter the equations).
    bounds
        Weight bounds on the active edges.
    objective
        A :class:`~formulations.terms.Term` of all ``n`` positions, or ``None`` (feasibility).
    symbol
        ``"MX"`` (default; fast to build) or ``"SX"``.
    relative_rows
        Scale constraint rows by ``1 / |L_i|`` (see the module docstring).
    weight_regularization, weight_scale
        Adds ``weight_regularization · mean((w / weight_scale)²)`` to the objective (default 0).
        Without it the objective ignores ``w``: the optimal weights are not unique and IPOPT
        can drift towards degenerate optima with unbounded weights; a tiny value makes the
        optimum isolated at a negligible cost in the objective.
    """

    topology: Topology
    vertices: np.ndarray
    loads: np.ndarray
    bounds: WeightBounds
    objective: Term | None = None
    symbol: str | type = "MX"
    relative_rows: bool = True
    weight_regularization: float = 0.0
    weight_scale: float = 1.0

    def __post_init__(self) -> None:
        top = self.topology
        self.vertices = np.asarray(self.vertices, float)
        self.loads = np.asarray(self.loads, float)
        if self.vertices.shape != (top.n, 3):
            raise InputError(f"vertices have shape {self.vertices.shape}, expected ({top.n}, 3)")
        if self.loads.shape != (top.n,):
            raise InputError(f"loads have shape {self.loads.shape}, expected ({top.n},)")
        if self.objective is not None and self.objective.n_vertices != top.n:
            raise InputError(f"the objective is defined on {self.objective.n_vertices} vertices, "
                             f"the problem has {top.n}")
        symbol_type(self.symbol)
        self.lower, self.upper = self.bounds.arrays(top.m)

    # ---------------------------------------------------------------- symbols
    @cached_property
    def equilibrium(self) -> Equilibrium:
        return Equilibrium(self.topology, symbol=self.symbol)

    @cached_property
    def row_scale_symbol(self):
        return symbol_type(self.symbol).sym("row_scale", self.topology.n_free)

    @property
    def n_x(self) -> int:
        return 3 * self.topology.n_free + self.topology.m

    @property
    def constraint_groups(self) -> dict[str, np.ndarray]:
        """Group name -> rows of ``g`` (row ``3 k + c``: coordinate ``c`` at free vertex ``k``)."""
        return self.equilibrium.groups

    # ---------------------------------------------------------------- NLP
    def nlp(self) -> dict:
        """The NLP dict for ``ca.nlpsol``: ``x``, ``p``, ``f``, ``g``."""
        eq = self.equilibrium
        r = eq.residual()
        if self.relative_rows:
            r = r * ca.vec(ca.repmat(self.row_scale_symbol.T, 3, 1))  # s_k repeated for x, y, z
        f = self.objective.expr(eq.all_positions()) if self.objective is not None else 0 * eq.w[0]
        if self.weight_regularization:
            f = f + self.weight_regularization / max(self.topology.m, 1) * ca.sumsqr(eq.w / self.weight_scale)
        return {"x": ca.vertcat(eq.X, eq.w), "p": ca.vertcat(eq.V_sup, eq.L, self.row_scale_symbol),
                "f": f, "g": r}

    def row_scale(self, loads: np.ndarray | None = None) -> np.ndarray:
        L = np.abs((self.loads if loads is None else np.asarray(loads, float))[self.topology.free])
        if not self.relative_rows:
            return np.ones_like(L)
        floor = ROW_SCALE_FLOOR * (L.mean() if L.size and L.mean() > 0 else 1.0)
        return 1.0 / np.maximum(L, floor)

    def parameters(self, loads: np.ndarray | None = None) -> np.ndarray:
        """Numeric ``p`` for the current (or the given ``(n,)``) loads."""
        top = self.topology
        L = self.loads if loads is None else np.asarray(loads, float)
        return np.concatenate([self.vertices[~top.free].ravel(), L[top.free], self.row_scale(L)])

    def pack(self, vertices: np.ndarray | None = None, weights: np.ndarray | None = None) -> np.ndarray:
        """``x`` from ``(n, 3)`` positions and ``(m,)`` active weights (defaults: own vertices, lower bound)."""
        V = self.vertices if vertices is None else np.asarray(vertices, float)
        w = np.maximum(self.lower, 0.0) if weights is None else np.asarray(weights, float)
        return np.concatenate([V[self.topology.free].ravel(), w])

    def unpack(self, x) -> tuple[np.ndarray, np.ndarray]:
        """``(V (n, 3) with the fixed supports, w (m,))`` from an NLP vector."""
        x = np.asarray(x, float).ravel()
        top = self.topology
        V = self.vertices.copy()
        V[top.free] = x[:3 * top.n_free].reshape(-1, 3)
        return V, x[3 * top.n_free:].copy()

    def bounds_args(self) -> dict[str, np.ndarray]:
        """``lbx, ubx, lbg, ubg`` for the solver call."""
        nf3 = 3 * self.topology.n_free
        return {"lbx": np.r_[np.full(nf3, -np.inf), self.lower], "ubx": np.r_[np.full(nf3, np.inf), self.upper],
                "lbg": np.zeros(nf3), "ubg": np.zeros(nf3)}

    def solver_args(self, x0: np.ndarray, loads: np.ndarray | None = None, **extra) -> dict:
        return {"x0": x0, "p": self.parameters(loads), **self.bounds_args(), **extra}

    # ---------------------------------------------------------------- functions (unscaled)
    def residual_function(self) -> ca.Function:
        """``residual(X, w, V_sup, L) -> r`` (3 n_free, unscaled)."""
        return self.equilibrium.residual_function()

    def jacobian_functions(self) -> dict[str, ca.Function]:
        """``{"X", "w", "V_sup"}`` -> Jacobian functions of the unscaled residual."""
        return self.equilibrium.jacobian_functions()

    def objective_function(self) -> ca.Function:
        """``objective(x, p) -> f``."""
        d = self.nlp()
        return ca.Function("objective", [d["x"], d["p"]], [d["f"]], ["x", "p"], ["f"])

    def residual_at(self, vertices: np.ndarray, weights: np.ndarray, loads: np.ndarray | None = None) -> np.ndarray:
        """Numeric ``(n_free, 3)`` residual at the given positions and active weights."""
        top = self.topology
        V = np.asarray(vertices, float)
        L = self.loads if loads is None else np.asarray(loads, float)
        r = self.residual_function()(V[top.free].ravel(), weights, V[~top.free].ravel(), L[top.free])
        return np.asarray(r).reshape(-1, 3)
