"""Step 3's conjugate-gradient tolerance (the staggered method's ``step_rtol``): what a looser
solve of the position step saves, and what it moves.

::

    python -m studies.step_tolerance --scenes ../shared/paper-scenes/scenes --out out/step_tolerance \\
        [--only lilium cas] [--tolerances 1e-7 1e-5 1e-4 1e-3] [--repeat 5]

Per scene, the default solve (the project's defaults, the method ``auto`` picks) at each
tolerance, the tolerances alternating within each repeat so that the machine's drift falls on
all of them alike. Each row: status, outer iterations, Step 3's CG iterations summed over the
run, the solve's CPU seconds (fastest and median of the repeats), max relative error, mean
distance to the reference over the bounding-box diagonal and its change against the tightest
tolerance, the CPU time relative to the tightest tolerance's (medians), and the largest
difference between the network and that of the scene turned by :data:`TURN` rad about the
vertical, turned back, over the diagonal (round-off where the solve is invariant). Writes
``step_tolerance.csv`` and ``.md`` to ``--out``, each row stamped (:func:`studies.common.run_stamp`).
"""
from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from selfsupport import api

from .common import STAMP_COLUMNS, Column, read_study_scene, run_stamp, study_scenes_or_exit, write_csv, write_markdown

#: The tolerances compared (the first is the reference of the relative columns).
TOLERANCES = (1e-7, 1e-5, 1e-4, 1e-3)
#: Solves per scene and tolerance.
REPEAT = 5
#: The turn of the invariance check [rad] about the vertical.
TURN = 0.3

COLUMNS = (Column("scene", "scene"), Column("step_rtol", "step_rtol", "{:g}"), Column("status", "status"),
           Column("iterations", "iterations"), Column("cg_iterations", "CG iterations"),
           Column("cpu_min", "CPU s (fastest)", "{:.3f}"), Column("cpu_median", "CPU s (median)", "{:.3f}"),
           Column("cpu_ratio", "CPU / tightest's", "{:.2f}"),
           Column("max_relative_error", "max rel. error", "{:.1e}"),
           Column("distance_mean", "mean distance / diag", "{:.6e}"),
           Column("distance_change", "distance change", "{:+.2e}"),
           Column("turned", "turned input: largest difference / diag", "{:.1e}"), *STAMP_COLUMNS)


def run_scene(scenes_dir: Path, name: str, tolerances: tuple[float, ...], repeat: int) -> list[dict[str, Any]]:
    """One scene's rows, one per tolerance."""
    scene = read_study_scene(scenes_dir, name)
    cpu: dict[float, list[float]] = {r: [] for r in tolerances}
    last: dict[float, Any] = {}
    for _ in range(repeat):
        for r in tolerances:
            t0 = time.process_time()
            last[r] = api.solve(scene, options={"step_rtol": r})
            cpu[r].append(time.process_time() - t0)
    c, s = np.cos(TURN), np.sin(TURN)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    turned = dataclasses.replace(scene, mesh=scene.mesh.with_vertices(scene.mesh.vertices @ R.T))
    diag = float(np.linalg.norm(np.ptp(scene.mesh.vertices, axis=0)))
    ref = tolerances[0]
    rows = []
    for r in tolerances:
        res = last[r]
        cg = sum(h["cg_iterations"] for h in res.history if isinstance(h.get("cg_iterations"), int))
        back = api.solve(turned, options={"step_rtol": r}).network.vertices @ R
        rows.append({"scene": name, "step_rtol": r, "status": res.status, "iterations": res.iterations,
                     "cg_iterations": cg, "cpu_min": min(cpu[r]), "cpu_median": statistics.median(cpu[r]),
                     "cpu_ratio": statistics.median(cpu[r]) / statistics.median(cpu[ref]),
                     "max_relative_error": res.max_relative_error, "distance_mean": res.distance_mean,
                     "distance_change": res.distance_mean / last[ref].distance_mean - 1.0,
                     "turned": float(np.abs(back - res.network.vertices).max()) / diag})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/step_tolerance"))
    ap.add_argument("--only", nargs="*", default=None, help="scene names (file stems; default: Table 1's)")
    ap.add_argument("--tolerances", nargs="+", type=float, default=list(TOLERANCES),
                    help="step_rtol values, the first the reference")
    ap.add_argument("--repeat", type=int, default=REPEAT, help="solves per scene and tolerance")
    a = ap.parse_args(argv)
    names = study_scenes_or_exit(a.scenes, a.only)
    a.out.mkdir(parents=True, exist_ok=True)
    stamp, rows = run_stamp(), []
    for name in names:
        scene_rows = run_scene(a.scenes, name, tuple(a.tolerances), a.repeat)
        rows += [{**r, **stamp} for r in scene_rows]
        print(f"{name}: " + ", ".join(f"{r['step_rtol']:g} {r['cpu_median']:.3f} s" for r in scene_rows), flush=True)
    write_csv(a.out / "step_tolerance.csv", rows, COLUMNS)
    notes = [f"`python -m studies.step_tolerance --only {' '.join(names)} --tolerances "
             f"{' '.join(f'{t:g}' for t in a.tolerances)} --repeat {a.repeat}`",
             "the default solve at each tolerance, alternating within each repeat; CPU of the solve (the process's "
             "start-up not included); distance change against the first tolerance"]
    print(write_markdown(a.out / "step_tolerance.md", "Step 3's conjugate-gradient tolerance", notes,
                         [("", rows, COLUMNS)]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
