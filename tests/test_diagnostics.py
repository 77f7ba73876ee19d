"""Diagnostics on stderr: a network far from its reference, the input
warnings of ``parameters.input_issues`` (each once), and a network outside the masonry hull."""
from __future__ import annotations

from selfsupport import api, cli
from selfsupport.core.shapes import make_shape
from selfsupport.io import write_mesh
from selfsupport.methods.diagnostics import FAR_FROM_REFERENCE, HULL_MAJORITY, solve_warnings


def _warnings(err: str) -> list[str]:
    lines = err.strip().splitlines()
    return [ln for ln in lines if ln.startswith("selfsupport: warning: ")]


def test_an_upside_down_dome_warns_that_the_network_is_far_from_its_reference(tmp_path, capsys):
    mesh = tmp_path / "dome.obj"
    write_mesh(mesh, make_shape("dome", n_vertices=300).mesh)  # z up; read with --up=-z it is a bowl
    code = cli.main(["solve", str(mesh), "--supports", "boundary", "--up=-z", "--out", str(tmp_path / "n.json"), "-q"])
    assert code == 0  # it converges, far away (mean distance 0.42 of the diagonal)
    far = [w for w in _warnings(capsys.readouterr().err) if "far from its reference" in w]
    assert len(far) == 1 and f"above {FAR_FROM_REFERENCE:g}" in far[0]


def test_input_warnings_are_printed_once_each(tmp_path, capsys):
    mesh = tmp_path / "dome.obj"
    write_mesh(mesh, make_shape("dome", n_vertices=300).mesh)
    res = api.solve(str(mesh), supports="boundary", up="-z")
    issues = [i["message"] for i in res.parameters["input_issues"] if i["severity"] == "warning"]
    assert issues  # (a bowl: its lowest vertex cannot be balanced where it is)
    cli.main(["solve", str(mesh), "--supports", "boundary", "--up=-z", "--out", str(tmp_path / "n.json"), "-q"])
    printed = _warnings(capsys.readouterr().err)
    for msg in issues:
        assert sum(msg in w for w in printed) == 1, msg


def test_a_network_outside_the_masonry_hull_is_reported(tmp_path, capsys):
    scene = make_shape("pillar_vault", n_vertices=300)
    res = api.solve(scene)
    (line,) = [w for w in solve_warnings(res, scene) if "masonry hull" in w]
    # the same numbers as the report a hull-constrained solve records (one computation)
    from formulations import Problem
    from selfsupport.core.loads import SelfWeight
    from selfsupport.methods.base import hull_excess, hull_report

    rep = hull_excess(scene, res.network, 0.1)
    assert rep == hull_report(Problem.build(scene, SelfWeight(), constraints=["hull"]), res.network)
    assert rep["outside"] > HULL_MAJORITY * rep["free"] and f"{rep['outside']} of {rep['free']}" in line
    # a thick enough shell holds the same network: no warning
    res_thick = api.solve(scene, thickness=10.0, density=24.0)  # same load ρ·t, a 10 m shell
    assert not [w for w in solve_warnings(res_thick, scene) if "masonry hull" in w]
    code = cli.main(["solve", "shape:pillar_vault:300", "--out", str(tmp_path / "n.json"), "-q"])
    assert code == 0 and sum("masonry hull" in w for w in _warnings(capsys.readouterr().err)) == 1


def test_a_network_near_its_reference_gets_no_warning(capsys, tmp_path):
    code = cli.main(["solve", "shape:dome:300", "--out", str(tmp_path / "n.json"), "-q"])
    assert code == 0 and _warnings(capsys.readouterr().err) == []


def test_a_refinement_that_kept_no_step_is_told():
    """A cross vault supported along one half with 5% of its weight on a free vertex: the
    refinement (on by default for point loads) rejects all its trial steps; the CLI says so
    instead of leaving it to the history (the network is the unrefined one)."""
    import dataclasses

    import numpy as np

    scene = make_shape("cross_vault", n_vertices=100)
    V = scene.mesh.vertices
    half = dataclasses.replace(scene, supports=scene.supports & (V[:, 0] <= np.median(V[:, 0])))
    weight = abs(float(api.solve(half).network.loads.sum()))
    res = api.solve(half, point_loads={5: 0.05 * weight})
    refine = [h for h in res.history if h.get("iteration") == "refine"][-1]
    assert res.converged and refine["tried"] > 0 and not refine["applied"]
    (line,) = [w for w in solve_warnings(res, half) if "refinement" in w]
    assert f"none of its {refine['tried']} trial steps" in line and "kept none" in res.message
    # (a refinement that did move the network gives no such line)
    plain = make_shape("cross_vault", n_vertices=100)
    moved = api.solve(plain, point_loads={int(np.flatnonzero(~plain.supports)[20]): 0.05 * weight})
    assert [h for h in moved.history if h.get("iteration") == "refine"][-1]["applied"]
    assert not [w for w in solve_warnings(moved, plain) if "refinement" in w]
