"""Step 2's Newton systems, solved directly and by preconditioned CG.

    python -m studies.newton_systems --out OUT [--shapes concave_disk,pillar_vault]
        [--sizes 4000,16000] [--fits 0,5,15,30] [--every 4] [--rtol 1e-8] [--maxiter 500]
        [--solvers cholmod,cholmod-stale,ilut,jacobi,amg-sa] [--amg-env DIR]

Each interior-point iteration of a Step-2 fit (:func:`selfsupport.methods.weightfit._box_qp_ipm`)
solves one system ``(AᵀA + prox·I + D) x = r``, m × m with m the number of edges; the backend
factors it with CHOLMOD, the symbolic analysis made once per solve. The question is whether an
iterative solver — algebraic multigrid (pyamg) or an incomplete factorization as CG's
preconditioner — would make a fit cheaper. This study takes the systems of real fits and
answers per system:

1. a staggered solve of the generated shape runs with the default backend until the last fit
   in ``--fits``; every interior-point system of those fits is kept (the lower triangle the
   backend factors, caught at :meth:`_LowerQ.with_diagonal`);
2. every ``--every``-th system is solved for a random right-hand side by each solver:

   ``cholmod``        the backend's own: numeric factorization (symbolic reused) and one solve;
   ``cholmod-stale``  CG preconditioned by the factor of the fit's previous system — what reusing
                      one factorization across interior-point iterations would cost;
   ``ilut``           CG preconditioned by scipy's incomplete LU (``spilu``, drop tolerance
                      1e-6, fill factor 20, symmetric ordering);
   ``jacobi``         CG preconditioned by the diagonal;
   ``amg-sa``         CG preconditioned by one V-cycle of pyamg's smoothed aggregation.

   CG stops at ``--rtol`` relative residual or after ``--maxiter`` iterations; a solver that did
   not reach it is reported as not converged, with the residual it left.

pyamg is not a dependency of the project: when it cannot be imported, the study installs it
with pip into ``--amg-env`` (default ``OUT/.pyamg``), its own folder, and adds that to the path.

Writes ``OUT/newton_systems.csv`` (one row per system and solver) and ``OUT/newton_systems.md``
(per shape, size and solver: systems, converged, median iterations and time, and the median
time over CHOLMOD's on the same systems).
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .common import Column, load_average, write_csv, write_markdown

SOLVERS = ("cholmod", "cholmod-stale", "ilut", "jacobi", "amg-sa")
#: the pyamg release this study was written against (PyPI)
PYAMG = "pyamg==5.3.0"


class _Enough(Exception):
    """Raised by the recording backend after the last fit wanted: ends the solve."""


@contextlib.contextmanager
def capture_newton_systems(fits: Sequence[int]) -> Iterator[tuple[Any, list]]:
    """A Step-2 backend that records the interior point's systems of the fits ``fits`` (0-based,
    in call order) and stops the solve after the last of them.

    Yields ``(backend, systems)``; ``systems`` fills with ``(fit, L, Q)``: ``L`` the lower
    triangle of the system as factored (CSC, diagonal stored), ``Q`` the fit's ``AᵀA + prox·I``.
    """
    from selfsupport.methods import weightfit as wf

    wanted, last = set(fits), max(fits)
    systems: list = []
    state = {"fit": -1, "Q": None}

    class Recording(wf.ActiveSetFit):
        def _fit(self, *, A, b, lower, upper, w0, prox, rtol, deadline):
            state["fit"] += 1
            if state["fit"] > last:
                raise _Enough
            A = sp.csc_matrix(A)
            state["Q"] = (A.T @ A + prox * sp.identity(A.shape[1])).tocsc()
            return super()._fit(A=A, b=b, lower=lower, upper=upper, w0=w0, prox=prox, rtol=rtol, deadline=deadline)

    original = wf._LowerQ.with_diagonal

    def with_diagonal(self, D):
        factor = original(self, D)
        if state["fit"] in wanted and np.any(D):  # (D = 0: PDAS's or the start's plain solve)
            systems.append((state["fit"], self.M.copy(), state["Q"]))
        return factor

    wf._LowerQ.with_diagonal = with_diagonal
    try:
        yield Recording(), systems
    finally:
        wf._LowerQ.with_diagonal = original


def record(shape: str, n_vertices: int, fits: Sequence[int]) -> tuple[Any, list]:
    """Run the staggered method on ``make_shape(shape, n_vertices)`` until the last fit in ``fits``;
    return the scene and its captured systems (:func:`capture_newton_systems`)."""
    from selfsupport.api import scene_loads
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods.staggered import StaggeredLinearization

    scene = make_shape(shape, n_vertices=n_vertices)
    with capture_newton_systems(fits) as (backend, systems):
        try:
            StaggeredLinearization(backend=backend).solve(scene, scene_loads(scene))
        except _Enough:
            pass
    return scene, systems


def symmetric(L: sp.spmatrix) -> sp.csr_matrix:
    """The full symmetric matrix of a lower triangle."""
    return (L + sp.tril(L, -1).T).tocsr()


def pcg(M: sp.spmatrix, b: np.ndarray, precondition: Callable[[np.ndarray], np.ndarray], *, rtol: float,
        maxiter: int) -> tuple[np.ndarray, int, bool]:
    """Preconditioned CG (scipy's) from zero: solution, iterations, whether it reached ``rtol``.

    With the exact inverse as preconditioner it converges in one iteration:

    >>> M = sp.diags([4.0, 2.0, 1.0]).tocsr()
    >>> x, its, ok = pcg(M, np.ones(3), lambda r: r / M.diagonal(), rtol=1e-12, maxiter=10)
    >>> its, ok, bool(np.allclose(M @ x, 1.0))
    (1, True, True)
    """
    its = [0]

    def count(_x: np.ndarray) -> None:
        its[0] += 1

    P = sla.LinearOperator(M.shape, matvec=precondition, dtype=float)
    x, info = sla.cg(M, b, rtol=rtol, atol=0.0, M=P, maxiter=maxiter, callback=count)
    return x, its[0], info == 0


def import_pyamg(env: Path) -> Any:
    """pyamg, installed into ``env`` (not the project's environment) when it is not importable."""
    with contextlib.suppress(ImportError):
        return importlib.import_module("pyamg")
    if str(env) not in sys.path:
        sys.path.insert(0, str(env))
    with contextlib.suppress(ImportError):
        return importlib.import_module("pyamg")
    print(f"installing {PYAMG} into {env} ...", flush=True)
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(env), PYAMG],
                   check=True)
    importlib.invalidate_caches()
    return importlib.import_module("pyamg")


