"""Heyman's hemisphere: the thinnest hemispherical dome that stands under self-weight, by the
limit program, against Heyman's t/R = 0.042.

::

    python -m studies.heyman --out out/heyman [--quick]

A hemisphere of radius 5 m, ρ = 2000 kg/m³ (t/R does not depend on either), its supports sliding
across the springing (:func:`selfsupport.structure.limit.min_thickness`), on meridian × parallel
meshes of growing resolution (:func:`selfsupport.core.shapes.meridian_dome`: every edge along a
meridian or a hoop) and on the ring triangulation of ``shape:dome`` (no meridian edges), whose
certified t/R stays near 0.05 at every resolution. Writes ``heyman.csv`` (stamped), ``heyman.md``,
``heyman.json`` and each certificate (``LAYOUT-PxM.json``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from studies.common import STAMP_COLUMNS, Column, run_stamp, write_csv, write_markdown

#: Heyman (1977): the thinnest hemispherical dome under self-weight, t/R
HEYMAN = 0.042
RADIUS, DENSITY = 5.0, 2000.0
#: (layout, parallels or rings, meridians) of the full run; the quick run takes the first two
MESHES = (("meridian", 8, 16), ("rings", 8, 0), ("meridian", 16, 64), ("meridian", 4, 8))

COLUMNS = (Column("layout", "layout"), Column("mesh", "mesh"), Column("vertices", "V"),
           Column("verdict", "verdict"), Column("t_over_r", "certified t/R", "{:.4f}"),
           Column("optimum_t_over_r", "program's t/R", "{:.4f}"),
           Column("vs_heyman", "vs Heyman's 0.042", "{:+.1%}"), Column("network", "certificate"),
           Column("seconds", "time [s]", "{:.1f}"), *STAMP_COLUMNS)


def run_case(layout: str, p: int, m: int, out: Path) -> dict[str, Any]:
    """The certified minimum thickness of one hemisphere mesh, its certificate written to ``out``."""
    from selfsupport.core.shapes import make_shape, meridian_dome
    from selfsupport.io import write_network
    from selfsupport.structure.limit import min_thickness

    scene = (meridian_dome(p, m, radius=RADIUS, height=RADIUS) if layout == "meridian" else
             make_shape("dome", rings=p, radius=RADIUS, height=RADIUS))
    mesh = f"{p}×{m}" if layout == "meridian" else f"{p} rings"
    t0 = time.perf_counter()
    r = min_thickness(scene, density=DENSITY, guess=0.1 * RADIUS, slide_supports=True)
    seconds = time.perf_counter() - t0
    name = f"{layout}-{p}x{m}.json" if layout == "meridian" else f"{layout}-{p}.json"
    if r.certified:
        write_network(out / name, r.certificate, thickness=r.value)
    t_r = r.value / RADIUS if r.certified else None
    print(f"{layout} {mesh}: {r.message} ({seconds:.1f} s)", file=sys.stderr)
    return {"layout": layout, "mesh": mesh, "vertices": scene.mesh.n_vertices, "verdict": r.verdict, "t_over_r": t_r,
            "optimum_t_over_r": r.optimum / RADIUS if r.optimum is not None else None,
            "vs_heyman": t_r / HEYMAN - 1 if t_r is not None else None,
            "network": name if r.certified else "", "seconds": seconds}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--quick", action="store_true", help="the first two meshes only")
    args = ap.parse_args(argv)
    stamp = run_stamp()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [run_case(layout, p, m, out) for layout, p, m in MESHES[:2 if args.quick else None]]
    notes = [f"hemisphere R = {RADIUS:g} m, ρ = {DENSITY:g} kg/m³, supports sliding across the springing; "
             "meridian: selfsupport.core.shapes.meridian_dome (edges along meridians and hoops); rings: "
             "shape:dome (its ring triangulation)",
             f"Heyman (1977): t/R = {HEYMAN}",
             f"command: python -m studies.heyman --out {args.out}{' --quick' if args.quick else ''}"]
    text = write_markdown(out / "heyman.md", "Heyman's hemisphere", notes, [("", rows, COLUMNS[:-len(STAMP_COLUMNS)])])
    (out / "heyman.json").write_text(json.dumps({"heyman": HEYMAN, "rows": rows}, indent=1, default=float) + "\n",
                                     encoding="utf-8")
    write_csv(out / "heyman.csv", [{**r, **stamp} for r in rows], COLUMNS)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
