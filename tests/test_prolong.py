"""The stress prolongation (methods/prolong.py): a coarse network's stress field carried to a finer
mesh reproduces a constant stress in the limit, and the prolonged network is in equilibrium on
the fine mesh, compressive and as near the reference as the coarse one."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from formulations import FixedTopView
from selfsupport.analysis.construction import lifting_weights
from selfsupport.core.evidence import distance_stats
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.core.subdivision import subdivide_like, subdivide_scene, subdivision_parents
from selfsupport.methods.base import as_problem
from selfsupport.methods.multilevel import coarse_problem, coarsen
from selfsupport.methods.prolong import PROLONG_TOL, boundary_weights, cofactor, face_stress, prolong, stress_weights
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.methods.warm import WarmStart, transfer

from .conftest import independent_check

H = np.array([[2.0, 0.3], [0.3, 1.0]])


def _quadratic(mesh):
    xy = mesh.vertices[:, :2]
    return 0.5 * np.einsum("pi,ij,pj->p", xy, H, xy)


def test_the_face_stresses_integrate_to_the_lifted_quadratics_cofactor():
    """∫σ of a piecewise-linear Airy function is Σ_e w_e e eᵀ; for the lifting of a quadratic
    ½ xᵀHx it tends to area · cof(H) as the mesh refines (the boundary edges carry nothing)."""
    devs = []
    for n in (400, 1600, 6400):
        m = make_shape("disk", n_vertices=n).mesh
        w, _ = lifting_weights(m, _quadratic(m))
        S, A = face_stress(m, m.vertices[:, :2], w)
        mean = (S * A[:, None, None]).sum(axis=0) / A.sum()
        devs.append(np.abs(mean - cofactor(H)).max() / np.abs(H).max())
    assert devs[2] < devs[1] < devs[0] and devs[2] < 0.01


def test_a_constant_stress_is_carried_to_a_finer_mesh_and_converges():
    """Weights of the coarse lifting of ½ xᵀHx, carried to a 4× finer mesh, against the fine
    lifting of the same function: close away from the boundary, closer on finer meshes."""
    med = []
    for nc in (400, 1600):
        c, f = make_shape("disk", n_vertices=nc).mesh, make_shape("disk", n_vertices=4 * nc).mesh
        wc, _ = lifting_weights(c, _quadratic(c))
        wf, _ = lifting_weights(f, _quadratic(f))
        got = stress_weights(c, c.vertices[:, :2], wc, f, f.vertices[:, :2])
        r = np.linalg.norm(f.vertices[:, :2], axis=1)
        far = (r[f.edges] < 0.7 * r.max()).all(axis=1)
        rel = np.abs(got - wf)[far] / np.median(np.abs(wf[far]))  # (a fine weight itself may be near 0)
        assert np.percentile(rel, 90) < 0.05 and rel.max() < 0.2
        med.append(float(np.median(rel)))
    assert med[1] < 0.3 * med[0] and med[1] < 2e-3  # (measured 4.1e-3 -> 8.8e-4: second order)


def test_a_boundary_arch_is_carried_once_as_a_force_not_smeared_into_the_interior():
    """A coarse network whose free edge carries an arch (a line force on its boundary edges, far
    above the areal stress): the fine interior edges get the stress of the areal field alone,
    the same as without the arch, and the fine boundary edges carry the arch's force. Counted in
    the boundary faces' stress as well, the arch was carried twice (the edges beside the boundary
    took up to its whole weight)."""
    c, f = make_shape("disk", n_vertices=400).mesh, make_shape("disk", n_vertices=1600).mesh
    cxy, fxy = c.vertices[:, :2], f.vertices[:, :2]
    wc, _ = lifting_weights(c, _quadratic(c))
    cb, fb = (c.edge_faces < 0).any(axis=1), (f.edge_faces < 0).any(axis=1)
    assert np.all(wc[cb] == 0.0)  # (a smooth Airy function's lifting: nothing on the boundary)
    arch = np.where(cb, 1e3 * np.median(np.abs(wc[~cb])), wc)
    smooth = stress_weights(c, cxy, wc, f, fxy)
    carried = stress_weights(c, cxy, arch, f, fxy)
    assert np.abs(carried - smooth).max() <= 1e-12 * np.abs(smooth).max()
    force = boundary_weights(c, cxy, arch, f, fxy)[fb] * np.linalg.norm(fxy[f.edges[fb, 1]] - fxy[f.edges[fb, 0]], axis=1)
    coarse_force = arch[cb] * np.linalg.norm(cxy[c.edges[cb, 1]] - cxy[c.edges[cb, 0]], axis=1)
    assert force.min() >= coarse_force.min() * (1 - 1e-12) and force.max() <= coarse_force.max() * (1 + 1e-12)


@pytest.fixture(scope="module")
def two_levels():
    fine = make_shape("concave_disk", n_vertices=2400)
    problem = as_problem(fine, SelfWeight())
    coarse = coarsen(fine, 600)
    res = StaggeredLinearization().solve(coarse_problem(problem, coarse))
    assert res.status == "converged"
    return problem, coarse, res


def test_the_prolonged_network_stands_on_the_fine_mesh(two_levels):
    problem, coarse, res = two_levels
    p = prolong(problem, res.network, coarse.mesh)
    net = p.network
    assert net is not None and p.max_relative_error <= PROLONG_TOL
    assert net.mesh.n_vertices == problem.scene.mesh.n_vertices
    assert np.array_equal(net.mesh.edges, problem.scene.mesh.edges)
    assert independent_check(net).ok
    # compressive: every active weight at or above the lower bound the fine problem states
    sp_ = problem.scaled()
    w = sp_.scaling.weight(net.weights[problem.scene.active_edges])
    assert np.all(w >= sp_.lower * (1 - 1e-12))
    # as near the reference as the coarse network was (the stress, not the shape, is carried)
    d_fine = distance_stats(net.vertices, problem.scene.mesh)[0]
    d_coarse = distance_stats(res.network.vertices, problem.scene.mesh)[0]
    assert d_fine <= 1.25 * d_coarse


def test_the_prolongation_declines_what_frozen_weights_cannot_hold(two_levels):
    problem, coarse, res = two_levels
    fixed = dataclasses.replace(problem, constraints=(FixedTopView(),))
    p = prolong(fixed, res.network, coarse.mesh)
    assert p.network is None and "constraint" in p.info["why"]


def test_boundary_edges_carry_the_coarse_boundarys_force():
    """Along a free boundary the horizontal force w ℓ of the boundary chain is what balances the
    interior's pull, so consecutive fine boundary edges must carry nearly the same force. A
    1,000-vertex pillar vault carried to 16,000 vertices: at every free boundary vertex the two
    boundary forces agree to 10% (measured ≤ 8%; taking the nearest coarse edge of any kind, as
    the prolongation once did, they differed up to 64×, and at 256k vertices 2·10⁴×, and the
    polish slid boundary vertices onto each other)."""
    coarse, fine = make_shape("pillar_vault", n_vertices=1000), make_shape("pillar_vault", n_vertices=16000)
    res = StaggeredLinearization().solve(coarse)
    assert res.status == "converged"
    V, _, _ = transfer(WarmStart(res.network, reference=coarse.mesh), fine)
    m = fine.mesh
    E, b = m.edges, (m.edge_faces < 0).any(axis=1)
    w = boundary_weights(res.network.mesh, res.network.vertices[:, :2], res.network.weights, m, V[:, :2])
    assert np.all(w[~b] == 0) and np.all(np.isfinite(w[b]))
    force = w * np.linalg.norm(V[E[:, 1], :2] - V[E[:, 0], :2], axis=1)
    ratios = []
    for i in np.flatnonzero(~fine.supports):
        inc = np.flatnonzero(b & ((E[:, 0] == i) | (E[:, 1] == i)))
        if len(inc) == 2 and not fine.supports[E[inc]].all(axis=1).any():
            ratios.append(force[inc].max() / force[inc].min())
    assert len(ratios) > 100 and max(ratios) < 1.1


def test_top_view_interpolation_reproduces_linear_fields_and_agrees_with_matplotlib():
    """The interpolation both transfers use (warm.interpolate_over_top_view, points located once
    for every column): a linear field is reproduced exactly by the linear and the C¹ cubic
    interpolant, and the linear one equals matplotlib's own LinearTriInterpolator elsewhere."""
    import matplotlib.tri as mtri

    from selfsupport.core.evidence import triangulate
    from selfsupport.methods.warm import interpolate_over_top_view

    mesh = make_shape("concave_disk", n_vertices=1500).mesh
    xy = mesh.vertices[:, :2]
    rng = np.random.default_rng(5)
    T = triangulate(mesh)
    bary = rng.dirichlet(np.ones(3), size=len(T))
    pts = np.einsum("tk,tkj->tj", bary, xy[T])  # one random point inside every triangle
    coef = rng.standard_normal((3, 3))
    linear = coef[0] + xy @ coef[1:]
    for cubic in (True, False):
        got = interpolate_over_top_view(mesh, linear, pts, cubic=cubic)
        np.testing.assert_allclose(got, coef[0] + pts @ coef[1:], rtol=0, atol=1e-12 * np.abs(linear).max())
    values = rng.standard_normal((mesh.n_vertices, 2))
    tri = mtri.Triangulation(xy[:, 0], xy[:, 1], T)
    ref = np.stack([mtri.LinearTriInterpolator(tri, values[:, k])(pts[:, 0], pts[:, 1]) for k in range(2)], axis=1)
    np.testing.assert_allclose(interpolate_over_top_view(mesh, values, pts, cubic=False), ref, rtol=0, atol=1e-12)


