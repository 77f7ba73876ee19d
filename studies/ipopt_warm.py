"""IPOPT warm-started: how its barrier starts (the simultaneous method's ``warm_barrier``) against
where the start comes from.

::

    python -m studies.ipopt_warm --scenes ../shared/paper-scenes/scenes --out out/ipopt_warm \\
        [--only structural twocirc-3 vault] [--time-limit 200]

Per scene, with the project's defaults (self-weight, the default ε, IPOPT's ``tol`` 1e-9): IPOPT
cold; then each start below solved with ``warm_barrier`` ``"low"`` (μ from 1e-6, variables pushed
1e-8 into their bounds: :attr:`~selfsupport.methods.simultaneous.Simultaneous.low_barrier`) and
``"default"`` (IPOPT's own: μ from 0.1, pushed 1e-2):

* ``own optimum``: the cold IPOPT result, the same problem;
* ``own optimum, point load``: the cold IPOPT result, the problem with a point load of
  ``--share`` of the self-weight at the highest free vertex added (an edit; its own cold solve is
  a row too);
* ``staggered network``: the staggered method's converged network (a plain network), the same
  problem.

Each row: status, iterations, seconds, max relative error (loads of the final geometry), mean
distance to the reference over the bounding-box diagonal, and the largest vertex move from the
start over the diagonal. ``auto`` picks ``low`` for the first two kinds of start and ``default``
for the third. Writes ``ipopt_warm.csv`` and ``.md`` to ``--out``, each row stamped
(:func:`studies.common.run_stamp`). A study, not a timed test: seconds depend on the machine;
iterations and distances do not.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from formulations import Problem
from selfsupport.core.result import Network, SolveResult
from selfsupport.io.problem import problem as build_problem
from selfsupport.methods.simultaneous import Simultaneous
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.methods.warm import as_warm_start

from .common import STAMP_COLUMNS, Column, read_study_scene, run_stamp, study_scenes_or_exit, write_csv, write_markdown
from .load_cases import highest_free_and_weight

#: The scenes run without ``--only``: Table 1's whose cold IPOPT solve converges within the
#: default limit on a 2-core machine (twocirc-3 in about 135 s; cas ran to it, 1,829 iterations).
DEFAULT_SCENES = ("structural", "twocirc-3", "vault")
#: Seconds per solve.
TIME_LIMIT = 200.0
#: The point load of the edit, a share of the self-weight.
SHARE = 0.02
#: The barriers compared, in the table's order.
BARRIERS = ("low", "default")

COLUMNS = (Column("scene", "scene"), Column("start", "start"), Column("barrier", "barrier"),
           Column("status", "status"), Column("iterations", "iterations"), Column("seconds", "s", "{:.2f}"),
           Column("max_relative_error", "max rel. error", "{:.1e}"),
           Column("distance_mean", "mean distance / diag", "{:.4e}"),
           Column("moved", "largest move from the start / diag", "{:.1e}"), *STAMP_COLUMNS)


def highest_free_load(scene: Any, share: float) -> dict[int, float]:
    """``--point-loads`` of the edit: ``share`` of the self-weight [N] at the highest free vertex."""
    v, weight = highest_free_and_weight(scene)
    return {v: share * weight}


def row(scene_name: str, start: str, barrier: str, res: SolveResult, seconds: float,
        start_vertices: np.ndarray | None) -> dict[str, Any]:
    """One solve's measurements."""
    V = res.network.vertices
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    moved = None if start_vertices is None else float(np.linalg.norm(V - start_vertices, axis=1).max()) / diag
    return {"scene": scene_name, "start": start, "barrier": barrier, "status": res.status,
            "iterations": res.iterations, "seconds": seconds, "max_relative_error": res.max_relative_error,
            "distance_mean": res.distance_mean, "moved": moved}


def run_scene(scenes_dir: Path, name: str, time_limit: float, share: float) -> list[dict[str, Any]]:
    """Every row of one scene."""
    scene = read_study_scene(scenes_dir, name)
    plain, edited = build_problem(scene), build_problem(scene, point_loads=highest_free_load(scene, share))
    rows = []

    def timed(start: str, problem: Problem, warm: SolveResult | Network | None, barrier: str = "") -> SolveResult:
        t0 = time.perf_counter()
        warm_kw = {} if warm is None else {"warm_start": warm, "warm_barrier": barrier}
        res = Simultaneous().solve(problem, {"time_limit": time_limit, **warm_kw})
        begun = None if warm is None else as_warm_start(warm).network.vertices
        rows.append(row(name, start, barrier, res, time.perf_counter() - t0, begun))
        print(json.dumps(rows[-1], default=str), flush=True)
        return res

    cold = timed("cold", plain, None)
    for barrier in BARRIERS:
        timed("own optimum", plain, cold, barrier)
    timed("cold, point load", edited, None)
    for barrier in BARRIERS:
        timed("own optimum, point load", edited, cold, barrier)
    staggered = StaggeredLinearization().solve(plain).network
    for barrier in BARRIERS:
        timed("staggered network", plain, staggered, barrier)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/ipopt_warm"))
    ap.add_argument("--only", nargs="*", default=list(DEFAULT_SCENES), help="scene names (file stems)")
    ap.add_argument("--time-limit", type=float, default=TIME_LIMIT, help="seconds per solve")
    ap.add_argument("--share", type=float, default=SHARE, help="the edit's point load, a share of the self-weight")
    a = ap.parse_args(argv)
    names = study_scenes_or_exit(a.scenes, a.only)
    a.out.mkdir(parents=True, exist_ok=True)
    stamp, rows = run_stamp(), []
    for name in names:
        rows += [{**r, **stamp} for r in run_scene(a.scenes, name, a.time_limit, a.share)]
    write_csv(a.out / "ipopt_warm.csv", rows, COLUMNS)
    notes = [f"`python -m studies.ipopt_warm --only {' '.join(names)} --time-limit {a.time_limit:g} "
             f"--share {a.share:g}`",
             "barrier low: μ from 1e-6, bounds pushed 1e-8; default: IPOPT's own (μ from 0.1, pushed 1e-2); "
             "auto takes low from an IPOPT optimum, default from any other start"]
    print(write_markdown(a.out / "ipopt_warm.md", "IPOPT warm-started: the barrier's start", notes,
                         [("", rows, COLUMNS)]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
