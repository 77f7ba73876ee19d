"""The symbolic formulation (CasADi) against the scipy assembly, and the objective terms
against central finite differences."""
from __future__ import annotations

import numpy as np
import pytest

from formulations import (
    GROUP_NAMES,
    TERMS,
    Equilibrium,
    Fairness,
    HullPenalty,
    NormalDrift,
    PlanarFaces,
    Planarity,
    PlanarityVolume,
    PointDistance,
    ReferenceDistance,
    Scaled,
    Sum,
    ThrustNetworkProblem,
    WeightBounds,
)
from formulations import equilibrium as assembly
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh


# ----------------------------------------------------------------------------- meshes
def grid_mesh(n: int = 5, *, mixed: bool = False, height: float = 0.5) -> PolyMesh:
    """n×n grid on [-1, 1]² lifted to a paraboloid; ``mixed`` splits every other quad."""
    xs = np.linspace(-1.0, 1.0, n)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.c_[X.ravel(), Y.ravel(), 1.0 - height * (X.ravel() ** 2 + Y.ravel() ** 2)]
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [[a, b, c], [a, c, d]] if mixed and (i + j) % 2 else [[a, b, c, d]]
    return PolyMesh.from_faces(V, faces)


def topology(mesh: PolyMesh) -> assembly.Topology:
    sup = mesh.boundary_vertex_mask
    e = mesh.edges
    active = ~(sup[e[:, 0]] & sup[e[:, 1]])
    return assembly.Topology.build(mesh.n_vertices, e[active], sup)


MESHES = {"quads": grid_mesh(5), "mixed": grid_mesh(6, mixed=True)}


def random_state(mesh: PolyMesh, top: assembly.Topology, seed: int = 0):
    rng = np.random.default_rng(seed)
    V = mesh.vertices + 0.05 * rng.standard_normal(mesh.vertices.shape)
    w = 0.1 + rng.random(top.m)
    L = -(0.5 + rng.random(mesh.n_vertices))
    return V, w, L


def args_of(top, V, w, L):
    return V[top.free].ravel(), w, V[~top.free].ravel(), L[top.free]


# ----------------------------------------------------------------------------- equilibrium
@pytest.mark.parametrize("symbol", ["SX", "MX"])
@pytest.mark.parametrize("name", sorted(MESHES))
def test_jacobians_equal_assembly_matrices(name, symbol):
    mesh = MESHES[name]
    top = topology(mesh)
    V, w, L = random_state(mesh, top)
    eq = Equilibrium(top, symbol=symbol)
    J = eq.jacobian_functions()
    a = args_of(top, V, w, L)
    A = assembly.weight_matrix(top, V).toarray()
    Kff, Kfs = assembly.position_blocks(top, w)
    I3 = np.eye(3)
    np.testing.assert_allclose(np.asarray(J["w"](*a)), A, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(J["X"](*a)), np.kron(Kff.toarray(), I3), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(J["V_sup"](*a)), np.kron(Kfs.toarray(), I3), rtol=0, atol=1e-12)
    r = np.asarray(eq.residual_function()(*a)).ravel()
    np.testing.assert_allclose(r, assembly.residual(top, V, w, L).ravel(), rtol=0, atol=1e-12)


def test_problem_functions_match_assembly():
    mesh = MESHES["mixed"]
    top = topology(mesh)
    V, w, L = random_state(mesh, top, seed=3)
    P = ThrustNetworkProblem(top, V, L, WeightBounds(1e-3))
    J = P.jacobian_functions()
    a = args_of(top, V, w, L)
    np.testing.assert_allclose(np.asarray(J["w"](*a)), assembly.weight_matrix(top, V).toarray(), atol=1e-12)
    np.testing.assert_allclose(P.residual_at(V, w), assembly.residual(top, V, w, L), atol=1e-12)


