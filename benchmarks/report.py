"""The documentation's benchmark page, written from the committed CSVs (``benchmarks/results``).

    python -m benchmarks.report [--results benchmarks/results] [--page docs/benchmarks.md]

``make bench`` runs this after the studies (:mod:`benchmarks.run`); the page is generated, never
edited by hand. One section per CSV (:data:`SECTIONS`, in that order; a CSV not listed there gets
a section with every column): what the study measures, the command that regenerates it, the run's
stamp (commit, date, CPU model, cores, load average at the start) and the table.
:func:`table1_comparison`, :func:`dome_comparison`, :func:`destruction_comparison` and
:func:`koebe_comparison` are the comparison tables of docs/guide/paper.md (the docs' build hook
puts them in that page, :data:`PAPER_TABLES`), from the same CSVs: the paper's claim beside ours,
with a verdict.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # run as a script, or loaded by the docs' build hook
    sys.path.insert(0, str(ROOT))

from studies.common import PAPER_TABLE1, STAMP_COLUMNS, Column, markdown_table, read_csv_rows  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "benchmarks.md"


@dataclass(frozen=True)
class Section:
    """How the page shows one CSV: a title, what it measures, the command, the columns."""

    csv: str
    title: str
    about: str
    command: str
    columns: tuple[Column, ...]


def _num(value: str) -> float | int | str:
    """A CSV cell as a number where it is one (int before float), else the text."""
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


def typed(rows: Sequence[Mapping[str, str]]) -> list[dict[str, float | int | str]]:
    """The rows of :func:`studies.common.read_csv_rows` with numbers as numbers and empty cells as NaN."""
    return [{k: (math.nan if v == "" else _num(v)) for k, v in r.items()} for r in rows]


#: The columns of the two bracing paths' sections.
_BRACING_COLUMNS = (Column("scene", "scene"), Column("step", "step"), Column("bound", "diagonal bound [N/m]", "{:.4g}"),
                    Column("method", "method"), Column("status", "status"),
                    Column("worst_error", "worst case: max rel. error", "{:.1e}"), Column("checker", "checker", "{:.1e}"),
                    Column("diagonal_share", "diagonals' share", "{:.2e}"),
                    Column("weight_max", "largest weight [N/m]", "{:.4g}"),
                    Column("shortest_edge", "shortest edge / reference", "{:.3g}"),
                    Column("star_degeneracy", "peel: smallest star degeneracy", "{:.1e}"),
                    Column("seconds", "time [s]", "{:.0f}"))

SECTIONS: tuple[Section, ...] = (
    Section("table1.csv", "Table 1: the paper's scenes",
            "Each Table 1 scene of the paper solved by the default method (staggered, active-set weight fit), "
            "with its refinement phase and by the simultaneous IPOPT solve; the time is the `solve()` call "
            "alone, in a process of its own after an untimed warm-up; the error is recomputed from the "
            "written network with plain numpy. *dist. to ref.*: mean distance to the reference surface over "
            "the bounding-box diagonal; *published*: the paper's network, weights fitted at fixed positions.",
            "python -m studies.table1 --scenes $SCENES --out OUT --methods staggered/active-set "
            "staggered-refine/active-set simultaneous/ipopt",
            (Column("scene", "scene"), Column("vertices", "V"), Column("method", "method"),
             Column("backend", "backend"), Column("status", "status"), Column("time_s", "time [s]", "{:.2f}"),
             Column("paper_time_s", "paper time [s]", "{:.1f}"), Column("iterations", "iterations", "{:d}"),
             Column("paper_iterations", "paper it.", "{:d}"),
             Column("max_rel_error", "max rel. error", "{:.1e}"),
             Column("paper_max_rel_error", "paper error", "{:.1e}"),
             Column("checker_error", "checker error", "{:.1e}"),
             Column("dist_ref_mean", "dist. to ref. (mean)", "{:.2e}"),
             Column("peak_rss_mib", "peak RSS [MiB]", "{:.0f}"), Column("time_limit_s", "limit [s]", "{:g}"))),
    Section("peers_original.csv", "The paper's original code side by side",
            "The paper's C++ code (built headless by `../shared/original-tool/build.sh OUT`, stopping at its "
            "displayed error < 1e-4 or 50 iterations) and `selfsupport solve`, alternating scene by scene; "
            "CPU seconds (medians over the rounds): the original's to its end and to a max relative error of "
            "1e-3 (its trace), ours to 1e-3 and to 1e-9 (the solve's history), the whole solve and the whole "
            "process; errors recomputed from the network files.",
            "python -m studies.peers --scenes $SCENES --tools original --original-driver OUT --out OUT2",
            (Column("scene", "scene"), Column("vertices", "V"), Column("orig_status", "original: status"),
             Column("orig_iterations", "it", "{:d}"), Column("orig_cpu_s", "CPU s to its end", "{:.3g}"),
             Column("orig_cpu_to_1e-03", "to 1e-3", "{:.3g}"), Column("orig_error", "final error", "{:.1e}"),
             Column("ss_status", "ours: status"), Column("ss_iterations", "it", "{:d}"),
             Column("ss_cpu_to_1e-03", "to 1e-3", "{:.3g}"), Column("ss_cpu_to_1e-09", "to 1e-9", "{:.3g}"),
             Column("ss_process_cpu_s", "process", "{:.3g}"), Column("ss_error", "error", "{:.1e}"),
             Column("ratio_process", "× process", "{:.3g}"), Column("rounds", "rounds", "{:d}"),
             Column("message", "message"))),
    Section("warm_resolve.csv", "Warm re-solve after an edit",
            "lilium edited (handle moves of 0.2 % of the diagonal, a density change, a pin) and solved cold (from "
            "the reference) and warm (from the unedited network); times are the best of the repeats.",
            "python -m studies.warm_resolve --scenes $SCENES --out OUT",
            (Column("scene", "scene"), Column("edit", "edit"), Column("cold_s", "cold [s]", "{:.3f}"),
             Column("cold_it", "cold it", "{:d}"), Column("warm_s", "warm [s]", "{:.3f}"),
             Column("warm_it", "warm it", "{:d}"), Column("speedup", "speed-up", "{:.1f}×"),
             Column("warm_used", "warm start kept"), Column("warm_err", "warm error", "{:.1e}"),
             Column("gap", "warm − cold / diag", "{:.1e}"))),
    Section("design_latency.csv", "Design tool latency",
            "A real `selfsupport design` server and a scripted WebSocket client: each edit sent when the "
            "previous frame arrived; end-to-end from the edit sent to the new frame received, the solve "
            "alone, and the server's time from the edit received to the frame built (median and 90th "
            "percentile).",
            "python -m studies.design_latency --scenes $SCENES --out OUT",
            (Column("scene", "scene"), Column("vertices", "V"), Column("interaction", "interaction"),
             Column("median_ms", "median [ms]", "{:.0f}"), Column("p90_ms", "p90 [ms]", "{:.0f}"),
             Column("solve_ms", "solve [ms]", "{:.0f}"), Column("server_ms", "server [ms]", "{:.0f}"),
             Column("iterations", "iterations", "{:g}"), Column("frame_kb", "frame [kB]", "{:.0f}"))),
    Section("scaling.csv", "Scaling with mesh size",
            "Generated shapes at growing sizes, each solve in a process of its own; *factor −K_ff*: one "
            "Cholesky factorization of the free-vertex stress Laplacian at the final weights, the unit of "
            "*time / (its × factor)*.",
            "python -m studies.scaling --out OUT --sizes 1000,4000  (make bench BENCH_SIZES=1000,4000,16000,64000)",
            (Column("shape", "shape"), Column("vertices", "V"), Column("method", "method"),
             Column("status", "status"), Column("time_s", "time [s]", "{:.2f}"),
             Column("iterations", "iterations", "{:d}"), Column("max_rel_error", "max rel. error", "{:.1e}"),
             Column("peak_rss_mib", "peak RSS [MiB]", "{:.0f}"), Column("factor_K_s", "factor −K_ff [s]", "{:.4f}"),
             Column("limit_ratio", "time / (its × factor)", "{:.1f}"), Column("message", "message"))),
    Section("scaling_exponents.csv", "Scaling: fitted exponents",
            "Least-squares slope of log time (and log solve memory) against log vertices over the converged "
            "rows of the scaling table.",
            "python -m studies.scaling --out OUT",
            (Column("shape", "shape"), Column("method", "method"), Column("sizes", "sizes used"),
             Column("time_exponent", "time ∝ n^k: k", "{:.2f}"),
             Column("memory_exponent", "solve memory ∝ n^k: k", "{:.2f}"))),
    Section("planarity.csv", "Planarity against closeness",
            "The quad scenes solved with planarity terms in the objective, then refined; non-planarity is the "
            "distance between a quad's diagonals over its mean edge length.",
            "python -m studies.planarity --scenes $SCENES --out OUT",
            (Column("scene", "scene"), Column("objective", "objective"), Column("refine", "refine", "{:d}"),
             Column("status", "status"), Column("nonplanar_max", "non-planarity max", "{:.2e}"),
             Column("nonplanar_mean", "mean", "{:.2e}"), Column("reduction", "max reduction", "{:.1f}×"),
             Column("dist_mean", "dist. to ref. (mean)", "{:.3e}"),
             Column("max_rel_error", "max rel. error", "{:.1e}"), Column("time_s", "time [s]", "{:.1f}"))),
    Section("pq.csv", "Planar quads along the principal directions (Fig. 12)",
            "Each scene remeshed along its relative principal directions and along a fixed grid (by the seamless "
            "integer-grid remesh, the default, and by streamlines), then solved with planar faces required "
            "(tolerance 1e-3, 300 s per solve); the published `*-pq-n.obj` measured the same way. The checker: "
            "the independent check_network.py's max relative error of the written network. Dist. before: the "
            "remesh, its heights from the network in equilibrium, before the planar solve. Rows tagged `published "
            "spacing`: the seamless remeshes again at the published mesh's mean top-view edge (where there is one).",
            "python -m studies.pq --scenes $SCENES/.. --out OUT --densities mean,published",
            (Column("scene", "scene"), Column("mesh", "mesh"), Column("faces", "faces"),
             Column("quads", "quads", "{:.1%}"),
             Column("status", "status"), Column("solved_by", "solved by"),
             Column("max_rel_error", "max rel. error", "{:.1e}"), Column("checker", "checker", "{:.1e}"),
             Column("start_nonplanar", "non-planarity before (max / mean)"),
             Column("nonplanar_max", "non-planarity after (max)", "{:.1e}"),
             Column("dist_start", "dist. to ref. before (mean)", "{:.3e}"),
             Column("dist_mean", "dist. to ref. (mean)", "{:.3e}"), Column("time_s", "time [s]", "{:.1f}"))),
    Section("stability_dome.csv", "The dome under added load (Figs. 9–10)",
            "dome2, ρ = 2,500 kg/m³, supported on its boundary vertices on the ground, added mass at the apex "
            "(the first row: the file as stored, its own pins, unloaded); per thickness and load a search for a "
            "compressive network in equilibrium inside reference ± t/2 (*inside hull*: found, which certifies "
            "that the shell stands; not found is no proof of collapse), and the mean closest-vertex distance "
            "to the paper's published network of that load.",
            "python -m studies.stability_dome --scenes $SCENES --out OUT",
            (Column("configuration", "configuration"), Column("thickness_m", "t [m]", "{:g}"),
             Column("added_kg", "added [kg]", "{:,.0f}"), Column("found", "inside hull"), Column("status", "status"),
             Column("max_relative_error", "max rel. error", "{:.1e}"),
             Column("max_hull_excess_m", "max excess [m]", "{:.3g}"), Column("outside", "outside"),
             Column("pub_nearest_mean_m", "to the published network [m]", "{:.2f}"),
             Column("seconds", "time [s]", "{:.1f}"))),
    Section("stability_dome_max_load.csv", "The dome's largest certified load",
            "The same dome: per thickness the largest added mass at the apex with a compressive network inside "
            "the hull, by one limit program (each vertex on the normal line through its reference vertex), its "
            "optimum certified by its network (equilibrium, compression and the hull checked outside the "
            "solver): a lower bound of the largest load.",
            "python -m studies.stability_dome --scenes $SCENES --out OUT",
            (Column("thickness_m", "t [m]", "{:g}"), Column("verdict", "verdict"),
             Column("max_load_kg", "certified [kg]", "{:,.0f}"), Column("optimum_kg", "program's optimum [kg]", "{:,.0f}"),
             Column("binding", "vertices on the hull's faces", "{:d}"),
             Column("max_relative_error", "max rel. error", "{:.1e}"), Column("seconds", "time [s]", "{:.0f}"))),
    Section("stability_dome_starts.csv", "The dome's largest load from many starts (Fig. 9)",
            "The limit program at t = 0.1 m from many starts: the staggered network, the published networks "
            "(weights fitted), the reference surface, perturbed starts, a lower weight bound near zero, the supports "
            "sliding across the springing, the vertices sliding along the reference (re-anchored rounds, each certified) and the load "
            "spread over the apex's one-ring; per start the certified "
            "load, the program's optimum and the bounds active there (hull faces on the extrados / intrados, "
            "weights at ε) with IPOPT's multipliers.",
            "python -m studies.stability_dome --scenes $SCENES --out OUT",
            (Column("start", "start"), Column("load_at", "load at"), Column("verdict", "verdict"),
             Column("max_load_kg", "certified [kg]", "{:,.0f}"), Column("optimum_kg", "program's optimum [kg]", "{:,.0f}"),
             Column("hull_active", "hull bounds active (extrados / intrados)"),
             Column("hull_top", "largest hull multipliers: vertex (side) kg per m"),
             Column("weights_at_lower", "weights at ε"), Column("seconds", "time [s]", "{:.0f}"))),
    Section("destruction.csv", "Destruction (Fig. 8)",
            "twocirc-3 as built (its own thrust network as the hull's mid-surface), ρ = 2,500 kg/m³: the paper's "
            "cuts, recovered by position from its published stages, applied in turn, each followed by our "
            "cascade; a published step that removes more than 10% of the faces is a collapse, not applied: our "
            "cascade after the previous cut must predict it.",
            "python -m studies.destruction --scenes $SCENES --out OUT",
            (Column("thickness_m", "t [m]", "{:g}"), Column("step", "step", "{:d}"), Column("kind", "paper step"),
             Column("paper_before", "paper: faces before", "{:,d}"), Column("paper_faces", "paper: after", "{:,d}"),
             Column("faces", "ours: after", "{:,d}"), Column("paper_lost", "lost by the paper (mapped)", "{:d}"),
             Column("lost_too", "of these lost by us", "{:d}"), Column("our_stages", "our stages", "{:d}"),
             Column("status", "status (ours)"))),
    Section("koebe.csv", "The Enneper family Φ + αR (Fig. 15)",
            "The networks −(Φ + αR) of our Koebe meshes of the Enneper layout (inscribed in the paraboloid and "
            "tangent to it) and of the published Φ, under the loads of their reciprocal cells (*top-view*: unit "
            "load per top-view area); the error from the independent checker.",
            "python -m studies.koebe --scenes $SCENES/.. --out OUT",
            (Column("mesh", "Φ"), Column("loads", "loads"), Column("alpha", "α", "{:.4g}"),
             Column("checker_max_rel_error", "checker max rel. error", "{:.1e}"),
             Column("min_weight", "min w", "{:.4f}"), Column("K_min", "K_Φ min", "{:.4f}"),
             Column("K_max", "K_Φ max", "{:.4f}"))),
    Section("koebe_published.csv", "What the published Enneper files are",
            "enneper-koebe.obj and enneper-summed.obj measured against our meshes (lengths over the published "
            "Φ's mean edge length).",
            "python -m studies.koebe --scenes $SCENES/.. --out OUT",
            (Column("quantity", "quantity"), Column("value", "value", "{:.6g}"), Column("about", "what it is"))),
    Section("load_cases.csv", "Several load cases on the paper's scenes",
            "One geometry for three cases (empty; snow 80 kg/m²; a point load of a share of the self-weight "
            "at the highest free vertex), each solve limited to 120 s: the default (the staggered method, then "
            "IPOPT over every case from its network when it does not converge), no bound on the weights "
            "(tension allowed), and the same design with its quads split into triangles. *worst case*: the "
            "case with the largest max relative error by the independent checker; *plan: edges − horizontal "
            "equations*: at a generic plan the count of its horizontal self-stresses (weights of either sign "
            "balancing every free vertex in plan); *self-stresses of the envelope's plan*: measured at the "
            "cases' envelope solved alone, where the continuation was blocked (one: over that plan no heights "
            "and no weights of either sign carry cases that are not proportional); *any weights carry the "
            "difference*: at the result's geometry, the relative residual of the best change of the weights "
            "(either sign, unbounded) carrying the cases' load differences (well above round-off: the "
            "geometry blocks, not the bounds); *the peel reaches the point load*: from the free vertices with "
            "three edges or fewer, the weights' difference between the point case and the empty one is forced "
            "to zero on every edge of the loaded vertex (the mesh alone decides it): then only a network with a "
            "degenerate vertex star carries both.",
            "python -m studies.load_cases --scenes $SCENES --out OUT --csv benchmarks/results/load_cases.csv",
            (Column("scene", "scene"), Column("cases", "cases"), Column("point_share", "point share", "{:.0%}"),
             Column("variant", "variant"), Column("status", "status"), Column("wall_s", "wall [s]", "{:.0f}"),
             Column("worst_case", "worst case"), Column("worst_error", "its error (checker)", "{:.1e}"),
             Column("ipopt_status", "IPOPT from the staggered network"),
             Column("plan_count", "plan: edges − horizontal equations", "{:.0f}"),
             Column("plan_self_stresses", "self-stresses of the envelope's plan", "{:.0f}"),
             Column("carry_residual", "any weights carry the difference: residual", "{:.1e}"),
             Column("peel_blocks", "the peel reaches the point load"))),
    Section("peel.csv", "The peel from the free edges: which meshes rule out a point-load case",
            "Every scene file, the point load at its highest free vertex, the empty case beside it: from the "
            "free vertices with three edges or fewer, the weights' difference between the two cases is forced "
            "to zero edge by edge ([theory](theory/load-cases.md)). Where it *reaches the loaded vertex*, only a "
            "network with a degenerate vertex star (two edges on a line or three in a plane) can carry both "
            "cases, whatever the weights' sign or bounds. The mesh alone decides it; the degeneracy is measured "
            "at the scene's own positions, in the peel's own order.",
            "python -m studies.peel --scenes $SCENES --out OUT",
            (Column("scene", "scene"), Column("faces", "faces"), Column("free", "free vertices", "{:.0f}"),
             Column("peel_starts", "free vertices with ≤ 3 edges", "{:.0f}"), Column("edges", "edges", "{:.0f}"),
             Column("loaded", "loaded vertex", "{:.0f}"), Column("steps", "peel steps", "{:.0f}"),
             Column("forced", "forced edges", "{:.0f}"), Column("reaches", "reaches the loaded vertex"),
             Column("degeneracy", "smallest star degeneracy", "{:.1e}"))),
    Section("bracing.csv", "How little bracing the quad designs need",
            "vault-pillar, whose three cases (as above, point load 5%) stall as quads: split into triangles and "
            "solved, then its diagonals' weights bounded to [0, f·D0] (D0: the split network's largest diagonal "
            "weight), each step IPOPT nearest the last step that stood (a step that does not stand retried "
            "halfway); then the design itself from there, its diagonals dropped, by the staggered method and by "
            "IPOPT. *diagonals' share*: per case the diagonals' forces (weight × length) over the case's total "
            "load, the largest; *shortest edge*: the design's shortest edge over its length in the reference (a "
            "shrinking edge turns quads into triangles); *peel: smallest star degeneracy*: at the row's "
            "positions, the smallest singular value of the edge directions of the stars the design's peel of the "
            "point load passes (0: degenerate; only there could the quads alone carry the cases).",
            "python -m studies.bracing --scenes $SCENES --out OUT",
            _BRACING_COLUMNS),
    Section("bracing_finer.csv", "How little bracing: another path",
            "The same continuation through finer bounds (0.5, 0.2, 0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001 of "
            "D0): where it ends depends on the path.",
            "python -m studies.bracing --scenes $SCENES --out OUT --fractions 0.5,0.2,0.1,0.05,0.02,0.01,0.005,0.002,0.001",
            _BRACING_COLUMNS),
    Section("theory_whys.csv", "Why not: the theory pages' measurements",
            "What the theory pages' *why not* paragraphs quote, on generated shapes: the weight fit's Gram "
            "matrix on its structural pattern against scipy's product, and the coupled position step's cost "
            "per outer iteration.",
            "python -m studies.theory_whys --out OUT",
            (Column("why", "why"), Column("quantity", "quantity"), Column("value", "value", "{:.3g}"),
             Column("about", "what it is"))),
)
_BY_CSV = {s.csv: s for s in SECTIONS}


def stamp_line(rows: Sequence[Mapping[str, object]]) -> str:
    """The run's stamp in one line: each stamp column's distinct values (one run: one value each)."""
    parts = []
    for c in STAMP_COLUMNS:
        values = list(dict.fromkeys(str(r.get(c.key, "")) for r in rows if str(r.get(c.key, "")) not in ("", "nan")))
        parts.append(f"{c.header}: {', '.join(values) if values else 'not recorded'}")
    return "; ".join(parts)


def section_markdown(section: Section, rows: Sequence[Mapping[str, object]]) -> str:
    """One CSV's section of the page."""
    present = [c for c in section.columns if any(c.key in r for r in rows)]
    return "\n".join([f"## {section.title}", "", section.about, "", f"`{section.command}`", "",
                      f"*{section.csv}* — {stamp_line(rows)}", "", markdown_table(rows, present), ""])


