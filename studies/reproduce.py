"""One report: every table and figure of the paper the project covers, the paper's claim and ours
side by side, with a picture and a verdict.

::

    python -m studies.reproduce --scenes ../shared/paper-scenes --out DIR [--quick]
        [--only "Table 1,Fig. 9"] [--study-timeout S] [--reuse] [--checker PATH]

``--scenes`` is the paper-scenes folder (``scenes/`` and ``published/`` in it; its ``scenes/``
folder is accepted too). The report runs the existing studies (:data:`STUDY_RUNS`: Table 1,
the Airy comparison, the destruction replay, the dome under load, the planar-quad remesh, the
Koebe family), each as ``python -m studies.NAME`` in its own process with its output and log in
``DIR/runs/NAME``, then reads what they wrote and judges each item of :data:`ITEMS`:

* **the paper** — the paper's numbers and statements, as the project records them
  (:data:`studies.common.PAPER_TABLE1`, ``docs/guide/paper.md``);
* **ours** — the numbers the study measured;
* **verdict** — ``reproduced``, ``differs: why`` or ``not covered: why`` (also when a study
  could not run or failed: its log is named);
* **picture** — a PNG drawn by :mod:`selfsupport.figures` (by the study, or rendered here from
  the network it saved), in ``DIR/figures``.

``--quick`` runs the long studies with smaller limits (Table 1 without the IPOPT rows, the
destruction cascade with fewer stages, the planar solves with a shorter time limit); the report
says which mode produced it and stamps commit, date, CPU, cores and load (:func:`run_stamp`).
``--reuse`` judges the outputs already in ``DIR/runs`` of the studies that finished before.
Writes ``DIR/index.html``, ``DIR/index.md`` and ``DIR/report.json``.
"""
from __future__ import annotations

import argparse
import html
import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from selfsupport.core.errors import InputError
from selfsupport.io.atomic import atomic_write_bytes
from selfsupport.io.safety import check_output_dir, write_target
from studies.common import (
    DEFAULT_CHECKER,
    PAPER_TABLE1,
    REPO,
    load_average,
    read_csv_rows,
    run_stamp,
)
from studies.pq import PUBLISHED_SPACING

REPRODUCED = "reproduced"
#: the three kinds of verdict (a verdict is one of them, the last two followed by ": why")
VERDICTS = (REPRODUCED, "differs", "not covered")


def differs(why: str) -> str:
    """The verdict of a claim ours does not agree with, and why."""
    return f"differs: {why}"


def not_covered(why: str) -> str:
    """The verdict of a claim the report has no result for, and why."""
    return f"not covered: {why}"


# ----------------------------------------------------------------------------- the studies
@dataclass(frozen=True)
class StudyRun:
    """One call of a study.

    Attributes
    ----------
    name
        Its folder under ``DIR/runs`` (output and ``log.txt``).
    module
        Run as ``python -m MODULE``.
    argv
        Its arguments given (paper-scenes folder, output folder, quick mode, checker or None).
    needs
        Files under the paper-scenes folder it reads; without them it is skipped.
    quick
        What ``--quick`` changes, for the report (empty: nothing).
    """

    name: str
    module: str
    argv: Callable[[Path, Path, bool, "Path | None"], list[str]]
    needs: tuple[str, ...]
    quick: str = ""


def _checker_args(checker: Path | None) -> list[str]:
    return ["--checker", str(checker)] if checker is not None else []


#: The Table 1 variant the paper's table is compared with, and the one its IPOPT claim is.
TABLE1_STAGGERED, TABLE1_IPOPT = "staggered/active-set", "simultaneous/ipopt"
#: Fig. 9's thickness and added mass; Fig. 10's thickness and added masses (the paper's).
FIG9 = (0.1, 11000.0)
FIG10 = (1.0, (0.0, 5000.0, 10000.0, 20000.0))
#: Stages of each destruction cascade (the study's default; fewer with --quick).
DESTRUCTION_STAGES, DESTRUCTION_STAGES_QUICK = 20, 4
#: Time limit of each planar-quad solve [s] (the study's default; shorter with --quick).
PQ_TIME_LIMIT, PQ_TIME_LIMIT_QUICK = 300.0, 120.0
#: The scenes Figs. 12–14 are judged on (the vault of Fig. 12, lilium of Fig. 13, cas of Fig. 14).
PQ_SCENES = ("vault", "lilium", "cas")

