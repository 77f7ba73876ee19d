"""Solves in the masonry hull on a grid of generated domes: does each method's "converged" mean
"inside the hull", and how often does it find a network at all?

::

    python -m studies.hull_grid --out out/hull_grid [--methods staggered,ipopt] [--vertices 100,300]

Domes (``shape:dome``, self-weight ρ = 2000 kg/m³, t = 0.1 m) with a downward apex load of a
fraction of the self-weight, in hulls of several thicknesses. Per case and method: status,
iterations, time, max relative error, and the largest distance of a free vertex from the
reference *surface* over t/2 (closest points, independent of the solvers' slabs; ≤ 1.01 is
inside). A converged row with a ratio above 1.01 would be a false certificate.

Method ``limit``: the limit program's feasibility (:func:`selfsupport.structure.limit.feasible`)
under the same loads (its self-weight is stated as ρ t per unit area: ρ is scaled so that ρ t is
the grid's 2000 × 0.1), "converged" when it certifies.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import Column, write_markdown

COLUMNS = [Column("vertices", "V"), Column("apex_load", "apex load / weight", "{:g}"),
           Column("thickness_m", "t [m]", "{:g}"), Column("method", "method"), Column("status", "status"),
           Column("iterations", "it."), Column("seconds", "time [s]", "{:.2f}"),
           Column("max_relative_error", "max rel. error", "{:.1e}"),
           Column("true_over_half_t", "max dist. / (t/2)", "{:.3f}"), Column("inside", "inside")]


def run_case(n: int, frac: float, t: float, method: str) -> dict[str, Any]:
    from formulations import Hull, Problem
    from selfsupport.core.loads import PointLoad, SelfWeight
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods import make_method
    from selfsupport.methods.base import HULL_TOL, hull_signed_distance

    scene = make_shape("dome", n_vertices=n)
    V = scene.mesh.vertices
    weight = SelfWeight(density=2000.0, thickness=0.1)
    f = np.zeros(len(V))
    apex = int(np.argmax(V[:, 2]))
    f[apex] = frac * weight.nodal(scene.mesh, V).sum()
    t0 = time.perf_counter()
    if method == "limit":
        from selfsupport.core.loads import G
        from selfsupport.structure.limit import feasible

        r = feasible(scene, thickness=t, density=2000.0 * 0.1 / t, kg=-f[apex] / G, at=[apex], time_limit=120.0)
        res = dataclasses.replace(r.certificate, status="converged" if r.certified else r.verdict) \
            if r.certificate is not None else None
    else:
        problem = Problem.build(scene, weight + PointLoad(f), constraints=[Hull(t)])
        res = make_method(method).solve(problem)
    seconds = time.perf_counter() - t0
    if res is None:
        return {"vertices": n, "apex_load": frac, "thickness_m": t, "method": method, "status": r.verdict,
                "iterations": 0, "seconds": seconds, "max_relative_error": float("nan"), "true_over_half_t": float("nan"),
                "inside": False}
    ratio = float(np.abs(hull_signed_distance(scene.mesh, res.network.vertices))[scene.free].max() / (0.5 * t))
    return {"vertices": n, "apex_load": frac, "thickness_m": t, "method": method, "status": res.status,
            "iterations": res.iterations, "seconds": seconds, "max_relative_error": res.max_relative_error,
            "true_over_half_t": ratio, "inside": ratio <= 1 + HULL_TOL}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--methods", default="staggered,ipopt,limit")
    ap.add_argument("--vertices", default="100,300")
    ap.add_argument("--loads", default="0.05,0.2", help="apex loads as fractions of the self-weight")
    ap.add_argument("--thickness", default="0.02,0.05,0.2", help="hull thicknesses [m]")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    grid = itertools.product([int(x) for x in args.vertices.split(",")], [float(x) for x in args.loads.split(",")],
                             [float(x) for x in args.thickness.split(",")], args.methods.split(","))
    for n, frac, t, method in grid:
        row = run_case(n, frac, t, method)
        print(f"V={n} load={frac:g} t={t:g} {method}: {row['status']} ({row['seconds']:.1f} s, "
              f"dist/(t/2) {row['true_over_half_t']:.3f})", file=sys.stderr)
        rows.append(row)
    false = [r for r in rows if r["status"] == "converged" and not r["inside"]]
    notes = ["shape:dome, self-weight ρ = 2000 kg/m³ × 0.1 m, apex point load as a fraction of it",
             "max dist. / (t/2): closest points on the reference surface, not the solvers' slabs",
             f"converged but outside the hull (false certificates): {len(false)}",
             "certificates (converged and inside) per method: " + ", ".join(
                 f"{m} {sum(r['status'] == 'converged' and r['inside'] for r in rows if r['method'] == m)}"
                 for m in args.methods.split(",")),
             f"command: python -m studies.hull_grid --out {args.out} --methods {args.methods} "
             f"--vertices {args.vertices} --loads {args.loads} --thickness {args.thickness}"]
    text = write_markdown(out / "hull_grid.md", "Solves in the masonry hull", notes, [("", rows, COLUMNS)])
    (out / "hull_grid.json").write_text(json.dumps(rows, indent=1, default=float) + "\n", encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
