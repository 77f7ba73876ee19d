"""Run the studies behind the numbers the documentation quotes (``make bench``).

    python -m benchmarks.run --scenes ../shared/paper-scenes/scenes --original ../build/original
        --checker ../shared/tools/check_network.py [--scaling-sizes 1000,4000] [--peers-repeat 3]
        [--only table1,pq]

``make bench`` passes the Makefile's ``SCENES``, ``ORIGINAL`` and ``CHECKER``, and
``BENCH_SIZES`` / ``BENCH_ONLY`` when they are set.

Each study (:data:`STUDIES`) runs in its own process with its output in ``benchmarks/out/NAME``
(networks, Markdown, figures: not committed); the CSVs it writes are copied into
``benchmarks/results`` (committed), and :mod:`benchmarks.report` then writes the documentation's
page ``docs/benchmarks.md`` from every CSV there. Every row of every CSV carries the run's stamp
(commit, date, CPU model, cores, load average at the start: :func:`studies.common.run_stamp`).

A study that cannot run here (no scenes folder, no driver of the original tool) is skipped with
one line saying why, and its committed CSV stays as it is; a study that fails says so in one line,
keeps its committed CSV too, and the others still run. Exit status 1 when a study failed.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
WORK = ROOT / "benchmarks" / "out"

#: The Table 1 variants whose numbers the docs quote: the default method, its refinement, IPOPT.
TABLE1_METHODS = ("staggered/active-set", "staggered-refine/active-set", "simultaneous/ipopt")
#: The bracing continuation's second path: finer bounds than its default ones, down to 0.001.
BRACING_FINER = "0.5,0.2,0.1,0.05,0.02,0.01,0.005,0.002,0.001"


@dataclass(frozen=True)
class Settings:
    """What ``make bench`` passes on (the Makefile's variables)."""

    scenes: Path
    original: Path
    checker: Path
    scaling_sizes: str
    peers_repeat: int


@dataclass(frozen=True)
class Study:
    """One study of the benchmark.

    Attributes
    ----------
    name
        Its name in ``--only`` and its output folder under ``benchmarks/out``.
    module
        The module run with ``python -m``.
    csvs
        ``(file the study writes, name in benchmarks/results)`` pairs.
    argv
        Its arguments, given the settings and its output folder.
    skip
        Why it cannot run with these settings (``""``: it can).
    """

    name: str
    module: str
    csvs: tuple[tuple[str, str], ...]
    argv: Callable[[Settings, Path], list[str]]
    skip: Callable[[Settings], str]


def _no_scenes(s: Settings) -> str:
    return "" if s.scenes.is_dir() else f"no scenes folder {s.scenes} (pass SCENES=PATH to make bench)"


def _no_driver(s: Settings) -> str:
    from studies.peers import find_original_driver

    reason = find_original_driver(s.original)[1]
    return _no_scenes(s) or (f"{reason} (make bench: ORIGINAL=OUT)" if reason else "")


def _no_published(*files: str) -> Callable[[Settings], str]:
    """Skip when the paper's published files (beside the scenes folder) are missing."""
    def skip(s: Settings) -> str:
        missing = [f for f in files if not (s.scenes.parent / "published" / f).is_file()]
        return _no_scenes(s) or (f"no {', '.join(missing)} in {s.scenes.parent / 'published'}" if missing else "")
    return skip


def _checker(s: Settings) -> list[str]:
    return ["--checker", str(s.checker)] if s.checker.is_file() else []


STUDIES: tuple[Study, ...] = (
    Study("table1", "studies.table1", (("table1.csv", "table1.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out), "--methods", *TABLE1_METHODS, *_checker(s)],
          _no_scenes),
    Study("warm_resolve", "studies.warm_resolve", (("warm_resolve.csv", "warm_resolve.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out)], _no_scenes),
    Study("design_latency", "studies.design_latency", (("design_latency.csv", "design_latency.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out)], _no_scenes),
    Study("peers", "studies.peers", (("original.csv", "peers_original.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out), "--tools", "original",
                          "--original-driver", str(s.original), "--repeat", str(s.peers_repeat), *_checker(s)],
          _no_driver),
    Study("scaling", "studies.scaling", (("scaling.csv", "scaling.csv"), ("scaling_exponents.csv", "scaling_exponents.csv")),
          lambda s, out: ["--out", str(out), "--sizes", s.scaling_sizes], lambda s: ""),
    Study("planarity", "studies.planarity", (("planarity.csv", "planarity.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out)], _no_scenes),
    # pq takes the paper-scenes folder itself (scenes/ and published/ in it)
    Study("pq", "studies.pq", (("pq.csv", "pq.csv"),),
          lambda s, out: ["--scenes", str(s.scenes.parent), "--out", str(out), "--densities", "mean,published",
                          *_checker(s)], _no_scenes),
    # the paper's Figs. 9-10, 8 and 15: docs/guide/paper.md's comparisons
    Study("stability_dome", "studies.stability_dome",
          (("stability_dome.csv", "stability_dome.csv"), ("stability_dome_max_load.csv", "stability_dome_max_load.csv"),
           ("stability_dome_starts.csv", "stability_dome_starts.csv")),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out), "--no-figures"], _no_scenes),
    Study("destruction", "studies.destruction", (("destruction.csv", "destruction.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out)],
          _no_published("remove-original.obj", *(f"remove-{k}-n.obj" for k in range(1, 5)))),
    Study("koebe", "studies.koebe", (("koebe.csv", "koebe.csv"), ("koebe_published.csv", "koebe_published.csv")),
          lambda s, out: ["--scenes", str(s.scenes.parent), "--out", str(out), *_checker(s)],
          _no_published("enneper-koebe.obj", "enneper-summed.obj")),
    # several load cases on the paper's scenes (the load-cases guide's measurements)
    Study("load_cases", "studies.load_cases", (("load_cases.csv", "load_cases.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out), *_checker(s)], _no_scenes),
    # how little bracing the quad designs that stall under those cases need
    Study("bracing", "studies.bracing", (("bracing.csv", "bracing.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out), *_checker(s)], _no_scenes),
    Study("bracing_finer", "studies.bracing", (("bracing.csv", "bracing_finer.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out), "--fractions", BRACING_FINER, *_checker(s)],
          _no_scenes),
    # which scenes' meshes rule out a point-load case beside the empty one (no solve)
    Study("peel", "studies.peel", (("peel.csv", "peel.csv"),),
          lambda s, out: ["--scenes", str(s.scenes), "--out", str(out)], _no_scenes),
    # the theory pages' "why not" measurements on generated shapes
    Study("theory_whys", "studies.theory_whys", (("theory_whys.csv", "theory_whys.csv"),),
          lambda s, out: ["--out", str(out)], lambda s: ""),
)
_BY_NAME = {st.name: st for st in STUDIES}


def run_study(study: Study, settings: Settings, *, work: Path = WORK, results: Path = RESULTS,
              log: Callable[[str], None] = print) -> str:
    """Run one study and copy its CSVs into ``results``.

    Returns
    -------
    str
        ``"skipped"``, ``"failed"`` or ``"done"``; a skipped or failed study leaves ``results``
        as it was and says why in one line of ``log``.
    """
    reason = study.skip(settings)
    if reason:
        log(f"bench: {study.name} skipped: {reason}")
        return "skipped"
    out = work / study.name
    for produced, _ in study.csvs:  # a CSV left by an earlier run must not pass for this one's
        (out / produced).unlink(missing_ok=True)
    cmd = [sys.executable, "-m", study.module, *study.argv(settings, out)]
    log(f"bench: [{time.strftime('%H:%M:%S')}] {study.name}: {' '.join(cmd[1:])}")
    t0 = time.perf_counter()
    code = subprocess.run(cmd, cwd=ROOT).returncode
    missing = [p for p, _ in study.csvs if not (out / p).is_file()]
    if code != 0 or missing:
        why = f"exit status {code}" if code else f"it wrote no {', '.join(missing)}"
        log(f"bench: {study.name} failed ({why}; its output is above); "
            f"{', '.join(r for _, r in study.csvs)} in {results} left as they were")
        return "failed"
    results.mkdir(parents=True, exist_ok=True)
    for produced, name in study.csvs:
        shutil.copyfile(out / produced, results / name)
    log(f"bench: {study.name} done in {time.perf_counter() - t0:.0f} s: "
        f"{', '.join(str(results / r) for _, r in study.csvs)}")
    return "done"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=Path, required=True, help="the paper's scenes folder")
    p.add_argument("--original", type=Path, required=True,
                   help="the original tool's build folder (../shared/original-tool/build.sh OUT) or its driver")
    p.add_argument("--checker", type=Path, required=True, help="the independent check_network.py")
    p.add_argument("--scaling-sizes", default="1000,4000",
                   help="the scaling study's vertex counts (the big ones: 1000,4000,16000,64000)")
    p.add_argument("--peers-repeat", type=int, default=3, help="rounds of the original tool against ours (medians)")
    p.add_argument("--only", default=None, help=f"comma-separated studies (default all: {', '.join(_BY_NAME)})")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the studies, then write the documentation's page; 1 when a study failed."""
    a = build_parser().parse_args(argv)
    names = [n for n in (a.only or ",".join(_BY_NAME)).split(",") if n]
    unknown = [n for n in names if n not in _BY_NAME]
    if unknown:
        print(f"bench: unknown study {', '.join(unknown)}; choose from {', '.join(_BY_NAME)}", file=sys.stderr)
        return 2
    if a.peers_repeat < 1:
        print(f"bench: --peers-repeat needs at least 1 round, got {a.peers_repeat}", file=sys.stderr)
        return 2
    settings = Settings(scenes=a.scenes.absolute(), original=a.original.absolute(), checker=a.checker.absolute(),
                        scaling_sizes=a.scaling_sizes,
                        peers_repeat=a.peers_repeat)
    log = lambda line: print(line, flush=True)  # noqa: E731
    outcome = {n: run_study(_BY_NAME[n], settings, log=log) for n in names}
    from benchmarks.report import write_page

    log(f"bench: wrote {write_page()}")
    failed = [n for n, o in outcome.items() if o == "failed"]
    if failed:
        log(f"bench: failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
