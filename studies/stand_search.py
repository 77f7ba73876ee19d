"""Does a quad design that the staggered method cannot carry under several load cases stand under
them anywhere? IPOPT over every case jointly from several starts.

::

    python -m studies.stand_search --scenes ../shared/paper-scenes/scenes --out out/stand_search \\
        --checker ../shared/tools/check_network.py --only vault-pillar --share 0.05 --time-limit 90

The cases are those of :mod:`studies.load_cases` (its functions build them): empty; snow 80 kg/m²
on all faces; a point load of ``--share`` of the self-weight at the highest free vertex. Snow is
the empty case's loads times a factor at any geometry, so, as every method does
(:func:`selfsupport.methods.base.proportional_members`), IPOPT solves the cases that are
not proportional (empty and point) and the snow case's network is the empty one's weights times
that factor (:func:`~selfsupport.methods.base.with_members`), re-measured at the result.

Each start is one run of the project's simultaneous method (:class:`selfsupport.methods.simultaneous.Simultaneous`,
its defaults: the default compression bound ε, no upper bound, IPOPT's ``tol`` 1e-9 and at most
3000 iterations per load round, the loads re-estimated at each round's geometry until consistent
with it, then the joint polish) with ``--time-limit`` seconds of its own. The starts:

* ``staggered, nearest it``: the staggered method's network over every case (``ipopt_finish=false``,
  the share of the solve's 120 s that the iteration gets before the finish), each case's
  weights; IPOPT seeks the network nearest it (``nearest_to_start``, as the solve's finish does);
* ``staggered, nearest the reference``: the same start, the objective the distance to the reference;
* ``single case``: the converged network of the empty case alone, its weights for every case;
* ``triangulated``: the design split into triangles (``selfsupport solve --triangulate``) solved
  under the three cases: its positions and each case's weights on the quad edges, its diagonals
  dropped (:func:`quad_weights`);
* ``reference``: IPOPT's own cold start (the reference, uniform weights);
* ``perturbed, seed k``: the reference with its free vertices' heights moved by a smooth random
  field (:func:`perturbed_heights`, at most :data:`PERTURBATION` of the span), the cold start's
  uniform weights.

``--max-iter`` raises IPOPT's iteration limit per load round (the method's 3000 end most runs
in 10–35 s on vault-pillar, well inside ``--time-limit``: with a higher one the time limit ends
them); ``--eps`` states the lower weight bound (zero or below, e.g. ``--eps=-1e12``: tension
allowed; no case is then carried by another's scaled weights, and the checker runs with
``--allow-tension``); ``--warm-barrier low`` starts IPOPT's barrier low from every start (the
method's ``warm_barrier``: the start kept rather than first pushed off its bounds).
``--control`` runs the same starts on a design that is known to stand under the cases
(:func:`write_control`): how far IPOPT's verdicts from these starts can be trusted.

Per start: the method's status and IPOPT's last status, IPOPT's iterations, seconds, every case's
max relative error with loads of the final geometry, the free vertices' mean and max distance to
the reference [m] and the network's mean and max distance to the reference surface over the
bounding-box diagonal, the least weight against ε and, for a network that converged or is in
equilibrium for every case to 1e-8, the independent checker's max relative error per case on the
written network JSON (its verdict at 1e-8). Writes
``stand_search-SCENE-SHARE.csv``, ``.md`` and ``.json`` (what building the starts measured; with
``--max-iter`` / ``--eps`` in the name) and every start's network to ``--out``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from formulations import LoadCases, Problem
from selfsupport import api
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io.network_json import write_network
from selfsupport.io.problem import problem as build_problem
from selfsupport.io.sss import write_scene_sss
from selfsupport.methods.base import proportional_members
from selfsupport.methods.simultaneous import COLD_START_FACTOR, WARM_BARRIERS, Simultaneous
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.methods.staggered.cases import FINISH_SHARE
from studies.common import DEFAULT_CHECKER, STAMP_COLUMNS, Column, run_stamp, vault_pillar_layout, write_csv, write_markdown
from studies.load_cases import TIME_LIMIT, checked, highest_free_and_weight, three_cases, toml_text

#: Largest height change of a perturbed start, relative to the span (the bounding box's largest
#: horizontal side).
PERTURBATION = 0.03
#: Seeds of the perturbed starts.
SEEDS = (0, 1, 2, 3, 4)
#: Per-start time limit [s] (IPOPT's wall time over all its load rounds, and the polish).
START_TIME_LIMIT = 90.0
#: The verdict's threshold on every case's max relative error (the independent checker's ``--tol``).
STANDS_TOL = 1e-8

COLUMNS = (Column("scene", "scene"), Column("point_share", "point share", "{:.0%}"), Column("start", "start"),
           Column("start_error", "start: max rel. error", "{:.1e}"),
           Column("status", "status"), Column("ipopt_status", "IPOPT's last status"),
           Column("iterations", "IPOPT iterations", "{:d}"), Column("rounds", "load rounds", "{:d}"),
           Column("seconds", "seconds", "{:.0f}"),
           Column("error_empty", "empty", "{:.1e}"), Column("error_snow", "snow", "{:.1e}"),
           Column("error_point", "point", "{:.1e}"),
           Column("moved_mean_m", "mean distance to ref. [m]", "{:.3g}"),
           Column("moved_max_m", "max distance to ref. [m]", "{:.3g}"),
           Column("distance_mean", "mean / bbox diag.", "{:.1e}"), Column("distance_max", "max / bbox diag.", "{:.1e}"),
           Column("min_weight", "min weight [N/m]", "{:.3g}"), Column("eps", "ε [N/m]", "{:.3g}"),
           Column("checker", "checker (max over cases)", "{:.1e}"), Column("stands", "stands")) + STAMP_COLUMNS


def quad_weights(split_edges: np.ndarray, split_weights: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The weights of a network on a mesh split into triangles over the edges of the mesh before
    the split: each edge ``(i, j)`` of ``edges`` takes the weight of the same pair among
    ``split_edges`` (either order); the diagonals the split added are dropped.

    Parameters
    ----------
    split_edges
        ``(m', 2)`` vertex pairs of the split mesh (every edge of ``edges`` among them).
    split_weights
        ``(m',)`` or ``(C, m')`` weights on ``split_edges`` (one row per load case).
    edges
        ``(m, 2)`` vertex pairs of the mesh before the split.

    Returns
    -------
    numpy.ndarray
        ``(m,)`` or ``(C, m)`` weights on ``edges``. Where the dropped diagonals' weights were
        zero, every vertex's force balance is the split network's.

    Raises
    ------
    ValueError
        An edge of ``edges`` that is not an edge of the split mesh.
    """
    index = {(int(min(a, b)), int(max(a, b))): k for k, (a, b) in enumerate(np.asarray(split_edges))}
    pairs = [(int(min(a, b)), int(max(a, b))) for a, b in np.asarray(edges)]
    missing = [p for p in pairs if p not in index]
    if missing:
        raise ValueError(f"{len(missing)} edge(s) are not edges of the split mesh, e.g. {missing[0]}")
    return np.asarray(split_weights, float)[..., [index[p] for p in pairs]]


