"""Where the multilevel method pays: the measurement behind ``--method auto``.

    python -m studies.method_choice --out DIR [--shapes dome,pillar_vault,concave_disk]
        [--sizes 1000,4000,16000] [--big pillar_vault:64000] [--scenes DIR] [--time-limit S]

For each generated shape and size (:func:`selfsupport.core.shapes.make_shape`) two rows, each in its
own spawned process after an untimed warm-up solve: the single-level staggered method, and the
multilevel method with at least one coarser level (its ``direct_max`` lowered to a third of the
mesh below :data:`~selfsupport.methods.multilevel.DIRECT_MAX`, so that it builds levels where it
otherwise would not). ``--big`` adds one large case, run once. With ``--scenes`` (default: the
paper's scenes beside the project, when there) the Table 1 scenes get the same two rows plus
one of ``api.solve(method="auto")``, whose method and iterations must be the staggered row's.

A case's method that *paid* (:func:`paid`) is the one that converged, or, both converged, the
one with less CPU time (the machine is shared: wall time is mostly waiting). From the cases,
:func:`threshold_interval` gives the sizes between which the switch to multilevel belongs; the
notes say whether :data:`~selfsupport.methods.choice.LEVELS_ABOVE`, the switch of
:func:`~selfsupport.methods.choice.choose_method`, lies there, and every case says what the rule
chose and whether that was the method that paid.

Writes ``method_choice.csv`` (every row) and ``method_choice.md`` (one line per case) into
``--out`` and prints the table.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from .common import (
    PAPER_TABLE1,
    REPO,
    Column,
    exit_on_sigterm,
    load_average,
    read_study_scene,
    run_isolated,
    run_stamp,
    safe_ratio,
    study_scenes,
    write_csv,
    write_markdown,
)

DEFAULT_SHAPES = ("dome", "pillar_vault", "concave_disk")
DEFAULT_SIZES = (1000, 4000, 16000)
DEFAULT_SCENES = REPO.parent / "shared" / "paper-scenes" / "scenes"
#: The methods compared (rows of a case) and the row that checks the default on Table 1 scenes.
COMPARED = ("staggered", "multilevel")
AUTO_ROW = "auto"


# ------------------------------------------------------------------------------ decisions
def paid(staggered: Mapping[str, Any], multilevel: Mapping[str, Any]) -> str:
    """The method that paid on one case: the one that converged; both converged, the one with
    less CPU time (``cpu_s``); neither, the one that ended nearer equilibrium.

    >>> paid({"status": "converged", "cpu_s": 9.0}, {"status": "converged", "cpu_s": 4.0})
    'multilevel'
    >>> paid({"status": "converged", "cpu_s": 9.0}, {"status": "time_limit", "cpu_s": 4.0})
    'staggered'
    """
    ok = [r.get("status") == "converged" for r in (staggered, multilevel)]
    if ok[0] != ok[1]:
        return COMPARED[0] if ok[0] else COMPARED[1]
    key = "cpu_s" if ok[0] else "max_relative_error"
    a, b = (float(r.get(key, float("inf"))) for r in (staggered, multilevel))
    return COMPARED[1] if b < a else COMPARED[0]


def threshold_interval(cases: Sequence[tuple[int, str]]) -> tuple[int | None, int | None]:
    """``(lo, hi)`` from ``(vertices, method that paid)`` pairs: ``lo`` the largest size up to
    which the staggered method paid on every case, ``hi`` the smallest size from which the
    multilevel method paid on every case (``None``: no such size). A switch ``n > T`` agrees with
    every case when ``lo <= T < hi``.

    >>> threshold_interval([(1000, "staggered"), (4000, "staggered"), (16000, "multilevel")])
    (4000, 16000)
    >>> threshold_interval([(4000, "staggered"), (16000, "staggered"), (16000, "multilevel"), (64000, "multilevel")])
    (4000, 64000)
    """
    sizes = sorted({n for n, _ in cases})
    lo = hi = None
    for n in sizes:
        if all(m == COMPARED[0] for k, m in cases if k <= n):
            lo = n
    for n in reversed(sizes):
        if all(m == COMPARED[1] for k, m in cases if k >= n):
            hi = n
    return lo, hi


# ------------------------------------------------------------------------------- one row
def _scene(source: str, scenes_dir: str | None) -> Any:
    if source.startswith("shape:"):
        from selfsupport.core.shapes import make_shape

        _, name, n = source.split(":")
        return make_shape(name, n_vertices=int(n))
    return read_study_scene(scenes_dir, source)


def solve_row(*, source: str, method: str, time_limit: float, scenes_dir: str | None = None,
              warmup: bool = True) -> dict[str, Any]:
    """Solve ``source`` (``shape:NAME:N`` or a scene name in ``scenes_dir``) with ``method``
    (``staggered``, ``multilevel`` with at least one coarser level, or ``auto`` through
    :func:`selfsupport.api.solve`); runs in a spawned process (:func:`studies.common.run_isolated`)."""
    from selfsupport import api
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods.choice import choose_method
    from selfsupport.methods.multilevel import DIRECT_MAX, Multilevel
    from selfsupport.methods.staggered import StaggeredLinearization

    scene = _scene(source, scenes_dir)
    n = scene.mesh.n_vertices
    prob = api.problem(scene)
    direct_max = min(DIRECT_MAX, n // 3)

    def run(sc: Any, p: Any) -> Any:
        if method == AUTO_ROW:
            return api.solve(sc, method="auto", time_limit=time_limit)
        solver = StaggeredLinearization() if method == "staggered" else Multilevel(direct_max=direct_max)
        return solver.solve(p, {"time_limit": time_limit})

    if warmup:  # (imports, first factorizations: not the method's cost)
        small = make_shape("dome", n_vertices=300)
        run(small, api.problem(small))
    cpu0, t0 = time.process_time(), time.perf_counter()
    res = run(scene, prob)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - t0
    ml = res.parameters.get("multilevel", {})
    choice = choose_method(prob)
    return {"vertices": n, "status": res.status, "iterations": res.iterations, "cpu_s": cpu, "wall_s": wall,
            "max_relative_error": res.max_relative_error, "distance_mean": res.distance_mean,
            "levels": " > ".join(str(lv["n_vertices"]) for lv in ml.get("levels", [])),
            "ran": res.parameters.get("method_choice", {}).get("method", res.method),
            "rule": choice.method, "rule_why": choice.why}


# ------------------------------------------------------------------------------- the study
ROW_COLUMNS = [Column("case", "case"), Column("kind", "kind"), Column("method", "row"), Column("ran", "ran"),
               Column("vertices", "vertices"), Column("levels", "levels"), Column("status", "status"),
               Column("iterations", "it."), Column("cpu_s", "CPU s", "{:.2f}"), Column("wall_s", "wall s", "{:.2f}"),
               Column("max_relative_error", "max rel. error", "{:.1e}"),
               Column("distance_mean", "mean distance", "{:.3e}"), Column("rule", "rule"),
               Column("rule_why", "why"), Column("load", "load before the row"), Column("message", "message")]
CASE_COLUMNS = [Column("case", "case"), Column("vertices", "vertices"),
                Column("staggered", "staggered: status / it. / CPU s"),
                Column("multilevel", "multilevel: levels / status / CPU s"),
                Column("speedup", "staggered / multilevel CPU", "{:.2f}"),
                Column("distance_ratio", "mean distance multilevel / staggered", "{:.2f}"), Column("paid", "paid"),
                Column("rule", "rule (auto)"), Column("agrees", "rule = paid"), Column("auto", "auto row")]


def _case_line(case: str, rows: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    s, m = rows["staggered"], rows["multilevel"]
    won = paid(s, m)
    line = {"case": case, "vertices": s.get("vertices"), "paid": won, "rule": s.get("rule"),
            "agrees": "yes" if s.get("rule") == won else "NO",
            "staggered": f"{s.get('status')} / {s.get('iterations')} / {float(s.get('cpu_s', float('nan'))):.2f}",
            "multilevel": f"{m.get('levels')} / {m.get('status')} / {float(m.get('cpu_s', float('nan'))):.2f}",
            "speedup": safe_ratio(s.get("cpu_s"), m.get("cpu_s")),
            "distance_ratio": safe_ratio(m.get("distance_mean"), s.get("distance_mean"))}
    a = rows.get(AUTO_ROW)
    if a is not None:
        same = a.get("ran") == "staggered" and a.get("iterations") == s.get("iterations")
        line["auto"] = f"{a.get('ran')}, {a.get('iterations')} it. ({'same as staggered' if same else 'DIFFERS'})"
    return line


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.method_choice", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder (method_choice.csv, method_choice.md)")
    p.add_argument("--shapes", default=",".join(DEFAULT_SHAPES), help="comma-separated built-in shapes")
    p.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)), help="comma-separated vertex counts")
    p.add_argument("--big", default="", metavar="SHAPE:N", help="one more case, e.g. pillar_vault:64000")
    p.add_argument("--scenes", default=str(DEFAULT_SCENES) if DEFAULT_SCENES.is_dir() else "",
                   help="folder of the paper's scenes (its Table 1 scenes are run; '' for none)")
    p.add_argument("--time-limit", type=float, default=600.0, help="time limit per row [s] (default 600)")
    args = p.parse_args(argv)
    exit_on_sigterm()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stamp = run_stamp()
    cases: list[tuple[str, str, str | None, tuple[str, ...]]] = []  # (case, source, scenes dir, rows)
    sizes = [int(x) for x in args.sizes.split(",") if x]
    for n in sizes:  # size by size: the rows compared run side by side
        for shape in (s for s in args.shapes.split(",") if s):
            cases.append((f"{shape}:{n}", f"shape:{shape}:{n}", None, COMPARED))
    if args.big:
        cases.append((args.big, f"shape:{args.big}", None, COMPARED))
    if args.scenes:
        for name in study_scenes(Path(args.scenes)):
            if name in PAPER_TABLE1:
                cases.append((name, name, args.scenes, (*COMPARED, AUTO_ROW)))
    rows: list[dict[str, Any]] = []
    lines: list[dict[str, Any]] = []
    for case, source, scenes_dir, methods in cases:
        by_method: dict[str, dict[str, Any]] = {}
        for method in methods:
            r = run_isolated("studies.method_choice:solve_row",
                             {"source": source, "method": method, "time_limit": args.time_limit,
                              "scenes_dir": scenes_dir}, hard_timeout=args.time_limit * 1.5 + 120)
            r = {**stamp, "case": case, "kind": "scene" if scenes_dir else "shape", "method": method,
                 "load": load_average(), **r}
            by_method[method] = r
            rows.append(r)
            print(f"{case:>24} {method:>10}: {r.get('status')} it={r.get('iterations')} "
                  f"cpu={float(r.get('cpu_s', float('nan'))):.2f}s wall={float(r.get('wall_s', float('nan'))):.2f}s "
                  f"levels={r.get('levels')} load={r['load']}", flush=True)
        lines.append(_case_line(case, by_method))
        write_csv(out / "method_choice.csv", rows, ROW_COLUMNS + [Column(k, k) for k in stamp])
    from selfsupport.methods.choice import LEVELS_ABOVE

    shape_cases = [(int(ln["vertices"]), ln["paid"]) for ln in lines if ln["case"] not in PAPER_TABLE1]
    lo, hi = threshold_interval(shape_cases)
    fits = (lo is None or lo <= LEVELS_ABOVE) and (hi is None or LEVELS_ABOVE < hi)
    notes = [f"commit {stamp['commit']}, {stamp['date']}, {stamp['cpu_model']} ({stamp['cores']} cores); load "
             f"average at the start {stamp['load_start']}, at the end {load_average()} (shared machine)",
             "CPU seconds of the solve alone (process CPU, after an untimed warm-up solve), one run per row",
             "multilevel rows: at least one coarser level (direct_max = min(DIRECT_MAX, n // 3))",
             f"shapes: the staggered method paid on every case up to {lo} vertices, the multilevel method on every "
             f"case from {hi}; the rule switches above LEVELS_ABOVE = {LEVELS_ABOVE} "
             f"({'consistent with every case' if fits else 'NOT consistent with the measurement'})"]
    text = write_markdown(out / "method_choice.md", "Method choice: staggered vs multilevel", notes,
                          [("", lines, CASE_COLUMNS)])
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
