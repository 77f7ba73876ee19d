"""The paper's dome experiment (Figs. 9–10): does dome2 stand under added load, thin and thick?

::

    python -m studies.stability_dome --scenes ../shared/paper-scenes/scenes --out out/stability_dome

dome2.sss, ρ = 2500 kg/m³, t = 0.1 m and 1 m, added 0 / 5,000 / 10,000 / 11,000 / 15,000 /
20,000 kg at the apex (:func:`selfsupport.structure.stability.stability_series`). Per thickness and
load: found or not (a compressive network in equilibrium inside reference ± t/2), max relative
error, max hull excess, vertices outside, and the distance to the paper's published network
``DIR/../published/dome2-<load>kg-n.obj`` — per vertex (same vertex count, order assumed shared)
and order-free (mean closest-vertex distance, both ways). Then the largest certified load per
thickness of ``--max-load-thickness`` (:func:`selfsupport.structure.limit.limit_load`: one limit
program, its optimum certified by its network). One figure per load
(:func:`selfsupport.figures.hull.hull_figure`). Writes ``stability_dome.csv`` (the series, with
one row of the file as stored), ``stability_dome_max_load.csv`` (the largest loads), each row
stamped (:func:`studies.common.run_stamp`), ``stability_dome.md``, ``.json`` and the networks.

The experiment's configuration, not the .sss's (``--as-stored`` uses the file as it is): dome2.sss
was saved in another state of the original tool — it pins a cap of vertices around the apex and
leaves 26 boundary vertices on the ground free (a free vertex on the ground has no vertical
force to balance its weight: the network lifts it, so nothing fits in a thin hull), and its one
handled vertex lies on the ground at the opening. In the published load series
the vertex that moves most with the load is the apex and the ground ring stays down. So, by
default, the study supports the dome on its boundary vertices on the ground (height within 1% of
the rise) and loads the highest free vertex; the CSV's first row is the file as stored, unloaded,
at the first thickness, to show that it does not fit.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import STAMP_COLUMNS, Column, run_stamp, write_csv, write_markdown

#: the published series' loads, and the load of Fig. 9 (11,000 kg)
LOADS = (0.0, 5000.0, 10000.0, 11000.0, 15000.0, 20000.0)
#: Fig. 9's thickness and Fig. 10's
THICKNESSES = (0.1, 1.0)
#: thicknesses of the largest-load programs (the paper's two and between)
MAX_LOAD_THICKNESSES = (0.05, 0.1, 0.2, 0.5, 1.0)
DENSITY = 2500.0
#: the two configurations of the series' rows
EXPERIMENT, AS_STORED = "ground ring, apex loaded", "as stored"
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

#: stability_dome.csv
CSV_COLUMNS = (Column("configuration", "configuration"), *COLUMNS, Column("hull_tolerance_m", "hull tolerance [m]"),
               *STAMP_COLUMNS)
#: stability_dome_max_load.csv
MAX_LOAD_COLUMNS = (Column("thickness_m", "t [m]", "{:g}"), Column("verdict", "verdict"),
                    Column("max_load_kg", "certified max load [kg]", "{:.0f}"),
                    Column("optimum_kg", "program's optimum [kg]", "{:.0f}"), Column("binding", "vertices on the hull's faces"),
                    Column("max_relative_error", "max rel. error", "{:.1e}"), Column("ipopt_status", "IPOPT status"),
                    Column("seconds", "time [s]", "{:.0f}"), Column("time_limit_s", "limit [s]", "{:g}"),
                    Column("message", "message"), *STAMP_COLUMNS)


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


def series_rows(scene: Any, at: list[int] | None, thickness: float, loads: Sequence[float],
                published: dict[float, np.ndarray], out: Path, *, configuration: str,
                figures: bool) -> list[dict[str, Any]]:
    """One row per added load at one thickness (:func:`stability_series`), its network written
    to ``out`` (and its figure)."""
    from selfsupport.figures.hull import hull_figure
    from selfsupport.io import write_network
    from selfsupport.structure.stability import stability_series

    rows: list[dict[str, Any]] = []
    base = None
    steps = stability_series(scene, thickness=thickness, loads_kg=loads, density=DENSITY, at=at,
                             progress=lambda s: print(f"{configuration}, t={thickness:g} m, {s.kg:g} kg: "
                                                      f"{s.result.status} ({s.result.wall_time:.1f} s)", file=sys.stderr))
    for s in steps:
        V = s.result.network.vertices
        base = V if s.kg == 0 else base
        row = {"configuration": configuration, "thickness_m": thickness, **s.row(),
               "moved_max_m": float(np.linalg.norm(V - scene.mesh.vertices, axis=1).max())}
        if s.kg in published:
            d = network_distances(V, published[s.kg])
            row.update(pub_vertex_mean_m=d.get("vertex_mean"), pub_nearest_mean_m=d["nearest_mean"])
            if 0.0 in published:
                row["pub_loaded_move_m"] = float(np.linalg.norm(published[s.kg] - published[0.0], axis=1).max())
        if base is not None:
            row["ours_loaded_move_m"] = float(np.linalg.norm(V - base, axis=1).max())
        rows.append(row)
        name = f"{'stored-' if configuration == AS_STORED else ''}t{thickness:g}-{s.kg:g}kg"
        write_network(out / f"{name}.json", s.result, added_mass_kg=s.kg, load_at=list(s.at))
        if figures:
            verdict = "stands (certified)" if s.certified else "not certified"
            hull_figure(s.result.network, out / f"{name}.png", thickness=thickness, reference=scene.mesh,
                        title=f"dome2, t = {thickness:g} m, +{s.kg:g} kg at {list(s.at)}: {verdict}")
    return rows


def max_load_row(scene: Any, at: list[int] | None, thickness: float, out: Path, *, time_limit: float) -> dict[str, Any]:
    """The largest certified added mass at ``at`` for one thickness (one limit program), its
    certificate written to ``out``."""
    from selfsupport.io import write_network
    from selfsupport.structure.limit import limit_load

    t0 = time.perf_counter()
    r = limit_load(scene, thickness=thickness, density=DENSITY, at=at, time_limit=time_limit)
    seconds = time.perf_counter() - t0
    print(f"max load, t={thickness:g} m: {r.message} ({seconds:.0f} s)", file=sys.stderr)
    if r.certificate is not None:
        write_network(out / f"max-load-t{thickness:g}.json", r.certificate, max_load_kg=r.value, verdict=r.verdict)
    return {"thickness_m": thickness, "verdict": r.verdict, "max_load_kg": r.value, "optimum_kg": r.optimum,
            "binding": len(r.binding), "ipopt_status": r.ipopt_status, "seconds": seconds, "time_limit_s": time_limit,
            "max_relative_error": r.certificate.max_relative_error if r.certificate is not None else None,
            "message": r.message}


#: stability_dome_starts.csv: the max-load program at Fig. 9's thickness from many starts
STARTS_COLUMNS = (Column("start", "start"), Column("thickness_m", "t [m]", "{:g}"), Column("load_at", "load at"),
                  Column("verdict", "verdict"), Column("max_load_kg", "certified [kg]", "{:.0f}"),
                  Column("optimum_kg", "program's optimum [kg]", "{:.0f}"), Column("ipopt_status", "IPOPT status"),
                  Column("hull_active", "hull bounds active (extrados / intrados)"),
                  Column("hull_top", "largest hull multipliers: vertex (side) kg per m"),
                  Column("weights_at_lower", "weights at ε"),
                  Column("weight_lower_top", "largest ε multipliers: edge kg per N/m"),
                  Column("seconds", "time [s]", "{:.0f}"), *STAMP_COLUMNS)
#: the lower weight bound of the "ε ≈ 0" start [N/m] (the default ε is scale-free, of order 1e-2 of a weight)
EPS_ZERO = 1e-6


def hull_problem(scene: Any, thickness: float) -> Any:
    """The problem of the scene in its hull: self-weight of ρ = :data:`DENSITY` and ``thickness``."""
    from formulations.problem import Hull
    from selfsupport.io.problem import problem

    return problem(scene, density=DENSITY, thickness=thickness, constraints=[Hull(thickness=thickness)])


def fitted_start(scene: Any, V: np.ndarray, thickness: float) -> Any:
    """A start network at positions ``V``: its weights the nonnegative least-squares fit of the
    equilibrium rows to the reference's self-weight (a published network carries no weights)."""
    from scipy.optimize import lsq_linear

    from formulations.equilibrium import Topology, load_vector, weight_matrix
    from selfsupport.core.result import Network

    L = hull_problem(scene, thickness).loads.nodal(scene.mesh, scene.mesh.vertices)[0]
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges, scene.supports)
    w = lsq_linear(weight_matrix(top, V), load_vector(top, L), bounds=(0.0, np.inf), lsmr_tol="auto").x
    return Network(mesh=scene.mesh.with_vertices(V), weights=w, loads=L, supports=scene.supports)


