"""Parameter sweeps on dask.distributed: a TOML file of scenes × methods × parameter grids,
one task per run, results stored atomically in SQLite as they finish (resumable), exported
to CSV / Parquet and summarised in a Markdown report with plots.

>>> from selfsupport.sweep import parse_spec
>>> spec = parse_spec('''
... [sweep]
... scenes = ["shape:dome?n_vertices=200", "shape:cross_vault?n_vertices=200"]
... methods = ["staggered", "ipopt"]
... [grid]
... density = [1000.0, 2000.0]
... w_max = ["none", 5e4]
... ''')
>>> len(spec.expand())   # 2 scenes x 2 methods x 2 densities x 2 bounds
16

Modules: :mod:`.spec` (definition), :mod:`.store` (SQLite store, keys, exports),
:mod:`.runner` (dask execution), :mod:`.report` (table and plots). The CLI is
``selfsupport sweep SWEEP.toml --out DIR`` (:mod:`selfsupport.cli.sweep`).
"""
from selfsupport.sweep.report import write_report
from selfsupport.sweep.runner import run_sweep
from selfsupport.sweep.spec import PARAMETERS, RunSpec, SceneRef, SweepSpec, load_spec, parse_spec
from selfsupport.sweep.store import ResultStore, read_export, run_key, scene_digest

__all__ = ["PARAMETERS", "RunSpec", "SceneRef", "SweepSpec", "load_spec", "parse_spec", "ResultStore",
           "read_export", "run_key", "scene_digest", "run_sweep", "write_report"]


def __getattr__(name: str):
    # dask and matplotlib load only when a sweep actually runs or reports
    if name == "run_sweep":
        return run_sweep
    if name == "write_report":
        return write_report
    raise AttributeError(name)
