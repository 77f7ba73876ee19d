"""Polygon mesh files: OBJ, PLY (ASCII, binary little/big endian) and OFF.

Small parsers of our own, because trimesh triangulates quads on every load path and the
thrust network lives on the polygon edges. Every reader

* keeps polygons as polygons,
* reports a broken file with an :class:`~selfsupport.core.errors.InputError` naming the file, the
  line (where there is one), what is wrong and what to do,
* maps the file's vertical axis (``up``, see :mod:`.axes`) to z up and validates the mesh
  (:meth:`PolyMesh.validate`, re-raised with the file name).

The common pieces (:class:`Source`, :class:`RawMesh`, :func:`finish_mesh`) are shared with the
``.sss`` and JSON readers.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from selfsupport.core.errors import InputError, MeshError
from selfsupport.core.mesh import PolyMesh
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.axes import rotation

__all__ = ["Source", "RawMesh", "LoadedMesh", "finish_mesh", "read_obj", "read_ply", "read_ply_elements", "read_off",
           "write_obj", "write_ply", "write_off"]


# ---------------------------------------------------------------------------------- shared
class Source:
    """A file being read: loads it and builds error messages that name it."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def error(self, what: str, fix: str = "", line: int | None = None, cls: type[InputError] = InputError) -> InputError:
        where = f"{self.path}:{line}" if line is not None else f"{self.path}"
        return cls(f"{where}: {what}" + (f"; {fix}" if fix else ""))

    def read_bytes(self) -> bytes:
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            raise self.error("no such file", "check the path") from None
        except IsADirectoryError:
            raise self.error("is a directory, not a file", "give the path of a mesh or scene file") from None
        except OSError as e:
            raise self.error(f"cannot be read ({e.strerror or e})", "check the path and permissions") from e
        if not data.strip():
            raise self.error("the file is empty", "give a file that contains a mesh")
        return data

    def read_text(self) -> str:
        data = self.read_bytes()
        try:
            return data.decode("utf-8-sig")  # a leading byte-order mark is not content
        except UnicodeDecodeError as e:
            line = data[:e.start].count(b"\n") + 1
            raise self.error("is not a UTF-8 text file (undecodable byte)", "check the file format and suffix",
                             line) from None


#: Fewest bytes a record of a text mesh file can take: ``0 0 0`` and a newline per vertex, ``3 0 1 2``
#: and a newline per face. Header counts are checked against the file's size with these before
#: anything of their size is allocated (an OFF header claiming 2e9 vertices ended in MemoryError).
MIN_VERTEX_BYTES, MIN_FACE_BYTES = 6, 8


def check_declared_counts(src: Source, declared: list[tuple[str, int, int]], size: int, line: int | None = None) -> None:
    """Refuse a header count the file is too small to hold: ``declared`` is (what, count, fewest
    bytes per record) per kind of record, ``size`` the file's bytes. Each count is checked on its
    own, which bounds every allocation by the file's size; a file a few records short is left to
    the parser, which says where it ends."""
    for what, count, per in declared:
        if count * per > size:
            raise src.error(f"the header declares {count:,} {what}, which need at least {count * per:,} bytes, but "
                            f"the file has {size:,}", "the counts are wrong or the file is truncated; fix the header",
                            line)


@dataclass
class RawMesh:
    """What a parser found, in file coordinates, before axis mapping and validation.

    ``vertex_lines`` / ``face_lines`` give the source line of each record (for messages),
    or are ``None`` for binary files.
    """

    vertices: np.ndarray
    face_vertices: np.ndarray
    face_offsets: np.ndarray
    vertex_lines: np.ndarray | None = None
    face_lines: np.ndarray | None = None
    index_base: int = 0  # how the file numbers vertices (OBJ: 1), for messages only


@dataclass(frozen=True)
class LoadedMesh:
    """A reader's result: the mesh (z up) and whatever else the file says about the scene."""

    mesh: PolyMesh
    supports: np.ndarray | None = None  # bool mask from the file's own pins (.sss, .json)
    handles: np.ndarray | None = None
    meta: dict = field(default_factory=dict)


