"""The measurements behind the theory pages' "why not X" paragraphs that need no paper scene.

::

    python -m studies.theory_whys --out out/theory_whys

* **The Gram matrix on its structural pattern** (docs/theory/staggered.md, Step 2): the first
  weight fit of a cross vault sits at the reference, whose grid edges have zero x, y or z
  differences. How many entries of the structural pattern of ``AᵀA`` scipy's product drops
  there, and one CHOLMOD factorization (symbolic and numeric, best of three) of the product as
  scipy gives it against the same matrix on the structural pattern
  (:func:`selfsupport.core.linalg.structural_gram`).
* **The coupled position step** (Step 3): solve time per outer iteration of the staggered method
  with ``coupled=true`` over the plain step's, on generated shapes.

Writes ``theory_whys.csv`` (one quantity a row, stamped: :func:`studies.common.run_stamp`) and
prints it.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from studies.common import STAMP_COLUMNS, Column, markdown_table, run_stamp, write_csv

COLUMNS = (Column("why", "why"), Column("quantity", "quantity"), Column("value", "value", "{:.3g}"),
           Column("about", "what it is"), *STAMP_COLUMNS)
#: the coupled step's shapes (each solved twice)
COUPLED_SHAPES = ("dome", "pillar_vault", "concave_disk")


def gram_rows(n_vertices: int = 4000, repeat: int = 3) -> list[dict[str, Any]]:
    """The structural pattern of the first fit's ``AᵀA`` at a cross vault's reference: entries the
    product drops, and one factorization's time both ways."""
    import scipy.sparse as sp

    from formulations.equilibrium import Topology, weight_matrix
    from selfsupport.core.linalg import SPDFactor, structural_gram
    from selfsupport.core.shapes import make_shape

    scene = make_shape("cross_vault", n_vertices=n_vertices)
    mesh = scene.mesh
    A = weight_matrix(Topology.build(mesh.n_vertices, mesh.edges, scene.supports), mesh.vertices)
    product = (A.T @ A).tocsc()
    product.eliminate_zeros()
    full = structural_gram(A)
    shift = 1e-6 * float(full.diagonal().max())  # positive definite whatever the pattern's rank

    def factor_time(M: Any) -> float:
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            SPDFactor(M)
            times.append(time.perf_counter() - t0)
        return min(times)

    t_product = factor_time((product + shift * sp.identity(product.shape[0], format="csc")).tocsc())
    t_full = factor_time(structural_gram(A, shift))
    where = f"cross_vault at its reference, {mesh.n_vertices} vertices, {mesh.n_edges} edges"
    return [{"why": "gram structural pattern", "quantity": "entries_dropped", "value": 1 - product.nnz / full.nnz,
             "about": f"share of the structural entries of AᵀA that scipy's product drops ({where})"},
            {"why": "gram structural pattern", "quantity": "factor_time_ratio", "value": t_product / t_full,
             "about": f"one CHOLMOD factorization of the product's pattern over the structural one's ({where}; "
                      f"{t_product:.3g} s against {t_full:.3g} s)"}]


def coupled_rows(n_vertices: int = 1000, shapes: Sequence[str] = COUPLED_SHAPES) -> list[dict[str, Any]]:
    """Solve time per outer iteration, coupled step over the plain one, per shape."""
    from selfsupport import api
    from selfsupport.core.shapes import make_shape

    rows = []
    for shape in shapes:
        scene = make_shape(shape, n_vertices=n_vertices)
        per_it = {}
        for coupled in (False, True):
            res = api.solve(scene, options={"coupled": coupled})
            if res.status != "converged":
                raise SystemExit(f"{shape}: the {'coupled' if coupled else 'plain'} solve ended {res.status}")
            per_it[coupled] = res.wall_time / max(res.iterations, 1)
        rows.append({"why": "coupled step", "quantity": f"time_per_iteration_ratio {shape}",
                     "value": per_it[True] / per_it[False],
                     "about": f"{shape}, {scene.mesh.n_vertices} vertices: solve time per outer iteration, "
                              "coupled=true over the plain step"})
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for theory_whys.csv")
    a = ap.parse_args(argv)
    stamp = run_stamp()
    rows = [{**r, **stamp} for r in (*gram_rows(), *coupled_rows())]
    a.out.mkdir(parents=True, exist_ok=True)
    write_csv(a.out / "theory_whys.csv", rows, COLUMNS)
    sys.stdout.write(markdown_table(rows, COLUMNS[:4]) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