def test_a_prolongation_short_of_its_tolerance_returns_its_nearest_network(monkeypatch):
    """With a tolerance no polish meets (0), ``network`` is None and ``nearest`` is the candidate
    whose polish came nearest: its max relative error, recomputed from the network itself, is the
    one reported, and it is near equilibrium (the polish reaches round-off)."""
    import selfsupport.methods.prolong as prolong_module

    coarse_scene = make_shape("concave_disk", n_vertices=600)
    fine_scene = make_shape("concave_disk", n_vertices=2400)
    coarse = StaggeredLinearization().solve(coarse_scene, {})
    monkeypatch.setattr(prolong_module, "PROLONG_TOL", 0.0)
    p = prolong(as_problem(fine_scene, None), coarse.network, coarse_scene.mesh)
    assert p.network is None and p.nearest is not None and p.info["nearest"] in ("projected", "as carried")
    assert p.nearest.max_relative_error() == p.max_relative_error <= 1e-9


@pytest.fixture(scope="module")
def subdivided_quads():
    """A pillar vault subdivided twice by Catmull–Clark (quads) and its network one level below."""
    fine = subdivide_scene(make_shape("pillar_vault", n_vertices=150), 2)
    parent = subdivision_parents(fine)[-1]
    res = StaggeredLinearization().solve(parent)
    assert res.status == "converged"
    return fine, parent, res