def solve_systems(systems: list, solvers: Sequence[str], *, every: int = 1, rtol: float = 1e-8, maxiter: int = 500,
                  pyamg: Any = None, seed: int = 0) -> list[dict[str, Any]]:
    """Solve every ``every``-th system with each solver; one row per system and solver.

    The CHOLMOD factor is updated on every system (as the backend does, so its symbolic
    analysis is reused); ``cholmod-stale`` uses the factor of the same fit's previous system.
    """
    from selfsupport.core import linalg

    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    shared = None  # the backend's way: one factor object, numeric refactorization only
    previous: dict[int, Any] = {}
    for k, (fit, L, _Q) in enumerate(systems):
        t = time.perf_counter()
        shared = linalg.spd_factor(L, lower=True, reuse=shared)
        t_factor = time.perf_counter() - t
        if k % every == 0:
            M = symmetric(L)
            b = rng.standard_normal(M.shape[0])
            d = M.diagonal()
            base = {"system": k, "fit": fit, "m": M.shape[0], "nnz": M.nnz,
                    "diag_ratio": float(d.max() / d.min())}
            for name in solvers:
                row = dict(base, solver=name, setup_s=0.0, iterations=0)
                t = time.perf_counter()
                if name == "cholmod":
                    row["setup_s"] = t_factor
                    x = shared.solve(b)
                    row["solve_s"], ok = time.perf_counter() - t, True
                else:
                    if name == "cholmod-stale":
                        if fit not in previous:
                            continue  # the fit's first system has no earlier factor
                        precondition = previous[fit].solve
                    elif name == "ilut":
                        try:
                            ilu = sla.spilu(M.tocsc(), drop_tol=1e-6, fill_factor=20, permc_spec="MMD_AT_PLUS_A",
                                            diag_pivot_thresh=0.0)
                        except RuntimeError as e:  # "Factor is exactly singular"
                            rows.append(dict(row, setup_s=time.perf_counter() - t, solve_s=float("nan"),
                                             converged=False, residual=float("nan"), note=str(e)))
                            continue
                        precondition = ilu.solve
                    elif name == "jacobi":
                        precondition = lambda r, d=d: r / d  # noqa: E731
                    elif name == "amg-sa":
                        ml = pyamg.smoothed_aggregation_solver(M, symmetry="symmetric", max_coarse=500)
                        precondition = ml.aspreconditioner(cycle="V")
                    else:
                        raise ValueError(f"unknown solver {name!r}; known: {', '.join(SOLVERS)}")
                    row["setup_s"] = time.perf_counter() - t
                    t = time.perf_counter()
                    x, row["iterations"], ok = pcg(M, b, precondition, rtol=rtol, maxiter=maxiter)
                    row["solve_s"] = time.perf_counter() - t
                row["converged"] = ok
                row["residual"] = float(np.linalg.norm(M @ x - b) / np.linalg.norm(b))
                row["total_s"] = row["setup_s"] + row["solve_s"]
                rows.append(row)
        if "cholmod-stale" in solvers and (k + 1) % every == 0:  # (the next system is solved)
            previous[fit] = linalg.spd_factor(L, lower=True)  # its own object: `shared` is refactored
        else:
            previous.pop(fit, None)  # (no stale factor of any but the system just before)
    return rows


