"""Reading and writing scenes, meshes and thrust networks.

Formats are chosen by file suffix through dict registries (:data:`READERS`,
:data:`MESH_WRITERS`, :data:`NETWORK_FORMATS`):

* ``.sss`` — the original tool's scenes (height = −y, pins, handles, cached loads, weights);
* ``.obj``, ``.ply`` (ASCII / binary), ``.off`` — polygon meshes (faces kept as polygons); the
  file's vertical axis is ``up`` (default ``"z"``; the paper's OBJ files need ``up="-y"``), and
  supports come from ``supports="boundary"`` or a supports file;
* ``.json`` — the project's network format (docs/reference/formats.md), or a COMPAS mesh JSON.

A network is written in any of :data:`NETWORK_FORMATS` (:func:`write_network_as`) and read back
from it to the same network (:func:`read_network`): the JSON network, a COMPAS mesh JSON, PLY
with its weights in an ``edge`` element, OBJ / OFF with side files, ``.sss``.

Every reader raises :class:`~selfsupport.core.errors.InputError` (file, line, what, what to do) on a
broken file and :class:`~selfsupport.core.errors.MeshError` on an unusable mesh. Every writer
writes atomically (:mod:`.atomic`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network
from selfsupport.core.scene import Scene
from selfsupport.io.meshfiles import MESH_READERS, MESH_WRITERS, LoadedMesh
from selfsupport.io.network_files import (
    read_ply_network,
    read_with_side_files,
    side_files,
    write_compas,
    write_ply_network,
    write_with_side_files,
)
from selfsupport.io.network_json import network_to_dict, read_json_scene, write_network
from selfsupport.io.network_json import read_network as read_json_network
from selfsupport.io.sss import read_sss, read_sss_network, write_network_sss, write_scene_sss
from selfsupport.io.supports import resolve_supports

__all__ = ["read_scene", "read_mesh", "write_mesh", "write_scene_sss", "network_to_dict", "write_network",
           "read_network", "NetworkFormat", "NETWORK_FORMATS", "NETWORK_SUFFIXES", "FORMAT_NAMES", "network_suffix",
           "network_outputs", "network_note", "write_network_as"]

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


@dataclass(frozen=True)
class NetworkFormat:
    """A file format a network is written in (:data:`NETWORK_FORMATS`) and read back from.

    ``write(path, result_or_network, *, up, **extra)`` writes it (``up``: the file's vertical axis
    where the format has a choice; ``extra``: keys for status and evidence, where it has a
    place); ``read(path, up)`` reads it back to the same :class:`~selfsupport.core.result.Network`.
    """

    name: str  # the --format name
    summary: str  # what the file is, for --help
    write: Callable[..., None]
    read: Callable[..., Network]
    #: with ``--format``: the suffixes its file may have (default: its own)
    suffixes: tuple[str, ...] = ()
    #: the files written beside it
    side_files: Callable[[Path], tuple[Path, ...]] = lambda path: ()
    #: what the file holds when that is not everything, ``{0}``, ``{1}`` its side files
    holds: str | None = None


def _fixed_axis(write: Callable[..., None]) -> Callable[..., None]:
    """The registry's writer of a format whose vertical axis is fixed (JSON, COMPAS: z up; .sss:
    y down): ``up`` is not its to choose."""

    def write_as(path: str | Path, result_or_network, *, up: str = "z", **extra) -> None:
        write(path, result_or_network, **extra)

    return write_as


#: suffix -> network format; a name is matched by its longest registered suffix (``.compas.json``
#: before ``.json``)
NETWORK_FORMATS: dict[str, NetworkFormat] = {
    ".json": NetworkFormat("json", "the network format (weights, loads, supports, status, evidence)",
                           _fixed_axis(write_network), read_json_network),
    ".compas.json": NetworkFormat("compas", "a COMPAS mesh (edge weight, vertex load and support, "
                                  "the rest as mesh attributes)", _fixed_axis(write_compas), read_json_network,
                                  suffixes=(".json",)),
    ".ply": NetworkFormat("ply", "mesh with vertex load and support and an edge element with weight",
                          write_ply_network, read_ply_network,
                          holds="the network (weights in its edge element, loads and supports as vertex properties)"),
    ".obj": NetworkFormat("obj", "mesh, with NAME.weights.csv and NAME.vertices.csv beside it",
                          write_with_side_files, read_with_side_files, side_files=side_files,
                          holds="the geometry; its weights are in {0}, its loads and supports in {1}"),
    ".off": NetworkFormat("off", "as .obj", write_with_side_files, read_with_side_files, side_files=side_files,
                          holds="the geometry; its weights are in {0}, its loads and supports in {1}"),
    ".sss": NetworkFormat("sss", "the original tool's scene, with the weights", _fixed_axis(write_network_sss),
                          read_sss_network,
                          holds="the network for the original tool (pins = supports, its load column = the "
                                "downward loads, edge records with the weights)"),
}
#: Suffixes a network can be written as.
NETWORK_SUFFIXES: tuple[str, ...] = tuple(NETWORK_FORMATS)
#: ``--format`` name -> suffix of :data:`NETWORK_FORMATS`
FORMAT_NAMES: dict[str, str] = {f.name: suffix for suffix, f in NETWORK_FORMATS.items()}


def _suffix_of(path: str | Path) -> str | None:
    """The longest suffix of :data:`NETWORK_FORMATS` that the file name ends with, or ``None``."""
    name = Path(path).name.lower()
    return max((s for s in NETWORK_FORMATS if name.endswith(s) and len(name) > len(s)), key=len, default=None)


def network_suffix(path: str | Path, what: str = "--out", fmt: str | None = None) -> str:
    """The format (its suffix in :data:`NETWORK_FORMATS`) a network output is written in,
    checked before any work: ``fmt`` (a ``--format`` name) when given, which the file's suffix
    must suit, else the file's own suffix; anything else raises :class:`InputError` saying what
    can be written."""
    suffix = _suffix_of(path)
    if fmt is not None:
        if fmt not in FORMAT_NAMES:
            raise InputError(f"--format {fmt!r}: no such format; give one of {', '.join(FORMAT_NAMES)}")
        want = FORMAT_NAMES[fmt]
        accepted = NETWORK_FORMATS[want].suffixes or (want,)
        if not any(Path(path).name.lower().endswith(s) and Path(path).name.lower() != s for s in accepted):
            raise InputError(f"{what} {path}: --format {fmt} writes {' or '.join(accepted)} files; "
                             f"give a name ending in {accepted[0]}")
        return want
    if suffix is None:
        given = Path(path).suffix.lower()
        raise InputError(f"{what} {path}: cannot write a network as {given or '(no suffix)'!r}; give a file "
                         f"ending in {', '.join(NETWORK_FORMATS)} (.json: the network with its status; see --help "
                         "for what each holds)")
    return suffix


def network_outputs(path: str | Path, fmt: str | None = None) -> list[Path]:
    """Every file a network output writes: ``path`` and its format's side files (for the checks
    before any work, :func:`~selfsupport.io.safety.check_outputs`)."""
    return [Path(path), *NETWORK_FORMATS[network_suffix(path, fmt=fmt)].side_files(Path(path))]


def network_note(path: str | Path, fmt: str | None = None) -> str | None:
    """One line saying what a network output in ``path`` holds when that is not everything
    (which side files hold the rest), or ``None`` (JSON, COMPAS: all of it)."""
    f = NETWORK_FORMATS[network_suffix(path, fmt=fmt)]
    if f.holds is None:
        return None
    return (f"{path} holds " + f.holds.format(*f.side_files(Path(path)))
            + "; status and evidence are written with --out NAME.json")


def write_network_as(path: str | Path, result_or_network, *, up: str = "z", fmt: str | None = None, **extra) -> str:
    """Write a network (or a solve result) in the format ``fmt`` or its suffix names
    (:func:`network_suffix`), with ``extra`` keys where the format has a place for them and
    ``up`` its vertical axis where it has a choice; every file atomically. Returns the format's
    suffix. :func:`read_network` reads it back to the same network."""
    suffix = network_suffix(path, fmt=fmt)
    NETWORK_FORMATS[suffix].write(path, result_or_network, up=up, **extra)
    return suffix


def read_network(path: str | Path, *, up: str | None = None) -> Network:
    """Read a network written in any format of :data:`NETWORK_FORMATS` (a COMPAS mesh JSON is
    told by its content, whatever its name).

    Parameters
    ----------
    path
        The network file (``.json``, ``.compas.json``, ``.ply``, ``.obj`` / ``.off`` with their
        side files, ``.sss``).
    up
        The file's vertical axis where the format has a choice (default ``"z"``).

    Raises
    ------
    InputError, MeshError
        Naming the file (or side file) and what is wrong.
    """
    suffix = _suffix_of(path)
    if suffix is None:
        raise InputError(f"{path}: unknown network file type {Path(path).suffix or '(no suffix)'!r}; "
                         f"readable types are {', '.join(NETWORK_FORMATS)}")
    return NETWORK_FORMATS[suffix].read(path, up)