def _without_stress(monkeypatch) -> None:
    """Steps 1–4 unavailable (their weights not finite), so step 5 is tried alone."""
    import selfsupport.methods.prolong as prolong_module

    monkeypatch.setattr(prolong_module, "stress_weights", lambda coarse, cxy, cw, fine, fxy, **kw: np.full(fine.n_edges, np.nan))


def test_a_subdivided_network_with_its_weights_carried_stands_on_the_finer_mesh(subdivided_quads, monkeypatch):
    """Step 5 on its own: the network subdivided by the designer's own Catmull–Clark step, its
    weights carried edge by edge (boundary arches keeping their force), polishes into equilibrium
    on the fine mesh (independent checker at 1e-8), compressive, within the multilevel method's
    RECLAIM × the coarse network's distance to the reference (measured 1.25×)."""
    from selfsupport.methods.multilevel import RECLAIM

    fine, parent, res = subdivided_quads
    _without_stress(monkeypatch)
    sub = subdivide_like(fine, parent, res.network.vertices)
    p = prolong(as_problem(fine), res.network, parent.mesh, subdivision=sub)
    assert p.network is not None and p.info["weights"] == "subdivided" and p.max_relative_error <= PROLONG_TOL
    assert independent_check(p.network, tol=1e-8).ok
    sp_ = as_problem(fine).scaled()
    assert np.all(sp_.scaling.weight(p.network.weights[fine.active_edges]) >= sp_.lower * (1 - 1e-12))
    d_fine = distance_stats(p.network.vertices, fine.mesh)[0]
    assert d_fine <= RECLAIM * distance_stats(res.network.vertices, fine.mesh)[0]
    # a free boundary is one arch at every level: its edges keep the force of the coarse edge
    # they halve (H κ = σ; with the weight kept instead, half of it, the arches of cyl2's quads
    # pulled their corner vertices onto their neighbours)
    net, coarse = p.network, res.network
    bf = np.flatnonzero(fine.mesh.boundary_edge_mask & (net.weights > 0))
    ef = fine.mesh.edges[bf]
    pe = np.where(ef[:, 0] < sub.n_old, ef[:, 1], ef[:, 0]) - sub.n_old  # the coarse edge each one halves
    ce = parent.mesh.edges[pe]

    def plan_lengths(V, e):
        return np.linalg.norm(V[e[:, 1], :2] - V[e[:, 0], :2], axis=1)

    ratio = net.weights[bf] * plan_lengths(net.vertices, ef) / (coarse.weights[pe] * plan_lengths(coarse.vertices, ce))
    assert bf.size > 50 and 0.9 < np.percentile(ratio, 10) and np.percentile(ratio, 90) < 1.1
    # without the subdivision step there is nothing to carry
    assert prolong(as_problem(fine), res.network, parent.mesh).network is None


def test_the_multilevel_method_goes_up_a_subdivided_design_by_its_own_subdivision(subdivided_quads, monkeypatch):
    """Where the stress cannot be carried, the designer's level below subdivided starts the fine
    level, which one iteration confirms."""
    from selfsupport.methods.multilevel import Multilevel

    fine, parent, _ = subdivided_quads
    _without_stress(monkeypatch)
    res = Multilevel(direct_max=parent.mesh.n_vertices).solve(fine)
    top = res.parameters["multilevel"]["levels"][-1]
    assert res.status == "converged" and top["prolongation"]["by"] == "subdivision" and top["iterations"] == 1
    assert independent_check(res, tol=1e-8).ok


