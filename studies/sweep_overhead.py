"""Benchmark of the sweep machinery (selfsupport.sweep): overhead per run and scaling.

    python -m studies.sweep_overhead [--runs 16] [--shape dome] [--vertices 1000] [--out DIR]

Measures, for the same solve repeated ``--runs`` times (distinct store keys through
``repetitions``):

* ``direct``: the solves called in a plain loop in this process (after one warm-up solve);
* ``sweep, k workers`` (k = 1, 2): :func:`selfsupport.sweep.runner.run_sweep` on a fresh
  LocalCluster with k worker processes whose imports are warmed up first; the wall time runs
  from the call to its return (planning, submission, store inserts, progress included;
  cluster start-up reported separately).

Targets: overhead per run = (sweep wall time with 1 worker − Σ solve times) / runs
≤ 0.5 s, and throughput with 2 workers ≥ 1.6 × that with 1. Writes ``sweep_overhead.md`` and
``sweep_overhead.json`` into ``--out`` and prints the table. The load average is printed too:
other processes on the machine distort both numbers.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path


def _spec_text(shape: str, vertices: int, runs: int) -> str:
    return (f'[sweep]\nname = "overhead"\nscenes = ["shape:{shape}?n_vertices={vertices}"]\n'
            f'methods = ["staggered"]\nrepetitions = {runs}\ntime_budget = 600.0\n')


def _direct(shape: str, vertices: int, runs: int) -> list[float]:
    from selfsupport.core.loads import SelfWeight
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods.staggered import StaggeredLinearization

    scene = make_shape(shape, n_vertices=vertices)
    StaggeredLinearization().solve(scene, SelfWeight())  # warm-up: imports, caches
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        StaggeredLinearization().solve(scene, SelfWeight(), time_limit=600.0)
        times.append(time.perf_counter() - t)
    return times


def _busy(n: int) -> float:
    x = 0
    for i in range(n):
        x += i * i
    return float(x)


def _calibration(workers: int, tasks: int = 8, n: int = 6_000_000) -> float:
    """Throughput [tasks/s] of a pure-Python CPU loop on ``workers`` plain processes: what
    the machine gives right now, with no dask and no solver (the ceiling for any scaling)."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as ex:
        list(ex.map(_busy, [1000] * workers))  # start the processes
        t = time.perf_counter()
        list(ex.map(_busy, [n] * tasks))
        return tasks / (time.perf_counter() - t)


def _warm() -> bool:
    import selfsupport.api  # noqa: F401
    import selfsupport.methods.staggered  # noqa: F401
    import selfsupport.sweep.runner  # noqa: F401
    return True


def _sweep(shape: str, vertices: int, runs: int, workers: int) -> dict:
    import dask
    from distributed import Client, LocalCluster

    from selfsupport.sweep import parse_spec
    from selfsupport.sweep.runner import LOCAL_CLUSTER_CONFIG, STORE_NAME, run_sweep
    from selfsupport.sweep.store import ResultStore

    spec = parse_spec(_spec_text(shape, vertices, runs))
    t0 = time.perf_counter()
    with dask.config.set(LOCAL_CLUSTER_CONFIG):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    try:
        client.run(_warm)
        startup = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as out:
            t = time.perf_counter()
            outcome = run_sweep(spec, out, client=client, progress=False)
            wall = time.perf_counter() - t
            with ResultStore(Path(out) / STORE_NAME) as store:
                df = store.frame()
    finally:
        client.close()
        cluster.close()
    assert outcome.n_executed == runs, outcome
    solve = df["solve_time"].to_numpy()
    task = df["task_time"].to_numpy()
    return {"workers": workers, "runs": runs, "startup_s": startup, "wall_s": wall,
            "sum_solve_s": float(solve.sum()), "median_solve_s": float(statistics.median(solve)),
            "worker_overhead_s": float((task - solve).mean()),
            # worker-seconds per run not spent in solve() (for 1 worker: (wall − Σ solve) / runs)
            "overhead_per_run_s": (wall * workers - float(solve.sum())) / runs,
            "throughput_runs_per_s": runs / wall, "statuses": df["status"].value_counts().to_dict()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=16)
    p.add_argument("--shape", default="dome")
    p.add_argument("--vertices", type=int, default=1000)
    p.add_argument("--out", default="sweep_overhead_out")
    args = p.parse_args(argv)

    load0 = os.getloadavg()
    direct = _direct(args.shape, args.vertices, args.runs)
    cal1 = _calibration(1)
    one = _sweep(args.shape, args.vertices, args.runs, 1)
    cal2 = _calibration(2)
    two = _sweep(args.shape, args.vertices, args.runs, 2)
    load1 = os.getloadavg()
    speedup = two["throughput_runs_per_s"] / one["throughput_runs_per_s"]
    cal_speedup = cal2 / cal1
    rows = [
        ("direct loop (this process)", f"{statistics.median(direct):.3f}", f"{sum(direct):.2f}", "-", "-",
         f"{args.runs / sum(direct):.3f}", "-", "-"),
        *[(f"sweep, {r['workers']} worker(s)", f"{r['median_solve_s']:.3f}", f"{r['sum_solve_s']:.2f}",
           f"{r['wall_s']:.2f}", f"{r['startup_s']:.1f}", f"{r['throughput_runs_per_s']:.3f}",
           f"{r['worker_overhead_s'] * 1e3:.1f}", f"{r['overhead_per_run_s']:.3f}") for r in (one, two)],
    ]
    head = ("", "median solve [s]", "Σ solve [s]", "wall [s]", "cluster start [s]", "runs/s", "task − solve [ms]",
            "(k·wall − Σ solve)/runs [s]")
    overhead = one["overhead_per_run_s"]
    lines = [f"# Sweep machinery overhead ({args.runs} × staggered on {args.shape} ~{args.vertices} vertices)", "",
             "| " + " | ".join(head) + " |", "|:---|" + "---:|" * (len(head) - 1)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    lines += ["", f"* overhead per run with 1 worker: (wall − Σ solve) / runs = **{overhead:.3f} s** (target ≤ 0.5 s)",
              f"* throughput 2 workers / 1 worker: **{speedup:.2f}×** (target ≥ 1.6×)",
              f"* the same ratio for a pure-Python CPU loop on 2 vs 1 plain processes, measured just before "
              f"each sweep: {cal_speedup:.2f}× (what the machine allowed; sweep / machine = {speedup / cal_speedup:.2f})",
              f"* load average before / after: {load0[0]:.2f} / {load1[0]:.2f} on {os.cpu_count()} cores "
              "(other processes compete with the workers)"]
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep_overhead.md").write_text(text)
    (out / "sweep_overhead.json").write_text(json.dumps(
        {"direct_s": direct, "one_worker": one, "two_workers": two, "overhead_per_run_s": overhead,
         "speedup": speedup, "calibration_speedup": cal_speedup, "loadavg": [load0, load1]}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
