"""Parameter sweeps on dask.distributed (selfsupport.sweep): definition, store, real
LocalCluster runs, failures recorded, kill-and-resume, exports and reports.

The cluster tests use one module-wide LocalCluster (2 worker processes, 1 thread each) on
tiny generated shapes (~200 vertices); the kill test starts the sweep command in a
subprocess with its own cluster and SIGKILLs it mid-sweep.
"""
from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest

from selfsupport.core.errors import InputError
from selfsupport.sweep import parse_spec, read_export, run_key, scene_digest
from selfsupport.sweep.runner import STORE_NAME, plan_runs
from selfsupport.sweep.store import COLUMN_NAMES, ResultStore
from tests.conftest import SHARED

# Two shapes that the staggered method solves to round-off in well under a second each.
SHAPES = ['"shape:dome?n_vertices=200"', '"shape:cross_vault?n_vertices=200"']
TINY_W_MAX = 1e-9  # below any lower weight bound: the method raises InputError


def sweep_text(scenes=SHAPES, methods=('"staggered"',), grid="density = [1000.0, 2000.0]", extra="",
               budget=60.0, grace=15.0, report="") -> str:
    return textwrap.dedent(f"""\
        [sweep]
        name = "test"
        scenes = [{", ".join(scenes)}]
        methods = [{", ".join(methods)}]
        time_budget = {budget}
        grace = {grace}
        [grid]
        {grid}
        {extra}
        """) + report


# ------------------------------------------------------------------------- definition
def test_expansion_counts_and_defaults(tmp_path):
    text = sweep_text(grid='density = [1000.0, 2000.0, 4000.0]\nw_max = ["none", 2e4]',
                      extra='[zip]\nthickness = [0.1, 0.2]\ntol = [1e-9, 1e-8]\n'
                            '[options.staggered]\nalpha0 = [1.0, 10.0]')
    spec = parse_spec(text.replace("time_budget", "repetitions = 2\ntime_budget"), scene_dir=tmp_path)
    runs = spec.expand()
    # scenes x methods x grid (3 x 2) x zip rows (2) x options (2) x repetitions (2)
    assert len(runs) == 2 * 1 * 6 * 2 * 2 * 2
    p = runs[0].param_dict
    assert set(p) == {"density", "thickness", "w_max", "eps", "tol", "max_iter", "objective"}
    assert p["eps"] is None and p["max_iter"] is None and p["objective"] is None
    # zip rows stay paired
    assert {(r.param_dict["thickness"], r.param_dict["tol"]) for r in runs} == {(0.1, 1e-9), (0.2, 1e-8)}
    assert {r.param_dict["w_max"] for r in runs} == {None, 2e4}
    # the staggered method's default backend is resolved, so "staggered" == "staggered:active-set"
    assert {r.backend for r in runs} == {"active-set"}


def test_objective_grid_is_read_by_name_and_reaches_the_solve(tmp_path, monkeypatch):
    """A sweep varies the objective like any parameter; names come from the term registry."""
    from selfsupport.core.shapes import make_shape
    from selfsupport.methods.staggered import StaggeredLinearization
    from selfsupport.sweep.runner import execute_run

    text = sweep_text(grid='objective = ["default", "reference=1, planarity=10"]')
    runs = parse_spec(text, scene_dir=tmp_path).expand()
    assert {r.param_dict["objective"] for r in runs} == {None, "reference=1 planarity=10"}
    with pytest.raises(InputError, match="unknown objective term"):
        parse_spec(sweep_text(grid='objective = ["smoothness=1"]'), scene_dir=tmp_path)
    run = next(r for r in runs if r.param_dict["objective"])
    seen = []
    real = StaggeredLinearization.solve

    def spy(self, *a, **k):
        res = real(self, *a, **k)
        seen.append(res.terms)
        return res

    monkeypatch.setattr(StaggeredLinearization, "solve", spy)
    out = execute_run(make_shape("barrel_vault", n_vertices=100),
                      {"key": "k", "method": run.method, "backend": run.backend, "params": run.param_dict,
                       "options": run.option_dict, "time_budget": 60.0})
    assert out["status"] == "converged", out
    assert set(seen[0]) == {"reference", "planarity"}  # the solve minimised the sweep's objective


