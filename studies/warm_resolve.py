"""Warm re-solve benchmark: cold vs warm staggered solves after small edits of lilium.

    python -m studies.warm_resolve --scenes ../shared/paper-scenes/scenes [--repeat 3] [--out DIR]

For each edit kind — a height-only handle move, a full (3D) handle move, a top-view handle move
(each by ``--size`` of the bounding-box diagonal, Laplacian deformation of 6 rings around the
vertex nearest the middle), a density change, a pin — the edited scene is solved cold (from the
reference, uniform weights) and warm (from the unedited scene's network:
:mod:`selfsupport.methods.warm`), and the table gives time (best of ``--repeat``), outer
iterations, final max relative error, whether the warm start was kept (it falls back to the cold
start when the first fit error exceeds ``finish_try``) and the largest vertex gap between the two
networks. A benchmark, not a timed test: the numbers depend on the machine. ``--out DIR``
writes the rows to ``DIR/warm_resolve.csv``, each stamped (:func:`studies.common.run_stamp`).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from selfsupport.design.edits import Design, Material, Move, Pin, Select
from selfsupport.io import read_scene
from selfsupport.methods.staggered import StaggeredLinearization

from .common import STAMP_COLUMNS, Column, run_stamp, write_csv

#: the CSV's columns (``--out``)
COLUMNS = (Column("scene", "scene"), Column("edit", "edit"), Column("cold_s", "cold [s]"), Column("cold_it", "cold it"),
           Column("cold_err", "cold error"), Column("warm_s", "warm [s]"), Column("warm_it", "warm it"),
           Column("warm_err", "warm error"), Column("warm_used", "warm kept"), Column("speedup", "speed-up"),
           Column("gap", "gap / diag"), Column("dist_cold", "dist. cold"), Column("dist_warm", "dist. warm"),
           Column("size", "move / diag"), Column("repeat", "solves"), *STAMP_COLUMNS)


def edits(scene, size: float) -> dict[str, object]:
    """The edit kinds of the table, as edits of :mod:`selfsupport.design.edits`."""
    V = scene.mesh.vertices
    c = tuple(0.5 * (V[:, :2].min(0) + V[:, :2].max(0)))
    sel = Select(nearest=c)
    d = size * float(np.linalg.norm(np.ptp(V, axis=0)))
    return {"height move": Move(sel, (0.0, 0.0, d), "height", roi_rings=6),
            "full move": Move(sel, (d, d, d), "full", roi_rings=6),
            "top-view move": Move(sel, (d, -d, 0.0), "top_view", roi_rings=6),
            "density +10%": Material(density=2200.0),
            "pin a vertex": Pin(sel)}


def run(scene_path: Path, size: float = 0.002, repeat: int = 3) -> list[dict]:
    stamp = run_stamp()
    method = StaggeredLinearization()
    base_design = Design(read_scene(scene_path))
    base = method.solve(base_design.problem())
    rows = []
    for kind, edit in edits(base_design.scene, size).items():
        design = edit.apply(base_design)
        prob = design.problem()
        best = {}
        for label, ws in (("cold", None), ("warm", base.network)):
            times, res = [], None
            for _ in range(repeat):
                t0 = time.perf_counter()
                res = method.solve(prob, warm_start=ws)
                times.append(time.perf_counter() - t0)
            best[label] = (min(times), res)
        (tc, rc), (tw, rw) = best["cold"], best["warm"]
        diag = float(np.linalg.norm(np.ptp(design.scene.mesh.vertices, axis=0)))
        rows.append({"edit": kind, "cold_s": tc, "cold_it": rc.iterations, "cold_err": rc.max_relative_error,
                     "warm_s": tw, "warm_it": rw.iterations, "warm_err": rw.max_relative_error,
                     "warm_used": bool((rw.parameters.get("warm_start") or {}).get("used")),
                     "speedup": tc / tw, "gap": float(np.linalg.norm(rw.network.vertices - rc.network.vertices,
                                                                     axis=1).max()) / diag,
                     "dist_cold": rc.distance_mean, "dist_warm": rw.distance_mean,
                     "scene": Path(scene_path).stem, "size": size, "repeat": repeat, **stamp})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", required=True, type=Path, help="folder with lilium.sss")
    ap.add_argument("--scene", default="lilium")
    ap.add_argument("--size", type=float, default=0.002, help="handle move / bounding-box diagonal")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="folder for warm_resolve.csv")
    a = ap.parse_args(argv)
    rows = run(a.scenes / f"{a.scene}.sss", a.size, a.repeat)
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        write_csv(a.out / "warm_resolve.csv", rows, COLUMNS)
    head = (f"| {'edit':<14} | cold s | cold it | warm s | warm it | speed-up | warm kept | warm err | "
            f"gap/diag | dist cold | dist warm |")
    print(head)
    print("|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|")
    for r in rows:
        print(f"| {r['edit']:<14} | {r['cold_s']:6.3f} | {r['cold_it']:7d} | {r['warm_s']:6.3f} | {r['warm_it']:7d} | "
              f"{r['speedup']:7.1f}x | {'yes' if r['warm_used'] else 'no':>9} | {r['warm_err']:8.1e} | "
              f"{r['gap']:8.1e} | {r['dist_cold']:9.2e} | {r['dist_warm']:9.2e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
