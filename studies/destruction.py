"""The paper's destruction sequence (Fig. 8) on twocirc-3: remove a vertex's 1-ring, see what stands.

::

    python -m studies.destruction --scenes ../shared/paper-scenes/scenes --out out/destruction

Runs :func:`selfsupport.destruction.destroy` (default: the highest free vertex, t = 0.5 m,
ρ = 2500 kg/m³) and compares the faces left per stage with the paper's ``remove-*-n.obj``
(``SCENES/../published``; remove-original's vertex order does not match twocirc-3, so only face
counts are compared). Writes ``destruction.md``, ``.json``, ``stages.png`` and each stage's network.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import Column, write_markdown

COLUMNS = [Column("stage", "stage"), Column("faces", "faces (ours)"), Column("paper_faces", "faces (paper)"),
           Column("paper_file", "paper file"), Column("status", "status (ours)"), Column("why", "removed before"),
           Column("outside", "outside"), Column("max_hull_excess_m", "max excess [m]", "{:.3g}"),
           Column("max_relative_error", "max rel. error", "{:.1e}")]


def _faces_in(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.startswith("f "))


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", required=True)
    ap.add_argument("--published", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--scene", default="twocirc-3")
    ap.add_argument("--remove", type=int, action="append", default=None, help="default: the highest free vertex")
    ap.add_argument("--thickness", type=float, default=0.5)
    ap.add_argument("--density", type=float, default=2500.0)
    ap.add_argument("--max-stages", type=int, default=8)
    args = ap.parse_args(argv)

    from selfsupport.destruction import destroy
    from selfsupport.figures.hull import stage_strip
    from selfsupport.io import read_scene, write_network

    scenes = Path(args.scenes)
    pub = Path(args.published) if args.published else scenes.parent / "published"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = read_scene(scenes / f"{args.scene}.sss", name=args.scene)
    remove = args.remove or [int(np.flatnonzero(scene.free)[np.argmax(scene.mesh.vertices[scene.free, 2])])]
    stages = destroy(scene, remove, thickness=args.thickness, density=args.density, max_stages=args.max_stages,
                     progress=lambda s: print(f"stage {s.index}: {s.n_faces} faces, {s.status}", file=sys.stderr))
    paper = [("remove-original.obj", pub / "remove-original.obj")] + [
        (f"remove-{k}-n.obj", pub / f"remove-{k}-n.obj") for k in range(1, 5)]
    rows: list[dict[str, Any]] = []
    for s in stages:
        row = s.row()
        if s.index < len(paper) and paper[s.index][1].is_file():
            row.update(paper_file=paper[s.index][0], paper_faces=_faces_in(paper[s.index][1]))
        rows.append(row)
        if s.result is not None:
            write_network(out / f"stage-{s.index}.json", s.result, stage=s.index, stage_status=s.status,
                          original_vertices=list(s.vertices), faces_removed=list(s.removed))
    for k in range(len(stages), len(paper)):
        if paper[k][1].is_file():
            rows.append({"stage": k, "paper_file": paper[k][0], "paper_faces": _faces_in(paper[k][1])})
    stage_strip(stages, out / "stages.png", thickness=args.thickness)
    notes = [f"{args.scene}: {scene.mesh.n_vertices} vertices, {scene.mesh.n_faces} faces; removed the 1-ring of "
             f"vertex {remove}; t = {args.thickness:g} m, ρ = {args.density:g} kg/m³",
             "orphaned vertices are dropped; pieces without a support and faces around hinge vertices are deleted",
             "the paper's removed vertex is not known (remove-original.obj is renumbered), so the sequences start "
             "differently; only face counts are compared",
             f"command: python -m studies.destruction --scenes {args.scenes} --out {args.out}"]
    text = write_markdown(out / "destruction.md", "Destruction sequence", notes, [("", rows, COLUMNS)])
    (out / "destruction.json").write_text(json.dumps(rows, indent=1, default=float) + "\n", encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