def quads_start(res: SolveResult, scene: Any, split_edges: np.ndarray, names: tuple[str, ...]) -> SolveResult:
    """A start on the design ``scene`` from a network ``res`` of its split mesh (edges
    ``split_edges``): its positions, and each of the cases ``names``' weights on the design's edges
    (:func:`quad_weights`, the diagonals dropped) with that case's loads."""
    nets = dict(res.case_networks)
    mesh = scene.mesh.with_vertices(res.network.vertices)
    cases = tuple((n, Network(mesh=mesh, weights=quad_weights(split_edges, nets[n].weights, scene.mesh.edges),
                              loads=nets[n].loads, supports=scene.supports, reference=scene.mesh)) for n in names)
    return SolveResult.build(cases[0][1], cases=cases, status=res.status, method=res.method, backend="",
                             iterations=0, wall_time=0.0)


def write_control(folder: Path, n: int = 10, span: float = 3.0) -> Path:
    """The control: the tests' free-edged quad vault (``tests/test_load_continuation.py``: an
    ``n`` × ``n`` grid over a paraboloid of rise 1 m, the paper's vault-pillar layout of
    :func:`studies.common.vault_pillar_layout`), which the staggered iteration carries under the
    self-weight and a 5% point load at its highest free vertex, written as ``.sss`` to ``folder``."""
    t = np.linspace(-0.5, 0.5, n) * span
    x, y = np.meshgrid(t, t)
    V = np.column_stack([x.ravel(), y.ravel(), 1.0 - 0.15 * (x ** 2 + y ** 2).ravel()])
    sup, quads = vault_pillar_layout(n)
    path = folder / "free-edged-quad-vault.sss"
    write_scene_sss(path, Scene(PolyMesh.from_faces(V, quads), sup, name="free-edged quad vault"))
    return path


