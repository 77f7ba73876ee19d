"""The paper's dome experiment (Figs. 9–10): does dome2 stand under added load, thin and thick?

::

    python -m studies.stability_dome --scenes ../shared/paper-scenes/scenes --out out/stability_dome

dome2.sss, ρ = 2500 kg/m³, t = 0.1 m and 1 m, added 0 / 5,000 / 10,000 / 15,000 / 20,000 kg at
the apex (:func:`selfsupport.structure.stability.stability_series`). Per thickness and
load: found or not (a compressive network in equilibrium inside reference ± t/2), max relative
error, max hull excess, vertices outside, and the distance to the paper's published network
``DIR/../published/dome2-<load>kg-n.obj`` — per vertex (same vertex count, order assumed shared)
and order-free (mean closest-vertex distance, both ways). One figure per load
(:func:`selfsupport.figures.hull.hull_figure`). Writes ``stability_dome.md``, ``.json`` and the
networks.

The experiment's configuration, not the .sss's (``--as-stored`` uses the file as it is): dome2.sss
was saved in another state of the original tool — it pins a cap of vertices around the apex and
leaves 26 boundary vertices on the ground free (a free vertex on the ground has no vertical
force to balance its weight: the network lifts it, 7 m on this dome, so nothing fits in any
hull), and its one handled vertex lies on the ground at the opening. In the published load series
the vertex that moves most with the load is the apex and the ground ring stays down. So, by
default, the study supports the dome on its boundary vertices on the ground (height within 1% of
the rise) and loads the highest free vertex.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import Column, write_markdown

LOADS = (0.0, 5000.0, 10000.0, 15000.0, 20000.0)
THICKNESSES = (0.1, 1.0)
DENSITY = 2500.0
#: published file tag per added load
PUBLISHED = {0.0: "0", 5000.0: "5K", 10000.0: "10K", 15000.0: "15K", 20000.0: "20K"}

COLUMNS = [Column("thickness_m", "t [m]", "{:g}"), Column("added_kg", "added [kg]", "{:g}"),
           Column("found", "inside hull"), Column("status", "status"),
           Column("max_relative_error", "max rel. error", "{:.1e}"),
           Column("max_hull_excess_m", "max excess [m]", "{:.3g}"), Column("outside", "outside"),
           Column("penalty", "penalty"), Column("moved_max_m", "max move from ref. [m]", "{:.3g}"),
           Column("pub_vertex_mean_m", "pub. dist. per vertex mean [m]", "{:.3g}"),
           Column("pub_nearest_mean_m", "pub. dist. nearest mean [m]", "{:.3g}"),
           Column("pub_loaded_move_m", "pub.: max move vs 0 kg [m]", "{:.3g}"),
           Column("ours_loaded_move_m", "ours: max move vs 0 kg [m]", "{:.3g}"),
           Column("seconds", "time [s]", "{:.1f}")]


def network_distances(A: np.ndarray, B: np.ndarray) -> dict[str, float]:
    """Per-vertex distances (same order assumed) and the order-free symmetric mean nearest-vertex
    distance between two vertex sets [m]."""
    from scipy.spatial import cKDTree

    out: dict[str, float] = {"nearest_mean": float(0.5 * (cKDTree(B).query(A)[0].mean() + cKDTree(A).query(B)[0].mean()))}
    if A.shape == B.shape:
        d = np.linalg.norm(A - B, axis=1)
        out.update(vertex_mean=float(d.mean()), vertex_max=float(d.max()))
    return out


def experiment_configuration(scene: Any, ground_rel: float = 0.01) -> tuple[Any, list[int]]:
    """The scene supported on its boundary vertices on the ground (height within ``ground_rel``
    of the rise above the lowest vertex) and the highest free vertex to load."""
    import dataclasses

    z = scene.mesh.vertices[:, 2]
    ground = scene.mesh.boundary_vertex_mask & (z <= z.min() + ground_rel * np.ptp(z))
    apex = int(np.argmax(np.where(ground, -np.inf, z)))
    return dataclasses.replace(scene, supports=ground, handles=None), [apex]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", required=True, help="folder with dome2.sss")
    ap.add_argument("--published", default=None, help="folder with dome2-*kg-n.obj (default SCENES/../published)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--thickness", default=",".join(f"{t:g}" for t in THICKNESSES))
    ap.add_argument("--loads", default=",".join(f"{k:g}" for k in LOADS))
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--as-stored", action="store_true",
                    help="the .sss's own pins and handled vertices instead of the experiment's ground ring and apex")
    args = ap.parse_args(argv)

    from selfsupport.figures.hull import hull_figure
    from selfsupport.io import read_scene, write_network
    from selfsupport.structure.stability import stability_series

    scenes = Path(args.scenes)
    pub_dir = Path(args.published) if args.published else scenes.parent / "published"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = read_scene(scenes / "dome2.sss", name="dome2")
    at = None  # the handled vertices
    if not args.as_stored:
        scene, at = experiment_configuration(scene)
    loads = [float(x) for x in args.loads.split(",")]
    published: dict[float, np.ndarray] = {}
    for kg, tag in PUBLISHED.items():
        p = pub_dir / f"dome2-{tag}kg-n.obj"
        if p.is_file():
            published[kg] = read_scene(p, up="-y", supports="boundary").mesh.vertices
    rows: list[dict[str, Any]] = []
    for t in [float(x) for x in args.thickness.split(",")]:
        base = None
        steps = stability_series(scene, thickness=t, loads_kg=loads, density=DENSITY, at=at,
                                 progress=lambda s: print(f"t={t:g} m, {s.kg:g} kg: {s.result.status} "
                                                          f"({s.result.wall_time:.1f} s)", file=sys.stderr))
        for s in steps:
            V = s.result.network.vertices
            base = V if s.kg == 0 else base
            row = {"thickness_m": t, **s.row(), "moved_max_m": float(np.linalg.norm(V - scene.mesh.vertices, axis=1).max())}
            if s.kg in published:
                d = network_distances(V, published[s.kg])
                row.update(pub_vertex_mean_m=d.get("vertex_mean"), pub_nearest_mean_m=d["nearest_mean"])
                if 0.0 in published:
                    row["pub_loaded_move_m"] = float(np.linalg.norm(published[s.kg] - published[0.0], axis=1).max())
            if base is not None:
                row["ours_loaded_move_m"] = float(np.linalg.norm(V - base, axis=1).max())
            rows.append(row)
            name = f"t{t:g}-{s.kg:g}kg"
            write_network(out / f"{name}.json", s.result, added_mass_kg=s.kg, load_at=list(s.at))
            if not args.no_figures:
                verdict = "stands (certified)" if s.certified else "not certified"
                hull_figure(s.result.network, out / f"{name}.png", thickness=t, reference=scene.mesh,
                            title=f"dome2, t = {t:g} m, +{s.kg:g} kg at {list(s.at)}: {verdict}")
    pub_note = []
    if published:
        P0 = published.get(0.0)
        pub_note.append("published dome2-*kg-n.obj vs the scene: mean closest-vertex distance "
                        f"{network_distances(P0, scene.mesh.vertices)['nearest_mean']:.3g} m (0 kg) — the published "
                        "networks are not solves of dome2.sss as stored (their pins differ: the vertex that moves most "
                        "with load in them, 0, is pinned in the .sss, and their ground ring is drawn in by up to "
                        "2.5 m)" if P0 is not None else "")
    where = (f"the handled vertices {list(np.flatnonzero(scene.handles)) if scene.handles is not None else []} "
             "(the .sss as stored)" if at is None else
             f"the apex (vertex {at[0]}), supported on the {int(scene.supports.sum())} boundary vertices on the ground "
             "(the experiment's configuration, see the module docstring; --as-stored for the file's own pins)")
    notes = [f"dome2.sss ({scene.mesh.n_vertices} vertices), ρ = {DENSITY:g} kg/m³, added mass at {where}; hull search: "
             "selfsupport.methods.hull_search.solve_in_hull (staggered: no hull, then the hull as an active set)",
             "paper: Fig. 9, t = 0.1 m, a network inside the hull under an added 11,000 kg; Fig. 10, t = 1 m, "
             "0 / 5,000 / 10,000 / 20,000 kg, the network leaving the hull as the load grows", *pub_note,
             f"command: python -m studies.stability_dome --scenes {args.scenes} --out {args.out}"]
    text = write_markdown(out / "stability_dome.md", "Stability of dome2 under added load", notes,
                          [("", rows, COLUMNS)])
    (out / "stability_dome.json").write_text(json.dumps(rows, indent=1, default=float) + "\n", encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
