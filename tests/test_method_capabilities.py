"""Methods are told apart by what they declare they can do (``selfsupport.methods.Capabilities``),
never by their names: the registry, the hull search, the memory guard, options and the hard-hull
IPOPT path."""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from formulations import Hull, Problem
from selfsupport import api
from selfsupport.core.errors import InputError
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import make_shape
from selfsupport.methods import METHODS, Capabilities, capabilities, find_method, memory, method_class
from selfsupport.methods.choice import AUTO, CANDIDATES, LEVELS_ABOVE, choose_method
from selfsupport.methods.simultaneous import Simultaneous
from selfsupport.structure.stability import solve_in_hull

ROOT = Path(__file__).resolve().parents[1]


def test_every_method_is_named_by_its_registry_key_and_declares_capabilities():
    """The name a result records is the name the user types (IPOPT and nlopt had both called
    themselves "simultaneous"), and every registered class states its capabilities."""
    for key in METHODS:
        cls = method_class(key)
        assert cls.name == key
        assert isinstance(cls.__dict__.get("capabilities"), Capabilities), key
    assert api.METHODS is METHODS  # (one registry, re-exported)
    res = api.solve(make_shape("dome", n_vertices=60), method="ipopt")
    assert res.method == "ipopt" and capabilities(res.method).simultaneous


def _is_method_name(node: ast.AST) -> bool:
    """An expression that holds a method's name: ``method``, ``name``, ``x.method``, ``x.name``."""
    ident = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
    return ident in {"method", "name", "method_name"}


def test_no_code_branches_on_a_method_name():
    """No comparison of a method's name with a registered name (``method == "ipopt"``,
    ``result.method in ("staggered", ...)``) anywhere in the package: callers ask for a capability.
    (``method == AUTO`` — the user leaving the choice to us — is not a method's name.)"""
    names = set(METHODS) | {"simultaneous"}
    hits = []
    for path in sorted((ROOT / "selfsupport").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.Compare):
                continue
            sides = [node.left, *node.comparators]
            if not any(_is_method_name(s) for s in sides):
                continue
            consts = [c.value for s in sides for c in ast.walk(s)
                      if isinstance(c, ast.Constant) and isinstance(c.value, str)]
            if any(c in names for c in consts):
                hits.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not hits, hits


class _Recorder:
    """A method that declares ``caps`` and answers every solve with ``result``, recording what it was asked."""

    name = "recorder"

    def __init__(self, caps: Capabilities, result) -> None:
        self.capabilities, self.result, self.calls = caps, result, []

    def solve(self, problem, options=None, *, progress=None):
        self.calls.append({"hull": problem.hull_thickness() if problem.constraint(Hull) else None,
                           "warm_start": dict(options or {}).get("warm_start")})
        return self.result


@pytest.fixture(scope="module")
def dome_in_hull():
    """A dome whose hull of t = 0.4 m holds a network (IPOPT certifies it with hard rows)."""
    scene = make_shape("dome", rings=5, radius=5.0, height=3.0)
    problem = Problem.build(scene, SelfWeight(density=2000.0, thickness=0.4), constraints=[Hull(0.4)])
    return problem, method_class("ipopt")().solve(problem)


def test_the_hull_search_follows_the_hull_as_rows_capability(dome_in_hull):
    """A method declaring hull_as_rows is asked once, with the hull, and handed the warm start when
    it takes one; a method declaring neither climbs the penalty ladder from the reference."""
    problem, found = dome_in_hull
    hard = _Recorder(Capabilities(hull_as_rows=True, warm_start=True), found)
    res = solve_in_hull(problem, method=hard, warm_start=found)
    assert hard.calls == [{"hull": 0.4, "warm_start": found}]
    assert [r["penalty"] for r in res.parameters["hull_search"]] == ["hard"]
    no_start = _Recorder(Capabilities(hull_as_rows=True), found)
    solve_in_hull(problem, method=no_start, warm_start=found)
    assert no_start.calls == [{"hull": 0.4, "warm_start": None}]
    ladder = _Recorder(Capabilities(warm_start=True), found)
    res = solve_in_hull(problem, method=ladder, warm_start=found)
    # (the answer is inside the hull already: the first rung, without the hull, ends the search)
    assert ladder.calls == [{"hull": None, "warm_start": None}]
    assert [r["penalty"] for r in res.parameters["hull_search"]] == [0.0]


