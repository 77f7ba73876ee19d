"""Network exports a designer uses: every ``--out`` format reads back to the same network
(vertices, faces, edges, weights, loads, supports); the COMPAS mesh JSON opens in COMPAS; the
``.sss`` opens in the original tool (slow, with its built driver); ``check --out`` writes the
fitted weights of a checked mesh with a status saying whether it stands."""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from selfsupport import cli
from selfsupport.core.errors import InputError
from selfsupport.core.result import Network
from selfsupport.io import read_network, write_mesh, write_network_as
from tests.conftest import document_check, independent_check, relative_residuals
from tests.test_cli import assert_one_line_error
from tests.test_io import mixed_mesh, same_mesh

#: every network format, with the vertical axis its file is written in
FORMATS = [("n.json", "z"), ("n.compas.json", "z"), ("n.ply", "-y"), ("n.obj", "-y"), ("n.off", "x"), ("n.sss", "z")]
#: the formats that also keep the handles
WITH_HANDLES = (".json", ".sss")


def random_network(seed: int = 0) -> Network:
    """A mixed triangle/quad network with full-mantissa weights and loads (one of them upward),
    boundary supports and two handles: a round trip that rounds anything shows."""
    rng = np.random.default_rng(seed)
    mesh = mixed_mesh(seed=seed)
    loads = -rng.uniform(1.0, 100.0, mesh.n_vertices)
    loads[int(np.flatnonzero(~mesh.boundary_vertex_mask)[0])] *= -1.0  # an upward load keeps its sign
    handles = np.zeros(mesh.n_vertices, bool)
    handles[np.flatnonzero(~mesh.boundary_vertex_mask)[:2]] = True
    return Network(mesh=mesh, weights=rng.uniform(0.1, 10.0, mesh.n_edges), loads=loads,
                   supports=mesh.boundary_vertex_mask, handles=handles)


def assert_same_network(back: Network, net: Network, *, handles: bool = True) -> None:
    same_mesh(back.mesh, net.mesh)
    np.testing.assert_array_equal(back.edges, net.edges)
    np.testing.assert_array_equal(back.weights, np.where(net.active_edges, net.weights, 0.0))  # docs/reference/formats.md
    np.testing.assert_array_equal(back.loads, net.loads)
    np.testing.assert_array_equal(back.supports, net.supports)
    if handles:
        np.testing.assert_array_equal(back.handles, net.handles)


# ---------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("name, up", FORMATS)
def test_every_format_reads_back_to_the_same_network(tmp_path, name, up):
    net = random_network()
    path = tmp_path / name
    write_network_as(path, net, up=up, status="converged")
    back = read_network(path, up=None if name.endswith((".json", ".sss")) else up)
    assert_same_network(back, net, handles=name.endswith(WITH_HANDLES + (".compas.json",)))


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".off"])
def test_the_geometry_of_a_network_file_is_still_a_mesh(tmp_path, suffix):
    """Other tools read the mesh: PLY readers skip the edge element and extra properties, OBJ
    and OFF are plain meshes (their network is in the side files)."""
    from selfsupport.io import read_mesh

    net = random_network(1)
    write_network_as(tmp_path / f"n{suffix}", net)
    same_mesh(read_mesh(tmp_path / f"n{suffix}"), net.mesh)


