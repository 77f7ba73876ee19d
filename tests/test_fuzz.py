"""Property-based fuzzing of the solve with hypothesis.

Generated scenes: jittered grids (quads or triangles) and ring-triangulated disks, with random
heights (a dome profile plus noise, possibly flat), random scale (1 mm .. 1 km across), random
supports (the boundary, part of it, or random vertices), random density, thickness and w_max.

Properties, for every example:

* the solve either raises a :class:`~selfsupport.core.errors.SelfSupportError` (a clear refusal) or
  returns a result with a known status — no other exception escapes;
* the file it writes holds finite numbers only, and the max relative error it reports (in the
  result and in the file) equals the one recomputed here from the written network with numpy;
* the written loads are the self-weight of the written geometry (vertex areas recomputed here,
  independently of ``selfsupport.core.geometry``);
* the weights are compressive and within ``w_max``; "converged" means error <= tol, or (said so
  in the message) within the round-off floor's tolerance (``FLOOR_MARGIN`` × the floor
  recomputed here, at most ``FLOOR_CAP``).

Profiles (environment variable ``HYPOTHESIS_PROFILE``): ``ci`` (default, used by ``make test``:
a fixed set of examples, no example database, well under a minute) and ``fuzz`` (``make fuzz``:
many random examples, failures saved to ``.hypothesis/`` and replayed first next time).
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from selfsupport import api
from selfsupport.core.errors import SelfSupportError
from selfsupport.core.evidence import floor_tolerance
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import STATUSES
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import disk
from selfsupport.io import write_network
from tests.conftest import document_errors, document_floors

G = 9.81
TOL = 1e-9  # the staggered method's default required max relative error

settings.register_profile("ci", max_examples=40, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow], print_blob=True)
settings.register_profile("fuzz", max_examples=2000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow], print_blob=True)
PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "ci")
#: The polish bug these tests found (a non-converged run's polish diverging) is fixed, so no
#: profile tolerates it any more.
TOLERATE_KNOWN_BUG = False


# ------------------------------------------------------------------ independent recomputation
def vertex_areas(V: np.ndarray, faces: list[list[int]]) -> np.ndarray:
    """Each vertex's share of its faces' area, face by face in plain Python/numpy: triangles by
    the mixed Voronoi rule (Meyer et al. 2003: the Voronoi region if no angle is obtuse, else
    half the area to the obtuse corner and a quarter to the others), larger polygons fanned from
    their centroid with half of each fan triangle to either of its two polygon corners."""
    A = np.zeros(len(V))
    for f in faces:
        P = V[f]
        if len(f) == 3:
            area = 0.5 * np.linalg.norm(np.cross(P[1] - P[0], P[2] - P[0]))
            if area == 0:
                continue  # a collapsed triangle carries nothing (and has no angles)
            dots = [float(np.dot(P[(k + 1) % 3] - P[k], P[(k + 2) % 3] - P[k])) for k in range(3)]
            if min(dots) < 0:
                for k in range(3):
                    A[f[k]] += area / 2 if dots[k] < 0 else area / 4
            else:
                cot = [d / (2 * area) for d in dots]  # cot of the angle at corner k
                for k in range(3):
                    i, j = (k + 1) % 3, (k + 2) % 3
                    # corner k touches edges k-i (opposite j) and k-j (opposite i)
                    A[f[k]] += (np.sum((P[i] - P[k]) ** 2) * cot[j] + np.sum((P[j] - P[k]) ** 2) * cot[i]) / 8
        else:
            c = P.mean(axis=0)
            for k in range(len(f)):
                t = 0.5 * np.linalg.norm(np.cross(P[k] - c, P[(k + 1) % len(f)] - c))
                A[f[k]] += t / 2
                A[f[(k + 1) % len(f)]] += t / 2
    return A



# ------------------------------------------------------------------ generated scenes
def grid(nx: int, ny: int, triangles: bool) -> tuple[np.ndarray, list[list[int]]]:
    x, y = np.meshgrid(np.linspace(-1, 1, nx + 1), np.linspace(-1, 1, ny + 1), indexing="xy")
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    faces = []
    for j in range(ny):
        for i in range(nx):
            a = j * (nx + 1) + i
            b, c, d = a + 1, a + nx + 2, a + nx + 1
            if not triangles:
                faces.append([a, b, c, d])
            elif (i + j) % 2:
                faces += [[a, b, c], [a, c, d]]
            else:
                faces += [[a, b, d], [b, c, d]]
    return V, faces


@st.composite
def cases(draw):
    kind = draw(st.sampled_from(["quad grid", "triangle grid", "disk"]))
    if kind != "disk":
        nx, ny = draw(st.integers(1, 7)), draw(st.integers(1, 7))
        V, faces = grid(nx, ny, kind == "triangle grid")
        spacing = 2.0 / max(nx, ny)
    else:
        rings = draw(st.integers(1, 4))
        d = disk(rings)
        V, faces, spacing = d.mesh.vertices.copy(), d.mesh.faces, 1.0 / rings
    n = len(V)
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    jitter = draw(st.floats(0.0, 0.3))
    V[:, :2] += rng.uniform(-jitter, jitter, (n, 2)) * spacing
    rise = draw(st.floats(0.0, 2.0))
    noise = draw(st.floats(0.0, 0.5))
    V[:, 2] = rise * (1 - 0.5 * (V[:, 0] ** 2 + V[:, 1] ** 2)) + rng.uniform(-noise, noise, n) * spacing
    scale = 10 ** draw(st.floats(-3.0, 3.0))
    mesh = PolyMesh.from_faces(V * scale, faces)
    mode = draw(st.sampled_from(["boundary", "part of the boundary", "random"]))
    if mode == "boundary":
        sup = mesh.boundary_vertex_mask.copy()
    elif mode == "part of the boundary":
        sup = mesh.boundary_vertex_mask & (rng.random(n) < draw(st.floats(0.2, 0.9)))
    else:
        sup = rng.random(n) < draw(st.floats(0.05, 0.9))
    density = 10 ** draw(st.floats(0.0, 4.0))
    thickness = 10 ** draw(st.floats(-3.0, 0.0))
    # w_max relative to the natural weight scale ρ t g × length (weights are loads per length)
    w_max = None
    if draw(st.booleans()):
        w_max = 10 ** draw(st.floats(-2.0, 3.0)) * density * thickness * G * scale
    event(f"mesh: {kind}; supports: {mode}; w_max: {'yes' if w_max else 'no'}")
    return Scene(mesh=mesh, supports=sup, name="fuzz"), density, thickness, w_max


# ------------------------------------------------------------------ the property
def shows_known_polish_bug(res) -> bool:
    """The reported bug: a run that did not converge, whose final polish (weights frozen,
    positions solved exactly, loads iterated) returns a network with a larger error than the
    last iterate had — typically blown up (coordinates ~1e130) or collapsed onto a support
    (loads ~1e-49 N) — instead of the best network so far."""
    if res.status == "converged":
        return False
    iterates = [h for h in res.history if h.get("iteration") != "polish"]
    return bool(iterates) and not res.max_relative_error <= iterates[-1]["max_rel_error"] * (1 + 1e-6)


def check_solve(scene: Scene, density: float, thickness: float, w_max: float | None,
                tolerate_known_bug: bool = False) -> str:
    """Solve and check every property of the module docstring; returns the outcome (the status,
    or the refusal's exception name)."""
    try:
        res = api.solve(scene, density=density, thickness=thickness, w_max=w_max, max_iter=25, time_limit=10)
    except SelfSupportError as e:
        assert str(e) and "\n" not in str(e)
        return type(e).__name__
    assert res.status in STATUSES
    if tolerate_known_bug and shows_known_polish_bug(res):
        return "known bug: polish worse than the last iterate"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "net.json"
        write_network(path, res)
        d = json.loads(path.read_text())  # strict JSON: a non-finite number would have been written as null
    for key in ("vertices", "weights", "loads"):
        assert np.isfinite(np.asarray(d[key], float)).all(), key
    err = float(document_errors(d).max())
    assert d["status"] == res.status
    assert d["max_relative_error"] == pytest.approx(err, rel=1e-9, abs=1e-300)
    assert res.max_relative_error == pytest.approx(err, rel=1e-9, abs=1e-300)
    # loads of the written geometry
    V = np.asarray(d["vertices"], float)
    expected = -density * thickness * G * vertex_areas(V, d["faces"])
    L = np.asarray(d["loads"], float)
    assert np.abs(L - expected).max() <= 1e-9 * np.abs(expected).max()
    # supports kept, weights compressive and bounded
    assert sorted(d["supports"]) == np.flatnonzero(scene.supports).tolist()
    w = np.asarray(d["weights"], float)
    assert w.min() >= 0
    if w_max is not None:
        assert w.max() <= w_max * (1 + 1e-9)
    if res.status == "converged":
        # every vertex within tol, or (said in the message) within FLOOR_MARGIN x its round-off
        # floor and FLOOR_CAP: rounding the coordinates to doubles leaves no better positions
        rel = document_errors(d)
        over = rel > TOL
        if over.any():
            assert np.all(rel[over] <= floor_tolerance(document_floors(d)[over]))
            assert "round-off floor" in res.message
    return res.status


@settings(settings.get_profile(PROFILE))
@given(case=cases())
def test_solve_never_crashes_and_reports_the_truth(case):
    event(f"outcome: {check_solve(*case, tolerate_known_bug=TOLERATE_KNOWN_BUG)}")


#: Scenes the ``fuzz`` profile found (shrunk), kept as fixed regression cases.
FOUND = {
    # 2 x 4 jittered quads, 5 supports, w_max: the polish moved the vertices ~1e11 diagonals, then
    # trimesh's closest-point query (distance to the reference) raised IndexError
    "polish blow-up, trimesh IndexError": (
        [[-1.0374, -1.0949, -0.1853], [-0.0814, -1.0342, 0.7873], [0.9186, -1.096, -0.1005],
         [-0.9456, -0.423, 0.7114], [-0.073, -0.5316, 1.4222], [0.9027, -0.516, 0.6982],
         [-1.0765, 0.0137, 0.7355], [0.0356, 0.0434, 1.7102], [0.9205, 0.0601, 1.0106],
         [-0.932, 0.454, 0.8065], [0.0952, 0.4673, 1.4026], [0.9513, 0.4313, 0.6997],
         [-0.9071, 1.0974, 0.0402], [0.0569, 0.9598, 0.893], [0.937, 1.0635, -0.058]],
        [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7], [6, 7, 10, 9], [7, 8, 11, 10],
         [9, 10, 13, 12], [10, 11, 14, 13]],
        [0, 2, 5, 8, 9], 1883.1441651438977, 0.21043852938669258, 30.90250944817797),
    # a flat strip of 4 quads held at one vertex: the written network has coordinates ~1e130 and
    # reports a max relative error of 3e257, which no recomputation can confirm (it overflows)
    # (flat, but its free straight edges cannot be balanced in plan, so it is not refused as
    # flat: the solve runs and must report the truth)
    "flat strip on one support, polish blow-up": (
        [[-1, -1, 0], [-0.5, -1, 0], [0, -1, 0], [0.5, -1, 0], [1, -1, 0],
         [-1, 1, 0], [-0.5, 1, 0], [0, 1, 0], [0.5, 1, 0], [1, 1, 0]],
        [[0, 1, 6, 5], [1, 2, 7, 6], [2, 3, 8, 7], [3, 4, 9, 8]],
        [6], 1.0, 1.0, None),
    # ... and the same strip with a w_max
    "flat strip on one support with w_max, polish blow-up": (
        [[-1, -1, 0], [-0.5, -1, 0], [0, -1, 0], [0.5, -1, 0], [1, -1, 0],
         [-1, 1, 0], [-0.5, 1, 0], [0, 1, 0], [0.5, 1, 0], [1, 1, 0]],
        [[0, 1, 6, 5], [1, 2, 7, 6], [2, 3, 8, 7], [3, 4, 9, 8]],
        [6], 1.0, 1.0, 10.0),
}


@pytest.mark.parametrize("name", list(FOUND))
def test_found_cases(name):
    V, faces, sup, density, thickness, w_max = FOUND[name]
    scene = Scene(mesh=PolyMesh.from_faces(np.array(V, float), faces), supports=np.array(sup), name=name)
    check_solve(scene, density, thickness, w_max)


def test_profiles_are_registered():
    assert settings.get_profile("ci").max_examples < settings.get_profile("fuzz").max_examples
