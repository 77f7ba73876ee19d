"""Design edits of the paper's §4 on a :class:`Design` (a scene and its material).

Each edit is one small frozen dataclass with ``apply(design) -> design`` and a ``op`` name in
:data:`EDITS`; ``Edit.from_dict`` / ``to_dict`` are the edit-script form (:mod:`.script`).

============  ==========================================================================
``move``      handles (a selection) moved by ``offset``; Laplacian deformation of a region of
              interest, ``mode`` full / height / top_view (:mod:`.laplacian`)
``raise``     ``move`` by ``(0, 0, by)`` in height mode; ``lower`` is the same downwards
``pillar``    pull a region to the ground (height edit) and pin it; ``hole = true`` first deletes
              the selected vertices' faces, and the hole's rim becomes the pillar
``pin``       make the selected vertices supports; ``unpin`` frees them
``delete``    delete faces (a selection) to make holes; ``support = true`` pins the new rim
``cut``       cut the mesh open along an edge chain (vertex indices or top-view way points
              joined by shortest edge paths); ``support = true`` pins both sides
``material``  density, thickness, w_max
``objective`` weights of objective terms beside the distance to the reference (planarity, fairness)
``load``      extra mass [kg] or point load [N, positive down] on the selected vertices
``subdivide`` Catmull–Clark ``levels`` times (:mod:`.subdivision`)
============  ==========================================================================

Selections (:class:`Select`) pick vertices by ``vertices`` (indices), ``nearest`` (the vertex
nearest a top-view point), ``near`` + ``radius`` (a top-view disk) or ``box`` (a top-view
rectangle ``[[x0, y0], [x1, y1]]``). With ``relative = true`` every length of the edit is
relative: points as fractions of the top-view bounding box, radii, offsets and heights as
fractions of the bounding-box diagonal (the ground height from the lowest vertex), so one
script serves a scene at any scale.

Example
-------
>>> from selfsupport.core.shapes import make_shape
>>> d = Design(make_shape("barrel_vault", n_vertices=200))
>>> d2 = Pillar(select=Select(nearest=(0.5, 0.5), relative=True), hole=True).apply(d)
>>> int(d2.scene.supports.sum() - d.scene.supports.sum()), d2.scene.mesh.n_vertices == d.scene.mesh.n_vertices - 1
(8, True)
"""
from __future__ import annotations

import collections.abc
import dataclasses
import math
import numbers
import typing
from dataclasses import dataclass, field, replace
from types import NoneType, UnionType
from typing import Any, ClassVar, Mapping

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from formulations.terms import TERMS
from selfsupport.core.defaults import DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.options import check_range
from selfsupport.core.scene import Scene
from selfsupport.core.subdivision import subdivide_scene
from selfsupport.design.laplacian import MODES, LaplacianEditor, ring_region
from selfsupport.io.problem import problem as stated_problem
from selfsupport.methods.memory import check_subdivision

__all__ = ["Design", "Select", "Edit", "EDITS", "Move", "Raise", "Lower", "Pillar", "Pin", "Unpin", "Delete",
           "Cut", "Material", "Objective", "Load", "Subdivide", "remove_faces", "cut_along", "edge_path", "edit_from_dict",
           "check_values"]


# ------------------------------------------------------------------------------ state
@dataclass(frozen=True, eq=False)
class Design:
    """What an edit acts on: the scene (reference, supports, extra loads) and the material.

    ``origin`` maps each vertex to its index in the previous stage's mesh (-1: new), for the
    record; warm starts transfer by position and do not need it."""

    scene: Scene
    density: float = DEFAULT_DENSITY
    thickness: float = DEFAULT_THICKNESS
    w_max: float | None = None
    origin: np.ndarray | None = None
    objective: Mapping[str, float] | None = None  # term name -> weight; None: the method's default

    def problem(self, **kw: Any):
        """The :class:`~formulations.Problem` of this design (self-weight plus the scene's extras)."""
        if self.objective is not None:
            kw.setdefault("objective", dict(self.objective))
        return stated_problem(self.scene, density=self.density, thickness=self.thickness, w_max=self.w_max, **kw)