def table1_comparison(rows: Sequence[Mapping[str, object]]) -> str:
    """The Table 1 of docs/guide/paper.md: per scene, the paper's numbers beside the default
    method's (``staggered`` / ``active-set``), and the mean distance to the reference of the
    paper's published network beside ours."""
    def first(scene: str, method: str, backend: str | None = None) -> Mapping[str, object]:
        return next((r for r in rows if r.get("scene") == scene and r.get("method") == method
                     and (backend is None or r.get("backend") == backend)), {})

    def f(value: object, fmt: str) -> str:
        return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else fmt.format(value)

    out = ["| scene (figure) | V / E | time [s]: paper / ours | iterations: paper / ours "
           "| max rel. error: paper / ours | dist. to reference: paper's network / ours |",
           "|---|---|---|---|---|---|"]
    for name, paper in PAPER_TABLE1.items():
        ours = first(name, "staggered", "active-set")
        if not ours:
            continue
        pub = first(name, "published")
        out.append(f"| {name} ({paper.figure}) | {f(ours.get('vertices'), '{}')} / {f(ours.get('edges'), '{}')} "
                   f"| {paper.time_s:g} / {f(ours.get('time_s'), '{:.2f}')} "
                   f"| {paper.iterations} / {f(ours.get('iterations'), '{}')} "
                   f"| {paper.max_rel_error:.1e} / {f(ours.get('max_rel_error'), '{:.1e}')} "
                   f"| {f(pub.get('dist_ref_mean'), '{:.2e}')} / {f(ours.get('dist_ref_mean'), '{:.2e}')} |")
    out += ["", f"*benchmarks/results/table1.csv* — {stamp_line([r for r in rows if r.get('method') == 'staggered'])}"]
    return "\n".join(out)


