"""``selfsupport sweep SWEEP.toml --out DIR [--scheduler ADDRESS] [--workers N] [--yes]``.

Runs a parameter sweep (:mod:`selfsupport.sweep`) on dask.distributed — a LocalCluster with
one worker process per core by default, or the cluster behind ``--scheduler`` — and writes
into ``DIR``: ``results.sqlite`` (the store, one row per finished run, resumable),
``results.csv`` and ``results.parquet`` (this sweep's rows), ``report.md`` and ``plots/*.png``.
Running the same command again executes only the runs missing from the store; ``--retry
failed timeout`` also re-runs those.

A sweep of more than :data:`CONFIRM_RUNS` runs starts only with ``--yes`` (a grid grows as the
product of its lists). Exit codes: 0 when every run of the sweep is in the store (whatever the runs' statuses:
a failed run is a result), 2 bad sweep file or arguments, 130 interrupted (finished runs are
kept). Registered through :data:`COMMANDS` (discovered by :mod:`selfsupport.cli`).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from selfsupport.cli.common import EXIT_CODES, Command, _positive_int, print_table
from selfsupport.cli.common import main as cli_main
from selfsupport.core.errors import InputError
from selfsupport.io.safety import check_output_dir
from selfsupport.sweep.report import write_report
from selfsupport.sweep.runner import run_sweep
from selfsupport.sweep.spec import load_spec
from selfsupport.sweep.store import ResultStore

__all__ = ["COMMANDS", "CONFIRM_RUNS", "add_arguments", "run", "main"]

#: Above this many runs a sweep starts only with ``--yes``.
CONFIRM_RUNS = 1000


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport sweep``."""
    p.add_argument("sweep", metavar="SWEEP.toml", help="sweep definition (see selfsupport.sweep.spec)")
    p.add_argument("--out", "-o", required=True, metavar="DIR",
                   help="output folder: results.sqlite (resumable store), results.csv/.parquet, report.md, plots/")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on an existing dask cluster (e.g. tcp://host:8786) instead of a local one")
    p.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--scenes", metavar="DIR", default=None,
                   help="folder of the sweep's scene files (default: $SELFSUPPORT_SCENES, else the "
                        "file's scene_dir, else the sweep file's folder)")
    p.add_argument("--retry", nargs="+", default=(), metavar="STATUS",
                   help="also re-run stored runs with these statuses (e.g. failed timeout crashed stalled)")
    p.add_argument("--no-report", action="store_true", help="skip the exports, report.md and plots")
    p.add_argument("--yes", action="store_true",
                   help=f"start a sweep of more than {CONFIRM_RUNS:,} runs (without it, such a sweep is refused)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display")


def run(args: argparse.Namespace) -> int:
    """Run the sweep, then export and report; returns the exit code."""
    if args.scheduler and args.workers:
        raise InputError("--workers sizes the local cluster; with --scheduler the cluster has its own workers")
    out = Path(args.out)
    check_output_dir(out, files=["results.sqlite", "results.csv", "results.parquet", "report.md"],
                     inputs=[("SWEEP.toml", args.sweep)])
    spec = load_spec(args.sweep, scene_dir=args.scenes)
    n_runs = len(spec.expand())
    if n_runs > CONFIRM_RUNS and not args.yes:
        raise InputError(f"{args.sweep} expands to {n_runs:,} runs (more than {CONFIRM_RUNS:,}); rerun with --yes to "
                         "start them all, or make its lists shorter")
    outcome = run_sweep(spec, out, scheduler=args.scheduler, workers=args.workers, retry=args.retry,
                        progress=not args.quiet)
    rows = [("sweep", f"{spec.name} ({spec.source})"), ("runs", str(outcome.n_runs)),
            ("already stored", str(outcome.n_skipped)), ("executed now", str(outcome.n_executed)),
            ("statuses now", ", ".join(f"{v} {k}" for k, v in sorted(outcome.by_status.items())) or "-"),
            ("cluster", outcome.cluster or "-"), ("wall time", f"{outcome.wall_time:.1f} s"),
            ("store", str(outcome.store_path))]
    if outcome.n_lost:
        rows.append(("lost", f"{outcome.n_lost} runs were cancelled by the cluster and are not stored; "
                             "run the same command again to do them"))
    if outcome.n_duplicates:
        rows.append(("duplicates", f"{outcome.n_duplicates} runs had the same key as another (same scene "
                                   "content and parameters) and ran once"))
    if not args.no_report:
        rows += _export_and_report(spec, outcome, out)
    print_table(f"selfsupport sweep -> {out}", rows)
    if outcome.interrupted:
        print("selfsupport: interrupted; the finished runs are stored, rerun the same command to finish",
              file=sys.stderr)
        return EXIT_CODES["interrupted"]
    failed = outcome.n_failed
    if failed:
        print(f"selfsupport: {failed} run(s) failed, timed out or crashed; their messages are in the store "
              "and report.md (rerun with --retry failed timeout crashed to try them again)", file=sys.stderr)
    return EXIT_CODES["ok"]


def _export_and_report(spec, outcome, out: Path) -> list[tuple[str, str]]:
    with ResultStore(outcome.store_path) as store:
        csv = store.export_csv(out / "results.csv", outcome.keys)
        pq = store.export_parquet(out / "results.parquet", outcome.keys)
        df = store.frame(outcome.keys)
    rep = write_report(df, spec.report, out, title=f"Sweep {spec.name}",
                       notes=[f"Sweep file `{spec.source}` (sha256 {spec.digest[:12]}), scenes from "
                              f"`{spec.scene_dir}`, time budget {spec.time_budget:g} s per run.",
                              f"{len(df)} of {outcome.n_runs} runs stored."])
    return [("exports", f"{csv}, {pq}"), ("report", str(rep.markdown)), ("plots", f"{len(rep.plots)} in {out / 'plots'}")]


#: Discovered by :func:`selfsupport.cli.discover_commands`.
COMMANDS: dict[str, Command] = {
    "sweep": Command("run a parameter sweep on dask (local or --scheduler), resumable; write results and a report",
                     add_arguments, run),
}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m selfsupport.cli.sweep ...`` = ``selfsupport sweep ...``."""
    return cli_main(["sweep", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
