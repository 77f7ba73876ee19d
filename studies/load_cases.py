"""Several load cases on the paper's scenes: does one geometry stand under all of them, and if
not, what blocks it.

::

    python -m studies.load_cases --scenes ../shared/paper-scenes/scenes --out out/load_cases \\
        --csv benchmarks/results/load_cases.csv   # (or: make bench, which copies OUT/load_cases.csv there)

Cases (written as TOML files under ``--out``): on vault-pillar, lilium and cas the three a designer
asks for — empty; snow 80 kg/m² on all faces; a point load of a share of the self-weight
at the highest free vertex — with the share 1% and 5% (where the plan blocks, it blocks at any
share: see below). At 5% also:

* ``tension allowed``: ``--eps -1e12`` (no bound on the weights; checked with
  ``--allow-tension``): where this converges and the default does not, the compression bound
  blocks; where this fails too, the geometry (one network for every case's equations) does;
* ``triangulated``: the same design, supports and cases with every quad split along its shorter
  diagonal (``selfsupport solve --triangulate``, :func:`selfsupport.core.triangulation.split_faces`):
  more edges than horizontal equations, so the plan has self-stresses to spare.

Each solve is ``selfsupport solve --time-limit 120`` in its own process. Per run: status, wall
time, every case's max relative error by the shared independent checker (its worst case
reported), the IPOPT finish's status and the joint count (unknowns less equations:
:func:`selfsupport.methods.staggered.cases.joint_freedom`), the plan's count (edges less
horizontal equations, ``m − 2 n_free``) and, where the continuation was blocked, the horizontal
self-stresses of the envelope's plan (:func:`selfsupport.methods.staggered.cases.top_view_self_stresses`:
one means no heights and no weights of either sign carry cases that are not proportional over
it), and, where the result did not converge, the fixed-plan test at its network
(:func:`selfsupport.methods.staggered.cases.fixed_plan`: the self-stresses of its plan, the fewest
that ``C`` cases need over a generic fixed plan, ``⌈(C − 1) n_free / C⌉``, and, below that, the
least-squares residual over that plan with heights and weights of either sign free), and how far any weights (either sign, unbounded) carry
the cases' load differences at its geometry
(:func:`selfsupport.methods.staggered.cases.any_weights_carry`: well above round-off, the
geometry blocks), and, where the continuation was blocked, the compression test of its report at
its last network (:func:`selfsupport.methods.staggered.cases.least_tension`, a linear program:
"carried", "tension" with the least total force short of the lower bound over the blocked case's
total load, or "no weights" of either sign). Writes the CSV (``--csv``) and the runs' JSON beside
the networks.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from formulations.peel import difference_peel, star_degeneracy
from selfsupport.io import read_network
from studies.common import DEFAULT_CHECKER, STAMP_COLUMNS, Column, markdown_table, run_stamp, write_csv

TIME_LIMIT = 120.0
SHARES = (0.01, 0.05)
SCENES = ("vault-pillar", "lilium", "cas")
#: variants at the largest share: label -> (extra ``selfsupport solve`` arguments, cases kept, checker flags)
VARIANTS: dict[str, tuple[list[str], tuple[str, ...], list[str]]] = {
    "tension allowed": (["--eps", "-1e12"], ("empty", "snow", "point"), ["--allow-tension"]),
    "triangulated": (["--triangulate"], ("empty", "snow", "point"), []),
}

COLUMNS = (Column("scene", "scene"), Column("cases", "cases"), Column("point_share", "point share", "{:.0%}"),
           Column("variant", "variant"), Column("status", "status"), Column("wall_s", "wall [s]", "{:.0f}"),
           Column("worst_case", "worst case"), Column("worst_error", "its error (checker)", "{:.1e}"),
           Column("ipopt_status", "IPOPT from the staggered network"),
           Column("freedom", "unknowns − equations", "{:d}"),
           Column("plan_count", "plan: edges − horizontal equations", "{:d}"),
           Column("plan_self_stresses", "self-stresses of the envelope's plan", "{:d}"),
           Column("result_self_stresses", "self-stresses of the result's plan", "{:d}"),
           Column("fixed_plan_needed", "fewest the cases need over a generic fixed plan", "{:d}"),
           Column("fixed_plan_residual", "least squares over the result's plan: residual", "{:.1e}"),
           Column("carry_residual", "any weights carry the difference: residual", "{:.1e}"),
           Column("blocked_case", "the continuation's blocked case"),
           Column("compression_lp", "within the bounds at its last network (LP)"),
           Column("tension_share", "least tension there / the case's load", "{:.2g}"),
           Column("peel_blocks", "the peel from the free edges reaches the point load"),
           Column("star_degeneracy", "its stars' smallest degeneracy at the result", "{:.1e}"),
           Column("errors", "error per case (checker)")) + STAMP_COLUMNS
#: The benchmark page's columns (benchmarks/report.py): the table kept short.
SHORT = tuple(c for c in COLUMNS if c.key in ("scene", "cases", "point_share", "variant", "status", "wall_s",
                                               "worst_case", "worst_error", "ipopt_status", "plan_count",
                                               "plan_self_stresses", "carry_residual", "peel_blocks"))


def highest_free_and_weight(path: Path | Any) -> tuple[int, float]:
    """The highest free vertex of a scene (a file or a scene) and its self-weight [N] (the
    project's defaults)."""
    from selfsupport import api
    from selfsupport.core.loads import SelfWeight

    scene = api.as_scene(str(path)) if isinstance(path, (str, Path)) else path
    V, free = scene.mesh.vertices, np.flatnonzero(scene.free)
    return int(free[np.argmax(V[free, 2])]), -float(SelfWeight().nodal(scene.mesh, V).sum())


def three_cases(vertex: int, weight: float, share: float) -> dict[str, dict]:
    """The study's cases (``--load-cases`` TOML tables): empty; snow 80 kg/m² on all faces; a
    point load of ``share`` of the self-weight ``weight`` [N] at ``vertex``.

    >>> three_cases(7, 1000.0, 0.05)["point"]
    {'point_loads': {7: 50.0}}
    """
    return {"empty": {}, "snow": {"uniform_mass": 80.0}, "point": {"point_loads": {vertex: round(share * weight, 2)}}}


def toml_text(cases: dict[str, dict]) -> str:
    """Load cases as the ``--load-cases`` TOML (:mod:`selfsupport.io.loadcases`)."""
    out = []
    for name, c in cases.items():
        out.append(f"[cases.{name}]")
        for k, v in c.items():
            out.append(f"{k} = " + ("{ " + ", ".join(f'"{i}" = {x!r}' for i, x in v.items()) + " }"
                                    if isinstance(v, dict) else repr(v)))
        out.append("")
    return "\n".join(out)


def checked(path: Path, checker: Path, flags: list[str]) -> dict[str, float]:
    """Every case's max relative error by the independent checker (a copy with that case's
    weights and loads at the top level; NaN where the checker printed none)."""
    d = json.loads(path.read_text())
    out = {}
    for case in d.get("load_cases") or [{"name": "self-weight", "weights": d["weights"], "loads": d["loads"]}]:
        one = path.with_suffix(f".{case['name']}.json")
        one.write_text(json.dumps({**d, "weights": case["weights"], "loads": case["loads"]}))
        p = subprocess.run([sys.executable, str(checker), str(one), "--tol", "1e-8", *flags],
                           capture_output=True, text=True)
        vals = dict(t.split("=", 1) for t in p.stdout.split() if "=" in t)
        out[case["name"]] = float(vals.get("max_rel_error", "nan"))
        one.unlink()
    return out


def design(path: Path, *, triangulate: bool = False) -> Any:
    """The scene at ``path`` or (``triangulate``) its design split into triangles as
    ``selfsupport solve --triangulate`` splits it."""
    from selfsupport import api

    return api.triangulated_design(str(path)) if triangulate else api.as_scene(str(path))


def plan_count(scene: Any) -> int:
    """Edges that carry a weight less twice the free vertices (the plan's horizontal equations)."""
    return int(np.count_nonzero(scene.active_edges)) - 2 * int(np.count_nonzero(~scene.supports))


def point_peel(scene: Any, vertex: int) -> Any:
    """The peel from the free edges (:func:`formulations.peel.difference_peel`) of the
    cases' one difference, the point load at ``vertex``."""
    return difference_peel(scene.mesh.n_vertices, scene.mesh.edges[scene.active_edges], scene.supports, [vertex])


def jobs(scenes: Path, names: tuple[str, ...], shares: tuple[float, ...],
         variants: tuple[str, ...] = ("default", *VARIANTS)) -> list[dict]:
    """The study's solves: per scene the three cases at every share (``"default"`` among
    ``variants``), and the other ``variants`` at the largest."""
    result = []
    for name in names:
        path = scenes / f"{name}.sss"
        scene = design(path)
        v, weight = highest_free_and_weight(scene)
        split = design(path, triangulate=True) if "triangulated" in variants else None
        for share in shares:
            cases = three_cases(v, weight, share)
            base = {"scene": name, "path": path, "point_share": share, "cases": cases,
                    "plan_count": plan_count(scene), "peel": point_peel(scene, v)}
            if "default" in variants:
                result.append({**base, "variant": "default", "extra": [], "flags": []})
            if share != max(shares):
                continue
            for label, (extra, kept, flags) in VARIANTS.items():
                if label not in variants:
                    continue
                job = {**base, "variant": label, "cases": {k: cases[k] for k in kept}, "extra": extra, "flags": flags}
                if "--triangulate" in extra:
                    job.update(plan_count=plan_count(split), peel=point_peel(split, v))
                result.append(job)
    return result


def run(job: dict, out: Path, checker: Path) -> dict:
    """One solve in its own process and its row."""
    stem = f"{job['scene']}-{job['point_share']:g}-{job['variant'].replace(' ', '_')}"
    toml = out / f"{stem}.toml"
    toml.write_text(toml_text(job["cases"]))
    net = out / f"{stem}.json"
    net.unlink(missing_ok=True)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "selfsupport", "solve", str(job["path"]),
                        "--load-cases", str(toml), "--time-limit", str(TIME_LIMIT), "--out", str(net), "-q",
                        *job["extra"]], capture_output=True, text=True)
    row = {"scene": job["scene"], "cases": "+".join(job["cases"]), "point_share": job["point_share"],
           "variant": job["variant"], "exit": p.returncode, "wall_s": round(time.perf_counter() - t0, 1),
           "plan_count": job["plan_count"]}
    if not net.is_file():
        row["status"] = f"no network (exit {p.returncode}: {p.stderr.strip()[-200:]})"
        return row
    d = json.loads(net.read_text())
    errs = checked(net, checker, job["flags"])
    worst = max(errs, key=lambda k: -np.inf if np.isnan(errs[k]) else errs[k])
    params = d.get("parameters", {})
    fin = params.get("ipopt_from_staggered") or {}
    carry = params.get("any_weights_carry") or {}
    plan = (params.get("load_continuation") or {}).get("top_view") or {}
    block = (params.get("load_continuation") or {}).get("blocking") or {}
    fp = params.get("fixed_plan") or {}
    lp = block.get("tension") or {}
    row.update(status=d.get("status"), errors=" ".join(f"{k}={e:.2e}" for k, e in errs.items()), worst_case=worst,
               worst_error=errs[worst], ipopt_status=fin.get("ipopt_status"), freedom=fin.get("freedom"),
               ipopt_error=fin.get("max_relative_error"), ipopt_seconds=fin.get("seconds"),
               plan_self_stresses=plan.get("self_stresses"), result_self_stresses=fp.get("self_stresses"),
               fixed_plan_needed=fp.get("needed"), fixed_plan_residual=fp.get("residual"),
               carry_residual=max((c["max_relative_residual"] for c in carry.values()), default=None),
               blocked_case=block.get("case"), compression_lp=lp.get("status"), tension_share=lp.get("tension_share"),
               peel_blocks="yes" if job["peel"].blocked else "no",
               star_degeneracy=star_degeneracy(job["peel"], read_network(net).vertices).smallest if job["peel"].steps else None,
               message=d.get("message"))
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/load_cases"), help="networks, TOML files, runs.json")
    ap.add_argument("--csv", type=Path, default=None, help="the CSV (default: OUT/load_cases.csv)")
    ap.add_argument("--only", nargs="+", default=list(SCENES),
                    help=f"these scenes (file stems of .sss files in --scenes; default: {' '.join(SCENES)})")
    ap.add_argument("--shares", nargs="+", type=float, default=list(SHARES), help="point load shares of the self-weight")
    ap.add_argument("--variants", nargs="+", default=["default", *VARIANTS], choices=["default", *VARIANTS],
                    help="these variants only (default: all)")
    ap.add_argument("--checker", type=Path, default=DEFAULT_CHECKER)
    a = ap.parse_args(argv)
    missing = [str(a.scenes / f"{n}.sss") for n in a.only if not (a.scenes / f"{n}.sss").is_file()]
    if missing:
        ap.error(f"no scene {', '.join(missing)}: give --scenes the folder of the scenes")
    a.out.mkdir(parents=True, exist_ok=True)
    a.csv = a.out / "load_cases.csv" if a.csv is None else a.csv
    stamp, rows = run_stamp(), []
    for job in jobs(a.scenes, tuple(a.only), tuple(sorted(a.shares)), tuple(a.variants)):
        rows.append({**run(job, a.out, a.checker), **stamp})
        print(json.dumps(rows[-1], default=str), flush=True)
        (a.out / "runs.json").write_text(json.dumps(rows, indent=1, default=str))
        a.csv.parent.mkdir(parents=True, exist_ok=True)
        write_csv(a.csv, rows, COLUMNS)  # (after every run: a partial study is kept)
    print(markdown_table(rows, SHORT))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
