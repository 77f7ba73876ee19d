"""Airy stress surface and reciprocal diagram of the paper's lilium network, compared with the
published ones; timings of the analysis on Table-1-sized and large networks.

::

    python -m studies.airy_published --published ../shared/paper-scenes/published --out out/airy

1. ``lilium-n.obj`` (read with ``up="-y"``, supports = boundary) gets compressive weights fitted
   with the positions fixed (:func:`selfsupport.api.check`: the staggered method's Step 2);
   then Φ, the reciprocal diagram and the relative principal directions are computed.
2. They are compared with ``lilium-n-stress.obj`` (a triangle soup, one planar triangle per
   network face, matched by top-view position), ``lilium-n-recip.obj`` (one vertex per face) and
   ``lilium-n-vf.txt``, **up to the gauge**: Φ up to an affine function and a scale (the
   published weights are in the original tool's units), the diagram up to translation and scale,
   directions as unsigned lines.
3. The fitted weights are not unique (a triangle mesh has more edges than equilibrium
   equations), so Φ is also rebuilt from the weights *implied by the published diagram*
   (``w = (R_L − R_R) · J e' / ‖e'‖²``): that isolates our Φ construction from the weight fit.
4. Timings of ``airy``, ``reciprocal`` and ``curvatures`` (with principal directions) on the
   published Table-1 networks (weights fitted as in 1) and on §2.5-constructed networks of
   1.2k–64k vertices (median of repeated runs).

Writes ``airy_published.json`` (every number), ``airy_published.md`` (tables), and for lilium
the analysis file, Φ and the diagram as OBJ in the paper's axes, and the vector fields.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from studies.common import Column, median_time, write_markdown

#: published network -> (scene file for the supports, or "boundary"), in the same vertex order
PUBLISHED_NETWORKS: dict[str, tuple[str, str]] = {
    "lilium-n": ("lilium", "boundary"),
    "lilium-pillar-n": ("lilium-pillar", "lilium-pillar.sss"),
    "cheese-n": ("cyl2", "cyl2.sss"),
    "structural-n": ("structural", "structural.supports"),
}

#: §2.5 networks for the timing rows: disk rings -> about 1.2k, 2.4k, 10k, 64k vertices
CONSTRUCTED_RINGS = (20, 28, 57, 146)


def _obj_vertices(path: Path) -> np.ndarray:
    """``v`` records of an OBJ (the published soups and diagrams need nothing else)."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.asarray(rows, dtype=float)


def _published_scene(published: Path, scenes: Path, stem: str):
    """The published network as a scene (positions as published, supports as the paper's)."""
    from dataclasses import replace

    from selfsupport.io import read_scene
    from selfsupport.io.supports import resolve_supports

    scene_name, supports = PUBLISHED_NETWORKS[stem]
    sc = read_scene(published / f"{stem}.obj", up="-y", supports="boundary", name=stem)
    if supports.endswith(".sss"):
        pins = read_scene(scenes / supports).supports
        if pins.shape == sc.supports.shape:
            sc = replace(sc, supports=pins)
    elif supports != "boundary":
        sc = replace(sc, supports=resolve_supports(str(scenes / supports), sc.mesh, source=scenes / supports))
    return sc