def _cell(value: object, fmt: str) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else fmt.format(value)


def _true(value: object) -> bool:
    return str(value) == "True"


#: Fig. 9's load [kg] and thickness [m], Fig. 10's thickness and loads (the paper's captions)
FIG9_KG, FIG9_T, FIG10_T, FIG10_KG = 11000.0, 0.1, 1.0, (0.0, 5000.0, 10000.0, 20000.0)


def verdict(ok: bool) -> str:
    """The comparison tables' last column."""
    return "**reproduced**" if ok else "**not reproduced**"


def dome_comparison(series: Sequence[Mapping[str, object]], max_load: Sequence[Mapping[str, object]]) -> str:
    """Figs. 9 and 10 of the paper beside ours (``stability_dome.csv``,
    ``stability_dome_max_load.csv``), a verdict per claim; the largest certified load per thickness below."""
    exp = [r for r in series if r.get("configuration") != "as stored"]

    def at(t: float, kg: float) -> Mapping[str, object]:
        return next((r for r in exp if r.get("thickness_m") == t and r.get("added_kg") == kg), {})

    out = ["| the paper | ours | |", "|---|---|---|"]
    r9 = at(FIG9_T, FIG9_KG)
    if r9:
        ours = ("a network inside the hull" if _true(r9.get("found")) else
                f"no network found ({_cell(r9.get('outside'), '{}')} vertices outside, up to "
                f"{_cell(r9.get('max_hull_excess_m'), '{:.3g}')} m)")
        out.append(f"| Fig. 9, t = {FIG9_T:g} m: stands under {FIG9_KG:,.0f} kg | {ours} | {verdict(_true(r9.get('found')))} |")
    m9 = next((r for r in max_load if r.get("thickness_m") == FIG9_T), {})
    if m9:
        kg = m9.get("max_load_kg")
        ok = isinstance(kg, (int, float)) and kg >= FIG9_KG
        ours = (f"largest certified load {_cell(kg, '{:,.0f}')} kg ({_cell(m9.get('binding'), '{}')} vertices on "
                "the hull's faces)" if m9.get("verdict") == "certified" else f"none certified ({m9.get('verdict')})")
        out.append(f"| Fig. 9, t = {FIG9_T:g} m: a largest load of at least {FIG9_KG:,.0f} kg | {ours} | {verdict(ok)} |")
    r10 = [at(FIG10_T, kg) for kg in FIG10_KG]
    if all(r10):
        found = [_true(r.get("found")) for r in r10]
        loads = ", ".join(f"{kg:,.0f}" for kg in FIG10_KG)
        if all(found):
            ours = "a network inside the hull at every one of these loads"
        else:
            ours = "inside the hull at " + (", ".join(f"{kg:,.0f}" for kg, f in zip(FIG10_KG, found) if f) or "none") + \
                   " kg; none found at " + ", ".join(f"{kg:,.0f}" for kg, f in zip(FIG10_KG, found) if not f) + " kg"
        out.append(f"| Fig. 10, t = {FIG10_T:g} m, {loads} kg: the network leaves the hull as the load grows "
                   f"| {ours} | {verdict(found[0] and not found[-1])} |")
    out += ["", "| t [m] | largest certified load [kg] | the program's optimum [kg] |", "|---|---|---|"]
    out += [f"| {r.get('thickness_m'):g} | {_cell(r.get('max_load_kg'), '{:,.0f}')} | {_cell(r.get('optimum_kg'), '{:,.0f}')} |"
            for r in max_load]
    out += ["", f"*benchmarks/results/stability_dome.csv* — {stamp_line(series)}", "",
            f"*benchmarks/results/stability_dome_max_load.csv* — {stamp_line(max_load)}"]
    return "\n".join(out)


