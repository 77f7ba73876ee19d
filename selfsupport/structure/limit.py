"""Limit analysis as one nonlinear program: the largest load factor, feasibility at a given load,
the smallest thickness, the largest horizontal acceleration and the range of the thrust, each
answered with a certificate (paper §4; Heyman's safe theorem).

    maximise    λ                          (:func:`limit_load`; :func:`max_horizontal`: λ in g)
                − t                        (:func:`min_thickness`; h = t/2 an unknown)
                − distance to reference    (:func:`feasible`; λ and t fixed)
                ∓ Σ_s ‖R_s,h‖              (:func:`thrust_range`; λ = 0: the supports' horizontal reactions)
    over        offsets s_i, active weights w (one vector), λ [kg] (, h)
    where       v_i = p_i + s_i n_i         (p_i the reference vertex, n_i its normal)
    subject to  Σ_j w_ij (v_j − v_i) = (0, 0, L_i) + λ H_i,   L = L_ref + λ P   (eqs. 2-3)
                eps ≤ w ≤ w_max,   |s_i| ≤ (1 − HULL_MARGIN) h,   λ ≥ 0

The equilibrium rows (relative to |L_i|) and the objective are those of
:class:`formulations.nlp.ThrustNetworkProblem`, built by :meth:`Simultaneous.formulation
<selfsupport.methods.simultaneous.Simultaneous.formulation>` in its scale-free units; the
program only substitutes its unknowns into them: the positions by the offsets, the load
parameter by ``L_ref + λ P`` (``P``: the added load per kg, spread over the loaded vertices).
For a horizontal acceleration ``P = 0`` and ``H_i = W_i (d_x, d_y, 0)``, W_i the vertex's weight
and d the plan direction, is subtracted from the rows in their relative scale (elsewhere H = 0).

The hull: each free vertex moves on the line of the hull's slab at its reference vertex
(:class:`formulations.terms.HullPenalty`: anchor ``p_i``, normal ``n_i``), so its distance to the
reference surface is at most ``|v_i − p_i| = |s_i|`` and the bound on ``s`` holds the true hull,
not a linearization of it: no re-anchoring, and the certificate needs no tolerance. (A vertex
free to slide along its slab leaves the curved hull by the curvature times the slide squared;
maximising λ drove vertices to slide as far as allowed, round after round.) With
``slide_supports`` the supports move on their normals too: the thrust may meet the ground
anywhere across the springing's thickness.

Sliding (``limit_load(slide=True)``, opt-in): after that program, rounds in which each vertex
also moves in the tangent plane at its anchor, ``v_i = p_i + s_i n_i + T_i u_i``, the anchor the
closest point of the last certificate's vertex on the reference. The hull rows are
``|s_i| + σ_i (a_i1 + a_i2) <= h``, ``|u_ik| <= a_ik <= r_i`` (linear; ``|u| <= a_1 + a_2``): the
reference is faceted, so it leaves the tangent plane linearly (slope σ_i of its triangles about
the anchor), which bounds the true distance (:func:`_slide_frames`); a curvature allowance
``κ |u|² / 2`` does not (a vertex sliding across a faceted apex left the hull by 9% of t/2), and
the smooth ``σ sqrt(|u|² + δ²)`` stalled IPOPT (3000 iterations on dome2). A round's loads are
the masonry's weight shared among the anchors (the self-weight of the mesh at the anchors,
scaled to the reference's total), so a vertex that slid carries the masonry around where it
now is, not the patch it left. Each round is certified as the program is (the certificate never
depends on the bound) and warm-started from the last λ and weights; the answer is the best
certified round.

Loads: held at the reference geometry, ``L_ref`` = the self-weight (and the scene's extras) of
the reference — the weight of the masonry where the masonry is, which does not move when the
thrust surface does. Re-estimating them from the network (an outer fixed point, as the
simultaneous method does for design) was tried: with vertices sliding, the load change
oscillated at 30-40% per round and never settled. The certificate therefore carries the
reference's loads (plus λ P), and its JSON records them, so the independent checker checks
equilibrium against exactly the loads the vault has.

Certificate: after IPOPT, λ is held and the network polished to round-off
(:func:`~selfsupport.methods.polish.polish_joint`). It counts only when, measured outside the
solver, its max relative error is at most :data:`CERTIFY_TOL` (:meth:`Network.max_relative_error`),
every weight is >= 0 and every free vertex lies within t/2 of the reference surface (libigl
closest points, :func:`~selfsupport.methods.base.hull_excess`). If the optimum's network fails
that, λ is backed off (:data:`BACK_OFF`) and the feasibility program solved there. "Does not
stand" is said as *locally infeasible* only when IPOPT reported ``Infeasible_Problem_Detected``;
otherwise the verdict says what was tried and how it ended.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from formulations import Problem
from formulations.equilibrium import to_dm
from formulations.problem import Hull
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import closest_points, load_vectors
from selfsupport.core.loads import G, PointLoad, plan_direction, spread_mass
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.problem import problem as stated_problem
from selfsupport.methods.base import case_networks, hull_excess, hull_signed_distance
from selfsupport.methods.hull_search import solve_in_hull
from selfsupport.methods.polish import polish_joint
from selfsupport.methods.simultaneous import IPOPT_STATUS, Simultaneous
from selfsupport.methods.weight_refit import edge_bounds, refit_weights

__all__ = ["LimitResult", "limit_load", "feasible", "min_thickness", "max_horizontal", "thrust_range", "CERTIFY_TOL",
           "HULL_MARGIN"]

#: Max relative equilibrium error of a certifying network (the paper's Table 1 metric).
CERTIFY_TOL = 1e-8
#: The program's slabs are this fraction thinner than t/2: the slack covers the curvature the
#: tangent slabs leave out, so the certificate holds by the true distance without a tolerance.
HULL_MARGIN = 1e-4
#: At most this many IPOPT runs of one program (a run that ends "acceptable" is re-solved warm).
MAX_ROUNDS = 5
#: IPOPT options of a second try when a run ends at its iteration limit: the adaptive barrier's
#: default oracle can drive μ to its floor while the iterate is still far from feasible and then
#: crawl; the probing oracle steers μ from the affine step instead.
RETRY_OPTIONS = {"mu_oracle": "probing"}
#: Relative back-offs of λ (or of 1/t) tried, in turn, when the optimum's network is not a certificate.
BACK_OFF = (1e-3, 1e-2, 5e-2)
#: The relative error to which the weights of a network under horizontal loads are refit at its
#: positions (the joint polish balances vertical loads only); well below :data:`CERTIFY_TOL`.
REFIT_TOL = 1e-11
#: Sliding (``limit_load(slide=True)``): each vertex's tangential trust region per round, a
#: fraction of the shortest reference edge at its nearest reference vertex (|u|_∞ ≤ r).
SLIDE_RADIUS = 0.2
#: Sliding: at most this many sliding rounds after the normal-line program, ...
SLIDE_ROUNDS = 4
#: ... stopping when a round raises the certified λ by less than this fraction.
SLIDE_GAIN = 0.005
#: IPOPT statuses that mean "no point found": the program is locally infeasible.
LOCALLY_INFEASIBLE = frozenset({"Infeasible_Problem_Detected"})


@dataclass(frozen=True)
class LimitResult:
    """The answer of one limit-analysis program.

    Attributes
    ----------
    kind
        ``"max_load"``, ``"feasibility"``, ``"min_thickness"``, ``"max_horizontal"``,
        ``"min_thrust"`` or ``"max_thrust"``.
    value
        The certified value: the added mass [kg] (max load, feasibility), the thickness [m]
        (min thickness), the acceleration [g] (max horizontal) or the certificate's thrust [N];
        ``None`` when nothing was certified.
    optimum
        The program's own optimum before the certificate (λ [kg], t [m], a [g] or the thrust
        [N]); ``None`` if IPOPT found no point.
    certified
        A network inside the hull, in equilibrium and compressive, was found (``certificate``).
    certificate
        That network (or, uncertified, the last one found, for diagnosis).
    verdict
        ``"certified"``, ``"locally infeasible"`` (IPOPT said so) or ``"not certified"``.
    ipopt_status
        IPOPT's return status in the last round.
    message
        One line: what was found, or what was tried and how it ended.
    rounds
        One record per IPOPT round and per polish / back-off.
    binding
        ``(vertex, d / (t/2))`` for the free vertices of the certificate (else of the last
        network) on the hull's faces (|d| within 1% of t/2), worst first.
    thickness
        The hull's thickness [m] of the certificate (for min thickness: the certified one).
    active
        The bounds active at the program's optimum (max load, max horizontal) with IPOPT's
        multipliers (:func:`_active`): ``hull`` ``(vertex, side, multiplier)`` and
        ``weight_lower`` / ``weight_upper`` ``(edge, multiplier)``, largest multiplier first.
    slide
        With sliding (:func:`limit_load` ``slide=True``): one record per round (round 0 the
        normal-line program, then the sliding rounds): its certified λ [kg] (``None``: none), the
        program's optimum, seconds, the binding vertices and how far the anchors have moved
        along the reference [m].
    """

    kind: str
    value: float | None
    optimum: float | None
    certified: bool
    certificate: SolveResult | None
    verdict: str
    ipopt_status: str
    message: str
    rounds: tuple[dict, ...] = ()
    binding: tuple[tuple[int, float], ...] = ()
    thickness: float | None = None
    active: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    slide: tuple[dict, ...] = ()


# ------------------------------------------------------------------------------ the program
class _Program:
    """The limit NLP of one problem in the scale-free units of the simultaneous method.

    ``horizontal`` (a unit plan vector): λ scales a horizontal load instead, λ g the acceleration
    of the vault's weight in that direction (λ in g). The thrust modes hold λ at 0 and minimise
    or maximise the thrust: the sum of the supports' horizontal reaction magnitudes."""

    def __init__(self, problem: Problem, start: np.ndarray, pattern: np.ndarray, mode: str,
                 slide_supports: bool = False, horizontal: np.ndarray | None = None,
                 anchor_at: np.ndarray | None = None) -> None:

        self.problem, self.mode, self.slide_supports = problem, mode, slide_supports
        form, sc = Simultaneous.formulation(problem, start)
        hull = form.hull  # the slabs at the reference vertices: their anchors and normals are the lines
        self.slide = anchor_at is not None
        if self.slide:  # sliding: anchored at the closest points of ``anchor_at`` [m] on the reference
            ref, hull = hull, hull.at(sc.pos(anchor_at))
        # (λ or t is the objective of the other two; feasibility keeps the distance to the reference)
        form = dataclasses.replace(form, hull=None, objective=form.objective if mode == "feasibility" else None)
        self.form, self.sc, self.hull = form, sc, hull
        top = form.topology
        self.free, self.nf, self.ns3 = top.free, top.n_free, 3 * (top.n - top.n_free)
        self.mesh0 = problem.scene.mesh
        # the vertices that move along their normals: the free ones (and the supports, sliding)
        self.move = self.free | slide_supports
        self.order = np.r_[np.flatnonzero(self.free), np.flatnonzero(~self.free)][:int(self.move.sum())]
        self.anchor, self.normal = hull.points[self.order], hull.normals[self.order]
        if self.slide:
            self.tangent, self.slope, self.radius = _slide_frames(ref, self.mesh0, self.anchor, self.normal)
        # the masonry's weight where the masonry is: the loads of the reference geometry, held
        self.base = sc.loads_at(problem.loads, self.mesh0, sc.pos(self.mesh0.vertices))[0]
        if self.slide:  # sliding: the masonry's weight shared by the anchors' tributaries, its total held
            moved = sc.loads_at(problem.loads, self.mesh0, hull.points)[0]
            self.base = moved * (self.base.sum() / moved.sum())
        # λ in units of the vault's own (free) weight, so that λ̂ is of order one (an acceleration: in g)
        self.horizontal = horizontal is not None
        self.lam_unit = 1.0 if self.horizontal else float(np.abs(sc.load_back(self.base[self.free])).sum() / G)
        self.P = sc.load(pattern) * self.lam_unit  # scaled load of λ̂ = 1
        # the horizontal load of λ̂ = 1: each vertex's weight (its downward load) along the direction
        self.H = np.zeros((len(self.base), 3))
        if self.horizontal:
            self.H[:, :2] = np.maximum(-self.base, 0.0)[:, None] * np.asarray(horizontal, float)[None, :2]
        self.h = hull.half_thickness
        self._build()

    def positions(self, s, part: slice = slice(None), u=None):
        """Positions (flattened, ``3 k + c``) of the moving vertices ``order[part]`` at offsets
        ``s`` along their normals (CasADi or numpy); sliding, plus ``T u`` in the tangent planes
        (``u`` ``(k, 2)`` in numpy, or the pair of CasADi columns ``(u1, u2)``)."""
        a, n = self.anchor[part], self.normal[part]
        if isinstance(s, np.ndarray):
            X = a + s[:, None] * n
            if u is not None:
                X = X + np.einsum("kc,kcj->kj", u, self.tangent[part])
            return X.ravel()
        X = ca.DM(a.T) + ca.DM(n.T) * ca.repmat(s.T, 3, 1)
        if u is not None:
            T = self.tangent[part]
            X = X + ca.DM(T[:, 0].T) * ca.repmat(u[0].T, 3, 1) + ca.DM(T[:, 1].T) * ca.repmat(u[1].T, 3, 1)
        return ca.vec(X)

    def tangential(self, Vs: np.ndarray) -> np.ndarray:
        """Sliding: the tangential coordinates ``(nm, 2)`` of scaled positions about the anchors."""
        return np.einsum("kcj,kj->kc", self.tangent, Vs[self.order] - self.anchor)

    def _build(self) -> None:
        form = self.form
        d = form.nlp()  # (equilibrium rows, relative, and the objective: formulations' statement)
        rows = ca.Function("rows", [d["x"], d["p"]], [d["g"], d["f"]])
        nf, ns3, m = self.nf, self.ns3, form.topology.m
        nm = len(self.order)
        s, w, lam = ca.MX.sym("s", nm), ca.MX.sym("w", m), ca.MX.sym("lam")
        u = (ca.MX.sym("u1", nm), ca.MX.sym("u2", nm)) if self.slide else None
        p = ca.MX.sym("p", ns3 + 6 * nf)  # V_sup, L_sw (free), row scale, P (free), H (free, x y z)
        loads = p[ns3:ns3 + nf] + lam * p[ns3 + 2 * nf:ns3 + 3 * nf]
        us, uf = (None, None) if u is None else ((u[0][nf:], u[1][nf:]), (u[0][:nf], u[1][:nf]))
        sup = self.positions(s[nf:], slice(nf, None), us) if self.slide_supports else p[:ns3]
        X = self.positions(s[:nf], slice(0, nf), uf)
        scale = p[ns3 + nf:ns3 + 2 * nf]
        g, f = rows(ca.vertcat(X, w), ca.vertcat(sup, loads, scale))
        if self.horizontal:  # the rows are relative residuals: the horizontal load scaled as the vertical one
            g = g - lam * p[ns3 + 3 * nf:] * ca.vec(ca.repmat(scale.T, 3, 1))
        xs = ca.vertcat(s, w, lam)
        if self.mode == "min_thickness":
            h = ca.MX.sym("h")
            xs = ca.vertcat(xs, h)
            g = ca.vertcat(g, s - h, s + h)
            f = f + h
        elif self.mode in ("max_load", "max_horizontal"):
            f = f - lam
        elif self.mode in ("min_thrust", "max_thrust"):
            f = f + (1.0 if self.mode == "min_thrust" else -1.0) * self.thrust_expr(X, w, sup)
        if self.slide:  # the faceted reference's hull, linear: |s| + σ (a1 + a2) <= h, |u_k| <= a_k (|u| <= a1 + a2)
            a1, a2 = ca.MX.sym("a1", nm), ca.MX.sym("a2", nm)
            bend = ca.DM(self.slope) * (a1 + a2)
            xs = ca.vertcat(xs, u[0], u[1], a1, a2)
            g = ca.vertcat(g, s + bend, bend - s, u[0] - a1, -u[0] - a1, u[1] - a2, -u[1] - a2)
        self.nlp = {"x": xs, "p": p, "f": f, "g": g}

    def thrust_expr(self, X, w, sup):
        """The thrust Σ_s ‖R_s,h‖ over the supports (smoothed at 0 by 1e-9 of the load unit), in
        units of the vault's free weight: ``R_s = Σ_j w_sj (v_j − v_s) − L_s``, its x and y."""
        M = self.form.equilibrium._matrices  # (the constant matrices of eqs. 2-3, stated once there)
        d = ca.mtimes(to_dm(M["Df"]), X) + ca.mtimes(to_dm(M["Ds"]), sup)
        force = ca.mtimes(to_dm(M["R"]), w) * d
        Rh = ca.mtimes(to_dm(self.support_assembly()), force)  # (2 n_sup): x, y per support (no horizontal loads)
        unit = float(np.abs(self.base[self.free]).sum())
        sq = Rh[0::2] ** 2 + Rh[1::2] ** 2
        return ca.sum1(ca.sqrt(sq + (1e-9 * unit) ** 2)) / unit

    def support_assembly(self) -> sp.csc_matrix:
        """``(2 n_sup, 3 m)``: x and y of each support's sum of edge forces ``w_k (v_j − v_i)``
        (+ at an edge's first end, − at its second), supports in vertex order."""
        top = self.form.topology
        e = top.edges
        sup_index = -np.ones(top.n, dtype=np.int64)
        sup_index[~top.free] = np.arange(int((~top.free).sum()))
        rows, cols, vals = [], [], []
        for end, sign in ((0, 1.0), (1, -1.0)):
            k = np.flatnonzero(sup_index[e[:, end]] >= 0)
            for c in range(2):
                rows.append(2 * sup_index[e[k, end]] + c)
                cols.append(3 * k + c)
                vals.append(np.full(len(k), sign))
        return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(2 * int((~top.free).sum()), 3 * top.m))

    def bounds(self, lam: tuple[float, float], h: float) -> dict[str, np.ndarray]:
        """Bounds: |s| <= ``h`` (the hull), the weights', λ's (and, for min thickness, h >= 0)."""
        b = self.form.bounds_args()
        nm, n3 = len(self.order), 3 * self.nf
        if self.mode == "min_thickness":
            lbx = np.r_[np.full(nm, -np.inf), b["lbx"][n3:], lam[0], 0.0]
            ubx = np.r_[np.full(nm, np.inf), b["ubx"][n3:], lam[1], np.inf]
            lbg = np.r_[np.zeros(n3), np.full(nm, -np.inf), np.zeros(nm)]
            ubg = np.r_[np.zeros(n3), np.zeros(nm), np.full(nm, np.inf)]
        else:
            lbx, ubx = np.r_[np.full(nm, -h), b["lbx"][n3:], lam[0]], np.r_[np.full(nm, h), b["ubx"][n3:], lam[1]]
            lbg, ubg = np.zeros(n3), np.zeros(n3)
        if self.slide:  # the trust region |u|_∞ <= r and the faceted hull's rows
            r = np.r_[self.radius, self.radius]
            lbx, ubx = np.r_[lbx, -r, np.zeros(2 * nm)], np.r_[ubx, r, r]
            lbg, ubg = np.r_[lbg, np.full(6 * nm, -np.inf)], np.r_[ubg, np.full(2 * nm, h), np.zeros(4 * nm)]
        return {"lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}

    def parameters(self, lam: float) -> np.ndarray:
        form, free = self.form, self.free
        return np.r_[form.vertices[~free].ravel(), self.base[free], form.row_scale(self.base + lam * self.P).ravel(),
                     self.P[free], self.H[free].ravel()]

    def offsets(self, Vs: np.ndarray) -> np.ndarray:
        """Offsets along the normals of scaled positions (their projections onto the lines)."""
        return np.einsum("ij,ij->i", self.normal, Vs[self.order] - self.anchor)

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float | None]:
        nm, m = len(self.order), self.form.topology.m
        s = x[:nm]
        u = np.c_[x[-4 * nm:-3 * nm], x[-3 * nm:-2 * nm]] if self.slide else None
        Vs = self.form.vertices.copy()
        Vs[self.order] = self.positions(s, u=u).reshape(-1, 3)
        h = float(x[nm + m + 1]) if self.mode == "min_thickness" else None
        return s, Vs, x[nm:nm + m], float(x[nm + m]), h

    def pack(self, s: np.ndarray, w: np.ndarray, lam: float, h: float | None, Vs: np.ndarray | None = None
             ) -> np.ndarray:
        """The unknowns' vector; sliding, the tangential offsets are those of ``Vs`` in the trust region."""
        x = np.r_[s, w, lam]
        if self.slide:
            u = np.clip(self.tangential(Vs), -self.radius[:, None], self.radius[:, None])
            return np.r_[x, u[:, 0], u[:, 1], np.abs(u[:, 0]), np.abs(u[:, 1])]
        return np.r_[x, h] if self.mode == "min_thickness" else x