# ------------------------------------------------------------------------- selections
@dataclass(frozen=True)
class Select:
    """A vertex selection (see the module docstring)."""

    vertices: tuple[int, ...] | None = None
    nearest: tuple[float, float] | None = None
    near: tuple[float, float] | None = None
    radius: float | None = field(default=None, metadata={"range": "(0, inf)"})
    box: tuple[tuple[float, float], tuple[float, float]] | None = None
    relative: bool = False

    @classmethod
    def of(cls, value: Any, what: str = "select") -> "Select":
        """A selection from its table (``what`` names it in messages)."""
        if isinstance(value, Select):
            return value
        if not isinstance(value, Mapping):
            raise InputError(f"a selection is a table like {{nearest = [x, y]}}, got {value!r}")
        d = _known(cls, value, what)
        for k in ("vertices", "nearest", "near"):
            if d.get(k) is not None:
                d[k] = tuple(int(x) if k == "vertices" else float(x) for x in d[k])
        if d.get("box") is not None:
            d["box"] = tuple(tuple(float(x) for x in p) for p in d["box"])
        return cls(**d)

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if k != "box" else [list(p) for p in v]) if isinstance(v, tuple) else v
                for k, v in dataclasses.asdict(self).items() if v is not None and not (k == "relative" and not v)}

    # lengths ---------------------------------------------------------------
    def point(self, mesh: PolyMesh, p: tuple[float, ...]) -> np.ndarray:
        """A top-view point in metres."""
        p = np.asarray(p[:2], float)
        if not self.relative:
            return p
        lo, hi = mesh.vertices[:, :2].min(0), mesh.vertices[:, :2].max(0)
        return lo + p * (hi - lo)

    def length(self, mesh: PolyMesh, x: float) -> float:
        """A length in metres."""
        return float(x) * (_diagonal(mesh) if self.relative else 1.0)

    # what it picks -----------------------------------------------------------
    def mask(self, mesh: PolyMesh) -> np.ndarray:
        """Boolean vertex mask; :class:`InputError` when it picks nothing."""
        n = mesh.n_vertices
        V = mesh.vertices
        m = np.zeros(n, bool)
        given = False
        if self.vertices is not None:
            given = True
            idx = np.asarray(self.vertices, np.int64)
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                raise InputError(f"selected vertex outside 0..{n - 1}")
            m[idx] = True
        if self.nearest is not None:
            given = True
            used = np.zeros(n, bool)
            used[mesh.face_vertices] = True
            d = np.linalg.norm(V[:, :2] - self.point(mesh, self.nearest), axis=1)
            d[~used] = np.inf
            m[int(np.argmin(d))] = True
        if self.near is not None:
            given = True
            if self.radius is None:
                raise InputError("select: 'near' needs a 'radius'")
            m |= np.linalg.norm(V[:, :2] - self.point(mesh, self.near), axis=1) <= self.length(mesh, self.radius)
        if self.box is not None:
            given = True
            a, b = self.point(mesh, self.box[0]), self.point(mesh, self.box[1])
            lo, hi = np.minimum(a, b), np.maximum(a, b)
            m |= np.all((V[:, :2] >= lo) & (V[:, :2] <= hi), axis=1)
        if not given:
            raise InputError("a selection needs one of: vertices, nearest, near + radius, box")
        if not m.any():
            raise InputError(f"the selection {self.to_dict()} picks no vertex")
        return m

    def face_mask(self, mesh: PolyMesh) -> np.ndarray:
        """Faces with a selected vertex (``vertices`` / ``nearest``) or with their centroid in the
        region (``near`` / ``box``)."""
        fv, fo = mesh.face_vertices, mesh.face_offsets
        if self.near is None and self.box is None:
            return np.logical_or.reduceat(self.mask(mesh)[fv], fo[:-1])
        cen = np.add.reduceat(mesh.vertices[fv], fo[:-1], axis=0) / np.diff(fo)[:, None]
        pts = replace(self, vertices=None, nearest=None, relative=False)
        if self.relative:  # relative points refer to the mesh's box, not the centroids'
            conv = {}
            if self.near is not None:
                conv["near"] = tuple(self.point(mesh, self.near))
                conv["radius"] = self.length(mesh, self.radius)
            if self.box is not None:
                conv["box"] = (tuple(self.point(mesh, self.box[0])), tuple(self.point(mesh, self.box[1])))
            pts = replace(pts, **conv)
        sel = np.zeros(mesh.n_faces, bool)
        if pts.near is not None:
            sel |= np.linalg.norm(cen[:, :2] - np.asarray(pts.near[:2]), axis=1) <= pts.radius
        if pts.box is not None:
            a, b = np.asarray(pts.box[0]), np.asarray(pts.box[1])
            sel |= np.all((cen[:, :2] >= np.minimum(a, b)) & (cen[:, :2] <= np.maximum(a, b)), axis=1)
        if not sel.any():
            raise InputError(f"the selection {self.to_dict()} picks no face")
        return sel


