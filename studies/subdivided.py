"""Subdivided designs: a paper scene refined by Catmull–Clark for
fabrication, solved on one level and by levels.

    python -m studies.subdivided --scenes ../shared/paper-scenes/scenes --out OUT
        [--only lilium,cyl2] [--levels 1,2] [--methods staggered,multilevel,multilevel/clusters]
        [--time-limit S] [--checker PATH] [--variants none,turned,flat,tall,bumpy,mirrored]

Each scene of Table 1 found in ``--scenes`` (:data:`studies.common.PAPER_TABLE1`; in a folder
without any, every scene file there: :func:`studies.common.study_scenes`) is subdivided
``--levels`` times (:func:`selfsupport.core.subdivision.subdivide_scene`: quads, supports kept
along creases).
That is how a designer takes a 1k-vertex design to 7k, 28k or 110k vertices. The multilevel
method solves the scenes it was refined from as its levels (the designer's own hierarchy);
``multilevel/clusters`` coarsens the subdivided top view instead, as for any other mesh. Then one
row per method:
- wall time of the ``solve()`` call alone (subdivision, imports and a warm-up solve of a tiny
  dome excluded);
- outer iterations, and the levels of a multilevel solve;
- status;
- the max relative error, recomputed from the saved JSON network, and the shared independent
  checker's (``--checker``);
- the mean distance to the subdivided reference, over its bounding-box diagonal;
- the peak memory of the row.

``--variants`` also runs each scene as variants no solver setting was chosen on (turned, scaled
and moved; flatter; taller; bumpy; mirrored: :data:`studies.variants.VARIANTS`), each before it
is subdivided, as a held-out check; ``--levels 0`` keeps the designs as they are.

Every row runs in its own spawned process (:func:`studies.common.run_isolated`). A crash, a
hang or a memory blow-up costs that row only.

Writes ``subdivided.csv``, ``subdivided.md`` and one ``SCENE-xLEVELS__METHOD.json`` network per
row into ``--out``, and prints the Markdown.
"""
from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path
from typing import Any, Sequence

from .common import (
    Column,
    Stopwatch,
    current_rss_mib,
    exit_on_sigterm,
    json_max_relative_error,
    load_average,
    peak_rss_mib,
    read_study_scene,
    run_checker,
    run_isolated,
    study_scenes_or_exit,
    write_csv,
    write_markdown,
)
from .variants import VARIANTS, variant_scene

#: method names; ``multilevel`` solves the designer's coarser scenes first (the subdivision's own
#: hierarchy), ``multilevel/clusters`` coarsens the subdivided top view like any other mesh
METHODS = ("staggered", "multilevel", "multilevel/clusters")


def _solver(method: str) -> Any:
    from selfsupport.api import make_method
    from selfsupport.methods.multilevel import Multilevel

    return Multilevel(use_subdivision=False) if method == "multilevel/clusters" else make_method(method)


def solve_row(*, scenes_dir: str, scene_name: str, levels: int, method: str, out_json: str, time_limit: float,
              warmup: bool = True, variant: str = "none") -> dict[str, Any]:
    """Worker (own process): subdivide the scene, solve it, save the network, return the row."""
    from selfsupport.api import scene_loads
    from selfsupport.core.shapes import make_shape
    from selfsupport.core.subdivision import subdivide_scene
    from selfsupport.io import write_network

    design = variant_scene(read_study_scene(scenes_dir, scene_name), variant)
    scene = subdivide_scene(design, levels) if levels else design
    loads = scene_loads(scene)
    if warmup:  # solver plug-ins and caches, untimed
        tiny = make_shape("dome", n_vertices=60)
        _solver(method).solve(tiny, scene_loads(tiny), time_limit=30.0)
    solver = _solver(method)
    rss0 = current_rss_mib()
    with Stopwatch() as sw:
        res = solver.solve(scene, loads, time_limit=float(time_limit))
    write_network(out_json, res, study={"scene": scene_name, "variant": variant, "subdivisions": levels, "method": method,
                                        "solve_seconds": sw.seconds, "time_limit": time_limit})
    ml = res.parameters.get("multilevel", {}).get("levels", [])
    quads = int((scene.mesh.face_sizes == 4).sum())
    return {"vertices": scene.mesh.n_vertices, "edges": scene.mesh.n_edges,
            "quad_share": quads / max(scene.mesh.n_faces, 1), "status": res.status, "time_s": sw.seconds,
            "iterations": res.iterations, "reported_error": res.max_relative_error,
            "distance_mean": res.distance_mean,
            "levels": " → ".join(f"{lv['n_vertices']}:{lv['iterations']}" for lv in ml) if len(ml) > 1 else "",
            "message": res.message, "peak_rss_mib": peak_rss_mib(), "rss_before_mib": rss0}


