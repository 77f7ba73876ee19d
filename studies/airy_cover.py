"""Eq. (6) and ``Δ_φ φ = 2 A*`` at every free vertex of the Table 1 scenes: Φ on the cover
against Φ averaged across the cuts.

::

    python -m studies.airy_cover --scenes ../shared/paper-scenes/scenes --out out/airy_cover

Each scene is solved with the defaults (``selfsupport solve``), then analysed twice:

* **cover** (what ``selfsupport airy`` does): every vertex's star sums use its own branch of Φ
  (:func:`selfsupport.analysis.reciprocal.cover_cells`), at all free vertices;
* **averaged** (the former analysis, rebuilt here for comparison): ``φ_i`` the mean of the
  incident face planes, ``Δ_φ φ = L φ``, cell areas from the single-valued face gradients, at
  interior free vertices only.

Writes ``airy_cover.json`` and ``airy_cover.md``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import Column, read_study_scene, study_scenes_or_exit, write_markdown


def averaged_residuals(net, res) -> dict[str, float]:
    """Max relative residuals of eq. (6) and of the cell identity with φ averaged across cuts."""
    from formulations.equilibrium import Topology, stress_laplacian
    from selfsupport.analysis.reciprocal import mixed_cell_areas

    mesh = net.mesh
    face_of, _, _ = mesh.corner_data
    fv = mesh.face_vertices
    xy = mesh.vertices[:, :2]
    plane = np.einsum("ci,ci->c", res.face_gradients[face_of], xy[fv]) + res.face_offsets[face_of]
    phi = np.bincount(fv, weights=plane, minlength=mesh.n_vertices) / np.bincount(fv, minlength=mesh.n_vertices)
    L = stress_laplacian(Topology.build(mesh.n_vertices, mesh.edges, net.supports), net.weights)
    lap_phi, lap_s = L @ phi, L @ mesh.vertices[:, 2]
    a = mixed_cell_areas(mesh, res.face_gradients, res.face_gradients, res.orientation)
    d = ~net.supports & ~mesh.boundary_vertex_mask
    bal = np.abs(2 * a[d] * lap_s[d] / lap_phi[d] - net.loads[d]) / np.abs(net.loads[d])
    ident = np.abs(lap_phi[d] - 2 * a[d]) / np.abs(lap_phi[d])
    return {"balance": float(bal.max()), "identity": float(ident.max()), "n_above_1e-9": int((bal > 1e-9).sum())}


def measure(scenes: Path, name: str) -> dict[str, Any]:
    from selfsupport import api
    from selfsupport.analysis import airy, curvatures

    sc = read_study_scene(scenes, name)
    t0 = time.perf_counter()
    sol = api.solve(sc)
    t_solve = time.perf_counter() - t0
    net = sol.network
    res = airy(net)
    cv = curvatures(net, res, directions=False)
    e = net.mesh.edges[res.cut_edges]
    free = ~net.supports
    on_cut = np.unique(e[free[e]])
    return {"scene": name, "vertices": net.mesh.n_vertices, "free": int(free.sum()),
            "free_boundary": int((free & net.mesh.boundary_vertex_mask).sum()), "solve_s": t_solve,
            "max_rel_error": net.max_relative_error(), "periods": len(res.periods),
            "free_on_cuts": int(on_cut.size), "copies": res.n_cover_copies, "flat": int(cv.flat.sum()),
            "nonplanar": int(res.nonplanar_faces.size),
            "balance": cv.max_balance_residual, "identity": cv.max_identity_residual,
            "n_above_1e-9": int((cv.balance_residual[free] > 1e-9).sum()),
            "averaged": averaged_residuals(net, res)}


COLUMNS = [Column("scene", "scene"), Column("free", "free V"), Column("free_boundary", "on free boundary"),
           Column("periods", "periods"), Column("free_on_cuts", "free V on cuts"), Column("copies", "Φ copies"),
           Column("flat", "flat V"), Column("avg_balance", "eq. 6 averaged", "{:.2e}"),
           Column("avg_bad", "> 1e-9 (averaged)"), Column("balance", "eq. 6 cover", "{:.2e}"),
           Column("identity", "Δφ φ = 2A* cover", "{:.2e}"), Column("n_above_1e-9", "> 1e-9 (cover)")]


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    p = argparse.ArgumentParser(prog="python -m studies.airy_cover", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", required=True, type=Path, help="folder with the paper's scenes")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--only", nargs="*", default=None,
                   help="scene names (default: the Table 1 scenes in --scenes, or, with none there, "
                        "every scene file in it)")
    a = p.parse_args(argv)
    rows = []
    for name in study_scenes_or_exit(a.scenes, a.only):
        r = measure(a.scenes.resolve(), name)
        r["avg_balance"], r["avg_bad"] = r["averaged"]["balance"], r["averaged"]["n_above_1e-9"]
        rows.append(r)
    a.out.mkdir(parents=True, exist_ok=True)
    from selfsupport.io.network_json import to_jsonable

    (a.out / "airy_cover.json").write_text(json.dumps(to_jsonable(rows), indent=1), encoding="utf-8")
    notes = ["max relative residuals; 'averaged' over interior free vertices (the former analysis), 'cover' over "
             "all free vertices (interior and free boundary); flat V: K_Φ = 0 to round-off, eq. (6) judged as "
             "2 A* Δs = Δφ A F"]
    print(write_markdown(a.out / "airy_cover.md", "Eq. (6) on the cover of Φ (Table 1 scenes)", notes,
                         [("max relative residual per scene", rows, COLUMNS)]))
    return rows


if __name__ == "__main__":  # pragma: no cover
    main(sys.argv[1:])
