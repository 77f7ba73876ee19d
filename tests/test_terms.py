"""Every registered objective term: its numeric Gauss–Newton linearization (used by Step 3 and
the refinement) against the CasADi statement (used by IPOPT / nlopt), its structure flags, and
the problem object that builds terms by name."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

from formulations import TERMS, Problem, TermContext
from formulations.problem import FixedTopView, Hull, ObjectiveTerm, parse_objective
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.shapes import make_shape
from tests.test_formulation import MESHES, all_terms, grid_mesh


def _casadi_r_J(term, V):
    x = ca.SX.sym("x", V.size)
    r = term.residual_expr(x)
    f = ca.Function("f", [x], [r, ca.jacobian(r, x)])
    r_, J_ = f(V.ravel())
    return np.asarray(r_).ravel(), np.asarray(ca.DM(J_))


@pytest.mark.parametrize("mesh_name", sorted(MESHES))
@pytest.mark.parametrize("name", sorted(TERMS))
def test_linearization_equals_casadi_derivatives(name, mesh_name):
    mesh = MESHES[mesh_name]
    rng = np.random.default_rng(11)
    V = mesh.vertices + 0.05 * rng.standard_normal(mesh.vertices.shape)
    term = all_terms(mesh)[name]
    r, J = term.linearize(V)
    rc, Jc = _casadi_r_J(term, V)
    assert sp.issparse(J) and J.shape == (r.size, V.size)
    if name == "hull":  # some vertices outside the slab, some inside: both branches are exercised
        assert 0 < np.count_nonzero(r) < r.size
    np.testing.assert_allclose(r, rc, rtol=0, atol=1e-12 * max(1.0, np.abs(rc).max(initial=0)))
    np.testing.assert_allclose(J.toarray(), Jc, rtol=0, atol=1e-10 * max(1.0, np.abs(Jc).max(initial=0)))
    # the energy from the numeric residual is the CasADi energy
    assert term.numeric_value(V) == pytest.approx(term.value(V), rel=1e-12, abs=1e-300)


@pytest.mark.parametrize("name", sorted(TERMS))
def test_structure_flags_say_what_the_jacobian_is(name):
    mesh = MESHES["mixed"]
    term = all_terms(mesh)[name]
    V = mesh.vertices + 0.03 * np.random.default_rng(2).standard_normal(mesh.vertices.shape)
    r, J = term.linearize(V)
    if not term.couples_xyz:  # J = J1 ⊗ I3: the same operator on x, y and z
        r1, J1 = term.per_coordinate(V)
        np.testing.assert_allclose(J.toarray(), np.kron(J1.toarray(), np.eye(3)), atol=0)
        np.testing.assert_allclose(r, r1.ravel(), atol=0)
    else:
        with pytest.raises(InputError):
            term.per_coordinate(V)
    if term.vertex_local:  # each row touches one vertex: JᵀJ is 3×3 block diagonal
        G = (J.T @ J).tocoo()
        assert np.all(G.row // 3 == G.col // 3)


def test_gauss_newton_model_is_first_order_exact():
    """r(V + h D) − (r(V) + h J D) = O(h²) for the nonlinear terms (halving h quarters it)."""
    mesh = MESHES["quads"]
    V = mesh.vertices + 0.05 * np.random.default_rng(4).standard_normal(mesh.vertices.shape)
    D = np.random.default_rng(5).standard_normal(V.shape)
    for name in ("planarity", "planarity_volume", "planar"):
        term = all_terms(mesh)[name]
        r, J = term.linearize(V)
        rem = [np.linalg.norm(term.linearize(V + h * D)[0] - r - h * (J @ D.ravel())) for h in (1e-3, 5e-4)]
        assert rem[1] / rem[0] == pytest.approx(0.25, abs=0.02), name


def test_planarity_terms_vanish_on_planar_quads():
    flat = grid_mesh(5, height=0.0)
    for name in ("planarity", "planarity_volume", "planar"):
        t = all_terms(flat)[name]
        assert t.numeric_value(flat.vertices) < 1e-24
        V = flat.vertices.copy()
        V[12, 2] += 0.1
        assert t.numeric_value(V) > 1e-6


def test_reference_term_reprojects_and_scaled_terms_keep_their_minimiser():
    mesh = MESHES["quads"]
    term = all_terms(mesh)["reference"]
    V = mesh.vertices + 0.02
    moved = term.at(V)
    assert moved is not term and not np.allclose(moved.points, term.points)


def test_problem_builds_registered_terms_by_name():
    scene = make_shape("barrel_vault", n_vertices=120)
    p = Problem.build(scene, objective=["reference=1", "planarity=10"], constraints=["hull"])
    assert [o.name for o in p.objective] == ["reference", "planarity"]
    assert p.hull_thickness() == pytest.approx(0.1)  # from the default self-weight
    ctx = TermContext(vertices=scene.mesh.vertices, reference=scene.mesh, free=scene.free, thickness=0.1)
    t = p.terms(ctx)
    assert [x.name for x in t.terms] == ["reference", "planarity", "hull"]
    assert t.terms[2].constraint and not t.terms[0].constraint
    assert Problem.build(scene, constraints=[FixedTopView()]).fixed_top_view
    assert parse_objective({"vertices": 2}) == (ObjectiveTerm("vertices", 2.0),)
    with pytest.raises(InputError, match="unknown objective term"):
        parse_objective("smoothness=3")
    with pytest.raises(InputError, match="WEIGHT"):
        parse_objective("planarity=lots")
    with pytest.raises(InputError, match="unknown constraint"):
        Problem.build(scene, constraints=["walls"])
    with pytest.raises(InputError, match="thickness"):
        Problem.build(scene, loads={"a": __import__("selfsupport").PointLoad(-np.ones(scene.mesh.n_vertices))},
                      constraints=[Hull()]).hull_thickness()


def test_per_edge_bounds_and_their_errors():
    scene = make_shape("dome", n_vertices=80)
    m = scene.mesh.n_edges
    sp_ = Problem.build(scene, w_max=np.linspace(1e4, 2e4, m)).scaled()
    up = sp_.scaling.weight_back(sp_.upper)
    np.testing.assert_allclose(up, np.linspace(1e4, 2e4, m)[scene.active_edges], rtol=1e-13)
    with pytest.raises(InputError, match="entries"):
        Problem.build(scene, w_max=np.ones(3)).scaled()
    with pytest.raises(InputError, match="must exceed"):
        Problem.build(scene, eps=5.0, w_max=1.0).scaled()


@pytest.mark.parametrize("name", sorted(n for n, c in TERMS.items() if c.vertex_local))
def test_vertex_blocks_are_the_gauss_newton_normal_equations(name):
    """Step 3 takes vertex-local terms as 3×3 blocks without sparse products: ``B = JᵢᵀJᵢ`` and
    ``b = Jᵢᵀ(Jᵢ vᵢ − rᵢ)`` must be what the generic linearization gives."""
    from formulations.terms.base import Term

    mesh = MESHES["mixed"]
    term = all_terms(mesh)[name]
    V = mesh.vertices + 0.05 * np.random.default_rng(8).standard_normal(mesh.vertices.shape)
    idx, B, b = type(term).vertex_blocks(term, V)
    idx_g, B_g, b_g = Term.vertex_blocks(term, V)  # the generic form, from linearize()
    keep = np.isin(idx, idx_g)
    assert np.array_equal(idx[keep], idx_g) and np.abs(B[~keep]).max(initial=0) <= 1e-14  # (zero blocks)
    np.testing.assert_allclose(B[keep], B_g, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b[keep], b_g, rtol=0, atol=1e-12)


def test_coplanarity_rows_of_polygons_vanish_exactly_when_planar():
    """Pentagons with a straight (T-junction) corner and hexagons: the rows are zero on planar
    faces whatever their shape, nonzero when one corner leaves the plane, and their CasADi
    statement matches the numeric Jacobian."""
    from formulations.terms.planarity import coplanarity_rows

    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0], [3, 0.5, 0], [1, 2, 0], [2, 2, 0.]])
    mesh = PolyMesh.from_faces(V, [[0, 1, 2, 3, 4], [2, 5, 3], [4, 3, 7, 6]])
    tilt = np.array([0.3, -0.2, 0.5])  # a plane through the origin, not horizontal
    Vp = V.copy()
    Vp[:, 2] = V @ tilt
    Q, owner, _ = coplanarity_rows(mesh)
    assert sorted(set(owner.tolist())) == [0, 2] and np.count_nonzero(owner == 0) == 2
    for name in ("planarity_volume", "planar"):
        term = TERMS[name](mesh)
        assert np.abs(term.linearize(Vp)[0]).max() < 1e-14
        bent = Vp.copy()
        bent[1, 2] += 0.05  # the straight corner of the pentagon leaves the plane
        r, J = term.linearize(bent)
        assert np.abs(r).max() > 1e-3
        rc, Jc = _casadi_r_J(term, bent)
        np.testing.assert_allclose(r, rc, atol=1e-13)
        np.testing.assert_allclose(J.toarray(), Jc, atol=1e-12)


def test_faces_with_three_fixed_corners_get_no_coplanarity_rows():
    """Their plane is the supports': a free fourth corner held in it would be pinned there."""
    from formulations.terms.planarity import coplanarity_rows

    mesh = grid_mesh(3)  # four quads
    fixed = np.zeros(mesh.n_vertices, bool)
    corner = next(f for f in mesh.faces if 0 in f)
    fixed[[v for v in corner if v != corner[2]][:3]] = True
    _, owner, _ = coplanarity_rows(mesh, fixed)
    held = [k for k, f in enumerate(mesh.faces) if fixed[list(f)].sum() >= 3]
    assert len(held) == 1 and held[0] not in owner.tolist() and len(owner) == mesh.n_faces - 1