# -------------------------------------------------------------------------------- edits
class Edit:
    """Base class: a frozen dataclass with an ``op`` name and ``apply``."""

    op: ClassVar[str] = ""

    def apply(self, design: Design) -> Design:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Edit":
        kw = _known(cls, {k: v for k, v in d.items() if k != "op"}, f"edit {cls.op!r}")
        if "select" in kw:
            kw["select"] = Select.of(kw["select"], f"edit {cls.op!r}: select")
        for k in ("offset", "chain"):
            if kw.get(k) is not None:
                kw[k] = tuple(float(x) if k == "offset" else int(x) for x in kw[k])
        if kw.get("path") is not None:
            kw["path"] = tuple(tuple(float(x) for x in p) for p in kw["path"])
        return cls(**kw)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"op": self.op}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if v is None or v == f.default:
                continue
            if isinstance(v, Select):
                v = v.to_dict()
            elif isinstance(v, tuple):
                v = [list(p) if isinstance(p, tuple) else p for p in v]
            out[f.name] = v
        return out


def _roi(mesh: PolyMesh, handles: np.ndarray, sel: Select, rings: int, radius: float | None) -> np.ndarray:
    if radius is not None:
        c = mesh.vertices[handles, :2]
        d = np.min(np.linalg.norm(mesh.vertices[:, None, :2] - c[None], axis=2), axis=1)
        return (d <= sel.length(mesh, radius)) | handles
    return ring_region(mesh, handles, rings)


@dataclass(frozen=True)
class Move(Edit):
    """Move the selected handles by ``offset`` (Laplacian deformation of ``roi_rings`` rings
    around them, or of the vertices within ``roi_radius`` in top view of a handle)."""

    select: Select
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mode: str = "full"
    roi_rings: int = field(default=8, metadata={"range": "[0, inf)"})
    roi_radius: float | None = field(default=None, metadata={"range": "(0, inf)"})
    op: ClassVar[str] = "move"

    def apply(self, design: Design) -> Design:
        if self.mode not in MODES:
            raise InputError(f"unknown mode {self.mode!r}; choose one of {', '.join(MODES)}")
        sc = design.scene
        mesh = sc.mesh
        h = self.select.mask(mesh)
        roi = _roi(mesh, h, self.select, self.roi_rings, self.roi_radius)
        off = np.asarray(self.offset, float) * (_diagonal(mesh) if self.select.relative else 1.0)
        V = LaplacianEditor(mesh, h, roi=roi, fixed=sc.supports & ~h).deform(mesh.vertices[h] + off, mode=self.mode)
        return _with(design, scene=replace(sc, mesh=mesh.with_vertices(V)))


@dataclass(frozen=True)
class Raise(Edit):
    """Raise the selected region by ``by`` (a height-only handle edit)."""

    select: Select
    by: float = 0.0
    roi_rings: int = field(default=8, metadata={"range": "[0, inf)"})
    roi_radius: float | None = field(default=None, metadata={"range": "(0, inf)"})
    op: ClassVar[str] = "raise"
    sign: ClassVar[float] = 1.0

    def apply(self, design: Design) -> Design:
        return Move(self.select, (0.0, 0.0, self.sign * self.by), "height", self.roi_rings,
                    self.roi_radius).apply(design)


@dataclass(frozen=True)
class Lower(Raise):
    """Lower the selected region by ``by``."""

    op: ClassVar[str] = "lower"
    sign: ClassVar[float] = -1.0