def perturbed_heights(vertices: np.ndarray, free: np.ndarray, amplitude: float, seed: int) -> np.ndarray:
    """``vertices`` with the heights of the ``free`` ones moved by a smooth random field: a sum of
    the plan's cosine modes ``cos(k π u) cos(l π v)`` (``k, l`` in 1..3, ``u, v`` the plan
    coordinates over the bounding box) with standard normal coefficients drawn with ``seed``,
    scaled to a largest change of ``amplitude`` [m]."""
    V = np.array(vertices, float)
    lo, hi = V[:, :2].min(axis=0), V[:, :2].max(axis=0)
    uv = (V[:, :2] - lo) / np.where(hi > lo, hi - lo, 1.0)
    coef = np.random.default_rng(seed).standard_normal((3, 3))
    field = sum(coef[k - 1, m - 1] * np.cos(k * np.pi * uv[:, 0]) * np.cos(m * np.pi * uv[:, 1])
                for k in range(1, 4) for m in range(1, 4))
    field = field[free]
    V[free, 2] += amplitude * field / np.abs(field).max()
    return V


def cold_weights(problem: Problem, vertices: np.ndarray) -> np.ndarray:
    """The simultaneous method's own cold-start weight (uniform, :data:`COLD_START_FACTOR` of its
    natural weight scale at ``vertices``) on every edge [N/m], for a start it is given as a network."""
    form, sc = Simultaneous.formulation(problem, vertices)
    return np.full(problem.scene.mesh.n_edges, float(sc.weight_back(COLD_START_FACTOR * form.weight_scale)))


def triangulated_start(path: Path, toml: Path, scene: Any, problem: Problem, time_limit: float,
                       eps: float | None = None) -> tuple[SolveResult | None, dict[str, Any]]:
    """The design split into triangles solved under the cases (the staggered method, as
    ``selfsupport solve --triangulate``, lower bound ``eps``), and a start on the quads: its
    positions and each of ``problem``'s cases' weights on the quad edges (:func:`quad_weights`)."""
    tri = api.triangulated_design(str(path))
    t0 = time.perf_counter()
    res = StaggeredLinearization().solve(build_problem(tri, load_cases=str(toml), eps=eps), {"time_limit": time_limit})
    info = {"status": res.status, "max_relative_error": res.max_relative_error,
            "seconds": round(time.perf_counter() - t0, 1)}
    return quads_start(res, scene, tri.mesh.edges, problem.loads.names), info


def starts(path: Path, toml: Path, problem: Problem, seeds: tuple[int, ...], eps: float | None = None,
           log: Any = print) -> tuple[list[tuple[str, SolveResult | Network | None, bool]], dict[str, Any]]:
    """The study's starts ``(label, warm start, nearest_to_start)`` for IPOPT over ``problem``,
    and what building them measured."""
    scene = problem.scene
    info: dict[str, Any] = {}
    stag_limit = TIME_LIMIT * (1 - FINISH_SHARE)
    stall = StaggeredLinearization().solve(problem, {"ipopt_finish": False, "time_limit": stag_limit})
    info["staggered"] = {"status": stall.status, "max_relative_error": stall.max_relative_error,
                         "seconds": round(stall.wall_time, 1), "time_limit": stag_limit}
    log(json.dumps({"staggered": info["staggered"]}))
    single_problem = dataclasses.replace(problem, loads=LoadCases(problem.loads.cases[:1]))
    single = StaggeredLinearization().solve(single_problem, {"time_limit": TIME_LIMIT})
    info["single"] = {"status": single.status, "max_relative_error": single.max_relative_error,
                      "seconds": round(single.wall_time, 1)}
    log(json.dumps({"single": info["single"]}))
    tri, info["triangulated"] = triangulated_start(path, toml, scene, problem, TIME_LIMIT, eps)
    log(json.dumps({"triangulated": info["triangulated"]}))
    V = scene.mesh.vertices
    span = float((V[:, :2].max(axis=0) - V[:, :2].min(axis=0)).max())
    out: list[tuple[str, SolveResult | Network | None, bool]] = [
        ("staggered, nearest it", stall, True), ("staggered, nearest the reference", stall, False),
        ("single case", single.network, False), ("triangulated", tri, False), ("reference", None, False)]
    for seed in seeds:
        Vp = perturbed_heights(V, scene.free, PERTURBATION * span, seed)
        out.append((f"perturbed, seed {seed}", Network(mesh=scene.mesh.with_vertices(Vp), weights=cold_weights(problem, Vp),
                                                       loads=np.zeros(len(V)), supports=scene.supports,
                                                       reference=scene.mesh), False))
    return out, info


