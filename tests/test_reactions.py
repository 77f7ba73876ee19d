"""Support reactions: global equilibrium, a parabolic arch's thrust in closed form, a symmetric
dome's symmetric, inward-pointing reactions, and the reactions in the network file, the
summaries and the figure."""
from __future__ import annotations

import json

import numpy as np
import pytest

from formulations.equilibrium import Topology, load_vector, weight_matrix
from selfsupport import api
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import residuals, support_reactions
from selfsupport.core.loads import SelfWeight
from selfsupport.core.result import Network
from selfsupport.core.shapes import make_shape
from selfsupport.io import read_network, write_network
from selfsupport.io.network_json import read_reactions


@pytest.fixture(scope="module")
def dome():
    """A solved dome (self-weight, outer ring supported)."""
    res = api.solve(make_shape("dome", n_vertices=170))
    assert res.converged
    return res


def symmetric_cap() -> Network:
    """A shallow spherical cap on the 6-fold symmetric ring mesh, at its reference positions, with
    the minimum-norm weights that balance its self-weight: unique, hence as symmetric as the
    mesh (a solve's weights and positions are not unique: they break the symmetry at 1e-4)."""
    scene = make_shape("dome", n_vertices=170, height=1.5)
    m, sup = scene.mesh, scene.supports
    V, E = m.vertices, m.edges
    act = ~(sup[E[:, 0]] & sup[E[:, 1]])
    loads = SelfWeight().nodal(m, V)
    top = Topology.build(len(V), E[act], sup)
    W = np.zeros(len(E))
    W[act] = np.linalg.lstsq(weight_matrix(top, V).toarray(), load_vector(top, loads), rcond=None)[0]
    return Network(mesh=m, weights=W, loads=loads, supports=sup)


def test_parabolic_arch_thrust_is_q_l_squared_over_8_f():
    """n equal loads P at equal plan spacing h on the parabola of span L and rise f: the
    funicular polygon, whose horizontal thrust is H = q L² / (8 f) with q = P / h. The weights
    come from a least-squares solve of eqs. (2)-(3) at the fixed positions (not from H)."""
    L, f, n, P = 12.0, 3.0, 8, 1500.0
    x = np.linspace(-L / 2, L / 2, n + 1)
    V = np.stack([x, np.zeros_like(x), 4 * f * (L / 2 - x) * (L / 2 + x) / L ** 2], axis=1)
    E = np.stack([np.arange(n), np.arange(1, n + 1)], axis=1)
    sup = np.zeros(n + 1, bool)
    sup[[0, n]] = True
    loads = np.where(sup, 0.0, -P)
    top = Topology.build(n + 1, E, sup)
    w = np.linalg.lstsq(weight_matrix(top, V).toarray(), load_vector(top, loads), rcond=None)[0]
    assert np.abs(residuals(vertices=V, edges=E, weights=w, loads=loads)[~sup]).max() < 1e-9 * P
    assert w.min() > 0  # compression
    R = support_reactions(vertices=V, edges=E, weights=w, loads=loads, supports=sup)
    H = (P / (L / n)) * L ** 2 / (8 * f)
    np.testing.assert_allclose(R[:, 0], [H, -H], rtol=1e-12)  # the ground pushes inward
    np.testing.assert_allclose(R[:, 1], 0.0, atol=1e-12 * H)
    np.testing.assert_allclose(R[:, 2], (n - 1) * P / 2, rtol=1e-12)  # half the load each


def test_reactions_balance_every_load_in_all_three_components(tmp_path):
    """Σ R = −Σ L (x, y and z) to rounding, for an asymmetric load (self-weight and an
    off-centre point load) on a pillar vault: what the supports carry is what is put on the vault."""
    scene = make_shape("pillar_vault", n_vertices=300)
    res = api.solve(scene, point_loads={int(np.flatnonzero(scene.free)[17]): 8000.0})
    assert res.converged
    net = res.network
    R = net.support_reactions()
    total = float(np.abs(net.loads).sum())
    np.testing.assert_allclose(R.sum(axis=0), [0.0, 0.0, -net.loads.sum()], atol=1e-9 * total)
    s = net.reaction_summary()
    assert s["vertical"] == pytest.approx(-net.loads.sum(), rel=1e-9)
    h = np.linalg.norm(R[:, :2], axis=1)
    assert s["max_horizontal"] == h.max() and s["thrust"] == pytest.approx(h.sum())
    assert s["max_horizontal_vertex"] == int(np.flatnonzero(net.supports)[np.argmax(h)])


