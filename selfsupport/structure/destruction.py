"""Destruction sequences (paper §4, Fig. 8): remove part of a vault and see what still stands.

Stage 0 is the intact vault. Then the faces of the removed vertices' 1-rings are deleted and,
stage after stage, a network in equilibrium inside the masonry hull is searched for what remains
(:func:`~selfsupport.methods.hull_search.solve_in_hull`, always against the *original* reference, with the
original supports). When none is found, the faces touching the vertices that the closest network
found leaves farthest outside the hull (by at least :data:`COLLAPSE_SHARE` of the worst excess)
are deleted, and so on, until what remains stands or nothing does.

Bookkeeping, deterministic (faces are sets of original face ids, processed in sorted order):

* vertices that lose all their faces are **dropped** (never kept as unloaded supports): a stage's
  scene holds exactly the vertices of its faces, with a map back to the original numbering;
* faces of a connected piece that no longer touches a support are deleted (it falls);
* a vertex where two fans of faces meet only at that vertex (non-manifold after a deletion) is a
  hinge, not a joint that can carry moment: its faces are deleted;
* a piece made only of supports carries nothing and stands.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.problem import problem as stated_problem
from selfsupport.methods.hull_search import solve_in_hull

__all__ = ["Stage", "sub_scene", "ring_faces", "clean_faces", "destroy"]

#: A failing stage loses the faces at the vertices outside the hull by at least this share of the
#: worst excess (the rest get another chance once those are gone).
COLLAPSE_SHARE = 0.5


@dataclass(frozen=True)
class Stage:
    """One stage of a destruction sequence.

    Attributes
    ----------
    index
        0 is the vault before the removal (intact, or where a previous sequence ended).
    faces
        Original face ids present at this stage (sorted).
    removed
        Original face ids deleted just before this stage (with the reason in ``why_removed``).
    vertices
        Original vertex ids of the stage's scene, in its order (``vertices[k]`` is its vertex k).
    status
        ``"stands"`` (certified network inside the hull), ``"fails"`` (none found) or ``"empty"``.
    result
        The hull search's result on the stage's scene (``None`` when there was nothing to solve).
    """

    index: int
    faces: tuple[int, ...]
    removed: tuple[int, ...]
    why_removed: str
    vertices: tuple[int, ...]
    status: str
    result: SolveResult | None = None
    scene: Scene | None = field(default=None, repr=False)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def row(self) -> dict[str, Any]:
        h = self.result.parameters.get("hull", {}) if self.result is not None else {}
        return {"stage": self.index, "faces": self.n_faces, "vertices": len(self.vertices),
                "removed": len(self.removed), "why": self.why_removed, "status": self.status,
                "max_relative_error": None if self.result is None else self.result.max_relative_error,
                "outside": h.get("outside"), "max_hull_excess_m": h.get("max_excess")}


def sub_scene(scene: Scene, faces: Sequence[int]) -> tuple[Scene, np.ndarray]:
    """The scene made of the original faces ``faces``: only their vertices (orphans dropped),
    renumbered in increasing original order; returns it and the original id of each vertex."""
    allf = scene.mesh.faces
    fs = [allf[k] for k in sorted(faces)]
    used = np.unique(np.fromiter((v for f in fs for v in f), dtype=np.int64))
    new = np.full(scene.mesh.n_vertices, -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    mesh = PolyMesh.from_faces(scene.mesh.vertices[used], [[int(new[v]) for v in f] for f in fs])

    def sub(a):
        return None if a is None else np.asarray(a)[used]

    return Scene(mesh=mesh, supports=scene.supports[used], handles=sub(scene.handles),
                 extra_mass=sub(scene.extra_mass), point_loads=sub(scene.point_loads),
                 name=f"{scene.name}[{len(fs)} faces]", meta=dict(scene.meta)), used


def ring_faces(scene: Scene, vertices: Sequence[int], faces: Sequence[int]) -> list[int]:
    """The faces among ``faces`` (original ids) that contain any of ``vertices`` (original ids)."""
    vs = set(int(v) for v in vertices)
    allf = scene.mesh.faces
    return [k for k in sorted(faces) if vs.intersection(allf[k])]


def clean_faces(scene: Scene, faces: Sequence[int]) -> tuple[list[int], list[int], str]:
    """Faces that remain after deleting pieces without a support and the faces around
    non-manifold (hinge) vertices, repeated until neither is left: ``(kept, deleted, why)``."""
    kept = sorted(faces)
    deleted: list[int] = []
    why: list[str] = []
    while kept:
        sc, used = sub_scene(scene, kept)
        labels = sc.mesh.connected_components
        grounded = np.zeros(labels.max() + 1, bool)
        grounded[labels[sc.supports]] = True
        face_label = labels[[f[0] for f in sc.mesh.faces]]
        falling = [k for k, lab in zip(kept, face_label) if not grounded[lab]]
        if falling:
            deleted += falling
            why.append(f"{len(falling)} faces of pieces without a support")
            kept = [k for k in kept if k not in set(falling)]
            continue
        hinge = _hinge_vertices(sc.mesh)
        if hinge.size:
            drop = ring_faces(scene, used[hinge].tolist(), kept)
            deleted += drop
            why.append(f"{len(drop)} faces around {hinge.size} hinge vertices")
            kept = [k for k in kept if k not in set(drop)]
            continue
        break
    return kept, sorted(deleted), "; ".join(why)


def _hinge_vertices(mesh: PolyMesh) -> np.ndarray:
    """Vertices that join several boundary fans (where two pieces touch at a point)."""
    he = mesh.halfedge_data
    is_b = mesh.boundary_edge_mask[he["halfedge_edge"]]
    starts = np.bincount(mesh.face_vertices[is_b], minlength=mesh.n_vertices)
    return np.flatnonzero(starts > 1)


def destroy(scene: Scene, remove: Sequence[int] = (), *, thickness: float, density: float = 2500.0,
            remove_faces: Sequence[int] = (), faces: Sequence[int] | None = None,
            max_stages: int = 20, method: Any = None, options: Mapping[str, Any] | None = None,
            progress: Callable[[Stage], None] | None = None) -> list[Stage]:
    """The destruction sequence of ``scene`` after removing the 1-rings of ``remove`` and the
    faces ``remove_faces`` (see the module docstring). Stage 0 is the vault before the removal:
    all faces, or ``faces`` (original face ids: what a previous sequence left, so that removals
    can follow each other); the sequence ends with a stage that stands, an empty stage, or after
    ``max_stages``."""

    n, nf = scene.mesh.n_vertices, scene.mesh.n_faces
    remove = sorted({int(v) for v in remove})
    remove_faces = sorted({int(f) for f in remove_faces})
    if not remove and not remove_faces:
        raise InputError("give at least one vertex to remove (--remove VERTEX)")
    bad = [v for v in remove if not 0 <= v < n]
    if bad:
        raise InputError(f"--remove vertex {bad[0]} is outside 0..{n - 1}")
    bad = [f for f in remove_faces + list(faces or ()) if not 0 <= int(f) < nf]
    if bad:
        raise InputError(f"face {bad[0]} is outside 0..{nf - 1}")

    def solve(faces: list[int]) -> tuple[Scene, np.ndarray, SolveResult | None, str]:
        sc, used = sub_scene(scene, faces)
        if sc.supports.all():
            return sc, used, None, "stands"  # nothing free: it rests on the ground
        prob = stated_problem(sc, density=density, thickness=thickness, constraints=["hull"])
        res = solve_in_hull(prob, method=method, options=options)
        return sc, used, res, "stands" if res.parameters["hull"]["certified"] else "fails"

    stages: list[Stage] = []
    faces = list(range(nf)) if faces is None else sorted({int(f) for f in faces})
    removed, why = [], "intact" if len(faces) == nf else "before the removal"
    for index in range(max_stages + 1):
        if not faces:
            stages.append(Stage(index, (), tuple(removed), why, (), "empty"))
            break
        sc, used, res, status = solve(faces)
        stage = Stage(index, tuple(faces), tuple(removed), why, tuple(int(v) for v in used), status, res, sc)
        stages.append(stage)
        if progress:
            progress(stage)
        if index == 0:  # the removal itself
            present = set(faces)
            drop = sorted(set(ring_faces(scene, remove, faces)) | (set(remove_faces) & present))
            why = ", ".join(([f"1-rings of vertices {remove}"] if remove else [])
                            + ([f"{len(set(remove_faces) & present)} chosen faces"] if remove_faces else [])
                            ) + f": {len(drop)} faces"
        elif status == "stands":
            break
        else:  # the faces touching the vertices that cannot stay inside the hull, the worst first:
            # those outside by at least COLLAPSE_SHARE of the worst excess (all of them at once
            # brought twocirc-3 down entirely after a cut the paper's vault survived in part)
            h = res.parameters["hull"]
            exc = np.asarray(h["outside_excess"], float)
            worst = np.asarray(h["outside_vertices"], dtype=np.int64)[exc >= COLLAPSE_SHARE * exc.max(initial=0.0)]
            out = used[worst]
            if out.size == 0:  # not in equilibrium anywhere near: the worst-balanced vertices go
                rel = res.network.relative_errors()
                free = np.flatnonzero(~sc.supports)
                out = used[free[rel > 1e-6]] if np.any(rel > 1e-6) else used[free]
            drop = ring_faces(scene, out.tolist(), faces)
            why = f"faces at {out.size} vertices outside the hull: {len(drop)} faces"
        kept, cleaned, more = clean_faces(scene, [k for k in faces if k not in set(drop)])
        removed = sorted(set(drop) | set(cleaned))
        why = why + (f"; then {more}" if more else "")
        faces = kept
    return stages
