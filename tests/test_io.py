"""I/O: round trips for every format, axis conventions, supports files, broken inputs,
atomic writes, the JSON network format (checked by the independent shared checker) and
the paper's own scenes (skipped when ../shared is absent)."""
from __future__ import annotations

import json
import os
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from selfsupport.core.errors import InputError, MeshError, SupportError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.io import network_to_dict, read_mesh, read_network, read_scene, write_mesh, write_network, write_scene_sss
from selfsupport.io.atomic import atomic_write_bytes, atomic_write_text
from selfsupport.io.axes import UP_AXES, to_file, to_ours
from tests.conftest import SHARED, independent_check, load_factor, requires_checker

SCENES = SHARED / "paper-scenes" / "scenes"


# ---------------------------------------------------------------------------------- fixtures
def mixed_mesh(nx: int = 4, ny: int = 3, seed: int = 0) -> PolyMesh:
    """A jittered height field over a grid: quads, with every other cell of odd rows split into
    two triangles (mixed polygon sizes), coordinates with full 53-bit mantissas."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(nx + 1, dtype=float), np.arange(ny + 1, dtype=float), indexing="xy")
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    v[:, :2] += rng.uniform(-0.2, 0.2, (len(v), 2))
    v[:, 2] = 1.0 - ((v[:, 0] - nx / 2) ** 2 + (v[:, 1] - ny / 2) ** 2) / (nx * ny) + rng.uniform(-1e-3, 1e-3, len(v))
    idx = lambda i, j: j * (nx + 1) + i  # noqa: E731
    faces = []
    for j in range(ny):
        for i in range(nx):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            if j % 2 and i % 2 == 0:
                faces += [[a, b, c], [a, c, d]]
            else:
                faces.append([a, b, c, d])
    return PolyMesh.from_faces(v, faces).validate()


def apex_network(reference: bool = False) -> Network:
    """One free apex over four supports, in exact equilibrium (weights by hand, all dyadic).

    Apex (a, b, h) = (1/4, -1/8, 2), supports at (±1, 0, 0), (0, ±1, 0), apex load L = -16:
    z: -h Σw = L gives Σw = S = 8; x: w_(+x) - w_(-x) = a S; y: w_(+y) - w_(-y) = b S; splitting
    S evenly between the x pair and the y pair gives w = 3, 1 (x) and 1.5, 2.5 (y).
    """
    v = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0.25, -0.125, 2.0]])
    mesh = PolyMesh.from_faces(v, [[4, 0, 1], [4, 1, 2], [4, 2, 3], [4, 3, 0]])
    by_edge = {(0, 4): 3.0, (2, 4): 1.0, (1, 4): 1.5, (3, 4): 2.5}
    # support-support edges get a junk weight: the writer must zero them
    w = np.array([by_edge.get(tuple(e), 7.0) for e in mesh.edges.tolist()])
    loads = np.array([-4.0, -4.0, -4.0, -4.0, -16.0])
    sup = np.array([True, True, True, True, False])
    ref = mesh.with_vertices(v + [0, 0, 0.5]) if reference else None
    return Network(mesh=mesh, weights=w, loads=loads, supports=sup, reference=ref,
                   handles=np.array([False, False, False, False, True]))


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def same_mesh(a: PolyMesh, b: PolyMesh) -> None:
    np.testing.assert_array_equal(a.vertices, b.vertices)  # exact: writers use repr
    assert a.faces == b.faces
    np.testing.assert_array_equal(a.face_sizes, b.face_sizes)


# ---------------------------------------------------------------------------------- axes
@pytest.mark.parametrize("up", list(UP_AXES))
def test_up_axes_are_proper_rotations_taking_up_to_z(up):
    R = UP_AXES[up]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=0)
    assert np.linalg.det(R) == pytest.approx(1.0)
    sign, axis = (-1.0, up[1]) if up.startswith("-") else (1.0, up)
    file_up = sign * np.eye(3)["xyz".index(axis)]
    np.testing.assert_array_equal(to_ours(file_up, up), [[0, 0, 1]])
    p = np.random.default_rng(1).normal(size=(5, 3))
    np.testing.assert_array_equal(to_file(to_ours(p, up), up), p)


def test_unknown_up_is_an_input_error(tmp_path):
    m = mixed_mesh()
    with pytest.raises(InputError, match="'up'|up="):
        write_mesh(tmp_path / "m.obj", m, up="w")
    write_mesh(tmp_path / "m.obj", m)
    with pytest.raises(InputError, match="one of"):
        read_mesh(tmp_path / "m.obj", up="+q")


# ---------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".obj", ".ply", ".off"])
@pytest.mark.parametrize("up", ["z", "-y", "x"])
def test_mesh_round_trip_keeps_polygons_and_exact_positions(tmp_path, suffix, up):
    m = mixed_mesh()
    assert set(m.face_sizes.tolist()) == {3, 4}
    p = tmp_path / f"m{suffix}"
    write_mesh(p, m, up=up)
    same_mesh(read_mesh(p, up=up), m)


def test_written_file_is_in_the_requested_axes(tmp_path):
    m = mixed_mesh()
    write_mesh(tmp_path / "m.obj", m, up="-y")
    # read as if z were up: the file's y is minus our height
    raw = read_mesh(tmp_path / "m.obj")
    np.testing.assert_array_equal(raw.vertices[:, 1], -m.vertices[:, 2])


def write_binary_ply(path: Path, v: np.ndarray, faces: list[list[int]], *, order: str = "<", coord: str = "d") -> None:
    """A binary PLY with extra vertex/face properties and an extra element (must be skipped)."""
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    ctype = {"d": "double", "f": "float"}[coord]
    header = (f"ply\nformat {fmt} 1.0\ncomment made by hand\nelement vertex {len(v)}\n"
              f"property {ctype} x\nproperty {ctype} y\nproperty {ctype} z\nproperty uchar red\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nproperty float quality\n"
              "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n")
    body = b"".join(struct.pack(f"{order}3{coord}B", *p, 200) for p in v.tolist())
    body += b"".join(struct.pack(f"{order}B{len(f)}if", len(f), *f, 0.5) for f in faces)
    body += struct.pack(f"{order}2i", 0, 1)
    path.write_bytes(header.encode() + body)


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_ply_keeps_polygons(tmp_path, order):
    m = mixed_mesh()
    write_binary_ply(tmp_path / "b.ply", m.vertices, m.faces, order=order)
    same_mesh(read_mesh(tmp_path / "b.ply"), m)


def test_binary_ply_float32(tmp_path):
    m = mixed_mesh()
    write_binary_ply(tmp_path / "f.ply", m.vertices, m.faces, coord="f")
    got = read_mesh(tmp_path / "f.ply")
    np.testing.assert_array_equal(got.vertices, m.vertices.astype(np.float32).astype(float))
    assert got.faces == m.faces


def test_ascii_ply_with_extra_properties(tmp_path):
    text = ("ply\nformat ascii 1.0\ncomment x\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nelement face 2\nproperty list uchar int vertex_indices\n"
            "property int flags\nend_header\n0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0.5 4\n3 0 1 2 7\n3 0 2 3 7\n")
    m = read_mesh(write(tmp_path, "a.ply", text))
    assert m.faces == [[0, 1, 2], [0, 2, 3]]
    np.testing.assert_array_equal(m.vertices[3], [0, 1, 0.5])


def test_obj_index_forms_relative_indices_and_ignored_records(tmp_path):
    text = """# comment