def test_keys_depend_on_content_and_parameters_only(tmp_path):
    from selfsupport.core.shapes import make_shape
    from selfsupport.io import write_mesh

    scene = make_shape("dome", n_vertices=150)
    a, b = tmp_path / "a" / "one.obj", tmp_path / "b" / "two.obj"
    write_mesh(a, scene.mesh)
    write_mesh(b, scene.mesh)
    moved = scene.mesh.vertices.copy()
    moved[5, 2] += 1e-9
    write_mesh(tmp_path / "three.obj", scene.mesh.with_vertices(moved))
    text = sweep_text(scenes=[f'{{path = "{a}", supports = "boundary"}}', f'{{path = "{b}", supports = "boundary"}}',
                              '{path = "three.obj", supports = "boundary"}'],
                      grid="density = [2000.0]")
    plan = plan_runs(parse_spec(text, scene_dir=tmp_path))
    keys = [r.key for r in plan.runs]
    # identical content under two names and folders: one key (run once); one vertex moved by 1 nm: new key
    assert len(keys) == 2 and plan.duplicates == 1
    assert scene_digest(plan.scenes[0]) == scene_digest(plan.scenes[1]) != scene_digest(plan.scenes[2])
    # an explicit default equals the omitted one; any parameter change changes the key
    explicit = plan_runs(parse_spec(text.replace("density = [2000.0]", "density = [2000.0]\nthickness = [0.1]"),
                                    scene_dir=tmp_path))
    assert [r.key for r in explicit.runs] == keys
    other = plan_runs(parse_spec(text.replace("density = [2000.0]", "density = [2000.0000001]"), scene_dir=tmp_path))
    assert not set(r.key for r in other.runs) & set(keys)
    ident = plan.runs[0].run.identity()
    assert run_key(scene_digest(plan.scenes[0]), ident) == keys[0]


@pytest.mark.parametrize("bad, fix", [
    ('[grid]\nspeed = [1.0]', "unknown parameter"),
    ('[grid]\ndensity = [-1.0]', "positive"),
    ('[zip]\ndensity = [1.0, 2.0]\ntol = [1e-9]', "equal lengths"),
    ('[options.staggered]\nalpha_zero = [1.0]', "alpha_zero"),
    ('[options.staggered]\ntol = [1e-3]', "sets itself"),
    ('[report]\ntable = ["colour"]', "not a result column"),
    ('[report]\nplots = [{kind = "pie"}]', "unknown kind"),
])
def test_bad_sweep_files_say_what_to_fix(bad, fix, tmp_path):
    text = textwrap.dedent("""\
        [sweep]
        scenes = ["shape:dome?n_vertices=150"]
        methods = ["staggered"]
        """) + bad
    with pytest.raises(InputError, match=fix):
        parse_spec(text, scene_dir=tmp_path)


def test_unknown_method_and_backend(tmp_path):
    with pytest.raises(InputError, match="unknown method"):
        parse_spec('[sweep]\nscenes = ["shape:dome"]\nmethods = ["magic"]', scene_dir=tmp_path)
    with pytest.raises(InputError, match="no backend"):
        parse_spec('[sweep]\nscenes = ["shape:dome"]\nmethods = ["staggered:magic"]', scene_dir=tmp_path)


# --------------------------------------------------------------------------- cluster
@pytest.fixture(scope="module")
def client():
    import dask
    from distributed import Client, LocalCluster

    from selfsupport.sweep.runner import LOCAL_CLUSTER_CONFIG

    with dask.config.set(LOCAL_CLUSTER_CONFIG):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        c = Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def finished(client, tmp_path_factory):
    """A sweep of 2 shapes + 1 missing file x 2 densities x 2 bounds, run on the cluster."""
    from selfsupport.sweep.runner import run_sweep

    out = tmp_path_factory.mktemp("sweep")
    text = sweep_text(scenes=SHAPES + ['"no_such_scene.sss"'],
                      grid=f'density = [1000.0, 2000.0]\nw_max = ["none", {TINY_W_MAX}]',
                      report='[report]\ntable = ["scene", "w_max"]\nplots = [{kind = "line", x = "density", '
                             'y = "distance_mean", facet = "scene"}, {kind = "success_rate", hue = "w_max"}, '
                             '{kind = "time_vs_size"}]\n')
    spec = parse_spec(text, scene_dir=out)
    outcome = run_sweep(spec, out, client=client, progress=False)
    return spec, outcome, out


