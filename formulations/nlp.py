"""The thrust-network problem stated once: unknowns, equilibrium constraints, bounds, objective.

    minimise    objective(V)
    over        X (free positions), w_c (active-edge weights, one vector per load case c)
    subject to  Σ_j w_c,ij (v_j − v_i) − (0, 0, L_c,i) = 0   at free vertices, every case   (named
                                                               groups equilibrium_x/y/z)
                lower ≤ w_c ≤ upper
                −h ≤ ⟨n_i, v_i − p_i⟩ ≤ h                      (optional: the masonry hull, group "hull")
                x_i, y_i = their given values                   (optional: fixed top view)

The NLP vector is ``x = [X_free.ravel(), w_1, …, w_C]``; the parameters are
``p = [V_sup.ravel(), L_1,free, …, L_C,free, row_scale_1, …, row_scale_C]`` so a solver built once
can be re-run with new loads (methods re-estimate self-weight from the geometry). With one case
this is ``[X, w]`` and ``[V_sup, L_free, row_scale]``. Constraint rows are
``g = [r_1 · s_1; …; r_C · s_C; hull]``, each case's rows scaled by its own ``row_scale`` (default
``1 / |L_c,i|`` per free vertex, so the constraint tolerance *is* the paper's relative error);
the residual functions are never scaled.

A fixed top view is stated as bounds ``lbx = ubx`` on the x, y entries (IPOPT then removes them
from its unknowns: ``fixed_variable_treatment = make_parameter``), so ``x`` keeps one layout.

Methods pick their own units; :mod:`selfsupport.methods.simultaneous` builds this in scale-free
units and wraps user terms with :class:`formulations.terms.Scaled`.

Example
-------
>>> import numpy as np
>>> top = Topology.build(3, np.array([[0, 1], [1, 2]]), np.array([True, False, True]))
>>> V = np.array([[0, 0, 0], [0.5, 0, 1.0], [1, 0, 0]])
>>> P = ThrustNetworkProblem(top, V, np.array([[0, -2.0, 0], [0, -4.0, 0]]), WeightBounds(0.1))
>>> P.n_cases, P.n_x, sorted(P.constraint_groups)[:2]
(2, 7, ['equilibrium_x[0]', 'equilibrium_x[1]'])
>>> x = P.pack(V, np.array([[1.0, 1.0], [2.0, 2.0]]))
>>> [r.ravel().tolist() for r in P.residual_at(V, P.unpack(x)[1])]
[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from formulations.equilibrium import GROUP_NAMES, Equilibrium, Topology, WeightBounds, symbol_type
from formulations.terms import Term
from formulations.terms.hull import HullPenalty
from selfsupport.core.errors import InputError
from selfsupport.core.lazy import lazy_module

ca = lazy_module("casadi")  # (imported when first used: a plain staggered solve never is)

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
        ``(n,)`` signed vertical loads of one case, or ``(n_cases, n)`` (only the free entries
        enter the equations).
    bounds
        Weight bounds on the active edges (the same for every case).
    objective
        A :class:`~formulations.terms.Term` of all ``n`` positions, or ``None`` (feasibility).
    symbol
        ``"MX"`` (default; fast to build) or ``"SX"``.
    relative_rows
        Scale constraint rows by ``1 / |L_c,i|`` (see the module docstring).
    weight_regularization, weight_scale
        Adds ``weight_regularization · mean((w / weight_scale)²)`` (over every case's weights)
        to the objective (default 0). Without it the objective ignores ``w``: the optimal weights
        are not unique and IPOPT can drift towards degenerate optima with unbounded weights; a
        tiny value makes the optimum isolated at a negligible cost in the objective.
    hull
        The masonry hull as hard rows ``−h ≤ ⟨n_i, v_i − p_i⟩ ≤ h`` (``h`` its half thickness),
        group ``"hull"``; ``None``: no hull rows.
    planar
        A :class:`~formulations.terms.PlanarFaces` term whose rows are held at zero (group
        ``"planar"``, after the hull's); ``None``: no planarity rows.
    fixed_xy
        ``(n_free, 2)`` values at which x and y of the free vertices are held (fixed top view);
        ``None``: they move.
    case_names
        Names of the load cases (constraint group suffixes); default ``"0"``, ``"1"``, …
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
    hull: HullPenalty | None = None
    fixed_xy: np.ndarray | None = None
    case_names: tuple[str, ...] | None = None
    planar: Term | None = None

    def __post_init__(self) -> None:
        top = self.topology
        self.vertices = np.asarray(self.vertices, float)
        L = np.asarray(self.loads, float)
        self.loads = L[None, :] if L.ndim == 1 else L
        if self.vertices.shape != (top.n, 3):
            raise InputError(f"vertices have shape {self.vertices.shape}, expected ({top.n}, 3)")
        if self.loads.ndim != 2 or self.loads.shape[1] != top.n or self.loads.shape[0] < 1:
            raise InputError(f"loads have shape {L.shape}, expected ({top.n},) or (n_cases, {top.n})")
        if self.objective is not None and self.objective.n_vertices != top.n:
            raise InputError(f"the objective is defined on {self.objective.n_vertices} vertices, "
                             f"the problem has {top.n}")
        if self.hull is not None and self.hull.n_vertices != top.n:
            raise InputError(f"the hull is defined on {self.hull.n_vertices} vertices, the problem has {top.n}")
        if self.planar is not None and self.planar.n_vertices != top.n:
            raise InputError(f"the planarity rows are defined on {self.planar.n_vertices} vertices, the problem has {top.n}")
        if self.fixed_xy is not None:
            self.fixed_xy = np.asarray(self.fixed_xy, float)
            if self.fixed_xy.shape != (top.n_free, 2):
                raise InputError(f"fixed_xy has shape {self.fixed_xy.shape}, expected ({top.n_free}, 2)")
        if self.case_names is None:
            self.case_names = tuple(str(c) for c in range(self.n_cases))
        elif len(self.case_names) != self.n_cases:
            raise InputError(f"{len(self.case_names)} case names for {self.n_cases} load cases")
        symbol_type(self.symbol)
        self.lower, self.upper = self.bounds.arrays(top.m)

    @property
    def n_cases(self) -> int:
        return int(self.loads.shape[0])

    # ---------------------------------------------------------------- symbols
    @cached_property
    def equilibrium(self) -> Equilibrium:
        return Equilibrium(self.topology, symbol=self.symbol)

    @cached_property
    def row_scale_symbol(self):
        return symbol_type(self.symbol).sym("row_scale", self.topology.n_free)

    @cached_property
    def case_symbols(self) -> list[tuple]:
        """``(w_c, L_c, row_scale_c)`` per case; the first case uses the equilibrium's own symbols."""
        S = symbol_type(self.symbol)
        eq, top = self.equilibrium, self.topology
        out = [(eq.w, eq.L, self.row_scale_symbol)]
        for c in range(1, self.n_cases):
            out.append((S.sym(f"w_{c}", top.m), S.sym(f"L_{c}", top.n_free), S.sym(f"row_scale_{c}", top.n_free)))
        return out

    @property
    def n_x(self) -> int:
        return 3 * self.topology.n_free + self.n_cases * self.topology.m

    @cached_property
    def n_planar(self) -> int:
        """Number of planarity rows."""
        return 0 if self.planar is None else int(self.planar.linearize(self.vertices)[0].size)

    @property
    def n_g(self) -> int:
        return (3 * self.topology.n_free * self.n_cases + (0 if self.hull is None else len(self.hull.idx))
                + self.n_planar)

    @property
    def constraint_groups(self) -> dict[str, np.ndarray]:
        """Group name -> rows of ``g``. Row ``3 k + c`` of a case's block: coordinate ``c`` at free
        vertex ``k``; with several cases the names carry the case (``equilibrium_x[name]``); the
        hull rows (one per free vertex) are ``"hull"``."""
        nf = self.topology.n_free
        out: dict[str, np.ndarray] = {}
        for c, case in enumerate(self.case_names):
            for k, g in enumerate(GROUP_NAMES):
                out[g if self.n_cases == 1 else f"{g}[{case}]"] = 3 * nf * c + 3 * np.arange(nf) + k
        if self.hull is not None:
            out["hull"] = 3 * nf * self.n_cases + np.arange(len(self.hull.idx))
        if self.n_planar:
            out["planar"] = self.n_g - self.n_planar + np.arange(self.n_planar)
        return out

    def weight_slice(self, case: int) -> slice:
        """Where case ``case``'s weights sit in ``x``."""
        nf3, m = 3 * self.topology.n_free, self.topology.m
        return slice(nf3 + case * m, nf3 + (case + 1) * m)

    # ---------------------------------------------------------------- NLP
    def nlp(self) -> dict:
        """The NLP dict for ``ca.nlpsol``: ``x``, ``p``, ``f``, ``g``."""
        eq = self.equilibrium
        rows, ws = [], []
        for w, L, s in self.case_symbols:
            r = eq.residual(w=w, L=L)
            if self.relative_rows:
                r = r * ca.vec(ca.repmat(s.T, 3, 1))  # s_k repeated for x, y, z
            rows.append(r)
            ws.append(w)
        X_all = eq.all_positions()
        if self.hull is not None:
            rows.append(self.hull.signed_distance_expr(X_all))
        if self.n_planar:
            rows.append(self.planar.residual_expr(X_all))
        f = self.objective.expr(X_all) if self.objective is not None else 0 * eq.w[0]
        if self.weight_regularization:
            reg = sum(ca.sumsqr(w / self.weight_scale) for w in ws)
            f = f + self.weight_regularization / max(self.n_cases * self.topology.m, 1) * reg
        syms = self.case_symbols
        return {"x": ca.vertcat(eq.X, *ws),
                "p": ca.vertcat(eq.V_sup, *[c[1] for c in syms], *[c[2] for c in syms]),
                "f": f, "g": ca.vertcat(*rows)}

    def _loads2d(self, loads: np.ndarray | None) -> np.ndarray:
        L = self.loads if loads is None else np.asarray(loads, float)
        L = L[None, :] if L.ndim == 1 else L
        if L.shape != self.loads.shape:
            raise InputError(f"loads have shape {L.shape}, expected {self.loads.shape}")
        return L

    def row_scale(self, loads: np.ndarray | None = None) -> np.ndarray:
        """``(n_cases, n_free)`` row scales (ones without ``relative_rows``)."""
        L = np.abs(self._loads2d(loads)[:, self.topology.free])
        if not self.relative_rows:
            return np.ones_like(L)
        out = np.empty_like(L)
        for c, Lc in enumerate(L):
            floor = ROW_SCALE_FLOOR * (Lc.mean() if Lc.size and Lc.mean() > 0 else 1.0)
            out[c] = 1.0 / np.maximum(Lc, floor)
        return out

    def parameters(self, loads: np.ndarray | None = None) -> np.ndarray:
        """Numeric ``p`` for the current (or the given ``(n,)`` / ``(n_cases, n)``) loads."""
        top = self.topology
        L = self._loads2d(loads)
        return np.concatenate([self.vertices[~top.free].ravel(), L[:, top.free].ravel(), self.row_scale(L).ravel()])

    def pack(self, vertices: np.ndarray | None = None, weights: np.ndarray | None = None) -> np.ndarray:
        """``x`` from ``(n, 3)`` positions and active weights: ``(m,)`` (the same for every case)
        or ``(n_cases, m)`` (defaults: own vertices, lower bound)."""
        V = self.vertices if vertices is None else np.asarray(vertices, float)
        m = self.topology.m
        w = np.maximum(self.lower, 0.0) if weights is None else np.asarray(weights, float)
        W = np.broadcast_to(w.reshape(-1, m), (self.n_cases, m))
        return np.concatenate([V[self.topology.free].ravel(), W.ravel()])

    def unpack_cases(self, x) -> tuple[np.ndarray, np.ndarray]:
        """``(V (n, 3) with the fixed supports, W (n_cases, m))`` from an NLP vector."""
        x = np.asarray(x, float).ravel()
        top = self.topology
        V = self.vertices.copy()
        V[top.free] = x[:3 * top.n_free].reshape(-1, 3)
        return V, x[3 * top.n_free:].reshape(self.n_cases, top.m).copy()

    def unpack(self, x) -> tuple[np.ndarray, np.ndarray]:
        """``(V, w)``: like :meth:`unpack_cases`, with ``w`` of shape ``(m,)`` for a single case."""
        V, W = self.unpack_cases(x)
        return V, (W[0] if self.n_cases == 1 else W)

    def bounds_args(self) -> dict[str, np.ndarray]:
        """``lbx, ubx, lbg, ubg`` for the solver call."""
        nf = self.topology.n_free
        lo_X, up_X = np.full((nf, 3), -np.inf), np.full((nf, 3), np.inf)
        if self.fixed_xy is not None:
            lo_X[:, :2] = up_X[:, :2] = self.fixed_xy
        C = self.n_cases
        lbg, ubg = np.zeros(3 * nf * C), np.zeros(3 * nf * C)
        if self.hull is not None:
            h = np.full(len(self.hull.idx), self.hull.half_thickness)
            lbg, ubg = np.r_[lbg, -h], np.r_[ubg, h]
        lbg, ubg = np.r_[lbg, np.zeros(self.n_planar)], np.r_[ubg, np.zeros(self.n_planar)]
        return {"lbx": np.r_[lo_X.ravel(), np.tile(self.lower, C)], "ubx": np.r_[up_X.ravel(), np.tile(self.upper, C)],
                "lbg": lbg, "ubg": ubg}

    def solver_args(self, x0: np.ndarray, loads: np.ndarray | None = None, **extra) -> dict:
        return {"x0": x0, "p": self.parameters(loads), **self.bounds_args(), **extra}

    # ---------------------------------------------------------------- functions (unscaled)
    def residual_function(self) -> ca.Function:
        """``residual(X, w, V_sup, L) -> r`` (3 n_free, unscaled; one case)."""
        return self.equilibrium.residual_function()

    def jacobian_functions(self) -> dict[str, ca.Function]:
        """``{"X", "w", "V_sup"}`` -> Jacobian functions of the unscaled residual (one case)."""
        return self.equilibrium.jacobian_functions()

    def objective_function(self) -> ca.Function:
        """``objective(x, p) -> f``."""
        d = self.nlp()
        return ca.Function("objective", [d["x"], d["p"]], [d["f"]], ["x", "p"], ["f"])

    def residual_at(self, vertices: np.ndarray, weights: np.ndarray, loads: np.ndarray | None = None) -> np.ndarray:
        """Numeric residual at the given positions: ``(n_free, 3)`` for ``(m,)`` weights and one
        case; ``(n_cases, n_free, 3)`` for ``(n_cases, m)`` weights."""
        top = self.topology
        V = np.asarray(vertices, float)
        L = self._loads2d(loads)
        W = np.asarray(weights, float)
        F = self.residual_function()
        out = np.stack([np.asarray(F(V[top.free].ravel(), w, V[~top.free].ravel(), Lc[top.free])).reshape(-1, 3)
                        for w, Lc in zip(W.reshape(-1, top.m), L)])
        return out[0] if W.ndim == 1 else out
