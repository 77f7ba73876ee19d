"""Which of the scenes can carry a point-load case beside the empty one without a degenerate
vertex star: the peel from the free edges (:mod:`formulations.peel`), per scene.

::

    python -m studies.peel --scenes ../shared/paper-scenes/scenes --out out/peel [--only vault cas]

Every scene file in ``--scenes`` (all of them, not only Table 1's), the point load at its highest
free vertex, as in :mod:`studies.load_cases`. Per scene: its faces by size, its free vertices and
those with three edges or fewer (where the peel starts), the edges that carry a weight, the
peel's steps and forced edges, whether it reaches the loaded vertex (then only a network with a
degenerate star can carry both cases, with weights of either sign), and the smallest degeneracy of
its stars at the scene's own positions. The mesh alone decides the peel: no solve, seconds in
all. Writes ``peel.csv`` (stamped: :func:`studies.common.run_stamp`) and prints it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from formulations.peel import MAX_PEELED, star_degeneracy
from studies.common import SCENE_SUFFIXES, STAMP_COLUMNS, Column, markdown_table, read_study_scene, run_stamp, write_csv
from studies.load_cases import highest_free_and_weight, point_peel

COLUMNS = (Column("scene", "scene"), Column("faces", "faces"), Column("free", "free vertices", "{:d}"),
           Column("peel_starts", "free vertices with ≤ 3 edges", "{:d}"), Column("edges", "edges", "{:d}"),
           Column("loaded", "loaded vertex", "{:d}"), Column("steps", "peel steps", "{:d}"),
           Column("forced", "forced edges", "{:d}"), Column("reaches", "reaches the loaded vertex"),
           Column("degeneracy", "smallest star degeneracy (the scene's positions)", "{:.1e}"), *STAMP_COLUMNS)


def faces_text(sizes: np.ndarray) -> str:
    """Faces by size, e.g. ``"80 quads"`` or ``"2300 triangles, 4 quads"``.

    >>> faces_text(np.array([4, 4, 3]))
    '1 triangles, 2 quads'
    """
    names = {3: "triangles", 4: "quads"}
    counts = np.bincount(sizes)
    return ", ".join(f"{c} {names.get(k, f'{k}-gons')}" for k, c in enumerate(counts) if c)


def measure(scene: Any) -> dict[str, Any]:
    """One scene's row (module docstring)."""
    V, free = scene.mesh.vertices, np.flatnonzero(scene.free)
    v = highest_free_and_weight(scene)[0]
    edges = scene.mesh.edges[scene.active_edges]
    valence = np.bincount(edges.ravel(), minlength=scene.mesh.n_vertices)
    peel = point_peel(scene, v)
    return {"scene": scene.name, "faces": faces_text(np.asarray(scene.mesh.face_sizes)), "free": int(free.size),
            "peel_starts": int(np.count_nonzero((valence[free] > 0) & (valence[free] <= MAX_PEELED))),
            "edges": int(edges.shape[0]), "loaded": v, "steps": peel.steps, "forced": int(peel.forced.sum()),
            "reaches": "yes" if peel.blocked else "no",
            "degeneracy": star_degeneracy(peel, V).smallest if peel.steps else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/peel"))
    ap.add_argument("--only", nargs="+", default=None, help="these scenes only (file stems)")
    a = ap.parse_args(argv)
    if not a.scenes.is_dir():
        raise SystemExit(f"no scenes folder {a.scenes}")
    names = a.only or sorted({p.stem for p in a.scenes.iterdir() if p.is_file() and p.suffix in SCENE_SUFFIXES})
    if not names:
        raise SystemExit(f"no scene file in {a.scenes} (looked for {', '.join('*' + x for x in SCENE_SUFFIXES)})")
    stamp = run_stamp()
    rows = [{**measure(read_study_scene(a.scenes, n)), **stamp} for n in names]
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "peel.csv", rows, COLUMNS)
    print(markdown_table(rows, COLUMNS[:-len(STAMP_COLUMNS)]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