def _fit_affine_scale(target: np.ndarray, source: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``target ≈ λ source + a·x + b·y + c``; returns (coefficients, residual)."""
    M = np.c_[source, xy, np.ones(len(source))]
    coef, *_ = np.linalg.lstsq(M, target, rcond=None)
    return coef, target - M @ coef


def _fit_similarity(target: np.ndarray, source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``target ≈ λ source + t`` for 2D point sets; returns ((λ, tx, ty), residual vectors)."""
    M = np.zeros((2 * len(source), 3))
    M[:, 0] = source.ravel()
    M[0::2, 1] = 1.0
    M[1::2, 2] = 1.0
    coef, *_ = np.linalg.lstsq(M, target.ravel(), rcond=None)
    return coef, (target.ravel() - M @ coef).reshape(-1, 2)


def _line_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle [deg] between unsigned top-view lines."""
    a = a[:, :2] / np.linalg.norm(a[:, :2], axis=1, keepdims=True)
    b = b[:, :2] / np.linalg.norm(b[:, :2], axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.abs((a * b).sum(axis=1)), 0.0, 1.0)))


def compare_lilium(published: Path, scenes: Path, out: Path) -> dict[str, Any]:
    """Steps 1–3 of the module docstring for ``lilium-n``; writes the lilium files into ``out``."""
    from scipy.spatial import cKDTree

    from selfsupport import api
    from selfsupport.analysis import airy, curvatures, face_principal_directions, reciprocal, write_vector_fields
    from selfsupport.cli.airy import airy_document
    from selfsupport.core.result import Network
    from selfsupport.io import write_mesh
    from selfsupport.io.atomic import atomic_write_text
    from selfsupport.io.axes import to_ours
    from selfsupport.io.network_json import to_jsonable

    sc = _published_scene(published, scenes, "lilium-n")
    t0 = time.perf_counter()
    rep = api.check(sc)
    t_fit = time.perf_counter() - t0
    net = rep.network
    res = airy(net)
    rd = reciprocal(res)
    cv = curvatures(net, res)
    rec: dict[str, Any] = {"vertices": net.mesh.n_vertices, "faces": net.mesh.n_faces, "edges": net.mesh.n_edges,
                           "fit_seconds": t_fit, "fit_max_relative_error": rep.max_relative_error,
                           "fit_min_weight": rep.min_weight, "fit_at_lower_bound": rep.n_at_lower,
                           "airy": res.summary(), "max_balance_residual": cv.max_balance_residual,
                           "max_identity_residual": cv.max_identity_residual}

    # --- Φ against the published stress soup (matched by top-view position)
    soup = to_ours(_obj_vertices(published / "lilium-n-stress.obj"), "-y")
    xy_s, phi_pub = soup[:, :2], -soup[:, 2]  # the soup stores φ in the file's y, which we read as −z
    dist, vid = cKDTree(net.vertices[:, :2]).query(xy_s)
    face = np.repeat(np.arange(len(soup) // 3), 3)
    same_faces = float(np.mean([set(vid[3 * k:3 * k + 3].tolist()) == set(f)
                                for k, f in enumerate(net.mesh.faces)]))
    rng_pub = float(np.ptp(phi_pub))
    coef, dev = _fit_affine_scale(phi_pub, res.phi[vid], xy_s)
    plane = (res.face_gradients[face] * xy_s).sum(axis=1) + res.face_offsets[face]
    coef_p, dev_p = _fit_affine_scale(phi_pub, plane, xy_s)
    rec["stress"] = {"match_distance_max": float(dist.max()), "soup_faces_match_network_faces": same_faces,
                     "scale": float(coef[0]), "affine": coef[1:].tolist(),
                     "max_deviation_rel": float(np.abs(dev).max() / rng_pub),
                     "rms_deviation_rel": float(np.sqrt(np.mean(dev ** 2)) / rng_pub),
                     "face_planes_max_deviation_rel": float(np.abs(dev_p).max() / rng_pub)}

    # --- reciprocal diagram against the published one (one vertex per face, face order)
    R_pub = to_ours(_obj_vertices(published / "lilium-n-recip.obj"), "-y")[:, :2]
    R = res.reciprocal_vertices
    sim, rdev = _fit_similarity(R_pub, R)
    size = float(np.linalg.norm(np.ptp(R_pub, axis=0)))
    dn = np.linalg.norm(rdev, axis=1)
    rec["reciprocal"] = {"scale": float(sim[0]), "translation": sim[1:].tolist(),
                         "max_deviation_rel": float(dn.max() / size), "rms_deviation_rel": float(np.sqrt(np.mean(dn ** 2)) / size)}

    # --- Φ and diagram from the weights the published diagram implies
    e, ef = net.mesh.edges, net.mesh.edge_faces
    inner = (ef >= 0).all(axis=1)
    ev = net.vertices[e[:, 1], :2] - net.vertices[e[:, 0], :2]
    Jev = np.c_[-ev[:, 1], ev[:, 0]]
    d = R_pub[ef[inner, 0]] - R_pub[ef[inner, 1]]
    w_pub = np.zeros(len(e))
    w_pub[inner] = (d * Jev[inner]).sum(axis=1) / (ev[inner] ** 2).sum(axis=1)
    w_pub = np.where(net.active_edges, w_pub, 0.0)
    tangential = np.abs((d * ev[inner]).sum(axis=1)) / np.linalg.norm(ev[inner], axis=1)
    act = net.active_edges & inner
    net_pub = Network(mesh=net.mesh, weights=w_pub, loads=net.loads, supports=net.supports)
    res_pub = airy(net_pub)
    coef2, dev2 = _fit_affine_scale(phi_pub, res_pub.phi[vid], xy_s)
    sim2, rdev2 = _fit_similarity(R_pub, res_pub.reciprocal_vertices)
    dn2 = np.linalg.norm(rdev2, axis=1)
    rec["from_published_weights"] = {
        "published_diagram_tangential_mismatch_rel": float(tangential.max() / np.linalg.norm(d, axis=1).mean()),
        "min_implied_weight": float(w_pub[act].min()),
        "correlation_with_fitted_weights": float(np.corrcoef(net.weights[act], w_pub[act])[0, 1]),
        "median_ratio_to_fitted_weights": float(np.median(w_pub[act] / net.weights[act])),
        "closure_residual": res_pub.max_closure_residual, "integration": res_pub.integration,
        "stress_scale": float(coef2[0]), "stress_max_deviation_rel": float(np.abs(dev2).max() / rng_pub),
        "stress_rms_deviation_rel": float(np.sqrt(np.mean(dev2 ** 2)) / rng_pub),
        "reciprocal_scale": float(sim2[0]), "reciprocal_max_deviation_rel": float(dn2.max() / size)}

    # --- relative principal directions against lilium-n-vf.txt (our export order: κ₂ first)
    vf = published / "lilium-n-vf.txt"
    if vf.is_file():
        rows = np.loadtxt(vf)
        U, V = to_ours(rows[:, :3], "-y"), to_ours(rows[:, 3:], "-y")
        for key, n_ in (("fitted", net), ("published_weights", net_pub)):
            fd = face_principal_directions(n_, curvatures(n_, airy(n_)))
            same = np.maximum(_line_angles(fd[:, 1], U), _line_angles(fd[:, 0], V))
            swap = np.maximum(_line_angles(fd[:, 0], U), _line_angles(fd[:, 1], V))
            ok = np.isfinite(same) & np.isfinite(swap)
            rec.setdefault("directions", {})[key] = {
                "faces_compared": int(ok.sum()), "median_angle_deg": float(np.median(same[ok])),
                "p90_angle_deg": float(np.percentile(same[ok], 90)),
                "fraction_in_other_order": float(np.mean(swap[ok] < same[ok]))}

    # --- files
    out.mkdir(parents=True, exist_ok=True)
    doc = airy_document(net, res, rd, cv)
    atomic_write_text(out / "lilium-airy.json", json.dumps(to_jsonable(doc), allow_nan=False, separators=(",", ":")))
    write_mesh(out / "lilium-phi.obj", res.stress_mesh(), up="-y")
    write_mesh(out / "lilium-recip.obj", rd.mesh("flat"), up="-y")
    write_vector_fields(out / "lilium-vf.txt", net, cv, up="-y")
    return rec


def _time_analysis(net) -> dict[str, Any]:
    from selfsupport.analysis import airy, curvatures, reciprocal

    res = airy(net)
    row = {"vertices": net.mesh.n_vertices, "faces": net.mesh.n_faces, "edges": net.mesh.n_edges,
           "integration": res.integration, "closure": res.max_closure_residual, "periods": len(res.periods)}
    row["t_airy"] = median_time(lambda: airy(net), repeat=3, budget=30.0)
    row["t_reciprocal"] = median_time(lambda: reciprocal(res), repeat=3, budget=30.0)
    row["t_curvatures"] = median_time(lambda: curvatures(net, res, directions=False), repeat=3, budget=30.0)
    row["t_directions"] = median_time(lambda: curvatures(net, res, directions=True), repeat=3, budget=30.0)
    row["t_total"] = row["t_airy"] + row["t_reciprocal"] + row["t_directions"]
    return row


def timings(published: Path, scenes: Path, rings: Sequence[int]) -> list[dict[str, Any]]:
    """Step 4: analysis times on the published networks and on constructed ones."""
    from selfsupport import api
    from selfsupport.analysis import construct
    from selfsupport.core.shapes import disk_points

    rows: list[dict[str, Any]] = []
    for stem in PUBLISHED_NETWORKS:
        if not (published / f"{stem}.obj").is_file():
            continue
        rep = api.check(_published_scene(published, scenes, stem))
        rows.append({"network": f"{stem} (published, weights fitted)",
                     "fit_max_rel_error": rep.max_relative_error, **_time_analysis(rep.network)})
    for r in rings:
        t0 = time.perf_counter()
        net = construct(disk_points(r, radius=5.0), "quartic", load=-1000.0)
        t_build = time.perf_counter() - t0
        rows.append({"network": f"§2.5 disk, {r} rings", "fit_max_rel_error": net.max_relative_error(),
                     "t_construct": t_build, **_time_analysis(net)})
    return rows


TIMING_COLUMNS = [Column("network", "network"), Column("vertices", "V"), Column("faces", "F"),
                  Column("fit_max_rel_error", "max rel. error", "{:.1e}"), Column("integration", "Φ by"),
                  Column("closure", "closure", "{:.1e}"), Column("t_construct", "construct [s]", "{:.3f}"),
                  Column("t_airy", "airy [s]", "{:.3f}"), Column("t_reciprocal", "reciprocal [s]", "{:.3f}"),
                  Column("t_curvatures", "curvatures [s]", "{:.3f}"),
                  Column("t_directions", "+directions [s]", "{:.3f}"), Column("t_total", "total [s]", "{:.3f}")]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m studies.airy_published", description=__doc__.split("\n\n")[0])
    p.add_argument("--published", required=True, type=Path, help="folder with the paper's published networks")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--scenes", type=Path, default=None, help="folder with the paper's scenes (default PUBLISHED/../scenes)")
    p.add_argument("--rings", type=int, nargs="*", default=list(CONSTRUCTED_RINGS),
                   help="disk rings of the constructed timing networks (default: ~1.2k, 2.4k, 10k, 64k vertices)")
    p.add_argument("--no-timings", action="store_true", help="only the lilium comparison")
    return p


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Run the study; returns everything written to ``airy_published.json``."""
    a = build_parser().parse_args(argv)
    published = a.published.resolve()
    scenes = (a.scenes or published.parent / "scenes").resolve()
    if not (published / "lilium-n.obj").is_file():
        raise SystemExit(f"{published}: no lilium-n.obj; give the paper's published folder")
    out = a.out.resolve()
    result: dict[str, Any] = {"lilium": compare_lilium(published, scenes, out)}
    if not a.no_timings:
        result["timings"] = timings(published, scenes, a.rings)
    from selfsupport.io.network_json import to_jsonable

    (out / "airy_published.json").write_text(json.dumps(to_jsonable(result), indent=1), encoding="utf-8")
    L = result["lilium"]
    cmp_rows = [
        {"what": "Φ (fitted weights) vs lilium-n-stress.obj", "scale": L["stress"]["scale"],
         "max": L["stress"]["max_deviation_rel"], "rms": L["stress"]["rms_deviation_rel"]},
        {"what": "reciprocal (fitted weights) vs lilium-n-recip.obj", "scale": L["reciprocal"]["scale"],
         "max": L["reciprocal"]["max_deviation_rel"], "rms": L["reciprocal"]["rms_deviation_rel"]},
        {"what": "Φ (weights implied by the published diagram) vs lilium-n-stress.obj",
         "scale": L["from_published_weights"]["stress_scale"],
         "max": L["from_published_weights"]["stress_max_deviation_rel"],
         "rms": L["from_published_weights"]["stress_rms_deviation_rel"]},
        {"what": "reciprocal (implied weights) vs lilium-n-recip.obj",
         "scale": L["from_published_weights"]["reciprocal_scale"],
         "max": L["from_published_weights"]["reciprocal_max_deviation_rel"], "rms": None},
    ]
    cols = [Column("what", "comparison (up to gauge)"), Column("scale", "fitted scale", "{:.6g}"),
            Column("max", "max deviation (rel.)", "{:.2e}"), Column("rms", "rms deviation (rel.)", "{:.2e}")]
    notes = [f"lilium-n: {L['vertices']} V, {L['faces']} F; weights fitted at fixed positions to max relative error "
             f"{L['fit_max_relative_error']:.1e} in {L['fit_seconds']:.1f} s; Φ convex: {L['airy']['convex']}; "
             f"balance (6) {L['max_balance_residual']:.1e}",
             "Φ deviations relative to the range of the published φ; diagram deviations relative to its bounding-box "
             "diagonal; the published files were matched by top-view position (soup) and face order (diagram)",
             f"weights implied by the published diagram vs ours: correlation "
             f"{L['from_published_weights']['correlation_with_fitted_weights']:.4f}; the published diagram's own "
             f"tangential mismatch {L['from_published_weights']['published_diagram_tangential_mismatch_rel']:.1e}"]
    if "directions" in L:
        dd = L["directions"]
        notes.append(f"relative principal directions vs lilium-n-vf.txt: median angle {dd['fitted']['median_angle_deg']:.1f}° "
                     f"(90%: {dd['fitted']['p90_angle_deg']:.1f}°) with fitted weights, "
                     f"{dd['published_weights']['median_angle_deg']:.1f}° with the implied ones")
    tables = [("lilium: comparison with the published files", cmp_rows, cols)]
    if "timings" in result:
        tables.append(("analysis timings (median of 3; 2-core machine)", result["timings"], TIMING_COLUMNS))
    md = write_markdown(out / "airy_published.md", "Airy analysis vs the paper's published lilium results", notes, tables)
    print(md)
    return result


if __name__ == "__main__":  # pragma: no cover
    main(sys.argv[1:])
