"""A thrust network in the polygon-mesh formats, read back to the same network.

* **PLY** holds it all in standard elements: vertex properties ``load`` (signed vertical load
  [N], negative = down) and ``support`` (0/1), and an ``edge`` element ``vertex1 vertex2
  weight`` (one per mesh edge, the force density [N/m]).
* **OBJ** and **OFF** have no place for them: beside ``NAME.obj`` go ``NAME.weights.csv``
  (``i,j,weight``, one row per mesh edge, 0-based vertex indices) and ``NAME.vertices.csv``
  (``vertex,load,support``, one row per vertex) — see :func:`side_files`.

The vertical axis of the file is ``up`` (as for meshes); loads are along it. Numbers are
written exactly (``repr``). Status and evidence have no place in these formats (the JSON
network and the COMPAS mesh JSON keep them).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from selfsupport.core.result import Network, SolveResult
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.compas_mesh import compas_mesh_data
from selfsupport.io.meshfiles import MESH_READERS, MESH_WRITERS, Source, read_ply_elements, write_ply
from selfsupport.io.network_json import edge_weights, network_from_arrays, network_to_dict

__all__ = ["SIDE_SUFFIXES", "side_files", "write_with_side_files", "read_with_side_files", "write_ply_network",
           "read_ply_network"]

#: What goes beside an OBJ or OFF network: ``NAME`` + these.
SIDE_SUFFIXES = (".weights.csv", ".vertices.csv")
_WEIGHTS_HEADER = ("i", "j", "weight")
_VERTICES_HEADER = ("vertex", "load", "support")


def _network(result_or_network: Network | SolveResult) -> Network:
    return getattr(result_or_network, "network", result_or_network)


def side_files(path: str | Path) -> tuple[Path, ...]:
    """The side files of an OBJ/OFF network ``NAME.obj``: ``NAME.weights.csv``, ``NAME.vertices.csv``."""
    p = Path(path)
    stem = p.name[:-len(p.suffix)] if p.suffix else p.name
    return tuple(p.with_name(stem + s) for s in SIDE_SUFFIXES)


def write_with_side_files(path: str | Path, result_or_network: Network | SolveResult, *, up: str = "z",
                          **extra: Any) -> None:
    """Write the network's mesh as OBJ/OFF (by the suffix of ``path``) and its weights, loads
    and supports in the :func:`side_files`, each atomically (the side files first). ``extra``
    (status, evidence) has no place in these files."""
    net = _network(result_or_network)
    wpath, vpath = side_files(path)
    e, w = net.mesh.edges.tolist(), edge_weights(net).tolist()
    atomic_write_text(wpath, [",".join(_WEIGHTS_HEADER) + "\n",
                              "".join(f"{i},{j},{x!r}\n" for (i, j), x in zip(e, w))])
    loads, sup = np.asarray(net.loads, float).tolist(), np.asarray(net.supports, bool).tolist()
    atomic_write_text(vpath, [",".join(_VERTICES_HEADER) + "\n",
                              "".join(f"{k},{x!r},{int(s)}\n" for k, (x, s) in enumerate(zip(loads, sup)))])
    MESH_WRITERS[Path(path).suffix.lower()](path, net.mesh, up=up)


def read_with_side_files(path: str | Path, up: str | None = None) -> Network:
    """The network of an OBJ/OFF file and its :func:`side_files`.

    Raises
    ------
    InputError
        The mesh file's errors; a side file that is missing, has another header, a row that is
        not numbers, a vertex listed twice or missing, or edges that are not the faces' edges.
    """
    loaded = MESH_READERS[Path(path).suffix.lower()](path, up)
    mesh = loaded.mesh
    wpath, vpath = side_files(path)
    wsrc, vsrc = Source(wpath), Source(vpath)
    i, j, w = _read_csv(wsrc, _WEIGHTS_HEADER, (int, int, float), Path(path))
    k, load, sup = _read_csv(vsrc, _VERTICES_HEADER, (int, float, int), Path(path))
    n = mesh.n_vertices
    if len(k) != n or not np.array_equal(np.sort(k), np.arange(n)):
        raise vsrc.error(f"lists vertices {_describe(k)} for the {n} vertices of {path}",
                         f"write one row per vertex 0..{n - 1}")
    if not np.isin(sup, (0, 1)).all():
        raise vsrc.error(f"support column holds {int(sup[~np.isin(sup, (0, 1))][0])}", "write 0 or 1")
    order = np.argsort(k)
    return network_from_arrays(wsrc, mesh, np.column_stack([i, j]), w, load[order], sup[order].astype(bool),
                               edges_key="the edge list", weights_key="the weight column", loads_key="the load column")


def _describe(k: np.ndarray) -> str:
    return f"{len(k)} rows" if len(k) == 0 else f"{len(k)} rows ({int(k.min())}..{int(k.max())})"


def _read_csv(src: Source, header: tuple[str, ...], kinds: tuple[type, ...], of: Path) -> list[np.ndarray]:
    """The columns of a side file: its first line must be ``header``, every other non-empty line
    one value per column."""
    if not src.path.exists():
        raise src.error(f"is missing (the network of {of} keeps its weights, loads and supports there)",
                        f"keep the side files {', '.join(p.name for p in side_files(of))} beside it, or write "
                        "the network as .json or .ply")
    lines = src.read_text().splitlines()
    got = tuple(t.strip() for t in lines[0].split(","))
    if got != header:
        raise src.error(f"header is {','.join(got)!r}", f"the first line must be {','.join(header)!r}", 1)
    cols: list[list] = [[] for _ in header]
    for lineno, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        tok = [t.strip() for t in line.split(",")]
        if len(tok) != len(header):
            raise src.error(f"row has {len(tok)} values, the header {len(header)}",
                            f"write {','.join(header)} per row", lineno)
        try:
            for c, t, kind in zip(cols, tok, kinds):
                c.append(kind(t))
        except ValueError:
            raise src.error(f"row {line.strip()!r} is not {', '.join(k.__name__ for k in kinds)}",
                            f"write {','.join(header)} with numbers", lineno) from None
    out = [np.array(c, dtype=np.int64 if kind is int else float) for c, kind in zip(cols, kinds)]
    bad = [k for k, a in enumerate(out) if a.dtype.kind == "f" and not np.isfinite(a).all()]
    if bad:
        raise src.error(f"column {header[bad[0]]!r} has a non-finite number", "fix it")
    return out


def write_ply_network(path: str | Path, result_or_network: Network | SolveResult, *, up: str = "z",
                      **extra: Any) -> None:
    """Write the network as an ASCII PLY: vertex ``load`` and ``support``, an ``edge`` element with
    ``weight`` (see the module docstring), atomically. ``extra`` has no place in the file."""
    net = _network(result_or_network)
    write_ply(path, net.mesh, up=up,
              vertex_properties={"load": np.asarray(net.loads, float), "support": np.asarray(net.supports, bool)},
              edge_properties={"weight": edge_weights(net)})


def read_ply_network(path: str | Path, up: str | None = None) -> Network:
    """The network of a PLY file written by :func:`write_ply_network` (ASCII or binary alike).

    Raises
    ------
    InputError
        The mesh's errors, a missing vertex ``load`` / ``support`` or ``edge`` element with
        ``vertex1 vertex2 weight``, edges that are not the faces' edges.
    """
    loaded, elements = read_ply_elements(path, up)
    src = Source(path)
    vertex, edge = elements["vertex"], elements.get("edge", {})
    missing = [f"vertex {p}" for p in ("load", "support") if p not in vertex]
    missing += [f"edge {p}" for p in ("vertex1", "vertex2", "weight") if p not in edge]
    if missing:
        raise src.error(f"has no {', '.join(missing)} property", "a PLY network has vertex load and support "
                        "and an edge element with vertex1, vertex2 and weight; for the geometry alone read it "
                        "as a mesh")
    columns = {name: np.asarray(col) for name, col in [*vertex.items(), *edge.items()]}
    for name in ("load", "support", "vertex1", "vertex2", "weight"):
        if columns[name].dtype.kind not in "iuf" or columns[name].ndim != 1:
            raise src.error(f"property {name!r} is not a scalar number", "write it as a scalar property")
    sup = columns["support"]
    if not np.isin(sup, (0, 1)).all():
        raise src.error("vertex property 'support' holds values other than 0 and 1", "write 0 or 1")
    e = np.column_stack([columns["vertex1"], columns["vertex2"]])
    if e.size and not np.array_equal(e, np.round(e)):
        raise src.error("edge vertex1/vertex2 are not integers", "write integer vertex indices")
    return network_from_arrays(src, loaded.mesh, e.astype(np.int64), columns["weight"].astype(float),
                               columns["load"].astype(float), sup.astype(bool), edges_key="element 'edge'",
                               weights_key="edge property 'weight'", loads_key="vertex property 'load'")


def write_compas(path: str | Path, result_or_network: Network | SolveResult, **extra: Any) -> None:
    """Write a network (or a solve result, with its status and evidence) as a COMPAS mesh JSON,
    atomically; ``extra`` keys go into the mesh's attributes."""
    doc = compas_mesh_data(network_to_dict(result_or_network, **extra))
    atomic_write_text(path, json.dumps(doc, allow_nan=False) + "\n")