@dataclass(frozen=True)
class Pillar(Edit):
    """Pull the selected region down to ``ground`` (default: the lowest support) by a height-only
    Laplacian edit and pin it. ``hole``: delete the selected vertices' faces first; the hole's
    rim is the pillar (the paper's lilium-pillar: a one-vertex hole, its 4-vertex rim pinned)."""

    select: Select
    ground: float | None = None
    hole: bool = False
    roi_rings: int = field(default=8, metadata={"range": "[0, inf)"})
    roi_radius: float | None = field(default=None, metadata={"range": "(0, inf)"})
    op: ClassVar[str] = "pillar"

    def apply(self, design: Design) -> Design:
        sc = design.scene
        mesh = sc.mesh
        sel = self.select.mask(mesh)
        if self.ground is None:
            ground = float(mesh.vertices[sc.supports, 2].min()) if sc.supports.any() else float(mesh.vertices[:, 2].min())
        elif self.select.relative:
            ground = float(mesh.vertices[:, 2].min()) + self.ground * _diagonal(mesh)
        else:
            ground = float(self.ground)
        if self.hole:
            before = mesh.boundary_vertex_mask
            keep = _kept_vertices(mesh, np.logical_or.reduceat(sel[mesh.face_vertices], mesh.face_offsets[:-1]))
            design = remove_faces(design, np.logical_or.reduceat(sel[mesh.face_vertices], mesh.face_offsets[:-1]))
            sc, mesh = design.scene, design.scene.mesh
            was_boundary = np.where(keep >= 0, before[np.maximum(keep, 0)], False)
            handles = mesh.boundary_vertex_mask & ~was_boundary
            if not handles.any():
                raise InputError("pillar: the hole has no rim (the selection reached the boundary)")
        else:
            handles = sel
        roi = _roi(mesh, handles, self.select, self.roi_rings, self.roi_radius)
        P = mesh.vertices[handles].copy()
        P[:, 2] = ground
        V = LaplacianEditor(mesh, handles, roi=roi, fixed=sc.supports & ~handles).deform(P, mode="height")
        sup = sc.supports | handles
        return _with(design, scene=replace(sc, mesh=mesh.with_vertices(V), supports=sup))


@dataclass(frozen=True)
class Pin(Edit):
    """Make the selected vertices supports."""

    select: Select
    op: ClassVar[str] = "pin"

    def apply(self, design: Design) -> Design:
        sc = design.scene
        return _with(design, scene=replace(sc, supports=sc.supports | self.select.mask(sc.mesh)))


@dataclass(frozen=True)
class Unpin(Edit):
    """Free the selected vertices."""

    select: Select
    op: ClassVar[str] = "unpin"

    def apply(self, design: Design) -> Design:
        sc = design.scene
        return _with(design, scene=replace(sc, supports=sc.supports & ~self.select.mask(sc.mesh)))


@dataclass(frozen=True)
class Delete(Edit):
    """Delete the selected faces (a hole); ``support``: pin the new rim."""

    select: Select
    support: bool = False
    op: ClassVar[str] = "delete"

    def apply(self, design: Design) -> Design:
        mesh = design.scene.mesh
        before = mesh.boundary_vertex_mask
        faces = self.select.face_mask(mesh)
        out = remove_faces(design, faces)
        if self.support:
            o = _kept_vertices(mesh, faces)
            rim = out.scene.mesh.boundary_vertex_mask & ~np.where(o >= 0, before[np.maximum(o, 0)], False)
            out = _with(out, scene=replace(out.scene, supports=out.scene.supports | rim))
        return out


@dataclass(frozen=True)
class Cut(Edit):
    """Cut along an edge chain: ``chain`` (vertex indices along edges) or ``path`` (top-view way
    points, each snapped to its nearest vertex and joined by shortest edge paths; ``relative``
    as in a selection). ``support``: pin both sides of the cut."""

    chain: tuple[int, ...] | None = None
    path: tuple[tuple[float, float], ...] | None = None
    relative: bool = False
    support: bool = False
    op: ClassVar[str] = "cut"

    def apply(self, design: Design) -> Design:
        mesh = design.scene.mesh
        if self.chain is not None:
            chain = np.asarray(self.chain, np.int64)
        elif self.path is not None:
            sel = Select(relative=self.relative)
            pts = [int(np.argmin(np.linalg.norm(mesh.vertices[:, :2] - sel.point(mesh, p), axis=1))) for p in self.path]
            chain = np.asarray(edge_path(mesh, pts), np.int64)
        else:
            raise InputError("cut: give 'chain' (vertex indices) or 'path' (top-view points)")
        return cut_along(design, chain, support=self.support)


