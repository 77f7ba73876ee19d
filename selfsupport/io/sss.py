"""The original tool's scene format ``.sss`` (evouga/SelfSupporting).

One record per line (docs/reference/formats.md)::

    v x y z load pinned handled     pinned/handled are 0/1
    f n i_1 ... i_n                 0-based vertex indices
    e i j crease creaseval weight   a stored edge weight (older files: ``e i j crease creaseval``)
    # ...                           a comment: any bytes (Latin-1 and the like included)

The text is UTF-8 (a leading byte-order mark is skipped); only what stands before a ``#``
has to decode. Vertices that belong to no face (the original tool wrote some) are made
supports that carry nothing, so that every index stays that of the file; the scene check
warns about them (``isolated_vertices``).

The vertical axis is y and points down (height = −y): file coordinates (X, Y, Z) become
ours as (X, Z, −Y), the proper rotation ``axes.UP_AXES["-y"]``.

``load`` is the old tool's cached nodal load, recomputed there on every solve; a scene's is
never used as a load here (the solver recomputes self-weight from the geometry) but kept in
``meta["sss_loads"]``. The ``e`` records' weights are kept in ``meta["sss_edge_weights"]``
as an ``(k, 3)`` array ``[i, j, w]`` (records without a weight are left out).

A network is written as a ``.sss`` with its own loads and weights (:func:`write_network_sss`)
and read back from them (:func:`read_sss_network`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.axes import rotation
from selfsupport.io.meshfiles import LoadedMesh, RawMesh, Source, faces_to_csr, finish_mesh
from selfsupport.io.network_json import edge_weights, network_from_arrays

__all__ = ["SSS_UP", "read_sss", "write_scene_sss", "write_network_sss", "read_sss_network"]

#: The .sss vertical axis (y pointing down); fixed by the format.
SSS_UP = "-y"


def read_sss(path: str | Path, up: str | None = None) -> LoadedMesh:
    """Parse a ``.sss`` scene: mesh (z up), pins as supports, handles, cached loads, edge weights."""
    src = Source(path)
    if up not in (None, SSS_UP):
        raise InputError(f"{src.path}: .sss files have height = -y by definition, got up={up!r}; "
                         "leave --up out (or pass --up=-y)")
    lines = _decoded_lines(src)
    vrows: list[list[str]] = []
    vlines: list[int] = []
    faces: list[list[int]] = []
    flines: list[int] = []
    erows: list[list[str]] = []
    elines: list[int] = []
    for lineno, line in lines:
        tok = line.split()
        if not tok:
            continue
        kind = tok[0]
        if kind == "v":
            if len(tok) != 7:
                raise src.error(f"vertex record has {len(tok) - 1} fields, expected 6",
                                "write 'v x y z load pinned handled'", lineno)
            vrows.append(tok[1:])
            vlines.append(lineno)
        elif kind == "f":
            try:
                n = int(tok[1])
                face = [int(t) for t in tok[2:]]
            except (ValueError, IndexError):
                raise src.error(f"face record {line.strip()!r} has a non-integer or missing field",
                                "write 'f n i_1 ... i_n' with 0-based indices", lineno) from None
            if n != len(face):
                raise src.error(f"face record says {n} corners but lists {len(face)} indices",
                                "write 'f n i_1 ... i_n' with exactly n indices", lineno)
            if n < 3:
                raise src.error(f"face has {n} corners", "a face needs at least 3 vertex indices", lineno)
            faces.append(face)
            flines.append(lineno)
        elif kind == "e":
            if len(tok) not in (5, 6):
                raise src.error(f"edge record has {len(tok) - 1} fields, expected 5 (or 4 without the weight)",
                                "write 'e i j crease creaseval weight'", lineno)
            erows.append(tok[1:] + ["nan"] * (6 - len(tok)))  # nan: no stored weight
            elines.append(lineno)
        else:
            raise src.error(f"unknown .sss record {kind!r}", "only v, f and e records exist; remove that line", lineno)
    if not vrows:
        raise src.error("contains no vertices ('v' records)", "give a .sss scene")
    if not faces:
        raise src.error("contains no faces ('f' records)", "give a .sss scene with faces")

    vl = np.array(vlines, dtype=np.int64)
    try:
        vals = np.array(vrows, dtype=float)  # fast path; the loop below only runs to find a bad line
    except ValueError:
        for row, ln in zip(vrows, vlines):
            try:
                [float(t) for t in row]
            except ValueError:
                raise src.error(f"vertex record has a non-numeric field: {' '.join(row)!r}",
                                "write 'v x y z load pinned handled' with numbers", ln) from None
        raise  # pragma: no cover - numpy and float() disagree
    flags = vals[:, 4:6]
    bad = ~np.isin(flags, (0.0, 1.0)).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise src.error(f"pinned/handled flags {' '.join(vrows[k][4:6])!r} are not 0 or 1",
                        "write 0 or 1 in the last two columns", int(vl[k]))

    fv, fo = faces_to_csr(faces)
    raw = RawMesh(vals[:, :3], fv, fo, vl, np.array(flines, dtype=np.int64))
    mesh = finish_mesh(raw, src, SSS_UP)

    n = mesh.n_vertices
    if erows:
        try:
            ew = np.array(erows, dtype=float)
        except ValueError:
            for row, ln in zip(erows, elines):
                try:
                    [float(t) for t in row]
                except ValueError:
                    raise src.error(f"edge record has a non-numeric field: {' '.join(row)!r}",
                                    "write 'e i j crease creaseval weight' with numbers", ln) from None
            raise  # pragma: no cover
        ij = ew[:, :2]
        given = ~np.isnan(ew[:, 4])
        bad = ((ij != np.round(ij)).any(axis=1) | (ij < 0).any(axis=1) | (ij >= n).any(axis=1)
               | ~np.isfinite(ew[:, :4]).all(axis=1) | (given & ~np.isfinite(ew[:, 4])))
        if bad.any():
            k = int(np.argmax(bad))
            raise src.error(f"edge record {' '.join(erows[k])!r} has a vertex index outside 0..{n - 1} "
                            "or a non-finite number", "fix or remove that record", elines[k])
        edge_weights = np.column_stack([ij, ew[:, 4]])[given]
    else:
        edge_weights = np.zeros((0, 3))
    meta = {"format": "sss", "up": SSS_UP, "sss_loads": vals[:, 3].copy(), "sss_edge_weights": edge_weights}
    supports = flags[:, 0] == 1.0
    isolated = mesh.isolated_vertices
    if isolated.size:
        supports[isolated] = True  # carry nothing; kept so that indices stay the file's
        meta["isolated_vertices"] = isolated
    return LoadedMesh(mesh, supports=supports, handles=flags[:, 1] == 1.0, meta=meta)


def _decoded_lines(src: Source) -> list[tuple[int, str]]:
    """``(line number, text before any '#')`` per line: a comment may hold any bytes, the rest
    must be UTF-8 (a leading byte-order mark is dropped)."""
    data = src.read_bytes()
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    out = []
    for lineno, raw in enumerate(data.splitlines(), 1):
        body = raw.split(b"#", 1)[0]
        try:
            out.append((lineno, body.decode("utf-8")))
        except UnicodeDecodeError:
            raise src.error("has a byte that is not UTF-8 outside a comment", "check the file format and suffix",
                            lineno) from None
    return out


def write_scene_sss(path: str | Path, scene: Scene) -> None:
    """Write ``scene`` as a ``.sss`` file that :func:`read_sss` reads back.

    The ``load`` column is written as 0 (loads are recomputed on every solve). One ``e`` record
    is written per mesh edge, with the weight from ``scene.meta["sss_edge_weights"]`` when the
    scene carries one for that edge, else 0.
    """
    mesh = scene.mesh
    edges = mesh.edges
    w = np.zeros(len(edges))
    stored = scene.meta.get("sss_edge_weights") if isinstance(scene.meta, dict) else None
    if stored is not None and len(stored):
        stored = np.asarray(stored, dtype=float).reshape(-1, 3)
        n1 = mesh.n_vertices + 1
        i, j = stored[:, 0].astype(np.int64), stored[:, 1].astype(np.int64)
        key = np.minimum(i, j) * n1 + np.maximum(i, j)
        ekey = edges[:, 0] * n1 + edges[:, 1]  # sorted: mesh.edges is lexicographic
        pos = np.clip(np.searchsorted(ekey, key), 0, len(ekey) - 1)
        hit = ekey[pos] == key
        w[pos[hit]] = stored[hit, 2]
    _write_sss(path, mesh, np.zeros(mesh.n_vertices), scene.supports, scene.handles, w)


def write_network_sss(path: str | Path, result_or_network: Network | SolveResult, **extra: object) -> None:
    """Write a network as a ``.sss`` scene of the original tool, which :func:`read_sss_network`
    reads back to the same network.

    ``pinned`` = the supports, ``handled`` = the handles, one ``e`` record per mesh edge with its
    weight (0 on support–support edges); ``load`` is the network's own downward load ``-L`` per
    vertex, where the original tool caches its 9.8·(ρ·A·t + extra) (it recomputes that on every
    solve). Status and evidence (``extra``) have no place in the format.
    """

    net = getattr(result_or_network, "network", result_or_network)
    _write_sss(path, net.mesh, -np.asarray(net.loads, dtype=float), net.supports, net.handles, edge_weights(net))


def _write_sss(path: str | Path, mesh: PolyMesh, load: np.ndarray, pinned: np.ndarray, handled: np.ndarray | None,
               weights: np.ndarray) -> None:
    """``v x y z load pinned handled`` per vertex (y down), ``f`` per face, ``e i j 0 0 w`` per
    ``mesh.edges`` row; numbers exact via ``repr``."""
    v = mesh.vertices @ rotation(SSS_UP)
    pinned = np.asarray(pinned, dtype=bool)
    handled = np.zeros(mesh.n_vertices, dtype=bool) if handled is None else np.asarray(handled, bool)

    def chunks():
        yield "".join(f"v {x!r} {y!r} {z!r} {c!r} {int(p)} {int(h)}\n"
                      for (x, y, z), c, p, h in zip(v.tolist(), np.asarray(load, float).tolist(), pinned.tolist(),
                                                    handled.tolist()))
        fv, fo = mesh.face_vertices.tolist(), mesh.face_offsets.tolist()
        yield "".join(f"f {fo[f + 1] - fo[f]} " + " ".join(map(str, fv[fo[f]:fo[f + 1]])) + "\n"
                      for f in range(mesh.n_faces))
        yield "".join(f"e {a} {b} 0 0 {wt!r}\n" for (a, b), wt in zip(mesh.edges.tolist(),
                                                                      np.asarray(weights, float).tolist()))

    atomic_write_text(path, chunks())


def read_sss_network(path: str | Path, up: str | None = None) -> Network:
    """The network a ``.sss`` file holds (one written by :func:`write_network_sss`): weights from
    the ``e`` records (every edge of the faces needs one), loads ``-load`` (the column is the
    downward load), supports = pinned, handles = handled.

    Raises
    ------
    InputError
        :func:`read_sss`'s errors, and ``e`` records that are not exactly the faces' edges with
        a weight each (a scene never solved has none: solve it first).
    """

    loaded = read_sss(path, up)
    ew = loaded.meta["sss_edge_weights"]
    return network_from_arrays(Source(path), loaded.mesh, ew[:, :2].astype(np.int64), ew[:, 2],
                               -loaded.meta["sss_loads"], loaded.supports, handles=loaded.handles,
                               edges_key="the list of weighted 'e' records",
                               weights_key="the list of 'e' records", loads_key="the list of 'v' records")
