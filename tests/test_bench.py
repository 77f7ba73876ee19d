"""``make bench``: the runner (:mod:`benchmarks.run`), the generated page (:mod:`benchmarks.report`)
and the committed results it is written from."""
from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import report, run
from studies import (
    bracing,
    common,
    design_latency,
    destruction,
    koebe,
    load_cases,
    peers,
    planarity,
    pq,
    scaling,
    stability_dome,
    table1,
    theory_whys,
    warm_resolve,
)

ROOT = Path(__file__).resolve().parents[1]
STAMP = {"commit": "abc1234", "date": "2030-01-02T03:04:05Z", "cpu_model": "Test CPU 9000", "cores": 2,
         "load_start": "1.5 / 1.2 / 1.0"}


def _write(path: Path, rows: list[dict], keys: list[str] | None = None) -> None:
    keys = keys or list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def _table1_rows() -> list[dict]:
    return [
        {"scene": "lilium", "vertices": 1201, "edges": 3504, "method": "staggered", "backend": "active-set",
         "status": "converged", "time_s": 1.23456, "paper_time_s": 21.6, "iterations": 21,
         "max_rel_error": 6.14e-13, "dist_ref_mean": 0.021734, **STAMP},
        {"scene": "lilium", "vertices": 1201, "edges": 3504, "method": "published",
         "backend": "paper's network, weights fitted", "status": "self-supporting", "time_s": "",
         "iterations": "", "max_rel_error": 3.1e-7, "dist_ref_mean": 0.022981, **STAMP},
        {"scene": "cas", "vertices": 1535, "edges": 2976, "method": "staggered", "backend": "active-set",
         "status": "converged", "time_s": 0.5, "iterations": 13, "max_rel_error": 1.5e-13,
         "dist_ref_mean": 0.00166, **STAMP},
    ]


# ------------------------------------------------------------------------------ the page
def test_report_page_has_a_section_per_csv_with_its_stamp_and_rounded_numbers(tmp_path):
    _write(tmp_path / "table1.csv", _table1_rows())
    _write(tmp_path / "zz_other.csv", [{"a": 1, "b": "x"}])  # a CSV the report does not know
    page = report.page_markdown(tmp_path)
    assert page.index("## Table 1: the paper's scenes") < page.index("## zz_other")
    assert ("commit: abc1234; date: 2030-01-02T03:04:05Z; CPU: Test CPU 9000; cores: 2; "
            "load at start (1/5/15 min): 1.5 / 1.2 / 1.0") in page
    row = next(line for line in page.splitlines() if line.startswith("| lilium | 1201 | staggered"))
    assert "| 1.23 |" in row and "| 21.6 |" in row and "| 6.1e-13 |" in row and "| 2.17e-02 |" in row
    assert "| 1 | x |" in page  # the unknown CSV: every column as it is
    assert "commit: not recorded" in page  # ... and no stamp is said to be missing, not left out


def test_report_table1_comparison_puts_the_papers_numbers_beside_ours(tmp_path):
    rows = report.typed([{k: str(v) for k, v in r.items()} for r in _table1_rows()])
    text = report.table1_comparison(rows)
    lines = text.splitlines()
    assert lines[2] == ("| lilium (Fig. 5b) | 1201 / 3504 | 21.6 / 1.23 | 9 / 21 | 4.2e-05 / 6.1e-13 "
                        "| 2.30e-02 / 2.17e-02 |")
    assert lines[3] == "| cas (Fig. 6) | 1535 / 2976 | 17 / 0.50 | 21 / 13 | 2.7e-05 / 1.5e-13 | — / 1.66e-03 |"
    assert len([ln for ln in lines if ln.startswith("| ")]) == 3  # the header and the two scenes run
    assert "commit: abc1234" in lines[-1]


def _typed(rows: list[dict]) -> list[dict]:
    return report.typed([{k: str(v) for k, v in r.items()} for r in rows])


