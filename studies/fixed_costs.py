"""Where a time-limited solve spends its time outside the solver loops.

    python -m studies.fixed_costs [--scene shape:dome:200000] [--time-limit 10] [--runs 3]
                                  [--json-runs 3] [--out DIR]

Three measurements, each repeated ``--runs`` times in a fresh interpreter (other jobs on the
machine distort single runs: medians are reported, with the load average):

* ``wall``: ``python -m selfsupport solve SCENE --time-limit T --out FILE`` as a user runs it,
  from the process start to its exit (status and whether the file was written);
* ``phases``: the same command in one interpreter with a timer around each phase (scene,
  validation, problem, the method's set-up, loop and polish, the hull record, the objective
  terms, the evidence of :meth:`SolveResult.build`, the JSON document, its text, the write),
  plus the import time before ``main`` and the time left before the deadline when the solver
  returned (negative: it overran);
* ``json``: :func:`selfsupport.io.network_json.dumps_network` alone on the written file's
  network (the number formatting, kept out of the test suite because it is a timing).

The bound it checks is 10% + 1 s over the limit: 12 s for ``--time-limit 10``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_PHASE_DRIVER = r'''
import json, sys, time
t_start = time.perf_counter()
import numpy as np
from selfsupport.cli import common as cli
from selfsupport.methods import solve as one_solve
from selfsupport.core import result
from selfsupport.io import network_json as nj
from selfsupport.methods.staggered import conclude as staggered_conclude
from selfsupport.methods.staggered import run as staggered
t_imported = time.perf_counter()
times = {}
extra = {}

def timed(name, f):
    def wrapper(*a, **k):
        t = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            times[name] = times.get(name, 0.0) + time.perf_counter() - t
    return wrapper

cli.load_scene = timed("scene", cli.load_scene)
one_solve.validate_scene = timed("validate", one_solve.validate_scene)
one_solve.Problem.build = classmethod(timed("problem", one_solve.Problem.build.__func__))
staggered._Run.__init__ = timed("method set-up", staggered._Run.__init__)
staggered_conclude.hull_report = timed("hull record", staggered_conclude.hull_report)
staggered_conclude.term_values = timed("objective terms", staggered_conclude.term_values)
result.SolveResult.build = classmethod(timed("evidence (SolveResult.build)", result.SolveResult.build.__func__))
nj.network_to_dict = timed("JSON document", nj.network_to_dict)
nj.dumps_network = timed("JSON text", nj.dumps_network)
nj.atomic_write_text = timed("file write", nj.atomic_write_text)
_solve = staggered._Run.solve

def run_solve(self):
    t = time.perf_counter()
    try:
        return _solve(self)
    finally:
        times["method solve (all)"] = time.perf_counter() - t

staggered._Run.solve = run_solve
_polish = staggered._Run.polish

marks = {}

def polish(self, *a, **k):
    t = time.perf_counter()
    extra["deadline left at the polish [s]"] = round(self.deadline - t, 3)
    marks.setdefault("polish", t)
    marks["deadline"] = self.deadline
    try:
        return _polish(self, *a, **k)
    finally:
        times["final polish"] = times.get("final polish", 0.0) + time.perf_counter() - t

staggered._Run.polish = polish
sys.argv = ["selfsupport"] + sys.argv[1:]
t_main = time.perf_counter()
try:
    cli.main()
except SystemExit as e:
    extra["exit"] = e.code
t_end = time.perf_counter()
times["imports"] = t_imported - t_start
times["total (after interpreter start)"] = t_end - t_start
inner = ("hull record", "objective terms", "evidence (SolveResult.build)", "final polish")
if "polish" in marks:
    from selfsupport.methods.deadline import finish_reserve
    n = int(sys.argv[2].rsplit(":", 1)[1]) if sys.argv[2].startswith("shape:") else None
    times["finish (polish start -> exit)"] = t_end - marks["polish"]
    extra["exit - deadline [s] (the reserve it needed)"] = round(t_end - marks["deadline"], 3)
    if n:
        extra["finish per vertex [us]"] = round(1e6 * (t_end - marks["polish"]) / n, 2)
        extra["reserve kept [s]"] = round(finish_reserve(n), 3)
times["method loop (solve - polish - finish)"] = times.get("method solve (all)", 0.0) - sum(times.get(k, 0.0) for k in inner)
print("PHASES " + json.dumps({"times": times, "extra": extra}))
'''


def _load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "?"


def wall(cmd: list[str], out: Path) -> tuple[float, int, bool, str]:
    """Wall time of one CLI run, its exit code, whether ``out`` was written and its status."""
    if out.exists():
        out.unlink()
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    dt = time.perf_counter() - t
    status = ""
    if out.exists():
        with out.open(encoding="utf-8") as f:
            for line in f:
                if line.startswith('"status"'):
                    status = json.loads(line.split(":", 1)[1].rstrip(",\n"))
                    break
    return dt, p.returncode, out.exists(), status


def phases(args: list[str]) -> dict:
    """Per-phase seconds of one run of ``selfsupport ARGS`` in a fresh interpreter."""
    p = subprocess.run([sys.executable, "-c", _PHASE_DRIVER, *args], capture_output=True, text=True)
    line = next((ln for ln in p.stdout.splitlines() if ln.startswith("PHASES ")), None)
    if line is None:
        raise RuntimeError(f"phase run failed:\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    return json.loads(line[len("PHASES "):])


def json_speed(path: Path, runs: int) -> dict:
    """Seconds of :func:`dumps_network` on the document of a written network file."""
    from selfsupport.io import network_json as nj
    from selfsupport.io import read_network

    net = read_network(path)
    out = {}
    cases = [("plain document + text (network_to_dict, dumps_network)", lambda: nj.dumps_network(nj.network_to_dict(net)))]
    if hasattr(nj, "_document"):  # what write_network formats: the arrays as they are
        cases.append(("as write_network does", lambda: nj.dumps_network(nj._document(net, {}, arrays=True))))
    for name, f in cases:
        ts = []
        for _ in range(runs):
            t = time.perf_counter()
            text = f()
            ts.append(time.perf_counter() - t)
        out[name] = statistics.median(ts)
    out["MB"] = len(text) / 1e6
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="shape:dome:200000")
    ap.add_argument("--time-limit", type=float, default=10.0)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--json-runs", type=int, default=0, help="repetitions of the JSON timing (0: skip)")
    ap.add_argument("--no-phases", action="store_true")
    ap.add_argument("--out", type=Path, default=None, help="directory for the network files (default: a temp dir)")
    a = ap.parse_args(argv)
    tmp = a.out or Path(tempfile.mkdtemp(prefix="fixed_costs-"))
    tmp.mkdir(parents=True, exist_ok=True)
    out = tmp / "net.json"
    args = ["solve", a.scene, "--time-limit", f"{a.time_limit:g}", "--out", str(out), "--quiet"]
    print(f"{a.scene}, --time-limit {a.time_limit:g}; load average {_load()}")
    walls = []
    for k in range(a.runs):
        w = wall([sys.executable, "-m", "selfsupport", *args], out)
        walls.append(w)
        print(f"  wall run {k + 1}: {w[0]:.2f} s, exit {w[1]}, written {w[2]}, status {w[3]!r}; load {_load()}")
    print(f"wall median {statistics.median(w[0] for w in walls):.2f} s (bound {1.1 * a.time_limit + 1:.1f} s)")
    if not a.no_phases:
        runs = [phases(args) for _ in range(a.runs)]
        names = list(dict.fromkeys(k for r in runs for k in r["times"]))
        print("phase medians [s] over", a.runs, "runs:")
        for n in names:
            vals = [r["times"].get(n, 0.0) for r in runs]
            print(f"  {n:40s} {statistics.median(vals):7.2f}   ({', '.join(f'{v:.2f}' for v in vals)})")
        for n in dict.fromkeys(k for r in runs for k in r["extra"]):
            print(f"  {n:40s} {[r['extra'].get(n) for r in runs]}")
    if a.json_runs and out.exists():
        print("JSON alone [s]:", {k: round(v, 3) for k, v in json_speed(out, a.json_runs).items()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