def test_ipopt_under_the_hull_takes_the_hard_rows_from_the_warm_start(dome_in_hull, monkeypatch):
    """``api.solve(method="ipopt")`` with the hull: one hard-row solve, and its first IPOPT round
    starts at the given network (the penalty ladder would start from the reference, without the hull)."""
    problem, _ = dome_in_hull
    kw = dict(method="ipopt", constraints=["hull"], density=2000.0, thickness=0.4)
    cold = api.solve(problem.scene, **kw)
    starts, hulls = [], []
    solve_round = Simultaneous._solve_round

    def spy(self, form, nlp, x, *args, **kwargs):
        starts.append(form.unpack_cases(x)[0])
        hulls.append(form.hull is not None)
        return solve_round(self, form, nlp, x, *args, **kwargs)

    monkeypatch.setattr(Simultaneous, "_solve_round", spy)
    warm = api.solve(problem.scene, warm_start=cold, **kw)
    for res in (cold, warm):
        assert res.status == "converged" and res.parameters["hull"]["certified"]
        assert [r["penalty"] for r in res.parameters["hull_search"]] == ["hard"]
    assert warm.parameters["warm_start"] and warm.parameters["design"]["start"] == "warm_start network"
    assert all(hulls)  # (every round with the hull's rows)
    scaling = problem.scaled().scaling
    np.testing.assert_allclose(starts[0], scaling.pos(cold.network.vertices), rtol=0, atol=1e-12)
    assert np.abs(starts[0] - scaling.pos(problem.scene.mesh.vertices)).max() > 1e-4


def test_the_memory_guard_reads_the_methods_rates():
    """The estimate is the method's declared rate; ``auto`` takes the larger of the methods it picks from."""
    n = 10_000
    for key in METHODS:
        assert memory.estimate_solve_bytes(n, key) == pytest.approx(
            memory.BASE_BYTES + capabilities(key).bytes_per_vertex * n)
    assert memory.bytes_per_vertex(AUTO) == max(capabilities(m).bytes_per_vertex for m in CANDIDATES)
    assert memory.bytes_per_vertex("ipopt") > memory.bytes_per_vertex("staggered")


def test_auto_on_a_small_mesh_asks_only_the_method_it_picks(monkeypatch):
    """Up to LEVELS_ABOVE vertices ``auto`` picks the staggered method (whatever the mesh), so its
    estimate asks that method alone for its rate (the multilevel module is not loaded for it);
    above, the larger of the candidates' rates."""
    small, big = LEVELS_ABOVE, LEVELS_ABOVE + 1
    dome = make_shape("dome", n_vertices=200)
    assert choose_method(Problem.build(dome, SelfWeight(density=2000.0, thickness=0.1))).method == "staggered"
    asked: list[str] = []
    rates = {"staggered": 1.0, "multilevel": 3.0}
    monkeypatch.setattr(memory, "capabilities", lambda m: asked.append(m) or Capabilities(bytes_per_vertex=rates[m]))
    assert memory.estimate_solve_bytes(small, AUTO) == memory.BASE_BYTES + 1.0 * small and asked == ["staggered"]
    assert memory.estimate_solve_bytes(big, AUTO) == memory.BASE_BYTES + 3.0 * big
    assert set(asked) == set(CANDIDATES)


def test_options_go_only_to_a_method_that_declares_their_type():
    scene = make_shape("dome", n_vertices=60)
    takes = [m for m in METHODS if capabilities(m).options_type is not None]
    assert takes == ["staggered", "multilevel"]
    with pytest.raises(InputError, match="apply to the staggered and multilevel methods only, not 'ipopt'"):
        api.solve(scene, method="ipopt", options={"coupled": True})
    with pytest.raises(InputError, match="shrink"):  # (checked against the declared type's ranges)
        api.solve(scene, method="staggered", options={"shrink": 7.0})


def test_find_method_picks_by_capability():
    assert find_method(planar_rows=True, warm_start=True) == "ipopt"
    assert find_method(levels=True) == "multilevel"
    with pytest.raises(InputError, match="unknown capabilities"):
        find_method(flies=True)


def test_each_class_declares_the_capabilities_its_registry_entry_states():
    """One declaration: a method class's ``capabilities`` is its registry entry's, so asking the
    registry (no import) and the class agree; the options type resolves to the class it names."""
    from selfsupport.methods.staggered import StaggeredOptions

    for key, spec in METHODS.items():
        assert method_class(key).capabilities is spec.capabilities is capabilities(key)
    assert capabilities("staggered").options_class() is StaggeredOptions
    assert capabilities("ipopt").options_class() is None