def _dome(found_9: bool, max_kg: float, found_10: list[bool]) -> tuple[list[dict], list[dict]]:
    series = [{"configuration": "as stored", "thickness_m": 0.1, "added_kg": 0.0, "found": False, **STAMP},
              {"configuration": "ground ring", "thickness_m": 0.1, "added_kg": 11000.0, "found": found_9,
               "outside": 0 if found_9 else 3, "max_hull_excess_m": 0.0 if found_9 else 0.25, **STAMP}]
    series += [{"configuration": "ground ring", "thickness_m": 1.0, "added_kg": kg, "found": f, **STAMP}
               for kg, f in zip((0.0, 5000.0, 10000.0, 20000.0), found_10)]
    max_load = [{"thickness_m": 0.1, "verdict": "certified", "max_load_kg": max_kg, "optimum_kg": max_kg,
                 "binding": 7, **STAMP}]
    return _typed(series), _typed(max_load)


def _verdicts(text: str) -> list[str]:
    return [ln.rsplit("|", 2)[-2].strip() for ln in text.splitlines() if ln.startswith("| Fig.")]


def test_dome_comparison_gives_each_claim_of_the_paper_its_verdict():
    """Fig. 9: found under 11,000 kg and a largest load of at least that; Fig. 10: found at 0 kg
    and not at 20,000 kg (the network leaves the hull as the load grows)."""
    text = report.dome_comparison(*_dome(True, 12000.0, [True, True, False, False]))
    assert _verdicts(text) == ["**reproduced**"] * 3
    text = report.dome_comparison(*_dome(False, 7000.0, [True, True, True, True]))
    assert _verdicts(text) == ["**not reproduced**"] * 3
    assert "no network found (3 vertices outside, up to 0.25 m)" in text
    assert "largest certified load 7,000 kg (7 vertices on the hull's faces)" in text
    assert "a network inside the hull at every one of these loads" in text
    assert "| 0.1 | 7,000 | 7,000 |" in text  # the largest load per thickness
    # the file as stored is not the experiment: its unloaded row is no Fig. 10 row
    assert "commit: abc1234" in text.splitlines()[-1]


def test_destruction_comparison_judges_cuts_and_the_collapse():
    base = {"paper_before": 1364, "paper_faces": 938, **STAMP}
    rows = _typed([
        {"thickness_m": 0.5, "step": 1, "kind": "cut", "faces": 1400, "our_stages": 1, "status": "stands",
         "paper_lost": 14, "lost_too": 14, **base},
        {"thickness_m": 0.5, "step": 3, "kind": "collapse", "faces": 1382, "our_stages": 0,
         "status": "(collapse not applied: predicted?)", "paper_lost": 448, "lost_too": 0, **base},
        {"thickness_m": 0.1, "step": 1, "kind": "cut", "faces": 1300, "our_stages": 3, "status": "stands",
         "paper_lost": 14, "lost_too": 14, **base},
        {"thickness_m": 0.1, "step": 3, "kind": "collapse", "faces": 900, "our_stages": 0,
         "status": "(collapse not applied: predicted?)", "paper_lost": 448, "lost_too": 224, **base},
    ])
    lines = report.destruction_comparison(rows).splitlines()
    assert lines[0] == "| step | the paper (faces) | ours, t = 0.5 m | ours, t = 0.1 m |"
    cut = next(ln for ln in lines if ln.startswith("| 1 |"))
    collapse = next(ln for ln in lines if ln.startswith("| 3 |"))
    # a cut stands with nothing more removed (one stage) at 0.5 m, not after a cascade at 0.1 m
    assert cut.count("**reproduced**") == 1 and cut.count("**not reproduced**") == 1
    assert "lost 0 of the paper's 448: **not reproduced**" in collapse
    assert "lost 224 of the paper's 448: **reproduced**" in collapse  # half of the paper's collapse
    assert "collapse: 1,364 → 938" in collapse


