"""The paper's destruction sequence (Fig. 8) on twocirc-3: remove a vertex's 1-ring, see what stands.

::

    python -m studies.destruction --scenes ../shared/paper-scenes/scenes --out out/destruction

Two parts (t = 0.5 m and 0.1 m, ρ = 2500 kg/m³ unless given):

* **The paper's sequence replayed** (when ``SCENES/../published/remove-*-n.obj`` exist). The
  published stages are renumbered networks, so the paper's removals are recovered by position:
  the faces of a stage with no face of the next stage within half a mean edge length (centroids)
  are what went between them; mapped onto twocirc-3 by top-view centroid (a scene face goes
  with the published face nearest to it). A step that removes at
  most :data:`CUT_FRACTION` of the faces is taken as the user's cut and applied; a larger one as
  a collapse, which is not applied: our cascade after the previous cut must predict it. Per paper
  stage: faces left (paper, ours), and how much of what the paper lost we lost too.
* **One removal** (``--remove VERTEX``, default the highest free vertex), at the first thickness:
  its 1-ring deleted, the cascade run (:func:`selfsupport.structure.destruction.destroy`).

The hull's mid-surface is, by default, the design's own thrust network — the vault as built (the
published stage 0 is a network, 3.8 m below twocirc-3's reference at the top); ``--reference
scene`` uses the scene's surface. Writes ``destruction.csv`` (the replay, one row per paper step
and thickness, each stamped: :func:`studies.common.run_stamp`), ``destruction.md``, ``.json``,
``stages.png`` / ``replay-tT.png`` and each stage's network.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from studies.common import STAMP_COLUMNS, Column, run_stamp, write_csv, write_markdown

COLUMNS = [Column("stage", "stage"), Column("faces", "faces (ours)"), Column("paper_faces", "faces (paper)"),
           Column("paper_file", "paper file"), Column("status", "status (ours)"), Column("why", "removed before"),
           Column("outside", "outside"), Column("max_hull_excess_m", "max excess [m]", "{:.3g}"),
           Column("max_relative_error", "max rel. error", "{:.1e}")]


#: A published step that removes at most this fraction of the faces is a cut, a larger one a collapse.
CUT_FRACTION = 0.1

REPLAY_COLUMNS = [Column("paper_stage", "paper stage"), Column("kind", "paper step"),
                  Column("paper_faces", "faces (paper)"), Column("faces", "faces (ours)"),
                  Column("paper_lost", "lost (paper, mapped)"), Column("lost_too", "of these lost by us"),
                  Column("our_stages", "our stages"), Column("status", "status (ours)")]
#: destruction.csv: the replay at every thickness
CSV_COLUMNS = (Column("thickness_m", "t [m]", "{:g}"), Column("step", "step"), *REPLAY_COLUMNS,
               Column("paper_before", "faces before (paper)"), *STAMP_COLUMNS)


def _faces_in(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.startswith("f "))


def _obj(path: Path) -> tuple[np.ndarray, list[list[int]]]:
    """Vertices (z up: the files' y points down) and 0-based faces of a published OBJ."""
    V, F = [], []
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            V.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            F.append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
    P = np.array(V)
    return np.c_[P[:, 0], P[:, 2], -P[:, 1]], F


def built_vault(scene: Any, *, density: float, thickness: float) -> Any:
    """The vault as built: the scene with its thrust network (staggered method, self-weight) as
    the reference — the published stage 0 is such a network (3.8 m below twocirc-3's reference
    at the top), and it is what the paper takes apart."""
    import dataclasses

    from selfsupport import api

    res = api.solve(scene, density=density, thickness=thickness)
    if res.status != "converged":
        raise SystemExit(f"the intact vault has no network in equilibrium ({res.status}): {res.message}")
    return dataclasses.replace(scene, mesh=scene.mesh.with_vertices(res.network.vertices))


def paper_steps(scene: Any, files: Sequence[Path]) -> list[dict[str, Any]]:
    """Per published step k (files[k-1] → files[k]): the scene's faces mapped from what went, and
    whether it is a cut or a collapse (:data:`CUT_FRACTION`)."""
    from scipy.spatial import cKDTree

    def centroids(P: np.ndarray, F: Sequence[Sequence[int]]) -> np.ndarray:
        return np.array([P[f].mean(axis=0) for f in F])

    mesh = scene.mesh
    C_scene = centroids(mesh.vertices, mesh.faces)
    lost = np.zeros(len(C_scene), dtype=bool)
    steps = []
    prev_P, prev_F = _obj(files[0])
    for f in files[1:]:
        P, F = _obj(f)
        edge = float(np.mean([np.linalg.norm(P[a] - P[b]) for face in F for a, b in zip(face, np.roll(face, -1))]))
        C_prev = centroids(prev_P, prev_F)
        gone = cKDTree(centroids(P, F)).query(C_prev)[0] > 0.5 * edge
        # each scene face goes with the published face nearest to it in the top view (a lost
        # face's nearest scene face alone under-maps where the two meshes' faces differ in size)
        owner = cKDTree(C_prev[:, :2]).query(C_scene[:, :2])[1]
        mapped = np.flatnonzero(gone[owner] & ~lost).tolist()
        lost[mapped] = True  # (a face lost earlier has a present neighbour as its owner now)
        steps.append({"file": f.name, "paper_faces": len(F), "paper_before": len(prev_F), "paper_lost": mapped,
                      "kind": "cut" if gone.sum() <= CUT_FRACTION * len(prev_F) else "collapse"})
        prev_P, prev_F = P, F
    return steps


def replay(scene: Any, steps: Sequence[Mapping[str, Any]], *, thickness: float, density: float,
           max_stages: int) -> tuple[list[dict[str, Any]], list[Any]]:
    """Apply the paper's cuts in turn, each followed by our cascade; compare every step."""
    from selfsupport.structure.destruction import destroy

    faces = list(range(scene.mesh.n_faces))
    rows, shown = [], []
    for k, st in enumerate(steps, start=1):
        before = set(faces)
        n_stages, status = 0, "(collapse not applied: predicted?)"
        if st["kind"] == "cut":
            stages = destroy(scene, remove_faces=st["paper_lost"], faces=faces, thickness=thickness,
                             density=density, max_stages=max_stages,
                             progress=lambda s: print(f"step {k}, stage {s.index}: {s.n_faces} faces, {s.status}",
                                                      file=sys.stderr))
            shown += stages[1:] if shown else stages
            faces, n_stages, status = list(stages[-1].faces), len(stages) - 1, stages[-1].status
        lost_paper = set(st["paper_lost"]) & before
        lost_ours = set().union(*[set(range(scene.mesh.n_faces)) - set(faces)])
        rows.append({"step": k, "paper_stage": st["file"], "kind": st["kind"], "paper_faces": st["paper_faces"],
                     "paper_before": st["paper_before"],
                     "faces": len(faces), "paper_lost": len(lost_paper),
                     "lost_too": len(lost_paper & lost_ours), "our_stages": n_stages, "status": status})
    return rows, shown


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", required=True)
    ap.add_argument("--published", default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--scene", default="twocirc-3")
    ap.add_argument("--remove", type=int, action="append", default=None, help="default: the highest free vertex")
    ap.add_argument("--thickness", default="0.5,0.1",
                    help="hull thicknesses [m], comma-separated (the one removal: the first)")
    ap.add_argument("--density", type=float, default=2500.0)
    ap.add_argument("--max-stages", type=int, default=20)
    ap.add_argument("--reference", choices=["network", "scene"], default="network",
                    help="the hull's mid-surface: the design's thrust network, i.e. the vault as built (default), "
                         "or the scene's reference surface")
    args = ap.parse_args(argv)
    thicknesses = [float(t) for t in args.thickness.split(",") if t.strip()]

    from selfsupport.figures.hull import stage_strip
    from selfsupport.io import read_scene, write_network
    from selfsupport.structure.destruction import destroy

    scenes = Path(args.scenes)
    pub = Path(args.published) if args.published else scenes.parent / "published"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stamp = run_stamp()
    read = read_scene(scenes / f"{args.scene}.sss", name=args.scene)
    paper = [("remove-original.obj", pub / "remove-original.obj")] + [
        (f"remove-{k}-n.obj", pub / f"remove-{k}-n.obj") for k in range(1, 5)]
    replay_rows: list[dict[str, Any]] = []
    built: dict[float, Any] = {}
    for t in thicknesses:
        scene = built_vault(read, density=args.density, thickness=t) if args.reference == "network" else read
        built[t] = scene
        if all(f.is_file() for _, f in paper):
            steps = paper_steps(scene, [f for _, f in paper])
            rows_t, shown = replay(scene, steps, thickness=t, density=args.density, max_stages=args.max_stages)
            replay_rows += [{"thickness_m": t, **r} for r in rows_t]
            stage_strip(shown, out / f"replay-t{t:g}.png", thickness=t)
    t0 = thicknesses[0]
    scene = built[t0]
    remove = args.remove or [int(np.flatnonzero(scene.free)[np.argmax(scene.mesh.vertices[scene.free, 2])])]
    stages = destroy(scene, remove, thickness=t0, density=args.density, max_stages=args.max_stages,
                     progress=lambda s: print(f"stage {s.index}: {s.n_faces} faces, {s.status}", file=sys.stderr))
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
    stage_strip(stages, out / "stages.png", thickness=t0)
    notes = [f"{args.scene}: {scene.mesh.n_vertices} vertices, {scene.mesh.n_faces} faces; t = "
             f"{', '.join(f'{t:g}' for t in thicknesses)} m (the one removal: {t0:g} m), "
             f"ρ = {args.density:g} kg/m³; the hull's mid-surface: "
             + ("the design's thrust network (the vault as built)" if args.reference == "network" else
                "the scene's reference surface"),
             "orphaned vertices are dropped; pieces without a support and faces around hinge vertices are deleted",
             "the paper's removed vertex is not known (remove-original.obj is renumbered), so the sequences start "
             "differently; only face counts are compared",
             "replay: the paper's cuts recovered by position from the published stages (see the module docstring); "
             "a step removing more than "
             f"{CUT_FRACTION:.0%} of the faces is a collapse our cascade must predict, not a cut",
             f"command: python -m studies.destruction --scenes {args.scenes} --out {args.out}"]
    tables = ([("The paper's sequence replayed", replay_rows, [CSV_COLUMNS[0], *REPLAY_COLUMNS])]
              if replay_rows else []) + [
        (f"One removal: the 1-ring of vertex {remove}", rows, COLUMNS)]
    text = write_markdown(out / "destruction.md", "Destruction sequence", notes, tables)
    (out / "destruction.json").write_text(json.dumps({"replay": replay_rows, "one_removal": rows}, indent=1,
                                                     default=float) + "\n", encoding="utf-8")
    write_csv(out / "destruction.csv", [{**r, **stamp} for r in replay_rows], CSV_COLUMNS)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
