"""Planarity of polygon faces (paper §5): the angle-sum defect, and a scale-free volume form."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp

from formulations.equilibrium import flat_selection, to_dm
from formulations.terms.base import Term, TermContext
from selfsupport.core.lazy import lazy_module
from selfsupport.core.mesh import PolyMesh

ca = lazy_module("casadi")  # (imported when first used: a plain staggered solve never is)


def _face_lengths(mesh: PolyMesh, faces: np.ndarray) -> np.ndarray:
    """Mean edge length of each face in ``faces`` (at the mesh's own positions)."""
    face_of, nxt, _ = mesh.corner_data  # (nxt: the next corner's vertex)
    V = mesh.vertices
    ln = np.linalg.norm(V[nxt] - V[mesh.face_vertices], axis=1)
    total = np.bincount(face_of, weights=ln, minlength=mesh.n_faces)
    return total[faces] / mesh.face_sizes[faces]


@dataclass(frozen=True, eq=False)
class _FaceTerm(Term):
    """A term of the faces of ``mesh`` (the reference, whose edge lengths set each face's scale)."""

    mesh: PolyMesh
    weight: float = 1.0

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "_FaceTerm":
        return cls(mesh=ctx.reference, weight=weight, **params)

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices


@dataclass(frozen=True, eq=False)
class Planarity(_FaceTerm):
    """``Σ_f ℓ_f² (2π − θ_f)²`` over faces with four or more corners, ``θ_f`` the sum of the
    face's corner angles (paper §5), ``ℓ_f`` its mean edge length on ``mesh`` (a constant that
    makes the residual a length, like every other term's).

    A skew quad has ``θ_f < 2π``; a planar convex one ``θ_f = 2π``. Faces with ``k > 4`` corners
    use their planar value ``(k − 2)π``; triangles are always planar and skipped. Corner
    angles are ``atan2(‖a × b‖, a · b)`` (smooth away from degenerate corners).
    Registered as ``"planarity"``.
    """

    name: ClassVar[str] = "planarity"

    @cached_property
    def _data(self) -> dict[str, Any] | None:
        m = self.mesh
        sizes = m.face_sizes
        faces = np.flatnonzero(sizes >= 4)
        if faces.size == 0:
            return None
        face_of, nxt, prv = m.corner_data
        corners = np.flatnonzero(sizes[face_of] >= 4)
        local = np.searchsorted(faces, face_of[corners])
        return {"cur": m.face_vertices[corners], "prv": prv[corners], "nxt": nxt[corners], "local": local,
                "nf": len(faces), "target": (sizes[faces] - 2) * np.pi, "scale": _face_lengths(m, faces)}

    def residual_expr(self, X_all):
        d = self._data
        if d is None:
            return ca.DM.zeros(0, 1)
        n = self.n_vertices
        Sc = flat_selection(d["cur"], n)
        a = ca.reshape(ca.mtimes(to_dm(flat_selection(d["prv"], n) - Sc), X_all), 3, -1)
        b = ca.reshape(ca.mtimes(to_dm(flat_selection(d["nxt"], n) - Sc), X_all), 3, -1)
        cross = ca.cross(a, b, 1)
        theta = ca.atan2(ca.sqrt(ca.sum1(cross * cross)), ca.sum1(a * b)).T
        k = len(d["cur"])
        S = sp.csr_matrix((np.ones(k), (d["local"], np.arange(k))), shape=(d["nf"], k))
        return d["scale"] * (d["target"] - ca.mtimes(to_dm(S), theta))

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        d = self._data
        n = self.n_vertices
        if d is None:
            return np.zeros(0), sp.csr_matrix((0, 3 * n))
        V = np.asarray(V, float)
        a, b = V[d["prv"]] - V[d["cur"]], V[d["nxt"]] - V[d["cur"]]
        ab = np.einsum("ij,ij->i", a, b)
        cr = np.linalg.norm(np.cross(a, b), axis=1)
        theta = np.arctan2(cr, ab)
        r = d["scale"] * (d["target"] - np.bincount(d["local"], weights=theta, minlength=d["nf"]))
        # ∂θ/∂a = −b⊥/(|a| |b⊥|), b⊥ the part of b orthogonal to a (and the same with a, b swapped)
        na2, nb2 = np.einsum("ij,ij->i", a, a), np.einsum("ij,ij->i", b, b)
        bp = b - (ab / na2)[:, None] * a
        ap = a - (ab / nb2)[:, None] * b
        ga = -bp / (np.sqrt(na2) * np.linalg.norm(bp, axis=1))[:, None]
        gb = -ap / (np.sqrt(nb2) * np.linalg.norm(ap, axis=1))[:, None]
        rows, cols, vals = [], [], []
        sc = -d["scale"][d["local"]][:, None]  # r = scale · (target − Σθ)
        for verts, g in ((d["prv"], ga), (d["nxt"], gb), (d["cur"], -(ga + gb))):
            rows.append(np.repeat(d["local"], 3))
            cols.append((3 * verts[:, None] + np.arange(3)).ravel())
            vals.append((sc * g).ravel())
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(d["nf"], 3 * n))
        return r, J


