"""Scenes from what a user hands over: a file, a built-in shape, a network, a mesh; and the
design a network file stores (its reference and its network)."""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import make_shape
from selfsupport.io import read_scene
from selfsupport.io.supports import resolve_supports

__all__ = ["as_scene", "design_of", "load_scene"]


def _supports_mask(spec: Any, mesh: PolyMesh, source: str) -> np.ndarray:
    """``spec`` as a boolean mask: ``"boundary"`` / a supports file / indices / a mask."""
    if isinstance(spec, (str, os.PathLike)):

        return np.asarray(resolve_supports(spec, mesh, source=source), bool)
    a = np.asarray(spec)
    if a.dtype == bool:
        if a.shape != (mesh.n_vertices,):
            raise InputError(f"supports mask has shape {a.shape} for {mesh.n_vertices} vertices")
        return a.copy()
    idx = a.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= mesh.n_vertices):
        raise InputError(f"support index outside 0..{mesh.n_vertices - 1}")
    m = np.zeros(mesh.n_vertices, bool)
    m[idx] = True
    return m


def as_scene(obj: Scene | Network | PolyMesh | str | os.PathLike, *, supports: Any = None,
             up: str | None = None) -> Scene:
    """A :class:`Scene` from a scene, a network, a mesh or a file.

    Parameters
    ----------
    obj
        A :class:`Scene` (``supports`` replaces its own if given); a :class:`Network` (its current
        geometry and supports); a :class:`PolyMesh` (needs ``supports``); or a path read with
        :func:`selfsupport.io.read_scene` (``.sss``, ``.obj``, ``.ply``, ``.off``, ``.json``).
    supports
        ``"boundary"``, a supports file, vertex indices or a boolean mask.
    up
        The file's vertical axis (files only; ``None`` = the format's convention).
    """
    if isinstance(obj, (str, os.PathLike)):
        if supports is None or isinstance(supports, (str, os.PathLike)):
            return read_scene(obj, up=up, supports=None if supports is None else str(supports))
        scene = read_scene(obj, up=up, supports="boundary")  # placeholder, replaced just below
        return replace(scene, supports=_supports_mask(supports, scene.mesh, str(obj)))
    if up is not None:
        raise InputError("up= only applies to files; rotate the mesh yourself for in-memory input")
    if isinstance(obj, Scene):
        if supports is None:
            return obj
        return replace(obj, supports=_supports_mask(supports, obj.mesh, obj.name))
    if isinstance(obj, Network):
        sup = obj.supports if supports is None else _supports_mask(supports, obj.mesh, "network")
        return Scene(mesh=obj.mesh, supports=sup, handles=obj.handles, name="network")
    if isinstance(obj, PolyMesh):
        if supports is None:
            raise InputError("a bare mesh has no supports; pass supports='boundary', a supports file or indices")
        return Scene(mesh=obj, supports=_supports_mask(supports, obj, "mesh"), name="mesh")
    raise InputError(f"cannot make a scene of a {type(obj).__name__}; pass a Scene, Network, PolyMesh or a file path")


#: scene.meta keys of a network file's stored reference and network (see design_of)
_STORED_KEYS = ("reference_vertices", "reference_faces", "stored_network", "stored_result")


def design_of(scene: Scene) -> tuple[Scene, Network | SolveResult | None]:
    """The design a solve of ``scene`` is for, and the network to start it from.

    A network file written by ``selfsupport solve`` stores the reference it was solved for
    (``reference_vertices`` / ``reference_faces``) beside the network. Re-solving the file
    solves for that reference — the design — starting from the stored network; taking the
    network's own vertices as the reference instead would move the target on every re-solve
    and lose the design. Any other scene is its own design and has no start.

    Parameters
    ----------
    scene
        A scene, e.g. from :func:`as_scene` of a ``.json`` file (its ``meta`` then holds what
        the file stored).

    Returns
    -------
    (Scene, Network, SolveResult or None)
        The scene with the stored reference as its mesh (same supports, handles and extras:
        they index the same vertices) and ``meta["design"]`` saying what was used; and the
        stored network with its weights — as a :class:`SolveResult` with the status, method and
        backend of the solve that wrote the file, where it records them (a method can tell its own
        optimum: IPOPT then keeps its barrier low) — or ``None`` when there is nothing to start from (no
        stored reference, or a hand-made file without weights: the solve then starts from
        the reference). A stored reference with another vertex count than the network
        cannot carry its supports: the network's vertices stay the reference, and
        ``meta["design"]["note"]`` says why.
    """
    meta = scene.meta
    if "reference_vertices" not in meta:
        return scene, None
    rest = {k: v for k, v in meta.items() if k not in _STORED_KEYS}
    source = meta.get("source", scene.name)
    ref_v = np.asarray(meta["reference_vertices"], float)
    n = scene.mesh.n_vertices
    if len(ref_v) != n:
        note = (f"{source}: its reference_vertices has {len(ref_v)} vertices and the network {n}, so the "
                "supports cannot be carried over; solving with the network's own vertices as the reference")
        return replace(scene, meta={**rest, "design": {"reference": "stored network", "note": note}}), None
    reference = PolyMesh.from_faces(ref_v, meta["reference_faces"])
    stored = meta.get("stored_network")
    record = meta.get("stored_result")
    if stored is not None and record is not None:
        stored = SolveResult(network=stored, status=record["status"], method=record["method"],
                             backend=record.get("backend", ""), iterations=0, wall_time=0.0,
                             message=f"the network {source} stores")
    design = {"reference": "stored reference_vertices",
              "start": "stored network" if stored is not None else "reference (the file stores no weights)"}
    return replace(scene, mesh=reference, meta={**rest, "design": design}), stored


def load_scene(spec: str, *, supports: Any = None, up: str | None = None) -> Scene:
    """A :class:`~selfsupport.core.scene.Scene` from a ``SCENE`` argument: a file, or a built-in
    shape written ``shape:NAME`` or ``shape:NAME:VERTICES``.

    >>> load_scene("shape:dome:100").mesh.n_vertices
    91
    """
    if spec.startswith("shape:"):
        parts = spec.split(":")
        if len(parts) not in (2, 3) or not parts[1]:
            raise InputError(f"{spec!r}: write a built-in shape as shape:NAME or shape:NAME:VERTICES")
        n = None
        if len(parts) == 3:
            n = parts[2].strip()
            if not n.isdigit() or int(n) < 1:
                raise InputError(f"{spec!r}: vertex count must be a positive integer, got {parts[2]!r}")
            n = int(n)
        if up is not None:
            raise InputError("--up applies to files only; built-in shapes are z up")
        return as_scene(make_shape(parts[1], n_vertices=n), supports=supports)
    if not Path(spec).exists():
        raise InputError(f"{spec}: no such file; give a scene/mesh file or shape:NAME[:VERTICES]")
    return as_scene(spec, supports=supports, up=up)
