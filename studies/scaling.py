"""How the solvers scale with mesh size, and how close the staggered method is to its floor.

    python -m studies.scaling --out DIR [--sizes 1000,4000,16000,64000]
        [--shapes concave_disk,pillar_vault] [--methods staggered,ipopt]
        [--time-limit S] [--ipopt-time-limit S] [--no-warmup]

``--methods`` also takes ``staggered/BACKEND`` (the staggered method with another Step-2
backend) and ``multilevel`` (:mod:`selfsupport.methods.multilevel`: its time covers every level,
its iterations and Step-2/3 columns are those of its finest level; ``levels`` lists each
level's vertices and iterations). Rows run size by size with the methods interleaved, so that
rows compared with one another are measured side by side on a shared machine.

For each generated shape (:func:`selfsupport.core.shapes.make_shape`) and target size one row per
method: solve time, iterations, max relative error (recomputed from the saved JSON), distance to
the reference, peak RSS. Each row runs in its own spawned process (peak memory is per row;
a row that hangs is terminated). IPOPT is run from the smallest size up and stops after the
first size that does not converge within ``--ipopt-time-limit``.

The floor
---------
For staggered rows the worker also measures, at the final weights:

* ``factor_K_s`` — one :func:`selfsupport.core.linalg.spd_factor` factorization of ``−K_ff``, the
  free-vertex block of the stress Laplacian (``n_free × n_free``: the polish's matrix), median of 7;
* ``factor_step3_s`` — one factorization of the Step-3 system itself, ``H ⊗ I₃ + c·⊕(b₀I + b₁nnᵀ)``
  (``3 n_free × 3 n_free``, ``H = K_tᵀK_t``, ``K_t`` = ``K_ff`` with rows over ``|A_i F_i|``):
  what a direct Step 3 costs (not measured above :data:`FLOOR_DIRECT_MAX` free vertices: the
  solver never factors it, and at 256k vertices it took the row past its 6 GiB guard);
* ``factor_step3_pre_s`` — one factorization of ``H + c I`` (``n_free × n_free``), what the
  solver's Step 3 actually factors (its conjugate gradients are preconditioned with it);
* ``factor_step2_s`` — one numeric refactorization (symbolic analysis done beforehand, as in
  the solver) of Step 2's matrix ``AᵀA + prox·I + D`` (``m × m``, m the number of weights): what
  each interior-point iteration and each PDAS solve of a fit costs;
* ``per_iter_over_factor`` — (solve time / outer iterations) / ``factor_step3_s``: an outer
  iteration's cost in direct Step-3 factorizations (1–3 would be a method that factors once per step);
* ``limit_ratio`` — solve time / (outer iterations × ``factor_K_s``): an outer iteration's cost
  in Cholesky factorizations of the plain stress Laplacian of the mesh, the limit a method that
  factors one mesh-sized Laplacian per step would approach (the target is ≤ 10). For
  multilevel rows the iterations are the finest level's (1 when it starts in equilibrium), so
  this is the whole solve's cost; ``solve_over_factor`` — solve time / ``factor_K_s`` — is that
  cost for every method alike (a 25-iteration staggered solve at ratio 10 would be 250);
* ``step2_ratio`` / ``step3_ratio`` — the limit ratio's share of each step (its time per outer
  iteration over ``factor_K_s``), and ``one_factor_ratio`` — (``factor_step2_s`` +
  ``factor_step3_pre_s``) / ``factor_K_s``: the floor of a staggered iteration that factors each
  of its two systems once and does nothing else (no second interior-point iteration, no CG);
* from the solve's own history: ``step2_s`` and ``step3_s`` (time in the weight fits and in the
  position steps), ``cg_mean`` (mean CG iterations per position step), ``fit_its_mean`` (mean
  Step-2 iterations per fit — each one factorization of that matrix);
* ``n_factorizations`` / ``factor_share`` — every numeric factorization the solve made (new
  factor objects and numeric refactorizations alike, recorded by wrapping ``SPDFactor``), and
  the share of the solve time they took.

Writes ``scaling.csv``, ``scaling.md`` and ``scaling.png`` (log-log time and memory vs
vertices, with the fitted exponents of ``time ∝ n^k``) into ``--out`` and prints the table.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .common import (
    STAMP_COLUMNS,
    Column,
    Stopwatch,
    current_rss_mib,
    exit_on_sigterm,
    json_max_relative_error,
    load_average,
    median_time,
    peak_rss_mib,
    run_isolated,
    run_stamp,
    safe_ratio,
    write_csv,
    write_markdown,
)

DEFAULT_SIZES = (1000, 4000, 16000, 64000)
DEFAULT_SHAPES = ("concave_disk", "pillar_vault")


def _staggered(backend: str = "active-set") -> Any:
    from selfsupport.methods.staggered import StaggeredLinearization

    return StaggeredLinearization(backend)


def _ipopt() -> Any:
    from selfsupport.methods.simultaneous import Simultaneous

    return Simultaneous()


def _multilevel() -> Any:
    from selfsupport.methods.multilevel import Multilevel

    return Multilevel()


#: method name -> (factory, default time limit [s]); ``staggered/BACKEND`` names the staggered
#: method with another Step-2 backend (:data:`selfsupport.methods.weightfit_backends.WEIGHT_FIT_BACKENDS`)
METHODS: dict[str, tuple[Callable[[], Any], float]] = {
    "staggered": (_staggered, 1200.0),
    "multilevel": (_multilevel, 1200.0),
    "ipopt": (_ipopt, 180.0),
}


def method_entry(method: str) -> tuple[Callable[[], Any], float]:
    """(factory, default time limit) of a method name (see :data:`METHODS`).

    >>> method_entry("staggered/active-set")[1]
    1200.0
    """
    base, _, backend = method.partition("/")
    if backend and base == "staggered":
        from selfsupport.methods.weightfit_backends import WEIGHT_FIT_BACKENDS

        if backend not in WEIGHT_FIT_BACKENDS:
            raise KeyError(method)
        return (lambda: _staggered(backend)), METHODS["staggered"][1]
    return METHODS[method]


def is_staggered(method: str) -> bool:
    """Whether the rows have a staggered history (multilevel: its finest level's)."""
    return method.partition("/")[0] in ("staggered", "multilevel")


class _FactorRecorder:
    """Record (matrix size, seconds) of every numeric factorization of :class:`SPDFactor`
    (creation and ``update`` alike) while active."""

    def __enter__(self) -> "_FactorRecorder":
        from selfsupport.core.linalg import SPDFactor

        self.calls: list[tuple[int, float]] = []
        self._cls, self._orig = SPDFactor, SPDFactor._factor
        orig, calls = self._orig, self.calls

        def timed(obj, M, *a, **kw):
            t = time.perf_counter()
            out = orig(obj, M, *a, **kw)
            calls.append((int(M.shape[0]), time.perf_counter() - t))
            return out

        SPDFactor._factor = timed
        return self

    def __exit__(self, *exc: Any) -> None:
        self._cls._factor = self._orig


#: Above this many free vertices the floor skips the direct Step-3 factorization (see the module docstring).
FLOOR_DIRECT_MAX = 100_000


def _floor_measurements(result, scene) -> dict[str, float]:
    """Factorization times at the final weights (see the module docstring)."""
    import scipy.sparse as sp

    from formulations.equilibrium import Topology, position_blocks, weight_matrix
    from formulations.scaling import Scaling
    from selfsupport.core.linalg import spd_factor
    from selfsupport.methods.weightfit import _LowerQ

    net = result.network
    active = scene.active_edges
    top = Topology.build(scene.mesh.n_vertices, scene.mesh.edges[active], scene.supports)
    sc = Scaling.of(net.vertices, net.loads, top.free)
    w = sc.weight(np.asarray(net.weights)[active])  # scaled units, as the solver factors them
    Kff, _ = position_blocks(top, w)
    negK = (-Kff).tocsc()
    s = 1.0 / np.abs(sc.load(np.asarray(net.loads))[top.free])
    Kt = sp.diags(s) @ Kff
    H = (Kt.T @ Kt).tocsr()
    c = float(np.mean((negK.diagonal() * s) ** 2))
    # Step 3's anchor b0 I + b1 n nᵀ per vertex (here n = (1, 1, 1)/√3) couples a vertex's x, y, z:
    # as a direct solve one 3n system, not three scalar ones
    pre = (H + c * sp.identity(top.n_free)).tocsc()
    step3 = float("nan")
    if top.n_free <= FLOOR_DIRECT_MAX:
        blocks = sp.kron(sp.identity(top.n_free), np.ones((3, 3)) / 3 + np.eye(3))
        M = (sp.kron(H, sp.identity(3), format="csr") + c * blocks).tocsc()
        step3 = median_time(lambda: spd_factor(M), repeat=3, budget=120.0)
        del M
    # Step 2's matrix AᵀA + prox·I (m×m, edges coupled through shared vertices): what every
    # interior-point iteration and PDAS solve of a fit factors
    A = weight_matrix(top, sc.pos(np.asarray(net.vertices)))
    Q = (A.T @ A).tocsc()
    Q = (Q + 1e-8 * float(Q.diagonal().mean()) * sp.identity(Q.shape[0], format="csc")).tocsc()
    lowq = _LowerQ(Q)
    lowq.with_diagonal(np.ones(Q.shape[0]))  # symbolic analysis, once per fit pattern in the solver
    return {"factor_step2_s": median_time(lambda: lowq.with_diagonal(np.ones(Q.shape[0])), repeat=3, budget=60.0),
            # (median of 7: the limit ratio divides by it, and a 1 ms factorization is as noisy as the machine)
            "factor_K_s": median_time(lambda: spd_factor(negK), repeat=7, budget=60.0),
            "factor_step3_s": step3,
            "factor_step3_pre_s": median_time(lambda: spd_factor(pre), repeat=3, budget=60.0),
            "n_free": top.n_free}


def _solve_from_file(path: Path) -> dict[str, Any]:
    """Status, solve time and iterations of a row's saved network (the worker writes it before
    the floor measurements, which can be what a memory guard stops)."""
    import json

    doc = json.loads(Path(path).read_text())
    study = doc.get("study") or {}
    out = {"solve_status": doc.get("status"), "iterations": doc.get("iterations")}
    if isinstance(study.get("solve_seconds"), (int, float)):
        out["time_s"] = float(study["solve_seconds"])
    return {k: v for k, v in out.items() if v is not None}


def iteration_ratios(row: dict[str, Any]) -> dict[str, float]:
    """An outer iteration's time, and its cost in Step-3 factorizations and in factorizations of
    the plain stress Laplacian (``limit_ratio``, the limit: ~1–3 for a method that factors it
    once per step). NaN where a number is missing.

    The limit ratio is split by step (``step2_ratio``, ``step3_ratio``: each step's time per
    iteration in the same unit; the rest is judging, polishing and bookkeeping), and
    ``one_factor_ratio`` is the floor of an iteration that factors each of its two systems once
    (Step 2's m×m matrix and Step 3's preconditioner ``H + cI``) and does nothing else.

    >>> r = iteration_ratios({"time_s": 6.0, "iterations": 3, "factor_step3_s": 0.5, "factor_K_s": 0.1,
    ...                       "step2_s": 3.0, "step3_s": 1.5, "factor_step2_s": 0.3, "factor_step3_pre_s": 0.2})
    >>> {k: round(v, 12) for k, v in r.items()}  # doctest: +NORMALIZE_WHITESPACE
    {'time_per_iter_s': 2.0, 'per_iter_over_factor': 4.0, 'limit_ratio': 20.0, 'solve_over_factor': 60.0,
     'step2_ratio': 10.0, 'step3_ratio': 5.0, 'one_factor_ratio': 5.0}
    """
    per = safe_ratio(row.get("time_s"), row.get("iterations"))
    K = row.get("factor_K_s")
    one = safe_ratio(row.get("factor_step2_s"), K) + safe_ratio(row.get("factor_step3_pre_s"), K)
    return {"time_per_iter_s": per, "per_iter_over_factor": safe_ratio(per, row.get("factor_step3_s")),
            "limit_ratio": safe_ratio(per, K),
            "solve_over_factor": safe_ratio(row.get("time_s"), K),
            "step2_ratio": safe_ratio(safe_ratio(row.get("step2_s"), row.get("iterations")), K),
            "step3_ratio": safe_ratio(safe_ratio(row.get("step3_s"), row.get("iterations")), K),
            "one_factor_ratio": one}


def scaling_row(*, shape: str, n_vertices: int, method: str, time_limit: float, out_json: str,
                warmup: bool = True) -> dict[str, Any]:
    """Worker (own process): generate the shape, solve it, save the network, return the numbers."""
    from selfsupport.api import scene_loads
    from selfsupport.core.shapes import make_shape
    from selfsupport.io import write_network

    factory = method_entry(method)[0]
    scene = make_shape(shape, n_vertices=n_vertices)
    loads = scene_loads(scene)
    solver = factory()
    if warmup:  # solver plug-ins and caches, untimed
        tiny = make_shape("dome", n_vertices=60)
        factory().solve(tiny, scene_loads(tiny), time_limit=30.0)
    rss0 = current_rss_mib()
    with _FactorRecorder() as rec, Stopwatch() as sw:
        res = solver.solve(scene, loads, time_limit=float(time_limit))
    write_network(out_json, res, study={"shape": shape, "target_vertices": n_vertices, "method": method,
                                        "solve_seconds": sw.seconds, "time_limit": time_limit})
    row: dict[str, Any] = {
        "vertices": scene.mesh.n_vertices, "edges": scene.mesh.n_edges, "status": res.status, "message": res.message,
        "time_s": sw.seconds, "iterations": res.iterations, "reported_error": res.max_relative_error,
        "dist_ref_mean": res.distance_mean, "dist_ref_max": res.distance_max, "rss_before_mib": rss0,
        "peak_rss_mib": peak_rss_mib(), "network": Path(out_json).name,
        "levels": " → ".join(f"{lv['n_vertices']}:{lv['iterations']}"
                             for lv in res.parameters.get("multilevel", {}).get("levels", []))}
    if is_staggered(method):
        steps = [h for h in res.history if isinstance(h.get("iteration"), int)]
        row["step2_s"] = sum(h.get("t_weights", 0.0) for h in steps)
        row["step3_s"] = sum(h.get("t_positions", 0.0) for h in steps)
        cg = [h["cg_iterations"] for h in steps if h.get("cg_iterations")]
        row["cg_mean"] = float(np.mean(cg)) if cg else float("nan")
        fits = [h["fit_iterations"] for h in steps if h.get("fit_iterations")]
        row["fit_its_mean"] = float(np.mean(fits)) if fits else float("nan")
        row["n_factorizations"] = len(rec.calls)
        row["factor_share"] = sum(t for _, t in rec.calls) / sw.seconds if rec.calls else float("nan")
        row.update(_floor_measurements(res, scene))
        # (peak_rss_mib stays the solve's own: the floor's direct 3n factorization can exceed it)
        row["peak_rss_floor_mib"] = peak_rss_mib()
    return row


COLUMNS: tuple[Column, ...] = (
    Column("shape", "shape"), Column("target", "target n"), Column("vertices", "V"), Column("edges", "E"),
    Column("method", "method"), Column("levels", "levels (V:its)"), Column("status", "status"),
    Column("time_s", "time [s]", "{:.2f}"),
    Column("iterations", "iterations", "{:d}"), Column("max_rel_error", "max rel. error", "{:.1e}"),
    Column("reported_error", "reported error", "{:.1e}"),
    Column("dist_ref_mean", "dist. to ref. mean", "{:.2e}"), Column("dist_ref_max", "dist. to ref. max", "{:.2e}"),
    Column("peak_rss_mib", "peak RSS [MiB]", "{:.0f}"), Column("rss_before_mib", "RSS before solve [MiB]", "{:.0f}"),
    Column("peak_rss_floor_mib", "peak RSS with floor [MiB]", "{:.0f}"),
    Column("time_per_iter_s", "time / iteration [s]", "{:.3f}"),
    Column("step2_s", "Step 2 [s]", "{:.2f}"), Column("step3_s", "Step 3 [s]", "{:.2f}"),
    Column("cg_mean", "CG its / step", "{:.1f}"),
    Column("fit_its_mean", "Step-2 its / fit", "{:.1f}"),
    Column("factor_step2_s", "factor Step 2 (m) [s]", "{:.4f}"),
    Column("factor_K_s", "factor −K_ff [s]", "{:.4f}"), Column("factor_step3_s", "factor Step 3 (3n) [s]", "{:.4f}"),
    Column("factor_step3_pre_s", "factor H + cI (n) [s]", "{:.4f}"),
    Column("per_iter_over_factor", "iteration / Step-3 factorization", "{:.1f}"),
    Column("limit_ratio", "time / (its × factor −K_ff)", "{:.1f}"),
    Column("solve_over_factor", "time / factor −K_ff", "{:.0f}"),
    Column("step2_ratio", "Step 2 / (its × factor −K_ff)", "{:.1f}"),
    Column("step3_ratio", "Step 3 / (its × factor −K_ff)", "{:.1f}"),
    Column("one_factor_ratio", "(factor Step 2 + factor H + cI) / factor −K_ff", "{:.1f}"),
    Column("n_factorizations", "factorizations", "{:d}"), Column("factor_share", "share in factorizations", "{:.0%}"),
    Column("time_limit_s", "time limit [s]", "{:g}"), Column("network", "network"), Column("message", "message"),
    *STAMP_COLUMNS,
)
_BY_KEY = {c.key: c for c in COLUMNS}
MD_COLUMNS = ("shape", "vertices", "edges", "method", "levels", "status", "time_s", "iterations", "max_rel_error",
              "dist_ref_mean", "peak_rss_mib", "rss_before_mib", "time_per_iter_s", "step2_s", "step3_s", "cg_mean",
              "fit_its_mean", "factor_step2_s", "factor_K_s", "factor_step3_s", "factor_step3_pre_s",
              "per_iter_over_factor", "limit_ratio", "step2_ratio", "step3_ratio", "one_factor_ratio",
              "solve_over_factor", "n_factorizations", "factor_share")
FIT_COLUMNS = (Column("shape", "shape"), Column("method", "method"), Column("sizes", "sizes used"),
               Column("time_exponent", "time ∝ n^k: k", "{:.2f}"),
               Column("memory_exponent", "solve memory ∝ n^k: k", "{:.2f}"), *STAMP_COLUMNS)


def fitted_exponent(n: Sequence[float], y: Sequence[float]) -> float:
    """Slope of ``log y`` against ``log n`` (least squares, ``np.polyfit``); NaN with < 2 points."""
    n, y = np.asarray(n, float), np.asarray(y, float)
    ok = np.isfinite(n) & np.isfinite(y) & (n > 0) & (y > 0)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(n[ok]), np.log(y[ok]), 1)[0])


