"""Fig. 12 as a study: planar faces on a mesh along the relative principal directions vs a grid.

    python -m studies.pq --scenes ../shared/paper-scenes --out OUT [--only dome,vault,lilium,cas]
        [--spacing 1.0] [--time-limit 300] [--remesher seamless,streamlines[,param]]
        [--densities mean[,published]] [--checker PATH]

For each scene (``dome``: a generated 400-vertex dome; others: ``SCENES/scenes/NAME.sss``) the
scene's own mesh solved with planar faces (when it has quads), the default staggered solve, then :func:`selfsupport.remesh.streamlines.remesh` along the relative principal
directions and along a fixed grid (``--spacing`` × the network's mean top-view edge length; with
each remesher of ``--remesher``, :data:`selfsupport.remesh.streamlines.METHODS`), each
solved with planar faces required (:class:`formulations.Planar`, tol 1e-3) by
:func:`selfsupport.remesh.planar.solve_planar` (the staggered method, and where it does not converge
the finishes, planar homotopy then IPOPT, the homotopy's network pulled toward the scene's reference;
``--no-finish``: the staggered method alone). Columns: faces, status, solved by,
max relative error (recomputed from the saved network), max / mean quad non-planarity (distance
of the diagonals / mean edge length) before (also the mean over the quads off the boundary) and
after, mean distance to the scene's reference (/ bbox diagonal) before the planar solve (the
remesh, its heights from the network in equilibrium) and after, the largest distance a vertex
moved in the planar solve (/ bbox diagonal), the pull toward the reference (its steps and why it
ended: converged, or at its share of the time limit), time. The published ``NAME-pq-n.obj`` (where present) is measured the same way
(its distance to the reference and its non-planarity). ``--densities published`` adds, for every
scene with such a published mesh, both fields again by the first remesher with the spacing the
published mesh's mean top-view edge length (rows tagged ``published spacing``): the comparison at
the paper's own density. With ``--checker``, the shared independent checker's max relative error of every written
network. Writes ``pq.csv``, ``pq.md`` and the networks.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .common import (
    STAMP_COLUMNS,
    Column,
    json_max_relative_error,
    read_study_scene,
    run_checker,
    run_stamp,
    write_csv,
    write_markdown,
)

#: The tag of the rows at the published mesh's spacing (``--densities published``).
PUBLISHED_SPACING = "published spacing"

COLUMNS = [Column("scene", "scene"), Column("mesh", "mesh"), Column("faces", "faces"),
           Column("quads", "quads", "{:.1%}"),
           Column("irregular", "interior valence ≠ 4"), Column("status", "status"),
           Column("solved_by", "solved by"),
           Column("max_rel_error", "max rel. error", "{:.1e}"),
           Column("checker", "checker max rel. error", "{:.1e}"),
           Column("start_nonplanar", "non-planarity before (max / mean)"),
           Column("start_nonplanar_interior", "non-planarity before, quads off the boundary (mean)", "{:.1e}"),
           Column("nonplanar_max", "non-planarity after (max)", "{:.1e}"),
           Column("dist_start", "dist. to reference before (mean)", "{:.3e}"),
           Column("dist_mean", "dist. to reference (mean)", "{:.3e}"),
           Column("moved_max", "largest vertex move in the planar solve", "{:.2e}"),
           Column("pull", "pull toward the reference (steps, end)"),
           Column("time_s", "time [s]", "{:.1f}")]
#: the CSV's columns: the table's, then the run's stamp (:func:`studies.common.run_stamp`)
CSV_COLUMNS = [*COLUMNS, *STAMP_COLUMNS]


def _nonplanarity(mesh) -> tuple[float, float]:
    from selfsupport.core.evidence import face_nonplanarity

    q = face_nonplanarity(mesh)
    q = q[np.isfinite(q)]
    return (float(q.max()), float(q.mean())) if q.size else (float("nan"), float("nan"))


def _interior_nonplanarity(mesh) -> float:
    """Mean non-planarity of the quads with no vertex on the boundary (where the field, not the
    boundary's shape or its supports, sets the quads)."""
    from selfsupport.core.evidence import face_nonplanarity

    q = face_nonplanarity(mesh)
    bnd = mesh.boundary_vertex_mask
    off = np.array([not bnd[list(f)].any() for f in mesh.faces]) & np.isfinite(q)
    return float(q[off].mean()) if off.any() else float("nan")


def _mean_top_edge(mesh) -> float:
    """Mean top-view edge length of a mesh."""
    e = mesh.edges
    return float(np.linalg.norm(mesh.vertices[e[:, 1], :2] - mesh.vertices[e[:, 0], :2], axis=1).mean())


def _pull_of(res) -> str:
    """The planar network's pull toward the reference: its steps and why it ended (empty when
    none ran)."""
    rec = (res.parameters.get("homotopy") or {}).get("pull") or res.parameters.get("planar_pull") or {}
    pull = rec.get("planar")
    return f"{pull['steps']} steps, {pull['stop']}" if pull else ""


def run(scenes: Path, out: Path, only: Sequence[str], spacing: float, time_limit: float,
        finish: bool = True, remeshers: Sequence[str] = ("seamless",),
        checker: Path | None = None, densities: Sequence[str] = ("mean",)) -> list[dict[str, Any]]:
    from selfsupport import api
    from selfsupport.core.errors import SelfSupportError
    from selfsupport.core.evidence import distance_stats
    from selfsupport.core.shapes import make_shape
    from selfsupport.io import read_mesh, write_network
    from selfsupport.remesh.planar import finish_summary, solve_planar
    from selfsupport.remesh.streamlines import remesh

    stamp = run_stamp()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for name in only:
        scene = make_shape("dome", n_vertices=400) if name == "dome" else read_study_scene(scenes / "scenes", name)
        net = api.solve(scene, time_limit=time_limit).network
        pub = scenes / "published" / f"{name}-pq-n.obj"
        pub_mesh = read_mesh(pub, up="-y") if pub.is_file() else None
        spacings = {"mean": spacing * _mean_top_edge(net.mesh)}
        if "published" in densities and pub_mesh is not None:
            spacings[PUBLISHED_SPACING] = _mean_top_edge(pub_mesh)
        todo_meshes = [("as is", "", "mean")] if (scene.mesh.face_sizes == 4).any() else []
        todo_meshes += [(field, how, d) for d in spacings for how in (remeshers if d == "mean" else remeshers[:1])
                        for field in ("principal", "grid")]
        for field, how, density in todo_meshes:
            h = spacings[density]
            # (the rows the docs quote keep their names: no tag for streamlines at the mean spacing)
            tags = [t for t in (how if how not in ("", "streamlines") else "",
                                density if density != "mean" else "") if t]
            tag = f" ({', '.join(tags)})" if tags else ""
            row: dict[str, Any] = {"scene": name, "mesh": "scene as is" if field == "as is" else f"remesh {field}{tag}",
                                   **stamp}
            t0 = time.perf_counter()
            try:
                q = None if field == "as is" else remesh(net, spacing=h, field=field, method=how)
                todo = scene if q is None else q.scene
                mx, mn = _nonplanarity(todo.mesh)
                inner = _interior_nonplanarity(todo.mesh)
                res = solve_planar(todo, tol=1e-3, finish=finish, time_limit=time_limit, reference=scene.mesh)
            except SelfSupportError as exc:
                row.update(status=f"failed: {exc}")
                rows.append(row)
                continue
            path = out / (f"{name}__{field.replace(' ', '-')}{'-' + how if how not in ('', 'streamlines') else ''}"
                          f"{'-published' if density != 'mean' else ''}.json")
            write_network(path, res, study={"scene": name, "field": field, "spacing": h})
            sizes = np.unique(todo.mesh.face_sizes, return_counts=True)
            val = np.bincount(todo.mesh.edges.ravel(), minlength=todo.mesh.n_vertices)
            row.update(faces=" ".join(f"{k}:{v}" for k, v in zip(*sizes)), status=res.status,
                       quads=float((todo.mesh.face_sizes == 4).mean()), checker=run_checker(checker, path),
                       irregular=int(((val != 4) & ~todo.mesh.boundary_vertex_mask).sum()),
                       solved_by=finish_summary(res),
                       max_rel_error=json_max_relative_error(path), start_nonplanar=f"{mx:.1e} / {mn:.1e}",
                       start_nonplanar_interior=inner,
                       moved_max=float(np.linalg.norm(res.network.vertices - todo.mesh.vertices, axis=1).max()
                                       / np.linalg.norm(np.ptp(scene.mesh.vertices, axis=0))),
                       nonplanar_max=res.parameters["planarity"]["max_nonplanarity"],
                       dist_start=distance_stats(todo.mesh.vertices, scene.mesh)[0],
                       dist_mean=distance_stats(res.network.vertices, scene.mesh)[0], pull=_pull_of(res),
                       time_s=time.perf_counter() - t0)
            rows.append(row)
            print(" | ".join(str(row.get(c.key)) for c in COLUMNS), flush=True)
        if pub_mesh is not None:
            m = pub_mesh
            mx, mn = _nonplanarity(m)
            rows.append({"scene": name, "mesh": "published pq-n", "faces": " ".join(
                f"{k}:{v}" for k, v in zip(*np.unique(m.face_sizes, return_counts=True))),
                "quads": float((m.face_sizes == 4).mean()),
                "start_nonplanar": f"{mx:.1e} / {mn:.1e}", "start_nonplanar_interior": _interior_nonplanarity(m),
                "dist_mean": distance_stats(m.vertices, scene.mesh)[0],
                **stamp})
    write_csv(out / "pq.csv", rows, CSV_COLUMNS)
    write_markdown(out / "pq.md", "Planar faces: aligned remesh vs grid (paper Fig. 12)",
                   ["non-planarity: distance between a quad's diagonals / its mean edge length",
                    "dist.: mean distance of the vertices to the scene's reference surface / bbox diagonal"],
                   [("", rows, COLUMNS)])
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.pq", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=Path, required=True, help="the paper-scenes folder (with scenes/ and published/)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--only", default="dome,vault,lilium,cas", help="scenes (comma-separated; dome is generated)")
    p.add_argument("--spacing", type=float, default=1.0, help="line spacing / the network's mean top-view edge length")
    p.add_argument("--time-limit", type=float, default=300.0, help="per planar solve, the finish included [s]")
    p.add_argument("--no-finish", dest="finish", action="store_false",
                   help="the staggered method alone (no finish, selfsupport.remesh.planar)")
    p.add_argument("--remesher", default="seamless,streamlines",
                   help="remeshers to compare (comma-separated: seamless, streamlines, param; "
                        "selfsupport.remesh.streamlines)")
    p.add_argument("--densities", default="mean",
                   help="spacings (comma-separated): mean, --spacing × the network's mean top-view edge; published, "
                        "the published NAME-pq-n.obj's mean top-view edge (scenes with one)")
    p.add_argument("--checker", type=Path, default=None, help="the shared independent checker (check_network.py)")
    a = p.parse_args(argv)
    dens = a.densities.split(",")
    if not set(dens) <= {"mean", "published"}:
        p.error(f"--densities: choose from mean, published (got {a.densities})")
    run(a.scenes, a.out, a.only.split(","), a.spacing, a.time_limit, a.finish, a.remesher.split(","), a.checker,
        dens)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