def perturbed(net: Any, scene: Any, amplitude: float, seed: int) -> Any:
    """``net`` with each free vertex moved by a uniform random offset in ±``amplitude`` along
    the reference's vertex normal."""
    import dataclasses

    rng = np.random.default_rng(seed)
    from selfsupport.core.geometry import vertex_normals

    V = net.vertices.copy()
    n = vertex_normals(scene.mesh)
    free = ~scene.supports
    V[free] += rng.uniform(-amplitude, amplitude, int(free.sum()))[:, None] * n[free]
    return dataclasses.replace(net, mesh=net.mesh.with_vertices(V))


def starts_rows(scene: Any, at: list[int], thickness: float, published: dict[float, np.ndarray], *,
                time_limit: float) -> list[dict[str, Any]]:
    """The max-load program at ``thickness`` from many starts (the staggered network, the published
    networks with fitted weights, perturbed starts, ε ≈ 0, the supports sliding, every vertex
    sliding along the reference, the load over the apex's one-ring): per start the certified load, the program's optimum and its active bounds
    with IPOPT's multipliers (:attr:`LimitResult.active <selfsupport.structure.limit.LimitResult>`)."""
    from selfsupport.methods.hull_search import solve_in_hull
    from selfsupport.structure.limit import limit_load

    ring = sorted({int(v) for e in scene.mesh.edges for v in e if at[0] in e} | set(at))
    stag = solve_in_hull(hull_problem(scene, thickness)).network
    cases: list[tuple[str, dict]] = [("staggered network (in the hull, unloaded)", {"start": stag})]
    cases += [(f"published dome2-{PUBLISHED[kg]}kg-n network, weights fitted", {"start": fitted_start(scene, P, thickness)})
              for kg, P in sorted(published.items())]
    cases += [("reference surface, weights fitted", {"start": fitted_start(scene, scene.mesh.vertices, thickness)})]
    cases += [(f"staggered network perturbed ±t/2 along the normals (seed {k})",
               {"start": perturbed(stag, scene, 0.5 * thickness, k)}) for k in (1, 2)]
    cases += [(f"staggered network, ε = {EPS_ZERO:g} N/m", {"start": stag, "eps": EPS_ZERO}),
              ("staggered network, supports sliding across the springing", {"start": stag, "slide_supports": True}),
              ("staggered network, vertices sliding along the reference", {"start": stag, "slide": True}),
              (f"staggered network, load spread over the apex's one-ring {ring}", {"start": stag, "at": ring})]
    rows = []
    for name, kw in cases:
        t0 = time.perf_counter()
        kw = {"at": at, **kw}
        r = limit_load(scene, thickness=thickness, density=DENSITY, time_limit=time_limit, **kw)
        act = r.active or {}
        hull = act.get("hull", [])
        low = act.get("weight_lower", [])
        if r.slide:  # (each sliding round's certified load, after the normal-line program's)
            name += " (rounds: " + ", ".join("-" if x["lambda_kg"] is None else f"{x['lambda_kg']:.0f}"
                                              for x in r.slide) + " kg)"
        row = {"start": name, "thickness_m": thickness, "load_at": " ".join(map(str, kw["at"])), "verdict": r.verdict,
               "max_load_kg": r.value, "optimum_kg": r.optimum, "ipopt_status": r.ipopt_status,
               "hull_active": f"{sum(1 for h in hull if h[1] > 0)} / {sum(1 for h in hull if h[1] < 0)}",
               "hull_top": "; ".join(f"{v} ({'+' if sd > 0 else '-'}) {m:.3g}" for v, sd, m in hull[:5]),
               "weights_at_lower": len(low), "weight_lower_top": "; ".join(f"{e} {m:.3g}" for e, m in low[:5]),
               "seconds": time.perf_counter() - t0}
        print(f"starts, t={thickness:g} m, {name}: {r.verdict} {r.value} (optimum {r.optimum}) "
              f"{row['seconds']:.0f} s", file=sys.stderr)
        rows.append(row)
    return rows