def test_the_subdivided_candidate_stands_on_the_designs_supports(monkeypatch):
    """Catmull–Clark moves a support at the end of a supported run of the boundary with its free
    neighbour (the curve rule (a + 6S + b)/8), which in a network has moved: the candidate puts
    every support back where the design has it (the ground holds it), the polish moves only free
    vertices. A cross vault with the boundary on one side unsupported: CC of its network moves
    supports by up to 3.5e-2 m."""
    base = make_shape("cross_vault", n_vertices=150)
    V = base.mesh.vertices
    base = dataclasses.replace(base, supports=base.supports & ~(base.mesh.boundary_vertex_mask & (V[:, 0] > np.median(V[:, 0]))))
    fine = subdivide_scene(base, 2)
    parent = subdivision_parents(fine)[-1]
    res = StaggeredLinearization().solve(parent)
    sub = subdivide_like(fine, parent, res.network.vertices)
    sup = fine.supports
    assert np.abs(sub.mesh.vertices[sup] - fine.mesh.vertices[sup]).max() > 1e-3  # (CC alone moves them)
    _without_stress(monkeypatch)
    p = prolong(as_problem(fine), res.network, parent.mesh, subdivision=sub)
    net = p.network if p.network is not None else p.nearest
    # (to the round-off of the scaling to the solver's units and back)
    assert np.abs(net.vertices[sup] - fine.mesh.vertices[sup]).max() <= 1e-12 * np.ptp(V, axis=0).max()


def test_a_candidate_at_its_round_off_floor_gets_no_newton_steps(monkeypatch):
    """A 3,000-vertex pillar vault 10⁴ m from the origin (site coordinates): its candidates'
    Anderson rounds end at 1.2e-8 / 1.6e-8, above the prolongation's tolerance and held there by
    the rounding of the positions alone (`Network.roundoff_limit`). Newton's steps cannot go
    below that floor, so neither candidate gets any (at 256k vertices they cost 30 s each), and
    the nearest network is handed on as before."""
    import selfsupport.methods.prolong as prolong_module
    from selfsupport.methods.multilevel import START_TOL

    scene = make_shape("pillar_vault", n_vertices=3000)
    far = dataclasses.replace(scene, mesh=scene.mesh.with_vertices(scene.mesh.vertices + [1e4, 3e3, 0.0]))
    problem = as_problem(far)
    coarse = coarsen(far, 750)
    res = StaggeredLinearization().solve(coarse_problem(problem, coarse))
    assert res.status == "converged"
    calls = []
    real = prolong_module.polish

    def counted(*a, **k):
        out = real(*a, **k)
        calls.append(bool(k.get("newton")))
        return out

    monkeypatch.setattr(prolong_module, "polish", counted)
    p = prolong(problem, res.network, coarse.mesh)
    assert p.network is None and PROLONG_TOL < p.max_relative_error <= START_TOL
    assert p.nearest.roundoff_limit(PROLONG_TOL) is not None
    assert calls == [False, False]  # Anderson's rounds for "projected" and "as carried", no Newton


def test_the_stress_with_its_boundary_is_the_fallback_where_the_others_do_not_come_near(two_levels, monkeypatch):
    """When neither candidate of the boundary-free stress comes within START_TOL (here its
    weights are spoiled: every interior edge's scaled by 10^u, u uniform in [−3, 3]), the stress
    with the boundary edges counted is tried, and carries the network into equilibrium. When a
    candidate has come near, the fallback is not made at all."""
    import selfsupport.methods.prolong as prolong_module

    problem, coarse, res = two_levels
    real = prolong_module.stress_weights
    made = []

    def spoiled(*a, with_boundary=False, **k):
        made.append(with_boundary)
        w = real(*a, with_boundary=with_boundary, **k)
        return w if with_boundary else w * 10.0 ** np.random.default_rng(0).uniform(-3, 3, len(w))

    monkeypatch.setattr(prolong_module, "stress_weights", spoiled)
    p = prolong(problem, res.network, coarse.mesh)
    assert p.network is not None and p.info["weights"] == prolong_module.FALLBACK
    assert p.max_relative_error <= PROLONG_TOL and independent_check(p.network, tol=1e-8).ok
    assert made == [False, True]
    made.clear()
    monkeypatch.setattr(prolong_module, "stress_weights", lambda *a, **k: (made.append(k.get("with_boundary")),
                                                                           real(*a, **k))[1])
    p = prolong(problem, res.network, coarse.mesh)
    assert p.network is not None and p.info["weights"] != prolong_module.FALLBACK and made == [False]