def test_a_symmetric_dome_has_symmetric_inward_reactions():
    """The ring mesh is invariant under a turn of 60°: each support's reaction turned by 60° is
    the reaction at the support it maps to; every horizontal reaction points towards the axis
    (the vault, in compression, thrusts outward) and every vertical one up."""
    net = symmetric_cap()
    assert net.max_relative_error() < 1e-12 and net.min_weight() > 0  # a compressive network in equilibrium
    sv = np.flatnonzero(net.supports)
    P = net.vertices[sv]
    R = net.support_reactions()
    c, s = np.cos(np.pi / 3), np.sin(np.pi / 3)
    T = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    image = np.array([int(np.argmin(np.linalg.norm(P - T @ p, axis=1))) for p in P])
    assert np.linalg.norm(P[image] - P @ T.T, axis=1).max() < 1e-12  # the supports map onto supports
    scale = np.abs(R).max()
    np.testing.assert_allclose(R[image], R @ T.T, atol=1e-10 * scale)
    mirror = np.array([int(np.argmin(np.linalg.norm(P - p * [1, -1, 1], axis=1))) for p in P])  # y -> -y
    np.testing.assert_allclose(R[mirror], R * [1, -1, 1], atol=1e-10 * scale)
    radial = np.einsum("ij,ij->i", R[:, :2], P[:, :2]) / np.linalg.norm(P[:, :2], axis=1)
    assert np.all(radial < 0) and np.all(R[:, 2] > 0)


def test_the_network_file_carries_the_reactions_and_old_files_still_read(dome, tmp_path):
    p = tmp_path / "dome.json"
    write_network(p, dome)
    doc = json.loads(p.read_text())
    entry = doc["support_reactions"]
    assert entry["vertices"] == doc["supports"] and entry["unit"] == "N"
    np.testing.assert_array_equal(np.asarray(entry["forces"]), dome.network.support_reactions())
    idx, forces = read_reactions(p)
    np.testing.assert_array_equal(forces, dome.network.support_reactions())
    # recomputed from the file alone (plain numpy): the same forces
    V, E, w = np.asarray(doc["vertices"]), np.asarray(doc["edges"]), np.asarray(doc["weights"])
    r = np.zeros_like(V)
    np.add.at(r, E[:, 0], w[:, None] * (V[E[:, 1]] - V[E[:, 0]]))
    np.add.at(r, E[:, 1], -w[:, None] * (V[E[:, 1]] - V[E[:, 0]]))
    r[:, 2] -= np.asarray(doc["loads"])
    np.testing.assert_allclose(forces, r[idx], rtol=1e-12, atol=1e-9)
    old = tmp_path / "old.json"
    old.write_text(json.dumps({k: v for k, v in doc.items() if k != "support_reactions"}))
    assert read_reactions(old) is None
    np.testing.assert_array_equal(read_network(old).support_reactions(), forces)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**doc, "support_reactions": {**entry, "vertices": entry["vertices"][:-1]}}))
    with pytest.raises(InputError, match="support_reactions") as e:
        read_network(bad)
    assert "\n" not in str(e.value)


def test_solve_and_check_print_the_reactions_in_kN(tmp_path, capsys):
    from selfsupport.cli import main

    out = tmp_path / "n.json"
    assert main(["solve", "shape:dome:100", "--out", str(out), "-q"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    net = read_network(out)
    s = net.reaction_summary()
    assert (f"support reactions vertical {s['vertical'] / 1e3:.6g} kN (load {-net.loads.sum() / 1e3:.6g} kN), max "
            f"horizontal {s['max_horizontal'] / 1e3:.4g} kN at {s['max_horizontal_vertex']}") in text
    assert f"{s['vertical'] / 1e3:.6g}" == f"{-net.loads.sum() / 1e3:.6g}"
    assert main(["check", str(out)]) == 0
    text = capsys.readouterr().out
    fitted = api.check(out).network.reaction_summary()
    assert (f"support reactions of the fitted weights: vertical {fitted['vertical'] / 1e3:.6g} kN (load "
            f"{-net.loads.sum() / 1e3:.6g} kN)") in text


def test_the_reactions_figure_draws_each_horizontal_reaction(dome):
    """One arrow per support, from the support, along its horizontal reaction, lengths in
    proportion to the forces."""
    from matplotlib.quiver import Quiver

    from selfsupport.figures.render import FigureInput, make_figure

    fig = make_figure("reactions", FigureInput(dome.network))
    q = [c for c in fig.axes[0].collections if isinstance(c, Quiver)]
    assert len(q) == 1
    net = dome.network
    R = net.support_reactions()
    np.testing.assert_allclose(q[0].X, net.vertices[net.supports][:, 0])
    np.testing.assert_allclose(q[0].Y, net.vertices[net.supports][:, 1])
    UV = np.stack([q[0].U, q[0].V], axis=1)
    k = UV[:, 0] / R[:, 0]
    np.testing.assert_allclose(UV, R[:, :2] * np.median(k), rtol=1e-9, atol=1e-12)
    assert np.median(k) > 0