mtllib x.mtl
o thing
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0  # trailing comment
v 2 0 0
vt 0 0
vn 0 0 1
g group
s off
usemtl stone
f 1/1/1 2/1/1 3/1/1 4/1/1
f 2//1 5//1 3//1
l 1 2
"""
    text += "v 2 1 0\nf -4 -2 -1\n"  # relative: vertices 3 (index 2), 5 (4), 6 (5)
    m = read_mesh(write(tmp_path, "m.obj", text))
    assert m.faces == [[0, 1, 2, 3], [1, 4, 2], [2, 4, 5]]


def test_off_variants(tmp_path):
    text = "OFF 4 2 5\n# comment\n0 0 0\n1 0 0\n\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3 255 0 0\n"
    assert read_mesh(write(tmp_path, "a.off", text)).faces == [[0, 1, 2], [0, 2, 3]]
    text = "COFF\n4 1 4\n0 0 0 1 0 0 1\n1 0 0 1 0 0 1\n1 1 0 1 0 0 1\n0 1 0 1 0 0 1\n4 0 1 2 3\n"
    assert read_mesh(write(tmp_path, "c.off", text)).faces == [[0, 1, 2, 3]]


def test_sss_round_trip(tmp_path):
    m = mixed_mesh()
    sup = m.boundary_vertex_mask.copy()
    handles = np.zeros(m.n_vertices, bool)
    handles[[5, 6]] = True
    ew = np.array([[m.edges[3, 1], m.edges[3, 0], 2.5], [m.edges[7, 0], m.edges[7, 1], 0.125]])
    scene = Scene(mesh=m, supports=sup, handles=handles, meta={"sss_edge_weights": ew})
    p = tmp_path / "s.sss"
    write_scene_sss(p, scene)
    back = read_scene(p)
    same_mesh(back.mesh, m)
    np.testing.assert_array_equal(back.supports, sup)
    np.testing.assert_array_equal(back.handles, handles)
    np.testing.assert_array_equal(back.meta["sss_loads"], 0.0)
    got = {(int(i), int(j)): w for i, j, w in back.meta["sss_edge_weights"]}
    assert len(got) == m.n_edges
    assert got[tuple(m.edges[3])] == 2.5 and got[tuple(m.edges[7])] == 0.125
    assert sum(w != 0 for w in got.values()) == 2
    assert back.name == "s"
    assert read_scene(p, name="other").name == "other"


def test_sss_axis_convention_and_obj_minus_y_agree(tmp_path):
    sss = "v 1 -2 3 7.5 1 0\nv 4 -2 3 7.5 1 0\nv 1 -2.5 5 7.5 0 1\nf 3 0 1 2\n"
    scene = read_scene(write(tmp_path, "t.sss", sss))
    np.testing.assert_array_equal(scene.mesh.vertices[0], [1, 3, 2])  # (X, Z, -Y)
    np.testing.assert_array_equal(scene.supports, [True, True, False])
    np.testing.assert_array_equal(scene.handles, [False, False, True])
    np.testing.assert_array_equal(scene.meta["sss_loads"], [7.5] * 3)  # kept, never used as a load
    assert scene.point_loads is None and scene.extra_mass is None
    obj = "v 1 -2 3\nv 4 -2 3\nv 1 -2.5 5\nf 1 2 3\n"
    m = read_mesh(write(tmp_path, "t.obj", obj), up="-y")
    np.testing.assert_array_equal(m.vertices, scene.mesh.vertices)
    np.testing.assert_array_equal(read_mesh(tmp_path / "t.sss", up="-y").vertices, m.vertices)
    # proper rotation: the face normal keeps its orientation relative to the surface
    n_file = np.cross([3, 0, 0], [0, -0.5, 2])
    v = m.vertices
    np.testing.assert_allclose(np.cross(v[1] - v[0], v[2] - v[0]), to_ours(n_file, "-y")[0])


def test_sss_rejects_other_up(tmp_path):
    p = write(tmp_path, "t.sss", "v 0 0 0 0 1 0\nv 1 0 0 0 1 0\nv 0 0 1 0 0 0\nf 3 0 1 2\n")
    with pytest.raises(InputError, match="-y"):
        read_scene(p, up="z")


def test_sss_supports_override(tmp_path):
    m = mixed_mesh()
    p = tmp_path / "s.sss"
    write_scene_sss(p, Scene(mesh=m, supports=np.zeros(m.n_vertices, bool)))
    assert not read_scene(p).supports.any()
    np.testing.assert_array_equal(read_scene(p, supports="boundary").supports, m.boundary_vertex_mask)


def test_json_network_round_trip(tmp_path):
    net = apex_network(reference=True)
    p = tmp_path / "net.json"
    write_network(p, net, scene="apex")
    d = json.loads(p.read_text())
    assert d["scene"] == "apex"
    assert d["edges"] == net.mesh.edges.tolist()
    assert d["supports"] == [0, 1, 2, 3] and d["handles"] == [4]
    back = read_network(p)
    same_mesh(back.mesh, net.mesh)
    expect_w = np.where(net.active_edges, net.weights, 0.0)
    np.testing.assert_array_equal(back.weights, expect_w)
    np.testing.assert_array_equal(back.loads, net.loads)
    np.testing.assert_array_equal(back.supports, net.supports)
    np.testing.assert_array_equal(back.handles, net.handles)
    same_mesh(back.reference, net.reference)
    assert back.max_relative_error() == 0.0


def test_json_edges_in_any_order_and_direction(tmp_path):
    net = apex_network()
    d = network_to_dict(net)
    perm = np.random.default_rng(3).permutation(len(d["edges"]))
    d["edges"] = [d["edges"][k][::-1] for k in perm]
    d["weights"] = [d["weights"][k] for k in perm]
    back = read_network(write(tmp_path, "n.json", json.dumps(d)))
    np.testing.assert_array_equal(back.weights, network_to_dict(net)["weights"])


def test_json_as_scene_keeps_reference(tmp_path):
    net = apex_network(reference=True)
    p = tmp_path / "n.json"
    write_network(p, net)
    s = read_scene(p)
    same_mesh(s.mesh, net.mesh)
    np.testing.assert_array_equal(s.supports, net.supports)
    np.testing.assert_array_equal(s.meta["reference_vertices"], net.reference.vertices)
    assert s.meta["reference_faces"] == net.reference.faces
    with pytest.raises(InputError, match="z up"):
        read_scene(p, up="-y")
    # a hand-made scene without supports needs --supports
    d = {"vertices": net.vertices.tolist(), "faces": net.mesh.faces}
    with pytest.raises(SupportError, match="--supports boundary"):
        read_scene(write(tmp_path, "h.json", json.dumps(d)))
    assert read_scene(tmp_path / "h.json", supports="boundary").supports.sum() == 4


def test_solve_result_fields_are_plain_json(tmp_path):
    net = apex_network()
    res = SolveResult(network=net, status="converged", method="staggered", backend="ipopt", iterations=np.int64(3),
                      wall_time=0.25, history=({"E": np.float64(1e-3), "step": np.arange(2), "bad": float("nan")},),
                      parameters={"alpha": np.float32(0.5), "schedule": (1, 2)}, max_relative_error=0.0,
                      min_weight=1.0, distance_mean=float("nan"), distance_max=float("inf"))
    p = tmp_path / "r.json"
    write_network(p, res, command="solve")
    text = p.read_text()
    assert "NaN" not in text and "Infinity" not in text
    d = json.loads(text)
    assert d["status"] == "converged" and d["method"] == "staggered" and d["backend"] == "ipopt"
    assert d["iterations"] == 3 and d["wall_time"] == 0.25 and d["command"] == "solve"
    assert d["distance_to_reference"] == {"mean": None, "max": None}
    assert d["history"] == [{"E": 1e-3, "step": [0, 1], "bad": None}]
    assert d["parameters"] == {"alpha": 0.5, "schedule": [1, 2]}
    assert d["max_relative_error"] == 0.0 and d["min_weight"] == 1.0
    with pytest.raises(ValueError, match="'weights'"):
        network_to_dict(net, weights=[1])


# ------------------------------------------------------- the JSON writer's number formatting
def _random_doubles(n: int, seed: int) -> np.ndarray:
    """Doubles from random bit patterns (every exponent: subnormals, 1e±300, NaN payloads, ±inf)
    plus the values a writer gets wrong first."""
    bits = np.random.default_rng(seed).integers(0, 2 ** 64, n, dtype=np.uint64, endpoint=False)
    special = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 2.225073858507201e-308, 1e-300, -1e300,
               1.7976931348623157e308, 1e16, 1e-5, 1e-4, 0.1, 1 / 3, 123456789012345680.0, 1.0, -1.5, 2.0 ** 53,
               float("nan"), float("inf"), -float("inf")]
    return np.concatenate([bits.view(np.float64), special])


def _numbers_in(text: str) -> list[str]:
    return [t for t in text.replace("[", " ").replace("]", " ").replace(",", " ").split()]


@pytest.mark.parametrize("shape", [(-1,), (-1, 3)])
def test_json_numbers_are_repr_exact_and_strict(shape):
    """Every float is written as ``float.__repr__`` writes it, so it reads back as the same double
    (sign of zero included); non-finite ones as null; byte for byte what json.dumps writes."""
    from selfsupport.io.network_json import _json_value, to_jsonable

    a = _random_doubles(30_000, seed=len(shape)).reshape(shape)
    text = _json_value(a)
    assert text == json.dumps(to_jsonable(a), allow_nan=False, separators=(", ", ": "))
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict token {c}"))
    for tok, x in zip(_numbers_in(text), a.ravel().tolist(), strict=True):
        if not np.isfinite(x):
            assert tok == "null"
        else:
            assert float(tok) == x and np.signbit(float(tok)) == np.signbit(x), (tok, x)
    subnormal = np.abs(a) < 2.2250738585072014e-308
    assert subnormal.any() and (np.abs(a[np.isfinite(a)]) > 1e300).any()  # the sample covers both ends


@pytest.mark.parametrize("a", [np.arange(-1005, 1005), np.array([0]), np.array([-9, 10, -99, 100, 2 ** 62, -(2 ** 62)]),
                               np.array([[0, 1], [10, 11], [999, -1000]]), np.zeros((0,), int), np.zeros((0, 2), int),
                               np.zeros((3, 0), int), np.zeros((2, 0)), np.zeros((0, 3)),
                               np.array([2 ** 64 - 1], np.uint64), np.array([np.iinfo(np.int64).min]),
                               np.arange(6, dtype=np.int32).reshape(2, 3), np.array([3, 2], np.uint8)])
def test_json_integers_match_json_dumps(a):
    from selfsupport.io.network_json import _json_value, to_jsonable

    assert _json_value(a) == json.dumps(to_jsonable(a), separators=(", ", ": "))


def test_json_faces_and_a_whole_result_match_the_plain_document(tmp_path):
    """The file write_network writes (arrays formatted straight from numpy) is byte for byte
    dumps_network(network_to_dict(...)), the plain-list document, for mixed polygons, a
    reference, handles and several load cases."""
    from selfsupport.io.network_json import _Faces, _json_value, dumps_network

    m = mixed_mesh(5, 4)
    assert len(set(np.diff(m.face_offsets).tolist())) == 2
    assert _json_value(_Faces(m)) == json.dumps(m.faces, separators=(", ", ": "))
    tri = PolyMesh.from_faces(m.vertices, [[0, 1, 6], [1, 7, 6]])
    assert _json_value(_Faces(tri)) == json.dumps(tri.faces, separators=(", ", ": "))
    net = apex_network(reference=True)
    other = Network(mesh=net.mesh, weights=net.weights * 2, loads=net.loads * 2, supports=net.supports)
    res = SolveResult.build(net, cases=(("a", net), ("b", other)), status="converged", method="staggered",
                            backend="active-set", iterations=2, wall_time=0.5,
                            history=({"E": 1.0, "w": np.array([0.5, np.nan])},),
                            parameters={"hull": {"signed_distance": [0.1, -0.0]}})
    p = tmp_path / "r.json"
    write_network(p, res, command="solve", extra_array=np.array([1.5, np.inf]))
    assert p.read_text() == dumps_network(network_to_dict(res, command="solve", extra_array=np.array([1.5, np.inf])))
    assert json.loads(p.read_text())["load_cases"][1]["weights"] == (2 * np.where(net.active_edges, net.weights, 0)).tolist()


@requires_checker
def test_written_network_passes_the_independent_checker(tmp_path):
    p = tmp_path / "apex.json"
    write_network(p, apex_network())
    r = independent_check(p, tol=1e-12)
    assert r.returncode == 0, r.stdout
    assert r.ok and r["supports"] == 4
    # and it does fail a network out of equilibrium (the check is not vacuous)
    d = json.loads(p.read_text())
    d["loads"][4] = -17.0
    q = write(tmp_path, "bad.json", json.dumps(d))
    r = independent_check(q, tol=1e-12)
    assert r.returncode == 1


# ---------------------------------------------------------------------------------- supports
def test_supports_file_with_comments(tmp_path):
    m = mixed_mesh()
    write_mesh(tmp_path / "m.obj", m)
    sf = write(tmp_path, "m.supports", "# ground contact\n0 1   2\n\n7 # corner\n# 9\n7\n")
    s = read_scene(tmp_path / "m.obj", supports=str(sf))
    assert np.flatnonzero(s.supports).tolist() == [0, 1, 2, 7]
    assert s.handles is None


def test_boundary_supports_and_missing_supports(tmp_path):
    m = mixed_mesh()
    for suffix in (".obj", ".ply", ".off"):
        p = tmp_path / f"m{suffix}"
        write_mesh(p, m)
        np.testing.assert_array_equal(read_scene(p, supports="boundary").supports, m.boundary_vertex_mask)
        with pytest.raises(SupportError, match="no supports.*--supports boundary or --supports FILE"):
            read_scene(p)


@pytest.mark.parametrize("text, match", [
    ("0 1\n2 x3\n", r":2: 'x3' is not a vertex index"),
    ("0 1\n\n# c\n2 99\n", r":4: vertex index 99 is outside 0\.\.19"),
    ("0 -1\n", r":1: vertex index -1"),
    ("1.5\n", r":1: '1.5' is not"),
    ("# nothing\n\n", "lists no vertex indices"),
])
def test_bad_supports_file(tmp_path, text, match):
    m = mixed_mesh()
    write_mesh(tmp_path / "m.obj", m)
    sf = write(tmp_path, "bad.supports", text)
    with pytest.raises(InputError, match=match) as e:
        read_scene(tmp_path / "m.obj", supports=str(sf))
    assert "bad.supports" in str(e.value)


# ---------------------------------------------------------------------------------- broken files
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
BAD_FILES = [
    ("e.obj", "", "empty"),
    ("e.obj", "\n  \n", "empty"),
    ("a.obj", TRI + "xyz 1 2\n", r":4: unknown OBJ record 'xyz'"),
    ("b.obj", "v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n", r":2: vertex record has a non-numeric"),
    ("c.obj", "v 0 0\n", r":1: vertex record has 2 numbers"),
    ("d.obj", TRI + "f 1 2 4\n", r":4: face 0 refers to vertex index 4, outside 1\.\.3"),
    ("f.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r":1: vertex 0 has a NaN"),
    ("g.obj", TRI + "f 1 2\n", r":4: face record has 2 corners"),
    ("h.obj", TRI + "f 0 1 2\n", r":4: face index 0"),
    ("i.obj", TRI + "f 1 2 x\n", r":4: face index 'x'"),
    ("j.obj", TRI + "f -1 -2 -4\n", r":4: relative face index -4"),
    ("k.obj", TRI, "no faces"),
    ("a.sss", "v 1 2 3 0 0\n", r":1: vertex record has 5 fields"),
    ("b.sss", TRI.replace("\n", " 0 1 0\n") + "f 4 0 1 2\n", r":4: face record says 4 corners but lists 3"),
    ("c.sss", "v 0 0 0 0 2 0\nv 1 0 0 0 1 0\nv 0 0 1 0 0 0\nf 3 0 1 2\n", r":1: pinned/handled flags"),
    ("d.sss", "v 0 0 0 0 1 0\nv 1 0 x 0 1 0\nv 0 0 1 0 0 0\nf 3 0 1 2\n", r":2: vertex record has a non-numeric"),
    ("e.sss", "v 0 0 0 0 1 0\nv 1 0 0 0 1 0\nv 0 0 1 0 0 0\n\nf 3 0 1 5\n", r":5: face 0 refers to vertex index 5"),
    ("f.sss", "v 0 0 0 0 1 0\nq 1\n", r":2: unknown .sss record 'q'"),
    ("g.sss", "v 0 0 0 0 1 0\nv 1 0 inf 0 1 0\nv 0 0 1 0 0 0\nf 3 0 1 2\n", r":2: vertex 1 has a NaN or infinite"),
    ("h.sss", "v 0 0 0 0 1 0\nv 1 0 0 0 1 0\nv 0 0 1 0 0 0\nf 3 0 1 2\ne 0 1 0\n", r":5: edge record has 3 fields"),
    ("i.sss", "v 0 0 0 0 1 0\nv 1 0 0 0 1 0\nv 0 0 1 0 0 0\nf 3 0 1 2\ne 0 9 0 0 1\n", r":5: edge record"),
    ("a.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n", "ends after 2 of the 3 vertices"),
    ("b.off", "OFF\n3 1 0\n0 0\n1 0 0\n0 1 0\n3 0 1 2\n", r":3: vertex record has 2 numbers"),
    ("c.off", "OFF\nthree 1 0\n", r":2: counts"),
    ("d.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", r":6: face record says 4 corners"),
    ("e.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", r":7: unexpected data"),
    ("f.off", "PLY\n3 1 0\n", r":1: header 'PLY'"),
    ("a.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n",
     r":11: 'vertex' record has too few values"),
    ("b.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0 9\n0 1 0\n3 0 1 2\n",
     r":11: 'vertex' record has 4 values"),
    ("c.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n", "no 'end_header'"),
    ("d.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
     r":13: face 0 refers to vertex index 7"),
    ("e.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "end_header\n0 0 0\n1 0 0\n0 1 0\n", "no 'face' element"),
    ("f.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n", "ends after 2 of"),
    ("a.json", "{\"vertices\": [[0, 0, 0],\n [1, 0 0]]}", r":2: is not valid JSON"),
    ("b.json", "[1, 2]", "not an object"),
    ("c.json", '{"vertices": [[0, 0, NaN], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]}', "NaN"),
    ("d.json", '{"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 3]]}', "face 0 refers"),
    ("e.json", '{"vertices": [[0, 0, "a"], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]}', "'vertices' contains a string"),
]


@pytest.mark.parametrize("name, text, match", BAD_FILES, ids=[b[0] + ":" + b[2][:20] for b in BAD_FILES])
def test_broken_file_raises_input_error_naming_file_and_line(tmp_path, name, text, match):
    p = write(tmp_path, name, text)
    with pytest.raises(InputError, match=match) as e:
        read_scene(p, supports="boundary")
    assert str(p) in str(e.value)
    assert not isinstance(e.value, SupportError)


def test_truncated_binary_ply(tmp_path):
    m = mixed_mesh()
    p = tmp_path / "t.ply"
    write_binary_ply(p, m.vertices, m.faces)
    data = p.read_bytes()
    for cut in (len(data) - 10, data.index(b"end_header") + 11 + 40):
        p.write_bytes(data[:cut])
        with pytest.raises(InputError, match="truncated"):
            read_mesh(p)


def test_unusable_mesh_is_a_mesh_error_naming_the_file(tmp_path):
    # three triangles on the edge (0, 1): non-manifold
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n"
    p = write(tmp_path, "nm.obj", text)
    with pytest.raises(MeshError, match="non-manifold") as e:
        read_mesh(p)
    assert "nm.obj" in str(e.value)


def test_missing_file_unknown_suffix(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_scene(tmp_path / "nope.obj")
    with pytest.raises(InputError, match="unknown file type '.stl'"):
        read_scene(write(tmp_path, "x.stl", "solid"))
    with pytest.raises(InputError, match="writable types"):
        write_mesh(tmp_path / "x.stl", mixed_mesh())


def _bad_network(tmp_path: Path, mutate) -> Path:
    d = network_to_dict(apex_network())
    mutate(d)
    return write(tmp_path, "bad.json", json.dumps(d))


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.pop("weights"), "missing key 'weights'"),
    (lambda d: d.pop("supports"), "missing key 'supports'"),
    (lambda d: d["weights"].__setitem__(3, "abc"), "key 'weights' contains a string where numbers"),
    (lambda d: d["weights"].__setitem__(3, None), "key 'weights' contains null"),
    (lambda d: d.__setitem__("weights", d["weights"][:-1]), "key 'weights' has 7 entries for 8 edges"),
    (lambda d: d.__setitem__("loads", d["loads"][:-1]), "key 'loads' has 4 entries for 5 vertices"),
    (lambda d: d.__setitem__("weights", 3), "key 'weights' is a JSON int, not a list"),
    (lambda d: d["edges"].__setitem__(0, [0, 99]), "key 'edges' refers to index 99"),
    (lambda d: d["edges"].__setitem__(0, [0, 1.5]), "key 'edges' contains a non-integer"),
    (lambda d: d["edges"].__setitem__(0, [0, 2]), r"\(0, 2\) is not an edge of the faces"),
    (lambda d: d["edges"].__setitem__(0, d["edges"][1][::-1]), "listed twice"),
    (lambda d: (d["edges"].pop(), d["weights"].pop()), "lacks the faces' edge"),
    (lambda d: d["supports"].append(5), "key 'supports' refers to index 5"),
    (lambda d: d["vertices"].__setitem__(0, [0, 0]), "key 'vertices' has rows of different lengths"),
    (lambda d: d["faces"].__setitem__(0, [4, 0]), "face 0 has 2 corners"),
])
def test_bad_network_file(tmp_path, mutate, match):
    p = _bad_network(tmp_path, mutate)
    with pytest.raises(InputError, match=match) as e:
        read_network(p)
    assert str(p) in str(e.value)


# ---------------------------------------------------------------------------------- atomic writes
def test_atomic_write_keeps_old_file_when_producer_fails(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old content\n")

    def chunks():
        yield "new beginning\n"
        raise RuntimeError("serializer broke midway")

    with pytest.raises(RuntimeError, match="midway"):
        atomic_write_text(p, chunks())
    assert p.read_text() == "old content\n"
    assert os.listdir(tmp_path) == ["out.txt"]  # no temporary file left behind


def test_write_network_failure_leaves_old_file(tmp_path):
    p = tmp_path / "net.json"
    write_network(p, apex_network())
    before = p.read_bytes()
    with pytest.raises(TypeError, match="note"):
        write_network(p, apex_network(), note=object())
    assert p.read_bytes() == before
    assert os.listdir(tmp_path) == ["net.json"]


def test_atomic_write_creates_parents_and_replaces(tmp_path):
    p = tmp_path / "a" / "b" / "m.obj"
    write_mesh(p, mixed_mesh())
    assert read_mesh(p).n_vertices == 20
    atomic_write_bytes(tmp_path / "x" / "d.bin", b"\x00\x01")
    atomic_write_bytes(tmp_path / "x" / "d.bin", [b"\x02", b"\x03"])
    assert (tmp_path / "x" / "d.bin").read_bytes() == b"\x02\x03"
    assert os.listdir(tmp_path / "x") == ["d.bin"]


def test_unwritable_target_is_an_input_error(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="cannot"):
        atomic_write_text(tmp_path / "file" / "sub" / "x.txt", "x")
    (tmp_path / "dir").mkdir()
    with pytest.raises(InputError, match="is a directory"):
        atomic_write_text(tmp_path / "dir", "x")


def test_an_output_folder_below_a_file_is_refused_naming_the_folder_given(tmp_path, capsys):
    """The message names the folder the user gave, not a path made up below it."""
    from selfsupport.cli import main

    (tmp_path / "file").write_text("kept")
    rep = tmp_path / "file" / "rep"
    assert main(["demo", "--out", str(rep)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"cannot write --out {rep}:" in err and "is a file, not a folder" in err
    assert str(rep / "x") not in err and (tmp_path / "file").read_text() == "kept"


# ---------------------------------------------------------------------------------- paper scenes
SSS_COUNTS = {  # ../shared/paper-scenes/README.md; pins from docs/reference/formats.md and the files
    "lilium": (1201, 3504, 96), "lilium-pillar": (1200, 3500, None), "cas": (1535, 2976, None),
    "twocirc-3": (752, 2165, None), "cyl2": (2348, 4302, None), "dome2": (577, 1600, None),
    "vault": (100, 180, None), "vault-pillar": (100, 180, None),
}


@pytest.mark.parametrize("name", list(SSS_COUNTS))
def test_paper_sss_scenes(name):
    path = SCENES / f"{name}.sss"
    if not path.exists():
        pytest.skip("shared paper scenes absent")
    s = read_scene(path)
    nv, ne, npin = SSS_COUNTS[name]
    assert (s.mesh.n_vertices, s.mesh.n_edges) == (nv, ne)
    if npin is not None:
        assert s.supports.sum() == npin
    assert s.meta["sss_edge_weights"].shape == (ne, 3)
    z = s.mesh.vertices[:, 2]
    assert z[s.supports].mean() < z[~s.supports].mean()  # height = -y puts the ground contact low


@pytest.mark.skipif(not (SCENES / "lilium.sss").exists(), reason="shared paper scenes absent")
def test_paper_scene_sss_rewrite_is_lossless(tmp_path):
    s = read_scene(SCENES / "lilium.sss")
    write_scene_sss(tmp_path / "l.sss", s)
    b = read_scene(tmp_path / "l.sss")
    same_mesh(b.mesh, s.mesh)
    np.testing.assert_array_equal(b.supports, s.supports)
    key = lambda a: {(min(int(i), int(j)), max(int(i), int(j))): w for i, j, w in a}  # noqa: E731
    assert key(b.meta["sss_edge_weights"]) == key(s.meta["sss_edge_weights"])


@pytest.mark.skipif(not (SCENES / "structural.obj").exists(), reason="shared paper scenes absent")
def test_paper_structural_obj_with_supports_file():
    s = read_scene(SCENES / "structural.obj", up="-y", supports=str(SCENES / "structural.supports"))
    assert (s.mesh.n_vertices, s.mesh.n_edges, int(s.supports.sum())) == (527, 998, 89)
    assert set(s.mesh.face_sizes.tolist()) == {3, 4}
    z = s.mesh.vertices[:, 2]
    assert z[s.supports].max() <= z[~s.supports].mean()


@pytest.mark.skipif(not (SCENES / "cyl2.sss").exists(), reason="shared paper scenes absent")
def test_reading_is_fast():
    best = min(_timed(read_scene, SCENES / "cyl2.sss") for _ in range(3))
    assert best < 0.2 * load_factor()  # a guard against a parser gone quadratic, not a benchmark


def _timed(f, *a) -> float:
    t = time.perf_counter()
    f(*a)
    return time.perf_counter() - t


# ------------------------------------------------------------------ the network JSON Schema
def network_schema() -> dict:
    """The JSON Schema of the network format, read as package data (as an installed copy has it)."""
    from importlib.resources import files

    return json.loads(files("selfsupport.io").joinpath("network.schema.json").read_text(encoding="utf-8"))


def test_network_schema_states_the_writer_and_reader_contract():
    """The schema is a valid draft 2020-12 schema whose required keys are the reader's and whose
    statuses are the results' (one list each, the schema follows them)."""
    import jsonschema

    from selfsupport.core.result import STATUSES
    from selfsupport.io.network_json import NETWORK_KEYS

    schema = network_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    assert tuple(schema["required"]) == NETWORK_KEYS
    assert tuple(schema["properties"]["status"]["enum"]) == STATUSES