def test_residual_is_equation_2_3_at_one_vertex():
    # one free vertex at the apex of a square pyramid, four supports
    V = np.array([[0, 0, 1.0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    mesh = PolyMesh.from_faces(V, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    top = topology(mesh)
    eq = Equilibrium(top, symbol="SX")
    k = np.flatnonzero(top.edges.min(axis=1) == 0)  # the four edges at the apex
    w = np.zeros(top.m)
    w[k] = 2.0
    # Σ w (v_j − v_0) = 4 · 2 · (0, 0, −1) = (0, 0, −8); with L = −8 the residual vanishes
    r = np.asarray(eq.residual_function()(V[0], w, V[1:].ravel(), [-8.0])).ravel()
    np.testing.assert_allclose(r, 0.0, atol=1e-14)
    r = np.asarray(eq.residual_function()(V[0], w, V[1:].ravel(), [-5.0])).ravel()
    np.testing.assert_allclose(r, [0, 0, -3.0], atol=1e-14)


def test_constraint_groups_are_coordinates():
    top = topology(MESHES["quads"])
    eq = Equilibrium(top)
    assert tuple(eq.groups) == GROUP_NAMES
    g = np.arange(3 * top.n_free, dtype=float)
    parts = eq.split(g)
    np.testing.assert_array_equal(parts["equilibrium_z"], g[2::3])
    assert sorted(np.concatenate(list(eq.groups.values())).tolist()) == list(range(3 * top.n_free))


def test_relative_rows_scale_the_nlp_constraints():
    mesh = MESHES["quads"]
    top = topology(mesh)
    V, w, L = random_state(mesh, top, seed=5)
    P = ThrustNetworkProblem(top, V, L, WeightBounds(1e-3))
    import casadi as ca

    d = P.nlp()
    g = np.asarray(ca.Function("g", [d["x"], d["p"]], [d["g"]])(P.pack(V, w), P.parameters())).reshape(-1, 3)
    r = assembly.residual(top, V, w, L)
    np.testing.assert_allclose(g, r / np.abs(L[top.free])[:, None], atol=1e-12)


def test_problem_pack_unpack_and_bounds():
    mesh = MESHES["mixed"]
    top = topology(mesh)
    V, w, L = random_state(mesh, top)
    P = ThrustNetworkProblem(top, V, L, WeightBounds(0.01, 5.0), objective=PointDistance(mesh.vertices))
    V2, w2 = P.unpack(P.pack(V, w))
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(w2, w)
    b = P.bounds_args()
    assert b["lbx"].size == P.n_x == 3 * top.n_free + top.m
    assert np.all(b["lbx"][3 * top.n_free:] == 0.01) and np.all(b["ubx"][3 * top.n_free:] == 5.0)
    assert np.all(np.isinf(b["lbx"][:3 * top.n_free]))
    d = P.nlp()
    assert d["x"].shape == (P.n_x, 1) and d["g"].shape == (3 * top.n_free, 1)


def test_problem_input_errors():
    mesh = MESHES["quads"]
    top = topology(mesh)
    V, w, L = random_state(mesh, top)
    with pytest.raises(InputError, match="w_max"):
        ThrustNetworkProblem(top, V, L, WeightBounds(1.0, 0.5))
    with pytest.raises(InputError, match="vertices"):
        ThrustNetworkProblem(top, V, L, WeightBounds(1e-3), objective=PointDistance(np.zeros((3, 3))))
    with pytest.raises(InputError, match="symbol"):
        Equilibrium(top, symbol="DM")


# ----------------------------------------------------------------------------- objectives
def central_gradient(term, V: np.ndarray, h: float = 1e-6) -> np.ndarray:
    g = np.zeros(V.size)
    x = V.ravel().astype(float)
    for k in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        g[k] = (term.value(xp.reshape(-1, 3)) - term.value(xm.reshape(-1, 3))) / (2 * h)
    return g.reshape(-1, 3)


def all_terms(mesh: PolyMesh, seed: int = 1):
    rng = np.random.default_rng(seed)
    n = mesh.n_vertices
    free = ~mesh.boundary_vertex_mask
    nrm = rng.standard_normal((n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    ref = mesh.with_vertices(mesh.vertices + 0.02 * rng.standard_normal((n, 3)))
    return {
        "reference": ReferenceDistance.from_reference(mesh.vertices, ref, mask=free, weight=1.5, tangential=0.05),
        "vertices": PointDistance(targets=ref.vertices, mask=free),
        "normal_drift": NormalDrift(points=ref.vertices, normals=nrm, weight=0.7),
        "planarity": Planarity(mesh, weight=2.0),
        "planarity_volume": PlanarityVolume(mesh, weight=3.0),
        "planar": PlanarFaces(mesh, weight=1.2),
        "fairness": Fairness(mesh, free=free),
        "hull": HullPenalty(points=ref.vertices, normals=nrm, half_thickness=0.01, mask=free, weight=5.0),
    }


@pytest.mark.parametrize("name", sorted(TERMS))
def test_term_gradients_match_central_differences(name):
    mesh = MESHES["mixed"]
    rng = np.random.default_rng(7)
    V = mesh.vertices + 0.05 * rng.standard_normal(mesh.vertices.shape)
    term = all_terms(mesh)[name]
    g = term.gradient(V)
    fd = central_gradient(term, V)
    assert np.linalg.norm(g) > 0
    assert np.linalg.norm(g - fd) <= 1e-6 * np.linalg.norm(g)


def test_every_registered_term_is_covered():
    assert set(TERMS) == set(all_terms(MESHES["quads"]))


def test_planarity_zero_on_planar_quads_positive_when_lifted():
    flat = grid_mesh(5, height=0.0)
    p = Planarity(flat)
    assert abs(p.value(flat.vertices)) < 1e-24
    # a paraboloid over a grid is a translational surface: its quads are planar too
    assert abs(Planarity(MESHES["quads"]).value(MESHES["quads"].vertices)) < 1e-20
    V = flat.vertices.copy()
    V[12, 2] += 0.1
    assert p.value(V) > 1e-6
    tri = PolyMesh.from_faces(flat.vertices, [[0, 1, 6], [0, 6, 5]])
    assert Planarity(tri).value(V) == 0.0 and not Planarity(tri).gradient(V).any()


def test_planarity_is_angle_defect_squared():
    # one quad with a corner lifted: compare against numpy corner angles
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.3], [0, 1, 0.]])
    mesh = PolyMesh.from_faces(V, [[0, 1, 2, 3]])
    ang = 0.0
    for k in range(4):
        a, b = V[k - 1] - V[k], V[(k + 1) % 4] - V[k]
        ang += np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b))
    ell = np.mean([np.linalg.norm(V[(k + 1) % 4] - V[k]) for k in range(4)])  # the face's length scale
    assert Planarity(mesh).value(V) == pytest.approx(ell ** 2 * (2 * np.pi - ang) ** 2, rel=1e-12)


def test_fairness_zero_on_affine_interior():
    flat = grid_mesh(5, height=0.0)
    free = ~flat.boundary_vertex_mask
    assert Fairness(flat, free=free).value(flat.vertices) < 1e-28


def test_terms_add_and_scale():
    mesh = MESHES["mixed"]
    t = all_terms(mesh)
    V = mesh.vertices + 0.01
    a, b, c = t["vertices"], t["planarity"], t["fairness"]
    s = 2.0 * a + b * 3.0 + c
    assert isinstance(s, Sum) and len(s.terms) == 3
    assert s.value(V) == pytest.approx(2 * a.value(V) + 3 * b.value(V) + c.value(V), rel=1e-13)
    np.testing.assert_allclose(s.gradient(V), 2 * a.gradient(V) + 3 * b.gradient(V) + c.gradient(V), rtol=1e-12,
                               atol=1e-14)
    assert (s * 0.5).value(V) == pytest.approx(0.5 * s.value(V), rel=1e-13)
    assert a.weight == 1.0  # scaling returns a new term


def test_scaled_term_evaluates_in_other_units():
    mesh = MESHES["quads"]
    term = PointDistance(targets=mesh.vertices)
    D, c = 4.0, (1.0, -2.0, 0.5)
    V = mesh.vertices + 0.1
    Xhat = (V - np.asarray(c)) / D
    assert Scaled(term, length=D, center=c).value(Xhat) == pytest.approx(term.value(V) / D ** 2, rel=1e-13)


def test_term_input_errors():
    with pytest.raises(InputError):
        PointDistance(targets=np.zeros((4, 2)))
    with pytest.raises(InputError):
        NormalDrift(points=np.zeros((4, 3)), normals=np.zeros((3, 3)))
    with pytest.raises(InputError, match="different vertex counts"):
        PointDistance(np.zeros((4, 3))) + PointDistance(np.zeros((5, 3)))


def test_symbol_types_resolve_to_casadi_classes_and_unknown_ones_are_refused():
    """CasADi is imported on first use (formulations name it lazily): the names and the classes
    still resolve to CasADi's own symbol classes, and any other name says which ones exist."""
    import casadi

    assert assembly.symbol_type("mx") is casadi.MX and assembly.symbol_type("SX") is casadi.SX
    assert assembly.symbol_type(casadi.SX) is casadi.SX
    with pytest.raises(InputError, match=r"use one of \['MX', 'SX'\]"):
        assembly.symbol_type("DM")
    with pytest.raises(InputError, match="unknown CasADi symbol type"):
        assembly.symbol_type(float)