def _slide_frames(ref: Any, mesh: Any, anchor: np.ndarray, normal: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sliding, per anchor ``a`` (on the reference, unit normal ``n``): an orthonormal tangent frame
    ``(k, 2, 3)`` ⊥ n, the slope σ and the trust radius r (scaled units, as ``ref``: the reference's
    hull term).

    The reference is faceted (the hull's distance is to its triangles), so within its reach it
    departs from the tangent plane at ``a`` linearly, not by curvature × slide² (a vertex sliding
    across the apex of a faceted dome left the hull by 9% of t/2 under a curvature bound): the
    triangles there are a graph over the plane, through ``a``, with heights ``|z(u)| <= σ |u|``,
    σ the largest tan(angle between n and a triangle's normal). So
    ``dist(a + s n + T u) <= |s − z(u)| <= |s| + σ |u|``. The reach: the triangles at the closed
    one-ring of ``a``'s nearest reference vertex; r = :data:`SLIDE_RADIUS` × that vertex's
    shortest edge, and at most half the anchor's distance to the reference's boundary over √2
    (beyond the boundary the reference is no graph). An anchor whose triangles tilt by 60° or
    more does not slide (r = 0)."""
    P = ref.points
    E, F = np.asarray(mesh.edges), np.asarray(mesh.triangle_corners)
    n_v = len(P)
    ell = np.linalg.norm(P[E[:, 1]] - P[E[:, 0]], axis=1)
    lv = np.full(n_v, np.inf)
    for c in range(2):
        np.minimum.at(lv, E[:, c], ell)
    nt = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    nt /= np.maximum(np.linalg.norm(nt, axis=1, keepdims=True), 1e-300)
    inc = sp.csr_matrix((np.ones(F.size), (F.ravel(), np.repeat(np.arange(len(F)), 3))), shape=(n_v, len(F)))
    adj = sp.csr_matrix((np.ones(2 * len(E)), (E.ravel(), E[:, ::-1].ravel())), shape=(n_v, n_v))
    reach = ((adj + sp.identity(n_v, format="csr")) @ inc).tocsr()
    near = cKDTree(P).query(anchor)[1]
    slope, radius = np.zeros(len(anchor)), SLIDE_RADIUS * lv[near]
    B = E[np.asarray(mesh.boundary_edge_mask)]
    if len(B):  # the distance of each anchor to the boundary's segments (in blocks: anchors × segments)
        A0, D = P[B[:, 0]], P[B[:, 1]] - P[B[:, 0]]
        DD = np.maximum(np.einsum("bj,bj->b", D, D), 1e-300)
        gap = np.empty(len(anchor))
        step = max(1, 2 ** 20 // len(B))
        for k in range(0, len(anchor), step):
            rel = anchor[k:k + step, None, :] - A0[None]
            f = np.clip(np.einsum("kbj,bj->kb", rel, D) / DD, 0.0, 1.0)
            gap[k:k + step] = np.linalg.norm(rel - f[..., None] * D[None], axis=2).min(axis=1)
        radius = np.minimum(radius, 0.5 * gap / np.sqrt(2.0))
    for i, v in enumerate(near):
        c = np.abs(nt[reach.indices[reach.indptr[v]:reach.indptr[v + 1]]] @ normal[i])
        cmin = float(c.min(initial=1.0))
        if cmin <= 0.5:
            radius[i] = 0.0
        else:
            slope[i] = np.sqrt(max(1.0 - cmin ** 2, 0.0)) / cmin
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normal, t1)
    return np.stack([t1, t2], axis=1), slope, radius


def _ipopt(prog: _Program, x0: np.ndarray, p: np.ndarray, bounds: dict, warm: dict | None, *, tol: float,
           max_iter: int, remaining: float, extra: Mapping[str, Any] | None = None) -> dict:
    """One IPOPT run with the simultaneous method's settings (and ``extra`` options)."""

    opts = dict(Simultaneous.defaults)
    if warm is not None:
        opts.update(Simultaneous.warm_defaults)
        opts["mu_init"] = min(opts.get("mu_init", 1.0), 0.01 * tol)
    opts.update(extra or {})
    opts.update({"tol": tol, "max_iter": int(max_iter), "max_wall_time": float(max(remaining, 1e-3)),
                 "print_level": 0})
    solver = ca.nlpsol("limit", "ipopt", prog.nlp, {"ipopt": opts, "print_time": False, "error_on_fail": False})
    t0 = time.perf_counter()
    sol = solver(**{"x0": x0, "p": p, **bounds, **(warm or {})})
    st = solver.stats()
    raw = str(st.get("return_status", "unknown"))
    return {"x": np.asarray(sol["x"]).ravel(), "warm": {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]},
            "raw": raw, "status": IPOPT_STATUS.get(raw, "failed"), "iterations": int(st.get("iter_count", 0) or 0),
            "seconds": time.perf_counter() - t0}


@dataclass
class _Run:
    """Where a program ended (scaled units)."""

    prog: _Program
    Vs: np.ndarray
    w: np.ndarray
    lam: float  # scaled
    h: float | None  # scaled (min thickness)
    raw: str
    settled: bool
    rounds: list
    lam_x: np.ndarray | None = None  # IPOPT's bound multipliers of the last round's point
    lam_g: np.ndarray | None = None  # and its rows' multipliers


def _rounds(prog: _Program, Vs: np.ndarray, w: np.ndarray, *, lam: float, lam_fixed: bool, h_over: float | None,
            deadline: float, tol: float, max_iter: int, progress: Callable[[dict], None] | None) -> _Run:
    """The program solved; a run IPOPT ends "acceptable" is re-solved warm from its point."""
    s = np.clip(prog.offsets(Vs), -prog.h, prog.h)
    Vs0 = Vs
    half = prog.h * (1 - HULL_MARGIN)
    h = h_over
    warm, raw, rounds, settled, lam_x, lam_g = None, "not run", [], False, None, None
    for rnd in range(1, MAX_ROUNDS + 1):
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            raw = "time limit"
            break
        args = (prog, prog.pack(s, w, lam, h, Vs0), prog.parameters(lam),
                prog.bounds((lam, lam) if lam_fixed else (0.0, np.inf), half), warm)
        out = _ipopt(*args, tol=tol, max_iter=max_iter, remaining=remaining)
        retried = out["raw"] == "Maximum_Iterations_Exceeded" and deadline > time.perf_counter()
        if retried:  # (from the same point, with the other barrier oracle)
            first = out
            out = _ipopt(*args, tol=tol, max_iter=max_iter, remaining=deadline - time.perf_counter(),
                         extra=RETRY_OPTIONS)
            out = {**out, "iterations": first["iterations"] + out["iterations"],
                   "seconds": first["seconds"] + out["seconds"]}
        raw = out["raw"]
        rec = {"round": rnd, "stage": "ipopt", "solver_status": raw, "iterations": out["iterations"],
               "seconds": out["seconds"], **({"retried": RETRY_OPTIONS} if retried else {})}
        ok = np.all(np.isfinite(out["x"]))
        if ok and out["status"] in ("converged", "stalled"):
            s, Vs, w, lam, h = prog.unpack(out["x"])
            Vs0 = Vs
            lam_x = np.asarray(out["warm"]["lam_x0"]).ravel()
            lam_g = np.asarray(out["warm"]["lam_g0"]).ravel()
            rec.update({"acceleration_g" if prog.horizontal else "lambda_kg": lam * prog.lam_unit,
                        **({"thickness": 2 * h * prog.sc.length} if h else {})})
        rounds.append(rec)
        if progress:
            progress(rec)
        if out["status"] != "stalled" or not ok:
            settled = out["status"] == "converged" and bool(ok)
            break
        warm = out["warm"]
    return _Run(prog, Vs, w, lam, h, raw, settled, rounds, lam_x, lam_g)


def _polish(run: _Run, lam: float, deadline: float) -> tuple[np.ndarray, np.ndarray, dict]:
    """λ held, the network made exact to round-off for its loads, hull rows held on their faces."""

    prog = run.prog
    if prog.horizontal:  # (the joint polish balances vertical loads: the weights are refit instead, in _finish)
        return run.Vs, run.w, {"stage": "polish", "skipped": "horizontal loads: the weights are refit at the positions"}
    form = prog.form
    hull = dataclasses.replace(prog.hull, half_thickness=prog.h * (1 - HULL_MARGIN) if run.h is None else run.h)
    total = (lambda Vs: (prog.base + lam * prog.P)[None, :])
    f = dataclasses.replace(form, loads=total(run.Vs), hull=hull)
    t0 = time.perf_counter()
    V, W, k, err, ok = polish_joint(f, run.Vs, run.w[None, :], loads_at=total, deadline=deadline)
    rec = {"stage": "polish", "iterations": k, "max_relative_error": err, "converged": bool(ok),
           "seconds": time.perf_counter() - t0}
    return V, W[0], rec


def _network(prog: _Program, Vs: np.ndarray, w: np.ndarray, lam: float, added: np.ndarray) -> Network:
    """The network in SI units with the loads it carries: the reference's (held) plus λ kg spread
    as ``added`` [N/kg]."""

    net, _ = case_networks(prog.problem, prog.sc, Vs, [w])
    if prog.slide_supports:  # (case_networks puts the supports back where the design has them)
        V = net.vertices.copy()
        V[~prog.free] = prog.sc.pos_back(Vs)[~prog.free]
        net = dataclasses.replace(net, mesh=net.mesh.with_vertices(V))
    loads = prog.sc.load_back(prog.base) + lam * prog.lam_unit * added
    if prog.horizontal:
        loads = load_vectors(loads)
        loads[:, :2] += lam * prog.lam_unit * prog.sc.load_back(prog.H[:, :2])
    return dataclasses.replace(net, loads=loads)


def _evidence(scene: Scene, net: Network, thickness: float, supports_too: bool = False) -> tuple[bool, dict]:
    """The certificate's test, measured outside the solver: equilibrium, compression, inside t/2
    (every free vertex; with ``supports_too`` the supports as well, which then slid)."""

    hull = hull_excess(scene, net, thickness, tol=1e-9)  # (1e-9 of t/2: round-off of the distance)
    err = float(net.max_relative_error())
    inside = hull["inside_all"]
    if supports_too:
        d = np.abs(hull_signed_distance(scene.mesh, net.vertices[scene.supports]))
        hull["support_max_excess"] = float(max((d - 0.5 * thickness).max(initial=0.0), 0.0))
        inside = inside and bool((d <= 0.5 * thickness * (1 + 1e-9)).all())
    ok = bool(err <= CERTIFY_TOL and net.min_weight() >= 0 and inside)
    return ok, {**hull, "max_relative_error": err, "certified": ok}


def _active(run: _Run, rel: float = 1e-4) -> dict[str, list]:
    """The bounds active at the run's point, with IPOPT's multipliers in the units of the answer
    per unit of the bound: λ [kg or g] per metre of the hull's half thickness (``side`` +1 the
    extrados, −1 the intrados) and per N/m of a weight bound; each list largest multiplier first.
    A bound counts as active within ``rel`` of its value (IPOPT relaxes its bounds by 1e-8).
    Sliding, the hull's are the rows ``±s + σ (|u_1| + |u_2|) <= h``."""
    prog = run.prog
    if run.lam_x is None:
        return {}
    nm, m = len(prog.order), prog.form.topology.m
    s, w, mult = prog.offsets(run.Vs), run.w, run.lam_x
    half = prog.h * (1 - HULL_MARGIN)
    per_m = prog.lam_unit / prog.sc.length
    if prog.slide:
        bend = prog.slope * np.abs(prog.tangential(run.Vs)).sum(axis=1)
        n3 = 3 * prog.nf
        rows = [(i, side, run.lam_g[n3 + (0 if side > 0 else nm) + i]) for side in (1, -1)
                for i in np.flatnonzero(np.abs(side * s + bend - half) <= rel * half)]
    else:
        rows = [(i, int(np.sign(s[i])), mult[i]) for i in np.flatnonzero(np.abs(np.abs(s) - half) <= rel * half)]
    hull = sorted(((int(prog.order[i]), side, float(abs(m_) * per_m)) for i, side, m_ in rows), key=lambda r: -r[2])
    edges = np.flatnonzero(prog.problem.scene.active_edges)  # the program's weights, in mesh edge numbers
    per_w = prog.lam_unit * float(prog.sc.weight(np.ones(1))[0])
    lo, up = np.broadcast_to(prog.form.lower, (m,)), np.broadcast_to(prog.form.upper, (m,))
    out: dict[str, list] = {"hull": hull}
    for key, bound in (("weight_lower", lo), ("weight_upper", up)):
        k = np.flatnonzero(np.isfinite(bound) & (np.abs(w - bound) <= rel * np.maximum(np.abs(bound), 1e-300)))
        out[key] = sorted(((int(edges[j]), float(abs(mult[nm + j]) * per_w)) for j in k), key=lambda r: -r[1])
    return out


def _binding(scene: Scene, hull: dict) -> tuple[tuple[int, float], ...]:
    d = np.asarray(hull["signed_distance"]) / (0.5 * hull["thickness"])
    free = np.flatnonzero(~scene.supports)
    on = free[np.abs(d[free]) >= 0.99]
    order = on[np.argsort(-np.abs(d[on]), kind="stable")]
    return tuple((int(v), float(d[v])) for v in order)


# ------------------------------------------------------------------------------ entry points
def _pattern(scene: Scene, at: Sequence[int] | None) -> tuple[np.ndarray, tuple[int, ...]]:
    """The added load per kg [N/kg] (downward, spread evenly over ``at``) and the loaded vertices."""

    share = spread_mass(scene, at, 1.0)
    P = np.zeros(scene.mesh.n_vertices)
    for v, m in share.items():
        P[v] = -G * m
    return P, tuple(sorted(share))


def _base_problem(scene: Scene, thickness: float, density: float, w_max: Any = None, eps: Any = None) -> Problem:
    return stated_problem(scene, density=density, thickness=thickness, w_max=w_max, eps=eps,
                       constraints=[Hull(thickness=thickness)])


def _start(problem: Problem, start: Network | SolveResult | None, kg: float, added: np.ndarray,
           options: Mapping[str, Any] | None, slide_supports: bool = False) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Start positions and weights [SI, per mesh edge]: ``start``, else the staggered network
    (:func:`~selfsupport.methods.hull_search.solve_in_hull`: certified, or the closest one found)."""
    if start is None:

        prob = problem if kg == 0 else dataclasses.replace(
            problem, loads=type(problem.loads)(tuple((n, c + PointLoad(kg * added)) for n, c in problem.loads.cases)))
        start = solve_in_hull(prob, options=options)
        how = f"the staggered network ({start.status})"
    else:
        how = "the given network"
    net = start.network if isinstance(start, SolveResult) else start
    scene = problem.scene
    if net.mesh.n_vertices != scene.mesh.n_vertices or net.weights.shape != (scene.mesh.n_edges,):
        raise InputError("the start network is on another mesh; start from a network of this scene")
    V = scene.mesh.vertices.copy()
    moved = np.ones_like(scene.free) if slide_supports else scene.free
    V[moved] = net.vertices[moved]
    return V, np.asarray(net.weights, float), how


def _program_run(problem: Problem, mode: str, V: np.ndarray, W: np.ndarray | None, added: np.ndarray, *, kg: float,
                 deadline: float, tol: float, max_iter: int, progress: Callable[[dict], None] | None,
                 slide_supports: bool = False, horizontal: np.ndarray | None = None,
                 anchor_at: np.ndarray | None = None) -> _Run:
    """Build the program at positions ``V`` [m] with weights ``W`` [N/m per mesh edge] (``None``:
    a cold start) and run its rounds from λ = ``kg`` (with ``horizontal``, λ is the horizontal
    acceleration in g in that plan direction; with ``anchor_at`` [m], the vertices slide about
    their closest points on the reference)."""
    prog = _Program(problem, V, added, mode, slide_supports, horizontal, anchor_at)
    sc, act = prog.sc, problem.scene.active_edges
    w = (np.clip(sc.weight(W[act]), prog.form.lower, prog.form.upper) if W is not None else
         np.full(prog.form.topology.m, 0.01 * prog.form.weight_scale))
    return _rounds(prog, sc.pos(V), w, lam=kg / prog.lam_unit, lam_fixed=mode not in ("max_load", "max_horizontal"),
                   h_over=prog.h if mode == "min_thickness" else None, deadline=deadline, tol=tol,
                   max_iter=max_iter, progress=progress)


def _si(run: _Run) -> tuple[np.ndarray, np.ndarray]:
    """The run's positions [m] and weights [N/m per mesh edge]."""
    prog = run.prog
    V = prog.sc.pos_back(run.Vs)
    W = np.zeros(prog.mesh0.n_edges)
    W[prog.problem.scene.active_edges] = prog.sc.weight_back(run.w)
    return V, W


def _finish(kind: str, scene: Scene, thickness: float, run: _Run, how: str, added: np.ndarray, *,
            t_start: float, deadline: float, extra: Mapping[str, Any] | None = None) -> tuple[bool, SolveResult, dict]:
    """Polish at the run's λ, build the network and measure it."""
    prog = run.prog
    Vs, w, rec = _polish(run, run.lam, deadline)
    run.rounds.append(rec)
    net = _network(prog, Vs, w, run.lam, added)
    if prog.horizontal:  # the weights moved by the least change to balance the positions to round-off
        lo, up = edge_bounds(prog.problem)
        fit = refit_weights(net, REFIT_TOL, lower=lo, upper=up)
        net = fit if fit is not None else net
        rec["refit"] = fit is not None
    ok, hull = _evidence(scene, net, thickness, prog.slide_supports)
    value = ({"horizontal_acceleration_g": run.lam * prog.lam_unit} if prog.horizontal else
             {"added_mass_kg": run.lam * prog.lam_unit})
    res = SolveResult.build(net, status="converged" if ok else "infeasible", method="limit", backend="ipopt",
                            iterations=sum(r.get("iterations", 0) for r in run.rounds),
                            wall_time=time.perf_counter() - t_start, history=tuple(run.rounds), message="",
                            parameters={"hull": hull, "limit": kind, "start": how, **value, "thickness": thickness,
                                        "ipopt_status": run.raw, **dict(extra or {})})
    return ok, res, hull


def _unsettled(kind: str, scene: Scene, thickness: float, run: _Run, how: str, added: np.ndarray, tried: str, *,
               t_start: float, deadline: float) -> LimitResult:
    """The verdict of rounds that did not settle: locally infeasible only on IPOPT's word."""
    if run.raw in LOCALLY_INFEASIBLE:
        verdict, message = "locally infeasible", f"locally infeasible: IPOPT reported {run.raw} ({tried})"
    else:
        verdict = "not certified"
        message = f"not certified: {tried}; IPOPT ended {run.raw} after {len(run.rounds)} round(s)"
    last, binding = None, ()
    if run.raw not in LOCALLY_INFEASIBLE and np.all(np.isfinite(run.Vs)) and run.rounds:
        _, last, hull = _finish(kind, scene, thickness, run, how, added, t_start=t_start, deadline=deadline)
        last = dataclasses.replace(last, status="infeasible", message=message)
        binding = _binding(scene, hull)
    return LimitResult(kind, None, None, False, last, verdict, run.raw, message, tuple(run.rounds), binding, thickness)


def _certified(kind: str, scene: Scene, value: float, optimum: float | None, res: SolveResult, run: _Run,
               hull: dict, thickness: float, message: str, active: Mapping[str, Any] | None = None) -> LimitResult:
    return LimitResult(kind, value, optimum, True, dataclasses.replace(res, message=message), "certified", run.raw,
                       message, tuple(run.rounds), _binding(scene, hull), thickness, dict(active or {}))


def limit_load(scene: Scene, *, thickness: float, density: float = 2000.0, at: Sequence[int] | None = None,
               w_max: Any = None, eps: Any = None, start: Network | SolveResult | None = None, start_kg: float = 0.0,
               slide_supports: bool = False, slide: bool = False, slide_rounds: int = SLIDE_ROUNDS,
               options: Mapping[str, Any] | None = None,
               time_limit: float = 600.0, tol: float = 1e-9, max_iter: int = 3000,
               progress: Callable[[dict], None] | None = None) -> LimitResult:
    """The largest added mass [kg] at ``at`` (spread evenly; default the scene's handled vertices)
    for which a compressive network lies inside the hull "reference ± t/2", by one NLP.

    Parameters
    ----------
    scene
        The vault; its supports hold the network.
    thickness, density
        The shell's t [m] (self-weight ρ t g per unit area and the hull) and ρ [kg/m³].
    at
        Loaded vertices (free).
    w_max
        Upper weight bound [N/m] (``None``: none).
    eps
        Lower weight bound [N/m] (``None``: the scale-free default ε).
    start
        A network on this mesh to start from; default the staggered network under
        ``start_kg`` (:func:`~selfsupport.methods.hull_search.solve_in_hull`).
    start_kg
        The λ [kg] the program starts from (a previous answer).
    slide_supports
        The supports move on their normals within the hull too (the thrust meets the ground
        anywhere across the springing); default: held where the design has them.
    slide
        The vertices also slide along the reference (:func:`_slide_rounds`): after the
        normal-line program, rounds in which each vertex moves by ``s n + T u`` about its
        anchor (the closest point of the last certificate's vertex on the reference), within
        ``|u|_∞ <= r`` and ``|s| + σ |u| <= (1 − HULL_MARGIN) t/2`` (σ the slope of the
        reference's triangles about the anchor, :func:`_slide_frames`); the answer is the
        best certified round (``slide`` the rounds' records). Default off.
    slide_rounds
        With ``slide``: at most this many sliding rounds (default :data:`SLIDE_ROUNDS`).
    options
        Options of the staggered start.
    time_limit
        Wall-clock limit [s] of the whole analysis (every IPOPT round and the polish stop there).
    tol
        IPOPT's tolerance (its rows are relative residuals).
    max_iter
        IPOPT's iteration limit per run: a round is one run, or two where the first ends at this
        limit (its retry with :data:`RETRY_OPTIONS` from the same point, within the time limit).
    progress
        Called with each round's record.

    Returns
    -------
    LimitResult
        ``value`` the certified mass (λ* or, if its network is not a certificate, the largest
        backed-off λ whose feasibility program gives one), ``optimum`` the program's λ*.
    """
    t_start = time.perf_counter()
    deadline = t_start + time_limit
    added, at_ = _pattern(scene, at)
    problem = _base_problem(scene, thickness, density, w_max, eps)
    V, W, how = _start(problem, start, float(start_kg), added, options, slide_supports)
    tried = (f"maximised the added mass at {list(at_)} over networks inside t = {thickness:g} m from {how} at "
             f"{start_kg:g} kg")
    if slide:
        return _slide_rounds(scene, thickness, problem, added, V, W, how, tried, start=float(start_kg),
                             at_=at_, t_start=t_start, deadline=deadline, tol=tol, max_iter=max_iter,
                             progress=progress, slide_supports=slide_supports, rounds=slide_rounds)
    return _maximise("max_load", scene, thickness, problem, added, V, W, how, tried, start=float(start_kg),
                     unit="kg", where=f" at {list(at_)}", extra={"at": list(at_)}, t_start=t_start,
                     deadline=deadline, tol=tol, max_iter=max_iter, progress=progress, slide_supports=slide_supports)


def _maximise(kind: str, scene: Scene, thickness: float, problem: Problem, added: np.ndarray, V: np.ndarray,
              W: np.ndarray | None, how: str, tried: str, *, start: float, unit: str, where: str,
              extra: Mapping[str, Any], t_start: float, deadline: float, tol: float, max_iter: int,
              progress: Callable[[dict], None] | None, slide_supports: bool,
              horizontal: np.ndarray | None = None, anchor_at: np.ndarray | None = None) -> LimitResult:
    """λ maximised (``kind`` ``"max_load"``: λ kg added at ``added``; ``"max_horizontal"``: λ g
    along ``horizontal``), then certified: the optimum's network, else the feasibility program's
    at λ backed off by :data:`BACK_OFF`. ``unit`` and ``where`` (after the certified value) are
    the messages' words for λ."""
    run = _program_run(problem, kind, V, W, added, kg=start, deadline=deadline, tol=tol, max_iter=max_iter,
                       progress=progress, slide_supports=slide_supports, horizontal=horizontal, anchor_at=anchor_at)
    if not run.settled:
        return _unsettled(kind, scene, thickness, run, how, added, tried, t_start=t_start, deadline=deadline)
    optimum = run.lam * run.prog.lam_unit
    active = _active(run)
    ok, res, hull = _finish(kind, scene, thickness, run, how, added, t_start=t_start, deadline=deadline, extra=extra)
    rounds, best = run.rounds, run
    for back in BACK_OFF if not ok else ():
        Vb, Wb = _si(run)
        frun = _program_run(problem, "feasibility", Vb, Wb, added, kg=optimum * (1 - back), deadline=deadline,
                            tol=tol, max_iter=max_iter, progress=progress, slide_supports=slide_supports,
                            horizontal=horizontal, anchor_at=anchor_at)
        rounds += [{**r, "back_off": back} for r in frun.rounds]
        if not frun.settled:
            continue
        ok, res, hull = _finish(kind, scene, thickness, frun, how, added, t_start=t_start, deadline=deadline,
                                extra=extra)
        best = frun
        if ok:
            break
    best.rounds = rounds
    value = best.lam * best.prog.lam_unit
    if ok:
        what = "a horizontal acceleration of " if kind == "max_horizontal" else ""
        message = (f"certified: {what}{value:.6g} {unit}{where} (the program's optimum {optimum:.6g} {unit}) is "
                   f"carried by a compressive network in equilibrium (max relative error {hull['max_relative_error']:.1e}) "
                   f"within t/2 = {0.5 * thickness:g} m of the reference")
        return _certified(kind, scene, value, optimum, res, best, hull, thickness, message, active)
    message = (f"not certified: the program's optimum {optimum:.6g} {unit} left a network that fails the check "
               f"(max relative error {hull['max_relative_error']:.1e}, {hull['outside']} free vertices beyond t/2 by "
               f"up to {hull['max_excess']:.3g} m), and so did the feasibility program at λ backed off by "
               f"{', '.join(f'{b:g}' for b in BACK_OFF)}")
    return LimitResult(kind, None, optimum, False, dataclasses.replace(res, message=message), "not certified",
                       best.raw, message, tuple(rounds), _binding(scene, hull), thickness, active)


def _slide_rounds(scene: Scene, thickness: float, problem: Problem, added: np.ndarray, V: np.ndarray,
                  W: np.ndarray | None, how: str, tried: str, *, start: float, at_: tuple, t_start: float,
                  deadline: float, tol: float, max_iter: int, progress: Callable[[dict], None] | None,
                  slide_supports: bool, rounds: int = SLIDE_ROUNDS) -> LimitResult:
    """The max-load program with sliding vertices: round 0 the normal-line program, then rounds
    anchored at the closest points of the best certificate's vertices on the reference, each
    warm from its λ and weights and certified as round 0 (the independent distance, the polish,
    the back-offs). Stops after ``rounds``, when a round gains less than
    :data:`SLIDE_GAIN` or gives no certificate, or at the deadline. The best certified round
    is the answer."""
    kw = dict(unit="kg", where=f" at {list(at_)}", extra={"at": list(at_)}, t_start=t_start, deadline=deadline,
              tol=tol, max_iter=max_iter, progress=progress, slide_supports=slide_supports)
    ref = scene.mesh.vertices
    records: list[dict] = []

    def record(k: int, r: LimitResult, seconds: float) -> None:
        moved = None
        if r.certified:
            C = closest_points(r.certificate.network.vertices, scene.mesh)[0]
            moved = float(np.linalg.norm(C - ref, axis=1)[~scene.supports].max())
        records.append({"round": k, "lambda_kg": r.value, "optimum_kg": r.optimum, "verdict": r.verdict,
                        "ipopt_status": r.ipopt_status, "seconds": seconds,
                        "binding": [v for v, _ in r.binding] if r.certified else [], "anchor_moved_m": moved})

    t0 = time.perf_counter()
    best = _maximise("max_load", scene, thickness, problem, added, V, W, how, tried, start=start, **kw)
    record(0, best, time.perf_counter() - t0)
    for k in range(1, int(rounds) + 1):
        if not best.certified or time.perf_counter() >= deadline:
            break
        net = best.certificate.network
        t0 = time.perf_counter()
        r = _maximise("max_load", scene, thickness, problem, added, net.vertices, net.weights, how,
                      f"{tried}, vertices sliding about the round-{k - 1} certificate", start=best.value,
                      anchor_at=net.vertices, **kw)
        record(k, r, time.perf_counter() - t0)
        gain = (r.value - best.value) / max(best.value, 1e-300) if r.certified else -np.inf
        if gain > 0:
            best = r
        if gain < SLIDE_GAIN:
            break
    values = ", ".join("-" if rec["lambda_kg"] is None else f"{rec['lambda_kg']:.6g}" for rec in records)
    message = f"{best.message}; sliding rounds' certified kg: {values}"
    return dataclasses.replace(best, message=message, slide=tuple(records),
                               certificate=None if best.certificate is None else
                               dataclasses.replace(best.certificate, message=message))


def max_horizontal(scene: Scene, *, thickness: float, direction: str | float = "x", density: float = 2000.0,
                   w_max: Any = None, start: Network | SolveResult | None = None, slide_supports: bool = False,
                   options: Mapping[str, Any] | None = None, time_limit: float = 600.0, tol: float = 1e-9,
                   max_iter: int = 3000, progress: Callable[[dict], None] | None = None) -> LimitResult:
    """The largest pseudo-static horizontal acceleration a [g] along ``direction`` for which a
    compressive network lies inside the hull "reference ± t/2": the loads are the self-weight
    (and the scene's extras) W_i, vertical, plus a W_i along the direction at every vertex
    (:class:`~selfsupport.core.loads.HorizontalAcceleration`), by the same NLP as :func:`limit_load`
    with λ = a.

    The certificate carries 3D loads (``Network.loads`` ``(n, 3)``); the joint polish balances
    vertical loads only, so its weights are refit at IPOPT's positions instead
    (:func:`~selfsupport.methods.weight_refit.refit_weights`, to :data:`REFIT_TOL`).

    Parameters
    ----------
    direction
        ``"x"``, ``"y"``, ``"-x"``, ``"-y"`` or an angle in degrees from the x axis
        (:func:`~selfsupport.core.loads.plan_direction`).
    Others
        As :func:`limit_load`.

    Returns
    -------
    LimitResult
        ``kind`` ``"max_horizontal"``; ``value`` the certified acceleration [g], ``optimum`` the
        program's.
    """
    t_start = time.perf_counter()
    deadline = t_start + time_limit
    d = plan_direction(direction)
    added = np.zeros(scene.mesh.n_vertices)
    problem = _base_problem(scene, thickness, density, w_max)
    V, W, how = _start(problem, start, 0.0, added, options, slide_supports)
    tried = (f"maximised the horizontal acceleration along ({d[0]:.4g}, {d[1]:.4g}) over networks inside "
             f"t = {thickness:g} m from {how}")
    return _maximise("max_horizontal", scene, thickness, problem, added, V, W, how, tried, start=0.0,
                     unit="g", where=f" along ({d[0]:.4g}, {d[1]:.4g})", extra={"direction": d.tolist()},
                     t_start=t_start, deadline=deadline, tol=tol, max_iter=max_iter, progress=progress,
                     slide_supports=slide_supports, horizontal=d)


def thrust_range(scene: Scene, *, thickness: float, density: float = 2000.0, w_max: Any = None,
                 start: Network | SolveResult | None = None, slide_supports: bool = False,
                 options: Mapping[str, Any] | None = None, time_limit: float = 600.0, tol: float = 1e-9,
                 max_iter: int = 3000, progress: Callable[[dict], None] | None = None
                 ) -> tuple[LimitResult, LimitResult]:
    """The least and the greatest thrust of compressive networks inside the hull "reference ± t/2"
    under self-weight (and the scene's extras): the thrust is the sum over the supports of their
    horizontal reaction magnitudes ‖R_s,h‖ (:meth:`Network.reaction_summary`), minimised and
    maximised by the limit NLP with λ = 0, from the same start.

    Each answer's value is the thrust [N] of its certificate, measured outside the solver from the
    polished network's reactions (:func:`~selfsupport.core.evidence.support_reactions`).

    Parameters
    ----------
    Others
        As :func:`limit_load` (``time_limit`` covers both programs).

    Returns
    -------
    (LimitResult, LimitResult)
        ``kind`` ``"min_thrust"`` and ``"max_thrust"``; ``value`` [N], ``optimum`` the program's
        thrust before the polish [N].
    """
    t_start = time.perf_counter()
    deadline = t_start + time_limit
    added = np.zeros(scene.mesh.n_vertices)
    problem = _base_problem(scene, thickness, density, w_max)
    V, W, how = _start(problem, start, 0.0, added, options, slide_supports)
    out = []
    for kind in ("min_thrust", "max_thrust"):
        word = "minimised" if kind == "min_thrust" else "maximised"
        tried = f"{word} the thrust over networks inside t = {thickness:g} m from {how}"
        run = _program_run(problem, kind, V, W, added, kg=0.0, deadline=deadline, tol=tol, max_iter=max_iter,
                           progress=progress, slide_supports=slide_supports)
        if not run.settled:
            out.append(_unsettled(kind, scene, thickness, run, how, added, tried, t_start=t_start, deadline=deadline))
            continue
        Vr, Wr = _si(run)  # the program's own thrust, before the polish
        optimum = Network(mesh=scene.mesh.with_vertices(Vr), weights=Wr,
                          loads=run.prog.sc.load_back(run.prog.base), supports=scene.supports
                          ).reaction_summary()["thrust"]
        ok, res, hull = _finish(kind, scene, thickness, run, how, added, t_start=t_start, deadline=deadline)
        thrust = res.network.reaction_summary()["thrust"]
        if ok:
            message = (f"certified: thrust {thrust / 1e3:.6g} kN ({word}; the program's {optimum / 1e3:.6g} kN) of a "
                       f"compressive network in equilibrium (max relative error {hull['max_relative_error']:.1e}) "
                       f"within t/2 = {0.5 * thickness:g} m of the reference")
            out.append(_certified(kind, scene, thrust, optimum, res, run, hull, thickness, message))
            continue
        message = (f"not certified: {tried}; the program's network (thrust {optimum / 1e3:.6g} kN) fails the check "
                   f"(max relative error {hull['max_relative_error']:.1e}, {hull['outside']} free vertices beyond "
                   f"t/2 by up to {hull['max_excess']:.3g} m)")
        out.append(LimitResult(kind, None, optimum, False, dataclasses.replace(res, message=message), "not certified",
                               run.raw, message, tuple(run.rounds), _binding(scene, hull), thickness))
    return out[0], out[1]


def feasible(scene: Scene, *, thickness: float, density: float = 2000.0, kg: float = 0.0,
             at: Sequence[int] | None = None, w_max: Any = None, start: Network | SolveResult | None = None,
             slide_supports: bool = False,
             options: Mapping[str, Any] | None = None, time_limit: float = 600.0, tol: float = 1e-9,
             max_iter: int = 3000, progress: Callable[[dict], None] | None = None) -> LimitResult:
    """Is there a compressive network inside the hull under self-weight plus ``kg`` at ``at``?
    The same program with λ fixed, its objective the distance to the reference vertices (the
    certificate then sits in the middle of what the hull allows). Parameters as
    :func:`limit_load`; ``at`` may be omitted when ``kg`` is 0 (no added load).

    Returns
    -------
    LimitResult
        ``kind`` ``"feasibility"``, ``value`` ``kg`` when certified.
    """
    t_start = time.perf_counter()
    deadline = t_start + time_limit
    added, at_, how, run = _fixed_load_run("feasibility", scene, thickness, density=density, kg=kg, at=at,
                                           w_max=w_max, start=start, options=options,
                                           slide_supports=slide_supports, deadline=deadline, tol=tol,
                                           max_iter=max_iter, progress=progress)
    tried = f"searched for a network inside t = {thickness:g} m under {kg:g} kg at {list(at_)} from {how}"
    if not run.settled:
        return _unsettled("feasibility", scene, thickness, run, how, added, tried, t_start=t_start, deadline=deadline)
    ok, res, hull = _finish("feasibility", scene, thickness, run, how, added, t_start=t_start, deadline=deadline,
                            extra={"at": list(at_)})
    if ok:
        message = (f"certified: a compressive network in equilibrium (max relative error "
                   f"{hull['max_relative_error']:.1e}) within t/2 = {0.5 * thickness:g} m of the reference carries "
                   f"{kg:g} kg at {list(at_)}")
        return _certified("feasibility", scene, float(kg), float(kg), res, run, hull, thickness, message)
    message = (f"not certified: {tried}; the program's network fails the check (max relative error "
               f"{hull['max_relative_error']:.1e}, {hull['outside']} free vertices beyond t/2 by up to "
               f"{hull['max_excess']:.3g} m)")
    return LimitResult("feasibility", None, float(kg), False, dataclasses.replace(res, message=message),
                       "not certified", run.raw, message, tuple(run.rounds), _binding(scene, hull), thickness)


def _fixed_load_run(mode: str, scene: Scene, thickness: float, *, density: float, kg: float,
                    at: Sequence[int] | None, w_max: Any, start: Network | SolveResult | None,
                    options: Mapping[str, Any] | None, slide_supports: bool, deadline: float, tol: float,
                    max_iter: int, progress: Callable[[dict], None] | None) -> tuple[np.ndarray, tuple, str, _Run]:
    """The limit program ``mode`` under self-weight plus a fixed ``kg`` at ``at`` (feasibility,
    min thickness), run from its start: (added pattern, loaded vertices, the start in words, the run)."""
    added, at_ = _added_pattern(scene, at, kg)
    problem = _base_problem(scene, thickness, density, w_max)
    V, W, how = _start(problem, start, float(kg), added, options, slide_supports)
    run = _program_run(problem, mode, V, W, added, kg=float(kg), deadline=deadline, tol=tol,
                       max_iter=max_iter, progress=progress, slide_supports=slide_supports)
    return added, at_, how, run


def _added_pattern(scene: Scene, at: Sequence[int] | None, kg: float) -> tuple[np.ndarray, tuple]:
    """Where ``kg`` goes: no pattern for no added load at no vertex, else :func:`_pattern`."""
    if kg == 0 and at is None:
        return np.zeros(scene.mesh.n_vertices), ()
    return _pattern(scene, at)


def min_thickness(scene: Scene, *, density: float = 2000.0, guess: float, kg: float = 0.0,
                  at: Sequence[int] | None = None, w_max: Any = None, start: Network | SolveResult | None = None,
                  slide_supports: bool = False,
                  options: Mapping[str, Any] | None = None, time_limit: float = 600.0, tol: float = 1e-9,
                  max_iter: int = 3000, progress: Callable[[dict], None] | None = None) -> LimitResult:
    """The smallest thickness t [m] whose hull holds a compressive network, by one NLP with the
    hull's half thickness h = t/2 an unknown (minimised), then certified by :func:`feasible` at
    ``t*`` (backed off upwards by :data:`BACK_OFF` if needed).

    The program holds the loads at the thickness ``guess`` (self-weight ρ t g per unit area).
    Under self-weight alone (``kg = 0``) that is exact: a change of t scales every load and
    weight alike and leaves the network's shape as it is. With an added load the loads of t* differ
    from those of ``guess``; the certificate is made with the loads of its own thickness either way.

    Parameters
    ----------
    guess
        A thickness [m] for the start (the staggered network in its hull) and the program's loads.
    Others
        As :func:`limit_load`.

    Returns
    -------
    LimitResult
        ``kind`` ``"min_thickness"``; ``value`` the certified t [m], ``optimum`` the program's t*.
    """
    t_start = time.perf_counter()
    deadline = t_start + time_limit
    added, at_, how, run = _fixed_load_run("min_thickness", scene, guess, density=density, kg=kg, at=at,
                                           w_max=w_max, start=start, options=options,
                                           slide_supports=slide_supports, deadline=deadline, tol=tol,
                                           max_iter=max_iter, progress=progress)
    tried = f"minimised the thickness under {kg:g} kg at {list(at_)} from {how}"
    if not run.settled:
        return _unsettled("min_thickness", scene, guess, run, how, added, tried, t_start=t_start, deadline=deadline)
    t_opt = 2 * run.h * run.prog.sc.length
    rounds = run.rounds
    Vs, Ws = _si(run)
    last = None
    for back in BACK_OFF:  # (at t* itself the hull is the program's limit: IPOPT may or may not find the point)
        t_c = t_opt * (1 + back) / (1 - HULL_MARGIN)  # (the feasibility program's slabs are (1 − margin) t/2)
        f = feasible(scene, thickness=t_c, density=density, kg=kg, at=at if at_ else None, w_max=w_max,
                     slide_supports=slide_supports,
                     start=Network(mesh=scene.mesh.with_vertices(Vs), weights=Ws * (t_c / guess),
                                   loads=np.zeros(scene.mesh.n_vertices), supports=scene.supports),
                     time_limit=max(deadline - time.perf_counter(), 1e-3), tol=tol, max_iter=max_iter,
                     progress=progress)
        rounds += [{**r, "back_off": back, "thickness": t_c} for r in f.rounds]
        last = f
        if f.certified:
            message = (f"certified: t = {t_c:.6g} m (the program's minimum {t_opt:.6g} m) holds a compressive network "
                       f"in equilibrium (max relative error {f.certificate.max_relative_error:.1e}) within t/2 of "
                       "the reference")
            return LimitResult("min_thickness", t_c, t_opt, True, dataclasses.replace(f.certificate, message=message),
                               "certified", f.ipopt_status, message, tuple(rounds), f.binding, t_c)
    message = (f"not certified: the program's minimum t* = {t_opt:.6g} m; the feasibility program at t* (1 + "
               f"{', '.join(f'{b:g}' for b in BACK_OFF)}) gave no certificate ({last.message})")
    return LimitResult("min_thickness", None, t_opt, False, last.certificate, "not certified", last.ipopt_status,
                       message, tuple(rounds), last.binding, None)
