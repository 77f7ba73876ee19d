"""How little bracing does a quad design need to stand under its load cases? A continuation from
the design split into triangles, with the diagonals' weights bounded ever lower, then the quads
alone.

::

    python -m studies.bracing --scenes ../shared/paper-scenes/scenes --out out/bracing \\
        [--only vault-pillar] [--share 0.05] [--fractions 0.5,0.1,0.01,0.001] [--steps ipopt]
        [--refine 2] [--time-limit 120] [--step-time-limit 600] [--checker PATH] [--control]

The cases are those of :mod:`studies.load_cases`: empty; snow 80 kg/m² on all faces; a point
load of ``--share`` of the self-weight at the highest free vertex. The steps, each a row:

* ``split``: the design split into triangles as ``selfsupport solve --triangulate`` splits it
  (:func:`selfsupport.api.triangulated_design`), the diagonals unbounded: ``D0`` is the largest
  diagonal weight over the cases;
* ``diagonals ≤ f·D0`` for each of ``--fractions`` (falling): the diagonals' weights bounded to
  ``[0, f·D0]`` [N/m] (the design's own edges keep the default bounds), solved from the last step
  that stood: by IPOPT nearest it (``--steps ipopt``, the default: the simultaneous method), or by
  the staggered method warm-started there (``--steps staggered``). A step that does not stand is
  retried halfway (on a log scale) from the last bound that stood, at most ``--refine`` times
  (:data:`REFINE`), and the target again after one that stands; where that does not reach it, the
  continuation stops;
* ``quads, staggered`` and ``quads, IPOPT``: the design itself, started from the last step that
  stood with its diagonals dropped (:func:`studies.stand_search.quads_start`): the staggered
  method, and IPOPT nearest that start (the simultaneous method).

A step stands when every case's max relative error (loads of its geometry) is at most
:data:`~studies.stand_search.STANDS_TOL`; with ``--checker`` the independent checker then confirms it.

Per row: the method and its status; the worst case's max relative error; the diagonals' share of
the load (per case the sum of ``|w| · length`` over the diagonals over the case's total load, the
largest over the cases); the largest weight; the shortest edge of the design over its length in
the reference (a shrinking edge is the network turning its quads into triangles); the smallest
degeneracy, at the row's positions, of the stars of the design's peel of the point load
(:mod:`formulations.peel`: where that peel reaches the loaded vertex, the quads alone can carry
the cases only where it is zero); iterations and seconds. The JSON also lists, for the last step
that stood, the diagonals at their bound in each
case (the faces that still need bracing there). Writes ``bracing.csv``, ``bracing.md``,
``bracing.json`` and each row's network (``SCENE-SHARE-stepK.json``) into ``--out``.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from formulations.peel import DifferencePeel, star_degeneracy
from formulations.problem import Bounds
from selfsupport import api
from selfsupport.core.result import SolveResult
from selfsupport.io.network_json import write_network
from selfsupport.io.problem import problem as build_problem
from selfsupport.methods.simultaneous import Simultaneous
from selfsupport.methods.staggered import StaggeredLinearization
from studies.common import DEFAULT_CHECKER, STAMP_COLUMNS, Column, run_stamp, write_csv, write_markdown
from studies.load_cases import TIME_LIMIT, checked, highest_free_and_weight, point_peel, three_cases, toml_text
from studies.stand_search import STANDS_TOL, quads_start, write_control

#: The diagonals' bounds as fractions of the split network's largest diagonal weight.
FRACTIONS = (0.3, 0.1, 0.03, 0.01, 0.003, 0.001, 3e-4, 1e-4, 3e-5, 1e-5)
#: Seconds per bounded step (IPOPT's steps took 3–52 s on vault-pillar, about 510 s on cas).
STEP_TIME_LIMIT = 600.0
#: The default scenes: the paper's quad design whose three cases stall (:mod:`studies.load_cases`)
#: and whose steps take seconds. cas (``--only cas``) stalls too, and its steps take minutes.
SCENES = ("vault-pillar",)
#: Steps halfway (on a log scale) to a bound after a step that does not stand, before the
#: continuation stops.
REFINE = 2
#: The methods of the bounded steps: IPOPT nearest the last step that stood, or the staggered
#: method from there.
STEP_METHODS = ("ipopt", "staggered")
#: A diagonal "at its bound" carries at least this share of it.
AT_BOUND = 0.99

COLUMNS = (Column("scene", "scene"), Column("point_share", "point share", "{:.0%}"), Column("step", "step"),
           Column("bound", "diagonal bound [N/m]", "{:.4g}"), Column("method", "method"), Column("status", "status"),
           Column("worst_error", "worst case: max rel. error", "{:.1e}"),
           Column("checker", "checker", "{:.1e}"),
           Column("diagonal_share", "diagonals' share of the load", "{:.2e}"),
           Column("weight_max", "largest weight [N/m]", "{:.4g}"),
           Column("shortest_edge", "shortest edge / its reference length", "{:.3g}"),
           Column("star_degeneracy", "the point load's peel: smallest star degeneracy", "{:.1e}"),
           Column("iterations", "iterations", "{:d}"), Column("seconds", "seconds", "{:.1f}"), *STAMP_COLUMNS)


def diagonal_mask(split_edges: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Which of ``split_edges`` the split added: those whose vertex pair is not among ``edges``.

    >>> diagonal_mask(np.array([[0, 1], [1, 2], [2, 0]]), np.array([[1, 0], [1, 2]])).tolist()
    [False, False, True]
    """
    kept = {(int(min(a, b)), int(max(a, b))) for a, b in np.asarray(edges)}
    return np.array([(int(min(a, b)), int(max(a, b))) not in kept for a, b in np.asarray(split_edges)], bool)