def finish_mesh(raw: RawMesh, src: Source, up: str) -> PolyMesh:
    """Check coordinates and indices, rotate to z up, build and validate the mesh."""
    v = np.asarray(raw.vertices, dtype=float).reshape(-1, 3)
    if v.shape[0] == 0:
        raise src.error("contains no vertices", "give a file that contains a mesh")
    if len(raw.face_offsets) < 2:
        raise src.error("contains no faces", "the thrust network lives on the faces' edges: give a polygon mesh, "
                        "not a point cloud")
    finite = np.isfinite(v).all(axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        line = int(raw.vertex_lines[k]) if raw.vertex_lines is not None else None
        raise src.error(f"vertex {k} has a NaN or infinite coordinate", "fix or remove that vertex", line)
    fv = np.asarray(raw.face_vertices, dtype=np.int64)
    fo = np.asarray(raw.face_offsets, dtype=np.int64)
    n = v.shape[0]
    bad = (fv < 0) | (fv >= n)
    if bad.any():
        f = int(np.searchsorted(fo, int(np.argmax(bad)), side="right") - 1)
        line = int(raw.face_lines[f]) if raw.face_lines is not None else None
        b = raw.index_base
        raise src.error(f"face {f} refers to vertex index {int(fv[np.argmax(bad)]) + b}, outside {b}..{n - 1 + b} "
                        f"(the file has {n} vertices)", "fix the face or add the missing vertices", line)
    mesh = PolyMesh(v @ rotation(up).T, fv, fo)
    try:
        return mesh.validate()
    except MeshError as e:
        raise src.error(str(e), cls=MeshError) from None


def faces_to_csr(faces: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    sizes = np.fromiter((len(f) for f in faces), dtype=np.int64, count=len(faces))
    offsets = np.zeros(len(faces) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    flat = np.fromiter((i for f in faces for i in f), dtype=np.int64, count=int(offsets[-1]))
    return flat, offsets


def strip_comment(line: str) -> str:
    return line.partition("#")[0] if "#" in line else line


def _fmt(x: float) -> str:
    # repr is the shortest string that reads back to the same double: exact round trips
    return repr(float(x))


# ---------------------------------------------------------------------------------- OBJ
#: OBJ records that carry nothing a thrust network needs; everything else unknown is an error.
_OBJ_IGNORED = frozenset({"vt", "vn", "vp", "g", "o", "s", "usemtl", "mtllib", "l"})


def read_obj(path: str | Path, up: str | None = None) -> LoadedMesh:
    """Read a Wavefront OBJ, keeping polygon faces.

    Handles ``v x y z [w]`` (and ``v x y z r g b`` vertex colours), ``f`` with ``a``, ``a/b``,
    ``a/b/c``, ``a//c`` index forms and negative (relative) indices; ignores ``vt vn vp g o s
    usemtl mtllib l`` and comments. ``up`` is the file's vertical axis (default ``"z"``).
    """
    src = Source(path)
    up = "z" if up is None else up
    rotation(up)
    text = src.read_text()
    verts: list[list[float]] = []
    vlines: list[int] = []
    faces: list[list[int]] = []
    flines: list[int] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = strip_comment(line).split()
        if not tok:
            continue
        kind = tok[0]
        if kind == "v":
            if len(tok) not in (4, 5, 7):
                raise src.error(f"vertex record has {len(tok) - 1} numbers",
                                "write 'v x y z' (optionally 'v x y z w' or 'v x y z r g b')", lineno)
            try:
                xyz = [float(tok[1]), float(tok[2]), float(tok[3])]
                if len(tok) == 5:
                    w = float(tok[4])
                    if w == 0.0 or not np.isfinite(w):
                        raise src.error(f"vertex weight w={tok[4]} cannot be divided by", "use w = 1", lineno)
                    xyz = [c / w for c in xyz]
            except ValueError:
                raise src.error(f"vertex record has a non-numeric coordinate: {line.strip()!r}",
                                "write 'v x y z' with decimal numbers", lineno) from None
            verts.append(xyz)
            vlines.append(lineno)
        elif kind == "f":
            if len(tok) < 4:
                raise src.error(f"face record has {len(tok) - 1} corners", "a face needs at least 3 vertex indices",
                                lineno)
            nv = len(verts)
            face = []
            for t in tok[1:]:
                try:
                    i = int(t.split("/", 1)[0])
                except ValueError:
                    raise src.error(f"face index {t!r} is not an integer", "write 'f i j k ...' with 1-based indices",
                                    lineno) from None
                if i > 0:
                    face.append(i - 1)
                elif i < 0:
                    face.append(nv + i)  # relative to the vertices read so far
                    if nv + i < 0:
                        raise src.error(f"relative face index {i} points before the first vertex",
                                        "fix the index", lineno)
                else:
                    raise src.error("face index 0 is not allowed (OBJ indices start at 1)", "fix the index", lineno)
            faces.append(face)
            flines.append(lineno)
        elif kind in _OBJ_IGNORED:
            continue
        else:
            raise src.error(f"unknown OBJ record {kind!r}",
                            "only v and f records (and vt vn vp g o s usemtl mtllib l) are understood; "
                            "remove that line", lineno)
    if not verts:
        raise src.error("contains no vertices ('v' records)", "give an OBJ file with a polygon mesh")
    if not faces:
        raise src.error("contains no faces ('f' records)", "give an OBJ file with a polygon mesh, not a point cloud")
    fv, fo = faces_to_csr(faces)
    raw = RawMesh(np.array(verts, dtype=float), fv, fo, np.array(vlines), np.array(flines), index_base=1)
    return LoadedMesh(finish_mesh(raw, src, up), meta={"format": "obj", "up": up})


def write_obj(path: str | Path, mesh: PolyMesh, *, up: str = "z") -> None:
    """Write an OBJ (1-based ``f`` records, polygons kept, coordinates exact via ``repr``)."""
    v = mesh.vertices @ rotation(up)

    def chunks():
        yield f"# selfsupport mesh: {mesh.n_vertices} vertices, {mesh.n_faces} faces, up={up}\n"
        yield "".join(f"v {_fmt(x)} {_fmt(y)} {_fmt(z)}\n" for x, y, z in v.tolist())
        fv, fo = (mesh.face_vertices + 1).tolist(), mesh.face_offsets.tolist()
        yield "".join("f " + " ".join(map(str, fv[fo[f]:fo[f + 1]])) + "\n" for f in range(mesh.n_faces))

    atomic_write_text(path, chunks())


# ---------------------------------------------------------------------------------- OFF
#: OFF header keywords: C (colours), N (normals), ST (texture coordinates) add vertex columns
_OFF_HEADERS = frozenset({"OFF", "COFF", "NOFF", "CNOFF", "NCOFF", "STOFF", "STCOFF", "STNOFF", "STCNOFF"})


def read_off(path: str | Path, up: str | None = None) -> LoadedMesh:
    """Read an OFF file (``OFF``/``COFF``/``NOFF``/``CNOFF`` header), keeping polygon faces.

    One record per line: ``x y z`` per vertex (extra columns only with a C/N header), then
    ``n i_1 ... i_n`` (0-based, optionally followed by a colour) per face.
    """
    src = Source(path)
    up = "z" if up is None else up
    rotation(up)
    text = src.read_text()
    lines = ((k, strip_comment(s).split()) for k, s in enumerate(text.splitlines(), 1))
    lines = ((k, t) for k, t in lines if t)
    try:
        lineno, tok = next(lines)
    except StopIteration:
        raise src.error("the file is empty", "give an OFF file") from None
    head = tok[0]
    if head not in _OFF_HEADERS:
        raise src.error(f"header {head!r} is not an OFF header", "the first line must be OFF (or COFF/NOFF)", lineno)
    extra_columns = head != "OFF"
    counts = tok[1:]
    if not counts:
        try:
            lineno, counts = next(lines)
        except StopIteration:
            raise src.error("the file ends after the header", "add the line 'n_vertices n_faces n_edges'") from None
    if len(counts) not in (2, 3):
        raise src.error(f"counts line has {len(counts)} numbers", "write 'n_vertices n_faces n_edges'", lineno)
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except ValueError:
        raise src.error(f"counts {' '.join(counts)!r} are not integers", "write 'n_vertices n_faces n_edges'",
                        lineno) from None
    if nv <= 0 or nf <= 0:
        raise src.error(f"declares {nv} vertices and {nf} faces", "an OFF mesh needs vertices and faces", lineno)
    check_declared_counts(src, [("vertices", nv, MIN_VERTEX_BYTES), ("faces", nf, MIN_FACE_BYTES)],
                          len(text.encode("utf-8")), lineno)
    verts = np.empty((nv, 3))
    vlines = np.empty(nv, dtype=np.int64)
    for k in range(nv):
        try:
            lineno, tok = next(lines)
        except StopIteration:
            raise src.error(f"the file ends after {k} of the {nv} vertices the header declares",
                            "the file is truncated; fix the counts or the data") from None
        if len(tok) < 3 or (len(tok) != 3 and not extra_columns):
            raise src.error(f"vertex record has {len(tok)} numbers", "write 'x y z' (one vertex per line)", lineno)
        try:
            verts[k] = float(tok[0]), float(tok[1]), float(tok[2])
        except ValueError:
            raise src.error(f"vertex record has a non-numeric coordinate: {' '.join(tok)!r}",
                            "write 'x y z' with decimal numbers", lineno) from None
        vlines[k] = lineno
    faces: list[list[int]] = []
    flines = np.empty(nf, dtype=np.int64)
    for k in range(nf):
        try:
            lineno, tok = next(lines)
        except StopIteration:
            raise src.error(f"the file ends after {k} of the {nf} faces the header declares",
                            "the file is truncated; fix the counts or the data") from None
        try:
            n = int(tok[0])
            face = [int(t) for t in tok[1:n + 1]]
        except ValueError:
            raise src.error(f"face record {' '.join(tok)!r} has a non-integer index", "write 'n i_1 ... i_n'",
                            lineno) from None
        if n < 3:
            raise src.error(f"face has {n} corners", "a face needs at least 3 vertex indices", lineno)
        if len(tok) - 1 - n not in (0, 1, 3, 4):  # optional colour: index, RGB or RGBA
            raise src.error(f"face record says {n} corners but has {len(tok) - 1} numbers",
                            "write 'n i_1 ... i_n' (optionally followed by a colour)", lineno)
        faces.append(face)
        flines[k] = lineno
    rest = next(lines, None)
    if rest is not None:
        raise src.error(f"unexpected data after the {nf} faces the header declares", "fix the counts in the header",
                        rest[0])
    fv, fo = faces_to_csr(faces)
    raw = RawMesh(verts, fv, fo, vlines, flines)
    return LoadedMesh(finish_mesh(raw, src, up), meta={"format": "off", "up": up})


def write_off(path: str | Path, mesh: PolyMesh, *, up: str = "z") -> None:
    """Write an OFF file (0-based, polygons kept, coordinates exact via ``repr``)."""
    v = mesh.vertices @ rotation(up)

    def chunks():
        yield f"OFF\n{mesh.n_vertices} {mesh.n_faces} {mesh.n_edges}\n"
        yield "".join(f"{_fmt(x)} {_fmt(y)} {_fmt(z)}\n" for x, y, z in v.tolist())
        fv, fo = mesh.face_vertices.tolist(), mesh.face_offsets.tolist()
        yield "".join(f"{fo[f + 1] - fo[f]} " + " ".join(map(str, fv[fo[f]:fo[f + 1]])) + "\n"
                      for f in range(mesh.n_faces))

    atomic_write_text(path, chunks())


# ---------------------------------------------------------------------------------- PLY
#: PLY scalar type -> (numpy/struct code, size, is integer)
_PLY_TYPES: dict[str, tuple[str, int, bool]] = {
    "char": ("b", 1, True), "int8": ("b", 1, True),
    "uchar": ("B", 1, True), "uint8": ("B", 1, True),
    "short": ("h", 2, True), "int16": ("h", 2, True),
    "ushort": ("H", 2, True), "uint16": ("H", 2, True),
    "int": ("i", 4, True), "int32": ("i", 4, True),
    "uint": ("I", 4, True), "uint32": ("I", 4, True),
    "float": ("f", 4, False), "float32": ("f", 4, False),
    "double": ("d", 8, False), "float64": ("d", 8, False),
}
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_FACE_LIST_NAMES = ("vertex_indices", "vertex_index")


@dataclass
class _PlyProperty:
    name: str
    type: str                 # scalar type, or the item type of a list
    count_type: str | None = None  # set for list properties


@dataclass
class _PlyElement:
    name: str
    count: int
    line: int
    properties: list[_PlyProperty] = field(default_factory=list)


def _ply_header(src: Source, data: bytes) -> tuple[str, list[_PlyElement], int, int]:
    """Parse the header: format, elements, byte offset of the body, line number of the body's first line."""
    if not data.startswith(b"ply"):
        raise src.error("does not start with 'ply'", "check the file format and suffix", 1)
    end = data.find(b"end_header")
    if end < 0:
        raise src.error("has no 'end_header' line", "the PLY header is incomplete")
    nl = data.find(b"\n", end)
    body = len(data) if nl < 0 else nl + 1
    try:
        header = data[:end].decode("ascii")
    except UnicodeDecodeError:
        raise src.error("has a non-ASCII header", "check the file format") from None
    fmt: str | None = None
    elements: list[_PlyElement] = []
    lines = header.splitlines()
    for lineno, line in enumerate(lines[1:], 2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if len(tok) != 3 or tok[1] not in _PLY_FORMATS:
                raise src.error(f"unsupported PLY format line {line.strip()!r}",
                                "use ascii, binary_little_endian or binary_big_endian 1.0", lineno)
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3:
                raise src.error(f"element line {line.strip()!r} needs a name and a count", "write 'element NAME COUNT'",
                                lineno)
            try:
                count = int(tok[2])
            except ValueError:
                raise src.error(f"element count {tok[2]!r} is not an integer", "write 'element NAME COUNT'",
                                lineno) from None
            if count < 0:
                raise src.error(f"element count {count} is negative", "fix the header", lineno)
            elements.append(_PlyElement(tok[1], count, lineno))
        elif tok[0] == "property":
            if not elements:
                raise src.error("property before any element", "fix the header", lineno)
            if len(tok) == 5 and tok[1] == "list":
                if tok[2] not in _PLY_TYPES or tok[3] not in _PLY_TYPES or not _PLY_TYPES[tok[2]][2]:
                    raise src.error(f"unknown types in {line.strip()!r}", "use PLY scalar types (uchar, int, float, ...)",
                                    lineno)
                elements[-1].properties.append(_PlyProperty(tok[4], tok[3], tok[2]))
            elif len(tok) == 3 and tok[1] in _PLY_TYPES:
                elements[-1].properties.append(_PlyProperty(tok[2], tok[1]))
            else:
                raise src.error(f"cannot read property line {line.strip()!r}",
                                "write 'property TYPE NAME' or 'property list COUNTTYPE ITEMTYPE NAME'", lineno)
        else:
            raise src.error(f"unknown PLY header line {line.strip()!r}", "fix the header", lineno)
    if fmt is None:
        raise src.error("has no 'format' line", "the PLY header is incomplete")
    return fmt, elements, body, header.count("\n") + 2


def _ply_ascii(src: Source, data: bytes, elements: list[_PlyElement], body: int, first_line: int) -> dict:
    try:
        text = data[body:].decode("ascii")
    except UnicodeDecodeError:
        raise src.error("ASCII PLY body contains non-ASCII bytes", "check the format line of the header") from None
    lines = ((k, s.split()) for k, s in enumerate(text.splitlines(), first_line))
    lines = ((k, t) for k, t in lines if t)
    out: dict[str, dict] = {}
    for el in elements:
        cols: dict[str, list] = {p.name: [] for p in el.properties}
        rec_lines = np.empty(el.count, dtype=np.int64)
        props = [(p, int if _PLY_TYPES[p.type][2] else float) for p in el.properties]
        for r in range(el.count):
            try:
                lineno, tok = next(lines)
            except StopIteration:
                raise src.error(f"the file ends after {r} of the {el.count} '{el.name}' records the header declares",
                                "the file is truncated; fix the count or the data") from None
            k = 0
            try:
                for p, conv in props:
                    if p.count_type is None:
                        cols[p.name].append(conv(tok[k]))
                        k += 1
                    else:
                        n = int(tok[k])
                        if n < 0 or k + 1 + n > len(tok):
                            raise IndexError
                        cols[p.name].append([conv(t) for t in tok[k + 1:k + 1 + n]])
                        k += 1 + n
            except ValueError:
                raise src.error(f"'{el.name}' record has a value of the wrong type: {' '.join(tok)!r}",
                                "numbers must match the header's property types", lineno) from None
            except IndexError:
                raise src.error(f"'{el.name}' record has too few values: {' '.join(tok)!r}",
                                "write one record per line with every property of the header", lineno) from None
            if k != len(tok):
                raise src.error(f"'{el.name}' record has {len(tok)} values, the header's properties take {k}",
                                "write one record per line with every property of the header", lineno)
            rec_lines[r] = lineno
        out[el.name] = {"columns": cols, "lines": rec_lines}
    rest = next(lines, None)
    if rest is not None:
        raise src.error("unexpected data after the last element the header declares", "fix the element counts",
                        rest[0])
    return out


def _ply_binary(src: Source, data: bytes, elements: list[_PlyElement], body: int, order: str) -> dict:
    out: dict[str, dict] = {}
    pos = body
    for el in elements:
        if all(p.count_type is None for p in el.properties):
            # fixed-size records: one vectorised read
            dt = np.dtype([(p.name, order + _PLY_TYPES[p.type][0]) for p in el.properties])
            need = dt.itemsize * el.count
            if pos + need > len(data):
                raise src.error(f"binary data ends inside the '{el.name}' element "
                                f"({(len(data) - pos) // max(dt.itemsize, 1)} of {el.count} records)",
                                "the file is truncated")
            rec = np.frombuffer(data, dtype=dt, count=el.count, offset=pos)
            pos += need
            out[el.name] = {"columns": {p.name: rec[p.name] for p in el.properties}, "lines": None}
            continue
        cols: dict[str, list] = {p.name: [] for p in el.properties}
        readers = []
        for p in el.properties:
            code, size, _ = _PLY_TYPES[p.type]
            if p.count_type is None:
                readers.append((p.name, None, struct.Struct(order + code), size, code))
            else:
                ccode, csize, _ = _PLY_TYPES[p.count_type]
                readers.append((p.name, (struct.Struct(order + ccode), csize), None, size, code))
        unpack_from = struct.unpack_from
        try:
            for r in range(el.count):
                for name, counter, scalar, size, code in readers:
                    if counter is None:
                        cols[name].append(scalar.unpack_from(data, pos)[0])
                        pos += size
                    else:
                        (n,) = counter[0].unpack_from(data, pos)
                        pos += counter[1]
                        cols[name].append(list(unpack_from(f"{order}{n}{code}", data, pos)))
                        pos += n * size
        except struct.error:
            raise src.error(f"binary data ends inside '{el.name}' record {r} of {el.count}",
                            "the file is truncated") from None
        out[el.name] = {"columns": cols, "lines": None}
    if pos != len(data) and data[pos:].strip():
        raise src.error(f"{len(data) - pos} bytes after the last element the header declares",
                        "fix the element counts or the property types in the header")
    return out


def read_ply(path: str | Path, up: str | None = None) -> LoadedMesh:
    """Read a PLY file (ASCII or binary), keeping polygon faces.

    Needs a ``vertex`` element with ``x y z`` and a ``face`` element with a
    ``vertex_indices`` (or ``vertex_index``) list; other properties and elements are skipped.
    """
    return read_ply_elements(path, up)[0]


def read_ply_elements(path: str | Path, up: str | None = None) -> tuple[LoadedMesh, dict[str, dict[str, Any]]]:
    """:func:`read_ply`, and every element of the file: ``{element: {property: column}}`` (a
    column holds one value, or one list for a list property, per record), for the properties
    beyond the mesh (a network's vertex ``load`` and ``support``, its ``edge`` element)."""
    src = Source(path)
    up = "z" if up is None else up
    rotation(up)
    data = src.read_bytes()
    fmt, elements, body, first_line = _ply_header(src, data)
    # (a record takes a byte per property at least: a binary char, an ASCII digit needs its separator too)
    check_declared_counts(src, [(f"'{el.name}' records", el.count, max(len(el.properties), 1)) for el in elements],
                          len(data) - body)
    if fmt == "ascii":
        parsed = _ply_ascii(src, data, elements, body, first_line)
    else:
        parsed = _ply_binary(src, data, elements, body, _PLY_FORMATS[fmt])
    # property name -> is it a list, per element
    is_list = {el.name: {p.name: p.count_type is not None for p in el.properties} for el in elements}
    line_of = {el.name: el.line for el in elements}
    if "vertex" not in parsed:
        raise src.error("has no 'vertex' element", "give a PLY file with a polygon mesh")
    missing = [c for c in "xyz" if is_list["vertex"].get(c, True)]
    if missing:
        raise src.error(f"vertex element has no scalar property {', '.join(missing)}", "give x, y and z per vertex",
                        line_of["vertex"])
    vcols = parsed["vertex"]["columns"]
    verts = np.column_stack([np.asarray(vcols[c], dtype=float) for c in "xyz"]).reshape(-1, 3)
    if "face" not in parsed:
        raise src.error("has no 'face' element", "give a PLY file with polygon faces, not a point cloud")
    name = next((n for n in _FACE_LIST_NAMES if is_list["face"].get(n, False)), None)
    if name is None:
        raise src.error("face element has no 'vertex_indices' list", "give each face as a vertex_indices list",
                        line_of["face"])
    faces = parsed["face"]["columns"][name]
    flines = parsed["face"]["lines"]
    for k, f in enumerate(faces):
        if len(f) < 3:
            raise src.error(f"face {k} has {len(f)} corners", "a face needs at least 3 vertex indices",
                            int(flines[k]) if flines is not None else None)
    fv, fo = faces_to_csr(faces)
    raw = RawMesh(verts, fv, fo, parsed["vertex"]["lines"], flines)
    loaded = LoadedMesh(finish_mesh(raw, src, up), meta={"format": "ply", "ply_format": fmt, "up": up})
    return loaded, {el: v["columns"] for el, v in parsed.items()}


def write_ply(path: str | Path, mesh: PolyMesh, *, up: str = "z", vertex_properties: dict[str, Any] | None = None,
              edge_properties: dict[str, Any] | None = None) -> None:
    """Write an ASCII PLY (double coordinates, exact via ``repr``; polygons kept).

    ``vertex_properties`` (name -> one value per vertex) add vertex properties after ``x y z``;
    ``edge_properties`` (name -> one value per ``mesh.edges`` row) add the standard ``edge``
    element, ``vertex1 vertex2`` and those properties. Floats are written as ``double``, booleans
    as ``uchar`` 0/1, integers as ``int``.
    """
    v = mesh.vertices @ rotation(up)
    count_type = "uchar" if mesh.n_faces == 0 or int(mesh.face_sizes.max()) < 256 else "int"
    vprops = _ply_columns(vertex_properties, mesh.n_vertices, "vertex")
    eprops = _ply_columns(edge_properties, mesh.n_edges, "edge")

    def declare(props: list[tuple[str, str, list]]) -> str:
        return "".join(f"property {t} {name}\n" for name, t, _ in props)

    def rows(first: list[list], props: list[tuple[str, str, list]]) -> str:
        cols = [col for _, _, col in props]
        return "".join(" ".join([*row, *(c[k] for c in cols)]) + "\n" for k, row in enumerate(first))

    def chunks():
        yield ("ply\nformat ascii 1.0\ncomment written by selfsupport, up=" + up + "\n"
               f"element vertex {mesh.n_vertices}\nproperty double x\nproperty double y\nproperty double z\n"
               + declare(vprops)
               + f"element face {mesh.n_faces}\nproperty list {count_type} int vertex_indices\n"
               + (f"element edge {mesh.n_edges}\nproperty int vertex1\nproperty int vertex2\n" + declare(eprops)
                  if eprops else "")
               + "end_header\n")
        yield rows([[_fmt(x), _fmt(y), _fmt(z)] for x, y, z in v.tolist()], vprops)
        fv, fo = mesh.face_vertices.tolist(), mesh.face_offsets.tolist()
        yield "".join(f"{fo[f + 1] - fo[f]} " + " ".join(map(str, fv[fo[f]:fo[f + 1]])) + "\n"
                      for f in range(mesh.n_faces))
        if eprops:
            yield rows([[str(i), str(j)] for i, j in mesh.edges.tolist()], eprops)

    atomic_write_text(path, chunks())


def _ply_columns(props: dict[str, Any] | None, n: int, what: str) -> list[tuple[str, str, list[str]]]:
    """``(name, PLY type, values as text)`` per property (see :func:`write_ply`)."""
    out = []
    for name, values in (props or {}).items():
        a = np.asarray(values)
        if a.shape != (n,):
            raise ValueError(f"PLY {what} property {name!r} has shape {a.shape}, expected ({n},)")
        if a.dtype.kind == "b":
            out.append((name, "uchar", [str(int(x)) for x in a.tolist()]))
        elif a.dtype.kind in "iu":
            out.append((name, "int", [str(x) for x in a.tolist()]))
        else:
            out.append((name, "double", [_fmt(x) for x in a.astype(float).tolist()]))
    return out


#: suffix -> mesh reader ``(path, up) -> LoadedMesh``
MESH_READERS: dict[str, Callable[..., LoadedMesh]] = {".obj": read_obj, ".ply": read_ply, ".off": read_off}
#: suffix -> mesh writer ``(path, mesh, *, up) -> None``
MESH_WRITERS: dict[str, Callable[..., None]] = {".obj": write_obj, ".ply": write_ply, ".off": write_off}
