"""The project's JSON thrust-network format (DESIGN.md §5).

::

    {"vertices": [[x, y, z], ...], "faces": [[i, j, k, ...], ...], "edges": [[i, j], ...],
     "weights": [w, ...], "loads": [A_i F_i, ...], "supports": [i, ...], ...}

z up, SI units; ``edges`` lists every mesh edge (``mesh.edges`` order when we write it),
``weights`` one per edge (0 on support–support edges, which carry no unknown), ``loads``
signed (negative = down) for every vertex, supports included. Beside these: ``handles``,
``reference_vertices`` / ``reference_faces`` and, for a solve, its status and evidence.

The file is strict JSON (no NaN/Infinity tokens): non-finite floats are written as ``null``.
It is read by ``../shared/tools/check_network.py`` without anything from this project.
"""
from __future__ import annotations

import dataclasses
import enum
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, MeshError
from ..mesh import PolyMesh
from ..result import Network, SolveResult
from .atomic import atomic_write_text
from .meshfiles import LoadedMesh, Source

__all__ = ["NETWORK_KEYS", "to_jsonable", "network_to_dict", "write_network", "read_network", "read_json_scene"]

#: keys every network file has
NETWORK_KEYS = ("vertices", "faces", "edges", "weights", "loads", "supports")


# ---------------------------------------------------------------------------------- writing
def to_jsonable(obj: Any, where: str = "value") -> Any:
    """Plain JSON types for ``obj``: numpy scalars/arrays become numbers/lists, tuples lists,
    non-finite floats ``None``; dataclasses become dicts, enums their value, paths strings.

    Raises
    ------
    TypeError
        For anything else, naming ``where`` (the key path) so the caller knows what to fix.
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (int, np.integer)) and not isinstance(obj, np.bool_):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind in "iub":
            return obj.tolist()
        if obj.dtype.kind == "f" and np.isfinite(obj).all():
            return obj.tolist()  # the common case: no per-element work
        return [to_jsonable(x, f"{where}[{k}]") for k, x in enumerate(obj)]
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(x, f"{where}[{k}]") for k, x in enumerate(obj)]
    if isinstance(obj, (set, frozenset)):
        return [to_jsonable(x, f"{where}[{k}]") for k, x in enumerate(sorted(obj, key=repr))]
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, f"{where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value, where)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name), f"{where}.{f.name}") for f in dataclasses.fields(obj)}
    raise TypeError(f"cannot write {where} (a {type(obj).__name__}) to JSON; pass numbers, strings, lists or dicts")


def _result_fields(result: SolveResult) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "status": result.status,
        "method": result.method,
        "backend": result.backend,
        "iterations": result.iterations,
        "wall_time": result.wall_time,
        "max_relative_error": result.max_relative_error,
        "min_weight": result.min_weight,
        "distance_to_reference": {"mean": result.distance_mean, "max": result.distance_max},
        "parameters": result.parameters,
        "history": list(result.history),
    }
    if result.message:
        fields["message"] = result.message
    if result.terms:
        fields["objective_terms"] = dict(result.terms)
    if result.cases:  # one weight vector (and load vector) per load case, each with its own evidence
        fields["load_cases"] = [{"name": name, "weights": _edge_weights(net), "loads": np.asarray(net.loads, float),
                                 "max_relative_error": net.max_relative_error(), "min_weight": net.min_weight()}
                                for name, net in result.cases]
    return fields


def _edge_weights(net: Network) -> np.ndarray:
    e = net.mesh.edges
    sup = np.asarray(net.supports, dtype=bool)
    w = np.array(net.weights, dtype=float)
    if w.shape != (len(e),):
        raise ValueError(f"network has {w.size} weights for {len(e)} edges")
    w[sup[e[:, 0]] & sup[e[:, 1]]] = 0.0  # support-support edges carry no unknown (DESIGN.md §5)
    return w


def network_to_dict(network: Network | SolveResult, **extra: Any) -> dict[str, Any]:
    """The JSON document of a network (or of a solve result, which adds its status and evidence).

    Parameters
    ----------
    network
        A :class:`Network`, or a :class:`SolveResult` (then ``status``, ``method``, ``backend``,
        ``iterations``, ``wall_time``, ``max_relative_error``, ``min_weight``,
        ``distance_to_reference``, ``parameters``, ``history`` are added).
    **extra
        More top-level keys (converted with :func:`to_jsonable`); they may not replace a key
        written from the network or result.

    Returns
    -------
    dict
        Plain JSON types only (non-finite floats as ``None``).
    """
    result = network if isinstance(network, SolveResult) else None
    net = result.network if result is not None else network
    mesh = net.mesh
    e = mesh.edges
    sup = np.asarray(net.supports, dtype=bool)
    w = _edge_weights(net)
    d: dict[str, Any] = {
        "vertices": to_jsonable(mesh.vertices, "vertices"),
        "faces": mesh.faces,
        "edges": e.tolist(),
        "weights": to_jsonable(w, "weights"),
        "loads": to_jsonable(np.asarray(net.loads, dtype=float), "loads"),
        "supports": np.flatnonzero(sup).tolist(),
    }
    if net.handles is not None and np.any(net.handles):
        d["handles"] = np.flatnonzero(np.asarray(net.handles, dtype=bool)).tolist()
    if net.reference is not None:
        d["reference_vertices"] = to_jsonable(net.reference.vertices, "reference_vertices")
        d["reference_faces"] = net.reference.faces
    if result is not None:
        d.update(to_jsonable(_result_fields(result), "result"))
    for k, v in extra.items():
        if k in d:
            raise ValueError(f"extra key {k!r} would replace the network's own {k!r}; use another name")
        d[k] = to_jsonable(v, k)
    return d


def dumps_network(d: dict[str, Any]) -> str:
    """One top-level key per line: diff-friendly and still compact for large meshes."""
    items = [f"{json.dumps(k)}: {json.dumps(v, allow_nan=False, separators=(', ', ': '))}" for k, v in d.items()]
    return "{\n" + ",\n".join(items) + "\n}\n"


def write_network(path: str | Path, result_or_network: Network | SolveResult, **extra: Any) -> None:
    """Write a network (or a solve result) as JSON, atomically; see :func:`network_to_dict`."""
    atomic_write_text(path, dumps_network(network_to_dict(result_or_network, **extra)))


# ---------------------------------------------------------------------------------- reading
def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not valid JSON")


def load_json(src: Source) -> dict[str, Any]:
    text = src.read_text()
    try:
        d = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as e:
        raise src.error(f"is not valid JSON ({e.msg}, column {e.colno})", "fix the syntax", e.lineno) from None
    except ValueError as e:
        raise src.error(f"contains {e}", "write non-finite numbers as null or fix them") from None
    if not isinstance(d, dict):
        raise src.error(f"holds a JSON {type(d).__name__}, not an object", "a network file is a JSON object "
                        "with vertices, faces, edges, weights, loads, supports")
    return d


_KIND_NAMES = {"U": "a string", "S": "a string", "O": "null or mixed values", "b": "true/false", "c": "a complex number"}


def _numbers(src: Source, d: dict, key: str, *, integer: bool, width: int | None) -> np.ndarray:
    """``d[key]`` as a numeric array of shape ``(k,)`` or ``(k, width)``, strictly typed."""
    if key not in d:
        raise src.error(f"missing key {key!r}", f"a network file needs {', '.join(NETWORK_KEYS)}")
    value = d[key]
    shape = "a list of numbers" if width is None else f"a list of [{', '.join('xyz'[:width] if width == 3 else 'ij')}] lists"
    if not isinstance(value, list):
        raise src.error(f"key {key!r} is a JSON {type(value).__name__}, not a list", f"write {shape}")
    if any(isinstance(x, bool) for x in (value if width is None else (y for row in value if isinstance(row, list) for y in row))):
        # numpy would silently read true/false as 1/0 among numbers
        raise src.error(f"key {key!r} contains true/false where {'integers' if integer else 'numbers'} are expected",
                        f"write {shape}")
    try:
        a = np.asarray(value)
    except (ValueError, OverflowError):
        raise src.error(f"key {key!r} has rows of different lengths", f"write {shape}") from None
    if a.size == 0:
        a = np.zeros((0,) if width is None else (0, width), dtype=np.int64 if integer else float)
    if a.dtype.kind not in ("iu" if integer else "iuf"):
        what = "a non-integer number" if integer and a.dtype.kind == "f" else _KIND_NAMES.get(a.dtype.kind, a.dtype.kind)
        raise src.error(f"key {key!r} contains {what} where {'integers' if integer else 'numbers'} are expected",
                        f"write {shape}")
    want_ndim = 1 if width is None else 2
    if a.ndim != want_ndim or (width is not None and a.shape[1] != width):
        raise src.error(f"key {key!r} has shape {a.shape}", f"write {shape}")
    if not integer:
        a = a.astype(float)
        if not np.isfinite(a).all():
            raise src.error(f"key {key!r} has a non-finite number", "fix it")
    return a.astype(np.int64) if integer else a


def _check_range(src: Source, key: str, idx: np.ndarray, n: int, what: str = "vertices") -> None:
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        bad = int(idx.min()) if idx.min() < 0 else int(idx.max())
        raise src.error(f"key {key!r} refers to index {bad}, outside the {n} {what}", "fix the index")


def _faces(src: Source, d: dict, key: str, n: int) -> list[list[int]]:
    if key not in d:
        raise src.error(f"missing key {key!r}", f"a network file needs {', '.join(NETWORK_KEYS)}")
    faces = d[key]
    if not isinstance(faces, list) or not faces:
        raise src.error(f"key {key!r} must be a non-empty list of faces", "write [[i, j, k, ...], ...]")
    for k, f in enumerate(faces):
        if not isinstance(f, list) or not all(type(i) is int for i in f):
            raise src.error(f"key {key!r}: face {k} is not a list of integers", "write [[i, j, k, ...], ...]")
        if len(f) < 3:
            raise src.error(f"key {key!r}: face {k} has {len(f)} corners", "a face needs at least 3 vertex indices")
        if min(f) < 0 or max(f) >= n:
            raise src.error(f"key {key!r}: face {k} refers to a vertex outside the {n} vertices", "fix the index")
    return faces


def _mesh(src: Source, vertices: np.ndarray, faces: list[list[int]]) -> PolyMesh:
    if len(vertices) == 0:
        raise src.error("key 'vertices' is empty", "a network needs vertices")
    try:
        return PolyMesh.from_faces(vertices, faces).validate()
    except MeshError as e:
        raise src.error(str(e), cls=MeshError) from None


def _mask(src: Source, d: dict, key: str, n: int) -> np.ndarray | None:
    if key not in d:
        return None
    idx = _numbers(src, d, key, integer=True, width=None)
    _check_range(src, key, idx, n)
    m = np.zeros(n, dtype=bool)
    m[idx] = True
    return m


def _reference(src: Source, d: dict, faces: list[list[int]]) -> tuple[np.ndarray | None, list[list[int]] | None]:
    if "reference_vertices" not in d:
        return None, None
    rv = _numbers(src, d, "reference_vertices", integer=False, width=3)
    rf = _faces(src, d, "reference_faces", len(rv)) if "reference_faces" in d else faces
    if "reference_faces" not in d:
        _check_range(src, "reference_vertices", np.fromiter((i for f in faces for i in f), dtype=np.int64), len(rv))
    return rv, rf


def read_network(path: str | Path) -> Network:
    """Read a network file back into a :class:`Network` (weights in ``mesh.edges`` order).

    Raises
    ------
    InputError
        Missing key, wrong type, length mismatch, index out of range, edges that are not
        exactly the faces' edges (the message names the file and the key).
    MeshError
        The faces do not form a usable mesh.
    """
    src = Source(path)
    return _network_of(src, load_json(src))


def _is_network(d: dict) -> bool:
    """A solved network, not a hand-made ``{"vertices", "faces", "supports"}`` scene."""
    return "weights" in d or "edges" in d


def _network_of(src: Source, d: dict) -> Network:
    """The :class:`Network` of the parsed document ``d`` of ``src`` (see :func:`read_network`)."""
    v = _numbers(src, d, "vertices", integer=False, width=3)
    n = len(v)
    faces = _faces(src, d, "faces", n)
    mesh = _mesh(src, v, faces)
    e = _numbers(src, d, "edges", integer=True, width=2)
    _check_range(src, "edges", e, n)
    w = _numbers(src, d, "weights", integer=False, width=None)
    if len(w) != len(e):
        raise src.error(f"key 'weights' has {len(w)} entries for {len(e)} edges", "write one weight per edge")
    loads = _numbers(src, d, "loads", integer=False, width=None)
    if len(loads) != n:
        raise src.error(f"key 'loads' has {len(loads)} entries for {n} vertices", "write one signed load per vertex")
    supports = _mask(src, d, "supports", n)
    if supports is None:
        raise src.error("missing key 'supports'", f"a network file needs {', '.join(NETWORK_KEYS)}")
    handles = _mask(src, d, "handles", n)

    # edges must be the faces' edges, each once; weights are reordered into mesh.edges order
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    if np.any(lo == hi):
        k = int(np.argmax(lo == hi))
        raise src.error(f"key 'edges': edge {k} joins vertex {int(lo[k])} to itself", "remove it")
    key = lo * (n + 1) + hi
    order = np.argsort(key, kind="stable")
    skey = key[order]
    dup = np.flatnonzero(skey[1:] == skey[:-1])
    if dup.size:
        k = int(order[dup[0] + 1])
        raise src.error(f"key 'edges': edge ({int(lo[k])}, {int(hi[k])}) is listed twice", "list every edge once")
    me = mesh.edges
    mkey = me[:, 0] * (n + 1) + me[:, 1]
    if len(skey) != len(mkey) or not np.array_equal(skey, mkey):
        extra = np.setdiff1d(skey, mkey)
        missing = np.setdiff1d(mkey, skey)
        if extra.size:
            a, b = divmod(int(extra[0]), n + 1)
            raise src.error(f"key 'edges': ({a}, {b}) is not an edge of the faces", "list exactly the faces' edges")
        a, b = divmod(int(missing[0]), n + 1)
        raise src.error(f"key 'edges' lacks the faces' edge ({a}, {b}) ({len(missing)} missing)",
                        "list every edge of the faces")
    ref_v, ref_f = _reference(src, d, faces)
    reference = None if ref_v is None else PolyMesh.from_faces(ref_v, ref_f)
    return Network(mesh=mesh, weights=w[order], loads=loads, supports=supports, reference=reference, handles=handles)


def read_json_scene(path: str | Path, up: str | None = None) -> LoadedMesh:
    """A network file (or a hand-made ``{"vertices", "faces", "supports"}``) as scene input.

    The mesh is built from ``vertices`` (``check`` judges the geometry as it is stored);
    ``reference_vertices`` / ``reference_faces`` are kept in ``meta``, and so is the whole network
    (``meta["stored_network"]``, weights included) when the file is one: a solve takes the
    stored reference as its design and starts from the stored network
    (:func:`selfsupport.api.design_of`). A file with ``weights`` or ``edges`` must be a complete,
    consistent network (:func:`read_network`'s errors otherwise).
    """
    src = Source(path)
    if up not in (None, "z"):
        raise InputError(f"{src.path}: JSON networks are z up by definition, got up={up!r}; leave --up out")
    d = load_json(src)
    v = _numbers(src, d, "vertices", integer=False, width=3)
    faces = _faces(src, d, "faces", len(v))
    mesh = _mesh(src, v, faces)
    meta: dict[str, Any] = {"format": "json", "up": "z"}
    ref_v, ref_f = _reference(src, d, faces)
    if ref_v is not None:
        meta["reference_vertices"] = ref_v
        meta["reference_faces"] = ref_f
    if _is_network(d):
        meta["stored_network"] = _network_of(src, d)
    return LoadedMesh(mesh, supports=_mask(src, d, "supports", len(v)), handles=_mask(src, d, "handles", len(v)),
                      meta=meta)