def destruction_comparison(rows: Sequence[Mapping[str, object]]) -> str:
    """Fig. 8 of the paper beside ours (``destruction.csv``): per published step the paper's faces
    and ours at each thickness, with a verdict: a cut is reproduced when what is left stands with
    nothing more removed (one stage of ours), the collapse when our cascade lost at least half of
    the faces the paper lost."""
    ts = list(dict.fromkeys(r.get("thickness_m") for r in rows))
    steps = list(dict.fromkeys(r.get("step") for r in rows))
    head = "| step | the paper (faces) | " + " | ".join(f"ours, t = {t:g} m" for t in ts) + " |"
    out = [head, "|---|---|" + "---|" * len(ts)]
    for k in steps:
        by_t = {r.get("thickness_m"): r for r in rows if r.get("step") == k}
        first = next(iter(by_t.values()))
        paper = (f"{first.get('kind')}: {_cell(first.get('paper_before'), '{:,}')} → "
                 f"{_cell(first.get('paper_faces'), '{:,}')}")
        cells = []
        for t in ts:
            r = by_t.get(t, {})
            if r.get("kind") == "collapse":
                lost, too = r.get("paper_lost"), r.get("lost_too")
                ok = isinstance(lost, int) and isinstance(too, int) and lost > 0 and 2 * too >= lost
                cells.append(f"{_cell(r.get('faces'), '{:,}')} faces stand; lost {_cell(too, '{}')} of the paper's "
                             f"{_cell(lost, '{}')}: {verdict(ok)}")
            else:
                ok = r.get("status") == "stands" and r.get("our_stages") == 1
                what = ("faces stand, nothing more removed" if ok else
                        f"faces after a cascade of {_cell(r.get('our_stages'), '{}')} stages ({r.get('status')})")
                cells.append(f"{_cell(r.get('faces'), '{:,}')} {what}: {verdict(ok)}")
        out.append(f"| {k} | {paper} | " + " | ".join(cells) + " |")
    out += ["", f"*benchmarks/results/destruction.csv* — {stamp_line(rows)}"]
    return "\n".join(out)