STUDY_RUNS: dict[str, StudyRun] = {s.name: s for s in (
    StudyRun("table1", "studies.table1",
             lambda root, out, quick, chk: ["--scenes", str(root / "scenes"), "--out", str(out),
                                            "--published", str(root / "published"), "--methods", TABLE1_STAGGERED,
                                            *([] if quick else [TABLE1_IPOPT]), *_checker_args(chk)],
             tuple(f"scenes/{p.file}" for p in PAPER_TABLE1.values()),
             quick=f"the {TABLE1_STAGGERED} rows only (no {TABLE1_IPOPT} rows)"),
    StudyRun("airy", "studies.airy_published",
             lambda root, out, quick, chk: ["--published", str(root / "published"), "--scenes", str(root / "scenes"),
                                            "--out", str(out), "--no-timings"],
             ("published/lilium-n.obj", "published/lilium-n-stress.obj", "published/lilium-n-recip.obj")),
    StudyRun("destruction", "studies.destruction",
             lambda root, out, quick, chk: ["--scenes", str(root / "scenes"), "--published", str(root / "published"),
                                            "--out", str(out), "--max-stages",
                                            str(DESTRUCTION_STAGES_QUICK if quick else DESTRUCTION_STAGES)],
             ("scenes/twocirc-3.sss", *(f"published/remove-{k}-n.obj" for k in range(1, 5)),
              "published/remove-original.obj"),
             quick=f"at most {DESTRUCTION_STAGES_QUICK} stages per cascade (full: {DESTRUCTION_STAGES})"),
    StudyRun("dome_fig9", "studies.stability_dome",
             lambda root, out, quick, chk: ["--scenes", str(root / "scenes"), "--published", str(root / "published"),
                                            "--out", str(out), "--thickness", f"{FIG9[0]:g}",
                                            "--loads", f"0,{FIG9[1]:g}", "--max-load-thickness", f"{FIG9[0]:g}",
                                            "--starts-thickness", "" if quick else f"{FIG9[0]:g}"],
             ("scenes/dome2.sss",), quick="no max-load program from many starts (full: one per start)"),
    StudyRun("dome_fig10", "studies.stability_dome",
             lambda root, out, quick, chk: ["--scenes", str(root / "scenes"), "--published", str(root / "published"),
                                            "--out", str(out), "--thickness", f"{FIG10[0]:g}",
                                            "--loads", ",".join(f"{k:g}" for k in FIG10[1]), "--starts-thickness", ""],
             ("scenes/dome2.sss",)),
    StudyRun("heyman", "studies.heyman",
             lambda root, out, quick, chk: ["--out", str(out), *(["--quick"] if quick else [])], (),
             quick="the 8×16 meridian mesh and the 8-ring triangulation (full: also 16×64 and 4×8)"),
    StudyRun("pq", "studies.pq",
             lambda root, out, quick, chk: ["--scenes", str(root), "--out", str(out), "--only", ",".join(PQ_SCENES),
                                            "--remesher", "seamless", "--densities", "mean,published",
                                            "--time-limit", f"{PQ_TIME_LIMIT_QUICK if quick else PQ_TIME_LIMIT:g}"],
             tuple(f"scenes/{s}.sss" for s in PQ_SCENES),
             quick=f"{PQ_TIME_LIMIT_QUICK:g} s per planar solve (full: {PQ_TIME_LIMIT:g} s)"),
    StudyRun("koebe", "studies.koebe",
             lambda root, out, quick, chk: ["--scenes", str(root), "--out", str(out), *_checker_args(chk)],
             ("published/enneper-koebe.obj", "published/enneper-summed.obj")),
)}


def paper_root(scenes: Path) -> Path:
    """The paper-scenes folder given it or its ``scenes/`` folder."""
    scenes = Path(scenes).resolve()
    return scenes.parent if not (scenes / "scenes").is_dir() and scenes.name == "scenes" else scenes


@dataclass
class Outcome:
    """How a study run ended: ``done``, ``failed`` or ``skipped``, why, and how long it took."""

    status: str
    why: str = ""
    seconds: float = float("nan")
    command: str = ""


def _stop_group(proc: subprocess.Popen) -> None:
    """End the study process started here and the row processes it spawned (its own session)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(10)
            return
        except subprocess.TimeoutExpired:
            continue


def run_study(study: StudyRun, root: Path, runs: Path, *, quick: bool, checker: Path | None, timeout: float,
              log: Callable[[str], None] = print) -> Outcome:
    """Run one study into ``runs/NAME`` (its output and ``log.txt``) within ``timeout`` seconds."""
    missing = [n for n in study.needs if not (root / n).is_file()]
    if missing:
        return Outcome("skipped", f"{root} has no {', '.join(missing)}")
    out = runs / study.name
    out.mkdir(parents=True, exist_ok=True)
    argv = study.argv(root, out, quick, checker)
    command = f"python -m {study.module} {' '.join(argv)}"
    log(f"reproduce: [{time.strftime('%H:%M:%S')}] {study.name}: {command}")
    t0 = time.perf_counter()
    with open(write_target(out / "log.txt", what="study log"), "w", encoding="utf-8") as f:
        proc = subprocess.Popen([sys.executable, "-m", study.module, *argv], cwd=REPO, stdout=f,
                                stderr=subprocess.STDOUT, start_new_session=True)
        try:
            code = proc.wait(timeout)
        except subprocess.TimeoutExpired:
            _stop_group(proc)
            return Outcome("failed", f"no end within the study limit of {timeout:g} s (stopped; "
                                     f"log {out / 'log.txt'})", time.perf_counter() - t0, command)
        except BaseException:  # interrupted: take the study along
            _stop_group(proc)
            raise
    seconds = time.perf_counter() - t0
    if code != 0:
        return Outcome("failed", f"exit status {code} (log {out / 'log.txt'})", seconds, command)
    log(f"reproduce: {study.name} done in {seconds:.0f} s")
    return Outcome("done", "", seconds, command)


# ------------------------------------------------------------------------------ judging
@dataclass
class Context:
    """What the judges read: the studies' output folders, where pictures go, the mode."""

    runs: Path
    figures: Path
    quick: bool
    outcomes: dict[str, Outcome] = field(default_factory=dict)

    def out(self, study: str) -> Path:
        return self.runs / study

    def picture(self, src: Path, name: str) -> str:
        """Copy a PNG a study drew into the report's figures; its path relative to the report."""
        atomic_write_bytes(self.figures / name, Path(src).read_bytes())
        return f"{self.figures.name}/{name}"

    def render(self, network_json: Path, name: str, kind: str = "network", title: str | None = None,
               thickness: float | None = None) -> str:
        """Draw a saved network with :func:`selfsupport.figures.render.render`; its path relative to the report."""
        from selfsupport.figures.render import FigureInput, render
        from selfsupport.io import read_network

        net = read_network(network_json)
        history = json.loads(Path(network_json).read_text(encoding="utf-8")).get("history", ()) if kind == "history" else ()
        self.figures.mkdir(parents=True, exist_ok=True)
        render(kind, FigureInput(net, history=history, title=title, thickness=thickness, size=(6.0, 4.5), dpi=70),
               self.figures / name)
        return f"{self.figures.name}/{name}"


#: ``(ours, verdict, pictures)`` from the studies' outputs
Judgement = tuple[str, str, tuple[str, ...]]


@dataclass(frozen=True)
class Item:
    """One table or figure of the paper.

    Attributes
    ----------
    item, subject
        ``"Fig. 9"`` and what it shows.
    claim
        What the paper reports there.
    studies
        The :data:`STUDY_RUNS` it is judged from (none: not covered by the project).
    judge
        Reads their outputs (:class:`Context`) and returns ours, the verdict and the pictures.
    absent
        Why it is not covered, for an item without studies.
    """

    item: str
    subject: str
    claim: str
    studies: tuple[str, ...]
    judge: Callable[[Context], Judgement] | None = None
    absent: str = ""


