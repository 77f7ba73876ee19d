"""Bounds a designer states: per-edge w_min / w_max from a file (CSV or JSON), w_max from a
material strength (``--max-stress``), and tension (a lower bound of zero or below).

The per-edge bounds are stated once (:class:`formulations.problem.Bounds`) and every method
holds them; the bound on a dome is put below its unbounded solution's largest weights, so it
must be active. The tension solve is of a dented dome, which stays nearer its reference when
some edges may pull; its file passes the shared checker with ``--allow-tension``.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from formulations import Bounds
from formulations.problem import stress_w_max
from selfsupport import api, cli
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.shapes import make_shape
from selfsupport.io.bounds import read_bounds, write_bounds
from tests.conftest import independent_check, requires_checker
from tests.test_cli import assert_one_line_error


@pytest.fixture(scope="module")
def dome():
    return make_shape("dome", n_vertices=80)


@pytest.fixture(scope="module")
def capped(dome, tmp_path_factory):
    """A bounds CSV capping, at 0.8 of the unbounded solution's largest weight, every edge that
    carried more than 0.6 of it (rows written by hand, each pair in reversed order)."""
    w = api.solve(dome).network.weights
    cap = 0.8 * float(w.max())
    mask = w > 0.6 * w.max()
    path = tmp_path_factory.mktemp("bounds") / "cap.csv"
    rows = [f"{j},{i},,{cap!r}" for i, j in dome.mesh.edges[mask].tolist()]
    path.write_text("i,j,w_min,w_max\n# the busiest edges of the unbounded dome\n" + "\n".join(rows) + "\n")
    return path, cap, mask


# ------------------------------------------------------------------ per-edge bounds hold
@pytest.mark.parametrize("method", ["staggered", "ipopt", "nlopt"])
def test_per_edge_w_max_from_a_file_holds_and_is_active_in_every_method(dome, capped, method):
    path, cap, mask = capped
    res = api.solve(dome, method=method, bounds=path, time_limit=60)
    assert res.converged, res.message
    w = res.network.weights
    assert w[mask].max() <= cap * (1 + 1e-9)
    assert w[mask].max() >= cap * (1 - 1e-6)  # active: the unbounded solution needs more
    assert independent_check(res, tol=1e-8).ok


def test_bounds_file_through_the_cli(dome, capped, tmp_path, capsys):
    path, cap, mask = capped
    out = tmp_path / "net.json"
    code = cli.main(["solve", "shape:dome:80", "--bounds", str(path), "--out", str(out), "-q"])
    assert code == 0, capsys.readouterr().err
    d = json.loads(out.read_text())
    assert np.array_equal(np.asarray(d["edges"]), dome.mesh.edges)
    w = np.asarray(d["weights"])
    assert cap * (1 - 1e-6) <= w[mask].max() <= cap * (1 + 1e-9)


def test_unstated_edges_take_the_defaults(dome, tmp_path):
    """A file stating one edge's w_min only: that edge's lower bound is its own, every other
    edge keeps the scale-free ε, and nothing gets an upper bound."""
    path = tmp_path / "one.csv"
    i, j = dome.mesh.edges[5]
    path.write_text(f"{j},{i},12.5,\n")
    plain = api.problem(dome).scaled()
    sp_ = api.problem(dome, bounds=path).scaled()
    k = int(np.flatnonzero(np.flatnonzero(dome.active_edges) == 5)[0])
    assert sp_.scaling.weight_back(sp_.lower[k]) == pytest.approx(12.5)
    others = np.arange(sp_.top.m) != k
    assert np.array_equal(sp_.lower[others], plain.lower[others])
    assert np.all(np.isinf(sp_.upper))


def test_file_bounds_override_the_scalar_ones_on_their_edges_only(dome, tmp_path):
    path = tmp_path / "one.csv"
    i, j = dome.mesh.edges[5]
    path.write_text(f"{i},{j},,7000\n")
    b = api.weight_bounds(dome, w_max=9000.0, bounds=path)
    assert b.upper[5] == 7000.0 and np.all(np.delete(b.upper, 5) == 9000.0)


# ------------------------------------------------------------------ readers
def test_csv_and_json_round_trip(dome, tmp_path):
    m = dome.mesh.n_edges
    rng = np.random.default_rng(3)
    lo = np.where(rng.random(m) < 0.5, np.nan, rng.uniform(-50.0, 5.0, m))
    up = np.where(rng.random(m) < 0.5, np.nan, rng.uniform(10.0, 900.0, m))
    for name in ("b.csv", "b.json"):
        write_bounds(tmp_path / name, dome.mesh, Bounds(lo, up))
        back = read_bounds(tmp_path / name, dome.mesh)
        np.testing.assert_array_equal(back.lower, lo)
        np.testing.assert_array_equal(back.upper, up)


def test_a_network_file_with_bounds_arrays_reads_in_its_own_edge_order(dome, tmp_path):
    """A JSON file's ``w_min`` / ``w_max`` follow its own ``edges`` (any order, either orientation)."""
    edges = dome.mesh.edges[::-1, ::-1]  # reversed order, each pair turned round
    up = np.linspace(100.0, 200.0, len(edges))
    doc = {"vertices": dome.mesh.vertices.tolist(), "edges": edges.tolist(), "w_max": up.tolist(),
           "w_min": [None] * len(edges)}
    (tmp_path / "n.json").write_text(json.dumps(doc))
    b = read_bounds(tmp_path / "n.json", dome.mesh)
    np.testing.assert_array_equal(b.upper, up[::-1])
    assert np.isnan(b.lower).all()