def exponents(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Fitted exponents of time and of the solve's memory (peak − RSS before the solve) per
    (shape, method), over the converged rows."""
    out = []
    keys = dict.fromkeys((r["shape"], r["method"]) for r in rows)
    for shape, method in keys:
        sel = [r for r in rows if r["shape"] == shape and r["method"] == method and r.get("status") == "converged"]
        n = [r["vertices"] for r in sel]
        mem = [r.get("peak_rss_mib", np.nan) - r.get("rss_before_mib", np.nan) for r in sel]
        stamp = {c.key: rows[0].get(c.key) for c in STAMP_COLUMNS}  # the run's, as its rows carry it
        out.append({"shape": shape, "method": method, "sizes": ", ".join(str(v) for v in n),
                    "time_exponent": fitted_exponent(n, [r["time_s"] for r in sel]),
                    "memory_exponent": fitted_exponent(n, mem), **stamp})
    return out


def plot(rows: Sequence[dict[str, Any]], fits: Sequence[dict[str, Any]], path: Path) -> None:
    """Log-log time and peak RSS against vertices, one line per (shape, method)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(11, 4.2))
    k_of = {(f["shape"], f["method"]): f["time_exponent"] for f in fits}
    for (shape, method) in dict.fromkeys((r["shape"], r["method"]) for r in rows):
        sel = sorted((r for r in rows if r["shape"] == shape and r["method"] == method and r.get("time_s")),
                     key=lambda r: r["vertices"])
        if not sel:
            continue
        n = np.array([r["vertices"] for r in sel], float)
        t = np.array([r["time_s"] for r in sel], float)
        conv = np.array([r.get("status") == "converged" for r in sel])
        k = k_of.get((shape, method), float("nan"))
        line, = ax_t.loglog(n, t, "-", label=f"{shape} / {method} (k = {k:.2f})")
        ax_t.loglog(n[conv], t[conv], "o", color=line.get_color())
        ax_t.loglog(n[~conv], t[~conv], "x", color=line.get_color(), markersize=9)
        ax_m.loglog(n, [r.get("peak_rss_mib", np.nan) for r in sel], "o-", color=line.get_color(),
                    label=f"{shape} / {method}")
    nn = np.array([1e3, 6.4e4])
    ax_t.loglog(nn, 60.0 * (nn / 6.4e4) ** 1.2, "k:", label="n^1.2 through 60 s at 64k (target)")
    ax_t.set_xlabel("vertices")
    ax_t.set_ylabel("solve time [s]")
    ax_t.set_title("time (o converged, x not)")
    ax_m.axhline(2048, color="k", ls=":", label="2 GiB (target)")
    ax_m.set_xlabel("vertices")
    ax_m.set_ylabel("peak RSS of the row's process [MiB]")
    ax_m.set_title("memory")
    for ax in (ax_t, ax_m):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_scaling(*, out: Path, shapes: Sequence[str], sizes: Sequence[int], methods: Sequence[str],
                time_limits: dict[str, float], warmup: bool = True, echo: Callable[[str], None] = print,
                on_row: Callable[[list[dict[str, Any]]], None] | None = None) -> list[dict[str, Any]]:
    """Every (shape, size, method) row, each in its own process; ``on_row(rows)`` after each
    (the CLI rewrites the outputs, so an interrupted run keeps its finished rows). Every row
    carries :func:`studies.common.run_stamp`, taken at the start."""
    stamp = run_stamp()
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for shape in shapes:
        given_up: dict[str, str] = {}
        # size outermost, methods interleaved: rows of one size are measured side by side
        for n in sorted(sizes):
            for method in methods:
                tl = time_limits.get(method, time_limits.get(method.partition("/")[0], method_entry(method)[1]))
                base = {"shape": shape, "target": n, "method": method, "time_limit_s": tl, **stamp}
                if method in given_up:
                    rows.append({**base, "status": "skipped", "message": given_up[method]})
                    continue
                out_json = out / f"{shape}-{n}__{method.replace('/', '-')}.json"
                out_json.unlink(missing_ok=True)
                echo(f"[{time.strftime('%H:%M:%S')}] {shape} n≈{n} {method} (time limit {tl:g} s) ...")
                r = run_isolated("studies.scaling:scaling_row",
                                 {"shape": shape, "n_vertices": n, "method": method, "time_limit": tl,
                                  "out_json": str(out_json), "warmup": warmup},
                                 hard_timeout=2.0 * tl + 300.0)
                r.update(base)
                if "vertices" not in r:  # the process died or was killed: size the row here (cheap)
                    from selfsupport.core.shapes import make_shape

                    mesh = make_shape(shape, n_vertices=n).mesh
                    r["vertices"], r["edges"] = mesh.n_vertices, mesh.n_edges
                if out_json.is_file():
                    r["max_rel_error"] = json_max_relative_error(out_json)
                    if "time_s" not in r:  # killed after the solve (in the floor): its file has the solve
                        r.update(_solve_from_file(out_json))
                r.update(iteration_ratios(r))
                echo(f"    {r.get('status')}: {r.get('vertices', '?')} V, time {r.get('time_s', float('nan')):.2f} s, "
                     f"{r.get('iterations', '-')} it, error {r.get('max_rel_error', float('nan')):.2e}, "
                     f"peak RSS {r.get('peak_rss_mib', float('nan')):.0f} MiB, "
                     f"limit ratio {r.get('limit_ratio', float('nan')):.1f}, "
                     f"time / factor −K_ff {r.get('solve_over_factor', float('nan')):.0f}"
                     + (f" — {r['message']}" if r.get("message") else ""))
                rows.append(r)
                if on_row is not None:
                    on_row(rows)
                if not is_staggered(method) and r.get("status") != "converged":
                    given_up[method] = f"{method} did not converge at n≈{n} ({r.get('status')}); larger sizes not tried"
    return rows


