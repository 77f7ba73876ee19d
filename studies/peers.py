"""Peers side by side: selfsupport next to jax-fdm, compas-tna and compas-tno on one problem.

``python -m studies.peers --scenes ../shared/paper-scenes/scenes --out out/peers
[--peers-env DIR] [--time-limit S] [--repeat N] [--problems NAME ...] [--tools NAME ...]``

Every tool gets the same problem (:func:`export_problem`): the reference mesh (vertices,
faces, its edges), the supports, one vertical load per vertex (the project's self-weight,
ρ = 2000 kg/m³, t = 0.1 m, computed once on the reference and then held fixed for everyone)
and the target (the reference itself). Each tool runs in its own process, from a small runner
script (:mod:`studies.peers_runners`) that writes vertices, edges and compression-positive force
densities; :func:`network_metrics` then recomputes for all of them, in one way:

* the max relative equilibrium error (DESIGN.md §1, the paper's Table 1 metric) with the
  problem's loads, by the project's :func:`selfsupport.evidence.max_relative_error` and again by
  the plain-numpy :func:`studies.common.equilibrium_errors` (the two must agree);
* the mean and max distance of the network's vertices to the reference surface over its
  bounding-box diagonal (:func:`selfsupport.evidence.distance_stats`);
* the smallest force density on an edge that carries something (not support to support):
  positive means compression only.

The peers are installed by the study into their own virtual environment (``--peers-env``,
default ``OUT/.venv-peers``), never into the project's. The runs are interleaved — per
problem, each tool in turn, ``--repeat`` rounds — and the table shows median times.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .common import Column, equilibrium_errors, load_average, write_markdown

RUNNERS = Path(__file__).resolve().parent / "peers_runners"
REPO = Path(__file__).resolve().parent.parent

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
        A :class:`selfsupport.scene.Scene` (reference mesh, z up, SI units; supports).
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
    from selfsupport.loads import SelfWeight, with_scene_extras

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
    """The :class:`~selfsupport.scene.Scene` of an exported problem (the inverse of
    :func:`export_problem` up to the loads, which a scene does not hold)."""
    from selfsupport.mesh import PolyMesh
    from selfsupport.scene import Scene

    mesh = PolyMesh.from_faces(np.asarray(problem["vertices"], float), problem["faces"])
    return Scene(mesh=mesh, supports=np.asarray(problem["supports"], int), name=str(problem["name"]))


def read_problem_source(source: str, scenes_dir: Path, name: str) -> Any:
    """A scene from the scenes folder (by stem) or a built-in ``shape:NAME:VERTICES``."""
    if source.startswith("shape:"):
        from selfsupport.shapes import make_shape

        _, shape, nv = source.split(":")
        scene = make_shape(shape, n_vertices=int(nv))
        from selfsupport.scene import Scene

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
    from selfsupport.evidence import distance_stats, max_relative_error
    from selfsupport.geometry import bbox_diagonal

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
    metrics; one row per (problem, tool) with the median time."""
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
                                   "time_s": statistics.median(times) if times else float("nan")}
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
    """``peers.json`` (every row in full) and ``peers.md`` (the table and what each tool solves)."""
    (out / "peers.json").write_text(json.dumps(rows, indent=1, default=float), encoding="utf-8")
    notes = [f"{repeat} interleaved round(s) per problem, median wall time of the solve (imports and file I/O "
             f"excluded; jax-fdm's includes its JIT compilation); time limit {time_limit:g} s; load average {load_average()}",
             "loads: the project's self-weight (2000 kg/m³, 0.1 m) on the reference, held fixed for every tool; "
             "target: the reference; error: DESIGN.md §1 metric with those loads, recomputed from each tool's "
             "vertices and force densities",
             *[f"{t.name}: {t.solves}" for t in TOOLS.values() if any(r['tool'] == t.name for r in rows)]]
    fails = [f"{r['problem']} / {r['tool']}: {r['status']}: {r['message']}" for r in rows
             if r["status"] in ("failed", "crashed", "killed", "skipped")]
    notes += [f"not in the table: {f}" for f in fails]
    return write_markdown(out / "peers.md", "Peers side by side", notes, [("", rows, COLUMNS)])


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.peers", description=__doc__.splitlines()[0])
    p.add_argument("--scenes", required=True, help="the paper's scenes folder (../shared/paper-scenes/scenes)")
    p.add_argument("--out", default="out/peers")
    p.add_argument("--peers-env", default=None, help="the peers' virtual environment (default OUT/.venv-peers)")
    p.add_argument("--time-limit", type=float, default=300.0, help="per solve [s]")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    p.add_argument("--tools", nargs="+", default=list(TOOLS), choices=list(TOOLS))
    a = p.parse_args(argv)
    scenes = Path(a.scenes)
    if not scenes.is_dir():
        print(f"peers: error: no scenes folder at {scenes}", file=sys.stderr)
        return 2
    if a.repeat < 1 or a.time_limit <= 0:
        print("peers: error: --repeat must be at least 1 and --time-limit positive", file=sys.stderr)
        return 2
    out = Path(a.out)
    env = Path(a.peers_env) if a.peers_env else out / ".venv-peers"
    rows = run_study(scenes, out, peers_env=env.absolute(), problems=a.problems, tools=a.tools, repeat=a.repeat,
                     time_limit=a.time_limit, log=lambda s: print(s, file=sys.stderr, flush=True))
    print(write_outputs(out, rows, repeat=a.repeat, time_limit=a.time_limit))
    return 0


if __name__ == "__main__":
    sys.exit(main())