def summarize(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per shape, size and solver: counts, medians, and the median time over CHOLMOD's."""
    out = []
    keys = list(dict.fromkeys((r["shape"], r["vertices"], r["solver"]) for r in rows))
    for shape, n, solver in keys:
        mine = [r for r in rows if (r["shape"], r["vertices"], r["solver"]) == (shape, n, solver)]
        chol = {r["system"]: r["total_s"] for r in rows
                if (r["shape"], r["vertices"], r["solver"]) == (shape, n, "cholmod")}
        ratios = [r["total_s"] / chol[r["system"]] for r in mine
                  if r["system"] in chol and np.isfinite(r.get("total_s", np.nan))]
        ok = [r for r in mine if r["converged"]]
        out.append({"shape": shape, "vertices": n, "m": mine[0]["m"], "solver": solver, "systems": len(mine),
                    "converged": len(ok),
                    "median_its": statistics.median(r["iterations"] for r in ok) if ok else float("nan"),
                    "median_total_s": statistics.median(r.get("total_s", np.nan) for r in mine),
                    "max_residual": max(r["residual"] for r in mine),
                    "over_cholmod": statistics.median(ratios) if ratios else float("nan")})
    return out


ROW_COLUMNS: tuple[Column, ...] = (
    Column("shape", "shape"), Column("vertices", "V"), Column("fit", "fit"), Column("system", "system"),
    Column("m", "m"), Column("nnz", "nnz"), Column("diag_ratio", "max/min diag", "{:.1e}"),
    Column("solver", "solver"), Column("setup_s", "setup [s]", "{:.4f}"), Column("iterations", "CG its"),
    Column("solve_s", "solve [s]", "{:.4f}"), Column("total_s", "total [s]", "{:.4f}"),
    Column("converged", "converged"), Column("residual", "rel. residual", "{:.1e}"), Column("note", "note"))
SUMMARY_COLUMNS: tuple[Column, ...] = (
    Column("shape", "shape"), Column("vertices", "V"), Column("m", "m"), Column("solver", "solver"),
    Column("systems", "systems"), Column("converged", "converged"), Column("median_its", "median CG its", "{:.0f}"),
    Column("median_total_s", "median time [s]", "{:.4f}"), Column("over_cholmod", "time / CHOLMOD's", "{:.1f}"),
    Column("max_residual", "max rel. residual", "{:.1e}"))


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m studies.newton_systems", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--shapes", default="concave_disk,pillar_vault", help="comma-separated make_shape names")
    p.add_argument("--sizes", default="4000,16000", help="comma-separated vertex counts")
    p.add_argument("--fits", default="0,5,15,30", help="which Step-2 fits (0-based, in call order)")
    p.add_argument("--every", type=int, default=4, help="solve every k-th captured system")
    p.add_argument("--rtol", type=float, default=1e-8, help="CG's relative residual")
    p.add_argument("--maxiter", type=int, default=500, help="CG's iteration limit")
    p.add_argument("--solvers", default=",".join(SOLVERS), help=f"comma-separated, of {', '.join(SOLVERS)}")
    p.add_argument("--amg-env", default=None, help="folder for pyamg when it is not importable (default OUT/.pyamg)")
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    solvers = [s for s in a.solvers.split(",") if s]
    unknown = sorted(set(solvers) - set(SOLVERS))
    if unknown:
        print(f"error: unknown solver(s) {unknown}; known: {', '.join(SOLVERS)}", file=sys.stderr)
        return 2
    pyamg = import_pyamg(Path(a.amg_env) if a.amg_env else out / ".pyamg") if "amg-sa" in solvers else None
    fits = sorted({int(f) for f in a.fits.split(",")})
    rows: list[dict[str, Any]] = []
    for shape in a.shapes.split(","):
        for n in (int(s) for s in a.sizes.split(",")):
            scene, systems = record(shape, n, fits)
            print(f"{shape} {scene.mesh.n_vertices} vertices: {len(systems)} systems "
                  f"of fits {sorted({s[0] for s in systems})}", flush=True)
            got = solve_systems(systems, solvers, every=a.every, rtol=a.rtol, maxiter=a.maxiter, pyamg=pyamg)
            for r in got:
                r.update(shape=shape, vertices=scene.mesh.n_vertices)
                print(f"  fit {r['fit']:3d} system {r['system']:3d} {r['solver']:14s} its {r['iterations']:4d} "
                      f"{r.get('total_s', float('nan')):8.4f} s  residual {r['residual']:.1e}", flush=True)
            rows.extend(got)
    summary = summarize(rows)
    write_csv(out / "newton_systems.csv", rows, ROW_COLUMNS)
    notes = [f"`python -m studies.newton_systems {' '.join(argv if argv is not None else sys.argv[1:])}`; "
             f"load average {load_average()}.",
             f"CG to relative residual {a.rtol:g} within {a.maxiter} iterations; time = set-up "
             "(factorization, incomplete factorization, hierarchy) + solve; *time / CHOLMOD's* is the median "
             "over the same systems of the ratio to the backend's own factorization and solve."]
    write_markdown(out / "newton_systems.md", "Step 2's Newton systems: direct and preconditioned CG",
                   notes, [("", summary, SUMMARY_COLUMNS)])
    print((out / "newton_systems.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
