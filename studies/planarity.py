"""Planarity against closeness on the paper's quad scenes.

    python -m studies.planarity --scenes ../shared/paper-scenes/scenes --out OUT
        [--only vault,cas] [--terms planarity,planarity_volume] [--weights 10,1000]
        [--refine 50] [--time-limit 600]

For each scene: the default staggered solve, the same with its refinement (the problem's
objective, the reference distance only), and for each planarity term and weight the staggered
method with ``objective = reference=1 + TERM=W`` and its refinement run to its step limit
(``refine_gain=0``: the penalty path relaxes the objective towards its end; the refinement
minimises it on the equilibrium manifold). Columns: max / mean face non-planarity (distance
between the diagonals / mean edge length, :func:`selfsupport.core.evidence.face_nonplanarity`), the
mean distance to the reference (/ bbox diagonal), the max relative error recomputed from the
saved network, time. Writes ``planarity.csv``, ``planarity.md`` and one JSON per row.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .common import STAMP_COLUMNS, Column, json_max_relative_error, read_study_scene, run_stamp, write_csv, write_markdown

COLUMNS = [Column("scene", "scene"), Column("objective", "objective"), Column("refine", "refine"),
           Column("status", "status"), Column("nonplanar_max", "non-planarity max", "{:.2e}"),
           Column("nonplanar_mean", "non-planarity mean", "{:.2e}"),
           Column("reduction", "max reduction vs default", "{:.1f}x"),
           Column("dist_mean", "dist. to reference (mean)", "{:.3e}"),
           Column("max_rel_error", "max rel. error", "{:.1e}"), Column("time_s", "time [s]", "{:.1f}")]
#: the CSV's columns: the table's, then the run's stamp (:func:`studies.common.run_stamp`)
CSV_COLUMNS = [*COLUMNS, *STAMP_COLUMNS]


def run(scenes: Path, out: Path, only: Sequence[str], terms: Sequence[str], weights: Sequence[float],
        refine: int, time_limit: float) -> list[dict[str, Any]]:
    from formulations import Problem
    from selfsupport.core.evidence import face_nonplanarity
    from selfsupport.core.loads import SelfWeight
    from selfsupport.io import write_network
    from selfsupport.methods.staggered import StaggeredLinearization

    stamp = run_stamp()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for name in only:
        scene = read_study_scene(scenes, name)
        runs = [("default", None, 0), ("default", None, refine)]
        runs += [(f"reference=1 {t}={w:g}", {"reference": 1.0, t: w}, refine) for t in terms for w in weights]
        base = None
        for label, objective, n_ref in runs:
            problem = Problem.build(scene, SelfWeight(), objective=objective)
            t0 = time.perf_counter()
            res = StaggeredLinearization(refine=n_ref, refine_gain=0.0, time_limit=time_limit).solve(problem)
            seconds = time.perf_counter() - t0
            path = out / f"{name}__{label.replace(' ', '_').replace('=', '-')}__refine{n_ref}.json"
            write_network(path, res, study={"scene": name, "objective": label, "refine": n_ref})
            npl = face_nonplanarity(res.network.mesh)
            row = {"scene": name, "objective": label, "refine": n_ref, "status": res.status,
                   "nonplanar_max": float(np.nanmax(npl)), "nonplanar_mean": float(np.nanmean(npl)),
                   "dist_mean": res.distance_mean, "max_rel_error": json_max_relative_error(path), "time_s": seconds,
                   **stamp}
            base = row["nonplanar_max"] if base is None else base
            row["reduction"] = base / row["nonplanar_max"]
            rows.append(row)
            print(" | ".join(str(row[c.key]) for c in COLUMNS), flush=True)
    write_csv(out / "planarity.csv", rows, CSV_COLUMNS)
    write_markdown(out / "planarity.md", "Planarity against closeness (staggered + refinement)",
                   ["non-planarity: distance between the diagonals / mean edge length, per quad",
                    "reduction: the default run's max non-planarity over this row's"], [("", rows, COLUMNS)])
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.planarity", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=Path, required=True, help="the paper's scenes folder")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--only", default="vault,cas", help="scenes (comma-separated file stems)")
    p.add_argument("--terms", default="planarity,planarity_volume")
    p.add_argument("--weights", default="10,1000")
    p.add_argument("--refine", type=int, default=50, help="refinement steps of the planarity rows")
    p.add_argument("--time-limit", type=float, default=600.0)
    a = p.parse_args(argv)
    run(a.scenes, a.out, a.only.split(","), a.terms.split(","), [float(w) for w in a.weights.split(",")],
        a.refine, a.time_limit)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