def test_every_run_is_recorded_with_physics_that_matches_its_parameters(finished):
    spec, outcome, out = finished
    with ResultStore(out / STORE_NAME) as store:
        df = store.frame(outcome.keys)
    assert outcome.n_runs == len(df) == 12 and outcome.n_executed == 12
    ok = df[df["status"] == "converged"]
    assert len(ok) == 4 and set(ok["w_max"].isna()) == {True}
    # the evidence stored is the method's: equilibrium to the requested tolerance, compression only
    assert (ok["max_rel_error"] <= ok["tol"]).all() and (ok["min_weight"] > 0).all()
    # self-weight scales the loads only, so without a weight bound the network's geometry does
    # not depend on the density: the stored distances agree across densities, scene by scene
    for scene, g in ok.groupby("scene"):
        d = g.sort_values("density")["distance_mean"].to_numpy()
        assert d[0] == pytest.approx(d[1], rel=1e-6, abs=1e-12), scene
    # sizes recorded are the scenes' (active edges: both-support edges carry no unknown)
    from selfsupport.core.shapes import make_shape
    dome = make_shape("dome", n_vertices=200)
    row = ok[ok["scene"] == "dome?n_vertices=200"].iloc[0]
    assert row["n_vertices"] == dome.mesh.n_vertices and row["n_edges"] == int(dome.active_edges.sum())
    # the runs ran in the worker processes, not here; timestamps are ordered
    assert set(ok["pid"]) and os.getpid() not in set(ok["pid"])
    assert (ok["finished_at"] >= ok["started_at"]).all() and (ok["solve_time"] <= ok["task_time"]).all()
    assert (ok["peak_rss_mb"] > 10).all()


def test_a_run_that_raises_is_recorded_as_failed_with_its_message(finished):
    spec, outcome, out = finished
    with ResultStore(out / STORE_NAME) as store:
        df = store.frame(outcome.keys)
    raised = df[df["w_max"] == TINY_W_MAX]
    raised = raised[raised["scene"] != "no_such_scene"]
    assert len(raised) == 4 and set(raised["status"]) == {"failed"}
    assert raised["message"].str.contains("InputError: w_max").all()
    assert raised["worker"].str.startswith("tcp://").all()  # it failed on a worker, and the sweep went on
    missing = df[df["scene"] == "no_such_scene"]
    assert len(missing) == 4 and set(missing["status"]) == {"failed"}
    assert missing["message"].str.contains("could not be loaded").all()
    assert outcome.by_status == {"converged": 4, "failed": 8}


def test_resume_skips_stored_runs_and_retry_reruns_only_failed(client, finished):
    from selfsupport.sweep.runner import run_sweep

    spec, outcome, out = finished
    with ResultStore(out / STORE_NAME) as store:
        before = store.frame(outcome.keys).set_index("key")
    again = run_sweep(spec, out, client=client, progress=False)
    assert again.n_executed == 0 and again.n_skipped == 12
    retry = run_sweep(spec, out, client=client, progress=False, retry=["failed"])
    assert retry.n_executed == 8 and retry.by_status == {"failed": 8}
    with ResultStore(out / STORE_NAME) as store:
        after = store.frame(outcome.keys).set_index("key")
        attempts = store.attempts()
    assert len(after) == 12 and after.index.is_unique
    conv = before.index[before["status"] == "converged"]
    # converged rows untouched; failed rows replaced by the retry session
    pd.testing.assert_frame_equal(after.loc[conv], before.loc[conv])
    assert set(after.drop(conv)["session"]) == {retry.session}
    failed = before.index.difference(conv)
    assert (after.loc[failed, "started_at"] > before.loc[failed, "finished_at"].max()).all()  # executed again
    assert not {k for k, s, _ in attempts if s == again.session}
    assert {k for k, s, _ in attempts if s == retry.session} == set(before.drop(conv).index) - set(
        before.index[before["scene"] == "no_such_scene"])