def measure(res: SolveResult, design_edges: np.ndarray, reference: np.ndarray, diagonals: np.ndarray | None,
            peel: DifferencePeel) -> dict[str, Any]:
    """A row's measurements of ``res`` (module docstring); ``diagonals`` marks the diagonals among
    its mesh's edges (``None``: the design itself, no diagonals); ``peel`` is the design's peel of
    the point load (:func:`studies.load_cases.point_peel`)."""
    V, E = res.network.vertices, res.network.edges
    nets = dict(res.case_networks)
    length = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    share = 0.0 if diagonals is None else max(
        float(np.abs(n.weights[diagonals]) @ length[diagonals]) / float(np.abs(n.loads).sum()) for n in nets.values())
    De = np.asarray(design_edges)
    ref_len = np.linalg.norm(reference[De[:, 0]] - reference[De[:, 1]], axis=1)
    return {"method": res.method, "status": res.status, "worst_error": max(n.max_relative_error() for n in nets.values()),
            "diagonal_share": share, "weight_max": max(float(n.weights.max()) for n in nets.values()),
            "shortest_edge": float((np.linalg.norm(V[De[:, 0]] - V[De[:, 1]], axis=1) / ref_len).min()),
            "star_degeneracy": star_degeneracy(peel, V).smallest if peel.steps else None,
            "iterations": res.iterations, "seconds": round(res.wall_time, 1),
            "errors": {k: n.max_relative_error() for k, n in nets.items()}}


