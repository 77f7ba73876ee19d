"""Objective terms, one small class each, stated symbolically in CasADi.

Every term acts on the flattened positions of *all* vertices, ``X_all`` (length ``3 n``, entry
``3 i + c`` is coordinate ``c`` of vertex ``i``), and returns a CasADi scalar already
multiplied by its ``weight``. Terms combine like cvxpy expressions::

    obj = PointDistance(targets=V0) * 0.1 + NormalDrift.from_mesh(mesh)

``value(V)`` / ``gradient(V)`` evaluate a term numerically on an ``(n, 3)`` array (through a
cached ``ca.Function``), for tests and diagnostics.

Example
-------
>>> import numpy as np
>>> V0 = np.zeros((2, 3))
>>> t = PointDistance(targets=V0) * 2.0 + PointDistance(targets=V0)
>>> float(t.value(np.ones((2, 3))))
18.0
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import casadi as ca
import numpy as np
import scipy.sparse as sp

from selfsupport.errors import InputError
from selfsupport.mesh import PolyMesh

from .equilibrium import flat_selection, to_dm


def _indices(mask: np.ndarray | None, n: int) -> np.ndarray:
    if mask is None:
        return np.arange(n)
    mask = np.asarray(mask)
    if mask.dtype == bool:
        if mask.shape != (n,):
            raise InputError(f"vertex mask has {mask.shape} entries for {n} vertices")
        return np.flatnonzero(mask)
    return mask.astype(np.int64).ravel()


def _points(a: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(a, float)
    if a.ndim != 2 or a.shape[1] != 3 or not np.isfinite(a).all():
        raise InputError(f"{what} must be a finite (n, 3) array, got shape {a.shape}")
    return a


class Term:
    """Base class: ``weight`` times a scalar energy of the vertex positions."""

    name: ClassVar[str] = "term"
    weight: float = 1.0

    # -------------------------------------------------------------- to implement
    @property
    def n_vertices(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def raw(self, X_all):  # pragma: no cover - abstract
        """The unweighted energy."""
        raise NotImplementedError

    # -------------------------------------------------------------- shared
    def expr(self, X_all):
        """Weighted energy as a CasADi scalar of the flattened positions ``X_all`` (3 n)."""
        return self.weight * self.raw(X_all)

    def __mul__(self, s: float) -> "Term":
        return dataclasses.replace(self, weight=self.weight * float(s))

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
        return float(self._functions[0](np.asarray(V, float).ravel()))

    def gradient(self, V: np.ndarray) -> np.ndarray:
        """``(n, 3)`` gradient with respect to the vertex positions."""
        return np.asarray(self._functions[1](np.asarray(V, float).ravel())).reshape(-1, 3)


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

    def raw(self, X_all):
        out = 0
        for t in self.terms:
            out = out + t.expr(X_all)
        return out


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

    def raw(self, X_all):
        shift = np.tile(np.asarray(self.center, float), self.n_vertices)
        return self.term.expr(self.length * X_all + shift) / self.length ** 2


@dataclass(frozen=True, eq=False)
class PointDistance(Term):
    """``Σ_i ‖v_i − t_i‖²`` over the selected vertices (``mask``; all by default)."""

    targets: np.ndarray
    mask: np.ndarray | None = None
    weight: float = 1.0
    name: ClassVar[str] = "point_distance"

    def __post_init__(self) -> None:
        object.__setattr__(self, "targets", _points(self.targets, "targets"))

    @property
    def n_vertices(self) -> int:
        return self.targets.shape[0]

    @cached_property
    def _sel(self) -> tuple[np.ndarray, np.ndarray]:
        idx = _indices(self.mask, self.n_vertices)
        rows = (3 * idx[:, None] + np.arange(3)).ravel()
        return rows, self.targets[idx].ravel()

    def raw(self, X_all):
        rows, t = self._sel
        return ca.sumsqr(X_all[rows.tolist()] - t)


@dataclass(frozen=True, eq=False)
class _PlaneDistance(Term):
    """``Σ_i ⟨n_i, v_i − p_i⟩²`` with fixed points ``p_i`` and unit normals ``n_i``."""

    points: np.ndarray
    normals: np.ndarray
    mask: np.ndarray | None = None
    weight: float = 1.0

    def __post_init__(self) -> None:
        p = _points(self.points, "points")
        nrm = _points(self.normals, "normals")
        if p.shape != nrm.shape:
            raise InputError(f"points {p.shape} and normals {nrm.shape} differ in shape")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "normals", nrm)

    @property
    def n_vertices(self) -> int:
        return self.points.shape[0]

    @cached_property
    def _data(self) -> tuple[ca.DM, np.ndarray]:
        idx = _indices(self.mask, self.n_vertices)
        r = np.repeat(np.arange(len(idx)), 3)
        c = (3 * idx[:, None] + np.arange(3)).ravel()
        N = sp.csr_matrix((self.normals[idx].ravel(), (r, c)), shape=(len(idx), 3 * self.n_vertices))
        return to_dm(N), np.einsum("ij,ij->i", self.normals[idx], self.points[idx])

    def raw(self, X_all):
        N, off = self._data
        return ca.sumsqr(ca.mtimes(N, X_all) - off)


@dataclass(frozen=True, eq=False)
class ReferenceDistance(_PlaneDistance):
    """Squared distance to the reference surface, linearised: ``p_i`` is the closest point of
    the reference to the current ``v_i`` and ``n_i`` the reference normal there (paper §3)."""

    name: ClassVar[str] = "reference_distance"

    @classmethod
    def from_reference(cls, vertices: np.ndarray, reference: PolyMesh, *, mask: np.ndarray | None = None,
                       weight: float = 1.0) -> "ReferenceDistance":
        from selfsupport.evidence import closest_points

        p, _, nrm = closest_points(np.asarray(vertices, float), reference)
        return cls(points=p, normals=nrm, mask=mask, weight=weight)


@dataclass(frozen=True, eq=False)
class NormalDrift(_PlaneDistance):
    """``Σ_i ⟨n_i, v_i − v_i⁰⟩²``: motion along the fixed starting normals (paper Step 3, α term)."""

    name: ClassVar[str] = "normal_drift"

    @classmethod
    def from_mesh(cls, mesh: PolyMesh, vertices: np.ndarray | None = None, *, mask: np.ndarray | None = None,
                  weight: float = 1.0) -> "NormalDrift":
        from selfsupport.geometry import vertex_normals

        v = mesh.vertices if vertices is None else np.asarray(vertices, float)
        return cls(points=v, normals=vertex_normals(mesh, v), mask=mask, weight=weight)


@dataclass(frozen=True, eq=False)
class Planarity(Term):
    """``Σ_f (2π − θ_f)²`` over quads, ``θ_f`` the sum of the face's corner angles (paper §5).

    A skew quad has ``θ_f < 2π``; a planar convex one ``θ_f = 2π``. Faces with ``k > 4`` corners
    use their planar value ``(k − 2)π`` as target; triangles are always planar and skipped.
    Corner angles are ``atan2(‖a × b‖, a · b)`` (smooth away from degenerate corners).
    """

    mesh: PolyMesh
    weight: float = 1.0
    name: ClassVar[str] = "planarity"

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @cached_property
    def _data(self) -> dict[str, object] | None:
        m = self.mesh
        sizes = m.face_sizes
        faces = np.flatnonzero(sizes >= 4)
        if faces.size == 0:
            return None
        face_of, nxt, prv = m._corner_data
        corners = np.flatnonzero(sizes[face_of] >= 4)
        cur = m.face_vertices[corners]
        n = m.n_vertices
        Sc = flat_selection(cur, n)
        a = flat_selection(prv[corners], n) - Sc
        b = flat_selection(nxt[corners], n) - Sc
        local = np.searchsorted(faces, face_of[corners])
        S = sp.csr_matrix((np.ones(len(corners)), (local, np.arange(len(corners)))), shape=(len(faces), len(corners)))
        return {"a": to_dm(a), "b": to_dm(b), "S": to_dm(S), "target": (sizes[faces] - 2) * np.pi,
                "k": len(corners)}

    def raw(self, X_all):
        d = self._data
        if d is None:
            return 0 * X_all[0]
        k = d["k"]
        a = ca.reshape(ca.mtimes(d["a"], X_all), 3, k)
        b = ca.reshape(ca.mtimes(d["b"], X_all), 3, k)
        cross = ca.cross(a, b, 1)
        sin = ca.sqrt(ca.sum1(cross * cross))
        cos = ca.sum1(a * b)
        theta = ca.atan2(sin, cos).T
        return ca.sumsqr(ca.mtimes(d["S"], theta) - d["target"])


@dataclass(frozen=True, eq=False)
class Fairness(Term):
    """Umbrella Laplacian ``Σ_i ‖Σ_j (v_j − v_i) / deg_i‖²`` over the ``free`` vertices (all by default)."""

    mesh: PolyMesh
    free: np.ndarray | None = None
    weight: float = 1.0
    name: ClassVar[str] = "fairness"

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @cached_property
    def _U(self) -> ca.DM:
        m = self.mesh
        n = m.n_vertices
        e = m.edges
        deg = np.bincount(e.ravel(), minlength=n).astype(float)
        A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
        U = (sp.diags(1.0 / np.maximum(deg, 1)) @ A - sp.eye(n)).tocsr()[_indices(self.free, n)]
        return to_dm(sp.kron(U, sp.eye(3)))

    def raw(self, X_all):
        return ca.sumsqr(ca.mtimes(self._U, X_all))


#: Registry of objective terms by name.
TERMS: dict[str, type[Term]] = {cls.name: cls for cls in
                                (ReferenceDistance, PointDistance, NormalDrift, Planarity, Fairness)}
