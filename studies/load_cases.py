"""Several load cases on the paper's scenes: the iteration over every case at once (before) and the
continuation from the cases' envelope first (after, the default).

::

    python -m studies.load_cases --scenes ../shared/paper-scenes/scenes --out out/load_cases

Cases (written as TOML files beside the results): on vault-pillar, lilium and cas the three of
the load-cases issue (empty; snow 80 kg/m²; a point load of 5% of the self-weight at the highest
free vertex); on vault-pillar also empty + 500 N at that vertex and the format reference's
example (snow, 5 kN at vertex 40 and 300 kg at vertex 12); on a generated 300-vertex dome the
guide's example. Each solve is ``selfsupport solve --time-limit 120`` in its own process, with
``--option continuation=false`` for "before"; with ``--repeat N`` each job runs N times, "before"
and "after" alternately (the machine's load drifts). Per run: status, wall time, every case's max
relative error by the shared independent checker, and, when the continuation did not reach every
case, its reach, the seconds it took, whether it was blocked before any stage, and the vertices
it names. Writes ``load_cases.md`` and ``load_cases.json``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CHECKER = Path(__file__).resolve().parents[2] / "shared" / "tools" / "check_network.py"
TIME_LIMIT = 120.0


def _highest_free_and_five_percent(path: Path) -> tuple[int, float]:
    """The highest free vertex of a scene and 5% of its self-weight [N] (the project's defaults)."""
    from selfsupport import api
    from selfsupport.core.loads import SelfWeight

    scene = api.as_scene(str(path))
    V, free = scene.mesh.vertices, np.flatnonzero(scene.free)
    return int(free[np.argmax(V[free, 2])]), 0.05 * -float(SelfWeight().nodal(scene.mesh, V).sum())


def _toml(cases: dict[str, dict]) -> str:
    out = []
    for name, c in cases.items():
        out.append(f"[cases.{name}]")
        for k, v in c.items():
            out.append(f"{k} = " + ("{ " + ", ".join(f'"{i}" = {x!r}' for i, x in v.items()) + " }"
                                    if isinstance(v, dict) else repr(v)))
        out.append("")
    return "\n".join(out)


def _checked(path: Path) -> dict[str, float]:
    """Every case's max relative error by the independent checker (a copy with that case's
    weights and loads at the top level)."""
    d = json.loads(path.read_text())
    out = {}
    for case in d.get("load_cases") or [{"name": "self-weight", "weights": d["weights"], "loads": d["loads"]}]:
        one = path.with_suffix(f".{case['name']}.json")
        one.write_text(json.dumps({**d, "weights": case["weights"], "loads": case["loads"]}))
        p = subprocess.run([sys.executable, str(CHECKER), str(one), "--tol", "1e-8"], capture_output=True, text=True)
        vals = dict(t.split("=", 1) for t in p.stdout.split() if "=" in t)
        out[case["name"]] = float(vals.get("max_rel_error", "nan"))
        one.unlink()
    return out


def runs(scenes: Path, out: Path, repeat: int = 1) -> list[dict]:
    """The study's solves (see the module docstring)."""
    jobs = []
    for name in ("vault-pillar", "lilium", "cas"):
        v, p = _highest_free_and_five_percent(scenes / f"{name}.sss")
        jobs.append((name, str(scenes / f"{name}.sss"), "three", {"empty": {}, "snow": {"uniform_mass": 80.0},
                                                                   "point": {"point_loads": {v: round(p, 2)}}}))
        if name == "vault-pillar":
            jobs.append((name, str(scenes / f"{name}.sss"), "500N", {"empty": {}, "point": {"point_loads": {v: 500.0}}}))
            jobs.append((name, str(scenes / f"{name}.sss"), "formats-example", {
                "empty": {}, "snow": {"uniform_mass": 80.0},
                "hoist": {"point_loads": {40: 5000.0}, "extra_mass": {12: 300.0}}}))
    jobs.append(("dome:300", "shape:dome:300", "guide-example", {"empty": {}, "snow": {"uniform_mass": 80.0},
                                                               "hoist": {"point_loads": {0: 3000.0}}}))
    rows = []
    for scene, arg, label, cases in jobs:
        toml = out / f"{scene.replace(':', '-')}-{label}.toml"
        toml.write_text(_toml(cases))
        for run, (variant, extra) in ((r, v) for r in range(repeat)
                                      for v in (("before", ["--option", "continuation=false"]), ("after", []))):
            net = out / f"{scene.replace(':', '-')}-{label}-{variant}-{run}.json"
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "selfsupport", "solve", arg, "--load-cases", str(toml),
                                "--time-limit", str(TIME_LIMIT), "--out", str(net), "-q", *extra],
                               capture_output=True, text=True)
            wall = time.perf_counter() - t0
            row = {"scene": scene, "cases": label, "variant": variant, "run": run, "exit": p.returncode,
                   "wall_s": round(wall, 1)}
            if net.is_file():
                d = json.loads(net.read_text())
                rec = d.get("parameters", {}).get("load_continuation") or {}
                row.update(status=d.get("status"), checked=_checked(net), reached=rec.get("reached"),
                           continuation_s=rec.get("time"), blocked_at_start=rec.get("blocked_at_start", False),
                           blocking_case=(rec.get("blocking") or {}).get("case"),
                           blocking_vertices=(rec.get("blocking") or {}).get("vertices"))
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def table(rows: list[dict]) -> str:
    """The rows as Markdown."""
    lines = ["| scene | cases | variant | run | status | wall [s] | max relative error per case (checker) | "
             "continuation reached (its seconds) | blocking case: vertices |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        errs = ", ".join(f"{k} {v:.1e}" for k, v in (r.get("checked") or {}).items())
        block = f"{r['blocking_case']}: {r['blocking_vertices']}" if r.get("blocking_case") else ""
        reached = "" if r.get("reached") is None else (
            f"{r['reached']:.0%}" + (" (blocked before any stage" if r.get("blocked_at_start") else " (")
            + ("" if r.get("continuation_s") is None else f"{', ' if r.get('blocked_at_start') else ''}"
               f"{r['continuation_s']:.1f} s") + ")")
        lines.append(f"| {r['scene']} | {r['cases']} | {r['variant']} | {r.get('run', 0) + 1} | {r.get('status')} | "
                     f"{r['wall_s']} | {errs} | {reached} | {block} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/load_cases"))
    ap.add_argument("--repeat", type=int, default=1, help="runs of each job, before and after alternately")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rows = runs(a.scenes, a.out, a.repeat)
    (a.out / "load_cases.json").write_text(json.dumps(rows, indent=1))
    (a.out / "load_cases.md").write_text(table(rows))
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