def coplanarity_rows(mesh: PolyMesh, fixed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``(corners (r, 4), face (r,), 1/ℓ_f² (r,))`` that are all zero exactly when every face
    with four or more corners is planar: per face, a triple ``a, b, c`` of its corners and, for
    each other corner ``d``, ``det[b − a, c − a, d − a]``. A quad ``v₀v₁v₂v₃`` has the one row
    ``(v₀, v₁, v₂, v₃)``; a larger polygon the triple of largest area at the mesh's positions
    (a T-junction's straight corner never makes it degenerate). ``fixed``: a vertex mask (the
    supports); faces with three or more fixed corners get no rows — their plane is the supports',
    and a free fourth corner held in it could not carry its load (a quad at a vault's foot would
    pin its free corner to the ground).

    >>> from selfsupport.core.mesh import PolyMesh
    >>> m = PolyMesh.from_faces(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0.]]), [[0, 1, 2, 3, 4]])
    >>> coplanarity_rows(m)[0].tolist()  # (0, 1, 2) is collinear: the triple is (0, 2, 3)
    [[0, 2, 3, 1], [0, 2, 3, 4]]
    """
    V = mesh.vertices
    sizes = mesh.face_sizes
    faces = np.flatnonzero(sizes >= 4)
    if fixed is not None and faces.size:
        face_of, _, _ = mesh.corner_data
        n_fixed = np.bincount(face_of, weights=np.asarray(fixed, bool)[mesh.face_vertices], minlength=mesh.n_faces)
        faces = faces[n_fixed[faces] < 3]
    ell = _face_lengths(mesh, faces) if faces.size else np.zeros(0)
    rows, owner, scale = [], [], []
    all_faces = mesh.faces  # (once: the property builds every face's list)
    for f, lf in zip(faces.tolist(), ell.tolist()):
        c = list(all_faces[f])
        if len(c) == 4:
            trip, rest = c[:3], c[3:]
        else:
            P = V[c]
            best, trip = -1.0, c[:3]
            for i in range(len(c)):
                for j in range(i + 1, len(c)):
                    ar = np.linalg.norm(np.cross(P[j] - P[i], P[j + 1:] - P[i]), axis=1) if j + 1 < len(c) else []
                    if len(ar) and ar.max() > best:
                        best, trip = float(ar.max()), [c[i], c[j], c[j + 1 + int(np.argmax(ar))]]
            rest = [v for v in c if v not in trip]
        for d in rest:
            rows.append(trip + [d])
            owner.append(f)
            scale.append(1.0 / lf ** 2)
    if not rows:
        return np.zeros((0, 4), np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.array(rows, np.int64), np.array(owner, np.int64), np.array(scale)


@dataclass(frozen=True, eq=False)
class PlanarityVolume(_FaceTerm):
    """Scale-free planarity of polygons with four or more corners: ``Σ (det[b − a, c − a, d − a] / ℓ_f²)²``
    over the rows of :func:`coplanarity_rows` — for a quad six times the volume of its
    tetrahedron over its squared mean edge length ``ℓ_f`` (on ``mesh``), i.e. the distance
    between the diagonals times their sine: a polynomial, free of the angle sum's ``atan2`` and
    of its insensitivity near 2π (its Jacobian does not vanish at a planar face, so its rows can
    be held as equality constraints: :class:`~formulations.problem.Planar`). Triangles are skipped.
    Registered as ``"planarity_volume"``.
    """

    name: ClassVar[str] = "planarity_volume"

    @cached_property
    def _data(self) -> tuple[np.ndarray, np.ndarray] | None:
        Q, _, s = coplanarity_rows(self.mesh)
        return None if len(Q) == 0 else (Q, s)

    def residual_expr(self, X_all):
        if self._data is None:
            return ca.DM.zeros(0, 1)
        Q, s = self._data
        n = self.n_vertices
        P = [ca.reshape(ca.mtimes(to_dm(flat_selection(Q[:, k], n)), X_all), 3, -1) for k in range(4)]
        e1, e2, e3 = P[1] - P[0], P[2] - P[0], P[3] - P[0]
        return s * ca.sum1(e1 * ca.cross(e2, e3, 1)).T

    def linearize(self, V: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        n = self.n_vertices
        if self._data is None:
            return np.zeros(0), sp.csr_matrix((0, 3 * n))
        Q, s = self._data
        V = np.asarray(V, float)
        e1, e2, e3 = (V[Q[:, k]] - V[Q[:, 0]] for k in (1, 2, 3))
        r = s * np.einsum("ij,ij->i", e1, np.cross(e2, e3))
        g1, g2, g3 = np.cross(e2, e3), np.cross(e3, e1), np.cross(e1, e2)  # ∂det/∂e_k
        grads = (-(g1 + g2 + g3), g1, g2, g3)
        k = len(Q)
        rows = np.tile(np.repeat(np.arange(k), 3), 4)
        cols = np.concatenate([(3 * Q[:, j][:, None] + np.arange(3)).ravel() for j in range(4)])
        vals = np.concatenate([(s[:, None] * g).ravel() for g in grads])
        return r, sp.csr_matrix((vals, (rows, cols)), shape=(k, 3 * n))


@dataclass(frozen=True, eq=False)
class PlanarFaces(PlanarityVolume):
    """The rows of :class:`PlanarityVolume` divided once more by ``ℓ_f``: dimensionless (for a
    square face twice its :func:`~selfsupport.core.evidence.face_nonplanarity`), held at zero by the
    :class:`~formulations.problem.Planar` constraint — equality rows of IPOPT's NLP and of the
    joint polish, a penalty not relaxed along the staggered path in Step 3.
    Registered as ``"planar"``.
    """

    name: ClassVar[str] = "planar"
    constraint: ClassVar[bool] = True
    free: np.ndarray | None = None  # faces with three or more corners not free get no rows

    @classmethod
    def build(cls, ctx: TermContext, weight: float = 1.0, **params: Any) -> "PlanarFaces":
        return cls(mesh=ctx.reference, weight=weight, free=ctx.free, **params)

    @cached_property
    def _data(self) -> tuple[np.ndarray, np.ndarray] | None:
        Q, _, s = coplanarity_rows(self.mesh, None if self.free is None else ~np.asarray(self.free, bool))
        return None if len(Q) == 0 else (Q, s ** 1.5)