def test_csv_and_parquet_exports_round_trip(finished, tmp_path):
    spec, outcome, out = finished
    with ResultStore(out / STORE_NAME) as store:
        df = store.frame(outcome.keys)
        csv = store.export_csv(tmp_path / "r.csv", outcome.keys)
        pq = store.export_parquet(tmp_path / "r.parquet", outcome.keys)
    assert list(df.columns) == list(COLUMN_NAMES)
    for path in (csv, pq):
        back = read_export(path)
        pd.testing.assert_frame_equal(back, df, check_exact=True)


def test_report_writes_table_and_plots(finished, tmp_path):
    from selfsupport.sweep.report import write_report

    spec, outcome, out = finished
    with ResultStore(out / STORE_NAME) as store:
        df = store.frame(outcome.keys)
    rep = write_report(df, spec.report, tmp_path, title="t")
    text = rep.markdown.read_text()
    lines = [ln for ln in rep.table.splitlines() if ln.startswith("| ") and not ln.startswith("| scene")]
    assert len(lines) == 6  # 3 scenes x 2 bounds
    cells = {(c[0], c[1]): c for c in ([x.strip() for x in ln.strip("|").split("|")] for ln in lines)}
    # runs / converged / success % / errors per group
    assert cells[("dome?n_vertices=200", "none")][2:6] == ["2", "2", "100", "0"]
    assert cells[("dome?n_vertices=200", "1e-09")][2:6] == ["2", "0", "0", "2"]
    assert "## Errors" in text and "InputError: w_max" in text
    assert len(rep.plots) == 3
    for p in rep.plots:
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
        assert f"plots/{p.name}" in text


# --------------------------------------------------------------------- kill + resume
def _rows(db: Path) -> int:
    if not db.exists():
        return 0
    con = sqlite3.connect(db, timeout=5)
    try:
        return int(con.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
    except sqlite3.Error:  # the table is not created yet
        return 0
    finally:
        con.close()


def test_sigkill_mid_sweep_then_resume_loses_and_repeats_nothing(tmp_path):
    import psutil
    sweep = tmp_path / "sweep.toml"
    # 3 shapes x 4 densities = 12 runs of ~0.2-1 s on 2 workers
    sweep.write_text(sweep_text(scenes=SHAPES + ['"shape:barrel_vault?n_vertices=200"'],
                                grid="density = [1000.0, 1500.0, 2000.0, 4000.0]"))
    expected = 12
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "selfsupport.cli.sweep", str(sweep), "--out", str(out), "--workers", "2",
           "--quiet", "--no-report"]
    db = out / STORE_NAME
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while _rows(db) < 2:
            assert proc.poll() is None, f"sweep ended before it could be killed: {proc.stderr.read().decode()}"
            assert time.monotonic() < deadline, "no rows after 120 s"
            time.sleep(0.02)
        children = psutil.Process(proc.pid).children(recursive=True)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    n_first = _rows(db)
    assert 2 <= n_first < expected, f"kill landed after the sweep finished ({n_first} rows); make the runs longer"
    # the worker processes notice that their parent is gone and exit
    gone, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, f"orphaned worker processes: {alive}"

    with ResultStore(db) as store:
        first = store.frame().set_index("key")
    done = subprocess.run(cmd, capture_output=True, timeout=240)
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    with ResultStore(db) as store:
        final = store.frame().set_index("key")
        attempts = store.attempts()
        sessions = store.sessions()
    con = sqlite3.connect(db)
    n, distinct = con.execute("SELECT COUNT(*), COUNT(DISTINCT key) FROM runs").fetchone()
    con.close()
    plan = plan_runs(parse_spec(sweep.read_text(), source=sweep))
    assert n == distinct == expected and set(final.index) == set(plan.keys)  # nothing lost, nothing doubled
    # runs finished before the kill were not executed again: their rows (worker pid, start time,
    # session) are unchanged and the second session did not even submit them
    pd.testing.assert_frame_equal(final.loc[first.index], first)
    s1, s2 = sessions[0][0], sessions[-1][0]
    assert len(sessions) == 2 and sessions[-1][3] == expected - n_first
    resubmitted = {k for k, s, _ in attempts if s == s2}
    assert not resubmitted & set(first.index)
    assert resubmitted == set(plan.keys) - set(first.index)
    assert set(final.drop(first.index)["session"]) == {s2} and set(first["session"]) == {s1}
    assert set(final["status"]) == {"converged"}


