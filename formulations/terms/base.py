"""The objective-term protocol: one small class per term, stated twice on purpose —
symbolically (CasADi, for IPOPT/nlopt and sensitivities) and as a numeric Gauss–Newton
linearization (for the staggered method's Step 3 and the refinement) — and cross-checked by
the tests for every registered term.

A term is ``weight · ‖r(V)‖²`` with a residual vector ``r`` of the flattened positions
``X_all`` (length ``3 n``, entry ``3 i + c`` is coordinate ``c`` of vertex ``i``). Residuals are
lengths (in the units of the positions), so terms add up meaningfully and a term keeps its
minimiser when the scene is scaled.

* ``residual_expr(X_all)`` — the CasADi residual; ``expr`` = ``weight · sumsqr``.
* ``linearize(V) -> (r, J)`` — numeric residual and sparse Jacobian ``∂r/∂X_all`` (unweighted).
* ``couples_xyz`` — ``False`` when ``J = J₁ ⊗ I₃`` (the same operator on x, y and z): Step 3
  then adds ``J₁ᵀJ₁`` to its per-coordinate matrix and keeps its fast CG path.
  ``vertex_local`` — every row involves one vertex only (``JᵀJ`` is 3×3 block diagonal).
* ``at(V)`` — the term re-linearized at new positions where it has moving data (closest
  points on the reference); most terms return themselves.
* ``constraint`` — a penalty standing for a constraint (the masonry hull): methods do not
  relax it along their penalty path.

"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from formulations.equilibrium import to_dm
from selfsupport.core.errors import InputError
from selfsupport.core.lazy import lazy_module
from selfsupport.core.mesh import PolyMesh

ca = lazy_module("casadi")  # (imported when first used: a plain staggered solve never is)


def vertex_indices(mask: np.ndarray | None, n: int) -> np.ndarray:
    """Indices of the selected vertices: a boolean mask of length ``n``, indices, or all."""
    if mask is None:
        return np.arange(n)
    mask = np.asarray(mask)
    if mask.dtype == bool:
        if mask.shape != (n,):
            raise InputError(f"vertex mask has {mask.shape} entries for {n} vertices")
        return np.flatnonzero(mask)
    return mask.astype(np.int64).ravel()


def points_array(a: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(a, float)
    if a.ndim != 2 or a.shape[1] != 3 or not np.isfinite(a).all():
        raise InputError(f"{what} must be a finite (n, 3) array, got shape {a.shape}")
    return a


def normal_rows(normals: np.ndarray, idx: np.ndarray, n: int) -> sp.csr_matrix:
    """``(len(idx), 3 n)`` matrix whose row ``k`` takes ``⟨normals[idx[k]], v_idx[k]⟩``."""
    r = np.repeat(np.arange(len(idx)), 3)
    c = (3 * idx[:, None] + np.arange(3)).ravel()
    return sp.csr_matrix((normals[idx].ravel(), (r, c)), shape=(len(idx), 3 * n))


def selection(idx: np.ndarray, n: int) -> sp.csr_matrix:
    """``(len(idx), n)`` matrix picking the rows ``idx``."""
    idx = np.asarray(idx, np.int64)
    return sp.csr_matrix((np.ones(len(idx)), (np.arange(len(idx)), idx)), shape=(len(idx), n))


@dataclass(frozen=True)
class TermContext:
    """What a registered term needs to build itself for one problem, in the method's units.

    ``vertices``: starting positions; ``reference``: the reference surface (its vertices are the
    design's positions); ``free``: vertices that move; ``thickness``: shell thickness (for the
    masonry hull).
    """

    vertices: np.ndarray
    reference: PolyMesh
    free: np.ndarray
    thickness: float | None = None

    @property
    def mesh(self) -> PolyMesh:
        return self.reference.with_vertices(self.vertices)

    @property
    def interior_free(self) -> np.ndarray:
        return self.free & ~self.reference.boundary_vertex_mask


class Term:
    """Base class: ``weight · ‖r(X_all)‖²``."""

    name: ClassVar[str] = "term"
    couples_xyz: ClassVar[bool] = True
    vertex_local: ClassVar[bool] = False
    constraint: ClassVar[bool] = False
    weight: float = 1.0

    # -------------------------------------------------------------- to implement
    @property
    def n_vertices(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def residual_expr(self, X_all):  # pragma: no cover - abstract
        """The CasADi residual vector (unweighted)."""
        raise NotImplementedError

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """Numeric residual and Jacobian ``∂r/∂X_all`` at ``(n, 3)`` positions (unweighted)."""
        if self.couples_xyz:  # pragma: no cover - abstract for coupling terms
            raise NotImplementedError
        r1, J1 = self.per_coordinate(V)
        return r1.ravel(), sp.kron(J1, sp.identity(3), format="csr")

    def per_coordinate(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """For terms with ``couples_xyz = False``: ``r`` as ``(k, 3)`` and ``J₁`` ``(k, n)``."""
        raise InputError(f"term {self.name!r} couples x, y and z; use linearize()")

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "Term":
        """The term for one problem (the registry's constructor)."""
        raise InputError(f"term {cls.name!r} cannot be built from a problem; construct it directly")

    # -------------------------------------------------------------- shared
    def vertex_blocks(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For ``vertex_local`` terms: the Gauss–Newton normal equations per vertex, ``(idx,
        B (k, 3, 3), b (k, 3))`` with ``B = J_iᵀJ_i`` and ``b = J_iᵀ(J_i v_i − r_i)`` (unweighted) —
        what ``linearize`` gives, without sparse matrices (Step 3 calls it every iteration)."""
        r, J = self.linearize(V)
        n = self.n_vertices
        G = (J.T @ J).tocoo()
        B = np.zeros((n, 3, 3))
        np.add.at(B, (G.row // 3, G.row % 3, G.col % 3), G.data)
        b = (J.T @ (J @ np.asarray(V, float).ravel() - r)).reshape(n, 3)
        idx = np.flatnonzero(np.abs(B).sum(axis=(1, 2)) > 0)
        return idx, B[idx], b[idx]

    def at(self, V: np.ndarray, projection: tuple | None = None) -> "Term":
        """This term with its moving data (closest points) taken at ``V``; most terms: itself.
        ``projection``: the closest points, distances and normals of ``V`` on the reference when
        the caller has them already (in the same units)."""
        return self

    def raw(self, X_all):
        """The unweighted energy ``‖r‖²``."""
        return ca.sumsqr(self.residual_expr(X_all))

    def expr(self, X_all):
        """Weighted energy as a CasADi scalar of the flattened positions ``X_all`` (3 n)."""
        return self.weight * self.raw(X_all)

    def __mul__(self, s: float) -> "Term":
        # (× 1 is the term itself: what it caches, e.g. a constant Jacobian, stays with it)
        return self if float(s) == 1.0 else dataclasses.replace(self, weight=self.weight * float(s))

    __rmul__ = __mul__

    def __add__(self, other: "Term") -> "Sum":
        if not isinstance(other, Term):
            return NotImplemented
        return Sum((self, other))

    @cached_property
    def _functions(self) -> tuple[ca.Function, ca.Function]:
        x = ca.SX.sym("x", 3 * self.n_vertices)
        e = self.expr(x)
        return (ca.Function(f"{self.name}_value", [x], [e]),
                ca.Function(f"{self.name}_gradient", [x], [ca.gradient(e, x)]))

    def value(self, V: np.ndarray) -> float:
        """Weighted energy at ``(n, 3)`` positions (CasADi)."""
        return float(self._functions[0](np.asarray(V, float).ravel()))

    def gradient(self, V: np.ndarray) -> np.ndarray:
        """``(n, 3)`` gradient with respect to the vertex positions (CasADi)."""
        return np.asarray(self._functions[1](np.asarray(V, float).ravel())).reshape(-1, 3)

    def numeric_value(self, V: np.ndarray) -> float:
        """Weighted energy from the numeric residual (no CasADi graph: cheap on large meshes)."""
        r, _ = self.linearize(np.asarray(V, float))
        return self.weight * float(r @ r)

    def parts(self) -> tuple["Term", ...]:
        """The weighted terms this one is made of (a :class:`Sum` flattens)."""
        return (self,)


@dataclass(frozen=True, eq=False)
class Sum(Term):
    """``weight · Σ terms``; built by ``term_a + term_b``."""

    terms: tuple[Term, ...]
    weight: float = 1.0
    name: ClassVar[str] = "sum"

    def __post_init__(self) -> None:
        flat: list[Term] = []
        for t in self.terms:
            flat.extend(t.terms if isinstance(t, Sum) and t.weight == 1.0 else (t,))
        sizes = {t.n_vertices for t in flat}
        if len(sizes) > 1:
            raise InputError(f"objective terms are defined on different vertex counts {sorted(sizes)}")
        object.__setattr__(self, "terms", tuple(flat))

    @property
    def n_vertices(self) -> int:
        return self.terms[0].n_vertices

    @property
    def couples_xyz(self) -> bool:  # type: ignore[override]
        return any(t.couples_xyz for t in self.terms)

    def raw(self, X_all):
        out = 0
        for t in self.terms:
            out = out + t.expr(X_all)
        return out

    def residual_expr(self, X_all):
        return ca.vertcat(*[np.sqrt(t.weight) * t.residual_expr(X_all) for t in self.terms])

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        lin = [t.linearize(V) for t in self.terms]
        s = [np.sqrt(t.weight) for t in self.terms]
        return (np.concatenate([si * r for si, (r, _) in zip(s, lin)]),
                sp.vstack([si * J for si, (_, J) in zip(s, lin)], format="csr"))

    def at(self, V: np.ndarray, projection: tuple | None = None) -> "Sum":
        return dataclasses.replace(self, terms=tuple(t.at(V, projection) for t in self.terms))

    def parts(self) -> tuple[Term, ...]:
        return tuple(t * self.weight for t in self.terms)


@dataclass(frozen=True, eq=False)
class Scaled(Term):
    """A term stated in other units: ``term(length · X + center) / length²``.

    Methods work in scale-free coordinates ``X̂ = (X − center) / length``; a user's terms are
    stated in real units and wrapped with this, which leaves their minimiser unchanged.
    """

    term: Term
    length: float
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    weight: float = 1.0
    name: ClassVar[str] = "scaled"

    @property
    def n_vertices(self) -> int:
        return self.term.n_vertices

    @property
    def couples_xyz(self) -> bool:  # type: ignore[override]
        return self.term.couples_xyz

    def _back(self, V: np.ndarray) -> np.ndarray:
        return self.length * np.asarray(V, float) + np.asarray(self.center, float)

    def raw(self, X_all):
        shift = np.tile(np.asarray(self.center, float), self.n_vertices)
        return self.term.expr(self.length * X_all + shift) / self.length ** 2

    def residual_expr(self, X_all):
        shift = np.tile(np.asarray(self.center, float), self.n_vertices)
        return np.sqrt(self.term.weight) * self.term.residual_expr(self.length * X_all + shift) / self.length

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        r, J = self.term.linearize(self._back(V))  # dr̂/dX̂ = (dr/dX · length) / length
        s = np.sqrt(self.term.weight)
        return s * r / self.length, (s * J).tocsr()

    def at(self, V: np.ndarray, projection: tuple | None = None) -> "Scaled":
        return dataclasses.replace(self, term=self.term.at(self._back(V)))  # (a projection in other units)


class OnPoints:
    """For terms holding per-vertex ``points`` and a vertex ``mask``: the vertex count and the
    selected indices."""

    @property
    def n_vertices(self) -> int:
        return self.points.shape[0]

    @cached_property
    def idx(self) -> np.ndarray:
        return vertex_indices(self.mask, self.n_vertices)


@dataclass(frozen=True, eq=False)
class PlaneDistance(OnPoints, Term):
    """``Σ_i (1 − τ) ⟨n_i, v_i − p_i⟩² + τ ‖v_i − p_i‖²`` with points ``p_i`` and unit normals
    ``n_i``: the squared distance to the tangent planes, plus a weak hold ``τ`` against sliding
    along them. Residual per selected vertex: ``[√(1−τ) ⟨n, d⟩, √τ d]`` (``τ = 0``: the first only)."""

    points: np.ndarray
    normals: np.ndarray
    mask: np.ndarray | None = None
    tangential: float = 0.0
    weight: float = 1.0
    vertex_local: ClassVar[bool] = True

    def __post_init__(self) -> None:
        p = points_array(self.points, "points")
        nrm = points_array(self.normals, "normals")
        if p.shape != nrm.shape:
            raise InputError(f"points {p.shape} and normals {nrm.shape} differ in shape")
        if not 0.0 <= float(self.tangential) <= 1.0:
            raise InputError(f"tangential weight must be in [0, 1], got {self.tangential}")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "normals", nrm)

    @cached_property
    def _normal_rows(self) -> sp.csr_matrix:
        return normal_rows(self.normals, self.idx, self.n_vertices)

    @cached_property
    def _coordinate_rows(self) -> sp.csr_matrix:
        return sp.kron(selection(self.idx, self.n_vertices), sp.identity(3), format="csr")

    def residual_expr(self, X_all):
        idx = self.idx
        off = np.einsum("ij,ij->i", self.normals[idx], self.points[idx])
        r = np.sqrt(1.0 - self.tangential) * (ca.mtimes(to_dm(self._normal_rows), X_all) - off)
        if self.tangential > 0:
            d = ca.mtimes(to_dm(self._coordinate_rows), X_all) - self.points[idx].ravel()
            r = ca.vertcat(r, np.sqrt(self.tangential) * d)
        return r

    def vertex_blocks(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # r is linear, r = J (v − p): B = (1 − τ) n nᵀ + τ I, b = B p
        idx = self.idx
        n = self.normals[idx]
        B = (1.0 - self.tangential) * n[:, :, None] * n[:, None, :] + self.tangential * np.eye(3)[None]
        return idx, B, np.einsum("kij,kj->ki", B, self.points[idx])

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        idx = self.idx
        d = np.asarray(V, float)[idx] - self.points[idx]
        a = np.sqrt(1.0 - self.tangential)
        r, J = a * np.einsum("ij,ij->i", self.normals[idx], d), a * self._normal_rows
        if self.tangential > 0:
            b = np.sqrt(self.tangential)
            r, J = np.r_[r, b * d.ravel()], sp.vstack([J, b * self._coordinate_rows], format="csr")
        return r, J.tocsr()