def published_in_hull(scene: Any, published: dict[float, np.ndarray], thickness: float) -> list[dict[str, Any]]:
    """Whether each published network's free vertices lie within t/2 of our reference surface
    (closest points on the reference, :func:`~selfsupport.methods.base.hull_signed_distance`)."""
    from selfsupport.methods.base import hull_signed_distance

    free = ~scene.supports
    rows = []
    for kg, P in sorted(published.items()):
        d = np.abs(hull_signed_distance(scene.mesh, P))[free]
        rows.append({"published": f"dome2-{PUBLISHED[kg]}kg-n", "thickness_m": thickness,
                     "max_distance_m": float(d.max()), "mean_distance_m": float(d.mean()),
                     "outside": int((d > 0.5 * thickness).sum()), "free": int(free.sum())})
    return rows


PUBLISHED_COLUMNS = [Column("published", "published network"), Column("thickness_m", "t [m]", "{:g}"),
                     Column("max_distance_m", "max distance to our reference [m]", "{:.3g}"),
                     Column("mean_distance_m", "mean [m]", "{:.3g}"),
                     Column("outside", "free vertices beyond t/2"), Column("free", "free vertices")]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", required=True, help="folder with dome2.sss")
    ap.add_argument("--published", default=None, help="folder with dome2-*kg-n.obj (default SCENES/../published)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--thickness", default=",".join(f"{t:g}" for t in THICKNESSES))
    ap.add_argument("--loads", default=",".join(f"{k:g}" for k in LOADS))
    ap.add_argument("--max-load-thickness", default=",".join(f"{t:g}" for t in MAX_LOAD_THICKNESSES),
                    help="thicknesses of the largest-load programs (empty: none)")
    ap.add_argument("--time-limit", type=float, default=900.0, help="wall-clock limit of each largest-load program [s]")
    ap.add_argument("--starts-thickness", default="0.1",
                    help="thickness of the max-load program from many starts (Fig. 9's; empty: none)")
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--as-stored", action="store_true",
                    help="the .sss's own pins and handled vertices instead of the experiment's ground ring and apex")
    args = ap.parse_args(argv)

    from selfsupport.io import read_scene

    stamp = run_stamp()
    scenes = Path(args.scenes)
    pub_dir = Path(args.published) if args.published else scenes.parent / "published"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stored = read_scene(scenes / "dome2.sss", name="dome2")
    scene, at = (stored, None) if args.as_stored else experiment_configuration(stored)
    configuration = AS_STORED if args.as_stored else EXPERIMENT
    thicknesses = [float(x) for x in args.thickness.split(",") if x.strip()]
    loads = [float(x) for x in args.loads.split(",")]
    published: dict[float, np.ndarray] = {}
    for kg, tag in PUBLISHED.items():
        p = pub_dir / f"dome2-{tag}kg-n.obj"
        if p.is_file():
            published[kg] = read_scene(p, up="-y", supports="boundary").mesh.vertices
    rows: list[dict[str, Any]] = []
    if not args.as_stored and thicknesses:  # the file as it is, unloaded: the reason for the experiment's configuration
        rows += series_rows(stored, None, thicknesses[0], [0.0], {}, out, configuration=AS_STORED, figures=False)
    for t in thicknesses:
        rows += series_rows(scene, at, t, loads, published, out, configuration=configuration,
                            figures=not args.no_figures)
    max_rows = [max_load_row(scene, at, float(t), out, time_limit=args.time_limit)
                for t in args.max_load_thickness.split(",") if t.strip()]
    start_rows, pub_rows = [], []
    if args.starts_thickness.strip() and not args.as_stored:
        t_s = float(args.starts_thickness)
        start_rows = starts_rows(scene, at, t_s, published, time_limit=args.time_limit)
        pub_rows = published_in_hull(scene, published, t_s)
    pub_note = []
    if published:
        P0 = published.get(0.0)
        pub_note.append("published dome2-*kg-n.obj vs the scene: mean closest-vertex distance "
                        f"{network_distances(P0, stored.mesh.vertices)['nearest_mean']:.3g} m (0 kg) — the published "
                        "networks are not solves of dome2.sss as stored (their pins differ: the vertex that moves most "
                        "with load in them, 0, is pinned in the .sss, and their ground ring is drawn in)"
                        if P0 is not None else "")
    where = (f"the handled vertices {list(np.flatnonzero(scene.handles)) if scene.handles is not None else []} "
             "(the .sss as stored)" if at is None else
             f"the apex (vertex {at[0]}), supported on the {int(scene.supports.sum())} boundary vertices on the ground "
             "(the experiment's configuration, see the module docstring; --as-stored for the file's own pins)")
    notes = [f"dome2.sss ({scene.mesh.n_vertices} vertices), ρ = {DENSITY:g} kg/m³, added mass at {where}; hull search: "
             "selfsupport.methods.hull_search.solve_in_hull (staggered: no hull, then the hull as an active set); "
             "largest load: selfsupport.structure.limit.limit_load",
             "paper: Fig. 9, t = 0.1 m, a network inside the hull under an added 11,000 kg; Fig. 10, t = 1 m, "
             "0 / 5,000 / 10,000 / 20,000 kg, the network leaving the hull as the load grows", *pub_note,
             f"command: python -m studies.stability_dome --scenes {args.scenes} --out {args.out}"]
    text = write_markdown(out / "stability_dome.md", "Stability of dome2 under added load", notes,
                          [("", rows, [Column("configuration", "configuration"), *COLUMNS]),
                           ("Largest certified load", max_rows, MAX_LOAD_COLUMNS[:-len(STAMP_COLUMNS)]),
                           ("The max-load program from many starts", start_rows, STARTS_COLUMNS[:-len(STAMP_COLUMNS)]),
                           ("The published networks against our hull", pub_rows, PUBLISHED_COLUMNS)])
    (out / "stability_dome.json").write_text(json.dumps({"series": rows, "max_load": max_rows, "starts": start_rows,
                                                         "published_in_hull": pub_rows}, indent=1,
                                                        default=float) + "\n", encoding="utf-8")
    write_csv(out / "stability_dome.csv", [{**r, **stamp} for r in rows], CSV_COLUMNS)
    write_csv(out / "stability_dome_max_load.csv", [{**r, **stamp} for r in max_rows], MAX_LOAD_COLUMNS)
    if start_rows:
        write_csv(out / "stability_dome_starts.csv", [{**r, **stamp} for r in start_rows], STARTS_COLUMNS)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
