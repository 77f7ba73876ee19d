"""A thrust network as a COMPAS mesh: the JSON of ``compas.datastructures.Mesh`` (COMPAS 2.x).

::

    {"dtype": "compas.datastructures/Mesh",
     "data": {"attributes": {...}, "default_vertex_attributes": {...}, "default_edge_attributes": {...},
              "default_face_attributes": {}, "vertex": {"0": {"x": .., "y": .., "z": .., "load": .., "support": ..}},
              "face": {"0": [i, j, k, ...]}, "facedata": {}, "edgedata": {"(i, j)": {"weight": w}},
              "max_vertex": n - 1, "max_face": f - 1},
     "guid": "..."}

``Mesh.from_json`` of COMPAS reads it (Rhino, Grasshopper, compas_tna and the rest of that
ecosystem then have it); the writer needs nothing from COMPAS. Per vertex ``load`` is the signed
vertical load [N] (negative = down) and ``support`` whether it is supported; per edge ``weight``
is the network's force density [N/m] (edge keys ``"(i, j)"`` with ``i < j``, as COMPAS writes
them). z is up. Every other key of the network file (status, evidence, handles, reference, load
cases) goes into the mesh's ``attributes``, so the file reads back to the same network
(:func:`network_document`).
"""
from __future__ import annotations

import uuid
from typing import Any

from selfsupport.io.meshfiles import Source

__all__ = ["COMPAS_MESH_DTYPE", "compas_mesh_data", "is_compas_mesh", "network_document"]

#: The ``dtype`` COMPAS 2.x writes for a mesh.
COMPAS_MESH_DTYPE = "compas.datastructures/Mesh"
#: The network keys that become the mesh's vertices, faces and vertex and edge attributes.
_MESH_KEYS = ("vertices", "faces", "edges", "weights", "loads", "supports")


def compas_mesh_data(doc: dict[str, Any]) -> dict[str, Any]:
    """The COMPAS JSON object (``dtype``, ``data``, ``guid``) of a network document
    (:func:`~selfsupport.io.network_json.network_to_dict`)."""
    supports = set(doc["supports"])
    vertex = {str(i): {"x": x, "y": y, "z": z, "load": load, "support": i in supports}
              for i, ((x, y, z), load) in enumerate(zip(doc["vertices"], doc["loads"]))}
    edgedata = {f"({min(i, j)}, {max(i, j)})": {"weight": w} for (i, j), w in zip(doc["edges"], doc["weights"])}
    data = {
        "attributes": {k: v for k, v in doc.items() if k not in _MESH_KEYS},
        "default_vertex_attributes": {"x": 0.0, "y": 0.0, "z": 0.0, "load": 0.0, "support": False},
        "default_edge_attributes": {"weight": 0.0},
        "default_face_attributes": {},
        "vertex": vertex,
        "face": {str(k): f for k, f in enumerate(doc["faces"])},
        "facedata": {},
        "edgedata": edgedata,
        "max_vertex": len(vertex) - 1,
        "max_face": len(doc["faces"]) - 1,
    }
    return {"dtype": COMPAS_MESH_DTYPE, "data": data, "guid": str(uuid.uuid4())}


def is_compas_mesh(d: Any) -> bool:
    """Whether a parsed JSON document is a COMPAS mesh (``dtype`` ``compas.datastructures/Mesh``)."""
    return isinstance(d, dict) and d.get("dtype") == COMPAS_MESH_DTYPE and isinstance(d.get("data"), dict)


