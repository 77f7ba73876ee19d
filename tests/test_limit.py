"""Limit analysis by one program (:mod:`selfsupport.structure.limit`): answers with analytic anchors, and
every "stands" checked outside the package: equilibrium by plain numpy and the shared checker,
"inside the hull" by brute-force point-to-triangle distances (tests/test_stability.py)."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from selfsupport import api
from selfsupport.core.loads import G
from selfsupport.core.shapes import make_shape
from selfsupport.structure.limit import CERTIFY_TOL, feasible, limit_load, min_thickness
from tests.conftest import independent_check, max_relative_error, requires_checker
from tests.test_stability import distance_to_mesh

#: Heyman (1977): the thinnest hemispherical dome that stands under self-weight, t/R.
HEYMAN = 0.042


def cap():
    """A shallow spherical cap (rise 3 m over a 5 m radius), supported on its rim."""
    return make_shape("dome", rings=6, radius=5.0, height=3.0)


def assert_certificate(res, reference, t: float, supports_too: bool = False) -> None:
    """In equilibrium (plain numpy), compressive, every free vertex (and the supports, when
    they slide) within t/2 of the reference by brute-force distances."""
    net = res.network
    err = max_relative_error(net.vertices, net.edges, net.weights, net.loads, net.supports)
    assert err <= CERTIFY_TOL and net.weights.min() >= 0
    d = distance_to_mesh(net.vertices, reference)
    held = np.ones_like(net.supports) if supports_too else ~np.asarray(net.supports)
    assert d[held].max() <= 0.5 * t * (1 + 1e-6), f"{d[held].max():.6g} m from the reference, t/2 = {0.5 * t}"


@requires_checker
def test_max_load_certificate_is_inside_the_hull_and_carries_the_load():
    scene = cap()
    r = limit_load(scene, thickness=0.3, density=2000.0, at=[0])
    assert r.certified and r.verdict == "certified" and r.value > 0
    assert_certificate(r.certificate, scene.mesh, 0.3)
    assert independent_check(r.certificate).ok
    # the loads: the vault's own weight (at the reference) plus the certified mass at the apex
    own = api.problem(scene, density=2000.0, thickness=0.3).loads.nodal(scene.mesh, scene.mesh.vertices)[0]
    assert r.certificate.network.loads.sum() - own.sum() == pytest.approx(-r.value * G, rel=1e-12)
    # and it is a limit: a vertex on the hull's face binds it
    assert r.binding and abs(r.binding[0][1]) == pytest.approx(1.0, abs=1e-3)


def test_shallow_cap_max_apex_load_grows_with_thickness():
    scene = cap()
    kg = [limit_load(scene, thickness=t, density=2000.0, at=[0]).value for t in (0.1, 0.2, 0.3)]
    assert all(k is not None for k in kg) and kg[0] < kg[1] < kg[2], kg


def test_above_the_max_load_the_program_reports_local_infeasibility():
    """5% above the certified limit the feasibility program finds no point; the verdict says
    "locally infeasible" because IPOPT said so, and no value is certified."""
    scene = cap()
    top = limit_load(scene, thickness=0.2, density=2000.0, at=[0])
    above = feasible(scene, thickness=0.2, density=2000.0, kg=1.05 * top.value, at=[0], start=top.certificate)
    below = feasible(scene, thickness=0.2, density=2000.0, kg=0.95 * top.value, at=[0], start=top.certificate)
    assert not above.certified and above.value is None
    assert above.verdict == "locally infeasible" and "IPOPT reported Infeasible_Problem_Detected" in above.message
    assert below.certified and below.value == pytest.approx(0.95 * top.value)
    assert_certificate(below.certificate, scene.mesh, 0.2)


@requires_checker
def test_hemisphere_min_thickness_is_certified_and_not_below_heymans():
    """A network of the hemisphere certifies its t (safe theorem), so the certified t/R cannot
    be below the exact minimum of the continuous dome, Heyman's 0.042 (the faceted reference
    could shift it by its sag, ~0.3% of R at 8 rings). The supports slide across the springing."""
    scene = make_shape("dome", rings=8, radius=5.0, height=5.0)
    r = min_thickness(scene, density=2000.0, guess=0.5, slide_supports=True)
    assert r.certified and r.value >= r.optimum
    assert r.value / 5.0 >= HEYMAN * (1 - 0.01)
    assert_certificate(r.certificate, scene.mesh, r.value, supports_too=True)
    assert independent_check(r.certificate).ok


@pytest.mark.xfail(strict=True, reason="the discrete program certifies t/R ~ 0.050 (8 and 12 rings alike), "
                                       "19% above Heyman's 0.042; the cause is not found yet")
def test_hemisphere_min_thickness_matches_heyman_within_15_percent():
    scene = make_shape("dome", rings=8, radius=5.0, height=5.0)
    r = min_thickness(scene, density=2000.0, guess=0.5, slide_supports=True)
    assert r.certified and abs(r.value / 5.0 - HEYMAN) <= 0.15 * HEYMAN


@requires_checker
def test_stability_cli_max_load_is_the_limit_program(tmp_path, capsys):
    from selfsupport.cli import main

    rc = main(["stability", "shape:dome:127", "--thickness", "0.3", "--density", "2000", "--load-at", "0",
               "--max-load", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    kg = float(re.fullmatch(r"max load: (\S+) kg", [ln for ln in out.splitlines() if ln.startswith("max load:")][0])
               .group(1))
    doc = json.loads((tmp_path / "max-load.json").read_text())
    prog = json.loads((tmp_path / "max-load-program.json").read_text())
    assert doc["added_mass_kg"] == pytest.approx(kg, rel=1e-5) and prog["verdict"] == "certified"
    assert doc["parameters"]["hull"]["certified"] and doc["parameters"]["limit"] == "max_load"
    assert independent_check(tmp_path / "max-load.json").ok
    assert not (tmp_path / "max-load-probes.json").exists()