@dataclass(frozen=True)
class Row:
    """One line of the report."""

    item: str
    subject: str
    claim: str
    ours: str
    verdict: str
    pictures: tuple[str, ...] = ()
    studies: tuple[str, ...] = ()


def _num(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


def _int(x: Any) -> int | None:
    v = _num(x)
    return int(v) if math.isfinite(v) else None


def _table1_rows(ctx: Context, backend_method: str = TABLE1_STAGGERED) -> dict[str, dict[str, str]]:
    from studies.table1 import VARIANTS

    v = VARIANTS[backend_method]
    return {r["scene"]: r for r in read_csv_rows(ctx.out("table1") / "table1.csv")
            if r["method"] == v.method and r["backend"] == v.backend}


def _scene_line(name: str, r: Mapping[str, str] | None) -> str:
    if r is None:
        return f"{name}: no row"
    it = _int(r.get("iterations"))
    return (f"{name}: {r.get('status')}, {_num(r.get('time_s')):.2f} s, {it if it is not None else '?'} it., "
            f"error {_num(r.get('max_rel_error')):.1e} (checker {_num(r.get('checker_error')):.1e})")


def _converged_below_paper(name: str, r: Mapping[str, str] | None) -> str:
    """Empty when the scene converged with an error at or below the paper's; else why not."""
    p = PAPER_TABLE1[name]
    if r is None:
        return f"{name} has no row"
    if r.get("status") != "converged":
        return f"{name} {r.get('status')}"
    err = _num(r.get("max_rel_error"))
    if not err <= p.max_rel_error:
        return f"{name} error {err:.1e} above the paper's {p.max_rel_error:.1e}"
    return ""


def _paper_line(name: str) -> str:
    p = PAPER_TABLE1[name]
    return f"{name} ({p.figure}, {p.vertices} V / {p.edges} E): {p.time_s:g} s, {p.iterations} it., error {p.max_rel_error:.1e}"


def judge_table1(ctx: Context) -> Judgement:
    rows = _table1_rows(ctx)
    names = list(PAPER_TABLE1)
    problems = [w for w in (_converged_below_paper(n, rows.get(n)) for n in names) if w]
    more_it = [n for n in names if n in rows and (_int(rows[n].get("iterations")) or 0) > PAPER_TABLE1[n].iterations]
    ours = "; ".join(_scene_line(n, rows.get(n)) for n in names)
    ours += ". Times from another machine and year (ours: this run's stamp), not judged."
    if problems:
        verdict = differs("; ".join(problems))
    elif more_it:
        verdict = differs(f"errors at or below the paper's on every scene, but more outer iterations than the "
                          f"paper on {', '.join(more_it)}")
    else:
        verdict = REPRODUCED
    pics = ()
    lil = ctx.out("table1") / "lilium__staggered-active-set.json"
    if lil.is_file():
        pics = (ctx.render(lil, "table1-lilium-history.png", "history", "lilium: convergence of the staggered method"),)
    return ours, verdict, pics


def judge_table1_ipopt(ctx: Context) -> Judgement:
    if ctx.quick:
        return NO_RESULT, not_covered(f"the quick mode runs no {TABLE1_IPOPT} rows (run without --quick)"), ()
    rows = _table1_rows(ctx, TABLE1_IPOPT)
    ours = "; ".join(f"{n}: {rows[n].get('status')} ({_num(rows[n].get('time_s')):.0f} s of "
                     f"{_num(rows[n].get('time_limit_s')):g})" if n in rows else f"{n}: no row" for n in PAPER_TABLE1)
    failed = [n for n in PAPER_TABLE1 if n in rows and rows[n].get("status") != "converged"]
    verdict = (REPRODUCED if failed else differs("IPOPT converged on every scene"))
    return f"simultaneous IPOPT (MUMPS): {ours}", verdict, ()


def _published_line(name: str, r: Mapping[str, str] | None) -> str:
    p = PAPER_TABLE1[name]
    d = _num((r or {}).get("dist_pub_mean"))
    if not p.published or not math.isfinite(d):
        return ""
    return f"; mean distance to the paper's {p.published} {d:.1e} of the bounding-box diagonal"


def _figure_of_scenes(names: Sequence[str]) -> Callable[[Context], Judgement]:
    """The judge of a figure showing Table 1 scenes: each converged with an error at or below the
    paper's, and its network drawn."""
    def judge(ctx: Context) -> Judgement:
        rows = _table1_rows(ctx)
        ours = "; ".join(_scene_line(n, rows.get(n)) + _published_line(n, rows.get(n)) for n in names)
        problems = [w for w in (_converged_below_paper(n, rows.get(n)) for n in names) if w]
        pics = []
        for n in names:
            net = ctx.out("table1") / f"{n}__staggered-active-set.json"
            if net.is_file():
                pics.append(ctx.render(net, f"{n}-network.png", "network", f"{n}: our thrust network"))
        return ours, differs("; ".join(problems)) if problems else REPRODUCED, tuple(pics)
    return judge


#: Relative agreement of Φ and of the reciprocal diagram with the published files that counts as
#: the same (the files' six significant digits, integrated over some 2,000 faces).
AIRY_TOL = 1e-4


def judge_airy(ctx: Context) -> Judgement:
    d = json.loads((ctx.out("airy") / "airy_published.json").read_text(encoding="utf-8"))["lilium"]
    pw = d["from_published_weights"]
    ours = (f"weights fitted to lilium-n.obj at fixed positions (error {d['fit_max_relative_error']:.1e}): Φ within "
            f"{d['stress']['max_deviation_rel']:.1e}, the diagram within {d['reciprocal']['max_deviation_rel']:.1e} of "
            f"the published ones (relative, up to gauge; a triangle mesh's weights are not unique). With the weights "
            f"the published diagram implies: Φ within {pw['stress_max_deviation_rel']:.1e}, the diagram within "
            f"{pw['reciprocal_max_deviation_rel']:.1e} (agreement needed: {AIRY_TOL:g})")
    worst = max(pw["stress_max_deviation_rel"], pw["reciprocal_max_deviation_rel"])
    verdict = REPRODUCED if worst <= AIRY_TOL else differs(
        f"from the published diagram's own weights, Φ or the diagram deviates by {worst:.1e} (> {AIRY_TOL:g})")
    pics = ()
    lil = ctx.out("table1") / "lilium__staggered-active-set.json"
    if lil.is_file() and "table1" in ctx.outcomes and ctx.outcomes["table1"].status == "done":
        pics = (ctx.render(lil, "lilium-reciprocal.png", "reciprocal", "lilium: reciprocal force diagram (ours)"),)
    return ours, verdict, pics


#: A destruction stage agrees with the paper's when its face count is within this fraction of
#: the paper's (the two meshes' faces are matched by position, not by index).
FACE_TOL = 0.05


def judge_destruction(ctx: Context) -> Judgement:
    d = json.loads((ctx.out("destruction") / "destruction.json").read_text(encoding="utf-8"))
    replay = d["replay"]
    if not replay:
        return "no replay (the published stages were not read)", not_covered("the study wrote no replay"), ()
    parts, off = [], []
    for k, r in enumerate(replay, start=1):
        pf, of = _int(r.get("paper_faces")), _int(r.get("faces"))
        parts.append(f"step {k} ({r.get('kind')}): paper {pf}, ours {of}")
        if pf is None or of is None or abs(of - pf) > FACE_TOL * pf:
            off.append(f"step {k}: {of} faces against the paper's {pf}")
    ours = ("the paper's cuts replayed on twocirc-3 (t = 0.5 m), our cascade after each: " + "; ".join(parts)
            + f" (agreement: within {FACE_TOL:.0%} of the paper's count)")
    pics = ()
    png = ctx.out("destruction") / "replay.png"
    if png.is_file():
        pics = (ctx.picture(png, "fig8-replay.png"),)
    return ours, differs("; ".join(off)) if off else REPRODUCED, pics


def _dome_output(ctx: Context, study: str) -> dict[str, Any]:
    """The stability_dome study's JSON: ``series`` (the experiment's configuration only), ``max_load``,
    ``starts`` and ``published_in_hull`` (empty when it did not run them)."""
    data = json.loads((ctx.out(study) / "stability_dome.json").read_text(encoding="utf-8"))
    data = data if isinstance(data, dict) else {"series": data}
    series = [r for r in data.get("series", []) if r.get("configuration", "") != "as stored"]
    return {"series": series, **{k: data.get(k) or [] for k in ("max_load", "starts", "published_in_hull")}}


def _dome_rows(ctx: Context, study: str) -> list[dict[str, Any]]:
    return _dome_output(ctx, study)["series"]


def _dome_line(r: Mapping[str, Any]) -> str:
    state = "a network inside the hull" if r.get("found") else (
        f"none found ({r.get('outside')} vertices out, up to {_num(r.get('max_hull_excess_m')):.3g} m)")
    return f"{_num(r.get('added_kg')):,.0f} kg: {state}"


def _dome_picture(ctx: Context, study: str, t: float, kg: float, name: str) -> tuple[str, ...]:
    png = ctx.out(study) / f"t{t:g}-{kg:g}kg.png"
    return (ctx.picture(png, name),) if png.is_file() else ()


def _fig9_limit(data: Mapping[str, Any], t: float) -> tuple[float | None, list[str]]:
    """The largest certified added mass at ``t`` over the study's limit programs (the max-load row
    and every start), and the sentences that say where it came from and what binds it."""
    said: list[str] = []
    best, best_row = None, None
    for r in [*data["max_load"], *data["starts"]]:
        if _num(r.get("thickness_m")) == t and r.get("max_load_kg") not in (None, ""):
            kg = _num(r["max_load_kg"])
            if len(str(r.get("load_at", "")).split()) > 1:
                continue  # the one-ring sensitivity row is not Fig. 9's configuration (the apex vertex)
            best, best_row = (kg, r) if best is None or kg > best else (best, best_row)
    if best is not None:
        where = f" (from the {best_row['start']})" if best_row.get("start") else ""
        said.append(f"limit program: largest certified added mass {best:,.0f} kg{where}")
    apex = [r for r in data["starts"] if len(str(r.get("load_at", "")).split()) <= 1]
    if apex:
        opt = [_num(r["optimum_kg"]) for r in apex if r.get("optimum_kg") not in (None, "")]
        said.append(f"{len(apex)} starts, program optima {min(opt):,.0f}–{max(opt):,.0f} kg" if opt else
                    f"{len(apex)} starts, no optimum")
        if best_row is not None and best_row.get("hull_active"):
            said.append(f"at the best optimum hull bounds active (extrados / intrados) {best_row['hull_active']}, "
                        f"largest multipliers {best_row.get('hull_top')}; weights at ε {best_row.get('weights_at_lower')}")
    for r in data["starts"]:
        if len(str(r.get("load_at", "")).split()) > 1 and r.get("max_load_kg") not in (None, ""):
            said.append(f"sensitivity, the mass spread over {len(str(r['load_at']).split())} vertices around the apex: "
                        f"{_num(r['max_load_kg']):,.0f} kg certified")
    for r in data["published_in_hull"]:
        if r.get("published", "").endswith("-0kg-n"):
            said.append(f"the published 0 kg network is outside our hull: {r['outside']} of {r['free']} free vertices "
                        f"beyond t/2, up to {_num(r['max_distance_m']):.3g} m from our reference")
    return best, said


def judge_fig9(ctx: Context) -> Judgement:
    t, kg = FIG9
    data = _dome_output(ctx, "dome_fig9")
    rows = {_num(r["added_kg"]): r for r in data["series"] if _num(r.get("thickness_m", t)) == t}
    r = rows[kg]
    best, said = _fig9_limit(data, t)
    ours = (f"dome2 on its ground ring, mass at the apex, t = {t:g} m, hull search: "
            + "; ".join(_dome_line(rows[k]) for k in sorted(rows)) + "".join(f"; {x}" for x in said))
    if r.get("found") or (best is not None and best >= kg):
        verdict = REPRODUCED
    else:
        verdict = differs(
            f"no network inside the hull found under {kg:,.0f} kg ({r.get('outside')} vertices out, up to "
            f"{_num(r.get('max_hull_excess_m')):.3g} m); the search is no proof of collapse"
            + (f"; not reproduced: the limit program certifies at most {best:,.0f} kg on this mesh and reference "
               "(best over its starts)" if best is not None else ""))
    return ours, verdict, _dome_picture(ctx, "dome_fig9", t, kg, "fig9-dome.png")


def judge_heyman(ctx: Context) -> Judgement:
    """Heyman's hemisphere: the finest meridian × parallel mesh's certified t/R within 15% of 0.042
    (the analytic check); the ring triangulation's beside it."""
    data = json.loads((ctx.out("heyman") / "heyman.json").read_text(encoding="utf-8"))
    heyman, rows = float(data["heyman"]), data["rows"]

    def line(r: Mapping[str, Any]) -> str:
        t = r.get("t_over_r")
        return (f"{r['layout']} {r['mesh']} ({r['vertices']} V): t/R = {t:.4f} ({t / heyman - 1:+.1%})"
                if t is not None else f"{r['layout']} {r['mesh']}: {r['verdict']}")

    ours = "min-thickness program, supports sliding: " + "; ".join(line(r) for r in rows)
    grid = [r for r in rows if r["layout"] == "meridian"]
    finest = max(grid, key=lambda r: r["vertices"]) if grid else None
    if finest is None or finest.get("t_over_r") is None:
        return ours, differs("no meridian × parallel hemisphere was certified"), ()
    off = finest["t_over_r"] / heyman - 1
    verdict = REPRODUCED if abs(off) <= 0.15 else differs(f"t/R {finest['t_over_r']:.4f}, {off:+.1%} from Heyman's")
    pics = (ctx.render(ctx.out("heyman") / finest["network"], "heyman-hemisphere.png", kind="network",
                       title=f"hemisphere {finest['mesh']}, t/R = {finest['t_over_r']:.4f}"),)
    return ours, verdict, pics


def judge_fig10(ctx: Context) -> Judgement:
    t, loads = FIG10
    rows = {_num(r["added_kg"]): r for r in _dome_rows(ctx, "dome_fig10")}
    ours = f"dome2, t = {t:g} m: " + "; ".join(_dome_line(rows[k]) for k in loads if k in rows)
    found = [bool(rows[k].get("found")) for k in loads if k in rows]
    heaviest = max(rows)
    if len(found) < len(loads):
        verdict = not_covered("the study did not run every load")
    elif found[0] and not found[-1] and found == sorted(found, reverse=True):
        verdict = REPRODUCED
    elif all(found):
        verdict = differs("a network inside the hull at every load: ours does not leave the hull")
    else:
        verdict = differs("inside or outside the hull does not follow the load as in the paper")
    return ours, verdict, _dome_picture(ctx, "dome_fig10", t, heaviest, "fig10-dome.png")


#: Largest quad non-planarity of a planar-quad network (the pq study's tolerance).
PQ_TOL = 1e-3
#: Largest max relative error of a planar-quad network that counts as in equilibrium.
PQ_EQ_TOL = 1e-8
#: The pq study's row of the remesh along the relative principal directions (the default remesher).
PQ_ALIGNED = "remesh principal (seamless)"


def pq_planar(r: Mapping[str, Any]) -> bool:
    """Whether a pq row is a planar-quad network in equilibrium."""
    return (r.get("status") == "converged" and _num(r.get("nonplanar_max")) <= PQ_TOL
            and _num(r.get("max_rel_error")) <= PQ_EQ_TOL)


def _pq_row_text(r: Mapping[str, Any]) -> str:
    return (f"{r.get('faces')} ({_num(r.get('quads')):.0%} quads), {r.get('status')}, non-planarity "
            f"{_num(r.get('nonplanar_max')):.1e}, error {_num(r.get('max_rel_error')):.1e}, distance "
            f"{_num(r.get('dist_mean')):.3e}")


def pq_same_spacing(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two pq rows are remeshes at the same spacing (the mean edge, or the published mesh's)."""
    return (PUBLISHED_SPACING in str(a.get("mesh"))) == (PUBLISHED_SPACING in str(b.get("mesh")))


def judge_pq(ctx: Context) -> Judgement:
    """Per scene of :data:`PQ_SCENES` and per spacing the study used (the network's mean edge, and
    where there is a published pq mesh its mean edge): the aligned remesh planar to
    :data:`PQ_TOL` in equilibrium, and closer to the reference (mean distance over the diagonal)
    than every grid remesh at the same spacing that became planar too (one that did not counts
    for the aligned remesh)."""
    all_rows = read_csv_rows(ctx.out("pq") / "pq.csv")
    parts, why, cut, pics = [], [], [], []
    for scene in PQ_SCENES:
        rows = [r for r in all_rows if r["scene"] == scene]
        main = next((r for r in rows if r["mesh"] == PQ_ALIGNED), None)
        if main is None:
            parts.append(f"{scene}: no aligned remesh")
            why.append(f"{scene}: the study has no {PQ_ALIGNED} row")
            continue
        aligned = [main] + [r for r in rows if r["mesh"] == f"{PQ_ALIGNED[:-1]}, {PUBLISHED_SPACING})"]
        net = ctx.out("pq") / f"{scene}__principal-seamless.json"
        if net.is_file():
            pics.append(ctx.render(net, f"fig12-{scene}-pq.png", "network",
                                   f"{scene} along the principal directions"))
        for a in aligned:
            at = f" at the {PUBLISHED_SPACING}" if a is not main else ""
            grids = [r for r in rows if str(r["mesh"]).startswith("remesh grid") and pq_same_spacing(r, a)]
            parts.append(f"{scene}{at}: aligned " + _pq_row_text(a) + "".join(
                f"; {g['mesh'].removeprefix('remesh ')} " + _pq_row_text(g) for g in grids))
            if ctx.quick and a.get("status") == "time_limit":
                cut.append(scene + at)
                continue
            if not pq_planar(a):
                why.append(f"{scene}{at}: the aligned remesh did not become a planar-quad network in equilibrium "
                           f"({a.get('status')}, non-planarity {_num(a.get('nonplanar_max')):.1e}, error "
                           f"{_num(a.get('max_rel_error')):.1e})")
            if not grids:
                why.append(f"{scene}{at}: no grid remesh to compare with")
            for g in grids:
                da, dg = _num(a.get("dist_mean")), _num(g.get("dist_mean"))
                if pq_planar(g) and not da < dg:
                    why.append(f"{scene}{at}: the aligned remesh ends farther from the reference than the "
                               f"{g['mesh'].removeprefix('remesh ')} ({da:.3e} vs {dg:.3e} of the diagonal)")
    ours = "; ".join(parts) + f" (planar: at most {PQ_TOL:g}; in equilibrium: error at most {PQ_EQ_TOL:g})"
    if why:
        return ours, differs("; ".join(why)), tuple(pics)
    if cut:
        return ours, not_covered(f"the quick mode's {PQ_TIME_LIMIT_QUICK:g} s limit ended the planar solve along the "
                                 f"principal directions of {', '.join(cut)} before its quads were planar "
                                 "(run without --quick)"), tuple(pics)
    return ours, REPRODUCED, tuple(pics)


#: Equilibrium of the rebuilt Koebe family that counts as exact (round-off of the checker).
KOEBE_EQ_TOL = 1e-9
#: Fit of the published summed mesh by Φ + αR [length units]: ten units of the files' sixth decimal.
KOEBE_FILE_TOL = 1e-5


def judge_koebe(ctx: Context) -> Judgement:
    d = json.loads((ctx.out("koebe") / "koebe.json").read_text(encoding="utf-8"))
    fam = [r for r in d["equilibrium"] if r["mesh"].startswith("enneper-") and r["loads"] == "reciprocal"]
    worst = max(_num(r["checker_max_rel_error"]) for r in fam)
    wmin = min(_num(r["min_weight"]) for r in fam)
    fit = d["rebuilt"]["inscribed"]["fit"]
    alphas = ", ".join(sorted({f"{r['alpha']:.4g}" for r in fam}))
    ours = (f"the family Φ + αR rebuilt ({len(fam)} members, α = {alphas}): "
            f"checker error at most {worst:.1e}, weights at least {wmin:.3g} (compressive); the published "
            f"enneper-summed.obj = enneper-koebe.obj + αR with α = {d['alpha_published']:.5f}, residual "
            f"{fit['max_residual_no_affine']:.1e} (file precision: {KOEBE_FILE_TOL:g})")
    why = []
    if not worst <= KOEBE_EQ_TOL:
        why.append(f"a family member is out of equilibrium by {worst:.1e}")
    if not wmin > 0:
        why.append("a family member has a tensile weight")
    if not fit["max_residual_no_affine"] <= KOEBE_FILE_TOL:
        why.append(f"the published summed mesh is not Φ + αR (residual {fit['max_residual_no_affine']:.1e})")
    pics = ()
    a = d["alpha_published"]
    net = ctx.out("koebe") / f"enneper-inscribed-alpha{a:g}.json"
    if net.is_file():
        pics = (ctx.render(net, "fig15-enneper.png", "network", f"Φ + αR, α = {a:.4f} (ours)"),)
    return ours, differs("; ".join(why)) if why else REPRODUCED, pics


def _table1_claim(names: Sequence[str]) -> str:
    return "; ".join(_paper_line(n) for n in names)


#: Every table and figure of the paper the report has a line for, in the paper's order.
ITEMS: tuple[Item, ...] = (
    Item("Table 1", "the staggered method on the paper's scenes",
         "time (Xeon 2.3 GHz), outer iterations and max. relative error per scene: " + _table1_claim(list(PAPER_TABLE1)),
         ("table1",), judge_table1),
    Item("Table 1 (IPOPT)", "a simultaneous solve with IPOPT",
         "a simultaneous solve with IPOPT fails on complex shapes", ("table1",), judge_table1_ipopt),
    Item("Fig. 5b, 5d", "lilium and lilium with a pillar",
         "self-supporting thrust networks: " + _table1_claim(["lilium", "lilium-pillar"])
         + " (published: lilium-n.obj, lilium-pillar-n.obj)", ("table1",), _figure_of_scenes(["lilium", "lilium-pillar"])),
    Item("Fig. 5c", "Airy stress surface and reciprocal diagram of lilium",
         "the reciprocal force diagram and Airy stress surface Φ of the lilium network (published: "
         "lilium-n-recip.obj, lilium-n-stress.obj)", ("airy",), judge_airy),
    Item("Fig. 6", "cas", "a self-supporting thrust network: " + _table1_claim(["cas"]), ("table1",),
         _figure_of_scenes(["cas"])),
    Item("Fig. 7", "(not recorded)", "the project records no scene, published result or statement of Fig. 7", (),
         absent="the paper-scenes folder holds no scene or published result of Fig. 7 "
                                      "(its README maps none to it)"),
    Item("Fig. 8", "destruction of twocirc-3",
         "twocirc-3 cut in four steps; its third step is a collapse of 445 faces (from 1,364 to 938); faces left "
         "per stage 1,394 / 1,364 / 938 / 899 (published remove-1..4-n.obj)", ("destruction",), judge_destruction),
    Item("Fig. 9", "the thin dome under added load",
         f"dome of 14 m span, t = {FIG9[0]:g} m, ρ = 2,500 kg/m³: a thrust network inside the masonry hull under "
         f"an added {FIG9[1]:,.0f} kg", ("dome_fig9",), judge_fig9),
    Item("Fig. 10", "the thick dome under growing load",
         f"the same dome with t = {FIG10[0]:g} m under added loads of "
         f"{' / '.join(f'{k:,.0f}' for k in FIG10[1])} kg: as the load grows the thrust network leaves the hull",
         ("dome_fig10",), judge_fig10),
    Item("Heyman", "the thinnest hemispherical dome (an analytic check; not in the paper)",
         "Heyman (1977): a hemispherical dome stands under its own weight down to t/R = 0.042", ("heyman",),
         judge_heyman),
    Item("Fig. 11", "swiss cheese (cyl2)",
         "a self-supporting thrust network: " + _table1_claim(["cyl2"]) + " (published: cheese-n.obj)",
         ("table1",), _figure_of_scenes(["cyl2"])),
    Item("Figs. 12–14", "planar quads along the relative principal directions",
         "a quad mesh along the relative principal directions (the vault of Fig. 12, lilium of Fig. 13, cas of "
         "Fig. 14) can be polished to a planar-quad network in equilibrium, and ends closer to the reference than "
         "a mesh along a fixed grid polished the same way", ("pq",), judge_pq),
    Item("Fig. 15", "the Enneper family",
         "the Koebe mesh of an Enneper surface and a member of its family Φ + αR, self-supporting for unit load "
         "(published: enneper-koebe.obj, enneper-summed.obj)", ("koebe",), judge_koebe),
    Item("Fig. 16", "structural (steel/glass)",
         "a self-supporting thrust network: " + _table1_claim(["structural"]) + " (published: structural-n.obj)",
         ("table1",), _figure_of_scenes(["structural"])),
)


#: The "ours" of a row without a result (its verdict says why).
NO_RESULT = "no result"


def judge_item(item: Item, ctx: Context) -> Row:
    """The report's line of one item: not covered when a study it needs did not finish or its
    output cannot be read (saying which and why)."""
    base = dict(item=item.item, subject=item.subject, claim=item.claim, studies=item.studies)
    if item.judge is None:
        return Row(**base, ours=NO_RESULT, verdict=not_covered(item.absent))
    for name in item.studies:
        o = ctx.outcomes.get(name)
        if o is None or o.status != "done":
            why = "it was not run" if o is None else f"{o.status}: {o.why}"
            return Row(**base, ours=NO_RESULT, verdict=not_covered(f"study {name} {why}"))
    try:
        ours, verdict, pics = item.judge(ctx)
    except (OSError, KeyError, ValueError, TypeError, IndexError) as exc:
        return Row(**base, ours=NO_RESULT, verdict=not_covered(
            f"the output of {', '.join(item.studies)} could not be read ({type(exc).__name__}: {exc})"))
    return Row(**base, ours=ours, verdict=verdict, pictures=pics)


# ------------------------------------------------------------------------------ writing
def verdict_kind(verdict: str) -> str:
    """``reproduced``, ``differs`` or ``not covered``."""
    return next(k for k in VERDICTS if verdict == k or verdict.startswith(k + ":"))


def _summary(rows: Sequence[Row]) -> str:
    counts = {k: sum(verdict_kind(r.verdict) == k for r in rows) for k in VERDICTS}
    return ", ".join(f"{n} {k}" for k, n in counts.items())


def _header_lines(stamp: Mapping[str, Any], mode: str, scenes: Path) -> list[str]:
    return [f"mode: **{mode}**", f"paper scenes: `{scenes}`",
            f"commit {stamp['commit']}, {stamp['date']}, {stamp['cpu_model']}, {stamp['cores']} cores, load average "
            f"(1/5/15 min) {stamp['load_start']} at the start, {stamp.get('load_end', '?')} at the end",
            "the paper's column: its numbers and statements as the project records them "
            "(studies.common.PAPER_TABLE1, docs/guide/paper.md)"]


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_markdown(rows: Sequence[Row], stamp: Mapping[str, Any], mode: str, scenes: Path,
                    outcomes: Mapping[str, Outcome]) -> str:
    """The report as Markdown: the stamp, the verdict table (pictures linked), the studies run."""
    out = ["# The paper reproduced", ""]
    out += [f"* {line}" for line in _header_lines(stamp, mode, scenes)]
    out += ["", f"**{_summary(rows)}**", "", "| item | subject | the paper | ours | verdict | picture |",
            "|---|---|---|---|---|---|"]
    for r in rows:
        pics = " ".join(f"[{Path(p).name}]({p})" for p in r.pictures)
        out.append("| " + " | ".join(_md_cell(x) for x in (r.item, r.subject, r.claim, r.ours, r.verdict)) +
                   f" | {pics} |")
    out += ["", "## Studies run", "", "| study | status | time [s] | command |", "|---|---|---|---|"]
    for name, o in outcomes.items():
        status = o.status + (f": {o.why}" if o.why else "")
        out.append(f"| {name} | {_md_cell(status)} | {o.seconds:.0f} | `{o.command}` |")
    return "\n".join(out) + "\n"


_CSS = ("body{font-family:sans-serif;max-width:1400px;margin:1em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #bbb;padding:4px 6px;vertical-align:top;font-size:90%}"
        ".reproduced{background:#dfd}.differs{background:#fdd}.not-covered{background:#eee}img{width:300px}")


def render_html(rows: Sequence[Row], stamp: Mapping[str, Any], mode: str, scenes: Path,
                outcomes: Mapping[str, Outcome]) -> str:
    """The report as one HTML page (pictures linked from ``figures/``)."""
    e = html.escape
    head = "".join(f"<li>{e(line).replace('**', '')}</li>" for line in _header_lines(stamp, mode, scenes))
    body = []
    for r in rows:
        pics = "".join(f'<a href="{e(p)}"><img src="{e(p)}" alt="{e(r.item)}"></a>' for p in r.pictures)
        cls = verdict_kind(r.verdict).replace(" ", "-")
        body.append(f"<tr><td>{e(r.item)}</td><td>{e(r.subject)}</td><td>{e(r.claim)}</td><td>{e(r.ours)}</td>"
                    f'<td class="{cls}">{e(r.verdict)}</td><td>{pics}</td></tr>')
    studies = "".join(f"<tr><td>{e(n)}</td><td>{e(o.status + (': ' + o.why if o.why else ''))}</td>"
                      f"<td>{o.seconds:.0f}</td><td><code>{e(o.command)}</code></td></tr>" for n, o in outcomes.items())
    return (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>The paper reproduced</title>"
            f"<style>{_CSS}</style></head><body><h1>The paper reproduced</h1><ul>{head}</ul>"
            f"<p><b>{e(_summary(rows))}</b></p><table><tr><th>item</th><th>subject</th><th>the paper</th>"
            f"<th>ours</th><th>verdict</th><th>picture</th></tr>{''.join(body)}</table>"
            f"<h2>Studies run</h2><table><tr><th>study</th><th>status</th><th>time [s]</th><th>command</th></tr>"
            f"{studies}</table></body></html>\n")


def write_report(out: Path, rows: Sequence[Row], stamp: Mapping[str, Any], mode: str, scenes: Path,
                 outcomes: Mapping[str, Outcome]) -> tuple[Path, Path]:
    """``index.md``, ``index.html`` and ``report.json`` in ``out``, each written atomically."""
    from selfsupport.io.atomic import atomic_write_text

    md, page = out / "index.md", out / "index.html"
    atomic_write_text(md, render_markdown(rows, stamp, mode, scenes, outcomes))
    atomic_write_text(page, render_html(rows, stamp, mode, scenes, outcomes))
    atomic_write_text(out / "report.json", json.dumps(
        {"stamp": dict(stamp), "mode": mode, "scenes": str(scenes), "rows": [asdict(r) for r in rows],
         "studies": {n: asdict(o) for n, o in outcomes.items()}}, indent=1, default=str) + "\n")
    return md, page


def assemble(ctx: Context, items: Sequence[Item] = ITEMS) -> list[Row]:
    """One :class:`Row` per item from the studies' outputs in ``ctx``."""
    return [judge_item(it, ctx) for it in items]


# ------------------------------------------------------------------------------ command line
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m studies.reproduce", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", required=True, type=Path,
                   help="the paper-scenes folder (with scenes/ and published/), or its scenes/ folder")
    p.add_argument("--out", required=True, type=Path, help="report folder (index.html, index.md, runs/, figures/)")
    p.add_argument("--quick", action="store_true", help="smaller limits for the long studies (the report says so)")
    p.add_argument("--only", default=None,
                   help=f"comma-separated items (default all: {', '.join(it.item for it in ITEMS)})")
    p.add_argument("--study-timeout", type=float, default=None,
                   help="seconds each study may take before it is stopped (default 1800 with --quick, else 14400)")
    p.add_argument("--reuse", action="store_true",
                   help="judge the outputs already in OUT/runs of studies that finished there before; run the others")
    p.add_argument("--checker", type=Path, default=DEFAULT_CHECKER, help="the independent check_network.py")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the studies the chosen items need, judge them, write the report; 0 unless a study failed."""
    a = build_parser().parse_args(argv)
    root = paper_root(a.scenes)
    if not (root / "scenes").is_dir():
        raise SystemExit(f"reproduce: {a.scenes} is not the paper-scenes folder (no scenes/ in {root}); "
                         "give --scenes ../shared/paper-scenes")
    names = [s.strip() for s in (a.only or "").split(",") if s.strip()]
    by_name = {it.item: it for it in ITEMS}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise SystemExit(f"reproduce: unknown item {', '.join(unknown)}; choose from {', '.join(by_name)}")
    timeout = a.study_timeout if a.study_timeout is not None else (1800.0 if a.quick else 14400.0)
    if not timeout > 0:
        raise SystemExit(f"reproduce: --study-timeout needs a positive number of seconds, got {a.study_timeout}")
    items = [by_name[n] for n in names] if names else list(ITEMS)
    out = a.out.resolve()
    try:  # before any study runs: a report that could not be written would waste them
        check_output_dir(out, what="--out", files=("index.md", "index.html", "report.json"))
    except InputError as e:
        raise SystemExit(f"reproduce: {e}") from None
    runs = out / "runs"
    checker = a.checker.resolve() if a.checker and a.checker.is_file() else None
    stamp = run_stamp()
    mode = "quick (--quick: " + "; ".join(f"{s.name}: {s.quick}" for s in STUDY_RUNS.values() if s.quick) + ")" \
        if a.quick else "full"
    ctx = Context(runs=runs, figures=out / "figures", quick=a.quick)
    needed = [s for s in STUDY_RUNS if any(s in it.studies for it in items)]
    previous = _previous_outcomes(out, quick=a.quick) if a.reuse else {}
    for name in needed:
        if name in previous and previous[name].status == "done":
            ctx.outcomes[name] = previous[name]
            continue
        ctx.outcomes[name] = run_study(STUDY_RUNS[name], root, runs, quick=a.quick, checker=checker, timeout=timeout)
        if ctx.outcomes[name].status != "done":
            print(f"reproduce: {name} {ctx.outcomes[name].status}: {ctx.outcomes[name].why}", flush=True)
    rows = assemble(ctx, items)
    stamp["load_end"] = load_average()
    md, page = write_report(out, rows, stamp, mode, root, ctx.outcomes)
    print(md.read_text(encoding="utf-8"))
    print(f"reproduce: wrote {page} and {md}")
    return 1 if any(o.status == "failed" for o in ctx.outcomes.values()) else 0


def _previous_outcomes(out: Path, *, quick: bool) -> dict[str, Outcome]:
    """The study outcomes of an earlier report in ``out`` made in the same mode (none when there
    is no readable one, or it was made in the other mode: the outputs would not be this mode's)."""
    try:
        d = json.loads((out / "report.json").read_text(encoding="utf-8"))
        if d.get("mode", "").startswith("quick") != quick:
            return {}
        return {n: Outcome(**o) for n, o in d.get("studies", {}).items()}
    except (OSError, ValueError, TypeError):
        return {}


if __name__ == "__main__":
    sys.exit(main())