def _net_json(dome, **cols) -> str:
    e = dome.mesh.edges[:3].tolist()
    return json.dumps({"edges": e, **{k: v for k, v in cols.items()}})


BAD_FILES = [
    ("unknown.csv", "{e0},,5\n{a},{far},,5\n", "is not an edge of the mesh"),
    ("outside.csv", "0,100000,,5\n", "names a vertex outside 0..90"),
    ("swapped.csv", "{e0},10,2\n", "is not below its w_max"),
    ("nan.csv", "{e0},nan,\n", "w_min is nan"),
    ("negative.csv", "{e0},,-3\n", "w_max must be positive"),
    ("zero.csv", "{e0},,0\n", "w_max must be positive"),
    ("inf_min.csv", "{e0},-inf,\n", "give a finite number"),
    ("word.csv", "{e0},,lots\n", "'lots' is not a number"),
    ("columns.csv", "{e0},5\n", "has 3 columns, not 4"),
    ("twice.csv", "{e0},,5\n{e0r},,6\n", "listed twice"),
    ("empty.csv", "i,j,w_min,w_max\n{e0},,\n", "states no bound"),
    ("suffix.txt", "{e0},,5\n", "unknown bounds file type"),
    ("short.json", "SHORT", "has 2 entries for 3 edges"),
    ("nanjson.json", "NAN", "NaN is not valid JSON"),
    ("nokeys.json", "NOKEYS", "neither 'w_min' nor 'w_max'"),
]


def _bad_text(dome, template: str) -> str:
    (a, b) = dome.mesh.edges[0].tolist()
    far = next(v for v in range(dome.mesh.n_vertices) if v != a and v not in dome.mesh.vertex_neighbors[a])
    if template == "SHORT":
        return _net_json(dome, w_max=[1.0, 2.0])
    if template == "NAN":
        return _net_json(dome, w_max=[1.0, 2.0, 3.0]).replace("3.0", "NaN")
    if template == "NOKEYS":
        return _net_json(dome)
    return template.format(e0=f"{a},{b}", e0r=f"{b},{a}", a=a, far=far)


@pytest.mark.parametrize("name,template,needle", BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_bounds_file_one_line_exit_2_output_untouched(dome, tmp_path, capsys, name, template, needle):
    path = tmp_path / name
    path.write_text(_bad_text(dome, template))
    out = tmp_path / "precious.json"
    out.write_text("precious\n")
    code = cli.main(["solve", "shape:dome:80", "--bounds", str(path), "--out", str(out), "-q"])
    cap = capsys.readouterr()
    assert_one_line_error(cap.err, code, 2, needle=needle)
    assert name in cap.err  # the message names the file
    assert out.read_text() == "precious\n"


def test_a_bad_per_edge_bound_is_named_by_its_edge_in_one_line(dome):
    """A per-edge array with one bad entry: one line naming the edge, not the array."""
    up = np.full(dome.mesh.n_edges, 500.0)
    k = int(np.flatnonzero(dome.active_edges)[7])
    up[k] = -1.0
    i, j = dome.mesh.edges[k]
    with pytest.raises(InputError) as e:
        api.solve(dome, w_max=up)
    assert "\n" not in str(e.value) and f"edge ({i}, {j})" in str(e.value) and "w_max must be positive" in str(e.value)


def test_w_max_and_max_stress_together_are_refused(tmp_path, capsys):
    out = tmp_path / "precious.json"
    out.write_text("precious\n")
    code = cli.main(["solve", "shape:dome:80", "--wmax", "3000", "--max-stress", "1", "--out", str(out), "-q"])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle="not both")
    assert out.read_text() == "precious\n"


# ------------------------------------------------------------------ stress-derived bound
def _grid(nx: int, ny: int, hx: float, hy: float) -> PolyMesh:
    V = np.array([[i * hx, j * hy, 0.0] for j in range(ny + 1) for i in range(nx + 1)])
    F = [[j * (nx + 1) + i, j * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i + 1, (j + 1) * (nx + 1) + i]
         for j in range(ny) for i in range(nx)]
    return PolyMesh.from_faces(V, F)