def write_outputs(rows: Sequence[dict[str, Any]], out: Path) -> str:
    fits = exponents(rows)
    write_csv(out / "scaling.csv", rows, COLUMNS)
    write_csv(out / "scaling_exponents.csv", fits, FIT_COLUMNS)
    plot(rows, fits, out / "scaling.png")
    notes = [
        "Times are the `solve()` call alone (process start-up, imports, mesh generation and a warm-up solve of "
        "a tiny dome excluded); each row runs in its own spawned process, so *peak RSS* is that row's "
        "solve (interpreter and imports included; *RSS before solve* is the level the solve started from; the "
        "CSV's *peak RSS with floor* includes the floor measurements below, whose direct 3n factorization is "
        "larger than anything the solve factors).",
        "*max rel. error* recomputed with plain numpy from the saved JSON network.",
        "Floor (at the final weights): *factor −K_ff* = one SPD factorization (`linalg.spd_factor`) of the "
        "free-vertex stress Laplacian; *factor Step 2 (m)* = one numeric refactorization of the weight fit's "
        "m×m matrix AᵀA + prox·I + D (one per *Step-2 its / fit*, the mean over the solve's fits); "
        "*factor Step 3 (3n)* = one factorization of the 3n_free×3n_free Step-3 "
        "system (what a direct Step 3 costs); *factor H + cI (n)* = one factorization of the n_free×n_free "
        "matrix the solver's Step 3 factors (its CG preconditioner); *iteration / Step-3 factorization* = "
        "(time / iterations) / the 3n factorization; *time / (its × factor −K_ff)* = (time / iterations) / the "
        "plain stress Laplacian's factorization (the limit: ~1–3 for a method that factors it once per step), "
        "split into *Step 2 / (…)* and *Step 3 / (…)* (each step's time per iteration in that unit); "
        "*(factor Step 2 + factor H + cI) / factor −K_ff* = the floor of an iteration that factors each of "
        "its two systems once and does nothing else. "
        "*Step 2*, *Step 3*: time in the weight fits and the "
        "position steps (from the solve's history); *factorizations*, *share*: every numeric factorization "
        "of the solve (new and refactored) and its share of the solve time.",
        "IPOPT is not tried at sizes above the first one where it does not converge within its time limit.",
        f"Load average at the end (1/5/15 min): {load_average()} — shared machine, timings are noisy.",
    ]
    return write_markdown(out / "scaling.md", "Scaling study", notes,
                          [("Rows", rows, [_BY_KEY[k] for k in MD_COLUMNS]),
                           ("Fitted exponents (converged rows)", fits, list(FIT_COLUMNS))])


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m studies.scaling", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, type=Path, help="output folder (scaling.csv, .md, .png, networks)")
    p.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)), help="comma-separated target vertex counts")
    p.add_argument("--shapes", default=",".join(DEFAULT_SHAPES), help="comma-separated make_shape names")
    p.add_argument("--methods", default=",".join(METHODS),
                   help=f"comma-separated, from {', '.join(METHODS)}, or staggered/BACKEND (a Step-2 backend)")
    p.add_argument("--time-limit", type=float, default=METHODS["staggered"][1],
                   help="staggered and multilevel time limit per row [s]")
    p.add_argument("--ipopt-time-limit", type=float, default=METHODS["ipopt"][1], help="IPOPT time limit per row [s]")
    p.add_argument("--no-warmup", action="store_true", help="skip the untimed warm-up solve in each row process")
    return p


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Run the study; returns the rows (also written to ``--out``)."""
    a = build_parser().parse_args(argv)
    sizes = [int(s) for s in a.sizes.split(",") if s]
    shapes = [s for s in a.shapes.split(",") if s]
    methods = [m for m in a.methods.split(",") if m]
    unknown = []
    for m in methods:
        try:
            method_entry(m)
        except KeyError:
            unknown.append(m)
    if unknown:
        raise SystemExit(f"unknown method(s) {unknown}; choose from {', '.join(METHODS)} or staggered/BACKEND")
    from selfsupport.core.shapes import SHAPES

    bad = [s for s in shapes if s not in SHAPES]
    if bad:
        raise SystemExit(f"unknown shape(s) {bad}; choose from {', '.join(sorted(SHAPES))}")
    rows = run_scaling(out=a.out.resolve(), shapes=shapes, sizes=sizes, methods=methods,
                       time_limits={"staggered": a.time_limit, "multilevel": a.time_limit, "ipopt": a.ipopt_time_limit}, warmup=not a.no_warmup,
                       on_row=lambda rs: write_outputs(rs, a.out))
    md = write_outputs(rows, a.out)
    print(md)
    print(f"written: {a.out / 'scaling.csv'}, {a.out / 'scaling.md'}, {a.out / 'scaling.png'}")
    return rows


if __name__ == "__main__":  # pragma: no cover
    exit_on_sigterm()  # a killed study stops its running solver process too
    main(sys.argv[1:])