def test_koebe_comparison_needs_round_off_equilibrium_and_the_files_digits():
    eq = [{"mesh": "enneper-inscribed", "loads": "reciprocal", "alpha": a, "checker_max_rel_error": e, **STAMP}
          for a, e in ((0.0, 2e-13), (1.0, 6e-13))]
    eq.append({"mesh": "enneper-tangent", "loads": "top-view", "alpha": 1.0, "checker_max_rel_error": 0.09, **STAMP})
    pub = [{"quantity": "alpha", "value": -0.2199098, **STAMP}, {"quantity": "alpha_fit_residual", "value": 5.4e-6, **STAMP}]
    text = report.koebe_comparison(_typed(eq), _typed(pub))
    assert "to 6.0e-13 for α = 0, 1" in text  # the top-view loads are not the family's
    assert text.count("**reproduced**") == 2 and "α = -0.21991, to 5.4e-06" in text
    eq[0]["checker_max_rel_error"] = 1e-6
    pub[1]["value"] = 1e-3
    assert report.koebe_comparison(_typed(eq), _typed(pub)).count("**not reproduced**") == 2


def test_report_without_results_folder_is_one_line_and_exit_2(tmp_path):
    p = subprocess.run([sys.executable, "-m", "benchmarks.report", "--results", str(tmp_path / "none"),
                        "--page", str(tmp_path / "page.md")], cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.strip().count("\n") == 0 and "run make bench" in p.stderr
    assert not (tmp_path / "page.md").exists()


def test_the_committed_page_is_the_one_the_committed_results_give():
    assert (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8") == report.page_markdown(), \
        "docs/benchmarks.md is generated: run python -m benchmarks.report"


# --------------------------------------------------------------------------- the results
def test_every_committed_result_row_is_stamped():
    files = sorted(report.RESULTS.glob("*.csv"))
    assert {"table1.csv", "warm_resolve.csv", "design_latency.csv", "scaling.csv", "planarity.csv",
            "pq.csv", "stability_dome.csv", "stability_dome_max_load.csv", "destruction.csv", "koebe.csv",
            "koebe_published.csv", "theory_whys.csv"} <= {f.name for f in files}
    for f in files:
        rows = common.read_csv_rows(f)
        assert rows, f.name
        for r in rows:
            assert all(r.get(c.key) for c in common.STAMP_COLUMNS), (f.name, r)
            assert "+dirty" not in r["commit"], f"{f.name}: measured on uncommitted code"
            assert int(r["cores"]) >= 1 and len(r["load_start"].split(" / ")) == 3


def test_every_study_of_the_bench_writes_the_stamp_columns():
    for columns in (table1.COLUMNS, scaling.COLUMNS, scaling.FIT_COLUMNS, peers.ORIGINAL_CSV_COLUMNS,
                    warm_resolve.COLUMNS, design_latency.COLUMNS, planarity.CSV_COLUMNS, pq.CSV_COLUMNS,
                    stability_dome.CSV_COLUMNS, stability_dome.MAX_LOAD_COLUMNS, destruction.CSV_COLUMNS,
                    koebe.PUBLISHED_COLUMNS, theory_whys.COLUMNS, load_cases.COLUMNS, bracing.COLUMNS):
        assert {c.key for c in common.STAMP_COLUMNS} <= {c.key for c in columns}


def test_design_latency_writes_its_rows_stamped_with_the_scenes_size(tmp_path):
    design_latency.main(["--scene", "shape:dome:60", "--steps", "2", "--out", str(tmp_path)])
    out = common.read_csv_rows(tmp_path / "design_latency.csv")
    assert [r["interaction"] for r in out] == ["drag (height)", "drag (full)", "drag (top view)", "pin / unpin",
                                               "density"]
    stamp = common.run_stamp()
    for r in out:
        assert (r["cpu_model"], r["cores"], r["scene"], int(r["steps"])) == (
            stamp["cpu_model"], str(stamp["cores"]), "shape:dome:60", 2)
        assert int(r["vertices"]) > 0 and 0 < float(r["solve_ms"]) <= float(r["median_ms"])


def test_warm_resolve_writes_its_rows_stamped(tmp_path):
    from selfsupport.core.shapes import make_shape
    from selfsupport.io.sss import write_scene_sss

    write_scene_sss(tmp_path / "dome.sss", make_shape("dome", n_vertices=80))
    warm_resolve.main(["--scenes", str(tmp_path), "--scene", "dome", "--repeat", "1", "--out", str(tmp_path / "o")])
    out = common.read_csv_rows(tmp_path / "o" / "warm_resolve.csv")
    assert [r["edit"] for r in out] == ["height move", "full move", "top-view move", "density +10%", "pin a vertex"]
    for r in out:
        assert r["scene"] == "dome" and r["commit"] and r["date"] and r["load_start"]
        assert float(r["speedup"]) == pytest.approx(float(r["cold_s"]) / float(r["warm_s"]))


def test_scaling_exponents_carry_the_stamp_of_their_rows():
    rows = [{"shape": "dome", "method": "staggered", "status": "converged", "vertices": n, "time_s": 0.01 * n ** 1.5,
             "peak_rss_mib": 100.0 + n, "rss_before_mib": 100.0, **STAMP} for n in (1000, 4000)]
    (fit,) = scaling.exponents(rows)
    assert fit["time_exponent"] == pytest.approx(1.5) and {k: fit[k] for k in STAMP} == STAMP


# ------------------------------------------------------------------------------ the runner
def _study(module: str, csv_name: str = "x.csv") -> run.Study:
    return run.Study("probe", module, ((csv_name, "probe.csv"),), lambda s, out: [str(out)], lambda s: "")


SETTINGS = run.Settings(scenes=Path("/nonexistent/scenes"), original=Path("/nonexistent/build"),
                        checker=Path("/nonexistent/check.py"), scaling_sizes="1000", peers_repeat=1)


def test_a_study_without_scenes_is_skipped_with_one_line_and_its_results_kept(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    (results / "table1.csv").write_text("kept\n", encoding="utf-8")
    lines: list[str] = []
    by_name = {s.name: s for s in run.STUDIES}
    for name in ("table1", "peers", "pq"):
        assert run.run_study(by_name[name], SETTINGS, work=tmp_path / "work", results=results,
                             log=lines.append) == "skipped"
    assert len(lines) == 3 and all("skipped: no scenes folder /nonexistent/scenes" in ln for ln in lines)
    assert (results / "table1.csv").read_text(encoding="utf-8") == "kept\n"
    assert not (tmp_path / "work").exists()


def test_the_original_tool_without_a_driver_is_skipped_with_its_reason(tmp_path):
    peers_study = next(s for s in run.STUDIES if s.name == "peers")
    here = run.Settings(scenes=tmp_path, original=tmp_path / "build", checker=SETTINGS.checker,
                        scaling_sizes="1000", peers_repeat=1)
    lines: list[str] = []
    assert run.run_study(peers_study, here, work=tmp_path / "w", results=tmp_path / "r", log=lines.append) == "skipped"
    assert lines == [f"bench: peers skipped: no driver of the original tool at {tmp_path / 'build'}; build it with "
                     "../shared/original-tool/build.sh OUT and pass --original-driver OUT (make bench: ORIGINAL=OUT)"]


def test_a_failing_study_leaves_the_committed_csv_and_the_next_one_runs(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    (results / "probe.csv").write_text("good\n", encoding="utf-8")
    lines: list[str] = []
    # a module that does not exist: python -m exits 1
    assert run.run_study(_study("studies.no_such_study"), SETTINGS, work=tmp_path / "w", results=results,
                         log=lines.append) == "failed"
    assert (results / "probe.csv").read_text(encoding="utf-8") == "good\n"
    assert "probe failed (exit status 1" in lines[-1]
    # a study that exits 0 but writes no CSV fails too, and a stale CSV of an earlier run is not taken
    (tmp_path / "w" / "probe").mkdir(parents=True)
    (tmp_path / "w" / "probe" / "x.csv").write_text("stale\n", encoding="utf-8")
    # (the standard library's ``this`` prints a poem and exits 0)
    assert run.run_study(_study("this"), SETTINGS, work=tmp_path / "w", results=results,
                         log=lines.append) == "failed"
    assert "it wrote no x.csv" in lines[-1] and (results / "probe.csv").read_text(encoding="utf-8") == "good\n"


def test_unknown_study_name_is_one_line_and_exit_2(tmp_path):
    p = subprocess.run([sys.executable, "-m", "benchmarks.run", "--scenes", str(tmp_path), "--original",
                        str(tmp_path), "--checker", str(tmp_path), "--only", "tabel1"],
                       cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.strip() == (
        "bench: unknown study tabel1; choose from " + ", ".join(s.name for s in run.STUDIES))


# ------------------------------------------------------------------------------ the site
def _hooks():
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_paper_page_shows_every_comparison_from_the_committed_csvs():
    page = (ROOT / "docs" / "guide" / "paper.md").read_text(encoding="utf-8")
    md = _hooks().on_page_markdown(page, None, None, None)
    assert "<!-- bench-" not in md
    for name in ("stability_dome.csv", "stability_dome_max_load.csv", "destruction.csv", "koebe.csv"):
        commit = common.read_csv_rows(report.RESULTS / name)[0]["commit"]
        assert f"*benchmarks/results/{name}* — commit: {commit}" in md, name
    assert md.count("| Fig. 9, t = 0.1 m") == 2 and md.count("| Fig. 10, t = 1 m") == 1


def test_the_paper_page_shows_table1_from_the_committed_csv():
    page = (ROOT / "docs" / "guide" / "paper.md").read_text(encoding="utf-8")
    assert page.count("<!-- bench-table1 -->") == 1 and "| lilium (Fig. 5b) |" not in page  # no copy by hand
    md = _hooks().on_page_markdown(page, None, None, None)
    csv_rows = common.read_csv_rows(report.RESULTS / "table1.csv")
    for r in csv_rows:
        if (r["method"], r["backend"]) == ("staggered", "active-set"):
            p = common.PAPER_TABLE1[r["scene"]]
            line = next(ln for ln in md.splitlines() if ln.startswith(f"| {r['scene']} ({p.figure}) |"))
            assert f"| {p.time_s:g} / {float(r['time_s']):.2f} |" in line
            assert f"| {p.iterations} / {r['iterations']} |" in line
            assert f"/ {float(r['max_rel_error']):.1e} |" in line
    assert f"commit: {csv_rows[0]['commit']}" in md


@pytest.mark.slow
def test_the_site_builds_strict_with_the_generated_pages(tmp_path):
    p = subprocess.run([str(Path(sys.executable).parent / "mkdocs"), "build", "--strict", "--quiet",
                        "--site-dir", str(tmp_path / "site")], cwd=ROOT, capture_output=True, text=True,
                       env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert p.returncode == 0, p.stderr[-2000:]
    html = (tmp_path / "site" / "benchmarks" / "index.html").read_text(encoding="utf-8")
    assert "Table 1: the paper" in html and "load at start" in html
    paper = (tmp_path / "site" / "guide" / "paper" / "index.html").read_text(encoding="utf-8")
    assert "lilium (Fig. 5b)" in paper


def test_the_bench_outputs_do_not_make_the_stamp_dirty(tmp_path):
    """``make bench`` writes each study's CSVs into the checkout before the next study runs: those
    outputs must not stamp the next study "+dirty", any other change must."""
    def git(*args: str) -> None:
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True)

    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    (tmp_path / "docs").mkdir()
    files = {"benchmarks/results/table1.csv": "a\n", "docs/benchmarks.md": "# page\n", "code.py": "x = 1\n"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    git("init", "-q")
    git("add", "-A")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "start")
    clean = common.git_commit(tmp_path)
    assert clean != "unknown" and not clean.endswith("+dirty")
    (tmp_path / "benchmarks/results/table1.csv").write_text("b\n")
    (tmp_path / "docs/benchmarks.md").write_text("# new page\n")
    assert common.git_commit(tmp_path) == clean
    (tmp_path / "code.py").write_text("x = 2\n")
    assert common.git_commit(tmp_path) == clean + "+dirty"
