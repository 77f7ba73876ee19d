"""The Step-3 tolerance study (studies/step_tolerance.py) on a generated scene. No paper scene is run."""
from __future__ import annotations

from selfsupport.core.shapes import make_shape
from selfsupport.io.sss import write_scene_sss
from studies.step_tolerance import run_scene


def test_the_study_measures_fewer_cg_iterations_the_same_network_and_a_turned_input_at_round_off(tmp_path):
    """A pillar vault at the default tolerance and at 1e-4: the reference row has no change
    against itself, the looser one fewer CG iterations and the same outer iterations, a mean
    distance within 1e-3, and at the default the turned input's network is the turned network
    to 1e-7 of the diagonal (tests/test_invariance.py's bound)."""
    write_scene_sss(tmp_path / "vault.sss", make_shape("pillar_vault", n_vertices=300))
    tight, loose = run_scene(tmp_path, "vault", (1e-7, 1e-4), repeat=1)
    assert tight["status"] == loose["status"] == "converged"
    assert tight["distance_change"] == 0.0 and tight["cpu_ratio"] == 1.0
    assert loose["cg_iterations"] < tight["cg_iterations"] and loose["iterations"] == tight["iterations"]
    assert abs(loose["distance_change"]) < 1e-3
    assert tight["turned"] <= 1e-7
