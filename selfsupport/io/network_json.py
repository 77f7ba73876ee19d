"""The project's JSON thrust-network format (docs/reference/formats.md).

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

from selfsupport.core.errors import InputError, MeshError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.compas_mesh import is_compas_mesh, network_document
from selfsupport.io.meshfiles import LoadedMesh, Source

__all__ = ["NETWORK_KEYS", "to_jsonable", "network_to_dict", "write_network", "read_network", "read_json_scene",
           "edge_weights", "load_case_entries", "network_from_arrays", "reactions_entry", "read_reactions"]

#: keys every network file has
NETWORK_KEYS = ("vertices", "faces", "edges", "weights", "loads", "supports")


# ---------------------------------------------------------------------------------- writing
def finite_or_none(x: Any) -> float | None:
    """``float(x)`` when that is a finite number, else ``None`` (JSON's null).

    >>> finite_or_none("2.5"), finite_or_none(float("nan")), finite_or_none(None)
    (2.5, None, None)
    """
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


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
        fields["load_cases"] = load_case_entries(result.cases)
    return fields


def load_case_entries(cases: Any) -> list[dict[str, Any]]:
    """The ``load_cases`` key of a network file: per ``(name, network)`` of ``cases``, its weights
    (:func:`edge_weights`), loads and evidence (max relative error, min weight)."""
    return [{"name": name, "weights": edge_weights(net), "loads": np.asarray(net.loads, float),
             "max_relative_error": net.max_relative_error(), "min_weight": net.min_weight(),
             "support_reactions": reactions_entry(net)}
            for name, net in cases]


def reactions_entry(net: Network, *, arrays: bool = False) -> dict[str, Any]:
    """The ``support_reactions`` key of a network file: the force [N] the ground exerts on each
    support (``vertices``, ``forces`` rows in that order; :meth:`Network.support_reactions`) and
    their summary (``total``, ``vertical``, ``max_horizontal`` at ``max_horizontal_vertex``,
    ``thrust``: the sum of the horizontal magnitudes)."""
    R = np.asarray(net.support_reactions(), float)
    s = net.reaction_summary()
    d = {"unit": "N", "vertices": np.flatnonzero(net.supports), "forces": R, "total": s["total"],
         "vertical": s["vertical"], "max_horizontal": s["max_horizontal"],
         "max_horizontal_vertex": s["max_horizontal_vertex"], "thrust": s["thrust"]}
    return d if arrays else to_jsonable(d, "support_reactions")


def read_reactions(path: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """The support reactions a network file stores: ``(vertices, forces (k, 3) [N])``, or ``None``
    for a file written without them (they are recomputed from the network:
    :meth:`Network.support_reactions`).

    Raises
    ------
    InputError
        The key is there but malformed (not the supports' vertices, not one 3-vector per support).
    """
    src = Source(path)
    d = load_json(src)
    net = _network_of(src, d)
    return _reactions(src, d, net.supports)


def _reactions(src: Source, d: dict, supports: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``d["support_reactions"]`` checked against the file's supports, or ``None`` when absent."""
    entry = d.get("support_reactions")
    if entry is None:
        return None
    if not isinstance(entry, dict):
        raise src.error("key 'support_reactions' is not an object", "write {\"vertices\": [...], \"forces\": [[x, y, z], ...]} "
                        "or leave the key out (it is recomputed from the network)")
    fix = "leave the key out (it is recomputed from the network) or fix it"
    try:
        idx = _numbers(src, entry, "vertices", integer=True, width=None)
        forces = _numbers(src, entry, "forces", integer=False, width=3)
    except InputError as e:  # (the message names the inner key: say where it is)
        raise src.error(f"key 'support_reactions': {str(e).split(': ', 1)[-1].split(';')[0]}", fix) from None
    if not np.array_equal(idx, np.flatnonzero(supports)) or len(forces) != len(idx):
        raise src.error("key 'support_reactions' does not list one force per support, in the order of 'supports'", fix)
    return idx, forces


def edge_weights(net: Network) -> np.ndarray:
    """The weights a network file holds, in ``mesh.edges`` order: the network's, with 0 on
    support–support edges (they carry no unknown; docs/reference/formats.md). Every network writer uses it."""
    e = net.mesh.edges
    sup = np.asarray(net.supports, dtype=bool)
    w = np.array(net.weights, dtype=float)
    if w.shape != (len(e),):
        raise ValueError(f"network has {w.size} weights for {len(e)} edges")
    w[sup[e[:, 0]] & sup[e[:, 1]]] = 0.0  # support-support edges carry no unknown (docs/reference/formats.md)
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
    return _document(network, extra, arrays=False)


class _Faces:
    """A mesh's faces in a document that :func:`dumps_network` writes straight from the flat
    arrays (``mesh.faces`` would first build one Python list per face: 0.4 s at 200k)."""

    __slots__ = ("mesh",)

    def __init__(self, mesh: PolyMesh) -> None:
        self.mesh = mesh


def _document(network: Network | SolveResult, extra: dict[str, Any], *, arrays: bool) -> dict[str, Any]:
    """:func:`network_to_dict`; with ``arrays`` the per-vertex and per-edge arrays stay numpy
    arrays and the faces a :class:`_Faces` (only :func:`dumps_network` reads that document:
    it formats them without building millions of Python lists)."""
    result = network if isinstance(network, SolveResult) else None
    net = result.network if result is not None else network
    mesh = net.mesh
    e = mesh.edges
    sup = np.asarray(net.supports, dtype=bool)
    w = edge_weights(net)

    def numbers(a: np.ndarray, where: str) -> Any:
        return a if arrays and a.dtype.kind in "fiu" and a.ndim in (1, 2) else to_jsonable(a, where)

    def faces(m: PolyMesh) -> Any:
        return _Faces(m) if arrays else m.faces

    d: dict[str, Any] = {
        "vertices": numbers(np.asarray(mesh.vertices), "vertices"),
        "faces": faces(mesh),
        "edges": numbers(e, "edges"),
        "weights": numbers(w, "weights"),
        "loads": numbers(np.asarray(net.loads, dtype=float), "loads"),
        "supports": numbers(np.flatnonzero(sup), "supports"),
    }
    d["support_reactions"] = reactions_entry(net, arrays=arrays)
    if net.handles is not None and np.any(net.handles):
        d["handles"] = numbers(np.flatnonzero(np.asarray(net.handles, dtype=bool)), "handles")
    if net.reference is not None:
        d["reference_vertices"] = numbers(np.asarray(net.reference.vertices), "reference_vertices")
        d["reference_faces"] = faces(net.reference)
    if result is not None:
        d.update(to_jsonable(_result_fields(result), "result"))
    for k, v in extra.items():
        if k in d:
            raise ValueError(f"extra key {k!r} would replace the network's own {k!r}; use another name")
        d[k] = to_jsonable(v, k)
    return d


#: The separators of every network file (``json.dumps`` with these writes it byte for byte).
_SEPARATORS = (", ", ": ")


def _json_numbers(a: np.ndarray) -> str:
    """JSON text of a 1-D or 2-D numeric array, byte for byte ``json.dumps(to_jsonable(a),
    separators=(", ", ": "))``: ``float.__repr__`` for each finite float (the shortest text that
    reads back as the same double, as ``json`` writes it), ``null`` for NaN and ±inf, decimal
    integers.

    ``to_jsonable`` + ``json.dumps`` built a Python list per row first (3 s for a 200k-vertex
    network, 70 MB). Here the floats are formatted from one ``tolist()`` and joined in C, and
    the integers (indices: edges, faces, supports) written digit by digit with numpy.

    >>> _json_numbers(np.array([[0.1, -0.0], [np.nan, 1e300]]))
    '[[0.1, -0.0], [null, 1e+300]]'
    >>> _json_numbers(np.array([[0, -12], [345, 6]]))
    '[[0, -12], [345, 6]]'
    """
    if a.ndim == 2 and a.shape[0] and not a.shape[1]:
        return "[" + ", ".join(["[]"] * a.shape[0]) + "]"
    if a.size == 0:
        return "[]"
    k = a.shape[1] if a.ndim == 2 else a.size
    if a.dtype.kind != "f":
        return _json_integers(a.ravel(), np.arange(k - 1, a.size, k) if a.ndim == 2 else None)
    strs = list(map(float.__repr__, a.ravel().tolist()))
    for i in np.flatnonzero(~np.isfinite(a.ravel())).tolist():  # strict JSON has no NaN/Infinity tokens
        strs[i] = "null"
    if a.ndim == 1:
        return "[" + ", ".join(strs) + "]"
    it = iter(strs)
    return "[[" + "], [".join(map(", ".join, zip(*([it] * k)))) + "]]"


#: 10, 100, ..., 10**18: a non-negative int64 x has 1 + searchsorted(_POW10, x, "right") digits
_POW10 = 10 ** np.arange(1, 19, dtype=np.int64)


def _json_integers(x: np.ndarray, row_last: np.ndarray | None) -> str:
    """JSON text of integers ``x``: a flat list, or (``row_last``: the index of each row's last
    element, increasing, the last one ``len(x) - 1``) a list of rows. Built as bytes with numpy,
    one pass per decimal digit: ``int.__repr__`` per number took 0.3 µs each, 0.35 s for the
    1.2 million indices of a 200k-vertex network's edges."""
    n = x.size
    if x.dtype.kind == "u" and n and int(x.max()) > np.iinfo(np.int64).max or (
            x.dtype.kind == "i" and n and int(x.min()) == np.iinfo(np.int64).min):
        body = [str(v) for v in x.tolist()]  # beyond int64's symmetric range (never an index)
        if row_last is None:
            return "[" + ", ".join(body) + "]"
        starts = np.r_[0, row_last[:-1] + 1].tolist()
        return "[" + ", ".join("[" + ", ".join(body[s:e + 1]) + "]" for s, e in zip(starts, row_last.tolist())) + "]"
    v = x.astype(np.int64)
    neg = v < 0
    v = np.abs(v)
    digits = 1 + np.searchsorted(_POW10, v, side="right")
    width = digits + neg
    sep = np.full(n, 2, dtype=np.int64)  # ", " after each number
    open_ = 1 if row_last is None else 2  # "[" or "[["
    if row_last is not None:
        sep[row_last] = 4  # "], [" after a row's last number
    sep[-1] = 0
    end = open_ + np.cumsum(width + sep) - sep  # one past each number's last byte
    buf = np.empty(int(end[-1]) + open_, dtype=np.uint8)
    buf[:open_] = ord("[")
    buf[-open_:] = ord("]")
    pos, rest = end - 1, v
    while pos.size:  # the last digit of every number, then the one before it, ...
        buf[pos] = 48 + rest % 10
        rest = rest // 10
        more = rest > 0
        pos, rest = pos[more] - 1, rest[more]
    buf[(end - width)[neg]] = ord("-")
    comma = end[sep > 0]
    buf[comma] = ord(",")
    buf[comma + 1] = ord(" ")
    if row_last is not None:
        rows = end[sep == 4]
        buf[rows] = ord("]")
        buf[rows + 1] = ord(",")
        buf[rows + 2] = ord(" ")
        buf[rows + 3] = ord("[")
    return buf.tobytes().decode("ascii")


def _json_faces(mesh: PolyMesh) -> str:
    """JSON text of ``mesh.faces`` (byte for byte ``json.dumps(mesh.faces, ...)``), from the flat
    face arrays."""
    fo = mesh.face_offsets
    if fo.size < 2:
        return "[]"
    return _json_integers(np.asarray(mesh.face_vertices), np.asarray(fo[1:], dtype=np.int64) - 1)


def _json_value(v: Any) -> str:
    """JSON text of one value of a document: numpy arrays and :class:`_Faces` on the fast path,
    dicts and lists holding them element by element, everything else by ``json.dumps``."""
    if isinstance(v, np.ndarray) and v.dtype.kind in "fiu" and v.ndim in (1, 2):
        return _json_numbers(v)
    if isinstance(v, _Faces):
        return _json_faces(v.mesh)
    if isinstance(v, dict) and any(isinstance(x, (np.ndarray, _Faces, dict, list)) for x in v.values()):
        return "{" + ", ".join(f"{json.dumps(str(k))}: {_json_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list) and any(isinstance(x, (np.ndarray, _Faces)) for x in v):
        return "[" + ", ".join(_json_value(x) for x in v) + "]"
    if isinstance(v, (np.ndarray, np.generic)):
        v = to_jsonable(v)
    return json.dumps(v, allow_nan=False, separators=_SEPARATORS)


def dumps_network(d: dict[str, Any]) -> str:
    """One top-level key per line: diff-friendly and still compact for large meshes.

    ``d`` is a :func:`network_to_dict` document; numpy arrays in it (1-D or 2-D, numeric) are
    written as the lists they stand for, so the writer can skip building those lists. The text
    is strict JSON and every float reads back as the same double (``float.__repr__``)."""
    items = [f"{json.dumps(k)}: {_json_value(v)}" for k, v in d.items()]
    return "{\n" + ",\n".join(items) + "\n}\n"


def write_network(path: str | Path, result_or_network: Network | SolveResult, **extra: Any) -> None:
    """Write a network (or a solve result) as JSON, atomically; see :func:`network_to_dict`
    (the file holds exactly that document, written from the arrays without the lists)."""
    atomic_write_text(path, dumps_network(_document(result_or_network, extra, arrays=True)))


# ---------------------------------------------------------------------------------- reading
def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not valid JSON")


def load_json(src: Source) -> dict[str, Any]:
    """The JSON object of ``src``: a network document, or the one a COMPAS mesh JSON holds
    (:func:`~selfsupport.io.compas_mesh.network_document`)."""
    text = src.read_text()
    try:
        d = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as e:
        raise src.error(f"is not valid JSON ({e.msg}, column {e.colno})", "fix the syntax", e.lineno) from None
    except ValueError as e:
        raise src.error(f"contains {e}", "write non-finite numbers as null or fix them") from None
    except RecursionError:  # (json's parser recurses once per level: 100k nested brackets exhaust the stack)
        raise src.error("nests its values deeper than the JSON reader can follow",
                        "a network file is an object of flat arrays; fix the file") from None
    if not isinstance(d, dict):
        raise src.error(f"holds a JSON {type(d).__name__}, not an object", "a network file is a JSON object "
                        "with vertices, faces, edges, weights, loads, supports")

    return network_document(src, d) if is_compas_mesh(d) else d  # a COMPAS mesh reads as the network it holds


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


def _z_up(src: Source, up: str | None) -> None:
    if up not in (None, "z"):
        raise InputError(f"{src.path}: JSON networks are z up by definition, got up={up!r}; leave --up out")


def read_network(path: str | Path, up: str | None = None) -> Network:
    """Read a network file back into a :class:`Network` (weights in ``mesh.edges`` order);
    ``up`` may only be ``None`` or ``"z"`` (JSON networks are z up).

    Raises
    ------
    InputError
        Missing key, wrong type, length mismatch, index out of range, edges that are not
        exactly the faces' edges (the message names the file and the key).
    MeshError
        The faces do not form a usable mesh.
    """
    src = Source(path)
    _z_up(src, up)
    return _network_of(src, load_json(src))


def _loads(src: Source, d: dict) -> np.ndarray:
    """``d["loads"]``: signed vertical loads ``(n,)``, or load vectors ``(n, 3)`` (horizontal loads)."""
    value = d.get("loads")
    if isinstance(value, list) and value and isinstance(value[0], list):
        return _numbers(src, d, "loads", integer=False, width=3)
    return _numbers(src, d, "loads", integer=False, width=None)


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
    w = _numbers(src, d, "weights", integer=False, width=None)
    loads = _loads(src, d)
    supports = _mask(src, d, "supports", n)
    if supports is None:
        raise src.error("missing key 'supports'", f"a network file needs {', '.join(NETWORK_KEYS)}")
    handles = _mask(src, d, "handles", n)
    ref_v, ref_f = _reference(src, d, faces)
    reference = None if ref_v is None else PolyMesh.from_faces(ref_v, ref_f)
    _reactions(src, d, supports)
    return network_from_arrays(src, mesh, e, w, loads, supports, handles=handles, reference=reference)


def network_from_arrays(src: Source, mesh: PolyMesh, edges: np.ndarray, weights: np.ndarray, loads: np.ndarray,
                        supports: np.ndarray, *, handles: np.ndarray | None = None,
                        reference: PolyMesh | None = None, edges_key: str = "key 'edges'",
                        weights_key: str = "key 'weights'", loads_key: str = "key 'loads'") -> Network:
    """A :class:`Network` from what a network file of any format holds, checked as one network:
    one weight per listed edge, the edges exactly the faces' edges (each once, in any order and
    direction; the weights are reordered into ``mesh.edges`` order), one load per vertex.

    ``src`` names the file in the messages, ``edges_key`` / ``weights_key`` / ``loads_key`` the
    place in it (a JSON key, a side file's rows, a PLY element).

    Raises
    ------
    InputError
        Naming the file and the place: a length mismatch, an index out of range, an edge listed
        twice, joining a vertex to itself, or not an edge of the faces.
    """
    n = mesh.n_vertices
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = np.asarray(weights, dtype=float)
    loads = np.asarray(loads, dtype=float)
    if e.size and (e.min() < 0 or e.max() >= n):
        bad = int(e.min()) if e.min() < 0 else int(e.max())
        raise src.error(f"{edges_key} refers to index {bad}, outside the {n} vertices", "fix the index")
    if len(w) != len(e):
        raise src.error(f"{weights_key} has {len(w)} entries for {len(e)} edges", "write one weight per edge")
    if len(loads) != n:
        raise src.error(f"{loads_key} has {len(loads)} entries for {n} vertices", "write one signed load per vertex")

    # edges must be the faces' edges, each once; weights are reordered into mesh.edges order
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    if np.any(lo == hi):
        k = int(np.argmax(lo == hi))
        raise src.error(f"{edges_key}: edge {k} joins vertex {int(lo[k])} to itself", "remove it")
    key = lo * (n + 1) + hi
    order = np.argsort(key, kind="stable")
    skey = key[order]
    dup = np.flatnonzero(skey[1:] == skey[:-1])
    if dup.size:
        k = int(order[dup[0] + 1])
        raise src.error(f"{edges_key}: edge ({int(lo[k])}, {int(hi[k])}) is listed twice", "list every edge once")
    me = mesh.edges
    mkey = me[:, 0] * (n + 1) + me[:, 1]
    if len(skey) != len(mkey) or not np.array_equal(skey, mkey):
        extra = np.setdiff1d(skey, mkey)
        missing = np.setdiff1d(mkey, skey)
        if extra.size:
            a, b = divmod(int(extra[0]), n + 1)
            raise src.error(f"{edges_key}: ({a}, {b}) is not an edge of the faces", "list exactly the faces' edges")
        a, b = divmod(int(missing[0]), n + 1)
        raise src.error(f"{edges_key} lacks the faces' edge ({a}, {b}) ({len(missing)} missing)",
                        "list every edge of the faces")
    return Network(mesh=mesh, weights=w[order], loads=loads, supports=supports, reference=reference, handles=handles)


def read_json_scene(path: str | Path, up: str | None = None) -> LoadedMesh:
    """A network file (or a hand-made ``{"vertices", "faces", "supports"}``) as scene input.

    The mesh is built from ``vertices`` (``check`` judges the geometry as it is stored);
    ``reference_vertices`` / ``reference_faces`` are kept in ``meta``, and so is the whole network
    (``meta["stored_network"]``, weights included) when the file is one, with the status,
    method and backend of the solve that wrote it (``meta["stored_result"]``): a solve takes the
    stored reference as its design and starts from the stored network
    (:func:`selfsupport.api.design_of`). A file with ``weights`` or ``edges`` must be a complete,
    consistent network (:func:`read_network`'s errors otherwise).
    """
    src = Source(path)
    _z_up(src, up)
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
        record = {k: d[k] for k in ("status", "method", "backend") if isinstance(d.get(k), str)}
        if {"status", "method"} <= record.keys():  # (a solve wrote it: what its result was)
            meta["stored_result"] = record
    return LoadedMesh(mesh, supports=_mask(src, d, "supports", len(v)), handles=_mask(src, d, "handles", len(v)),
                      meta=meta)