def network_document(src: Source, d: dict[str, Any]) -> dict[str, Any]:
    """The network document (keys of docs/reference/formats.md) of a COMPAS mesh JSON ``d`` read from ``src``.

    Vertex keys are numbered in increasing order (a mesh COMPAS edited may skip some); the
    mesh's attributes come back as the other keys. A mesh without any ``weight`` gives a scene
    (vertices, faces, supports), one with weights the whole network; a vertex or edge without the
    attribute takes the mesh's default.

    Raises
    ------
    InputError
        A key that is not an integer, a face or edge naming a vertex the mesh lacks, a
        coordinate, load or weight that is not a number (edge attributes of edges that are
        not the faces' are ignored, as COMPAS ignores them).
    """
    data = d["data"]
    vertex, face = data.get("vertex"), data.get("face")
    if not isinstance(vertex, dict) or not vertex or not isinstance(face, dict) or not face:
        raise src.error("COMPAS mesh has no vertices or no faces", "give a mesh with both")
    vkeys = _int_keys(src, vertex, "vertex")
    index = {k: i for i, k in enumerate(sorted(vkeys))}
    vdefault = data.get("default_vertex_attributes") or {}
    edefault = data.get("default_edge_attributes") or {}

    def attr(attrs: Any, defaults: dict, name: str, where: str) -> Any:
        value = attrs.get(name, defaults.get(name)) if isinstance(attrs, dict) else None
        if name != "support" and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise src.error(f"COMPAS mesh: {where} has no number {name!r}", f"give every {where.split()[0]} a {name}")
        return value

    rows = sorted((index[k], vertex[s]) for k, s in zip(vkeys, vertex))
    out: dict[str, Any] = {
        "vertices": [[attr(a, vdefault, c, f"vertex {i}") for c in "xyz"] for i, a in rows],
        "faces": [_face(src, index, face[s], k) for k, s in sorted(zip(_int_keys(src, face, "face"), face))],
    }
    out["supports"] = [i for i, a in rows if bool(a.get("support", vdefault.get("support", False)))]
    edgedata = data.get("edgedata") or {}
    if not isinstance(edgedata, dict):
        raise src.error("COMPAS mesh: 'edgedata' is not an object", "write edge attributes as {\"(i, j)\": {...}}")
    if any(isinstance(a, dict) and "weight" in a for a in edgedata.values()) or "weight" in edefault:
        edges = sorted({(min(a, b), max(a, b)) for f in out["faces"] for a, b in zip(f, f[1:] + f[:1])})
        given = {}
        for key, a in edgedata.items():
            i, j = _edge_key(src, key)
            where = f"edge {key}"
            given[tuple(sorted((_vertex(src, index, i, where), _vertex(src, index, j, where))))] = a
        out["edges"] = [list(e) for e in edges]
        out["weights"] = [attr(given.get(e), edefault, "weight", f"edge {e}") for e in edges]
        out["loads"] = [attr(a, vdefault, "load", f"vertex {i}") for i, a in rows]
    attributes = data.get("attributes") or {}
    if isinstance(attributes, dict):
        out.update({k: v for k, v in attributes.items() if k not in _MESH_KEYS})
    return out


def _int_keys(src: Source, d: dict, what: str) -> list[int]:
    try:
        return [int(k) for k in d]
    except ValueError:
        bad = next(k for k in d if not str(k).lstrip("-").isdigit())
        raise src.error(f"COMPAS mesh: {what} key {bad!r} is not an integer", "number vertices and faces") from None


def _vertex(src: Source, index: dict[int, int], key: Any, where: Any) -> int:
    try:
        return index[int(key)]
    except (KeyError, TypeError, ValueError):
        raise src.error(f"COMPAS mesh: {where} names vertex {key!r}, which the mesh does not have",
                        "fix the face or edge") from None


def _face(src: Source, index: dict[int, int], f: Any, k: int) -> list[int]:
    if not isinstance(f, list) or len(f) < 3:
        raise src.error(f"COMPAS mesh: face {k} is not a list of at least 3 vertex keys", "fix the face")
    return [_vertex(src, index, v, f"face {k}") for v in f]


def _edge_key(src: Source, key: str) -> tuple[int, int]:
    try:
        i, j = (int(t) for t in str(key).strip("()").split(","))
    except ValueError:
        raise src.error(f"COMPAS mesh: edge key {key!r} is not '(i, j)'", "write edge keys as COMPAS does") from None
    return i, j
