"""The bracing study (studies/bracing.py) on the tests' free-edged quad vault, which stands under
the cases as quads. No paper scene is run."""
from __future__ import annotations

import json

import numpy as np
import pytest

from selfsupport import api
from studies.bracing import diagonal_mask, study
from studies.stand_search import STANDS_TOL, write_control


@pytest.mark.parametrize("steps", ["staggered", "ipopt"])
def test_the_diagonals_bound_holds_at_every_step_and_the_quads_stand_from_the_last_one(tmp_path, steps):
    """By either method of the steps: every step that stands keeps its diagonals' weights within
    [0, f·D0] in every case, the diagonals' share of the load falls with the bound, and the design
    itself, started from the last step with its diagonals dropped, stands by both methods."""
    path = write_control(tmp_path, n=6)
    design_edges = api.as_scene(str(path)).mesh.edges
    rows, info = study(path, tmp_path, None, 0.05, (0.1, 0.001), time_limit=60.0, step_time_limit=60.0, steps=steps,
                       log=lambda _: None)
    assert [r["step"] for r in rows] == ["split", "diagonals ≤ 0.1·D0", "diagonals ≤ 0.001·D0",
                                         "quads, staggered", "quads, IPOPT"]
    assert all(r["stands"] and r["worst_error"] <= STANDS_TOL for r in rows)
    assert info["last_standing_bound"] == rows[2]["bound"] == 0.001 * info["D0"]
    for k, r in enumerate(rows[1:3], start=1):
        doc = json.loads((tmp_path / f"{path.stem}-0.05-step{k}.json").read_text())
        diag = diagonal_mask(np.asarray(doc["edges"]), design_edges)
        assert diag.sum() == info["diagonals"]
        for case in doc["load_cases"]:
            w = np.asarray(case["weights"])[diag]
            assert w.min() >= -1e-12 * r["bound"] and w.max() <= r["bound"] * (1 + 1e-12)
    assert rows[0]["diagonal_share"] > rows[1]["diagonal_share"] > rows[2]["diagonal_share"] > 0.0
    assert rows[3]["diagonal_share"] == rows[4]["diagonal_share"] == 0.0


def test_bracing_docstring_examples():
    """studies/ is not collected for doctests (scripts); the bracing study's examples run here."""
    import doctest

    from studies import bracing

    result = doctest.testmod(bracing, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted >= 1 and result.failed == 0


def test_bounds_that_do_not_fall_or_a_missing_scene_are_refused_before_any_solve(tmp_path, capsys):
    from studies.bracing import main

    with pytest.raises(SystemExit):
        main(["--control", "--out", str(tmp_path), "--fractions", "0.1,0.5"])
    assert "--fractions: positive numbers, falling" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--scenes", str(tmp_path), "--only", "absent", "--out", str(tmp_path / "o")])
    assert "no scene" in capsys.readouterr().err and not (tmp_path / "o" / "bracing.csv").exists()