@dataclass(frozen=True)
class Material(Edit):
    """Change density [kg/m³], thickness [m] and/or w_max [N/m] (``w_max = 0``: no bound)."""

    density: float | None = None
    thickness: float | None = None
    w_max: float | None = None
    op: ClassVar[str] = "material"

    def apply(self, design: Design) -> Design:
        kw: dict[str, Any] = {}
        for k in ("density", "thickness"):
            v = getattr(self, k)
            if v is not None:
                if not (np.isfinite(v) and v > 0):
                    raise InputError(f"material: {k} must be positive, got {v}")
                kw[k] = float(v)
        if self.w_max is not None:
            kw["w_max"] = None if self.w_max == 0 else float(self.w_max)
        return _with(design, **kw)


@dataclass(frozen=True)
class Objective(Edit):
    """Set objective term weights (``weights``: name -> weight, names from
    :data:`formulations.terms.TERMS`) beside the distance to the reference (weight 1, the method's
    default term); a weight of 0 drops that term.

    >>> from selfsupport.core.shapes import make_shape
    >>> d = Objective(weights={"planarity": 0.5}).apply(Design(make_shape("dome", n_vertices=80)))
    >>> dict(d.objective), [t.name for t in d.problem().objective]
    ({'reference': 1.0, 'planarity': 0.5}, ['reference', 'planarity'])
    """

    weights: Mapping[str, float] | None = None
    op: ClassVar[str] = "objective"

    def apply(self, design: Design) -> Design:

        cur = dict(design.objective) if design.objective is not None else {"reference": 1.0}
        for k, v in dict(self.weights or {}).items():
            if k not in TERMS or k == "hull":
                raise InputError(f"objective: unknown term {k!r}; choose from "
                                 f"{', '.join(sorted(set(TERMS) - {'hull'}))}")
            v = float(v)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"objective: the weight of {k!r} must be a finite number >= 0, got {v}")
            if v == 0:
                cur.pop(k, None)
            else:
                cur[k] = v
        if not cur:
            raise InputError("objective: every term would have weight 0; keep one (e.g. reference = 1)")
        return replace(design, objective=cur)


@dataclass(frozen=True)
class Load(Edit):
    """Add ``extra_mass`` [kg] and/or ``point_load`` [N, positive down] to each selected vertex."""

    select: Select
    extra_mass: float = 0.0
    point_load: float = 0.0
    op: ClassVar[str] = "load"

    def apply(self, design: Design) -> Design:
        sc = design.scene
        m = self.select.mask(sc.mesh)
        n = sc.mesh.n_vertices
        em = np.zeros(n) if sc.extra_mass is None else np.array(sc.extra_mass)
        pl = np.zeros(n) if sc.point_loads is None else np.array(sc.point_loads)
        em[m] += float(self.extra_mass)
        pl[m] -= float(self.point_load)  # the scene's point loads are signed, negative down
        return _with(design, scene=replace(sc, extra_mass=em, point_loads=pl))


@dataclass(frozen=True)
class Subdivide(Edit):
    """Catmull–Clark ``levels`` times (supports and creases carried; :mod:`.subdivision`)."""

    levels: int = field(default=1, metadata={"range": "[1, inf)"})
    op: ClassVar[str] = "subdivide"

    def apply(self, design: Design) -> Design:
        check_subdivision(design.scene.mesh, int(self.levels))
        sc = subdivide_scene(design.scene, int(self.levels))
        n_old = design.scene.mesh.n_vertices
        origin = np.r_[np.arange(n_old), -np.ones(sc.mesh.n_vertices - n_old, np.int64)]
        return _with(design, scene=sc, origin=origin)