COLUMNS = [
    Column("scene", "scene"), Column("variant", "variant"), Column("subdivisions", "subdivisions"), Column("vertices", "V"),
    Column("edges", "E"), Column("quad_share", "quads", "{:.0%}"), Column("method", "method"),
    Column("levels", "levels (V:its)"), Column("status", "status"), Column("time_s", "time [s]", "{:.2f}"),
    Column("iterations", "iterations"), Column("max_rel_error", "max rel. error", "{:.1e}"),
    Column("checker_error", "checker error", "{:.1e}"), Column("distance_mean", "dist. to ref. mean", "{:.3e}"),
    Column("peak_rss_mib", "peak RSS [MiB]", "{:.0f}"), Column("message", "message"),
]


def run(*, scenes: Path, out: Path, names: Sequence[str], levels: Sequence[int], methods: Sequence[str],
        time_limit: float, checker: Path | None, warmup: bool = True,
        variants: Sequence[str] = ("none",)) -> list[dict[str, Any]]:
    """Every (scene, variant, levels, method) row, each in its own process; the tables are rewritten after
    each row (a long run can be read while it goes on)."""
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for name, variant, k, method in itertools.product(names, variants, levels, methods):
        tag = name if variant == "none" else f"{name}-{variant}"
        net = out / f"{tag}-x{k}__{method.replace('/', '-')}.json"
        print(f"{tag} ×{k} {method} ...", file=sys.stderr, flush=True)
        row = {"scene": name, "variant": variant, "subdivisions": k, "method": method, **run_isolated(
            "studies.subdivided:solve_row",
            {"scenes_dir": str(scenes), "scene_name": name, "levels": k, "method": method,
             "out_json": str(net), "time_limit": time_limit, "warmup": warmup, "variant": variant},
            hard_timeout=time_limit + 600.0)}
        if net.is_file() and row.get("status") not in ("killed", "crashed"):
            row["max_rel_error"] = json_max_relative_error(net)
            row["checker_error"] = run_checker(checker, net)
        rows.append(row)
        print(f"    {row.get('status')}: {row.get('vertices')} V, {row.get('time_s', float('nan')):.1f} s, "
              f"error {row.get('max_rel_error', float('nan')):.1e}", file=sys.stderr, flush=True)
        _write(out, rows, scenes, time_limit)
    return rows


def _write(out: Path, rows: list[dict[str, Any]], scenes: Path, time_limit: float) -> str:
    write_csv(out / "subdivided.csv", rows, COLUMNS)
    notes = [
        "Scenes subdivided by Catmull–Clark (`subdivide_scene`: quads, supports kept along creases); "
        f"scenes: `{scenes}`; time limit {time_limit:g} s per row.",
        "*time*: the `solve()` call alone, each row in its own process (subdivision, imports and a warm-up "
        "solve excluded); *max rel. error* recomputed from the saved JSON network, *checker error* the shared "
        "`check_network.py` on the same file; distances over the reference's bounding-box diagonal.",
        f"Load average at the end (1/5/15 min): {load_average()} — shared machine, timings are noisy.",
    ]
    return write_markdown(out / "subdivided.md", "Subdivided designs", notes, [("Rows", rows, COLUMNS)])


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", required=True, type=Path, help="folder with the paper's scene files")
    p.add_argument("--out", required=True, type=Path, help="output folder (created)")
    p.add_argument("--only", default="", help="comma-separated scene names (default: the Table 1 scenes in "
                                              "--scenes, or, with none there, every scene file in it)")
    p.add_argument("--levels", default="2", help="comma-separated numbers of Catmull–Clark steps (default 2)")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, from {', '.join(METHODS)}")
    p.add_argument("--time-limit", type=float, default=900.0, help="per-row time limit [s] (default 900)")
    p.add_argument("--checker", type=Path, default=None,
                   help="check_network.py (default: ../tools/check_network.py next to --scenes)")
    p.add_argument("--no-warmup", action="store_true", help="skip the untimed warm-up solve")
    p.add_argument("--variants", default="none",
                   help=f"comma-separated variants of each scene, from {', '.join(VARIANTS)} (default none)")
    a = p.parse_args(argv)
    methods = [m for m in a.methods.split(",") if m]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise SystemExit(f"unknown method(s) {bad}; choose from {', '.join(METHODS)}")
    try:
        levels = [int(k) for k in a.levels.split(",") if k]
    except ValueError:
        raise SystemExit(f"--levels takes comma-separated integers, got {a.levels!r}") from None
    variants = [v for v in a.variants.split(",") if v]
    if not variants or any(v not in VARIANTS for v in variants):
        raise SystemExit(f"--variants takes names from {', '.join(VARIANTS)}, got {a.variants!r}")
    if not levels or min(levels) < 0:
        raise SystemExit(f"--levels takes integers >= 0, got {a.levels!r}")
    names = study_scenes_or_exit(a.scenes, [s for s in a.only.split(",") if s])
    checker = a.checker if a.checker is not None else a.scenes.resolve().parent.parent / "tools" / "check_network.py"
    exit_on_sigterm()
    rows = run(scenes=a.scenes, out=a.out, names=names, levels=levels, methods=methods, time_limit=a.time_limit,
               checker=checker, warmup=not a.no_warmup, variants=variants)
    print((a.out / "subdivided.md").read_text(encoding="utf-8"))
    return rows


if __name__ == "__main__":
    main()