# ------------------------------------------------------------------------ hard limit
def test_hard_time_limit_records_timeout_and_the_sweep_goes_on(client, tmp_path):
    """A budget far below the solve time and no grace: the backstop fires while the run is still
    validating and setting up its scene (0.3-0.5 s at 40k vertices, before any deadline check;
    at 2k vertices a solve whose time limit has passed now ends within the backstop's 0.05 s
    poll), cancels the run, restarts its worker and writes a timeout row; the cluster then runs
    the next sweep."""
    from selfsupport.sweep.runner import run_sweep

    spec = parse_spec(sweep_text(scenes=['"shape:pillar_vault?n_vertices=40000"'], grid="density = [2000.0]",
                                 budget=0.001, grace=0.0), scene_dir=tmp_path)
    first = run_sweep(spec, tmp_path / "a", client=client, progress=False)
    assert first.by_status == {"timeout": 1}
    with ResultStore(tmp_path / "a" / STORE_NAME) as store:
        row = store.frame().iloc[0]
    assert "worker restarted" in row["message"] and row["worker"].startswith("tcp://")
    again = run_sweep(parse_spec(sweep_text(grid="density = [2000.0]"), scene_dir=tmp_path), tmp_path / "b",
                      client=client, progress=False)
    assert again.by_status == {"converged": 2}


PAPER_SCENES = SHARED / "paper-scenes" / "scenes"


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parents[1] / "studies").glob("*.toml")),
                         ids=lambda p: p.name)
def test_shipped_sweep_files_parse_and_expand(path):
    """The sweep files under studies/ are valid: every scene is found, every method and
    option is known, and the expansion has the documented size."""
    from selfsupport.methods.staggered import StaggeredOptions
    from selfsupport.sweep import load_spec

    text = path.read_text(encoding="utf-8")
    if "paper-scenes" in text or "--scenes" in text:
        if not PAPER_SCENES.is_dir():
            pytest.skip("the paper scenes (../shared) are not beside the repository")
        spec = load_spec(path, scene_dir=PAPER_SCENES)
    else:
        spec = load_spec(path)
    runs = spec.expand()
    assert runs and len({r.scene for r in runs}) == len(spec.scenes)
    for r in runs:
        if r.method == "staggered":
            assert {k for k, _ in r.options} <= set(StaggeredOptions.__dataclass_fields__)
    if path.name == "sweep_schedule.toml":  # 6 scenes × 4 shrink × 2 refine (the README's 48 runs)
        assert len(runs) == 48 and {dict(r.options)["shrink"] for r in runs} == {0.5, 0.35, 0.25, 0.15}


def test_a_sweep_above_the_confirmation_count_needs_yes(tmp_path, capsys):
    """40 densities × 30 thicknesses = 1,200 runs: refused in one line that gives the count and
    --yes, before any scene is loaded or anything is written."""
    from selfsupport.cli import main

    grid = (f"density = [{', '.join(str(1000.0 + k) for k in range(40))}]\n"
            f"thickness = [{', '.join(str(0.1 + k / 100) for k in range(30))}]")
    path = tmp_path / "big.toml"
    path.write_text(sweep_text(scenes=['"shape:dome?n_vertices=200"'], grid=grid))
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "1,200 runs" in err and "--yes" in err and not out.exists()


def test_the_stderr_count_agrees_with_the_summary(tmp_path, capsys):
    """Runs whose scene cannot be loaded are recorded without a cluster; the line on stderr and
    the table on stdout give the same number of runs, stored and to do."""
    from selfsupport.cli import main

    (tmp_path / "broken.obj").write_text("v 0 0 0\nf 1 2 3\n")
    path = tmp_path / "s.toml"
    path.write_text(sweep_text(scenes=['"broken.obj"'], grid="density = [1000.0, 2000.0, 3000.0]"))
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--no-report"]) == 0
    cap = capsys.readouterr()
    assert "sweep: 3 runs, 0 already stored, 3 to do now" in cap.err
    rows = dict(line.split(None, 1) for line in cap.out.splitlines()[1:] if line.startswith(("runs", "executed")))
    assert rows["runs"].strip() == "3" and rows["executed"].split()[-1] == "3"