def test_stress_w_max_on_a_flat_rectangular_grid():
    """On a grid of spacings hx, hy, an x edge (length hx) stands for a strip of width hy (hy / 2
    on the boundary): w_max = σ t hy / hx, and likewise for the y edges."""
    hx, hy, sigma, t = 0.5, 0.8, 2.0e6, 0.12
    mesh = _grid(4, 3, hx, hy)
    w = stress_w_max(mesh, sigma, t)
    d = mesh.vertices[mesh.edges[:, 1]] - mesh.vertices[mesh.edges[:, 0]]
    along_x = np.abs(d[:, 0]) > 0
    boundary = mesh.boundary_edge_mask
    expected = np.where(along_x, sigma * t * hy / hx, sigma * t * hx / hy) * np.where(boundary, 0.5, 1.0)
    np.testing.assert_allclose(w, expected, rtol=1e-12)


def test_max_stress_through_the_cli_holds_the_strength_per_edge(dome, tmp_path, capsys):
    """--max-stress MPA (thickness 0.1 m): no edge's force w |e| exceeds σ t b_e, with
    b_e = w_max(1 Pa) |e| / t, and the most stressed edge sits at the strength (0.8 of what the
    unbounded dome needs)."""
    per_pa = stress_w_max(dome.mesh, 1.0, 0.1)
    act = dome.active_edges
    need = float((api.solve(dome).network.weights / per_pa)[act].max())  # [Pa]
    mpa = 0.8 * need / 1e6
    out = tmp_path / "s.json"
    code = cli.main(["solve", "shape:dome:80", "--max-stress", repr(mpa), "--thickness", "0.1", "--out", str(out),
                     "-q"])
    assert code == 0, capsys.readouterr().err
    w = np.asarray(json.loads(out.read_text())["weights"])
    ratio = (w / (mpa * 1e6 * per_pa))[act]
    assert ratio.max() == pytest.approx(1.0, rel=1e-9)


# ------------------------------------------------------------------ tension
def test_eps_zero_is_accepted_and_keeps_compression(tmp_path, capsys):
    out = tmp_path / "z.json"
    code = cli.main(["solve", "shape:dome:80", "--eps", "0", "--out", str(out), "-q"])
    assert code == 0, capsys.readouterr().err
    d = json.loads(out.read_text())
    assert d["parameters"]["eps"] == 0.0 and min(d["weights"]) >= 0.0
    assert d["parameters"]["tension"]["edges"] == 0  # allowed down to zero, none in tension


@requires_checker
def test_tension_allowed_solve_reports_its_tension_edges_and_passes_the_checker(tmp_path, capsys):
    """A dome dented in the middle: with --w-min -2000 some edges pull, the network stays nearer
    the dented reference than the compression-only one, the summary and the file count the
    tension edges, and the shared checker passes it with --allow-tension (and refuses it without)."""
    out = tmp_path / "t.json"
    code = cli.main(["solve", "shape:concave_disk:120", "--w-min", "-2000", "--out", str(out), "-q"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    d = json.loads(out.read_text())
    w, e, sup = np.asarray(d["weights"]), np.asarray(d["edges"]), np.zeros(len(d["vertices"]), bool)
    sup[d["supports"]] = True
    active = ~(sup[e[:, 0]] & sup[e[:, 1]])
    n_tension = int(np.sum(active & (w < 0)))
    t = d["parameters"]["tension"]
    assert n_tension > 0 and t["edges"] == n_tension and t["min_weight"] == pytest.approx(w.min())
    assert t["edge_indices"] == np.flatnonzero(active & (w < 0)).tolist()
    assert w.min() >= -2000.0 * (1 + 1e-9)
    assert f"tension edges               {n_tension} (most negative weight" in cap.out
    compression = api.solve(make_shape("concave_disk", n_vertices=120))
    assert d["distance_to_reference"]["mean"] < 0.5 * compression.distance_mean
    report = independent_check(out, tol=1e-8, allow_tension=True)
    assert report.ok and report["tension_edges"] == n_tension
    assert not independent_check(out, tol=1e-8).ok  # the weights really are tension


def test_a_per_edge_tension_bound_from_a_file_holds(tmp_path):
    """Negative w_min per edge, from a CSV: only those edges may pull, and not beyond their bound."""
    scene = make_shape("concave_disk", n_vertices=120)
    allowed = np.arange(scene.mesh.n_edges) % 2 == 0
    path = tmp_path / "t.csv"
    write_bounds(path, scene.mesh, Bounds(np.where(allowed, -1500.0, np.nan), None))
    res = api.solve(scene, bounds=path)
    assert res.converged
    w = res.network.weights
    act = scene.active_edges
    assert w[act & allowed].min() >= -1500.0 * (1 + 1e-9) and w[act & allowed].min() < 0
    assert w[act & ~allowed].min() > 0
    assert res.parameters["tension"]["edges"] == int(np.sum(act & (w < 0)))
