"""Limits that hold: the time limit inside every inner loop, and the
memory guard before any allocation.

The whole-run test slows Step 2 down on purpose instead of solving a 200k-vertex mesh: each
factorization of the interior point sleeps 0.3 s, so that one fit (15-30 iterations) takes far
longer than the limit, as at 200k vertices (44 s for the first fit), while the test stays
small and its timing does not depend on the machine's speed.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

from selfsupport import api, cli
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.methods import weightfit, weightfit_backends
from selfsupport.methods.deadline import DeadlineReached, finish_reserve, out_of_time

from .conftest import load_factor, time_limit_bound


def _bound(limit: float) -> float:
    """A run with time limit T ends within 10% + 1 s of T (stretched by the machine's load)."""
    return time_limit_bound(limit)


@pytest.fixture
def slow_step2(monkeypatch):
    """Every factorization of the Step-2 interior point / PDAS takes 0.3 s longer."""
    original = weightfit._LowerQ._factor

    def slow(self, data):
        time.sleep(0.3)
        return original(self, data)

    monkeypatch.setattr(weightfit._LowerQ, "_factor", slow)


def test_a_slow_step_2_fit_stops_at_the_limit_and_the_network_is_written(slow_step2, tmp_path, capsys):
    out = tmp_path / "net.json"
    limit = 1.0
    t0 = time.perf_counter()
    code = cli.main(["solve", "shape:pillar_vault:300", "--time-limit", str(limit), "--out", str(out), "-q"])
    took = time.perf_counter() - t0
    assert took <= _bound(limit), took  # unpatched-deadline code: >= 0.3 s x 20+ iterations x 2 fits
    assert code == cli.EXIT_CODES["limit"]
    doc = json.loads(out.read_text())
    assert doc["status"] == "time_limit" and "time limit" in doc["message"]
    assert len(doc["weights"]) == len(doc["edges"]) and np.all(np.isfinite(doc["vertices"]))
    assert "time_limit" in capsys.readouterr().err


def test_the_api_limit_holds_inside_the_first_fit(slow_step2):
    scene = make_shape("pillar_vault", n_vertices=300)
    t0 = time.perf_counter()
    res = api.solve(scene, time_limit=0.5)
    assert time.perf_counter() - t0 <= _bound(0.5)
    assert res.status == "time_limit"
    assert res.history[0]["fit_status"] == "time_limit"  # stopped inside Step 2, not after it


def test_interior_point_returns_an_interior_point_at_its_deadline():
    rng = np.random.default_rng(1)
    import scipy.sparse as sp

    A = sp.random(60, 90, density=0.1, random_state=rng, format="csc") + sp.eye(60, 90)
    b = rng.normal(size=60)
    lo, up = np.full(90, 1e-3), np.full(90, np.inf)
    fit = weightfit.ActiveSetFit().fit(A=A, b=b, lower=lo, upper=up, w0=np.ones(90), prox=1e-8,
                                       deadline=time.perf_counter() - 1.0)
    assert fit.status == "time_limit" and fit.iterations == 0 and np.all(fit.w >= lo)
    done = weightfit.ActiveSetFit().fit(A=A, b=b, lower=lo, upper=up, w0=np.ones(90), prox=1e-8,
                                        deadline=time.perf_counter() + 60.0)
    assert done.status == "optimal"


def test_step_3_cg_and_the_polishes_honour_a_passed_deadline():
    import scipy.sparse as sp

    from formulations import Problem
    from selfsupport.methods.polish import polish, polish_joint
    from selfsupport.methods.staggered import _solve_blocks

    rng = np.random.default_rng(0)
    H = sp.diags(np.linspace(1.0, 1e2, 50)).tocsr()
    Q = np.linalg.qr(rng.normal(size=(50, 3, 3)))[0]
    blocks = Q @ (np.array([1e-3, 1.0, 1e3])[None, :, None] * np.transpose(Q, (0, 2, 1)))  # anisotropic: CG iterates
    with pytest.raises(DeadlineReached):
        _solve_blocks(H, blocks, np.ones((50, 3)), {}, start=np.zeros((50, 3)), deadline=time.perf_counter() - 1.0)
    assert _solve_blocks(H, blocks, np.ones((50, 3)), {}, start=np.zeros((50, 3)),
                         deadline=time.perf_counter() + 60) is not None

    scene = make_shape("dome", n_vertices=100)
    prob = Problem.build(scene, SelfWeight())
    sp_ = prob.scaled()
    w = np.ones(sp_.top.m)
    X, L, rounds = polish(sp_.top, sp_.X, w, SelfWeight(), scene.mesh, sp_.scaling, deadline=time.perf_counter() - 1)
    assert rounds == 0 and np.array_equal(X, sp_.X)  # past the deadline: the input, untouched

    from formulations import ThrustNetworkProblem, WeightBounds

    form = ThrustNetworkProblem(sp_.top, sp_.X, sp_.L, WeightBounds(sp_.lower, sp_.upper))
    loads_at = lambda V: sp_.scaling.load(prob.loads.nodal(scene.mesh, sp_.scaling.pos_back(V)))  # noqa: E731
    V, W, k, err, ok = polish_joint(form, sp_.X, w[None], loads_at=loads_at, deadline=time.perf_counter() - 1)
    assert k == 0 and not ok and np.array_equal(V, sp_.X)


def test_deadline_helpers():
    assert not out_of_time(None) and out_of_time(time.perf_counter() - 1e-3)
    assert out_of_time(time.perf_counter() + 1.0, step_seconds=2.0)  # the next step would end past it
    assert finish_reserve(200_000) == pytest.approx(4.0) and finish_reserve(1000) < 0.1


@pytest.mark.parametrize("backend", ["ipopt", "nlopt", "osqp"])
def test_other_step_2_backends_stop_at_a_passed_deadline(backend):
    import scipy.sparse as sp

    rng = np.random.default_rng(2)
    A = sp.random(40, 60, density=0.2, random_state=rng, format="csc") + sp.eye(40, 60)
    fit = weightfit_backends.make_backend(backend).fit(A=A, b=rng.normal(size=40), lower=np.full(60, 1e-3),
                                              upper=np.full(60, np.inf), w0=np.ones(60),
                                              deadline=time.perf_counter() - 1.0)
    assert fit.status == "time_limit"
    later = weightfit_backends.make_backend(backend).fit(A=A, b=rng.normal(size=40), lower=np.full(60, 1e-3),
                                                upper=np.full(60, np.inf), w0=np.ones(60),
                                                deadline=time.perf_counter() + 60.0)
    assert later.status in ("optimal", "max_iter")  # a deadline far off changes nothing


def test_ipopt_fit_stops_inside_its_iterations():
    """The cached IPOPT solver cannot change its max_wall_time per fit: its iteration callback
    holds the deadline (User_Requested_Stop)."""
    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    A = sp.random(400, 600, density=0.02, random_state=rng, format="csc") + sp.eye(400, 600)
    b = rng.normal(size=400)
    be = weightfit_backends.make_backend("ipopt")
    kw = dict(A=A, b=b, lower=np.full(600, 1e-3), upper=np.full(600, np.inf), w0=np.ones(600))
    assert be.fit(**kw).status == "optimal"  # builds the solver
    be._stop.deadline = None
    original = be._stop.eval
    fit = be.fit(**kw, deadline=time.perf_counter() + 1e-4)  # passes during the first iterations
    assert fit.status == "time_limit" and fit.iterations < 5, (fit.status, fit.iterations)
    assert be.fit(**kw).status == "optimal" and be._stop.eval == original  # the next fit is unaffected


def test_the_ipopt_stop_asks_to_stop_before_an_iteration_that_would_end_past_the_deadline():
    """IPOPT cannot be cut inside an iteration (one over three load cases on cas took over 10 s):
    the callback stops when the deadline is nearer than the last iteration lasted, not after it
    has passed. Its first call (after IPOPT's set-up) has no duration to go by; setting the
    deadline again starts a new count."""
    from selfsupport.methods.deadline import ipopt_stop_callback

    stop = ipopt_stop_callback(1, 0, 0)
    stop.deadline = time.perf_counter() + 0.5
    assert stop.eval([]) == [0] and not stop.stopped
    time.sleep(0.3)  # an iteration of 0.3 s: another would end past the deadline, which has not passed
    assert stop.eval([]) == [1] and stop.stopped and not out_of_time(stop.deadline)
    stop.deadline = time.perf_counter() + 0.5
    assert stop.eval([]) == [0] and not stop.stopped


# ------------------------------------------------------------------ item 5: the size guard
def test_absurd_built_in_shapes_are_refused_up_front(capsys):
    t0 = time.perf_counter()
    code = cli.main(["solve", "shape:dome:1000000000", "--out", "/nonexistent-dir/x.json"])
    assert time.perf_counter() - t0 < 5.0 * load_factor()  # nothing of that size was allocated (it was killed at 21 GB)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == cli.EXIT_CODES["input"] and len(err) == 1
    assert "needs about" in err[0] and "GiB" in err[0] and "--max-memory or a coarser mesh" in err[0]
    from selfsupport.core.errors import InputError
    from selfsupport.core.shapes import MAX_SHAPE_VERTICES

    with pytest.raises(InputError, match="use fewer vertices"):
        make_shape("dome", n_vertices=MAX_SHAPE_VERTICES + 1)  # also for the API and every command


def test_a_solve_beyond_the_available_memory_is_refused_before_any_work(monkeypatch, tmp_path, capsys):
    from selfsupport.core.errors import TooLarge
    from selfsupport.methods import memory
    from selfsupport.methods import solve as one_solve

    # pretend the machine has 100 MB free: the refusal must come from the estimate, not an allocation
    monkeypatch.setattr(memory, "available_bytes", lambda: 100e6)
    called = []
    monkeypatch.setattr(one_solve, "validate_scene", lambda *a, **k: called.append(1))
    with pytest.raises(TooLarge, match=r"needs about 0\.\d+ GiB, this machine has 0\.093 GiB available"):
        api.solve(make_shape("dome", n_vertices=2000))
    assert not called  # refused before the validation, the first work proportional to the mesh
    out = tmp_path / "x.json"
    code = cli.main(["solve", "shape:dome:2000", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == cli.EXIT_CODES["input"] and len(err) == 1 and "coarser mesh" in err[0] and not out.exists()


def test_a_subdivision_beyond_the_memory_is_refused_before_it_is_built(monkeypatch, tmp_path, capsys):
    """``--subdivide K`` quadruples the mesh per step: the refined size is checked before the
    subdivision runs (ten steps of a 200-vertex dome would be 3·10⁸ vertices)."""
    from selfsupport.core import subdivision

    monkeypatch.setattr(subdivision, "subdivide_scene", lambda *a, **k: pytest.fail("subdivided"))
    out = tmp_path / "x.json"
    t0 = time.perf_counter()
    code = cli.main(["solve", "shape:dome:200", "--subdivide", "10", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert time.perf_counter() - t0 < 5.0 * load_factor()
    assert code == cli.EXIT_CODES["input"] and len(err) == 1 and not out.exists()
    n = subdivision.subdivided_vertex_count(make_shape("dome", n_vertices=200).mesh, 10)
    assert f"a solve of {n:,} vertices" in err[0] and "--max-memory or a coarser mesh" in err[0]


def test_max_memory_overrides_the_machine_both_ways(monkeypatch, tmp_path, capsys):
    from selfsupport.methods import memory

    out = tmp_path / "x.json"
    assert cli.main(["solve", "shape:dome:3000", "--max-memory", "0.05", "--out", str(out), "-q"]) == 2
    assert "needs about 0.18 GiB, --max-memory allows 0.05 GiB" in capsys.readouterr().err and not out.exists()
    monkeypatch.setattr(memory, "available_bytes", lambda: 1e6)  # the user knows better than the estimate
    assert cli.main(["solve", "shape:dome:100", "--max-memory", "4", "--out", str(out), "-q"]) == 0
    assert out.exists()


def test_the_estimate_covers_the_measured_peaks():
    from selfsupport.methods.memory import estimate_solve_bytes

    measured = {("staggered", 20_000): 313e6, ("staggered", 50_000): 705e6, ("staggered", 200_000): 2.16e9,
                ("ipopt", 2_000): 212e6, ("ipopt", 8_000): 654e6}  # peak RSS, see selfsupport.methods.memory
    for (method, n), peak in measured.items():
        assert peak < estimate_solve_bytes(n, method) < 2.5 * peak, (method, n)


# ------------------------------------------------- limits that hold for every input
def _run_measured(tmp_path, argv: list[str], timeout: float = 60.0) -> dict:
    """``selfsupport ARGV`` in a fresh interpreter: exit code, stderr, wall time of the command
    (from its call, imports excluded) and the process's peak resident memory [bytes]."""
    import subprocess
    import sys

    # (the peak of the process's own address space: ru_maxrss would inherit the pytest worker's
    # RSS through fork and exec)
    script = ("import json, sys, time\n"
              "from selfsupport import cli\n"
              "from studies.common import peak_rss_mib\n"
              "t0 = time.perf_counter()\n"
              "code = cli.main(sys.argv[1:])\n"
              "took = time.perf_counter() - t0\n"
              "peak = peak_rss_mib() * 2 ** 20\n"
              "print(json.dumps({'code': code, 'took': took, 'peak': peak}), file=open(sys.argv[0] + '.out', 'w'))\n")
    path = tmp_path / "measure.py"
    path.write_text(script)
    proc = subprocess.run([sys.executable, str(path), *argv], capture_output=True, text=True, timeout=timeout)
    return {**json.loads((tmp_path / "measure.py.out").read_text()), "err": proc.stderr}


def _cases_file(tmp_path, n: int):
    path = tmp_path / "cases.toml"
    path.write_text("".join(f"[cases.c{i}]\nuniform_mass = {10.0 + i}\n\n" for i in range(n)))
    return path


def test_many_load_cases_hold_the_memory_and_the_time_limit(tmp_path):
    """30 uniform-mass cases on a 91-vertex dome: the joint polish paired every two cases in one
    factored matrix (60 cases: 2.4 GB, 20 s for its first step, past a 5 s limit)."""
    out = tmp_path / "net.json"
    limit, memory = 5.0, 0.4
    run = _run_measured(tmp_path, ["solve", "shape:dome:100", "--load-cases", str(_cases_file(tmp_path, 30)),
                                   "--time-limit", str(limit), "--max-memory", str(memory), "--out", str(out), "-q"])
    assert run["code"] in (cli.EXIT_CODES["ok"], cli.EXIT_CODES["limit"]), run["err"]
    assert run["took"] <= _bound(limit), run["took"]
    assert run["peak"] <= memory * 1024 ** 3, run["peak"]
    assert len(json.loads(out.read_text())["load_cases"]) == 30


def test_the_estimate_counts_load_cases(tmp_path, capsys):
    from selfsupport.methods.memory import estimate_solve_bytes

    # peak RSS of solves of a 5,000-vertex dome under C uniform-mass cases (selfsupport.methods.memory.case_factor)
    measured = {1: 158e6, 2: 549e6, 4: 1.62e9, 5: 524e6, 16: 1.32e9}
    for cases, peak in measured.items():
        assert peak < estimate_solve_bytes(5000, "staggered", cases), cases
    out = tmp_path / "x.json"
    t0 = time.perf_counter()
    code = cli.main(["solve", "shape:dome:3000", "--load-cases", str(_cases_file(tmp_path, 4)), "--max-memory", "0.5",
                     "--time-limit", "2", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert time.perf_counter() - t0 < 5.0
    assert code == cli.EXIT_CODES["input"] and len(err) == 1 and not out.exists()
    assert "under 4 load cases needs about" in err[0] and "fewer load cases" in err[0]


def _fan(tmp_path, n: int):
    """An OFF fan: ``n`` rim vertices (to be supported) around one free apex of valence ``n``."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1.0 + 0.3 * np.cos(3 * t)
    V = np.r_[np.c_[r * np.cos(t), 0.8 * r * np.sin(t), 0.05 * np.sin(2 * t)], [[0.2, -0.1, 0.5]]]
    path = tmp_path / f"fan{n}.off"
    path.write_text(f"OFF\n{n + 1} {n} 0\n" + "".join(f"{x:.9f} {y:.9f} {z:.9f}\n" for x, y, z in V)
                    + "".join(f"3 {n} {i} {(i + 1) % n}\n" for i in range(n)))
    return path


def test_a_high_valence_vertex_solves_in_bounded_memory_and_time(tmp_path):
    """The weight fit of an apex with 3,000 edges: its rows put a dense 3,000² block into AᵀA
    (2,000 edges: 0.43 GB and 5.7 s; 8,000: 4 GB and over 100 s)."""
    out = tmp_path / "net.json"
    limit, memory = 10.0, 0.4
    run = _run_measured(tmp_path, ["solve", str(_fan(tmp_path, 3000)), "--supports", "boundary", "--time-limit",
                                   str(limit), "--max-memory", str(memory), "--out", str(out), "-q"])
    assert run["code"] == cli.EXIT_CODES["ok"], run["err"]
    assert run["took"] <= _bound(limit) and run["peak"] <= memory * 1024 ** 3, (run["took"], run["peak"])
    assert json.loads(out.read_text())["status"] == "converged"


def test_dense_rows_split_off_give_the_weights_of_the_full_gram_matrix(tmp_path, monkeypatch):
    import scipy.sparse as sp

    from formulations.equilibrium import Topology, weight_matrix
    from selfsupport.core import linalg
    from selfsupport.io import read_mesh

    mesh = read_mesh(_fan(tmp_path, 400))
    free = np.zeros(mesh.n_vertices, bool)
    free[-1] = True
    A = sp.csc_matrix(weight_matrix(Topology.build(mesh.n_vertices, mesh.edges, ~free), mesh.vertices))
    assert linalg.GramPattern(A).dense.size == 3  # the apex's x, y, z rows
    b = np.array([0.3, -0.2, -1.0])
    kw = dict(A=A, b=b, lower=np.full(A.shape[1], 1e-3), upper=np.full(A.shape[1], np.inf), w0=np.ones(A.shape[1]))
    split = weightfit.ActiveSetFit().fit(**kw, prox=1e-4)
    monkeypatch.setattr(linalg, "DENSE_ROW_MIN", 10 ** 9)  # every row in the Gram matrix, as a plain Cholesky
    whole = weightfit.ActiveSetFit().fit(**kw, prox=1e-4)
    assert split.status == whole.status == "optimal"
    assert np.allclose(split.w, whole.w, rtol=1e-8, atol=1e-10 * np.abs(whole.w).max())
    assert split.objective == pytest.approx(whole.objective, rel=1e-8, abs=1e-20)


def test_a_ring_count_beyond_the_mesh_ends_with_the_connected_region(tmp_path):
    """``roi_rings = 1e9`` ran 1e9 ring steps (a hang, in the CLI and in the design server)."""
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from selfsupport.design.laplacian import ring_region\n"
            "from selfsupport.core.shapes import make_shape\n"
            "m = make_shape('dome', n_vertices=200).mesh\n"
            "seed = np.zeros(m.n_vertices, bool); seed[0] = True\n"
            "print(int(ring_region(m, seed, int(1e9)).sum()), int(ring_region(m, seed, 1).sum()), m.n_vertices)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=15)
    everything, first_ring, n = map(int, proc.stdout.split())
    assert everything == n and 1 < first_ring < n


def test_subdividing_goes_through_the_size_guard(monkeypatch):
    """An edit script's or the design page's ``subdivide`` is refused before it is built, as
    ``solve --subdivide`` is (levels=10 ended in MemoryError at 5.2 GB)."""
    from selfsupport.core import subdivision
    from selfsupport.core.errors import TooLarge
    from selfsupport.design.edits import Design, Subdivide
    from selfsupport.methods import memory

    monkeypatch.setattr(memory, "available_bytes", lambda: 300e6)
    monkeypatch.setattr(subdivision, "catmull_clark", lambda *a, **k: pytest.fail("subdivided"))
    scene = make_shape("dome", n_vertices=200)
    with pytest.raises(TooLarge, match=r"subdividing 3 times .* needs about .* GiB, this machine has 0\.28 GiB"):
        Subdivide(levels=3).apply(Design(scene=scene))
    t0 = time.perf_counter()
    with pytest.raises(TooLarge, match="subdividing 1000000000 times"):
        subdivision.subdivide_scene(scene, 10 ** 9)
    assert time.perf_counter() - t0 < 1.0


def _one_line_input_error(capsys, code: int) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert code == cli.EXIT_CODES["input"] and len(err) == 1, err
    assert "internal error" not in err[0] and "Traceback" not in err[0]
    return err[0]


def test_mesh_headers_are_checked_against_the_file_size(tmp_path, capsys):
    off = tmp_path / "bomb.off"
    off.write_text("OFF\n2000000000 1 0\n0 0 0\n3 0 0 0\n")
    ply = tmp_path / "bomb.ply"
    ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
                    b"property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                    b"end_header\n" + bytes(40))
    for path in (off, ply):
        t0 = time.perf_counter()
        line = _one_line_input_error(capsys, cli.main(["check", str(path)]))
        assert time.perf_counter() - t0 < 2.0  # nothing of the declared size was allocated
        assert "2,000,000,000" in line and "the file has" in line and "fix the header" in line


def test_deeply_nested_json_and_toml_are_input_errors(tmp_path, capsys):
    deep = tmp_path / "deep.json"
    deep.write_text('{"vertices": ' + "[" * 100_000 + "]" * 100_000 + "}")
    line = _one_line_input_error(capsys, cli.main(["check", str(deep)]))
    assert "nests its values deeper" in line
    cases = tmp_path / "cases.toml"
    cases.write_text("[cases.a]\nuniform_mass = " + "[" * 100_000 + "]" * 100_000 + "\n")
    out = tmp_path / "x.json"
    line = _one_line_input_error(capsys, cli.main(["solve", "shape:dome:50", "--load-cases", str(cases),
                                                   "--out", str(out), "-q"]))
    assert "nests its values deeper" in line and not out.exists()


def test_render_dpi_and_construct_disk_have_upper_bounds(tmp_path, capsys):
    from selfsupport.figures.render import MAX_PIXELS

    net = tmp_path / "net.json"
    assert cli.main(["solve", "shape:dome:50", "--out", str(net), "-q"]) == 0
    capsys.readouterr()
    png = tmp_path / "big.png"
    line = _one_line_input_error(capsys, cli.main(["render", str(net), "--dpi", "100000", "--out", str(png)]))
    assert f"{MAX_PIXELS:,} pixels" in line and "use at most" in line and not png.exists()
    out = tmp_path / "disk.json"
    t0 = time.perf_counter()
    line = _one_line_input_error(capsys, cli.main(["construct", "--disk", "100000", "--out", str(out)]))
    assert time.perf_counter() - t0 < 2.0 and not out.exists()
    assert "--disk) of 30,000,300,001 vertices needs about" in line
