"""The command line: solve / check / demo end to end, judged by recomputing equilibrium from the
written JSON with plain numpy (and by the shared independent checker when present); exit codes
and one-line errors for bad input, in-process and in a real subprocess; Ctrl-C; the subcommand
registry; the progress display."""
from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import selfsupport.cli.common as cli_main
from selfsupport import cli
from selfsupport.core.shapes import make_shape
from selfsupport.io import write_mesh
from tests.conftest import SHARED, document_check, independent_check, requires_checker

G = 9.81


# ---------------------------------------------------------------------------- helpers
def boundary_vertices(faces: list[list[int]], n: int) -> np.ndarray:
    """Vertices on edges used by exactly one face (computed here, not by the project)."""
    count: dict[tuple[int, int], int] = {}
    for f in faces:
        for a, b in zip(f, f[1:] + f[:1]):
            k = (min(a, b), max(a, b))
            count[k] = count.get(k, 0) + 1
    m = np.zeros(n, bool)
    for (a, b), c in count.items():
        if c == 1:
            m[[a, b]] = True
    return m


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``python -m selfsupport ARGS`` in a real process (exercises __main__ and the exit code)."""
    return subprocess.run([sys.executable, "-m", "selfsupport", *args], capture_output=True, text=True,
                          timeout=timeout)


def assert_one_line_error(err: str, code: int, expected_code: int, *, needle: str = "") -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == expected_code, err
    assert len(lines) == 1, err
    assert lines[0].startswith("selfsupport: error: "), err
    assert "Traceback" not in err
    assert needle.lower() in lines[0].lower()


@pytest.fixture(scope="module")
def barrel_obj(tmp_path_factory) -> Path:
    """A 300-vertex catenary barrel vault as OBJ; its supports are exactly its boundary."""
    p = tmp_path_factory.mktemp("mesh") / "barrel.obj"
    write_mesh(p, make_shape("barrel_vault", n_vertices=300).mesh)
    return p


@pytest.fixture(scope="module")
def solved(barrel_obj, tmp_path_factory):
    """``selfsupport solve barrel.obj --supports boundary`` run in-process once for the module."""
    out = tmp_path_factory.mktemp("solve") / "net.json"
    return out, cli.main(["solve", str(barrel_obj), "--supports", "boundary", "--out", str(out), "--quiet"])


# ------------------------------------------------------------------------------ solve
def test_solve_writes_a_network_in_equilibrium_with_loads_of_its_geometry(solved, barrel_obj):
    out, code = solved
    assert code == 0
    d = json.loads(out.read_text())
    chk = document_check(d)
    assert d["status"] == "converged"
    assert chk["max_rel"] <= 1e-8
    assert chk["min_w"] >= 0.0
    # loads are the self-weight ρ t g × area of the *final* geometry (default ρ = 2000, t = 0.1)
    assert chk["total_load"] == pytest.approx(-2000 * 0.1 * G * chk["area"], rel=1e-9)
    # supports: the OBJ's boundary, held at their reference positions
    ref = np.asarray(d["reference_vertices"])
    assert np.array_equal(chk["supports"], boundary_vertices(d["faces"], len(ref)))
    diag = np.linalg.norm(ref.max(axis=0) - ref.min(axis=0))
    assert np.abs(np.asarray(d["vertices"])[chk["supports"]] - ref[chk["supports"]]).max() <= 1e-13 * diag
    # the file's own evidence agrees with the recomputation
    assert d["max_relative_error"] == pytest.approx(chk["max_rel"], rel=1e-6, abs=1e-15)
    assert d["parameters"]["loads"] == {"type": "self_weight", "density": 2000.0, "thickness": 0.1, "g": G}
    assert d["scene"]["supports_from"] == "boundary"


@requires_checker
def test_solve_output_passes_the_shared_checker(solved):
    out, _ = solved
    chk = independent_check(out, tol=1e-8, unit_weight=2000 * 0.1 * G, load_tol=1e-9)
    assert chk.returncode == 0, chk.stdout
    assert chk.ok


def test_solve_summary_reports_the_written_numbers(barrel_obj, tmp_path, capsys):
    out = tmp_path / "n.json"
    assert cli.main(["solve", str(barrel_obj), "--supports", "boundary", "--out", str(out), "-q",
                     "--density", "2400", "--thickness", "0.2"]) == 0
    text = capsys.readouterr().out
    d = json.loads(out.read_text())
    chk = document_check(d)
    assert chk["total_load"] == pytest.approx(-2400 * 0.2 * G * chk["area"], rel=1e-9)
    row = next(ln for ln in text.splitlines() if ln.startswith("max relative error"))
    assert float(row.split()[-1]) == pytest.approx(chk["max_rel"], rel=1e-3, abs=1e-15)
    for key in ("vertices", "edges", "method", "backend", "status", "iterations", "min weight",
                "distance to reference mean", "distance to reference max"):
        assert any(ln.startswith(key) for ln in text.splitlines()), key
    assert f"{len(d['vertices'])}" in next(ln for ln in text.splitlines() if ln.startswith("vertices"))


def test_iteration_limit_still_writes_the_network_labelled_and_exits_5(tmp_path, capsys):
    out = tmp_path / "limit.json"
    code = cli.main(["solve", "shape:pillar_vault:300", "--out", str(out), "--max-iter", "2", "-q"])
    err = capsys.readouterr().err
    d = json.loads(out.read_text())
    assert code == cli.EXIT_CODES["limit"] == 5
    assert d["status"] == "iteration_limit"
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "NOT converge" in lines[0] and "--max-iter" in lines[0]
    # the stopped run is polished (weights frozen, positions exact), so the line must not claim
    # it is out of equilibrium when it is not
    assert document_check(d)["max_rel"] <= 1e-8
    assert "in equilibrium" in lines[0] and "not the solution nearest" in lines[0]


def test_a_network_out_of_equilibrium_is_written_labelled_and_exits_4(tmp_path, capsys, monkeypatch):
    from selfsupport import api
    from selfsupport.core.result import Network, SolveResult

    scene = make_shape("dome", n_vertices=100)
    net = Network(mesh=scene.mesh, weights=np.ones(scene.mesh.n_edges), loads=-np.ones(scene.mesh.n_vertices),
                  supports=scene.supports, reference=scene.mesh)
    fake = SolveResult.build(net, status="stalled", method="staggered", backend="active-set", iterations=7,
                             wall_time=0.1, message="no step helps", parameters={"tol": 1e-9})
    monkeypatch.setattr(api, "solve", lambda *a, **k: fake)
    out = tmp_path / "stalled.json"
    code = cli.main(["solve", "shape:dome:100", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 4
    d = json.loads(out.read_text())
    assert d["status"] == "stalled"
    assert document_check(d)["max_rel"] == pytest.approx(fake.max_relative_error)
    assert len(err) == 1 and "NOT in equilibrium" in err[0] and "try" in err[0]


def test_a_design_in_site_coordinates_is_told_to_move_to_the_origin(tmp_path, capsys):
    """A vault 10⁶ m from the origin can only be balanced to ~1e-7 in its own coordinates: the
    line says so and what to do (translate it), not the stalled solve's usual hint."""
    scene = make_shape("pillar_vault", n_vertices=600)
    obj, sup = tmp_path / "site.obj", tmp_path / "site.sup"
    write_mesh(obj, scene.mesh.with_vertices(scene.mesh.vertices + [1e6, 3e5, 0.0]))
    sup.write_text("\n".join(str(i) for i in np.flatnonzero(scene.supports)) + "\n")
    out = tmp_path / "site.json"
    code = cli.main(["solve", str(obj), "--supports", str(sup), "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 4 and len(err) == 1
    assert "translate it near the origin" in err[0] and "see the message" in err[0] and "ipopt" not in err[0]
    d = json.loads(out.read_text())
    assert d["status"] == "stalled" and 1e-9 < document_check(d)["max_rel"] < 1e-6


@pytest.mark.parametrize("n, suggested", [(100, False), (6500, True)])
def test_a_stalled_big_mesh_is_pointed_to_the_multilevel_method(tmp_path, capsys, monkeypatch, n, suggested):
    """Above the multilevel method's one-level size, a stalled staggered solve's line suggests it
    (subdivided paper scenes, 28k quads, stalled there and converge by levels); below, not."""
    from selfsupport import api
    from selfsupport.core.result import Network, SolveResult
    from selfsupport.methods.multilevel import DIRECT_MAX

    scene = make_shape("dome", n_vertices=n)
    assert (scene.mesh.n_vertices > DIRECT_MAX) == suggested
    net = Network(mesh=scene.mesh, weights=np.ones(scene.mesh.n_edges), loads=-np.ones(scene.mesh.n_vertices),
                  supports=scene.supports, reference=scene.mesh)
    fake = SolveResult.build(net, status="stalled", method="staggered", backend="active-set", iterations=57,
                             wall_time=0.1, message="the fit error stopped falling", parameters={"tol": 1e-9})
    monkeypatch.setattr(api, "solve", lambda *a, **k: fake)
    code = cli.main(["solve", f"shape:dome:{n}", "--out", str(tmp_path / "n.json"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 4 and len(err) == 1
    assert ("try --method multilevel" in err[0]) == suggested
    # (IPOPT is suggested only for meshes it can solve)
    assert ("--method ipopt" in err[0]) == (n <= cli.IPOPT_HINT_MAX)
    assert "try more or other supports" in err[0] or n <= cli.IPOPT_HINT_MAX


def test_solve_subdivides_the_design_and_solves_it_on_the_designers_levels(tmp_path):
    """``--subdivide K``: the design refined by K Catmull–Clark steps is what is solved (the same
    supports), by default (auto) with the multilevel method on levels that are the design and its steps;
    the file stands by the independent checker. A network file's *design* is subdivided (its
    stored reference), not its network."""
    from selfsupport.core.subdivision import subdivide_scene

    out = tmp_path / "fine.json"
    code = cli.main(["solve", "shape:pillar_vault:450", "--subdivide", "2", "--out", str(out), "-q"])
    assert code == 0
    expected = subdivide_scene(make_shape("pillar_vault", n_vertices=450), 2)
    doc = json.loads(out.read_text())
    assert np.array_equal(np.asarray(doc["reference_vertices"]), expected.mesh.vertices)
    assert sorted(doc["supports"]) == np.flatnonzero(expected.supports).tolist()
    assert doc["method"] == "multilevel"
    assert "subdivided" in doc["parameters"]["method_choice"]["why"]  # (the default chose it, and says why)
    levels = doc["parameters"]["multilevel"]["levels"]
    assert expected.mesh.n_vertices > 6000 and [lv["coarsening"] for lv in levels] == ["subdivision", None]
    assert independent_check(out).ok
    coarse, again = tmp_path / "coarse.json", tmp_path / "again.json"
    assert cli.main(["solve", "shape:pillar_vault:150", "--out", str(coarse), "-q"]) == 0
    assert cli.main(["solve", str(coarse), "--subdivide", "1", "--out", str(again), "-q"]) == 0
    design = make_shape("pillar_vault", n_vertices=150)
    ref = np.asarray(json.loads(again.read_text())["reference_vertices"])
    assert np.allclose(ref, subdivide_scene(design, 1).mesh.vertices, atol=1e-12)
    solved = np.asarray(json.loads(coarse.read_text())["vertices"])
    assert np.abs(solved - design.mesh.vertices).max() > 1e-3  # (so the two would differ)


# ------------------------------------------------------------------------- bad input
def _bad_inputs(tmp: Path) -> dict[str, tuple[list[str], str]]:
    (tmp / "garbage.obj").write_text("this is not a mesh\n\x00\x01 binary junk\n")
    (tmp / "nan.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nv 1 1 1\nf 1 2 3\nf 2 4 3\n")
    (tmp / "nosup.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\nf 1 2 3\nf 2 4 3\n")
    return {
        "missing file": ([str(tmp / "missing.obj"), "--supports", "boundary"], "no such file"),
        "garbage file": ([str(tmp / "garbage.obj"), "--supports", "boundary"], "garbage.obj"),
        "NaN coordinate": ([str(tmp / "nan.obj"), "--supports", "boundary"], "nan"),
        "no supports": ([str(tmp / "nosup.obj")], "supports"),
    }


@pytest.mark.parametrize("case", ["missing file", "garbage file", "NaN coordinate", "no supports"])
def test_bad_input_in_process_one_line_exit_2_output_kept(case, tmp_path, capsys):
    args, needle = _bad_inputs(tmp_path)[case]
    out = tmp_path / "existing.json"
    out.write_text("precious")
    code = cli.main(["solve", *args, "--out", str(out)])
    cap = capsys.readouterr()
    assert_one_line_error(cap.err, code, 2, needle=needle)
    assert out.read_text() == "precious"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize("case", ["NaN coordinate", "no supports"])
def test_bad_input_in_a_real_process(case, tmp_path):
    args, needle = _bad_inputs(tmp_path)[case]
    out = tmp_path / "existing.json"
    out.write_text("precious")
    p = run_cli("solve", *args, "--out", str(out))
    assert_one_line_error(p.stderr, p.returncode, 2, needle=needle)
    assert p.stdout == ""
    assert out.read_text() == "precious"


@pytest.mark.parametrize("argv, needle, code", [
    (["solve", "shape:dome:100"], "--out", 2),                               # missing option
    (["frobnicate"], "invalid choice", 2),                                   # unknown command
    (["solve", "shape:dome:100", "--out", "x.json", "--density", "-1"], "positive", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--max-iter", "1.5"], "integer", 2),
    (["solve", "shape:nope", "--out", "x.json"], "unknown shape", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--backend", "nope"], "unknown backend", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--up", "w"], "up", 2),
    (["check", "missing.json"], "no such file", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--option", "nope=1"], "KEY=VALUE", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--option", "coupled=maybe"], "bool", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--option", "shrink=nan"], "finite", 2),
    (["solve", "shape:dome:100", "--out", "x.json", "--method", "ipopt", "--option", "coupled=1"], "staggered", 2),
])
def test_usage_errors_are_one_line(argv, needle, code, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc = cli.main(argv)
    assert_one_line_error(capsys.readouterr().err, rc, code, needle=needle)
    assert not (tmp_path / "x.json").exists()


def test_out_that_is_a_directory_fails_before_solving(tmp_path, capsys, monkeypatch):
    from selfsupport import api

    monkeypatch.setattr(api, "solve", lambda *a, **k: pytest.fail("solved although the output is unwritable"))
    rc = cli.main(["solve", "shape:dome:100", "--out", str(tmp_path)])
    assert_one_line_error(capsys.readouterr().err, rc, 2, needle="directory")


def test_unexpected_exception_one_line_exit_1_and_debug_reraises(capsys, monkeypatch, tmp_path):
    from selfsupport import api

    def boom(*a, **k):
        raise RuntimeError("kaboom\nsecond line")

    monkeypatch.setattr(api, "solve", boom)
    out = tmp_path / "x.json"
    rc = cli.main(["solve", "shape:dome:100", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "kaboom second line" in err[0] and "--debug" in err[0]
    with pytest.raises(RuntimeError, match="kaboom"):
        cli.main(["solve", "shape:dome:100", "--out", str(out), "--debug"])
    assert not out.exists()


def test_keyboard_interrupt_exit_130_nothing_written(capsys, monkeypatch, tmp_path):
    from selfsupport import api

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(api, "solve", interrupted)
    out = tmp_path / "x.json"
    out.write_text("precious")
    assert cli.main(["solve", "shape:dome:100", "--out", str(out)]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "interrupted" in err[0]
    assert out.read_text() == "precious"


@pytest.mark.slow
def test_sigint_in_a_real_process(tmp_path):
    out = tmp_path / "x.json"
    out.write_text("precious")
    # Python keeps SIGINT ignored if its parent ignored it (background jobs of a non-interactive
    # shell do): restore the default so the child gets KeyboardInterrupt as a terminal user would.
    p = subprocess.Popen([sys.executable, "-m", "selfsupport", "solve", "shape:pillar_vault:64000", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(8.0)  # imports done (even on a loaded machine), solve under way (it takes far longer)
    assert p.poll() is None, "the solve finished before it could be interrupted; use a larger shape"
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, (p.returncode, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    # either interrupted before anything was written (old file intact) or the solver stopped
    # cleanly and wrote its best network so far, labelled as such — never a half-written file
    text = out.read_text()
    if text != "precious":
        net = json.loads(text)
        assert net["status"] == "interrupted"
        assert document_check(net)["max_rel"] <= 1e-8
    assert not [q for q in tmp_path.iterdir() if q.name.endswith(".tmp")]


# ------------------------------------------------------------------------------ check
def test_check_says_self_supporting_for_a_solved_network(solved, capsys):
    out, _ = solved
    rc = cli.main(["check", str(out)])
    text = capsys.readouterr().out
    assert rc == 0
    assert "self-supporting: the stored weights" in text and "compressive weights fitted" in text
    # the stored weights are evaluated as they are, too
    stored = next(ln for ln in text.splitlines() if ln.startswith("stored weights: max relative error (stored"))
    assert float(stored.split()[-1]) == pytest.approx(document_check(json.loads(out.read_text()))["max_rel"],
                                                      rel=1e-3, abs=1e-15)


def test_check_says_not_self_supporting_when_a_vertex_sits_below_its_neighbours(solved, tmp_path, capsys):
    """Compression can only push a vertex *up* toward neighbours above it: a vertex below all its
    neighbours has Σ w (z_j − z_i) ≥ 0 > A_i F_i, so its relative error is at least 1."""
    out, _ = solved
    d = json.loads(out.read_text())
    V = np.asarray(d["vertices"])
    sup = np.zeros(len(V), bool)
    sup[d["supports"]] = True
    k = int(np.flatnonzero(~sup)[len(np.flatnonzero(~sup)) // 2])
    nbrs = {b for a, b in d["edges"] if a == k} | {a for a, b in d["edges"] if b == k}
    V[k, 2] = min(V[j, 2] for j in nbrs) - 0.05
    bent = tmp_path / "bent.obj"
    from selfsupport.core.mesh import PolyMesh

    write_mesh(bent, PolyMesh.from_faces(V, d["faces"]))
    (tmp_path / "sup.txt").write_text(" ".join(map(str, d["supports"])) + "\n")
    rc = cli.main(["check", str(bent), "--supports", str(tmp_path / "sup.txt")])
    text = capsys.readouterr().out
    assert rc == 1
    assert "NOT self-supporting" in text
    row = next(ln for ln in text.splitlines() if ln.startswith("fitted weights: max relative error"))
    assert float(row.split()[-1]) >= 1.0 - 1e-9


def test_check_of_a_reference_that_must_move_fails(barrel_obj, capsys):
    """The solve moved this vault's vertices (distance > 0), so as given it does not stand."""
    rc = cli.main(["check", str(barrel_obj), "--supports", "boundary"])
    text = capsys.readouterr().out
    row = next(ln for ln in text.splitlines() if ln.startswith("fitted weights: max relative error"))
    assert rc == 1 and float(row.split()[-1]) > 1e-6


# ------------------------------------------------------------------------------- demo
def test_demo_writes_network_and_report(tmp_path, capsys):
    out = tmp_path / "demo"
    rc = cli.main(["demo", "--out", str(out), "--vertices", "300", "-q"])
    text = capsys.readouterr().out
    assert rc == 0
    d = json.loads((out / "network.json").read_text())
    chk = document_check(d)
    assert d["status"] == "converged" and chk["max_rel"] <= 1e-8 and chk["min_w"] >= 0
    report = (out / "report.md").read_text()
    # one history row per record, plus the summary with the written error
    rows = [ln for ln in report.splitlines() if ln.startswith("| ") and ln.split("|")[1].strip().isdigit()]
    assert len(rows) == sum(1 for h in d["history"] if isinstance(h["iteration"], int))
    assert f"{d['max_relative_error']:.3e}" in report and "| polish |" in report
    assert "pillar_vault" in text and "converged" in text


@pytest.mark.slow
def test_default_demo_is_fast_and_converges(tmp_path):
    t0 = time.perf_counter()
    p = run_cli("demo", "--out", str(tmp_path / "d"), timeout=120)
    elapsed = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr
    assert elapsed < 30
    assert document_check(json.loads((tmp_path / "d" / "network.json").read_text()))["max_rel"] <= 1e-8


# ----------------------------------------------------------------- registry, progress
def test_a_registered_command_is_parsed_and_run(monkeypatch, capsys):
    seen = {}

    def add(p):
        p.add_argument("--n", type=int, default=1)

    def run(args):
        seen["n"] = args.n
        print("ran")
        return 3

    monkeypatch.setitem(cli.COMMANDS, "hello", cli.Command("say hello", add, run))
    assert cli.main(["hello", "--n", "7"]) == 3
    assert seen == {"n": 7} and capsys.readouterr().out == "ran\n"


def test_every_plugin_module_defines_commands():
    cmds = cli.discover_commands()
    assert {"solve", "check", "demo"} <= set(cmds)
    assert all(isinstance(c, cli.Command) for c in cmds.values())


def test_the_index_agrees_with_the_imported_commands():
    """The index, read from each module's source, names the module that defines each command and
    its help exactly as the imported ``Command`` says."""
    index, cmds = cli.command_index(), cli.discover_commands()
    assert list(index) == list(cmds)
    for name, entry in index.items():
        assert entry.help == cmds[name].help and cmds[name].run.__module__ == entry.module, name


_MODULES_AFTER = ("import json, sys\nfrom selfsupport.cli import main\ntry:\n    main({argv!r})\n"
                  "except SystemExit:\n    pass\nprint(json.dumps(sorted(sys.modules)), file=sys.stderr)\n")


def _modules_after(*argv: str) -> tuple[str, set[str]]:
    """The help printed by ``selfsupport ARGV`` in a fresh interpreter and the modules it imported."""
    p = subprocess.run([sys.executable, "-c", _MODULES_AFTER.format(argv=list(argv))], capture_output=True,
                       text=True, timeout=120)
    return p.stdout, set(json.loads(p.stderr.splitlines()[-1]))


def test_top_level_help_imports_neither_numpy_nor_scipy_nor_a_command_module():
    out, mods = _modules_after("--help")
    assert not {"numpy", "scipy", "casadi", "rich"} & mods
    assert {m for m in mods if m.startswith("selfsupport.cli.")} == {"selfsupport.cli.common"}
    for name, entry in cli.command_index().items():  # and yet every command is listed, with its help
        assert f"    {name}" in out and entry.help.split()[0] in out, name


_BLAS_TIMEOUT = ("import os, sys\nfrom selfsupport.cli import main\n"
                 "print(os.environ.get('OPENBLAS_THREAD_TIMEOUT'), 'numpy' in sys.modules)\n")


@pytest.mark.parametrize("user, expected", [(None, "4"), ("28", "28")])
def test_the_command_line_sends_idle_blas_threads_to_sleep_before_numpy_loads(user, expected):
    """OpenBLAS reads its threads' spin time once, when numpy (scipy, cvxopt) loads it: the command
    line sets the shortest before any of them loads, and a value the user set stays."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    if user is not None:
        env["OPENBLAS_THREAD_TIMEOUT"] = user
    p = subprocess.run([sys.executable, "-c", _BLAS_TIMEOUT], capture_output=True, text=True, timeout=120, env=env)
    assert p.stdout.split() == [expected, "False"]


#: What a plain solve of a small mesh file does not need: other methods' machinery (multilevel,
#: IPOPT's hull search and sensitivities, CasADi's symbolic expressions), the analysis,
#: scipy.optimize (a built-in shape's catenary, the polish's last fallback), plots, the browser
#: tool and the sweeps; nor scipy.spatial with scipy.special (~0.13 s: the input check's coincident
#: vertices and the smallest box's hull are numpy kernels), nor tomllib (load-case files), nor rich
#: off a terminal (its progress lines are not printed there, its summary is plain text).
NOT_FOR_A_PLAIN_SOLVE = ("casadi", "scipy.optimize", "scipy.spatial", "scipy.special", "tomllib", "rich",
                         "selfsupport.methods.multilevel",
                         "selfsupport.methods.prolong", "selfsupport.methods.simultaneous", "selfsupport.methods.sensitivity", "selfsupport.analysis",
                         "selfsupport.structure", "selfsupport.figures", "matplotlib", "plotly", "starlette", "dask")


@pytest.mark.parametrize("quiet", [("--quiet",), ()])
def test_a_plain_solve_imports_only_what_it_needs(barrel_obj, tmp_path, quiet):
    out = tmp_path / "net.json"
    summary, mods = _modules_after("solve", str(barrel_obj), "--supports", "boundary", "--out", str(out), *quiet)
    assert document_check(json.loads(out.read_text()))["max_rel"] <= 1e-8  # (it did solve)
    assert sorted(m for m in mods if m.startswith(NOT_FOR_A_PLAIN_SOLVE)) == []
    assert re.search(r"^max relative error +\S+$", summary, re.M)  # (the summary printed, without rich)


def test_a_command_imports_its_own_module_only():
    out, mods = _modules_after("view", "--help")
    assert "--open" in out or "usage: selfsupport view" in out
    assert {m for m in mods if m.startswith("selfsupport.cli.")} == {"selfsupport.cli.common", "selfsupport.cli.figures"}


def _command_module_on_path(folder, monkeypatch, name: str) -> None:
    """``folder`` joins the command package's path, with no module ``name`` imported from it yet."""
    import selfsupport.cli as package

    monkeypatch.setattr(package, "__path__", [*package.__path__, str(folder)])
    monkeypatch.delitem(sys.modules, f"selfsupport.cli.{name}", raising=False)


def test_a_new_module_adds_a_command_without_touching_the_core(tmp_path, monkeypatch, capsys):
    """A module dropped into the package's path is listed by ``--help`` without being imported, and
    runs when named."""
    (tmp_path / "hello.py").write_text(
        "from selfsupport.cli.common import Command\n\n\ndef add(p):\n    p.add_argument('--n', type=int)\n\n\n"
        "def run(args):\n    print('hello', args.n)\n    return 3\n\n\n"
        "COMMANDS = {\n    'hello': Command('say hello'\n                     ' to the world', add, run),\n}\n")
    _command_module_on_path(tmp_path, monkeypatch, "hello")
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    assert "say hello to the world" in " ".join(capsys.readouterr().out.split())
    assert "selfsupport.cli.hello" not in sys.modules
    assert cli.main(["hello", "--n", "7"]) == 3 and capsys.readouterr().out == "hello 7\n"
    sys.modules.pop("selfsupport.cli.hello")


def test_a_command_runs_with_what_was_imported_frozen_out_of_the_garbage_collector(tmp_path, monkeypatch, capsys):
    """While a command runs, the objects alive once it is imported (the modules: tens of
    thousands) are frozen, so no full collection walks them again, and the collector is on;
    afterwards nothing is frozen and the collector is on as before."""
    import gc

    (tmp_path / "frozen.py").write_text(
        "import gc\n\nfrom selfsupport.cli.common import Command\n\n\ndef add(p):\n    pass\n\n\n"
        "def run(args):\n    print(gc.get_freeze_count(), gc.isenabled())\n    return 0\n\n\n"
        "COMMANDS = {\n    'frozen': Command('count the frozen objects', add, run),\n}\n")
    _command_module_on_path(tmp_path, monkeypatch, "frozen")
    assert gc.get_freeze_count() == 0
    assert cli.main(["frozen"]) == 0
    frozen, enabled = capsys.readouterr().out.split()
    assert int(frozen) > 10_000 and enabled == "True"  # (numpy's and the project's modules: pytest's too)
    assert gc.get_freeze_count() == 0 and gc.isenabled()
    sys.modules.pop("selfsupport.cli.frozen")


@pytest.mark.parametrize("source, why", [
    ("x = 1\n", "no declaration"),
    ("COMMANDS = make()\n", "not a dict literal"),
    ("COMMANDS = {'a': Command(f'{HELP}', add, run)}\n", "help not a string literal"),
    ("COMMANDS = {NAME: Command('help', add, run)}\n", "name not a string literal"),
    ("COMMANDS = {'a': Command('help', add, run)\n\ndef f():\n    pass\n", "statement does not end"),
])
def test_a_declaration_the_index_cannot_read_is_refused_with_what_to_write(source, why):
    with pytest.raises(TypeError, match=r"m must declare COMMANDS as a dict literal .*the help a string literal"):
        cli.common.declared_commands(source, "m")


def test_a_module_may_not_redefine_a_command(tmp_path, monkeypatch):
    (tmp_path / "again.py").write_text("COMMANDS = {'solve': Command('solve again', add, run)}\n")
    import selfsupport.cli as package

    monkeypatch.setattr(package, "__path__", [*package.__path__, str(tmp_path)])
    with pytest.raises(TypeError, match=r"selfsupport.cli.again redefines command\(s\) \['solve'\]"):
        cli.command_index()


def _rich_table(title: str, rows, width: int) -> str:
    """``print_table``'s table as rich lays it out on a console ``width`` wide, off a terminal."""
    import io

    from rich.console import Console
    from rich.table import Table

    t = Table(title=title, show_header=False, title_justify="left", box=None, pad_edge=False)
    t.add_column(style="bold")
    t.add_column()
    for k, v in rows:
        t.add_row(k, v)
    console = Console(file=io.StringIO(), highlight=False, soft_wrap=True, width=width)
    with console.capture() as cap:
        console.print(t)
    return "".join(line.rstrip() + "\n" for line in cap.get().splitlines())


def test_the_plain_summary_table_is_the_text_rich_lays_out_off_a_terminal():
    """Off a terminal ``print_table`` writes the table without rich: the same text, wrapped at the
    same words, for tables that fit, that wrap their values (one line or several, runs of
    spaces), that wrap their keys, at several console widths; where only rich can lay it out
    (markup, emoji codes, other than printable ASCII, a word wider than its column) it says so."""
    import random

    rng = random.Random(7)

    def text(words: int) -> str:
        out = ""
        for _ in range(words):
            out += "".join(rng.choice("abcxyz0123.,-()=<") for _ in range(rng.choice([1, 2, 4, 7, 11])))
            out += rng.choice([" ", " ", "  ", "\n"])
        return out if rng.random() < 0.5 else out.strip()

    compared = wrapped = 0
    for _ in range(600):
        width = rng.choice([30, 50, 80, 120])
        rows = [(text(rng.choice([1, 2, 4, 9])), text(rng.choice([0, 1, 3, 8, 20]))) for _ in range(rng.randint(1, 5))]
        title = text(rng.choice([0, 1, 4, 15]))
        plain = cli.common.plain_table(title, rows, width)
        if plain is not None:
            compared += 1
            wrapped += any(len(k) + len(v) + 2 > width for k, v in rows)
            assert plain == _rich_table(title, rows, width), (title, rows, width)
    assert compared > 200 and wrapped > 50
    summary = [("scene", "structural"), ("method", "staggered (auto: 527 vertices <= 3,000: one level is fastest at "
                                                    "this size)"), ("max relative error", "1.640e-12")]
    assert cli.common.plain_table("selfsupport solve -> out.json", summary, 80) == _rich_table(
        "selfsupport solve -> out.json", summary, 80)
    for rows in ([("a", "[bold]x[/bold]")], [("a", "at :smile: o'clock")], [("a", "σ = 2")], [("a", "x" * 90)], []):
        assert cli.common.plain_table("t", rows, 80) is None


def test_progress_off_a_terminal_prints_nothing_and_builds_no_console(monkeypatch):
    import io

    from selfsupport.core.progress import ProgressDisplay

    monkeypatch.delenv("FORCE_COLOR", raising=False)
    monkeypatch.delenv("TTY_COMPATIBLE", raising=False)
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    p = ProgressDisplay()
    p({"iteration": 1, "max_rel_error": 0.5})
    assert p.console is None and not p.enabled and p.records == 1 and sys.stderr.getvalue() == ""


_CONSOLE_MAIN = ("import atexit, sys, threading, time\n"
                 "atexit.register(lambda: print('exit handler ran', flush=True))\n"
                 "def wait():  # (until the main thread is done: Python's own exit)\n"
                 "    while threading.main_thread().is_alive():\n"
                 "        time.sleep(0.01)\n"
                 "    print('thread finished', flush=True)\n"
                 "if sys.argv[1] == 'thread':\n"
                 "    threading.Thread(target=wait).start()\n"
                 "sys.argv = ['selfsupport', *sys.argv[2:]]\n"
                 "from selfsupport.cli import console_main\nconsole_main()\n")


@pytest.mark.parametrize("thread", [False, True])
def test_the_console_script_ends_with_the_commands_exit_code_its_output_and_exit_handlers(barrel_obj, tmp_path,
                                                                                           thread):
    """The process ends with the command's exit code, after everything it printed (through a
    pipe, buffered) and the exit handlers; a thread still running is waited for as Python does."""
    out = tmp_path / "net.json"
    p = subprocess.run([sys.executable, "-c", _CONSOLE_MAIN, "thread" if thread else "-", "solve", str(barrel_obj),
                        "--supports", "boundary", "--out", str(out), "--max-iter", "1"], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == cli.EXIT_CODES["limit"], p.stderr
    lines = p.stdout.splitlines()
    assert lines[0] == f"selfsupport solve -> {out}"
    assert any(re.match(r"max relative error +\S+$", line) for line in lines)
    assert lines[-2:] == ["thread finished", "exit handler ran"] if thread else lines[-1] == "exit handler ran"
    assert "Traceback" not in p.stderr and out.is_file()


def test_progress_prints_one_line_per_record_with_its_numbers():
    import io

    from rich.console import Console

    from selfsupport.core.progress import ProgressDisplay

    buf = io.StringIO()
    p = ProgressDisplay(console=Console(file=buf, force_terminal=True, color_system=None, width=120))
    recs = [{"iteration": 1, "max_rel_error": 0.25, "E": 3.0, "alpha": 1.0, "beta": 0.1, "accepted": True},
            {"iteration": 2, "max_rel_error": 0.0125, "E": 0.5, "alpha": 0.5, "beta": 0.05, "accepted": False},
            {"iteration": "polish", "max_rel_error": 1e-13}]
    for r in recs:
        p(r)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 1 + len(recs)
    assert lines[0].split()[:3] == ["iter", "max", "rel"]
    assert lines[2].split()[:6] == ["2", "1.25e-02", "5.00e-01", "5.00e-01", "5.00e-02", "no"]
    assert lines[3].split()[:2] == ["polish", "1.00e-13"]
    quiet = io.StringIO()
    q = ProgressDisplay(console=Console(file=quiet, force_terminal=False), enabled=None)
    q(recs[0])
    assert quiet.getvalue() == "" and q.records == 1


@pytest.mark.skipif(not (SHARED / "paper-scenes" / "scenes" / "vault-pillar.sss").exists(),
                    reason="paper scenes not present")
def test_solve_a_paper_scene(tmp_path):
    out = tmp_path / "vp.json"
    p = run_cli("solve", str(SHARED / "paper-scenes" / "scenes" / "vault-pillar.sss"), "--out", str(out))
    assert p.returncode == 0, p.stderr
    chk = document_check(json.loads(out.read_text()))
    assert chk["max_rel"] <= 1e-8 and chk["min_w"] >= 0
    assert chk["total_load"] == pytest.approx(-2000 * 0.1 * G * chk["area"], rel=1e-9)


def test_solve_report_writes_figures_and_view(tmp_path, capsys):
    out, rep = tmp_path / "net.json", tmp_path / "report"
    assert cli.main(["solve", "shape:dome:150", "--out", str(out), "--report", str(rep), "-q"]) == 0
    import matplotlib.image as mpimg

    for kind in ("network", "deviation", "history"):
        img = mpimg.imread(rep / f"{kind}.png")
        assert img.shape[0] > 400 and img.shape[1] > 400
        assert img[..., :3].std() > 0.05  # not a blank canvas
    html = (rep / "view.html").read_text()
    assert "plotly" in html.lower() and "<script src=\"http" not in html  # self-contained


def test_option_reaches_the_staggered_method(tmp_path):
    out = tmp_path / "n.json"
    rc = cli.main(["solve", "shape:pillar_vault:200", "--out", str(out), "--quiet",
                   "--option", "coupled=true", "--option", "finish-slack=0.1"])
    assert rc == 0
    params = json.loads(out.read_text())["parameters"]
    assert params["coupled"] is True and params["finish_slack"] == 0.1


def test_summary_of_a_warm_started_solve_names_its_start_without_a_stored_reference():
    """A warm start on a plain scene records only where the solve began (the pq command's finish on
    a turned vault printed ``KeyError: 'reference'`` after writing its file)."""
    from selfsupport import api

    scene = make_shape("barrel_vault", n_vertices=200)
    first = api.solve(scene)
    again = api.solve(scene, warm_start=first)
    assert set(again.parameters["design"]) == {"start"}
    rows = dict(cli.summary_rows(again, scene))
    assert rows["start"] == again.parameters["design"]["start"] and "reference" not in rows


def test_the_hint_of_an_unfinished_ipopt_solve_suggests_the_other_method():
    """An IPOPT run stopped at its iteration limit was told to "try --method ipopt"."""
    from selfsupport import api

    res = api.solve(make_shape("dome", n_vertices=100), method="ipopt", max_iter=2)
    assert res.status == "iteration_limit"
    line = cli_main._not_converged_line(res)
    assert "--method ipopt" not in line and "--method staggered" in line


@pytest.mark.parametrize("status", sorted(cli.STATUS_HINT) + ["hull"])
def test_no_hint_points_a_big_mesh_to_ipopt(status):
    """Above IPOPT_HINT_MAX vertices every hint has its IPOPT alternative struck out
    (cli_main._NO_IPOPT rewrites the phrases of STATUS_HINT and HULL_HINT: this keeps the two in step)."""
    from selfsupport.core.result import Network, SolveResult

    scene = make_shape("dome", n_vertices=cli.IPOPT_HINT_MAX + 500)
    assert scene.mesh.n_vertices > cli.IPOPT_HINT_MAX
    net = Network(mesh=scene.mesh, weights=np.ones(scene.mesh.n_edges), loads=-np.ones(scene.mesh.n_vertices),
                  supports=scene.supports, reference=scene.mesh)
    hull = {"hull": {"thickness": 0.1}} if status == "hull" else {}
    res = SolveResult.build(net, status="infeasible" if status == "hull" else status, method="multilevel",
                            backend="active-set", iterations=1, wall_time=0.1, parameters={"tol": 1e-9, **hull})
    line = cli_main._not_converged_line(res)
    assert "ipopt" not in line.lower() and "  " not in line and ", ;" not in line


def test_a_negative_vertical_axis_is_taken_after_a_space(barrel_obj, tmp_path, capsys):
    """``--up -y`` (the axis the errors suggest, written as they write it) reads the mesh as
    ``--up=-y`` does: argparse alone took ``-y`` for an unknown option. The barrel turned so that
    its rise points along -y, checked both ways: the same verdict and fitted weights as the
    barrel itself."""
    from selfsupport.io import read_mesh

    m = read_mesh(barrel_obj)
    turned = tmp_path / "turned.obj"
    V = np.asarray(m.vertices)
    write_mesh(turned, dataclasses.replace(m, vertices=np.c_[V[:, 0], -V[:, 2], V[:, 1]]))
    outs = []
    for path, up in ((turned, ["--up", "-y"]), (turned, ["--up=-y"]), (barrel_obj, [])):
        code = cli.main(["check", str(path), "--supports", "boundary", *up])
        c = capsys.readouterr()
        outs.append((code, [ln for ln in c.out.splitlines() if ln.startswith("fitted weights")], c.err))
    assert outs[0] == outs[1] == outs[2]  # (and the same as the barrel itself, read z up)
    assert len(outs[0][1]) >= 4


def test_a_point_load_on_a_support_is_warned_and_changes_nothing(tmp_path, capsys):
    """A point load on a support goes straight into the ground: the solve says so in one warning
    line naming the vertex, and the network is the one solved without that load."""
    from selfsupport.core.shapes import make_shape as shape

    scene = shape("pillar_vault", n_vertices=100)
    s = int(np.flatnonzero(scene.supports)[0])
    f = int(np.flatnonzero(~scene.supports)[0])
    outs = {}
    for name, extra in (("bare", []), ("on_support", ["--point-load", f"{s}:5000"])):
        out = tmp_path / f"{name}.json"
        assert cli.main(["solve", "shape:pillar_vault:100", "--out", str(out), "-q", *extra]) == 0
        outs[name] = (json.loads(out.read_text()), capsys.readouterr().err)
    assert f"on supports ({s})" in outs["on_support"][1] and "on supports" not in outs["bare"][1]
    assert np.array_equal(outs["bare"][0]["vertices"], outs["on_support"][0]["vertices"])
    # a load on a free vertex is no such case
    assert cli.main(["solve", "shape:pillar_vault:100", "--out", str(tmp_path / "free.json"), "-q",
                     "--point-load", f"{f}:5000"]) == 0
    assert "on supports" not in capsys.readouterr().err


# ------------------------------------------------------------------ numeric option ranges
@pytest.mark.parametrize("argv, interval", [
    (["check", "N.json", "--tol", "100"], "(0, 1]"),
    (["solve", "shape:dome", "--out", "OUT", "--tol", "2"], "(0, 1]"),
    (["solve", "shape:dome", "--out", "OUT", "--planar", "nan"], "(0, 1]"),
    (["solve", "shape:dome", "--out", "OUT", "--time-limit", "inf"], "(0, inf)"),
    (["render", "N.json", "--out", "OUT", "--elev", "nan"], "[-90, 90]"),
    (["render", "N.json", "--out", "OUT", "--azim", "inf"], "[-360, 360]"),
    (["pq", "N.json", "--out", "OUT", "--angle", "nan"], "[-360, 360]"),
    (["pq", "N.json", "--out", "OUT", "--tol", "5"], "(0, 1]"),
    (["pq", "N.json", "--out", "OUT", "--smoothing", "0"], "(0, inf)"),
    (["construct", "--disk", "3", "--out", "OUT", "--load", "5"], "(-inf, 0)"),
    (["construct", "--disk", "3", "--out", "OUT", "--boundary-height", "nan"], "(-inf, inf)"),
    (["construct", "--random", "9", "--out", "OUT", "--seed", "-1"], "[0, inf)"),
    (["stability", "shape:dome", "--thickness", "0.1", "--out", "OUT", "--max-load", "--time-limit", "-2"], "(0, inf)"),
    (["destroy", "shape:dome", "--thickness", "0.1", "--out", "OUT", "--remove", "-3"], "[0, inf)"),
    (["destroy", "shape:dome", "--thickness", "0.1", "--out", "OUT", "--remove", "3", "--max-stages", "0"],
     "[1, inf)"),
    (["design", "shape:dome", "--port", "70000"], "[0, 65535]"),
    (["design", "shape:dome", "--density", "nan"], "(0, inf)"),
])
def test_numeric_options_out_of_range_are_refused_with_the_range(tmp_path, capsys, argv, interval):
    """NaN, infinities and values outside an option's range: exit 2 before any work, one line that
    names the option and its range, nothing written."""
    out = tmp_path / "out"
    code = cli.main([str(out) if a == "OUT" else str(tmp_path / a) if a == "N.json" else a for a in argv])
    err = capsys.readouterr().err
    option = next(a for a in reversed(argv) if a.startswith("--"))
    assert_one_line_error(err, code, 2, needle=f"argument {option}")
    assert interval in err and not out.exists()


def test_a_negative_number_in_e_notation_is_taken_as_the_option_value(tmp_path, capsys):
    out = tmp_path / "net.json"
    assert cli.main(["construct", "--disk", "3", "--load", "-1e3", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["construction"]["load"] == -1000.0


@pytest.mark.parametrize("option", ["--extra-mass=3:-1e9", "--point-load=3:-1e9"])
def test_an_upward_extra_load_is_named_as_such_not_as_a_zero_area(tmp_path, capsys, option):
    out = tmp_path / "net.json"
    code = cli.main(["solve", "shape:dome:80", "--out", str(out), option])
    err = capsys.readouterr().err
    assert_one_line_error(err, code, 2, needle="vertex 3 carries a net upward load")
    assert "zero area" not in err and not out.exists()


@pytest.mark.parametrize("name", ["result.txt", "result"])
@pytest.mark.parametrize("command", [["solve", "shape:dome:80"], ["koebe"], ["construct", "--disk", "2"]])
def test_out_with_a_suffix_no_writer_has_is_refused_before_any_work(tmp_path, capsys, monkeypatch, command, name):
    from selfsupport import api

    monkeypatch.setattr(api, "solve", lambda *a, **k: pytest.fail("solved although --out cannot be written"))
    out = tmp_path / name
    code = cli.main([*command, "--out", str(out)])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle=".json")
    assert not out.exists()


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".off", ".sss", ".compas.json"])
def test_out_in_every_format_reads_back_to_the_network_the_json_holds(tmp_path, capsys, suffix):
    """``--out NET.obj`` (and .ply, .off, .sss, .compas.json) writes that format, not JSON under
    its suffix, and reads back to the network ``--out NET.json`` writes: weights, loads and
    supports included. A format that leaves something out says in one stderr line where the
    rest is (OBJ/OFF: the side files)."""
    from selfsupport.io import read_network

    out, ref = tmp_path / f"net{suffix}", tmp_path / "net.json"
    assert cli.main(["construct", "--disk", "2", "--out", str(ref)]) == 0
    assert cli.main(["construct", "--disk", "2", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    if suffix in (".obj", ".off"):
        assert err.count("\n") == 1 and "net.weights.csv" in err and "net.vertices.csv" in err
    assert not out.read_bytes().lstrip().startswith(b"{") or suffix == ".compas.json"
    back, net = read_network(out), read_network(ref)
    np.testing.assert_array_equal(back.vertices, net.vertices)
    assert back.mesh.faces == net.mesh.faces
    for key in ("weights", "loads", "supports"):
        np.testing.assert_array_equal(getattr(back, key), getattr(net, key))