#: Edit registry: ``op`` name -> class.
EDITS: dict[str, type[Edit]] = {c.op: c for c in (Move, Raise, Lower, Pillar, Pin, Unpin, Delete, Cut, Material,
                                                   Objective, Load, Subdivide)}


def edit_from_dict(d: Mapping[str, Any]) -> Edit:
    """An edit from its script table (``op`` names the class in :data:`EDITS`): each field is
    checked against its type and range (naming the field), then the whole table by
    :func:`check_values` (plain, finite data, bounded nesting)."""
    op = d.get("op")
    if not isinstance(op, str) or op not in EDITS:
        raise InputError(f"unknown edit op {op!r}; choose one of {', '.join(EDITS)}")
    edit = EDITS[op].from_dict(d)
    check_values(d, f"edit {op!r}")
    return edit


#: Deepest nesting :func:`check_values` accepts (a design message's selection box is 5 deep).
MAX_DEPTH = 12


def check_values(value: Any, what: str) -> None:
    """Raise :class:`InputError` unless ``value`` is plain data an edit may hold: finite numbers,
    integers within 64 bits, strings, booleans, null, lists and tables nested at most
    :data:`MAX_DEPTH` deep.

    The one check of an edit's values, for edit scripts and the design page's messages alike
    (:func:`edit_from_dict`) and again before an edit enters the session's log
    (:meth:`selfsupport.app.session.EditLog.apply`): a NaN or an infinite offset would make the
    design's vertices NaN, and the log's JSON form (strict JSON has no NaN) unsendable.

    Parameters
    ----------
    value
        The data to check (an edit's table, a whole message).
    what
        Names ``value`` in the message (e.g. ``"edit 'move'"``).
    """
    stack: list[tuple[Any, str, int]] = [(value, "", 0)]
    while stack:
        v, path, depth = stack.pop()
        where = f"{what}: {path}" if path else what
        if hasattr(v, "tolist") and not isinstance(v, (str, bytes)):
            v = v.tolist()  # numpy arrays and scalars: their Python values
        if v is None or isinstance(v, (bool, str)):
            continue
        if isinstance(v, numbers.Integral):
            if not -2**63 <= int(v) < 2**63:
                raise InputError(f"{where} = {v} is out of range; give an index or count that fits 64 bits")
        elif isinstance(v, numbers.Real):
            if not math.isfinite(float(v)):
                raise InputError(f"{where} = {v} is not a finite number; give a finite value")
        elif isinstance(v, (Mapping, list, tuple)):
            if depth >= MAX_DEPTH:
                raise InputError(f"{what}: values nested deeper than {MAX_DEPTH} levels; an edit is a flat table")
            items = v.items() if isinstance(v, Mapping) else enumerate(v)
            for k, x in items:
                sub = (f"{path}.{k}" if path else str(k)) if isinstance(v, Mapping) else f"{path}[{k}]"
                stack.append((x, sub, depth + 1))
        else:
            raise InputError(f"{where}: a {type(v).__name__} is not a value an edit can hold")


# --------------------------------------------------------------------- topology helpers
def remove_faces(design: Design, faces: np.ndarray) -> Design:
    """Delete the faces in the mask and the vertices left in no face; supports, handles and
    extra loads follow their vertices; ``origin`` maps new vertices to old ones."""
    sc = design.scene
    mesh = sc.mesh
    faces = np.asarray(faces, bool)
    if faces.all():
        raise InputError("the edit would delete every face")
    kept = [f for f, k in zip(mesh.faces, ~faces) if k]
    used = np.zeros(mesh.n_vertices, bool)
    used[np.fromiter((i for f in kept for i in f), np.int64)] = True
    new_index = -np.ones(mesh.n_vertices, np.int64)
    new_index[used] = np.arange(int(used.sum()))
    new_mesh = PolyMesh.from_faces(mesh.vertices[used], [[int(new_index[i]) for i in f] for f in kept])
    return _reindexed(design, new_mesh, np.flatnonzero(used))


def _kept_vertices(mesh: PolyMesh, faces: np.ndarray) -> np.ndarray:
    """Old index of each vertex :func:`remove_faces` keeps."""
    used = np.zeros(mesh.n_vertices, bool)
    fo = mesh.face_offsets
    for f in np.flatnonzero(~np.asarray(faces, bool)):
        used[mesh.face_vertices[fo[f]:fo[f + 1]]] = True
    return np.flatnonzero(used)