def test_solved_networks_validate_against_the_schema(tmp_path):
    """A solved network with two load cases, written by write_network, validates; the same file
    with a defect the reader refuses does not (the schema is not vacuous)."""
    import jsonschema

    from selfsupport import api
    from selfsupport.core.shapes import make_shape

    cases = write(tmp_path, "cases.toml", '[cases.empty]\n\n[cases.apex]\npoint_loads = { "0" = 2000.0 }\n')
    res = api.solve(make_shape("dome", n_vertices=100), load_cases=cases)
    assert res.status == "converged"
    p = tmp_path / "dome.json"
    write_network(p, res)
    doc = json.loads(p.read_text())
    validator = jsonschema.Draft202012Validator(network_schema())
    assert list(validator.iter_errors(doc)) == []
    assert [c["name"] for c in doc["load_cases"]] == ["empty", "apex"]
    for key, bad in [("edges", [[0, 1, 2]]), ("supports", [-1]), ("status", "done"), ("vertices", [[0.0, 1.0]]),
                     ("weights", [None])]:
        broken = {**doc, key: bad}
        assert not validator.is_valid(broken), key
    assert not validator.is_valid({k: v for k, v in doc.items() if k != "loads"})


@pytest.mark.parametrize("argv", [["construct", "--disk", "4"], ["koebe", "--example", "grid", "--n", "6"]])
def test_other_commands_write_networks_that_validate(tmp_path, argv):
    """The commands that write a network without a solve (construct, koebe) write the same format."""
    import jsonschema

    from selfsupport.cli import main

    out = tmp_path / "net.json"
    assert main([*argv, "--out", str(out)]) == 0
    jsonschema.validate(json.loads(out.read_text()), network_schema(), cls=jsonschema.Draft202012Validator)