def study(path: Path, out: Path, checker: Path | None, share: float, fractions: tuple[float, ...],
          time_limit: float = TIME_LIMIT, refine: int = REFINE, steps: str = STEP_METHODS[0],
          step_time_limit: float = STEP_TIME_LIMIT, log: Any = print) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The continuation's rows for the scene at ``path`` and what it found at the last step that
    stood (module docstring): ``time_limit`` seconds for the split design and for each solve of the
    design itself, ``step_time_limit`` for each bounded step."""
    name = path.stem
    scene, split = api.as_scene(str(path)), api.triangulated_design(str(path))
    v, weight = highest_free_and_weight(scene)
    cases = three_cases(v, weight, share)
    toml = out / f"{name}-{share:g}.toml"
    toml.write_text(toml_text(cases))
    diag = diagonal_mask(split.mesh.edges, scene.mesh.edges)
    peel = point_peel(scene, v)
    stamp, rows, info = run_stamp(), [], {"cases": cases, "diagonals": int(diag.sum()), "edges": len(scene.mesh.edges)}

    def row(step: str, bound: float | None, res: SolveResult, diagonals: np.ndarray | None) -> dict[str, Any]:
        r = {"scene": name, "point_share": share, "step": step, "bound": bound,
             **measure(res, scene.mesh.edges, scene.mesh.vertices, diagonals, peel), **stamp}
        net = out / f"{name}-{share:g}-step{len(rows)}.json"
        write_network(net, res)
        if checker is not None and r["worst_error"] <= STANDS_TOL:
            r["checker"] = max(checked(net, checker,
                                       ["--allow-tension"] if diagonals is not None else []).values())
        r["stands"] = bool(r["worst_error"] <= STANDS_TOL and r.get("checker", 0.0) <= STANDS_TOL)
        rows.append(r)
        log(json.dumps({k: r[k] for k in ("step", "bound", "status", "worst_error", "diagonal_share", "shortest_edge",
                                          "seconds")}, default=str))
        return r

    def problem(mesh_scene: Any, lower: Any, upper: Any) -> Any:
        return build_problem(mesh_scene, load_cases=str(toml), bounds=None if lower is None else Bounds(lower, upper))

    def staggered(mesh_scene: Any, lower: Any = None, upper: Any = None, start: Any = None,
                  limit: float = time_limit) -> SolveResult:
        return StaggeredLinearization().solve(problem(mesh_scene, lower, upper), {"time_limit": limit}, warm_start=start)

    def ipopt(mesh_scene: Any, lower: Any = None, upper: Any = None, start: Any = None,
              limit: float = time_limit) -> SolveResult:
        return Simultaneous().solve(problem(mesh_scene, lower, upper),
                                    {"warm_start": start, "time_limit": limit, "nearest_to_start": True})

    step = {"staggered": staggered, "ipopt": ipopt}[steps]

    last = staggered(split)
    d0 = max(float(n.weights[diag].max()) for _, n in last.case_networks)
    info["D0"] = d0
    if not row("split", None, last, diag)["stands"]:
        return rows, {**info, "verdict": "the split design does not stand: no continuation"}
    last_f, stopped = 1.0, None  # (the split network's diagonals are within 1·D0)
    for target in fractions:
        f, failed = target, 0
        while last_f > target and stopped is None:
            lower, upper = np.full(len(diag), np.nan), np.full(len(diag), np.nan)
            lower[diag], upper[diag] = 0.0, f * d0
            res = step(split, lower, upper, last, step_time_limit)
            if row(f"diagonals ≤ {f:.3g}·D0", f * d0, res, diag)["stands"]:
                last, last_f, f = res, f, target
            elif failed < refine:
                failed, f = failed + 1, math.sqrt(last_f * f)  # halfway, on a log scale
            else:
                stopped = target
    last_bound = None if last_f == 1.0 else last_f * d0
    if last_bound is not None:
        info["at_bound"] = {n: split.mesh.edges[diag][net.weights[diag] >= AT_BOUND * last_bound].tolist()
                            for n, net in last.case_networks}
    info["last_standing_bound"], info["stopped_at"] = last_bound, stopped
    start = quads_start(last, scene, split.mesh.edges, tuple(n for n, _ in last.case_networks))
    row("quads, staggered", None, staggered(scene, start=start), None)
    row("quads, IPOPT", None, ipopt(scene, start=start), None)
    return rows, info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/bracing"))
    ap.add_argument("--checker", type=Path, default=DEFAULT_CHECKER)
    ap.add_argument("--only", default=",".join(SCENES), help="comma-separated scenes (file stems of .sss files in --scenes)")
    ap.add_argument("--share", type=float, default=0.05, help="point load's share of the self-weight")
    ap.add_argument("--fractions", default=",".join(f"{f:g}" for f in FRACTIONS),
                    help="the diagonals' bounds over the split network's largest diagonal weight, falling")
    ap.add_argument("--time-limit", type=float, default=TIME_LIMIT,
                    help="seconds for the split design and for each solve of the design itself")
    ap.add_argument("--step-time-limit", type=float, default=STEP_TIME_LIMIT, help="seconds per bounded step")
    ap.add_argument("--refine", type=int, default=REFINE,
                    help="steps halfway to a bound after one that does not stand, before stopping")
    ap.add_argument("--steps", choices=STEP_METHODS, default=STEP_METHODS[0],
                    help="the method of the bounded steps (each from the last step that stood)")
    ap.add_argument("--control", action="store_true",
                    help="instead of --only: the tests' free-edged quad vault, which stands under the cases")
    a = ap.parse_args(argv)
    fractions = tuple(float(x) for x in a.fractions.split(","))
    if any(not 0 < f for f in fractions) or list(fractions) != sorted(fractions, reverse=True):
        ap.error("--fractions: positive numbers, falling")
    a.out.mkdir(parents=True, exist_ok=True)
    paths = [write_control(a.out)] if a.control else [a.scenes / f"{n}.sss" for n in a.only.split(",")]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        ap.error(f"no scene {', '.join(missing)}: give --scenes the folder of the paper's scenes")
    rows, infos = [], {}
    for path in paths:
        scene_rows, infos[path.stem] = study(path, a.out, a.checker if a.checker.is_file() else None, a.share,
                                             fractions, a.time_limit, a.refine, a.steps, a.step_time_limit)
        rows += scene_rows
    write_csv(a.out / "bracing.csv", rows, COLUMNS)
    (a.out / "bracing.json").write_text(json.dumps({"info": infos, "rows": rows}, indent=1, default=str))
    which = "--control" if a.control else f"--only {a.only}"
    notes = [f"`python -m studies.bracing {which} --share {a.share:g} --fractions {a.fractions} --steps {a.steps} "
             f"--refine {a.refine} --time-limit {a.time_limit:g} --step-time-limit {a.step_time_limit:g}`"]
    for name, info in infos.items():
        ends = ", ".join(f"{r['step']} {r['status']}" for r in rows if r["scene"] == name and r["step"].startswith("quads"))
        notes.append(f"{name}: {info['diagonals']} diagonals added to {info['edges']} edges, D0 = {info['D0']:.4g} N/m; "
                     f"last step that stood: diagonals ≤ {info.get('last_standing_bound')} N/m (stopped at "
                     f"{info.get('stopped_at')}·D0); from there {ends}")
    print(write_markdown(a.out / "bracing.md", f"How little bracing the quad designs need at {a.share:.0%}", notes,
                         [("", rows, COLUMNS)]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