def _reindexed(design: Design, mesh: PolyMesh, origin: np.ndarray) -> Design:
    sc = design.scene
    kw = {k: (None if getattr(sc, k) is None else np.asarray(getattr(sc, k))[origin])
          for k in ("handles", "extra_mass", "point_loads")}
    new = replace(sc, mesh=mesh, supports=np.asarray(sc.supports)[origin], **kw)
    mesh.validate()
    return _with(design, scene=new, origin=np.asarray(origin, np.int64))


def edge_path(mesh: PolyMesh, waypoints: list[int]) -> list[int]:
    """Vertices of the shortest edge paths (Euclidean lengths) through ``waypoints`` in order."""

    e = mesh.edges
    V = mesh.vertices
    n = mesh.n_vertices
    ln = np.linalg.norm(V[e[:, 1]] - V[e[:, 0]], axis=1)
    G = sp.csr_matrix((np.r_[ln, ln], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    out = [int(waypoints[0])]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        _, pred = dijkstra(G, indices=int(a), return_predecessors=True)
        seg = [int(b)]
        while seg[-1] != a:
            p = int(pred[seg[-1]])
            if p < 0:
                raise InputError(f"cut: no edge path from vertex {a} to vertex {b}")
            seg.append(p)
        out += seg[::-1][1:]
    return out


def cut_along(design: Design, chain: np.ndarray, *, support: bool = False) -> Design:
    """Cut the mesh open along the edge chain ``chain`` (consecutive vertices share an edge; a
    closed chain repeats its first vertex at the end). Every chain vertex whose faces fall into
    two fans when the chain edges are cut (interior chain vertices, boundary end points) is
    duplicated; the copy takes the fan on the left of the chain. An interior end point stays
    one vertex (the slit ends there)."""
    sc = design.scene
    mesh = sc.mesh
    chain = [int(v) for v in chain]
    if len(chain) < 2:
        raise InputError("cut: the chain needs at least two vertices")
    nk = mesh.n_vertices + 1
    ekey = mesh.edges[:, 0] * nk + mesh.edges[:, 1]
    cut_keys = set()
    all_keys = set(ekey.tolist())
    for a, b in zip(chain[:-1], chain[1:]):
        k = min(a, b) * nk + max(a, b)
        if k not in all_keys:
            raise InputError(f"cut: vertices {a} and {b} are not joined by an edge")
        cut_keys.add(k)
    fv = mesh.face_vertices
    face_of, nxt, prv = mesh.corner_data
    faces = [list(f) for f in mesh.faces]
    V = list(mesh.vertices)
    origin = list(range(mesh.n_vertices))
    rim: set[int] = set()
    seen: set[int] = set()
    for pos, v in enumerate(chain):
        if v in seen:  # a closed chain's repeated first vertex
            continue
        seen.add(v)
        corners = np.flatnonzero(fv == v)
        fs = face_of[corners]
        # fans: faces around v linked across non-cut edges (v, u)
        parent = {int(f): int(f) for f in fs}

        def find(x: int) -> int:
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        by_edge: dict[int, list[int]] = {}
        for c, f in zip(corners, fs):
            for u in (int(nxt[c]), int(prv[c])):
                k = min(v, u) * nk + max(v, u)
                if k not in cut_keys:
                    by_edge.setdefault(k, []).append(int(f))
        for fl in by_edge.values():
            for g in fl[1:]:
                parent[find(g)] = find(fl[0])
        comps: dict[int, list[int]] = {}
        for f in parent:
            comps.setdefault(find(f), []).append(f)
        if len(comps) < 2:
            continue
        # the left side: the face holding the half-edge v -> next chain vertex (or prev -> v)
        w = chain[pos + 1] if pos + 1 < len(chain) else None
        left = None
        for c, f in zip(corners, fs):
            if w is not None and int(nxt[c]) == w:
                left = int(f)
            elif w is None and int(prv[c]) == chain[pos - 1]:
                left = int(f)
        if left is None:
            raise InputError(f"cut: cannot tell the sides of the chain at vertex {v}")
        new = len(V)
        V.append(mesh.vertices[v].copy())
        origin.append(v)
        for f in comps[find(left)]:
            faces[f] = [new if x == v else x for x in faces[f]]
        rim.update((v, new))
    if not rim:
        raise InputError("cut: the chain cuts nothing open (an interior slit needs both ends on a boundary or "
                         "more than one edge)")
    new_mesh = PolyMesh.from_faces(np.asarray(V), faces)
    origin_a = np.asarray(origin, np.int64)
    out = _reindexed(design, new_mesh, origin_a)
    if support:
        sup = out.scene.supports.copy()
        sup[sorted(rim)] = True
        sup[np.isin(origin_a, chain)] = True
        out = _with(out, scene=replace(out.scene, supports=sup))
    return out


# ------------------------------------------------------------------------------ helpers
def _with(design: Design, **kw: Any) -> Design:
    if kw.get("origin") is not None and design.origin is not None:  # compose: back to the stage's start
        o = np.asarray(kw["origin"])
        kw["origin"] = np.where(o >= 0, design.origin[np.maximum(o, 0)], -1)
    elif "origin" not in kw and design.origin is None and "scene" in kw:
        kw["origin"] = np.arange(kw["scene"].mesh.n_vertices)
    return replace(design, **kw)


def _diagonal(mesh: PolyMesh) -> float:
    V = mesh.vertices
    return float(np.linalg.norm(V.max(0) - V.min(0)))


def _known(cls: type, d: Mapping[str, Any], what: str) -> dict[str, Any]:
    """``d`` as keywords of ``cls``: every key one of its fields, every value of the field's type
    (:func:`_check_value`) and inside its ``metadata["range"]`` (:func:`selfsupport.core.options.check_range`)."""

    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(d) - set(fields)
    if unknown:
        raise InputError(f"{what}: unknown key(s) {sorted(unknown)}; known: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    for k, v in d.items():
        _check_value(v, hints[k], f"{what}: {k}")
        if fields[k].metadata.get("range") is not None and v is not None:
            try:
                check_range(k, v, fields[k].metadata["range"])
            except InputError as e:
                raise InputError(f"{what}: {e}") from None
    return dict(d)


def _check_value(value: Any, hint: Any, where: str) -> None:
    """Raise :class:`InputError` unless ``value`` (as read from TOML or JSON) has the type ``hint``
    of an edit's field: a bool for ``bool`` (not the string "false"), an integer for ``int``, a
    finite number for ``float``, a list of them for a ``tuple`` (of the tuple's length)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, UnionType):
        if value is None and NoneType in args:
            return
        (hint,) = [a for a in args if a is not NoneType]  # (every field is X or X | None)
        origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Select:
        if not isinstance(value, (Select, Mapping)):
            raise InputError(f"{where} must be a table like {{nearest = [x, y]}}, got {value!r}")
        return
    if hint is bool:
        ok, kind = isinstance(value, bool), "true or false (no quotes)"
    elif hint is int:
        ok, kind = isinstance(value, int) and not isinstance(value, bool), "an integer"
    elif hint is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        kind = "a finite number"
    elif hint is str:
        ok, kind = isinstance(value, str), "a string"
    elif origin is tuple:
        fixed = not (len(args) == 2 and args[1] is Ellipsis)
        if not isinstance(value, (list, tuple)) or (fixed and len(value) != len(args)):
            raise InputError(f"{where} must be a list of {len(args) if fixed else 'any number of'} "
                             f"entries, got {value!r}")
        for k, x in enumerate(value):
            _check_value(x, args[k] if fixed else args[0], f"{where}[{k}]")
        return
    elif origin in (collections.abc.Mapping, dict):
        if not isinstance(value, Mapping):
            raise InputError(f"{where} must be a table, got {value!r}")
        for k, x in value.items():
            _check_value(x, args[1], f"{where}.{k}")
        return
    else:  # pragma: no cover - a field type this check does not know yet
        raise TypeError(f"{where}: no check for the field type {hint!r}")
    if not ok:
        raise InputError(f"{where} must be {kind}, got {value!r}")
