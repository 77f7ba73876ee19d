"""Peers side by side: selfsupport next to jax-fdm, compas-tna and compas-tno on one problem.

``python -m studies.peers --scenes ../shared/paper-scenes/scenes --out out/peers
[--peers-env DIR] [--time-limit S] [--repeat N] [--problems NAME ...] [--tools NAME ...]``

Every tool gets the same problem (:func:`export_problem`): the reference mesh (vertices,
faces, its edges), the supports, one vertical load per vertex (the project's self-weight,
ρ = 2000 kg/m³, t = 0.1 m, computed once on the reference and then held fixed for everyone)
and the target (the reference itself). Each tool runs in its own process, from a small runner
script (:mod:`studies.peers_runners`) that writes vertices, edges and compression-positive force
densities; :func:`network_metrics` then recomputes for all of them, in one way:

* the max relative equilibrium error (the paper's Table 1 metric, docs/development/design.md) with the
  problem's loads, by the project's :func:`selfsupport.core.evidence.max_relative_error` and again by
  the plain-numpy :func:`studies.common.equilibrium_errors` (the two must agree);
* the mean and max distance of the network's vertices to the reference surface over its
  bounding-box diagonal (:func:`selfsupport.core.evidence.distance_stats`);
* the smallest force density on an edge that carries something (not support to support):
  positive means compression only.

The peers are installed by the study into their own virtual environment (``--peers-env``,
default ``OUT/.venv-peers``), never into the project's. The runs are interleaved — per
problem, each tool in turn, ``--repeat`` rounds — and the table shows median times.

The paper's own C++ code (``--tools original``, built by ``../shared/original-tool/build.sh
OUT``; ``--original-driver OUT``) is compared differently, on the scenes themselves
(:func:`run_original_study`): each tool solves each scene of ``--scenes`` its own way, with its
own loads, alternating with ``selfsupport solve`` round by round, and the table gives CPU
seconds (median of ``--repeat``): the original's to its end and to a max relative error of
1e-3 and 1e-4 (its trace, with the loads of the current geometry), its final error recomputed
from its network file; selfsupport's to 1e-3, 1e-4 and 1e-9 (its history records), of the
whole solve and of the whole process; and the ratios. Without a driver its rows say why.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .common import (
    DEFAULT_CHECKER,
    REPO,
    STAMP_COLUMNS,
    Column,
    equilibrium_errors,
    json_network_arrays,
    load_average,
    run_checker,
    run_stamp,
    safe_ratio,
    scene_read_args,
    study_scenes,
    write_csv,
    write_markdown,
)

RUNNERS = Path(__file__).resolve().parent / "peers_runners"

#: the peers' versions this study was written against (PyPI)
PEER_PACKAGES = ("jax-fdm==0.14.1", "compas-tna==0.9.0", "compas-tno==0.4.0")

#: the problems: name -> (source, largest tool set). A source is a scene in ``--scenes`` or a
#: built-in ``shape:NAME:VERTICES``.
PROBLEMS: dict[str, str] = {
    "vault-pillar": "vault-pillar",
    "pillar_vault-2000": "shape:pillar_vault:2000",
    "lilium": "lilium",
    "pillar_vault-10k": "shape:pillar_vault:10000",
}

#: above this many vertices a problem gets one round, not ``--repeat``
LARGE = 5000


@dataclass(frozen=True)
class Tool:
    """One column of the comparison: a runner script, the environment that runs it, extra
    arguments, and a one-line statement of the problem it solves."""

    name: str
    runner: str
    env: str  # "peers" or "project"
    solves: str
    args: tuple[str, ...] = ()
    #: larger problems are skipped (with this reason) instead of run
    max_vertices: int | None = None
    skip_reason: str = ""


TOOLS: dict[str, Tool] = {t.name: t for t in (
    Tool("selfsupport-free", "selfsupport_runner.py", "project",
         "staggered: positions (x, y, z) and w ≥ ε; min distance to the reference surface s.t. equilibrium"),
    Tool("selfsupport-fixed", "selfsupport_runner.py", "project",
         "staggered with the top view fixed: heights and w ≥ ε; min distance to the reference s.t. equilibrium",
         ("--fixed-top-view",)),
    Tool("jax-fdm", "jaxfdm_runner.py", "peers",
         "FDM: unknowns q ≤ 0 (x, y, z follow from q, plan free); min Σ (z − z_target)² over free vertices, L-BFGS-B"),
    Tool("compas-tna", "tna_runner.py", "peers",
         "TNA, plan fixed: force diagram parallelised to the form (horizontal), one scale to the target's max height (vertical)"),
    Tool("compas-tno", "tno_runner.py", "peers",
         "TNO best fit, plan fixed: q of the independent edges (compression) and support heights; "
         "min Σ (z − z_target)², load-path SDP start, SLSQP",
         max_vertices=500,
         skip_reason="its load-path start is an SDP with an n × n PSD cone (Clarabel: NumericalError after 27 s "
                     "on lilium) and SLSQP is dense"),
)}


# ------------------------------------------------------------------------------ the problem
def export_problem(scene: Any, *, density: float = 2000.0, thickness: float = 0.1) -> dict[str, Any]:
    """The shared problem of a scene as plain JSON data.

    Parameters
    ----------
    scene
        A :class:`selfsupport.core.scene.Scene` (reference mesh, z up, SI units; supports).
    density, thickness
        Of the self-weight (kg/m³, m).

    Returns
    -------
    dict
        ``name``, ``vertices`` (the reference, also the target), ``faces``, ``edges`` (the
        mesh's, in its order), ``supports`` (indices), ``loads`` (signed vertical load per vertex
        [N], negative down: the self-weight on the reference, plus the scene's own extras),
        ``density``, ``thickness``.
    """
    from selfsupport.core.loads import SelfWeight, with_scene_extras

    mesh = scene.mesh
    loads = with_scene_extras(SelfWeight(density=density, thickness=thickness), scene).nodal(mesh, mesh.vertices)
    return {
        "name": scene.name,
        "vertices": np.asarray(mesh.vertices, float).tolist(),
        "faces": [[int(i) for i in f] for f in mesh.faces],
        "edges": np.asarray(mesh.edges, int).tolist(),
        "supports": np.flatnonzero(scene.supports).tolist(),
        "loads": np.asarray(loads, float).tolist(),
        "density": float(density),
        "thickness": float(thickness),
    }


def problem_scene(problem: Mapping[str, Any]) -> Any:
    """The :class:`~selfsupport.core.scene.Scene` of an exported problem (the inverse of
    :func:`export_problem` up to the loads, which a scene does not hold)."""
    from selfsupport.core.mesh import PolyMesh
    from selfsupport.core.scene import Scene

    mesh = PolyMesh.from_faces(np.asarray(problem["vertices"], float), problem["faces"])
    return Scene(mesh=mesh, supports=np.asarray(problem["supports"], int), name=str(problem["name"]))


def read_problem_source(source: str, scenes_dir: Path, name: str) -> Any:
    """A scene from the scenes folder (by stem) or a built-in ``shape:NAME:VERTICES``."""
    if source.startswith("shape:"):
        from selfsupport.core.shapes import make_shape

        _, shape, nv = source.split(":")
        scene = make_shape(shape, n_vertices=int(nv))
        from selfsupport.core.scene import Scene

        return Scene(mesh=scene.mesh, supports=scene.supports, name=name)
    from .common import read_study_scene

    return read_study_scene(scenes_dir, source)


# ------------------------------------------------------------------------------ the metrics
def align_weights(problem_edges: np.ndarray, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """A tool's weights in the problem's edge order (edges matched unordered; an edge the tool
    left out carries 0). Raises ``ValueError`` for an edge that is not in the problem."""
    index = {(min(a, b), max(a, b)): k for k, (a, b) in enumerate(np.asarray(problem_edges, int))}
    w = np.zeros(len(problem_edges))
    for (a, b), x in zip(np.asarray(edges, int).reshape(-1, 2), np.asarray(weights, float)):
        k = index.get((min(a, b), max(a, b)))
        if k is None:
            raise ValueError(f"edge ({a}, {b}) is not an edge of the problem")
        w[k] = x
    return w


def network_metrics(problem: Mapping[str, Any], vertices: np.ndarray, edges: np.ndarray,
                    weights: np.ndarray) -> dict[str, float]:
    """The comparison's numbers for one network, computed the same way for every tool.

    Parameters
    ----------
    problem
        The exported problem (:func:`export_problem`): its loads are the ones balanced.
    vertices, edges, weights
        The tool's network; ``weights`` compression-positive force densities [N/m].

    Returns
    -------
    dict
        ``max_rel_error`` (project's evidence), ``max_rel_error_check`` (plain numpy; equal up
        to rounding), ``dist_mean``, ``dist_max`` (to the reference surface, over its bbox
        diagonal), ``min_w`` (over edges not joining two supports), ``n_tension`` (edges there
        with w < 0), ``xy_drift`` (max horizontal move of a vertex, over the diagonal).
    """
    from selfsupport.core.evidence import distance_stats, max_relative_error
    from selfsupport.core.geometry import bbox_diagonal

    V0 = np.asarray(problem["vertices"], float)
    E = np.asarray(problem["edges"], int).reshape(-1, 2)
    L = np.asarray(problem["loads"], float)
    sup = np.zeros(len(V0), bool)
    sup[np.asarray(problem["supports"], int)] = True
    X = np.asarray(vertices, float)
    w = align_weights(E, edges, weights)
    err = max_relative_error(vertices=X, edges=E, weights=w, loads=L, supports=sup)
    err_check = float(equilibrium_errors(X, E, w, L, sup).max())
    reference = problem_scene(problem).mesh
    d_mean, d_max = distance_stats(X, reference)
    carrying = ~(sup[E[:, 0]] & sup[E[:, 1]])
    diag = bbox_diagonal(V0)
    return {
        "max_rel_error": float(err),
        "max_rel_error_check": err_check,
        "dist_mean": float(d_mean),
        "dist_max": float(d_max),
        "min_w": float(w[carrying].min()) if carrying.any() else float("nan"),
        "n_tension": int((w[carrying] < 0).sum()),
        "xy_drift": float(np.abs(X[:, :2] - V0[:, :2]).max() / diag),
    }


# ------------------------------------------------------------------------------ environments
def ensure_peers_env(env: Path, *, log=print) -> Path:
    """The peers' interpreter, creating ``env`` (``python -m venv`` + pip install of
    :data:`PEER_PACKAGES`) when it has none. Returns ``env/bin/python``."""
    py = env / "bin" / "python"
    if py.is_file() and (env / ".peers-installed").is_file():
        return py
    base = getattr(sys, "_base_executable", None) or sys.executable
    log(f"peers: creating {env} and installing {' '.join(PEER_PACKAGES)} (a few minutes)")
    subprocess.run([base, "-m", "venv", str(env)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "-q", *PEER_PACKAGES], check=True)
    (env / ".peers-installed").write_text("\n".join(PEER_PACKAGES) + "\n", encoding="utf-8")
    return py


def run_tool(tool: Tool, python: Path, problem_path: Path, result_path: Path, *, time_limit: float) -> dict[str, Any]:
    """Run one tool's runner on a problem file; its result dict (``status`` ``killed`` past
    the time limit plus two minutes, ``crashed`` when it wrote nothing)."""
    env = dict(os.environ)
    if tool.env == "project":
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    else:
        env.pop("PYTHONPATH", None)  # the peers' environment must not see the project
    env.setdefault("JAX_PLATFORMS", "cpu")
    result_path.unlink(missing_ok=True)
    cmd = [str(python), str(RUNNERS / tool.runner), str(problem_path), str(result_path),
           "--time-limit", f"{time_limit:g}", *tool.args]
    t0 = time.perf_counter()
    try:
        # the backstop behind the runners' own limits (compas-tna and compas-tno have none)
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=time_limit + 120)
    except subprocess.TimeoutExpired:
        return {"tool": tool.name, "status": "killed", "message": f"no result within {time_limit + 120:g} s",
                "time_s": float("nan")}
    if not result_path.is_file():
        last = (p.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"tool": tool.name, "status": "crashed", "message": f"exit {p.returncode}: {last}", "time_s": float("nan")}
    out = json.loads(result_path.read_text(encoding="utf-8"))
    out["process_s"] = time.perf_counter() - t0
    return out


# ------------------------------------------------------------------------------ the study
COLUMNS = (
    Column("problem", "problem"), Column("vertices", "V"), Column("tool", "tool"), Column("status", "status"),
    Column("time_s", "time [s] (median)", "{:.3g}"), Column("time_ratio", "time / selfsupport free", "{:.3g}"),
    Column("max_rel_error", "max rel. error", "{:.2e}"), Column("dist_mean", "dist. mean / diag", "{:.2e}"),
    Column("dist_max", "dist. max / diag", "{:.2e}"), Column("xy_drift", "plan drift / diag", "{:.2e}"),
    Column("min_w", "min w [N/m]", "{:.3g}"), Column("n_tension", "edges in tension"),
)


def run_study(scenes_dir: Path, out: Path, *, peers_env: Path, problems: Sequence[str], tools: Sequence[str],
              repeat: int, time_limit: float, log=print) -> list[dict[str, Any]]:
    """Export every problem, run every tool on it ``repeat`` times interleaved, recompute the
    metrics; one row per (problem, tool) with the median time, stamped
    (:func:`studies.common.run_stamp`) at the start."""
    stamp = run_stamp()
    out.mkdir(parents=True, exist_ok=True)
    chosen = [TOOLS[t] for t in tools]
    pythons = {"project": Path(sys.executable)}
    if any(t.env == "peers" for t in chosen):
        pythons["peers"] = ensure_peers_env(peers_env, log=log)
    rows: list[dict[str, Any]] = []
    for name in problems:
        scene = read_problem_source(PROBLEMS[name], scenes_dir, name)
        problem = export_problem(scene)
        ppath = out / f"{name}.problem.json"
        ppath.write_text(json.dumps(problem), encoding="utf-8")
        runs: dict[str, list[dict[str, Any]]] = {t.name: [] for t in chosen}
        nv = len(problem["vertices"])
        rounds = repeat if nv <= LARGE else 1  # one round where a solve takes minutes
        for tool in chosen:
            if tool.max_vertices is not None and nv > tool.max_vertices:
                runs[tool.name].append({"status": "skipped", "time_s": float("nan"),
                                        "message": f"not run above {tool.max_vertices} vertices: {tool.skip_reason}"})
        for r in range(rounds):
            for tool in chosen:  # interleaved: each tool once per round
                if runs[tool.name] and runs[tool.name][0]["status"] == "skipped":
                    continue
                rpath = out / f"{name}.{tool.name}.json"
                res = run_tool(tool, pythons[tool.env], ppath, rpath, time_limit=time_limit)
                runs[tool.name].append(res)
                log(f"peers: {name} round {r + 1}/{rounds} {tool.name}: {res.get('status')} "
                    f"{res.get('time_s', float('nan')):.3g} s")
        base = None
        for tool in chosen:
            results = runs[tool.name]
            last = results[-1]
            times = [float(x.get("time_s", float("nan"))) for x in results]
            times = [t for t in times if t == t]
            row: dict[str, Any] = {"problem": name, "vertices": nv, "tool": tool.name,
                                   "status": last.get("status"), "message": last.get("message", ""),
                                   "solves": tool.solves, "times_s": times,
                                   "time_s": statistics.median(times) if times else float("nan"), **stamp}
            if last.get("vertices"):
                row.update(network_metrics(problem, np.asarray(last["vertices"], float),
                                           np.asarray(last["edges"], int), np.asarray(last["weights"], float)))
            if tool.name == "selfsupport-free":
                base = row["time_s"]
            rows.append(row)
        for row in rows:
            if row["problem"] == name:
                row["time_ratio"] = row["time_s"] / base if base and row["time_s"] == row["time_s"] else float("nan")
    return rows


def write_outputs(out: Path, rows: list[dict[str, Any]], *, repeat: int, time_limit: float) -> str:
    """``peers.json`` (every row in full), ``peers.csv`` (the table's columns, the message and the
    stamp) and ``peers.md`` (the table and what each tool solves)."""
    (out / "peers.json").write_text(json.dumps(rows, indent=1, default=float), encoding="utf-8")
    write_csv(out / "peers.csv", rows, (*COLUMNS, Column("message", "message"), *STAMP_COLUMNS))
    notes = [f"{repeat} interleaved round(s) per problem, median wall time of the solve (imports and file I/O "
             f"excluded; jax-fdm's includes its JIT compilation); time limit {time_limit:g} s; load average {load_average()}",
             "loads: the project's self-weight (2000 kg/m³, 0.1 m) on the reference, held fixed for every tool; "
             "target: the reference; error: the paper's Table 1 metric with those loads, recomputed from each tool's "
             "vertices and force densities",
             *[f"{t.name}: {t.solves}" for t in TOOLS.values() if any(r['tool'] == t.name for r in rows)]]
    fails = [f"{r['problem']} / {r['tool']}: {r['status']}: {r['message']}" for r in rows
             if r["status"] in ("failed", "crashed", "killed", "skipped")]
    notes += [f"not in the table: {f}" for f in fails]
    return write_markdown(out / "peers.md", "Peers side by side", notes, [("", rows, COLUMNS)])


# ------------------------------------------------------------------------------ the paper's own code
#: the tool name of the paper's C++ code in ``--tools``
ORIGINAL = "original"
#: the original's stopping rule (the tool's README): its displayed error below 1e-4, or 50 iterations
ORIGINAL_STOP = ("--tol", "1e-4", "--maxit", "50")
#: where ``../shared/original-tool/build.sh OUT`` is looked for when no --original-driver is given
DEFAULT_ORIGINAL_BUILD = REPO.parent / "build" / "original"
#: the errors whose first CPU time is reported for both tools, and selfsupport's convergence
THRESHOLDS = (1e-3, 1e-4)
CONVERGED = 1e-9


def find_original_driver(path: str | Path | None) -> tuple[Path | None, str]:
    """The original tool's driver binary.

    Parameters
    ----------
    path
        The binary itself, or a build folder: ``build.sh``'s ``OUT`` (the driver is in
        ``OUT/build``) or ``OUT/build``. ``None``: :data:`DEFAULT_ORIGINAL_BUILD`.

    Returns
    -------
    tuple
        ``(driver, "")``, or ``(None, reason)`` with the reason in one line.
    """
    where = Path(path) if path is not None else DEFAULT_ORIGINAL_BUILD
    for candidate in (where, where / "driver", where / "build" / "driver"):
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate, ""
    given = "" if path is not None else " (the default build folder)"
    return None, (f"no driver of the original tool at {where}{given}; build it with "
                  "../shared/original-tool/build.sh OUT and pass --original-driver OUT")


def _number(text: str) -> Any:
    """``text`` as an int, else a float, else itself."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_original_result(output: str) -> dict[str, Any]:
    """The ``key=value`` fields of the driver's ``RESULT`` line, numbers as numbers.

    Raises
    ------
    ValueError
        No ``RESULT`` line in ``output``, or one without ``iters``, ``cpu_s`` or
        ``maxrel_consistent`` as numbers.
    """
    line = next((ln for ln in output.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise ValueError("the driver printed no RESULT line")
    fields = {}
    for token in line.split()[1:]:
        key, eq, value = token.partition("=")
        if eq:
            fields[key] = _number(value)
    bad = [k for k in ("iters", "cpu_s", "maxrel_consistent") if not isinstance(fields.get(k), (int, float))]
    if bad:
        raise ValueError(f"the RESULT line has no number for {', '.join(bad)}: {line.strip()}")
    return fields


#: the columns of the driver's trace CSV that the study reads
TRACE_COLUMNS = ("iter", "cpu_s", "maxrel_consistent")


def read_original_trace(path: str | Path) -> list[dict[str, float]]:
    """The driver's per-iteration trace (``OUTPREFIX.trace.csv``): one dict of floats per row.
    ``cpu_s`` is cumulative; ``maxrel_consistent`` is the error with the loads of the current
    geometry. A row that is not all numbers (the half-written last line of a run cut short) is
    left out.

    Raises
    ------
    ValueError
        The file lacks one of :data:`TRACE_COLUMNS`.
    """
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        missing = [c for c in TRACE_COLUMNS if c not in (reader.fieldnames or ())]
        if missing:
            raise ValueError(f"{path}: no column {', '.join(missing)} in the trace")
        rows = []
        for row in reader:
            try:
                rows.append({k: float(row[k]) for k in reader.fieldnames})
            except (TypeError, ValueError):
                continue
    return rows


def cpu_to_reach(points: Iterable[tuple[float, float]], threshold: float) -> float:
    """The first CPU time at which the error fell below ``threshold``.

    Parameters
    ----------
    points
        ``(cpu_seconds, error)`` in the order they happened.
    threshold
        The error to get below (strictly).

    Returns
    -------
    float
        That CPU time, NaN when no point is below it.
    """
    for t, err in points:
        if err < threshold:
            return float(t)
    return float("nan")


def selfsupport_cpu_points(doc: Mapping[str, Any]) -> list[tuple[float, float]]:
    """``(CPU seconds since the solve began, max relative error)`` of a selfsupport network
    file's history records: those with a CPU stamp (``cpu_s``, the fits and the polish of the
    staggered method), measured from ``parameters.cpu.at_entry``. A polish that was not kept
    (its network was discarded) is left out. Empty when the file has no stamps."""
    origin = (doc.get("parameters") or {}).get("cpu", {}).get("at_entry")
    if not isinstance(origin, (int, float)):
        return []
    return [(float(h["cpu_s"]) - origin, float(h["max_rel_error"])) for h in doc.get("history", ())
            if isinstance(h, dict) and isinstance(h.get("cpu_s"), (int, float))
            and isinstance(h.get("max_rel_error"), (int, float)) and h.get("kept", True)]


def _children_cpu() -> float:
    """User + system CPU seconds of this process's finished children."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run_timed(cmd: list[str], time_limit: float, who: str,
               env: Mapping[str, str] | None = None) -> tuple[subprocess.CompletedProcess | None, float, dict | None]:
    """Run ``cmd`` (in ``env``, default this process's) with ``time_limit`` + 120 s to spare:
    ``(process, its CPU seconds, None)``, or ``(None, nan, a 'killed' row)`` when it ran out of
    that time."""
    c0 = _children_cpu()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=time_limit + 120, env=env)
    except subprocess.TimeoutExpired:
        return None, float("nan"), {"status": "killed", "message": f"{who}: no result within {time_limit + 120:g} s"}
    return p, _children_cpu() - c0, None


def _network_errors(path: Path, checker: Path | None) -> dict[str, float]:
    """Max relative error of a network file with its own loads: by the project's evidence, and
    by the independent checker (NaN without one)."""
    from selfsupport.core.evidence import max_relative_error

    return {"error": float(max_relative_error(**json_network_arrays(path))),
            "error_checker": run_checker(checker, path)}


def original_input(scenes_dir: Path, name: str, work: Path) -> list[str]:
    """The driver's arguments for scene ``name``: a ``.sss`` file as it is, a mesh with the
    paper's vertical axis (−y) with its supports file; any other scene is read as the project
    reads it and written for the original as an OBJ with y down plus a supports file."""
    path, up, supports = scene_read_args(scenes_dir, name)
    if path.suffix.lower() == ".sss":
        return [str(path)]
    if path.suffix.lower() == ".obj" and up == "-y" and supports:
        return [str(path), "--supports", str(supports)]
    from selfsupport.io import write_mesh

    from .common import read_study_scene

    scene = read_study_scene(scenes_dir, name)
    mesh_path, sup_path = work / f"{name}.input.obj", work / f"{name}.input.supports"
    write_mesh(mesh_path, scene.mesh, up="-y")
    sup_path.write_text("\n".join(str(i) for i in np.flatnonzero(scene.supports)) + "\n", encoding="utf-8")
    return [str(mesh_path), "--supports", str(sup_path)]


def run_original(driver: Path, inputs: Sequence[str], prefix: Path, *, time_limit: float,
                 checker: Path | None) -> dict[str, Any]:
    """One run of the original tool (:data:`ORIGINAL_STOP`) on a scene.

    Returns
    -------
    dict
        ``status`` ("displayed tol": the error it displays, with the loads of the geometry before
        its last step, fell below its tolerance; "iteration_limit"; "killed"; "crashed"),
        ``iterations``, ``cpu_s`` (its iterations, to its end), the CPU seconds to each of
        :data:`THRESHOLDS` (``cpu_to_1e-03`` …; from its trace), ``error`` and ``error_checker``
        (recomputed from its network file, loads of the final geometry), ``error_driver`` (its
        own RESULT line) and ``process_cpu_s``.
    """
    for suffix in (".json", ".trace.csv"):
        Path(f"{prefix}{suffix}").unlink(missing_ok=True)
    cmd = [str(driver), inputs[0], str(prefix), *ORIGINAL_STOP, "--quiet", *inputs[1:]]
    p, cpu, killed = _run_timed(cmd, time_limit, "the original")
    if killed:
        return killed
    try:
        res = parse_original_result(p.stdout + p.stderr)
        points = [(r["cpu_s"], r["maxrel_consistent"]) for r in read_original_trace(f"{prefix}.trace.csv")]
    except (OSError, ValueError) as exc:
        last = (p.stderr.strip().splitlines() or [str(exc)])[-1]
        return {"status": "crashed", "message": f"the original: exit {p.returncode}: {last}"}
    out = {"status": "displayed tol" if res.get("converged") == 1 else "iteration_limit", "iterations": res["iters"],
           "cpu_s": float(res["cpu_s"]), "error_driver": float(res["maxrel_consistent"]), "process_cpu_s": cpu,
           **{f"cpu_to_{t:.0e}": cpu_to_reach(points, t) for t in THRESHOLDS}}
    return {**out, **_network_errors(Path(f"{prefix}.json"), checker)}


def selfsupport_env() -> dict[str, str]:
    """The environment of the timed ``selfsupport`` processes: this one's, with the project's
    bytecode read from and written to its ``__pycache__`` folders even where
    ``PYTHONDONTWRITEBYTECODE`` is set. An installed package is compiled once, at install; with
    the variable set, each process would compile the project's ~80 modules from source again
    (~0.15 s of a process's CPU), a cost of this checkout, not of the tool."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def compile_project() -> bool:
    """Compile the project's modules once (``compileall``, untimed), as an install does. True
    when that succeeded (a read-only checkout cannot keep its bytecode: then every timed
    process compiles, as before)."""
    p = subprocess.run([sys.executable, "-m", "compileall", "-q", str(REPO / "selfsupport"),
                        str(REPO / "formulations")], env=selfsupport_env(), capture_output=True, text=True)
    return p.returncode == 0


def selfsupport_command() -> list[str]:
    """``selfsupport`` of this interpreter's environment (its console script, else ``-m``)."""
    script = Path(sys.executable).parent / "selfsupport"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "selfsupport"]


def run_selfsupport(scenes_dir: Path, name: str, net: Path, *, time_limit: float,
                    checker: Path | None) -> dict[str, Any]:
    """One ``selfsupport solve`` of a scene in its own process, with the default method.

    Returns
    -------
    dict
        ``status``, ``method``, ``iterations``, the CPU seconds from the solve's start to each of
        :data:`THRESHOLDS` and to :data:`CONVERGED` (``cpu_to_1e-03`` …; from the history
        records), ``solve_cpu_s`` (the whole solve), ``process_cpu_s`` (the whole process:
        start-up, reading, solving, writing), ``error`` and ``error_checker`` (recomputed from
        the network file).
    """
    path, up, supports = scene_read_args(scenes_dir, name)
    net.unlink(missing_ok=True)
    cmd = [*selfsupport_command(), "solve", str(path), *([f"--up={up}"] if up else []),
           *(["--supports", str(supports)] if supports else []), "--out", str(net), "--time-limit", f"{time_limit:g}"]
    p, cpu, killed = _run_timed(cmd, time_limit, "selfsupport", env=selfsupport_env())
    if killed:
        return killed
    if not net.is_file():
        last = (p.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"status": "crashed", "message": f"selfsupport: exit {p.returncode}: {last}"}
    doc = json.loads(net.read_text(encoding="utf-8"))
    points = selfsupport_cpu_points(doc)
    solve_cpu = (doc.get("parameters") or {}).get("cpu", {}).get("solve", float("nan"))
    return {"status": doc.get("status"), "method": doc.get("method"), "iterations": doc.get("iterations"),
            "solve_cpu_s": float(solve_cpu), "process_cpu_s": cpu,
            **{f"cpu_to_{t:.0e}": cpu_to_reach(points, t) for t in (*THRESHOLDS, CONVERGED)},
            **_network_errors(net, checker)}


def _median(runs: Sequence[Mapping[str, Any]], key: str) -> float:
    """Median of ``key`` over the runs that have it as a number (NaN: none); a run that never
    reached a threshold (NaN) makes the median NaN only when most runs never reached it."""
    xs = [float(r[key]) for r in runs if isinstance(r.get(key), (int, float))]
    reached = [x for x in xs if not math.isnan(x)]
    return statistics.median(reached) if xs and 2 * len(reached) > len(xs) else float("nan")


def original_row(name: str, orig: Sequence[Mapping[str, Any]], ours: Sequence[Mapping[str, Any]],
                 stamp: Mapping[str, Any]) -> dict[str, Any]:
    """One table row from a scene's runs: medians of the CPU times, the last run's status,
    iterations and errors (both tools are deterministic), the ratios original / selfsupport."""
    row: dict[str, Any] = {"scene": name, "rounds": max(len(orig), len(ours))}
    messages = []
    for tag, runs in (("orig", orig), ("ss", ours)):
        done = [r for r in runs if r.get("status") not in ("killed", "crashed")]
        last = (done or list(runs) or [{}])[-1]
        messages += [r["message"] for r in runs if r.get("message")][-1:]
        row[f"{tag}_status"] = last.get("status", "")
        for key in ("method", "iterations", "error", "error_checker", "error_driver"):
            if key in last:
                row[f"{tag}_{key}"] = last[key]
        for key in {k for r in done for k in r if k.endswith("cpu_s") or k.startswith("cpu_to_")}:
            row[f"{tag}_{key}"] = _median(done, key)
    for t in THRESHOLDS:
        row[f"ratio_{t:.0e}"] = safe_ratio(row.get(f"orig_cpu_to_{t:.0e}"), row.get(f"ss_cpu_to_{t:.0e}"))
    converged = row.get("ss_status") == "converged" and row.get("ss_error", 1.0) <= CONVERGED
    row["ratio_solve"] = safe_ratio(row.get("orig_cpu_s"), row.get("ss_solve_cpu_s")) if converged else float("nan")
    row["ratio_process"] = safe_ratio(row.get("orig_cpu_s"), row.get("ss_process_cpu_s"))
    row["message"] = "; ".join(messages)
    return {**row, **stamp}


def run_original_study(scenes_dir: Path, names: Sequence[str], out: Path, *, driver: Path | None, reason: str,
                       repeat: int, time_limit: float, checker: Path | None, log=print) -> list[dict[str, Any]]:
    """The original tool and ``selfsupport solve`` on each scene, alternating (the original
    first in odd rounds, selfsupport first in even ones), ``repeat`` rounds; one row per scene
    (:func:`original_row`), stamped (:func:`studies.common.run_stamp`) at the start. Without a
    driver every row is "skipped" with ``reason`` and nothing runs."""
    stamp = run_stamp()
    if driver is None:
        return [{"scene": name, "orig_status": "skipped", "ss_status": "", "message": reason, **stamp}
                for name in names]
    work = out / "original-runs"
    work.mkdir(parents=True, exist_ok=True)
    if not compile_project():
        log("peers: the project's bytecode could not be written; each selfsupport process compiles it")
    rows = []
    for name in names:
        inputs = original_input(scenes_dir, name, work)
        orig: list[dict[str, Any]] = []
        ours: list[dict[str, Any]] = []
        for r in range(repeat):
            for tool in ("original", "selfsupport") if r % 2 == 0 else ("selfsupport", "original"):
                if tool == "original":
                    res = run_original(driver, inputs, work / f"{name}.original", time_limit=time_limit,
                                       checker=checker)
                    orig.append(res)
                else:
                    res = run_selfsupport(scenes_dir, name, work / f"{name}.selfsupport.json",
                                          time_limit=time_limit, checker=checker)
                    ours.append(res)
                log(f"peers: {name} round {r + 1}/{repeat} {tool}: {res.get('status')} "
                    f"{res.get('cpu_s', res.get('solve_cpu_s', float('nan'))):.3g} CPU s, load {load_average()}")
        row = original_row(name, orig, ours, stamp)
        net = work / f"{name}.selfsupport.json"
        if net.is_file():  # the mesh's size, as the project reads it
            d = json.loads(net.read_text(encoding="utf-8"))
            row.update(vertices=len(d["vertices"]), edges=len(d["edges"]))
        rows.append(row)
    return rows


ORIGINAL_COLUMNS = (
    Column("scene", "scene"), Column("vertices", "V"),
    Column("orig_status", "original: status"), Column("orig_iterations", "it"),
    Column("orig_cpu_s", "CPU s to its end", "{:.3g}"),
    Column("orig_cpu_to_1e-03", "to 1e-3", "{:.3g}"), Column("orig_cpu_to_1e-04", "to 1e-4", "{:.3g}"),
    Column("orig_error", "final error", "{:.1e}"),
    Column("ss_method", "selfsupport: method"), Column("ss_status", "status"), Column("ss_iterations", "it"),
    Column("ss_cpu_to_1e-03", "to 1e-3", "{:.3g}"), Column("ss_cpu_to_1e-04", "to 1e-4", "{:.3g}"),
    Column("ss_cpu_to_1e-09", "to 1e-9", "{:.3g}"), Column("ss_solve_cpu_s", "solve", "{:.3g}"),
    Column("ss_process_cpu_s", "process", "{:.3g}"), Column("ss_error", "error", "{:.1e}"),
    Column("ratio_1e-03", "× to 1e-3", "{:.3g}"), Column("ratio_1e-04", "× to 1e-4", "{:.3g}"),
    Column("ratio_solve", "× solve (original's end / ours to converge)", "{:.3g}"),
    Column("ratio_process", "× process (original's end / our process)", "{:.3g}"),
    *STAMP_COLUMNS,
)
#: the CSV's columns: the table's, then what it leaves out
ORIGINAL_CSV_COLUMNS = (*ORIGINAL_COLUMNS, Column("edges", "E"), Column("rounds", "rounds"),
                        Column("orig_error_checker", ""), Column("orig_error_driver", ""),
                        Column("orig_process_cpu_s", ""), Column("ss_error_checker", ""), Column("message", ""))


def write_original_outputs(out: Path, rows: list[dict[str, Any]], *, repeat: int, time_limit: float) -> str:
    """``original.csv`` (every column, full precision) and ``original.md`` (the table)."""
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "original.csv", rows, ORIGINAL_CSV_COLUMNS)
    notes = [f"the paper's C++ code (../shared/original-tool, stopping at its displayed error < 1e-4 or 50 "
             f"iterations) and `selfsupport solve` (default method, time limit {time_limit:g} s), alternating "
             f"scene by scene, {repeat} round(s); CPU seconds, medians",
             "original: CPU of its iterations to its end and to a max relative error of 1e-3 / 1e-4 with the loads "
             "of the current geometry (its trace); final error recomputed from its network file (loads of the "
             "final geometry)",
             "selfsupport: CPU from the solve's start to 1e-3 / 1e-4 / 1e-9 (its history records), of the whole "
             "solve, and of the whole process (start-up, reading, writing; the project's bytecode compiled once "
             "beforehand, as an install has it); error recomputed from its network file",
             "original status \"displayed tol\": the error it displays (loads of the geometry before its last "
             "step) fell below 1e-4; the final error, with the loads of the final geometry, can be larger",
             "× columns: original / selfsupport; an empty time: that error was never reached"]
    by_message: dict[str, list[str]] = {}
    for r in rows:
        if r.get("message"):
            by_message.setdefault(r["message"], []).append(r["scene"])
    notes += [f"{', '.join(scenes)}: {message}" for message, scenes in by_message.items()]
    return write_markdown(out / "original.md", "The paper's original code side by side", notes,
                          [("", rows, ORIGINAL_COLUMNS)])


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.peers", description=__doc__.splitlines()[0])
    p.add_argument("--scenes", required=True, help="the paper's scenes folder (../shared/paper-scenes/scenes)")
    p.add_argument("--out", default="out/peers")
    p.add_argument("--peers-env", default=None, help="the peers' virtual environment (default OUT/.venv-peers)")
    p.add_argument("--time-limit", type=float, default=300.0, help="per solve [s]")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    p.add_argument("--tools", nargs="+", default=[*TOOLS, ORIGINAL], choices=[*TOOLS, ORIGINAL])
    p.add_argument("--original-driver", default=None,
                   help="the original tool's driver, or the folder build.sh built it in "
                        f"(default {DEFAULT_ORIGINAL_BUILD}); without one its rows say so")
    p.add_argument("--only", nargs="+", default=None,
                   help="scenes (file stems) for the original tool (default: the Table 1 scenes in --scenes, "
                        "else every scene file there)")
    p.add_argument("--checker", default=str(DEFAULT_CHECKER),
                   help="the independent check_network.py (its error is in original.csv)")
    a = p.parse_args(argv)
    scenes = Path(a.scenes)
    if not scenes.is_dir():
        print(f"peers: error: no scenes folder at {scenes}", file=sys.stderr)
        return 2
    if a.repeat < 1 or a.time_limit <= 0:
        print("peers: error: --repeat must be at least 1 and --time-limit positive", file=sys.stderr)
        return 2
    names = study_scenes(scenes, a.only) if ORIGINAL in a.tools else []
    if ORIGINAL in a.tools and not names:
        print(f"peers: error: no scene file in {scenes} for the original tool; give a folder of .sss/.obj scenes",
              file=sys.stderr)
        return 2
    out = Path(a.out)
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    tools = [t for t in a.tools if t != ORIGINAL]
    if tools:
        env = Path(a.peers_env) if a.peers_env else out / ".venv-peers"
        rows = run_study(scenes, out, peers_env=env.absolute(), problems=a.problems, tools=tools, repeat=a.repeat,
                         time_limit=a.time_limit, log=log)
        print(write_outputs(out, rows, repeat=a.repeat, time_limit=a.time_limit))
    if names:
        driver, reason = find_original_driver(a.original_driver)
        checker = Path(a.checker) if a.checker else None
        rows = run_original_study(scenes, names, out, driver=driver, reason=reason, repeat=a.repeat,
                                  time_limit=a.time_limit, checker=checker, log=log)
        print(write_original_outputs(out, rows, repeat=a.repeat, time_limit=a.time_limit))
    return 0


if __name__ == "__main__":
    sys.exit(main())
