"""Reproduce the paper's Table 1 and compare the solvers on the paper's own scenes.

    python -m studies.table1 --scenes ../shared/paper-scenes/scenes --out OUT
        [--published DIR] [--methods staggered/active-set simultaneous/ipopt ...]
        [--time-limit S] [--only lilium,cas] [--checker PATH] [--no-warmup] [--repeat N]
        [--objective NAME=W ...]

For every Table 1 scene found in ``--scenes`` (:data:`studies.common.PAPER_TABLE1`; a folder
without any, e.g. held-out scenes of the same kind, runs every scene file in it) and every
variant in ``--methods`` (:data:`VARIANTS`: the staggered method with each Step-2 backend, its
coupled variant and its refinement phase, the simultaneous IPOPT solve cold and warm-started
from the staggered network, nlopt where it applies) one row: wall time, outer iterations, max
relative error, min weight, distance to the reference, status and peak memory, with the paper's
time / iterations / error beside them.

How each number is measured
---------------------------
* Every row runs in its own spawned Python process (:func:`studies.common.run_isolated`):
  one crash or hang costs one row, and the peak RSS is that row's own. The process first
  reads the scene and solves a tiny dome with the same method (imports, solver plug-ins and
  caches loaded: ``--no-warmup`` skips this); the **time is the ``solve()`` call alone** —
  no interpreter start-up, imports or file reading. With ``--repeat N`` the row's process
  solves N times and the time column is the median (``time_min_s``: the fastest): this
  machine's speed drifts by tens of percent within minutes. The solves are deterministic;
  a row whose repeats disagree in any vertex says so in its message.
* The **error column is recomputed from the saved JSON network** with plain numpy
  (:func:`studies.common.json_max_relative_error`), not taken from the result object; the
  shared independent checker (``--checker``) is run on the same file as a second opinion.
* Distances to the reference are the mean / max distance from the network's vertices to the
  reference surface over its bounding-box diagonal (the result's evidence fields).
* ``published`` rows: the paper's own network (``--published``, same vertex order) with
  weights fitted to it at fixed positions by :func:`selfsupport.api.check`; their error is
  recomputed from the saved JSON of that fit like every other row. ``vs published`` columns:
  vertex-to-vertex distance between our network and the paper's, over the bbox diagonal.
* ``× staggered``: the row's time over the staggered/active-set time on the same scene.
  ``speed-up``: the paper's time over ours (the paper ran on a Xeon 2.3 GHz).

Writes ``table1.csv`` (all columns), ``table1.md`` and one ``SCENE__METHOD-BACKEND.json``
network per row into ``--out``; prints the Markdown.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from formulations import ObjectiveTerm

from .common import (
    PAPER_TABLE1,
    PUBLISHED_UP,
    STAMP_COLUMNS,
    Column,
    Stopwatch,
    current_rss_mib,
    equilibrium_errors,
    exit_on_sigterm,
    json_network_arrays,
    load_average,
    peak_rss_mib,
    read_study_scene,
    run_checker,
    run_isolated,
    run_stamp,
    safe_ratio,
    scene_file,
    study_scenes_or_exit,
    write_csv,
    write_markdown,
)


# ------------------------------------------------------------------------------ variants
def _staggered(backend: str, **options: Any) -> Callable[[], Any]:
    def make():
        from selfsupport.methods.staggered import StaggeredLinearization

        return StaggeredLinearization(backend=backend, **options)
    return make


def _simultaneous(**options: Any) -> Callable[[], Any]:
    def make():
        from selfsupport.methods.simultaneous import Simultaneous

        return Simultaneous(**options)
    return make


#: The regulariser weights of the homotopy variants before the method's own (1e-6).
HOMOTOPY = (1.0, 1e-2, 1e-4)


#: The surface objective of the IPOPT row compared with the refinement: the distance to the
#: reference surface (tangent planes at the start's closest points, no tangential hold) plus 0.1 ×
#: the distance to the reference vertices (the paper's α = 1, β = 0.1).
SURFACE_OBJECTIVE = (ObjectiveTerm("reference", 1.0, {"tangential": 0.0}), ObjectiveTerm("vertices", 0.1))


def _nlopt() -> Any:
    from selfsupport.methods.nlopt_methods import NloptSimultaneous

    return NloptSimultaneous()


@dataclass(frozen=True)
class Variant:
    """One method/backend combination of the table.

    Attributes
    ----------
    key
        ``METHOD/BACKEND`` as used by ``--methods``.
    method, backend
        For the table's columns.
    make
        Builds the method object (in the worker process).
    time_limit
        Default per-row time limit [s] handed to ``solve(time_limit=...)``.
    warm_start
        Start from the staggered/active-set network of the same scene.
    solve_kw
        Further keyword arguments of ``solve()`` (e.g. IPOPT's objective), as (name, value) pairs.
    """

    key: str
    method: str
    backend: str
    make: Callable[[], Any]
    time_limit: float
    warm_start: bool = False
    solve_kw: tuple[tuple[str, Any], ...] = ()


#: The reference row of each scene: warm starts and the ``× staggered`` ratios refer to it.
REFERENCE = "staggered/active-set"

#: Every variant the table knows, in the order rows are run. The staggered method with the
#: default Step-2 backend gets 600 s (it is the subject of the study); the others 120 s — the
#: DESIGN notes say IPOPT may never answer on complex shapes and the CasADi Step-2 backends
#: take 0.5–4 s per fit.
VARIANTS: dict[str, Variant] = {v.key: v for v in (
    Variant(REFERENCE, "staggered", "active-set", _staggered("active-set"), 600.0),
    Variant("staggered-coupled/active-set", "staggered (coupled)", "active-set",
            _staggered("active-set", coupled=True), 600.0),
    Variant("staggered-refine/active-set", "staggered + refine (20)", "active-set",
            _staggered("active-set", refine=20), 600.0),
    Variant("staggered/active-set-centred", "staggered", "active-set-centred", _staggered("active-set-centred"),
            600.0),
    Variant("staggered/active-set-centred-all", "staggered", "active-set-centred-all",
            _staggered("active-set-centred-all"), 600.0),
    Variant("staggered/ipopt", "staggered", "ipopt", _staggered("ipopt"), 120.0),
    Variant("staggered/osqp", "staggered", "osqp", _staggered("osqp"), 120.0),
    Variant("staggered/nlopt", "staggered", "nlopt", _staggered("nlopt"), 120.0),
    Variant("simultaneous/ipopt", "simultaneous", "ipopt (cold)", _simultaneous(), 120.0),
    Variant("simultaneous/ipopt-warm", "simultaneous", "ipopt (warm from staggered)", _simultaneous(), 120.0,
            warm_start=True),
    # the refinement's objective (distance to the reference *surface*) rather than to its vertices:
    # the like-for-like comparison for staggered-refine
    Variant("simultaneous/ipopt-surface-warm", "simultaneous", "ipopt (surface objective, warm)", _simultaneous(),
            120.0, warm_start=True, solve_kw=(("objective", SURFACE_OBJECTIVE),)),
    # the weight regulariser raised from 1e-6 to 1 (the objective then sees the weights' null space,
    # m − 3·n_free directions, where IPOPT's steps were unbounded): a slightly different problem,
    # its share of the objective reported
    Variant("simultaneous/ipopt-reg1", "simultaneous", "ipopt (weight reg. 1, cold)",
            _simultaneous(weight_regularization=1.0), 300.0),
    Variant("simultaneous/ipopt-reg1-warm", "simultaneous", "ipopt (weight reg. 1, warm)",
            _simultaneous(weight_regularization=1.0), 300.0, warm_start=True),
    # ... and the homotopy that ends at the stated problem: regulariser 1, 1e-2, 1e-4, then the default
    Variant("simultaneous/ipopt-homotopy", "simultaneous", "ipopt (homotopy in the weight reg., cold)",
            _simultaneous(continuation=HOMOTOPY), 300.0),
    Variant("simultaneous/ipopt-homotopy-warm", "simultaneous", "ipopt (homotopy in the weight reg., warm)",
            _simultaneous(continuation=HOMOTOPY), 300.0, warm_start=True),
    Variant("simultaneous/nlopt", "simultaneous", "nlopt", _nlopt, 120.0),
)}


# ------------------------------------------------------------------------ worker side
def _loads(scene):
    from selfsupport.api import scene_loads

    return scene_loads(scene)


def _warmup(variant: Variant) -> None:
    """Solve a tiny dome with the same method: loads solver plug-ins and caches (untimed)."""
    from selfsupport.core.errors import SelfSupportError
    from selfsupport.core.shapes import make_shape

    scene = make_shape("dome", n_vertices=60)
    try:
        variant.make().solve(scene, _loads(scene), time_limit=30.0)
    except SelfSupportError:
        pass  # e.g. nlopt "not applicable": the real solve says so again


def solve_row(*, scenes_dir: str, scene_name: str, variant: str, out_json: str, time_limit: float,
              warm_from: str | None = None, warmup: bool = True, repeat: int = 1,
              objective: Sequence[str] | None = None) -> dict[str, Any]:
    """Worker: solve one scene with one variant, save the network, return the row's numbers.

    Runs in its own process (see :func:`studies.common.run_isolated`). The time is the
    ``solve()`` call alone; the scene is read and the warm-up solve done before the clock starts.
    """
    from selfsupport.core.errors import BackendUnavailable
    from selfsupport.io import read_network, write_network

    v = VARIANTS[variant]
    scene = read_study_scene(scenes_dir, scene_name)
    loads = _loads(scene)
    row: dict[str, Any] = {"vertices": scene.mesh.n_vertices, "edges": scene.mesh.n_edges}
    kw: dict[str, Any] = {"time_limit": float(time_limit), **dict(v.solve_kw)}
    if objective:  # the same objective for every method ("NAME=W" items, formulations.TERMS)
        kw["objective"] = list(objective)
    if v.warm_start:
        if warm_from and Path(warm_from).is_file():
            kw["warm_start"] = read_network(warm_from)
        else:  # no staggered row to start from: make one (untimed)
            kw["warm_start"] = VARIANTS[REFERENCE].make().solve(scene, loads).network
            row["message"] = "staggered start computed in this row (untimed)"
    try:
        method = v.make()
        if warmup:
            _warmup(v)
        rss0 = current_rss_mib()
        times, networks = [], []
        for _ in range(max(int(repeat), 1)):
            with Stopwatch() as sw:
                res = method.solve(scene, loads, **kw)
            times.append(sw.seconds)
            networks.append(res.network.vertices)
        if any(not np.array_equal(networks[0], V) for V in networks[1:]):
            row["message"] = "; ".join(m for m in (row.get("message"), "the repeated solves differ") if m)
    except BackendUnavailable as exc:
        return {**row, "status": "not applicable", "message": str(exc), "peak_rss_mib": peak_rss_mib()}
    seconds = float(np.median(times))
    write_network(out_json, res, study={"scene": scene_name, "variant": variant, "solve_seconds": seconds,
                                        "solve_seconds_each": times, "time_limit": time_limit})
    msg = "; ".join(m for m in (row.get("message", ""), res.message) if m)
    return {**row, "status": res.status, "message": msg, "time_s": seconds, "time_min_s": min(times),
            "repeats": len(times), "iterations": res.iterations,
            "reported_error": res.max_relative_error, "min_weight": res.min_weight,
            "dist_ref_mean": res.distance_mean, "dist_ref_max": res.distance_max,
            "regularizer_share": res.parameters.get("regularizer_share"),
            "rss_before_mib": rss0, "peak_rss_mib": peak_rss_mib(), "network": Path(out_json).name}


def published_row(*, scenes_dir: str, scene_name: str, published: str, out_json: str) -> dict[str, Any]:
    """Worker: the paper's own network — weights fitted at fixed positions (``api.check``),
    its distance to the reference, saved as JSON like the solver rows."""
    from selfsupport.api import check
    from selfsupport.core.evidence import distance_stats
    from selfsupport.core.result import Network
    from selfsupport.core.scene import Scene
    from selfsupport.io import read_mesh, write_network

    scene = read_study_scene(scenes_dir, scene_name)
    pub = read_mesh(published, up=PUBLISHED_UP)
    if pub.n_vertices != scene.mesh.n_vertices or pub.faces != scene.mesh.faces:
        return {"status": "not comparable", "message": f"{Path(published).name} does not share the scene's mesh"}
    pscene = Scene(mesh=pub, supports=scene.supports, handles=scene.handles, extra_mass=scene.extra_mass,
                   point_loads=scene.point_loads, name=Path(published).stem)
    rep = check(pscene)
    dm, dx = distance_stats(pub.vertices, scene.mesh)
    net = rep.network
    net = Network(mesh=net.mesh, weights=net.weights, loads=net.loads, supports=net.supports,
                  reference=scene.mesh, handles=net.handles)
    write_network(out_json, net, study={"scene": scene_name, "variant": "published", "source": str(published),
                                        "check_status": rep.fit_status, "check_seconds": rep.seconds})
    return {"vertices": pub.n_vertices, "edges": pub.n_edges,
            "status": "self-supporting" if rep.self_supporting else "not self-supporting",
            "message": f"paper's network {Path(published).name}; weights fitted at fixed positions "
                       f"(check, tol {rep.tol:g}, fit {rep.fit_status}, {rep.seconds:.1f} s)",
            "reported_error": rep.max_relative_error, "min_weight": rep.min_weight,
            "dist_ref_mean": dm, "dist_ref_max": dx, "peak_rss_mib": peak_rss_mib(), "network": Path(out_json).name}


# ------------------------------------------------------------------------ parent side
#: Every column of ``table1.csv``, in order.
COLUMNS: tuple[Column, ...] = (
    Column("scene", "scene"), Column("figure", "figure"), Column("vertices", "V"), Column("edges", "E"),
    Column("method", "method"), Column("backend", "backend"), Column("status", "status"),
    Column("time_s", "time [s]", "{:.2f}"), Column("time_min_s", "fastest [s]", "{:.2f}"),
    Column("repeats", "solves", "{:d}"), Column("paper_time_s", "paper time [s]", "{:.1f}"),
    Column("speedup_vs_paper", "speed-up vs paper", "{:.1f}×"),
    Column("time_vs_staggered", "× staggered", "{:.2f}"),
    Column("iterations", "iterations", "{:d}"), Column("paper_iterations", "paper it.", "{:d}"),
    Column("max_rel_error", "max rel. error", "{:.1e}"), Column("paper_max_rel_error", "paper error", "{:.1e}"),
    Column("median_rel_error", "median rel. error", "{:.1e}"), Column("checker_error", "checker error", "{:.1e}"),
    Column("reported_error", "reported error", "{:.1e}"),
    Column("min_weight", "min w [N/m]", "{:.3g}"),
    Column("regularizer_share", "IPOPT: weight reg. / objective", "{:.1e}"),
    Column("dist_ref_mean", "dist. to ref. mean", "{:.2e}"), Column("dist_ref_max", "dist. to ref. max", "{:.2e}"),
    Column("dist_pub_mean", "vs published mean", "{:.2e}"), Column("dist_pub_max", "vs published max", "{:.2e}"),
    Column("peak_rss_mib", "peak RSS [MiB]", "{:.0f}"), Column("rss_before_mib", "RSS before solve [MiB]", "{:.0f}"),
    Column("time_limit_s", "time limit [s]", "{:g}"), Column("network", "network"), Column("message", "message"),
    *STAMP_COLUMNS,
)
_BY_KEY = {c.key: c for c in COLUMNS}
#: The Markdown's two tables: Table 1 itself, then fidelity, memory and messages.
MD_MAIN = ("scene", "figure", "vertices", "edges", "method", "backend", "status", "time_s", "time_min_s",
           "repeats", "paper_time_s",
           "speedup_vs_paper", "time_vs_staggered", "iterations", "paper_iterations", "max_rel_error",
           "paper_max_rel_error", "min_weight")
MD_MORE = ("scene", "method", "backend", "dist_ref_mean", "dist_ref_max", "dist_pub_mean", "dist_pub_max",
           "median_rel_error", "checker_error", "peak_rss_mib", "rss_before_mib", "message")


def paper_columns(scene_name: str) -> dict[str, Any]:
    """The paper's figure, time, iterations and error for a scene (blank for unknown scenes)."""
    p = PAPER_TABLE1.get(scene_name)
    if p is None:
        return {"figure": "", "paper_time_s": float("nan"), "paper_iterations": None, "paper_max_rel_error": float("nan")}
    return {"figure": p.figure, "paper_time_s": p.time_s, "paper_iterations": p.iterations,
            "paper_max_rel_error": p.max_rel_error}


def _vertex_distance(ours: Path, theirs: np.ndarray) -> tuple[float, float]:
    """Mean / max ``‖v_i − v'_i‖`` over the reference's bounding-box diagonal."""
    import json

    d = json.loads(ours.read_text(encoding="utf-8"))
    V = np.asarray(d["vertices"], float)
    ref = np.asarray(d.get("reference_vertices", d["vertices"]), float)
    diag = float(np.linalg.norm(ref.max(axis=0) - ref.min(axis=0)))
    if V.shape != theirs.shape:
        return float("nan"), float("nan")
    dist = np.linalg.norm(V - theirs, axis=1) / diag
    return float(dist.mean()), float(dist.max())


def _complete(row: dict[str, Any], out: Path, checker: Path | None) -> dict[str, Any]:
    """Independent evidence from the saved JSON: the error column and the checker's opinion."""
    net = row.get("network")
    if net and (out / net).is_file():
        rel = equilibrium_errors(**json_network_arrays(out / net))
        row["max_rel_error"] = float(rel.max()) if rel.size else 0.0
        row["median_rel_error"] = float(np.median(rel)) if rel.size else 0.0
        row["checker_error"] = run_checker(checker, out / net)
    return row


def run_table(*, scenes_dir: Path, out: Path, published_dir: Path | None, variants: Sequence[str],
              scenes: Sequence[str], time_limit: float | None, checker: Path | None, warmup: bool = True,
              repeat: int = 1, objective: Sequence[str] | None = None,
              echo: Callable[[str], None] = print,
              on_scene: Callable[[list[dict[str, Any]]], None] | None = None) -> list[dict[str, Any]]:
    """Run every (scene, variant) row and the published comparisons; return the rows.
    ``on_scene(rows)`` is called after each scene (the CLI rewrites the table then). Every row
    carries :func:`studies.common.run_stamp`, taken at the start."""
    stamp = run_stamp()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for name in scenes:
        scene_rows: list[dict[str, Any]] = []
        ref_json: Path | None = None
        for key in variants:
            v = VARIANTS[key]
            tl = float(time_limit if time_limit is not None else v.time_limit)
            out_json = out / f"{name}__{key.replace('/', '-')}.json"
            out_json.unlink(missing_ok=True)  # a stale file from an earlier run must not pass for this row's
            hard = (max(int(repeat), 1) * 1.5 * tl + 180.0
                    + (VARIANTS[REFERENCE].time_limit if v.warm_start and ref_json is None else 0.0))
            echo(f"[{time.strftime('%H:%M:%S')}] {name} {key} (time limit {tl:g} s) ...")
            r = run_isolated("studies.table1:solve_row",
                             {"scenes_dir": str(scenes_dir), "scene_name": name, "variant": key,
                              "out_json": str(out_json), "time_limit": tl,
                              "warm_from": str(ref_json) if ref_json else None, "warmup": warmup,
                              "repeat": repeat, "objective": list(objective) if objective else None},
                             hard_timeout=hard)
            r.update({"scene": name, "method": v.method, "backend": v.backend, "time_limit_s": tl})
            _complete(r, out, checker)
            if key == REFERENCE and out_json.is_file():
                ref_json = out_json
            echo(f"    {r.get('status')}: time {r.get('time_s', float('nan')):.2f} s, "
                 f"{r.get('iterations', '-')} it, error {r.get('max_rel_error', float('nan')):.2e}"
                 + (f" — {r['message']}" if r.get("message") else ""))
            scene_rows.append(r)
        spec = PAPER_TABLE1.get(name)
        pub_file = published_dir / spec.published if (published_dir and spec and spec.published) else None
        if pub_file is not None and pub_file.is_file():
            out_json = out / f"{name}__published.json"
            r = run_isolated("studies.table1:published_row",
                             {"scenes_dir": str(scenes_dir), "scene_name": name, "published": str(pub_file),
                              "out_json": str(out_json)}, hard_timeout=600.0)
            r.update({"scene": name, "method": "published", "backend": "paper's network, weights fitted"})
            _complete(r, out, checker)
            echo(f"    published {pub_file.name}: {r.get('status')}, error {r.get('max_rel_error', float('nan')):.2e}")
            scene_rows.append(r)
            from selfsupport.io import read_mesh

            theirs = read_mesh(pub_file, up=PUBLISHED_UP).vertices
            for r in scene_rows:
                if r.get("network") and r["method"] != "published":
                    r["dist_pub_mean"], r["dist_pub_max"] = _vertex_distance(out / r["network"], theirs)
        t_ref = next((r.get("time_s") for r in scene_rows
                      if f"{r['method']}/{r['backend']}" == REFERENCE and r.get("status") == "converged"), None)
        for r in scene_rows:
            r.update(paper_columns(name), **stamp)
            r["speedup_vs_paper"] = safe_ratio(r.get("paper_time_s"), r.get("time_s"))
            r["time_vs_staggered"] = safe_ratio(r.get("time_s"), t_ref)
        rows += scene_rows
        if on_scene is not None:
            on_scene(rows)
    return rows


def write_outputs(rows: Sequence[dict[str, Any]], out: Path, *, scenes_dir: Path, variants: Sequence[str]) -> str:
    """``table1.csv`` and ``table1.md``; returns the Markdown."""
    write_csv(out / "table1.csv", rows, COLUMNS)
    notes = [
        "**Times are the `solve()` call alone**: process start-up, imports, file reading and a warm-up "
        "solve of a tiny dome (solver plug-ins loaded) are excluded. Each row runs in its own process; "
        "*time* is the median of the row's *solves* (`--repeat`), *fastest* the quickest of them.",
        "**max rel. error** is recomputed with plain numpy from the saved JSON network (the paper's "
        "Table 1 metric, loads of the network's own geometry); *checker error* is the shared "
        "`check_network.py` on the same file, *reported error* the method's own evidence field.",
        "Distances are relative to the reference's bounding-box diagonal: *to ref.* = vertex to reference "
        "surface; *vs published* = vertex to the same vertex of the paper's network.",
        "*published* rows: the paper's network with weights fitted at fixed positions (`selfsupport.api.check`).",
        "*iterations*: outer iterations (staggered); IPOPT / nlopt iterations summed over the load rounds "
        "(simultaneous). The warm-started IPOPT time excludes the staggered solve it starts from.",
        "*speed-up vs paper* = paper time / our time (paper: Xeon 2.3 GHz); *× staggered* = time / the "
        f"{REFERENCE} time on the same scene.",
        f"Scenes: `{scenes_dir}`; methods: {', '.join(variants)}; machine: {_machine()}; "
        f"load average at the end (1/5/15 min): {load_average()} — a shared machine, timings are noisy.",
    ]
    main_cols = [_BY_KEY[k] for k in MD_MAIN]
    more_cols = [_BY_KEY[k] for k in MD_MORE]
    return write_markdown(out / "table1.md", "Table 1 — reproduced", notes,
                          [("Time, iterations, error", rows, main_cols),
                           ("Fidelity, memory, messages", rows, more_cols)])


def _machine() -> str:
    import os
    import platform

    return f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m studies.table1", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", required=True, type=Path, help="folder with the paper's scenes (lilium.sss, ...)")
    p.add_argument("--out", required=True, type=Path, help="output folder (table1.csv, table1.md, networks)")
    p.add_argument("--published", type=Path, default=None,
                   help="folder with the paper's networks (default: SCENES/../published, i.e. "
                        "../shared/paper-scenes/published for the usual --scenes)")
    p.add_argument("--methods", nargs="+", default=list(VARIANTS), metavar="METHOD/BACKEND",
                   help=f"variants to run (comma or space separated; default all): {', '.join(VARIANTS)}")
    p.add_argument("--time-limit", type=float, default=None,
                   help="time limit per row [s] (default: 600 for staggered/active-set, 120 for the others)")
    p.add_argument("--only", default=None, help="comma-separated scene names (file stems); default: every "
                                                "Table 1 scene found in --scenes, or, with none there, every "
                                                "scene file in it")
    p.add_argument("--checker", type=Path, default=None,
                   help="independent checker script (default: SCENES/../../tools/check_network.py if present)")
    p.add_argument("--no-warmup", action="store_true", help="skip the untimed warm-up solve in each row process")
    p.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="solve each row N times in its process and report the median time (and the fastest)")
    p.add_argument("--objective", action="append", default=[], metavar="NAME=WEIGHT",
                   help="objective term for every method, repeatable (formulations.TERMS; default: each "
                        "method's own)")
    return p


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Run the study; returns the rows (also written to ``--out``)."""
    a = build_parser().parse_args(argv)
    if a.repeat < 1:
        raise SystemExit(f"--repeat needs a positive number of solves, got {a.repeat}")
    variants = [m for item in a.methods for m in item.split(",") if m]
    unknown = [m for m in variants if m not in VARIANTS]
    if unknown:
        raise SystemExit(f"unknown method(s) {unknown}; choose from {', '.join(VARIANTS)}")
    scenes = study_scenes_or_exit(a.scenes, [s for s in (a.only or "").split(",") if s])
    missing = []
    for s in scenes:
        try:
            scene_file(a.scenes, s)
        except FileNotFoundError as e:
            missing.append(str(e))
    if missing:
        raise SystemExit("; ".join(missing))
    # run the reference variant first in each scene: warm starts and ratios refer to it
    variants.sort(key=lambda m: m != REFERENCE)
    published = a.published if a.published is not None else a.scenes.resolve().parent / "published"
    checker = a.checker if a.checker is not None else a.scenes.resolve().parent.parent / "tools" / "check_network.py"
    rows = run_table(scenes_dir=a.scenes.resolve(), out=a.out.resolve(), published_dir=published,
                     variants=variants, scenes=scenes, time_limit=a.time_limit,
                     checker=checker if checker.is_file() else None, warmup=not a.no_warmup, repeat=a.repeat,
                     objective=a.objective or None,
                     on_scene=lambda rs: write_outputs(rs, a.out, scenes_dir=a.scenes, variants=variants))
    md = write_outputs(rows, a.out, scenes_dir=a.scenes, variants=variants)
    print(md)
    print(f"written: {a.out / 'table1.csv'}, {a.out / 'table1.md'} and the networks beside them")
    return rows


if __name__ == "__main__":  # pragma: no cover
    exit_on_sigterm()  # a killed study stops its running solver process too
    main(sys.argv[1:])