#: the largest relative fit residual that counts as "to the files' six digits"
SIX_DIGITS = 1e-4
#: the largest max relative error that counts as equilibrium to round-off
ROUND_OFF = 1e-9


def koebe_comparison(eq_rows: Sequence[Mapping[str, object]], pub_rows: Sequence[Mapping[str, object]]) -> str:
    """Fig. 15 of the paper beside ours (``koebe.csv``, ``koebe_published.csv``), a verdict per claim."""
    q = {r.get("quantity"): r.get("value") for r in pub_rows}
    family = [r for r in eq_rows if str(r.get("mesh", "")).startswith("enneper-") and r.get("loads") == "reciprocal"]
    worst = max((float(r["checker_max_rel_error"]) for r in family), default=math.nan)
    alphas = ", ".join(f"{a:.4g}" for a in sorted({float(r["alpha"]) for r in family}))
    out = ["| the paper | ours | |", "|---|---|---|"]
    if family:
        out.append(f"| the family Φ + αR of the Enneper Koebe mesh is self-supporting | in equilibrium, checked "
                   f"independently, to {worst:.1e} for α = {alphas}, inscribed and tangent | "
                   f"{verdict(worst <= ROUND_OFF)} |")
    if "alpha" in q:
        res = q.get("alpha_fit_residual")
        ok = isinstance(res, float) and res <= SIX_DIGITS
        out.append(f"| enneper-summed.obj is a member of the family of enneper-koebe.obj | enneper-summed.obj − "
                   f"enneper-koebe.obj = α R with α = {q['alpha']:.5f}, to {_cell(res, '{:.1e}')} of the height "
                   f"difference | {verdict(ok)} |")
    out += ["", f"*benchmarks/results/koebe.csv* — {stamp_line(eq_rows)}"]
    return "\n".join(out)