def start_error(start: SolveResult | Network | None) -> float | None:
    """A start's own max relative error (over its cases), ``None`` for the cold start or a network
    without loads."""
    if isinstance(start, SolveResult):
        return max(n.max_relative_error() for _, n in start.case_networks)
    return None


def run_start(problem: Problem, start: SolveResult | Network | None, nearest: bool, time_limit: float,
              max_iter: int | None = None, warm_barrier: str = "auto") -> SolveResult:
    """IPOPT over ``problem``'s cases from ``start`` (the simultaneous method; ``max_iter``: its
    iteration limit per load round, ``None`` its default; ``warm_barrier``: its option)."""
    opts = {"warm_start": start, "time_limit": time_limit, "nearest_to_start": nearest,
            "warm_barrier": warm_barrier, **({} if max_iter is None else {"max_iter": max_iter})}
    return Simultaneous().solve(problem, opts)


def row_of(res: SolveResult, scene: Any, net: Path, checker: Path | None, flags: tuple[str, ...] = ()
           ) -> dict[str, Any]:
    """One start's measurements (module docstring); the checker (with ``flags``) runs on a network
    that converged or is in equilibrium for every case to :data:`STANDS_TOL` (a run that ended
    "stalled" because its loads did not settle may still stand)."""
    raw = [h for h in res.history if h.get("stage") == Simultaneous.backend]
    d = np.linalg.norm(res.network.vertices[scene.free] - scene.mesh.vertices[scene.free], axis=1)
    row: dict[str, Any] = {
        "status": res.status, "ipopt_status": raw[-1]["solver_status"] if raw else None,
        "iterations": res.iterations, "rounds": len(raw), "seconds": round(res.wall_time, 1),
        **{f"error_{name}": n.max_relative_error() for name, n in res.case_networks},
        "moved_mean_m": float(d.mean()), "moved_max_m": float(d.max()), "distance_mean": res.distance_mean,
        "distance_max": res.distance_max, "min_weight": res.min_weight, "eps": res.parameters.get("eps"),
        "message": res.message}
    write_network(net, res)
    if checker is not None and (res.status == "converged"
                                or max(n.max_relative_error() for _, n in res.case_networks) <= STANDS_TOL):
        errs = checked(net, checker, list(flags))
        row["checker"] = max(errs.values())
        row["checker_errors"] = errs
        row["stands"] = bool(all(e <= STANDS_TOL for e in errs.values()))
    else:
        row["stands"] = False
    return row


def run_tag(max_iter: int | None, eps: float | None, warm_barrier: str = "auto") -> str:
    """The file names' tag of a run's options beyond the defaults.

    >>> run_tag(None, None), run_tag(5000, -1e12, "low")
    ('', '-it5000-eps-1e+12-barrier_low')
    """
    return ("" if max_iter is None else f"-it{max_iter}") + ("" if eps is None else f"-eps{eps:g}") + \
        ("" if warm_barrier == "auto" else f"-barrier_{warm_barrier}")