def test_obj_side_files_are_plain_csv(tmp_path):
    """``NAME.weights.csv`` is ``i,j,weight`` per edge, ``NAME.vertices.csv`` ``vertex,load,support``
    per vertex: a spreadsheet or Grasshopper reads them as they are."""
    import csv

    net = random_network(2)
    write_network_as(tmp_path / "n.obj", net)
    with open(tmp_path / "n.weights.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    w = {(int(r["i"]), int(r["j"])): float(r["weight"]) for r in rows}
    assert len(w) == net.mesh.n_edges
    for (i, j), x, active in zip(net.edges.tolist(), net.weights.tolist(), net.active_edges.tolist()):
        assert w[(i, j)] == (x if active else 0.0)
    with open(tmp_path / "n.vertices.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["load"]) for r in rows] == net.loads.tolist()
    assert [r["support"] == "1" for r in rows] == net.supports.tolist()


def test_a_missing_or_stale_side_file_is_named(tmp_path):
    net = random_network(3)
    write_network_as(tmp_path / "n.obj", net)
    (tmp_path / "n.vertices.csv").unlink()
    with pytest.raises(InputError, match=r"n\.vertices\.csv: is missing .*n\.obj"):
        read_network(tmp_path / "n.obj")
    write_network_as(tmp_path / "n.obj", net)
    lines = (tmp_path / "n.weights.csv").read_text().splitlines()
    (tmp_path / "n.weights.csv").write_text("\n".join(lines[:-1]) + "\n")  # one edge lost
    with pytest.raises(InputError, match=r"n\.weights\.csv: the edge list lacks the faces' edge .* \(1 missing\)"):
        read_network(tmp_path / "n.obj")


def test_sss_load_column_is_the_downward_load_and_pins_are_supports(tmp_path):
    """The original tool's ``load`` is the nodal load magnitude 9.8·(ρ·A·t + extra), positive
    down; the file is y down (height = −y)."""
    net = random_network(5)
    write_network_as(tmp_path / "n.sss", net)
    v = [ln.split() for ln in (tmp_path / "n.sss").read_text().splitlines() if ln.startswith("v ")]
    cols = np.array([[float(t) for t in row[1:]] for row in v])
    np.testing.assert_array_equal(-cols[:, 1], net.vertices[:, 2])  # height = -y
    np.testing.assert_array_equal(cols[:, 3], -net.loads)
    np.testing.assert_array_equal(cols[:, 4] == 1, net.supports)
    np.testing.assert_array_equal(cols[:, 5] == 1, net.handles)


# ---------------------------------------------------------------------------------- COMPAS
def test_compas_mesh_json_opens_in_compas(tmp_path):
    compas_ds = pytest.importorskip("compas.datastructures")
    net = random_network(6)
    path = tmp_path / "n.compas.json"
    write_network_as(path, net, status="converged")
    mesh = compas_ds.Mesh.from_json(str(path))
    keys = sorted(mesh.vertices())
    assert keys == list(range(net.mesh.n_vertices))
    np.testing.assert_array_equal([mesh.vertex_coordinates(k) for k in keys], net.vertices)
    assert [mesh.face_vertices(f) for f in sorted(mesh.faces())] == net.mesh.faces
    assert {tuple(sorted(e)) for e in mesh.edges()} == set(map(tuple, net.edges.tolist()))
    for (i, j), w, active in zip(net.edges.tolist(), net.weights.tolist(), net.active_edges.tolist()):
        assert mesh.edge_attribute((j, i), "weight") == (w if active else 0.0)
    assert mesh.vertices_attribute("load", keys=keys) == net.loads.tolist()
    assert mesh.vertices_attribute("support", keys=keys) == net.supports.tolist()
    assert mesh.attributes["status"] == "converged"


def test_a_mesh_compas_wrote_reads_as_the_network_it_holds(tmp_path):
    """The schema both ways: a COMPAS-made mesh with weight, load and support attributes (written by
    COMPAS itself, keys and defaults as it writes them) reads back as that network."""
    compas_ds = pytest.importorskip("compas.datastructures")
    net = random_network(7)
    mesh = compas_ds.Mesh.from_vertices_and_faces(net.vertices.tolist(), net.mesh.faces)
    mesh.update_default_vertex_attributes(load=0.0, support=False)
    mesh.update_default_edge_attributes(weight=0.0)
    for k, (load, sup) in enumerate(zip(net.loads.tolist(), net.supports.tolist())):
        mesh.vertex_attributes(k, ["load", "support"], [load, sup])
    for (i, j), w in zip(net.edges.tolist(), net.weights.tolist()):
        mesh.edge_attribute((i, j), "weight", w)
    path = tmp_path / "made-by-compas.json"
    mesh.to_json(str(path))
    back = read_network(path)
    same_mesh(back.mesh, net.mesh)
    np.testing.assert_array_equal(back.weights, net.weights)
    np.testing.assert_array_equal(back.loads, net.loads)
    np.testing.assert_array_equal(back.supports, net.supports)


def test_the_compas_writer_needs_no_compas(tmp_path):
    """Writing the COMPAS JSON works where COMPAS is not installed (it is a test extra only)."""
    out = tmp_path / "n.compas.json"
    code = ("import sys; sys.modules['compas'] = None\n"
            "from tests.test_exports import random_network\n"
            "from selfsupport.io import write_network_as\n"
            f"write_network_as({str(out)!r}, random_network())\n"
            "assert not any(m == 'compas' or m.startswith('compas.') for m in sys.modules if sys.modules[m])\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       cwd=Path(__file__).resolve().parents[1])
    assert p.returncode == 0, p.stderr
    assert json.loads(out.read_text())["dtype"] == "compas.datastructures/Mesh"


# ---------------------------------------------------------------------------------- the CLI
@pytest.mark.parametrize("fmt, name", [("compas", "net.json"), ("ply", "net.ply")])
def test_format_option_names_the_format(tmp_path, capsys, fmt, name):
    out = tmp_path / name
    assert cli.main(["construct", "--disk", "2", "--format", fmt, "--out", str(out)]) == 0
    net = read_network(out)
    assert net.mesh.n_vertices == 19
    if fmt == "compas":
        assert json.loads(out.read_text())["dtype"] == "compas.datastructures/Mesh"


def test_format_that_cannot_be_written_under_that_name_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    from selfsupport import api

    monkeypatch.setattr(api, "solve", lambda *a, **k: pytest.fail("solved although --out cannot be written"))
    out = tmp_path / "net.json"
    code = cli.main(["solve", "shape:dome:80", "--format", "obj", "--out", str(out)])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle="--format obj writes .obj")
    assert not out.exists()


def test_a_side_file_that_cannot_be_written_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    """``--out NET.obj`` writes NET.weights.csv too: a read-only one is refused up front, and
    nothing is written (the OBJ is not created, the side file keeps its content)."""
    from selfsupport import api

    monkeypatch.setattr(api, "solve", lambda *a, **k: pytest.fail("solved although --out cannot be written"))
    side = tmp_path / "net.weights.csv"
    side.write_text("precious\n")
    side.chmod(stat.S_IRUSR | stat.S_IRGRP)
    code = cli.main(["solve", "shape:dome:80", "--out", str(tmp_path / "net.obj")])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle="net.weights.csv")
    assert side.read_text() == "precious\n"
    assert not (tmp_path / "net.obj").exists() and not (tmp_path / "net.vertices.csv").exists()


# ---------------------------------------------------------------------------------- check --out
def _stands(tmp_path: Path) -> tuple[Path, Path, dict]:
    """A surface that stands under its self-weight (the §2.5 construction, in equilibrium by
    construction) given as a plain mesh and a supports file, and its network document."""
    net_path = tmp_path / "built.json"
    assert cli.main(["construct", "--disk", "3", "--self-weight", "--out", str(net_path)]) == 0
    d = json.loads(net_path.read_text())
    from selfsupport.core.mesh import PolyMesh

    mesh_path, sup_path = tmp_path / "surface.obj", tmp_path / "surface.supports"
    write_mesh(mesh_path, PolyMesh.from_faces(np.asarray(d["vertices"]), d["faces"]))
    sup_path.write_text(" ".join(map(str, d["supports"])) + "\n")
    return mesh_path, sup_path, d


def test_check_out_writes_the_fitted_network_of_a_surface_that_stands(tmp_path, capsys):
    mesh_path, sup_path, built = _stands(tmp_path)
    out = tmp_path / "checked.json"
    code = cli.main(["check", str(mesh_path), "--supports", str(sup_path), "--out", str(out)])
    assert code == 0
    d = json.loads(out.read_text())
    assert d["status"] == "self_supporting"
    np.testing.assert_array_equal(d["vertices"], built["vertices"])  # the surface as checked, unmoved
    rep = document_check(d)
    assert rep["max_rel"] <= 1e-8 and rep["min_w"] >= 0.0
    # the loads are the self-weight of this geometry (default 2000 kg/m^3 x 0.1 m x g)
    from selfsupport.core.loads import G

    assert rep["total_load"] == pytest.approx(-2000 * 0.1 * G * rep["area"], rel=1e-9)
    checker = independent_check(out, tol=1e-8, unit_weight=2000 * 0.1 * G, load_tol=1e-9)
    assert checker.ok, checker.stdout


def test_check_out_of_a_surface_that_cannot_stand_says_so(tmp_path, capsys):
    """A free vertex pushed below all its neighbours cannot be balanced by compression (the
    relative error there is at least 1): the file is written, its status says it does not stand."""
    mesh_path, sup_path, d = _stands(tmp_path)
    V = np.asarray(d["vertices"])
    sup = np.zeros(len(V), bool)
    sup[d["supports"]] = True
    k = int(np.flatnonzero(~sup)[0])
    nbrs = {b for a, b in d["edges"] if a == k} | {a for a, b in d["edges"] if b == k}
    V[k, 2] = min(V[j, 2] for j in nbrs) - 0.05
    from selfsupport.core.mesh import PolyMesh

    write_mesh(mesh_path, PolyMesh.from_faces(V, d["faces"]))
    out = tmp_path / "checked.ply"
    code = cli.main(["check", str(mesh_path), "--supports", str(sup_path), "--out", str(out)])
    assert code == 1
    back = read_network(out)
    errors = relative_residuals(back.vertices, back.edges, back.weights, back.loads, back.supports)
    assert errors.max() >= 1.0 - 1e-9 and back.weights.min() >= 0.0
    out = tmp_path / "checked.json"
    assert cli.main(["check", str(mesh_path), "--supports", str(sup_path), "--out", str(out)]) == 1
    assert json.loads(out.read_text())["status"] == "not_self_supporting"


def test_check_out_keeps_every_load_case(tmp_path, capsys):
    """A network file solved for several load cases: the checked file carries each case's fitted
    weights, each balancing that case's loads, and its load model (checking it again uses them)."""
    _, _, d = _stands(tmp_path)
    d["parameters"] = {"load_model": {"density": 2000.0, "thickness": 0.1,
                                      "cases": [{"name": "empty"}, {"name": "snow", "uniform_mass": 80.0}]}}
    src = tmp_path / "cases.json"
    src.write_text(json.dumps(d))
    out = tmp_path / "checked.json"
    assert cli.main(["check", str(src), "--out", str(out)]) == 0
    c = json.loads(out.read_text())
    assert [case["name"] for case in c["load_cases"]] == ["empty", "snow"]
    V, E, sup = np.asarray(c["vertices"]), np.asarray(c["edges"]), np.zeros(len(c["vertices"]), bool)
    sup[c["supports"]] = True
    for case in c["load_cases"]:
        assert relative_residuals(V, E, case["weights"], case["loads"], sup).max() <= 1e-8
    empty, snow = (np.sum(case["loads"]) for case in c["load_cases"])
    assert snow / empty == pytest.approx((2000 * 0.1 + 80.0) / (2000 * 0.1), rel=1e-12)
    assert c["parameters"]["load_model"]["cases"][1]["uniform_mass"] == 80.0


def test_check_out_that_cannot_be_written_is_refused_before_the_check(tmp_path, capsys, monkeypatch):
    from selfsupport import api

    monkeypatch.setattr(api, "check", lambda *a, **k: pytest.fail("checked although --out cannot be written"))
    out = tmp_path / "checked.json"
    out.write_text("precious\n")
    out.chmod(stat.S_IRUSR)
    code = cli.main(["check", "shape:dome:80", "--out", str(out)])
    assert_one_line_error(capsys.readouterr().err, code, 2, needle="read-only")
    assert out.read_text() == "precious\n"


# ---------------------------------------------------------------------------------- the original tool
@pytest.mark.slow
def test_the_original_tool_loads_the_written_sss(tmp_path):
    """The paper's own C++ tool (its headless driver, built by ../shared/original-tool/build.sh)
    loads the ``.sss``: the same counts and pins, our weights on its edges, and the load column
    read as the nodal self-weight (the ρ·t its loads imply is ours, times g/9.8)."""
    from selfsupport.core.loads import G
    from studies.peers import find_original_driver

    driver, reason = find_original_driver(os.environ.get("SELFSUPPORT_ORIGINAL_DRIVER"))
    if driver is None:
        pytest.skip(reason)
    sss = tmp_path / "vault.sss"
    assert cli.main(["solve", "shape:pillar_vault:200", "--out", str(sss), "-q"]) == 0
    net = read_network(sss)
    p = subprocess.run([str(driver), str(sss), str(tmp_path / "orig"), "--maxit", "0", "--quiet",
                        "--density", "2000", "--thickness", "0.1"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    head = next(ln for ln in p.stdout.splitlines() if ln.startswith("scene "))
    fields = dict(t.split("=", 1) for t in head.split() if "=" in t and not t.startswith("load("))
    assert (int(fields["V"]), int(fields["E"]), int(fields["F"]), int(fields["pinned"])) == (
        net.mesh.n_vertices, net.mesh.n_edges, net.mesh.n_faces, int(net.supports.sum()))
    implied = float(head.split("stored-loads imply rho*t=")[1].split()[0])
    assert implied == pytest.approx(2000 * 0.1 * G / 9.8, rel=1e-5)
    d = json.loads((tmp_path / "orig.json").read_text())  # its network as loaded (no iteration)
    theirs = {tuple(sorted(e)): w for e, w in zip(d["edges"], d["weights"])}
    for (i, j), w, active in zip(net.edges.tolist(), net.weights.tolist(), net.active_edges.tolist()):
        if active:
            assert theirs[(i, j)] == pytest.approx(w, rel=1e-6)
    np.testing.assert_allclose(d["vertices"], net.vertices, rtol=0, atol=1e-6 * np.abs(net.vertices).max())