def _rows(name: str, results: Path = RESULTS) -> list[dict[str, float | int | str]]:
    return typed(read_csv_rows(results / name))


#: The paper-comparison tables that docs/hooks.py puts in docs/guide/paper.md: marker -> table.
PAPER_TABLES: dict[str, Callable[[], str]] = {
    "<!-- bench-table1 -->": lambda: table1_comparison(_rows("table1.csv")),
    "<!-- bench-dome -->": lambda: dome_comparison(_rows("stability_dome.csv"), _rows("stability_dome_max_load.csv")),
    "<!-- bench-destruction -->": lambda: destruction_comparison(_rows("destruction.csv")),
    "<!-- bench-koebe -->": lambda: koebe_comparison(_rows("koebe.csv"), _rows("koebe_published.csv")),
}


def page_markdown(results: Path = RESULTS) -> str:
    """The whole page from the CSVs in ``results``."""
    files = sorted(results.glob("*.csv"), key=lambda p: (p.name not in _BY_CSV,
                                                          [s.csv for s in SECTIONS].index(p.name)
                                                          if p.name in _BY_CSV else 0, p.name))
    parts = ["# Benchmarks", "",
             "<!-- Generated by `python -m benchmarks.report` from benchmarks/results/*.csv: do not edit. -->", "",
             "Every number below comes from a CSV in `benchmarks/results`, written by `make bench` "
             "(`python -m benchmarks.run`; the paper's scenes from `SCENES`, default "
             "`../shared/paper-scenes/scenes`), and every row there records the commit, the date, the CPU "
             "model, the number of cores and the load average when its study started. The machine may be "
             "shared: timings taken under load vary by tens of percent between runs. "
             "The full tables, with every column, are the CSVs themselves.", ""]
    if not files:
        parts += ["No results yet: run `make bench`.", ""]
    for path in files:
        rows = typed(read_csv_rows(path))
        section = _BY_CSV.get(path.name) or Section(
            path.name, path.stem, "", f"see {path.name}", tuple(Column(k, k) for k in (rows[0] if rows else {})))
        parts.append(section_markdown(section, rows))
    return "\n".join(parts).rstrip() + "\n"


def write_page(results: Path = RESULTS, page: Path = PAGE) -> Path:
    """Write :func:`page_markdown` to ``page``; returns it."""
    page.write_text(page_markdown(results), encoding="utf-8")
    return page


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.report", description=__doc__.split("\n\n")[0])
    p.add_argument("--results", type=Path, default=RESULTS, help="folder of the CSVs")
    p.add_argument("--page", type=Path, default=PAGE, help="the page to write")
    a = p.parse_args(argv)
    if not a.results.is_dir():
        print(f"report: no results folder {a.results}; run make bench first", file=sys.stderr)
        return 2
    print(f"wrote {write_page(a.results, a.page)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