def study(path: Path, out: Path, checker: Path | None, share: float, time_limit: float,
          seeds: tuple[int, ...] = SEEDS, max_iter: int | None = None,
          eps: float | None = None, warm_barrier: str = "auto") -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Every start of one scene at one share: its rows and what building the starts measured.
    ``eps``: the lower weight bound [N/m] (``None``: the default; zero or below: tension allowed,
    the checker run with ``--allow-tension``); ``warm_barrier``: the simultaneous method's option."""
    name = path.stem
    scene = api.as_scene(str(path))
    v, weight = highest_free_and_weight(scene)
    toml = out / f"{name}-{share:g}.toml"
    cases = three_cases(v, weight, share)
    toml.write_text(toml_text(cases))
    problem = build_problem(scene, load_cases=str(toml), eps=eps)
    members, names = proportional_members(problem), problem.loads.names
    stamp, rows = run_stamp(), []
    runs, info = starts(path, toml, problem, seeds, eps)
    flags = ("--allow-tension",) if eps is not None and eps <= 0 else ()
    tag = run_tag(max_iter, eps, warm_barrier)
    info.update(cases=cases, ipopt_cases=[n for c, n in enumerate(names) if c not in members],
                proportional={names[c]: {"of": names[r], "factor": k} for c, (r, k) in members.items()})
    for label, start, nearest in runs:
        res = run_start(problem, start, nearest, time_limit, max_iter, warm_barrier)
        stem = f"{name}-{share:g}{tag}-{label.replace(', ', '-').replace(' ', '_')}"
        row = {"scene": name, "point_share": share, "start": label, "start_error": start_error(start),
               **row_of(res, scene, out / f"{stem}.json", checker, flags), **stamp}
        rows.append(row)
        print(json.dumps({k: row[k] for k in row if k != "message"}, default=str), flush=True)
    return rows, info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=Path, default=Path("../shared/paper-scenes/scenes"))
    ap.add_argument("--out", type=Path, default=Path("out/stand_search"))
    ap.add_argument("--checker", type=Path, default=DEFAULT_CHECKER)
    ap.add_argument("--only", default="vault-pillar", help="the scene (file stem of a .sss file in --scenes)")
    ap.add_argument("--share", type=float, default=0.05, help="point load's share of the self-weight")
    ap.add_argument("--time-limit", type=float, default=START_TIME_LIMIT, help="seconds per start")
    ap.add_argument("--max-iter", type=int, default=None,
                    help="IPOPT's iteration limit per load round (default: the method's, 3000)")
    ap.add_argument("--eps", type=float, default=None,
                    help="lower weight bound [N/m] (default: the scale-free default; <= 0: tension allowed)")
    ap.add_argument("--seeds", type=int, nargs="*", default=list(SEEDS), help="seeds of the perturbed starts")
    ap.add_argument("--warm-barrier", choices=WARM_BARRIERS, default="auto",
                    help="how IPOPT's barrier starts from a start (the simultaneous method's warm_barrier)")
    ap.add_argument("--control", action="store_true",
                    help="instead of --only: the tests' free-edged quad vault, which stands under the cases")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    if a.control:
        path = write_control(a.out)
        a.only = path.stem
    else:
        path = a.scenes / f"{a.only}.sss"
    if not path.is_file():
        ap.error(f"no scene {path}: give --scenes the folder of the paper's scenes")
    rows, info = study(path, a.out, a.checker if a.checker.is_file() else None, a.share, a.time_limit, tuple(a.seeds),
                       a.max_iter, a.eps, a.warm_barrier)
    stem = f"stand_search-{a.only}-{a.share:g}" + run_tag(a.max_iter, a.eps, a.warm_barrier)
    write_csv(a.out / f"{stem}.csv", rows, COLUMNS)
    (a.out / f"{stem}.json").write_text(json.dumps({"starts": info, "rows": rows}, indent=1, default=str))
    found = [r for r in rows if r.get("stands")]
    verdict = (f"stands from {len(found)} of {len(rows)} starts" if found else
               f"no start of {len(rows)} found a network that stands (every case ≤ {STANDS_TOL:g}, checker-clean)")
    it = ("" if a.max_iter is None else f" --max-iter {a.max_iter}") + ("" if a.eps is None else f" --eps={a.eps:g}") + \
        ("" if a.warm_barrier == "auto" else f" --warm-barrier {a.warm_barrier}")
    which = "--control" if a.control else f"--only {a.only}"
    notes = [f"`python -m studies.stand_search {which} --share {a.share:g} --time-limit {a.time_limit:g}{it}`",
             f"cases {info['cases']}; IPOPT over {info['ipopt_cases']}; proportional: {info['proportional']}",
             f"starts: staggered {info['staggered']}; single case {info['single']}; triangulated {info['triangulated']}",
             verdict]
    print(write_markdown(a.out / f"{stem}.md", f"{a.only} at {a.share:.0%}: IPOPT from several starts", notes,
                         [("", rows, COLUMNS)]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
