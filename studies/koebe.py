"""The paper's Fig. 15: a Koebe mesh Φ, its minimal partner R and the family Φ + αR, rebuilt and
compared with the published ``enneper-koebe.obj`` and ``enneper-summed.obj``.

::

    python -m studies.koebe --scenes ../shared/paper-scenes --out out/koebe

1. **What the published files are.** Both are read in their own axes (the paraboloid's axis is
   the file's y: ``up="y"`` gives the convex Φ, ``up="-y"`` the dome = thrust network). For Φ:
   vertex gaps to ``z = ½(x² + y²)``, the gaps of the edges' lines (0 = tangent), face
   planarity, the top view inverted in the unit circle (a square grid?), the Koenigs defect of Φ*.
   For the summed mesh: same top view? planar faces?
2. **Rebuilt.** :func:`selfsupport.analysis.koebe.koebe_mesh` with the grid spacing fitted to the
   published top view, ``kind="inscribed"`` and ``"tangent"``; the distance to the published Φ;
   the published height difference ``D = summed − Φ`` fitted by ``α R`` (+ an affine function,
   which is a trivial minimal partner) with our R (from our exact Φ, and from the published Φ).
3. **Equilibrium.** The family networks for α ∈ {0, 0.5, 1, 2} and the published α, written as
   network JSON and checked with the independent checker (``--checker``); the same for the
   published Φ itself (its 6-digit coordinates limit the equilibrium).

Writes ``koebe.csv`` (the equilibrium rows), ``koebe_published.csv`` (what the published files are,
one quantity a row), both stamped (:func:`studies.common.run_stamp`), ``koebe.json`` (every
number), ``koebe.md`` (the tables), the networks and, in the axes of
the published files (``up="y"``: Φ a bowl, as in ``enneper-koebe.obj``), ``phi.obj``,
``partner.obj`` and ``summed.obj`` (ours, inscribed, at the published α).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import DEFAULT_CHECKER, STAMP_COLUMNS, Column, run_checker, run_stamp, write_csv, write_markdown

ALPHAS = (0.0, 0.5, 1.0, 2.0)


def _published_dir(scenes: Path) -> Path:
    for d in (scenes / "published", scenes, scenes.parent / "published"):
        if (d / "enneper-koebe.obj").is_file() and (d / "enneper-summed.obj").is_file():
            return d
    raise SystemExit(f"no enneper-koebe.obj / enneper-summed.obj under {scenes} (or its published/ folder)")


def _rel(a: float, b: float) -> float:
    return float(a) / float(b) if b else float("nan")


def _mean_edge(mesh) -> float:
    e = mesh.edges
    return float(np.linalg.norm(mesh.vertices[e[:, 1]] - mesh.vertices[e[:, 0]], axis=1).mean())


def describe(mesh, name: str) -> dict[str, Any]:
    """Facts about a mesh against the Maxwell paraboloid (lengths over the mean edge length)."""
    from selfsupport.analysis.koebe import paraboloid_gaps
    from selfsupport.core.evidence import face_nonplanarity

    ell = _mean_edge(mesh)
    vg, eg = paraboloid_gaps(mesh)
    loops = mesh.boundary_loops
    return {"mesh": name, "vertices": mesh.n_vertices, "faces": mesh.n_faces,
            "euler": mesh.n_vertices - mesh.n_edges + mesh.n_faces, "boundary_loops": [len(b) for b in loops],
            "vertex_gap_max": float(np.abs(vg).max()) / ell, "edge_gap_min": float(eg.min()) / ell,
            "edge_gap_max": float(eg.max()) / ell, "nonplanarity_max": float(np.nanmax(face_nonplanarity(mesh)))}


def inverted_grid_fit(xy: np.ndarray) -> dict[str, float]:
    """Invert the top view in the unit circle and fit a square grid ``((i + ½) h, (j + ½) h)``."""
    u = xy / np.sum(xy * xy, axis=1, keepdims=True)
    h0 = 2 * float(np.abs(u).min())
    k = np.round(u / h0 - 0.5) + 0.5
    h = float(np.sum(u * k) / np.sum(k * k))
    return {"spacing": h, "max_residual": float(np.abs(u - k * h).max()), "grid_min": float(k.min()),
            "grid_max": float(k.max())}


def fit_partner(D: np.ndarray, r: np.ndarray, xy: np.ndarray) -> dict[str, float]:
    """``D ≈ α r + a·x + b`` in least squares (and ``D ≈ α r`` alone)."""
    A = np.c_[r, xy, np.ones(len(r))]
    c = np.linalg.lstsq(A, D, rcond=None)[0]
    a0 = float(np.dot(r, D) / np.dot(r, r))
    return {"alpha": float(c[0]), "affine": c[1:].tolist(), "max_residual": float(np.abs(A @ c - D).max()),
            "alpha_no_affine": a0, "max_residual_no_affine": float(np.abs(a0 * r - D).max()),
            "max_abs_D": float(np.abs(D).max())}


def match(points: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, float]:
    """Nearest ``targets`` row for every point (by top view) and the largest top-view distance."""
    from scipy.spatial import cKDTree

    d, idx = cKDTree(targets).query(points)
    if len(set(idx.tolist())) != len(idx):
        raise SystemExit("the rebuilt mesh does not match the published top view one to one")
    return idx, float(d.max())


def family_rows(label: str, phi, partner, alphas: Sequence[float], out: Path, checker: Path | None,
                loads: str = "reciprocal") -> list[dict[str, Any]]:
    """One row per α: the family network written as JSON and checked independently."""
    from selfsupport.analysis.koebe import family
    from selfsupport.io import write_network

    rows = []
    for a in alphas:
        fam = family(phi, a, partner=partner, loads=loads)
        net = fam.network
        path = out / f"{label}-alpha{a:g}.json"
        write_network(path, net, koebe={"alpha": a, "phi": fam.phi, "r": fam.r, "loads": loads})
        K = fam.gauss_curvature[~np.isnan(fam.gauss_curvature)]
        rows.append({"mesh": label, "loads": loads, "alpha": a, "max_rel_error": net.max_relative_error(),
                     "checker_max_rel_error": run_checker(checker, path), "min_weight": net.min_weight(),
                     "K_min": float(K.min()), "K_max": float(K.max()), "harmonic": fam.harmonic_residual,
                     "file": path.name})
    return rows


def run(scenes: Path, out: Path, checker: Path | None) -> dict[str, Any]:
    from selfsupport.analysis.koebe import koebe_mesh, minimal_partner
    from selfsupport.io import read_mesh, write_mesh

    out.mkdir(parents=True, exist_ok=True)
    pub = _published_dir(scenes)
    phi_p = read_mesh(pub / "enneper-koebe.obj", up="y")
    sum_p = read_mesh(pub / "enneper-summed.obj", up="y")
    ell = _mean_edge(phi_p)
    facts = [describe(phi_p, "enneper-koebe.obj (Φ)"), describe(sum_p, "enneper-summed.obj")]
    same_faces = phi_p.faces == sum_p.faces
    top_diff = float(np.abs(phi_p.vertices[:, :2] - sum_p.vertices[:, :2]).max())
    grid = inverted_grid_fit(phi_p.vertices[:, :2])
    R_pub = minimal_partner(phi_p, tol=1e-3)
    D = sum_p.vertices[:, 2] - phi_p.vertices[:, 2]
    xy = phi_p.vertices[:, :2]

    rebuilt: dict[str, Any] = {}
    comparisons = []
    meshes = {}
    for kind in ("inscribed", "tangent"):
        phi = koebe_mesh("enneper", kind=kind, spacing=grid["spacing"])
        R = minimal_partner(phi)
        idx, top = match(xy, phi.vertices[:, :2])
        dist = float(np.linalg.norm(phi.vertices[idx] - phi_p.vertices, axis=1).max())
        fit = fit_partner(D, R.heights[idx], xy)
        meshes[kind] = (phi, R)
        rebuilt[kind] = {"description": describe(phi, f"rebuilt ({kind})"), "koenigs_defect": R.dual.koenigs_defect,
                         "top_view_distance": top, "max_distance": dist, "fit": fit}
        comparisons.append({"what": f"rebuilt Φ ({kind}) vs enneper-koebe.obj", "top_view": top / ell,
                            "distance": dist / ell, "alpha": fit["alpha"],
                            "fit_residual": _rel(fit["max_residual"], fit["max_abs_D"]),
                            "fit_residual_no_affine": _rel(fit["max_residual_no_affine"], fit["max_abs_D"])})
    fit_pub = fit_partner(D, R_pub.heights, xy)
    comparisons.append({"what": "R from the published Φ itself (Koenigs defect "
                                f"{R_pub.dual.koenigs_defect:.1e})", "top_view": 0.0, "distance": 0.0,
                        "alpha": fit_pub["alpha"], "fit_residual": _rel(fit_pub["max_residual"], fit_pub["max_abs_D"]),
                        "fit_residual_no_affine": _rel(fit_pub["max_residual_no_affine"], fit_pub["max_abs_D"])})
    alpha_pub = rebuilt["inscribed"]["fit"]["alpha_no_affine"]
    alphas = tuple(ALPHAS) + (alpha_pub,)
    eq_rows = []
    for kind, (phi, R) in meshes.items():
        eq_rows += family_rows(f"enneper-{kind}", phi, R, alphas, out, checker)
    eq_rows += family_rows("enneper-inscribed", *meshes["inscribed"], (1.0,), out, checker, loads="top-view")
    eq_rows += family_rows("enneper-tangent", *meshes["tangent"], (1.0,), out, checker, loads="top-view")
    eq_rows += family_rows("published-phi", phi_p, R_pub, (0.0, alpha_pub), out, checker)
    # our α = published α member, in the paper's axes, for a side-by-side look
    phi_i, R_i = meshes["inscribed"]
    write_mesh(out / "phi.obj", phi_i, up="y")
    write_mesh(out / "partner.obj", phi_i.with_vertices(np.c_[phi_i.vertices[:, :2], R_i.heights]), up="y")
    write_mesh(out / "summed.obj", phi_i.with_vertices(
        np.c_[phi_i.vertices[:, :2], phi_i.vertices[:, 2] + alpha_pub * R_i.heights]), up="y")
    return {"published_dir": str(pub), "mean_edge": ell, "facts": facts, "same_faces": same_faces, "summed_top_view_diff": top_diff,
            "inverted_grid": grid, "published_koenigs_defect": R_pub.dual.koenigs_defect, "rebuilt": rebuilt,
            "comparisons": comparisons, "alpha_published": alpha_pub, "equilibrium": eq_rows,
            "checker": str(checker) if checker else None}


FACT_COLUMNS = [Column("mesh", "mesh"), Column("vertices", "V"), Column("faces", "F"), Column("euler", "χ"),
                Column("boundary_loops", "boundary loops"), Column("vertex_gap_max", "max vertex gap", "{:.1e}"),
                Column("edge_gap_min", "edge-line gap min", "{:.1e}"),
                Column("edge_gap_max", "edge-line gap max", "{:.1e}"),
                Column("nonplanarity_max", "max non-planarity", "{:.1e}")]
COMPARE_COLUMNS = [Column("what", "comparison"), Column("top_view", "top-view dist.", "{:.1e}"),
                   Column("distance", "3D dist.", "{:.1e}"), Column("alpha", "α (D ≈ αR + affine)", "{:.6f}"),
                   Column("fit_residual", "max resid. / max|D|", "{:.1e}"),
                   Column("fit_residual_no_affine", "same, no affine", "{:.1e}")]
EQ_COLUMNS = [Column("mesh", "Φ"), Column("loads", "loads"), Column("alpha", "α", "{:.4g}"),
              Column("checker_max_rel_error", "checker max rel. error", "{:.2e}"),
              Column("max_rel_error", "our max rel. error", "{:.2e}"), Column("min_weight", "min w", "{:.4f}"),
              Column("K_min", "K_Φ min", "{:.4f}"), Column("K_max", "K_Φ max", "{:.4f}"),
              Column("harmonic", "|Δφ r|/|Δφ φ|", "{:.1e}")]


#: koebe_published.csv: one quantity a row
PUBLISHED_COLUMNS = (Column("quantity", "quantity"), Column("value", "value", "{:.6g}"), Column("about", "what it is"),
                     *STAMP_COLUMNS)


def published_rows(res: dict[str, Any]) -> list[dict[str, Any]]:
    """What the published ``enneper-koebe.obj`` and ``enneper-summed.obj`` are, one number a row
    (lengths over the published Φ's mean edge length)."""
    phi = res["facts"][0]
    fit = res["rebuilt"]["inscribed"]["fit"]
    tangent = res["rebuilt"]["tangent"]
    return [
        {"quantity": "phi_vertex_gap_max", "value": phi["vertex_gap_max"],
         "about": "enneper-koebe.obj: largest |½(x²+y²) − z| of a vertex (0: inscribed in the paraboloid)"},
        {"quantity": "phi_edge_gap_max", "value": phi["edge_gap_max"],
         "about": "enneper-koebe.obj: largest gap of an edge's line to the paraboloid (0: tangent; < 0: a chord)"},
        {"quantity": "inscribed_distance", "value": res["rebuilt"]["inscribed"]["max_distance"] / res["mean_edge"],
         "about": "largest distance of our inscribed Φ from enneper-koebe.obj"},
        {"quantity": "tangent_distance", "value": tangent["max_distance"] / res["mean_edge"],
         "about": "largest distance of our tangent Φ (a Koebe mesh proper) from enneper-koebe.obj"},
        {"quantity": "alpha", "value": res["alpha_published"],
         "about": "enneper-summed.obj − enneper-koebe.obj fitted by α R (our R, inscribed Φ; max |r| = Φ's height range)"},
        {"quantity": "alpha_fit_residual", "value": _rel(fit["max_residual_no_affine"], fit["max_abs_D"]),
         "about": "that fit's largest residual over the largest height difference"},
        {"quantity": "published_koenigs_defect", "value": res["published_koenigs_defect"],
         "about": "Koenigs defect of the published Φ's polar (its coordinates have six digits)"},
    ]


def report(res: dict[str, Any], out: Path) -> str:
    g = res["inverted_grid"]
    fact_rows = [dict(f, boundary_loops="+".join(map(str, f["boundary_loops"]))) for f in res["facts"]]
    fact_rows += [dict(res["rebuilt"][k]["description"], boundary_loops="+".join(
        map(str, res["rebuilt"][k]["description"]["boundary_loops"]))) for k in ("inscribed", "tangent")]
    notes = [f"published files: {res['published_dir']}; lengths over the published Φ's mean edge length; "
             "gaps are ½(x²+y²) − z (vertex) and its minimum along each edge's line (0: the line touches)",
             f"summed has Φ's faces: {res['same_faces']}, and its top view to {res['summed_top_view_diff']:.1e}",
             f"Φ's top view inverted in the unit circle is the square grid ((i+½)h, (j+½)h), i, j = "
             f"{g['grid_min'] - 0.5:.0f}..{g['grid_max'] - 0.5:.0f}, h = {g['spacing']:.6f}, to {g['max_residual']:.1e}",
             f"Koenigs defect of the published Φ* (6-digit file): {res['published_koenigs_defect']:.1e}; of the "
             f"rebuilt ones: {res['rebuilt']['inscribed']['koenigs_defect']:.1e} (inscribed), "
             f"{res['rebuilt']['tangent']['koenigs_defect']:.1e} (tangent)",
             f"α is relative to our normalization of R (max |r| = Φ's height range); the published summed mesh is "
             f"Φ + αR with α = {res['alpha_published']:.6f}",
             f"checker: {res['checker']}"]
    text = write_markdown(out / "koebe.md", "Koebe meshes and the family Φ + αR (paper Fig. 15)", notes, [
        ("The published meshes and the rebuilt ones", fact_rows, FACT_COLUMNS),
        ("Rebuilt against published", res["comparisons"], COMPARE_COLUMNS),
        ("Equilibrium of the family −(Φ + αR), unit load", res["equilibrium"], EQ_COLUMNS)])
    return text


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", required=True, type=Path,
                    help="the paper-scenes folder (or its published/ folder) holding enneper-koebe.obj")
    ap.add_argument("--out", type=Path, default=Path("out/koebe"), help="output folder (default out/koebe)")
    ap.add_argument("--checker", type=Path, default=DEFAULT_CHECKER,
                    help="the independent check_network.py (default ../shared/tools/check_network.py)")
    a = ap.parse_args(argv)
    checker = a.checker if a.checker and a.checker.is_file() else None
    stamp = run_stamp()
    res = run(a.scenes, a.out, checker)
    write_csv(a.out / "koebe.csv", [{**r, **stamp} for r in res["equilibrium"]], (*EQ_COLUMNS, *STAMP_COLUMNS))
    write_csv(a.out / "koebe_published.csv", [{**r, **stamp} for r in published_rows(res)], PUBLISHED_COLUMNS)
    from selfsupport.io.network_json import to_jsonable

    (a.out / "koebe.json").write_text(json.dumps(to_jsonable(res), indent=1) + "\n", encoding="utf-8")
    sys.stdout.write(report(res, a.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
