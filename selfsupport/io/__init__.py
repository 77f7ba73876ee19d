"""Reading and writing scenes, meshes and thrust networks.

Formats are chosen by file suffix through dict registries (:data:`READERS`,
:data:`MESH_WRITERS`):

* ``.sss`` — the original tool's scenes (height = −y, pins, handles, cached loads, weights);
* ``.obj``, ``.ply`` (ASCII / binary), ``.off`` — polygon meshes (faces kept as polygons); the
  file's vertical axis is ``up`` (default ``"z"``; the paper's OBJ files need ``up="-y"``), and
  supports come from ``supports="boundary"`` or a supports file;
* ``.json`` — the project's network format (DESIGN.md §5).

Every reader raises :class:`~selfsupport.errors.InputError` (file, line, what, what to do) on a
broken file and :class:`~selfsupport.errors.MeshError` on an unusable mesh. Every writer
writes atomically (:mod:`.atomic`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError
from ..mesh import PolyMesh
from ..scene import Scene
from .meshfiles import MESH_READERS, MESH_WRITERS, LoadedMesh
from .network_json import network_to_dict, read_json_scene, read_network, write_network
from .sss import read_sss, write_scene_sss
from .supports import resolve_supports

__all__ = ["read_scene", "read_mesh", "write_mesh", "write_scene_sss", "network_to_dict", "write_network",
           "read_network", "NETWORK_SUFFIXES", "network_suffix", "write_network_as"]

#: suffix -> reader ``(path, up) -> LoadedMesh``
READERS: dict[str, Callable[..., LoadedMesh]] = {".sss": read_sss, **MESH_READERS, ".json": read_json_scene}


def _reader(path: Path) -> Callable[..., LoadedMesh]:
    try:
        return READERS[path.suffix.lower()]
    except KeyError:
        raise InputError(f"{path}: unknown file type {path.suffix or '(no suffix)'!r}; "
                         f"readable types are {', '.join(READERS)}") from None


def read_mesh(path: str | Path, *, up: str | None = None) -> PolyMesh:
    """Read the geometry of any supported file (z up, validated).

    Parameters
    ----------
    path
        ``.sss``, ``.obj``, ``.ply``, ``.off`` or ``.json`` file.
    up
        The file's vertical axis (see :mod:`.axes`); ``None`` means the format's own convention
        (``"-y"`` for ``.sss``, ``"z"`` otherwise).
    """
    path = Path(path)
    return _reader(path)(path, up).mesh


def read_scene(path: str | Path, *, up: str | None = None, supports: str | None = None,
               name: str | None = None) -> Scene:
    """Read a scene: mesh, supports, handles.

    Parameters
    ----------
    path
        ``.sss``, ``.obj``, ``.ply``, ``.off`` or ``.json`` file.
    up
        The file's vertical axis; ``None`` = the format's convention.
    supports
        ``None`` keeps the file's own supports (``.sss`` pins, JSON ``supports``) and is an error
        for formats without any; ``"boundary"`` pins every boundary vertex; anything else is a
        supports file (0-based vertex indices, ``#`` comments).
    name
        Scene name for reports (default: the file's stem).

    Raises
    ------
    InputError, MeshError, SupportError
        With the file, line and what to do. Whether the supports hold the mesh up is not
        checked here (the solver does that).
    """
    path = Path(path)
    loaded = _reader(path)(path, up)
    mask = loaded.supports if supports is None else None
    if mask is None:
        mask = resolve_supports(supports, loaded.mesh, source=path)
    meta = {"source": str(path), **loaded.meta}
    if supports is not None:
        meta["supports_from"] = str(supports)
    return Scene(mesh=loaded.mesh, supports=np.asarray(mask, dtype=bool), handles=loaded.handles,
                 name=path.stem if name is None else name, meta=meta)


def write_mesh(path: str | Path, mesh: PolyMesh, *, up: str = "z") -> None:
    """Write a mesh as ``.obj``, ``.ply`` (ASCII) or ``.off``, polygons kept, atomically.

    ``up`` is the vertical axis of the written file (``"-y"`` for the paper's convention).
    """
    path = Path(path)
    try:
        writer = MESH_WRITERS[path.suffix.lower()]
    except KeyError:
        raise InputError(f"{path}: cannot write meshes of type {path.suffix or '(no suffix)'!r}; "
                         f"writable types are {', '.join(MESH_WRITERS)} (scenes: write_scene_sss, "
                         "networks: write_network)") from None
    writer(path, mesh, up=up)


#: Suffixes a network can be written as: the network format, or its geometry alone as a mesh.
NETWORK_SUFFIXES: tuple[str, ...] = (".json", *MESH_WRITERS)


def network_suffix(path: str | Path, what: str = "--out") -> str:
    """The (lower-case) suffix of a network output, checked before any work: ``.json`` (the
    network format) or a mesh suffix of :data:`MESH_WRITERS` (the geometry only); anything else
    raises :class:`InputError` with the list."""
    suffix = Path(path).suffix.lower()
    if suffix not in NETWORK_SUFFIXES:
        raise InputError(f"{what} {path}: cannot write a network as {suffix or '(no suffix)'!r}; give a .json file "
                         f"(the network: weights, loads, supports) or {', '.join(MESH_WRITERS)} (its geometry only)")
    return suffix


def write_network_as(path: str | Path, result_or_network, *, up: str = "z", **extra) -> str:
    """Write a network in the format its suffix names (:func:`network_suffix`): JSON with
    :func:`write_network` (``extra`` keys included), or the network's mesh with :func:`write_mesh`
    (``up`` its vertical axis; weights, loads, supports and ``extra`` are not in a mesh file).
    Returns the suffix written."""
    suffix = network_suffix(path)
    if suffix == ".json":
        write_network(path, result_or_network, **extra)
    else:
        write_mesh(path, getattr(result_or_network, "network", result_or_network).mesh, up=up)
    return suffix
